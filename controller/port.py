"""The cell's side of the controller contract: fieldbus process data in, ``CellController`` called, set-points out.

:class:`ControllerPort` is the one place that turns what the managing node observed
(``fieldbus.ObservedActuals``) into a :class:`controller.contract.ControllerInput`,
calls the controller's ``step`` and turns its :class:`~controller.contract.ControllerOutput`
into the ``fieldbus.Setpoints`` of the next PReqs. The one-process cell
(:class:`cosim.cell.link.FieldbusLink`) and the split cell's controller side use it, so
every controller - built-in, user class, FMU - is driven the same way.

Costs per cycle: the input is bound to the observed arrays (no copy); an output that is
the controller's own ``fieldbus.Setpoints`` alias (the built-in controller) goes out as is;
any other output is checked (finite, modes of operation known and carried by the bus)
and copied: a few µs.
"""
from __future__ import annotations

import math
import time
from dataclasses import fields

import numpy as np

from controller.contract import (MODE_CSP, MODES_OF_OPERATION, OUTPUT_INTEGER, OUTPUT_REAL, CellController,
                                 ControllerInfo, ControllerInput, ControllerOutput)
from controller.cycle_timer import CycleTimer, TimingSummary
from fieldbus import ObservedActuals, Setpoints

# fieldbus.Setpoints field that carries each output field (first name present wins)
_CARRIER_NAMES = {
    "controlword": ("controlword",),
    "modes_of_operation": ("modes_of_operation", "mode_of_operation"),
    "target_position": ("target_position", "position"),
    "target_velocity": ("target_velocity", "velocity"),
    "velocity_offset": ("velocity_offset",),
    "target_torque": ("target_torque", "torque"),
    "torque_offset": ("torque_offset",),
}
# fieldbus.ObservedActuals field that carries each input field
_OBSERVED_NAMES = {
    "statusword": ("statusword",), "position": ("position",), "velocity": ("velocity",), "torque": ("torque",),
    "error_code": ("error_code",), "fresh": ("fresh",), "node_fault": ("node_fault",),
    "modes_of_operation_display": ("modes_of_operation_display", "mode_of_operation_display", "mode_display"),
}


def bus_carriers() -> dict[str, str | None]:
    """Output field -> the ``fieldbus.Setpoints`` field carrying it (None: the bus carries none yet)."""
    have = {f.name for f in fields(Setpoints)}
    return {name: next((c for c in options if c in have), None) for name, options in _CARRIER_NAMES.items()}


COMMAND_LOG_GROUPS = (("controlword", "controlword", "-", "Integer"), ("mode", "modes_of_operation", "-", "Integer"),
                      ("target", "target_position", "rad", "Real"),
                      ("target_velocity", "target_velocity", "rad/s", "Real"),
                      ("velocity_offset", "velocity_offset", "rad/s", "Real"),
                      ("target_torque", "target_torque", "N.m", "Real"), ("tau_ff", "torque_offset", "N.m", "Real"),
                      ("statusword", "statusword", "-", "Integer"), ("q_obs", "position", "rad", "Real"),
                      ("qd_obs", "velocity", "rad/s", "Real"), ("tau_obs", "torque", "N.m", "Real"))
"""The per-joint column groups of :class:`CommandLog`: (column prefix, ControllerOutput /
ControllerInput field, unit, recorder kind). Names shared with the built-in controller's log
(``controller.LOG_COLUMNS``) mean the same: ``target`` the target position sent, ``tau_ff`` the
torque offset sent, ``q_obs`` the position actual the controller saw."""
COMMAND_LOG_SCALARS = (("t", "s", "Real"), ("cycle", "-", "Integer"), ("late", "-", "Integer"),
                       ("lost", "-", "Integer"), ("compute_us", "us", "Real"), ("compute_cpu_us", "us", "Real"))
COMMAND_LOG_BLOCK_ROWS = 2048
"""Rows a :class:`CommandLog` holds before it hands them to its sink (0.8 s at 400 µs)."""


def command_log_columns(n_joints: int = 6) -> tuple[list[str], list[str], dict[str, str]]:
    """(columns, recorder kinds, units) of a :class:`CommandLog` for ``n_joints`` drives."""
    columns, kinds, units = [], [], {}
    for name, unit, kind in COMMAND_LOG_SCALARS[:4]:
        columns.append(name)
        kinds.append(kind)
        units[name] = unit
    for prefix, _, unit, kind in COMMAND_LOG_GROUPS:
        for j in range(1, n_joints + 1):
            columns.append(f"{prefix}{j}")
            kinds.append(kind)
            units[f"{prefix}{j}"] = unit
    for name, unit, kind in COMMAND_LOG_SCALARS[4:]:
        columns.append(name)
        kinds.append(kind)
        units[name] = unit
    return columns, kinds, {k: v for k, v in units.items() if v != "-"}


