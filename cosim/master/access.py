"""Signal access of the co-simulation master: what a periodic task, a recorder or a caller
uses to read and write the buses (:meth:`SignalAccess.view`, :meth:`~SignalAccess.reader`,
:meth:`~SignalAccess.value`, :meth:`~SignalAccess.set_value`, :meth:`~SignalAccess.refresher`).

:class:`cosim.master.master.Master` has these methods; they live below its scheduler, so a task
the master runs reads and writes through this floor and never calls back into the run loop.
"""
from __future__ import annotations

from collections.abc import Callable, Sequence
from functools import partial

import numpy as np

from cosim.master.errors import MasterConfigError
from cosim.master.variables import split_signal


class SignalReader:
    """Reads a fixed list of signals of one bus type: ``read()`` returns their current values."""

    def __init__(self, bus: np.ndarray, indices: np.ndarray) -> None:
        self._bus = bus
        self._indices = indices
        self._out = np.zeros(len(indices), dtype=bus.dtype)
        #: refresh() puts the current values into the array :meth:`read` returns (for a caller that
        #: keeps that array). The method ``take`` with positional arguments: np.take adds two Python
        #: calls, keywords their parsing; mode "clip" writes straight into the output, where "raise"
        #: (the default) gathers into a temporary first (0.2 against 1.2 us for 18 values). The
        #: indices are the master's own bus locations, always in range: the values are the same.
        self.refresh: Callable[[], np.ndarray] = partial(bus.take, indices, None, self._out, "clip")

    def read(self) -> np.ndarray:
        """Current values (a reused array: copy it to keep it)."""
        self.refresh()
        return self._out


class SignalAccess:
    """The signal-access methods of :class:`cosim.master.master.Master` (a mixin: they use the
    master's plan, engine, tick, FMUs and variables)."""

    def _split(self, signal: str) -> tuple[str, str]:
        try:
            return split_signal(signal)
        except ValueError as exc:
            raise MasterConfigError(str(exc)) from None

    def refresher(self, instances: Sequence[str]) -> Callable[[], None]:
        """A function that, called by a task at tick ``n``, sets the connected inputs of the FMUs
        ``instances`` whose communication point is ``t_n`` as they are on the buses now, and reads
        their outputs again: for outputs that depend directly on the inputs at the same instant
        (FMI direct feedthrough; e.g. a drive's position actual latched at the bus cycle's start).
        The FMUs' steps from ``t_n`` set the inputs again as the tasks leave them. Call after
        :meth:`initialize`."""
        if self.plan is None or self.engine is None:
            raise MasterConfigError("refresher() needs an initialized master")
        order = [slave.component.name for slave in self.plan.slaves]
        missing = [name for name in instances if name not in order]
        if missing:
            raise MasterConfigError(f"refresher(): {missing} are not FMU instances (have {order})")
        refresh = self.engine.refresher([order.index(name) for name in instances])
        return lambda: refresh(self._tick)

    def _location(self, signal: str) -> tuple[str, int]:
        if not self._initialized:
            raise MasterConfigError("signal access needs initialize() first")
        if signal in self._locations:
            return self._locations[signal]
        inst, var = self._split(signal)
        if inst in self._fmus:
            self._fmus[inst].variable(var)  # raises for an unknown variable
            raise MasterConfigError(f"signal {signal!r} is not on the buses: it is not an output, a connected "
                                    f"input or a recorded variable; call expose([{signal!r}]) before initialize()")
        raise MasterConfigError(f"signal {signal!r}: unknown instance {inst!r} (FMUs {sorted(self._fmus)}, "
                                f"master variables {sorted(self._variables)})")

    def view(self, signals: Sequence[str], writable: bool = False) -> np.ndarray:
        """A live numpy view of contiguous signals of one bus type (no copy).

        FMU outputs of one instance are contiguous in modelDescription order; master
        variables in declaration order. ``writable=True`` only for master variables.
        """
        locs = [self._location(s) for s in signals]
        types = {t for t, _ in locs}
        if len(types) != 1:
            raise MasterConfigError(f"view({list(signals)}): expected signals of one type, got {sorted(types)}")
        indices = [i for _, i in locs]
        if indices != list(range(indices[0], indices[0] + len(indices))):
            raise MasterConfigError(f"view({list(signals)}): signals are not contiguous on the bus; "
                                    f"use reader() instead")
        if writable:
            bad = [s for s in signals if s not in self._variables]
            if bad:
                raise MasterConfigError(f"view(writable=True): {bad} are not master variables (tasks write "
                                        f"master variables, which connections carry to FMU inputs)")
        bus_t = types.pop()
        v = self.plan.buses[bus_t][indices[0]:indices[0] + len(indices)]
        if not writable:
            v = v.view()
            v.flags.writeable = False
        return v

    def reader(self, signals: Sequence[str]) -> SignalReader:
        """A reader of any signals of one bus type (gathers with one numpy call)."""
        locs = [self._location(s) for s in signals]
        types = {t for t, _ in locs}
        if len(types) != 1:
            raise MasterConfigError(f"reader({list(signals)}): expected signals of one type, got {sorted(types)}")
        bus_t = types.pop()
        return SignalReader(self.plan.buses[bus_t], np.array([i for _, i in locs], dtype=np.intp))

    def value(self, signal: str) -> float | int | bool:
        """Current value of one signal (convenience; use view/reader in periodic tasks)."""
        t, i = self._location(signal)
        v = self.plan.buses[t][i]
        return float(v) if t == "Real" else bool(v) if t == "Boolean" else int(v)

    def set_value(self, signal: str, value: float | int | bool) -> None:
        """Set a master variable (convenience; use view(writable=True) in periodic tasks)."""
        if signal not in self._variables:
            raise MasterConfigError(f"set_value({signal!r}): only master variables can be written")
        t, i = self._location(signal)
        self.plan.buses[t][i] = value
