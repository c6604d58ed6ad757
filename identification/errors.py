"""Errors of the dynamic identification (all are ``ValueError`` subclasses)."""
from __future__ import annotations


class IdentificationError(ValueError):
    """Base class: the identification cannot proceed with what it was given."""


class IdentificationDataError(IdentificationError):
    """Measured data are malformed: file, columns, NaNs, sampling, too few samples."""


class InsufficientExcitationError(IdentificationError):
    """The data do not excite every base parameter (rank deficient or badly conditioned).

    ``poorly_excited`` names the base parameters that the data cannot separate;
    ``condition_number`` is the condition number of the column-normalised base
    regressor (``inf`` when rank deficient).
    """

    def __init__(self, message: str, poorly_excited: tuple[str, ...] = (),
                 condition_number: float = float("inf")) -> None:
        super().__init__(message)
        self.poorly_excited = tuple(poorly_excited)
        self.condition_number = float(condition_number)


class ExcitationDesignError(IdentificationError):
    """An exciting-trajectory design request is malformed or infeasible."""