class CommandLog:
    """Per-cycle record of a user's controller as the cell drove it: one row per ``step``.

    Columns (:func:`command_log_columns`): ``t`` (cycle time, s), ``cycle``, ``late`` and
    ``lost`` (the previous output came late / was lost: 1), per joint what went to the drive
    (``controlword``, ``mode`` = modes of operation, ``target`` position, ``target_velocity``,
    ``velocity_offset``, ``target_torque``, ``tau_ff`` = torque offset) and what the controller
    was given (``statusword``, ``q_obs``, ``qd_obs``, ``tau_obs``: position, velocity and torque
    actuals), then the controller's own compute time (``compute_us`` wall, ``compute_cpu_us``
    thread CPU). Rows are handed to ``sink`` (a recorder sink: ``open``, ``write``, ``flush``,
    ``close``) a block at a time; without a sink they stay in memory until :meth:`close`.
    """

    def __init__(self, port: "ControllerPort", sink=None, block_rows: int = COMMAND_LOG_BLOCK_ROWS) -> None:
        self.columns, self.kinds, self.units = command_log_columns(port.n)
        self.sink = sink
        self.rows = 0
        self.total_rows = 0
        self._held: list[np.ndarray] = []
        self._block = np.empty((max(int(block_rows), 16), len(self.columns)))
        self._head = np.zeros(4)
        self._tail = np.zeros(2)
        sp, inp = port.setpoints, port.inputs
        carriers = bus_carriers()
        parts: list[np.ndarray] = [self._head]
        for _, name, _, _ in COMMAND_LOG_GROUPS:
            carrier = carriers.get(name)
            if carrier is not None:
                parts.append(getattr(sp, carrier))
            elif hasattr(inp, name):
                parts.append(None)  # bound to the input arrays at each row (the port rebinds them)
            else:
                parts.append(np.zeros(port.n))
        parts.append(self._tail)
        self._parts = parts
        self._inputs = inp
        self._input_slots = [(k + 1, name) for k, (_, name, _, _) in enumerate(COMMAND_LOG_GROUPS)
                             if parts[k + 1] is None]
        if sink is not None:
            sink.open(self.columns, self.kinds)

    def add(self, t: float, cycle: int, late: bool, lost: bool, compute_ns: int, cpu_ns: int) -> None:
        """Append the row of the cycle just run (the set-points as they go on the bus)."""
        if self.rows == self._block.shape[0]:
            self._spill()
        head, tail, parts, inp = self._head, self._tail, self._parts, self._inputs
        head[0], head[1], head[2], head[3] = t, cycle, late, lost
        tail[0], tail[1] = compute_ns * 1e-3, cpu_ns * 1e-3
        for slot, name in self._input_slots:
            parts[slot] = getattr(inp, name)
        np.concatenate(parts, out=self._block[self.rows], casting="unsafe")
        self.rows += 1

    def _spill(self) -> None:
        if not self.rows:
            return
        block = self._block[:self.rows].copy() if self.sink is None else self._block[:self.rows]
        if self.sink is None:
            self._held.append(block)
        else:
            self.sink.write(block)
            self.sink.flush()
        self.total_rows += self.rows
        self.rows = 0

    def block(self) -> np.ndarray:
        """Every row held in memory (no sink) as one (rows, columns) array."""
        return np.concatenate([*self._held, self._block[:self.rows]]) if self._held or self.rows \
            else np.zeros((0, len(self.columns)))

    def close(self, sink=None) -> None:
        """Write what is left to the log's sink and close it; a log without one writes all its rows to
        ``sink`` now (given: opened, written, closed)."""
        if self.sink is None:
            if sink is None:
                return
            sink.open(self.columns, self.kinds)
            try:
                rows = self.block()
                if len(rows):
                    sink.write(rows)
            finally:
                sink.close()
            self.total_rows += self.rows
            self.rows = 0
            self._held = []
            return
        try:
            self._spill()
        finally:
            self.sink.close()
            self.sink = None


class ControllerFailure(RuntimeError):
    """The controller raised or returned an unusable output in a cycle (ends the run).

    Attributes: time_s (the cycle's time, s), cycle, reason (one line)."""

    def __init__(self, time_s: float, cycle: int, reason: str) -> None:
        super().__init__(reason)
        self.time_s = time_s
        self.cycle = cycle
        self.reason = reason


