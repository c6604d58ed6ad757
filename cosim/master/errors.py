"""Errors raised by the co-simulation master.

``MasterConfigError`` is bad wiring found while building a co-simulation (unknown
variable, type or causality mismatch, step not a multiple of the base step); it is the
FMU layer's ``fmus.errors.FmuConfigError`` (a ``ValueError``), so a wrong variable name
is one error whether the FMU or the master finds it. ``SimulationError``
(``fmus.errors``) is a failure while the simulation runs (an FMU returned
fmi2Error/fmi2Fatal/fmi2Discard, produced NaN/Inf, or a task raised); it carries the
component, the simulated time and the FMU's last logged messages.
"""
from __future__ import annotations

from fmus.errors import FmuConfigError, SimulationError


#: Bad wiring of a co-simulation: the FMU layer's configuration error (one class for both).
MasterConfigError = FmuConfigError


class EndSimulation(Exception):
    """Raised by a periodic task to end the run early and successfully (e.g. a job is done)."""


class FmuEnded(Exception):
    """Raised by an engine when an FMU ended the simulation itself (FMI 3.0 terminateSimulation):
    the run ends normally at base tick ``tick`` (the master records who ended it)."""

    def __init__(self, tick: int) -> None:
        super().__init__(f"an FMU ended the simulation (run ends at tick {tick})")
        self.tick = tick


class FmuTerminated(FmuEnded):
    """Raised by an engine when an FMI 2.0 FMU ended the simulation itself: fmi2DoStep returned
    fmi2Discard and fmi2GetBooleanStatus(fmi2Terminated) is true. The run ends normally at base tick
    ``tick`` (the communication point the step started from); ``instance`` reached
    ``last_successful_time`` (s, fmi2LastSuccessfulTime), where its last values are recorded."""

    def __init__(self, tick: int, instance: str, last_successful_time: float) -> None:
        super().__init__(tick)
        self.instance = instance
        self.last_successful_time = float(last_successful_time)


__all__ = ["EndSimulation", "FmuEnded", "FmuTerminated", "MasterConfigError", "SimulationError"]
