"""``ScenarioError``: a scenario file is wrong; names the file, the key path, what was given and expected."""
from __future__ import annotations

from pathlib import Path

_MISSING = object()


class ScenarioError(ValueError):
    """A scenario file failed validation.

    Attributes:
        file: the scenario file (None for in-memory documents).
        key: key path such as ``fmus[2].parameters.Kp`` (empty for the whole file).
        given: the offending value (or None when a key is missing).
        expected: what was expected, in words.
    """

    def __init__(self, file: str | Path | None, key: str, expected: str, given: object = _MISSING,
                 problem: str | None = None) -> None:
        self.file = None if file is None else Path(file)
        self.key = key
        self.expected = expected
        self.given = None if given is _MISSING else given
        where = f"{self.file}" if self.file is not None else "<scenario>"
        if key:
            where += f": {key}"
        text = f"{where}: {problem + '; ' if problem else ''}expected {expected}"
        if given is not _MISSING:
            text += f", got {given!r}"
        super().__init__(text)