class ControllerPort:
    """Drive ``controller`` (a :class:`~controller.contract.CellController`) from the fieldbus.

    ``setpoints`` is what goes into the next PReqs (before the first cycle: controlword 0,
    the start pose, no offsets). :meth:`step` runs one controller cycle. Attributes
    ``stop_reason``, ``stopped_at_s`` mirror the controller's (None when it has none).
    """

    def __init__(self, controller: CellController, n_joints: int = 6, q_start: np.ndarray | None = None) -> None:
        self.controller = controller
        self.n = n_joints
        self.name = type(controller).__name__
        self.inputs = ControllerInput.zeros(n_joints)
        self._display = self.inputs.modes_of_operation_display
        self._bound: ObservedActuals | None = None
        self._observed_fields: dict[str, str | None] = {}
        own_out = getattr(controller, "output", None)
        own_sp = getattr(controller, "setpoints", None)
        # the built-in controller's output aliases its own Setpoints: hand those to the bus directly
        self._alias_out = own_out if isinstance(own_out, ControllerOutput) and isinstance(own_sp, Setpoints) else None
        self._alias_sp = own_sp if self._alias_out is not None else None
        if self._alias_sp is not None:
            self.setpoints = self._alias_sp
        self._carriers = bus_carriers()
        self._real_block: np.ndarray | None = None
        if self._alias_sp is None:
            # the real set-points as rows of one block: one finiteness check per cycle
            carried_real = [self._carriers[name] for name in OUTPUT_REAL if self._carriers[name] is not None]
            self._real_block = np.zeros((len(carried_real), n_joints))
            self.setpoints = Setpoints.zeros(n_joints)
            for row, field_name in enumerate(carried_real):
                setattr(self.setpoints, field_name, self._real_block[row])
            if q_start is not None:
                self.setpoints.position[:] = q_start
        self._sp_fields = [(name, getattr(self.setpoints, c)) for name, c in self._carriers.items() if c is not None]
        self._uncarried = [name for name, c in self._carriers.items() if c is None]
        carrier = self._carriers["modes_of_operation"]
        self._modes = getattr(self.setpoints, carrier) if carrier is not None else None
        self._modes_ok = self._modes.tolist() if self._modes is not None else None
        self._closed = False
        self.close_error: str | None = None
        # a user's controller is timed here (the built-in one times its own work)
        self.timer: CycleTimer | None = None if self._alias_out is not None else CycleTimer(100e-6)
        # the port's own cost per cycle, bounded for any length of run (CycleTimer folds long runs)
        self._overhead: CycleTimer | None = CycleTimer(1.0) if self.timer is not None else None
        self.log: CommandLog | None = None

    def start_log(self, sink=None) -> CommandLog | None:
        """Record every cycle of a user's controller in a :class:`CommandLog` (streamed to ``sink``, a
        recorder sink, or held in memory without one); the built-in controller keeps its own log
        (``Controller.log``): None then."""
        if self.timer is None:
            return None
        self.log = CommandLog(self, sink)
        return self.log

    # ------------------------------------------------------------------ lifecycle
    def setup(self, info: ControllerInfo) -> None:
        """``controller.setup(info)``; a failure is a :class:`ControllerFailure` at t = 0."""
        if self.timer is not None:
            self.timer = CycleTimer(info.compute_budget_s)
        try:
            self.controller.setup(info)
        except Exception as exc:  # noqa: BLE001 - a user's code: report, do not crash
            raise ControllerFailure(0.0, -1, f"{self.name}.setup() raised {type(exc).__name__}: {exc}") from exc

    def close(self) -> None:
        """``controller.close()`` once (errors are reported in the returned text, never raised)."""
        if self._closed:
            return
        self._closed = True
        try:
            self.controller.close()
        except Exception as exc:  # noqa: BLE001
            self.close_error = f"{self.name}.close() raised {type(exc).__name__}: {exc}"

    @property
    def stop_reason(self) -> str | None:
        return getattr(self.controller, "stop_reason", None)

    @property
    def stopped_at_s(self) -> float | None:
        return getattr(self.controller, "stopped_at_s", None)

    # ------------------------------------------------------------------ the cycle
    def _bind(self, observed: ObservedActuals) -> None:
        inp = self.inputs
        have = {f.name for f in fields(observed)} if hasattr(observed, "__dataclass_fields__") else set(dir(observed))
        for name, options in _OBSERVED_NAMES.items():
            source = next((c for c in options if c in have), None)
            if source is not None:
                setattr(inp, name, getattr(observed, source))
            elif name == "modes_of_operation_display":
                inp.modes_of_operation_display = self._display  # drives without 0x6061: the mode they run, CSP
        self._bound = observed

    def step(self, cycle: int, t: float, observed: ObservedActuals, late: bool = False,
             lost: bool = False) -> Setpoints:
        """One controller cycle with what the managing node ``observed`` at ``t`` (s): the
        set-points of the next PReqs. Raises :class:`ControllerFailure` when the controller
        raises or returns an unusable output."""
        entered = time.perf_counter_ns() if self.timer is not None else 0  # a user's controller: the port's cost
        if observed is not self._bound:
            self._bind(observed)
        inp = self.inputs
        inp.cycle = cycle
        inp.time_s = t
        inp.previous_output_late = late
        inp.previous_output_lost = lost
        timer = self.timer
        if timer is None:
            try:
                out = self.controller.step(inp)
            except Exception as exc:  # noqa: BLE001 - stop the run cleanly
                raise ControllerFailure(t, cycle, f"{self.name}.step() raised {type(exc).__name__}: {exc}") from exc
            if out is self._alias_out:
                return self._alias_sp
            return self._convert(out, cycle, t)
        started, cpu_started = time.perf_counter_ns(), time.thread_time_ns()
        try:
            out = self.controller.step(inp)
        except Exception as exc:  # noqa: BLE001 - a user's code: stop the run cleanly
            raise ControllerFailure(t, cycle, f"{self.name}.step() raised {type(exc).__name__}: {exc}") from exc
        own = time.perf_counter_ns() - started
        cpu = time.thread_time_ns() - cpu_started
        timer.record(own, cpu)
        sp = self._convert(out, cycle, t)
        if self.log is not None:
            self.log.add(t, cycle, late, lost, own, cpu)
        self._overhead.record(time.perf_counter_ns() - entered - own)
        return sp

    def overhead(self) -> dict[str, float] | None:
        """What the port itself cost per cycle of a user controller, µs (p50, p99, mean over the
        cycles run): binding the input, timing, checking and copying the output - the time of
        :meth:`step` minus the controller's own ``step``. None for the built-in controller."""
        if self._overhead is None or not self._overhead.count:
            return None
        s = self._overhead.summary()
        return {"p50_us": s.p50_us, "p99_us": s.p99_us, "mean_us": s.mean_us, "cycles": s.cycles}

    def timing(self) -> TimingSummary | None:
        """Compute time of a user controller's ``step`` per cycle (None for the built-in controller,
        which times its own work: ``Controller.timing()``)."""
        return self.timer.summary() if self.timer is not None else None

    def _convert(self, out: ControllerOutput, cycle: int, t: float) -> Setpoints:
        """Copy ``out`` into :attr:`setpoints` and check it (finite, modes known and carried);
        anything unusable is diagnosed field by field (:meth:`_diagnose`)."""
        try:
            for name, target in self._sp_fields:
                target[:] = getattr(out, name)
        except (AttributeError, TypeError, ValueError):
            self._diagnose(out, cycle, t)
            raise  # pragma: no cover - _diagnose raised already
        total = math.fsum(self._real_block.ravel().tolist()) if self._real_block is not None else 0.0
        if not math.isfinite(total):
            self._diagnose(out, cycle, t)
        modes = self._modes.tolist() if self._modes is not None else None
        if modes != self._modes_ok:
            self._diagnose(out, cycle, t)
            self._modes_ok = modes
        if self._uncarried:
            self._diagnose(out, cycle, t)
        return self.setpoints

    def _diagnose(self, out: ControllerOutput, cycle: int, t: float) -> None:
        """Raise a :class:`ControllerFailure` naming the first unusable field of ``out`` (return if none)."""
        n = self.n
        for name in OUTPUT_REAL + OUTPUT_INTEGER:
            try:
                value = getattr(out, name)
            except AttributeError:
                raise ControllerFailure(t, cycle, f"{self.name}.step() returned {type(out).__name__} without "
                                                  f"{name!r}: expected a controller.ControllerOutput") from None
            values = value.tolist() if isinstance(value, np.ndarray) else list(np.ravel(value))
            if len(values) != n:
                raise ControllerFailure(t, cycle, f"{self.name}.step(): {name} has {len(values)} values, "
                                                  f"expected {n} (one per joint)")
            try:
                total = math.fsum(values)
            except (TypeError, ValueError, OverflowError):
                total = math.nan
            if not math.isfinite(total):
                raise ControllerFailure(t, cycle, f"{self.name}.step(): {name} = {values} at t = {t:.6g} s "
                                                  f"(cycle {cycle}): expected finite numbers")
        modes = np.asarray(out.modes_of_operation).tolist()
        for joint, mode in enumerate(modes, start=1):
            if mode not in MODES_OF_OPERATION:
                raise ControllerFailure(t, cycle, f"{self.name}.step(): modes_of_operation of joint {joint} = "
                                                  f"{mode!r}: expected one of {MODES_OF_OPERATION} (8 CSP, 9 CSV, "
                                                  f"10 CST)")
        for name in self._uncarried:
            values = np.asarray(getattr(out, name))
            unused = (values == MODE_CSP) if name == "modes_of_operation" else (values == 0)
            if not unused.all():
                raise ControllerFailure(t, cycle, f"{self.name}.step(): {name} = {values.tolist()}, but this "
                                                  f"fieldbus/drive build carries no {name} yet: expected "
                                                  f"{'8 (CSP)' if name == 'modes_of_operation' else 0}")
