"""Errors raised by an FMU instance (:class:`fmus.fmu.Fmu`) and, above it, by the co-simulation master.

``FmuConfigError`` is something given to an FMU that it cannot take: a file that is not an
FMI 2.0/3.0 co-simulation FMU, an unknown variable name, a value of the wrong type; it is
a ``ValueError`` and its message names the FMU, the variable, what was given and what was
expected. The master raises it for bad wiring too (``cosim.master.MasterConfigError`` is
this class). ``SimulationError`` is a failure while an FMU runs (a call returned
fmi2Discard/fmi2Error/fmi2Fatal, an output became NaN/Inf, or, in the master, a task
raised); it carries the instance, the simulated time and the FMU's last logged messages.
"""
from __future__ import annotations

from collections.abc import Sequence


class FmuConfigError(ValueError):
    """Something an FMU cannot take (file, variable, value); the message names FMU, variable, given and expected."""


class SimulationError(RuntimeError):
    """The simulation failed at simulated time ``time`` (s) in ``component``.

    Attributes:
        component: instance name of the FMU (or, in the master, task name) that failed.
        time: simulated time in s of the communication point where it failed.
        reason: one-line description (status returned, variable that became NaN, ...).
        messages: the component's last logged messages, oldest first.
    """

    def __init__(self, component: str, time: float, reason: str, messages: Sequence[str] = (),
                 hint: str = "") -> None:
        self.component = component
        self.time = float(time)
        self.reason = reason
        self.messages = list(messages)
        text = f"{component} at t = {self.time:.9g} s: {reason}"
        if self.messages:
            text += "\n  FMU log:\n" + "\n".join(f"    {m}" for m in self.messages)
        elif hint:
            text += f" ({hint})"
        super().__init__(text)


__all__ = ["FmuConfigError", "SimulationError"]
