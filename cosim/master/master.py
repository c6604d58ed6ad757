"""The fixed-step, multi-rate co-simulation master.

One simulated clock ticks at the base step ``h0``; tick ``n`` is time
``t_n = start_time + n * h0``. Each FMU steps every ``m`` ticks (its step is ``m * h0``),
each periodic task runs every ``p`` ticks at phase ``phi`` (ticks ``n = phi mod p``), each
recorder samples every ``r`` ticks. At a tick ``n``, in this order (docs/explanation/architecture.md, "The co-simulation master"):

1. FMU outputs: every FMU whose communication point is ``t_n`` has published its
   outputs at ``t_n`` on the buses (an FMU between communication points shows the
   values of its last one).
2. Tasks due at ``n`` run, lowest ``priority`` first (then in the order added); they
   read outputs at ``t_n`` and write master variables.
3. Recorders due at ``n`` sample (outputs at ``t_n``, master variables as the tasks left
   them, connected inputs as they will be applied from ``t_n``).
4. Every FMU due at ``n``, in stepping order: its connected inputs are copied from
   their sources, set, and it steps ``t_n -> t_n + m h0``. Jacobi (default): all due
   FMUs see the sources as at ``t_n``; outputs are published when the clock reaches an
   FMU's next communication point. Gauss-Seidel: an FMU publishes right after its step,
   so FMUs later in the order see its outputs at ``t_n + m h0``.

Usage::

    master = Master(base_step=1e-4)
    master.add_fmu("plant", "plant.fmu", start_values={"q0[2]": 0.1})
    master.add_variable("ctrl.u", "Real")
    master.connect("ctrl.u", "plant.tau[1]")
    master.add_task(controller, period=4e-4, name="controller")
    master.add_recorder(["plant.q[1]", "ctrl.u"], period=1e-3, sink=MemorySink())
    master.initialize(stop_time=1.0)
    q = master.view(["plant.q[1]"]); u = master.view(["ctrl.u"], writable=True)
    master.run(1.0)
    master.close()
"""
from __future__ import annotations

import math
import time as _time
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from cosim.master.engines import (BUS_DTYPE, BUS_ORDER, Exchange, NativeEngine, Plan, PythonEngine, SlavePlan,
                                  gather, make_engine, publish, set_inputs)
from cosim.master.access import SignalAccess, SignalReader
from cosim.master.errors import EndSimulation, FmuEnded, FmuTerminated, MasterConfigError, SimulationError
from cosim.master.recorder import Recorder, Sink
from cosim.master.variables import (MasterTypeUnsupported, bus_type, check_connection_ends, check_declared_range,
                                    check_start_value,
                                    is_pattern, matches_pattern, parse_connection)
from fmus.fmu import Fmu, load_model_description, status_name

COUPLINGS = ("jacobi", "gauss_seidel")
ENGINES = ("auto", "native", "python")
_BUS_FMI_TYPES = ("Real", "Integer", "Enumeration", "Boolean", "Float32", "Float64", "Int8", "UInt8", "Int16",
                  "UInt16", "Int32", "UInt32", "Int64", "UInt64", "Clock", "Binary")
_RECORDABLE_CAUSALITIES = ("output", "local", "parameter", "calculatedParameter", "input", "independent")


def ticks_of(value: float, base_step: float, what: str, allow_zero: bool = False) -> int:
    """``value`` (s) as an integer number of base steps; MasterConfigError when it is not one.

    The tolerance is 1e-9 relative, so 4e-4 with base 1e-4 is exactly 4 ticks.
    """
    if isinstance(value, bool) or not isinstance(value, (int, float)) or not math.isfinite(value):
        raise MasterConfigError(f"{what}: expected a number of seconds, got {value!r}")
    ratio = value / base_step
    if not math.isfinite(ratio):
        raise MasterConfigError(f"{what}: expected a whole number of base steps of {base_step!r} s, got {value!r} s "
                                f"(the ratio overflows)")
    n = round(ratio)
    if (n < 1 and not allow_zero) or n < 0 or abs(ratio - n) > 1e-9 * max(1.0, abs(ratio)):
        smallest = "a non-negative" if allow_zero else "a positive"
        raise MasterConfigError(f"{what}: expected {smallest} integer multiple of the base step {base_step!r} s, "
                                f"got {value!r} s ({ratio:.6g} base steps)")
    return int(n)


@dataclass
class Task:
    """A periodic Python callable ``fn(t)`` (t in s), run every ``period_ticks`` at ``phase_ticks``."""

    fn: Callable[[float], None]
    name: str
    period_ticks: int
    phase_ticks: int
    priority: int
    setup: Callable[["Master"], None] | None = None
    timed: bool = False
    durations_s: list[float] = field(default_factory=list)
    calls: int = 0


@dataclass
class _MasterVariable:
    name: str
    type: str
    start: object


@dataclass
class _Event:
    """A task or recorder in the event schedule."""

    next_tick: int
    period: int
    order: tuple[int, int, int]  # (0 task / 1 recorder, priority, sequence)
    item: Task | Recorder


class Master(SignalAccess):
    """Fixed-step multi-rate co-simulation master (see module docstring for the scheme).

    Args:
        base_step: base macro step h0 in s; every step/period is an integer multiple of it.
        start_time: simulated time of tick 0, s.
        coupling: ``"jacobi"`` (default) or ``"gauss_seidel"``.
        engine: ``"auto"`` (compiled kernel when a C compiler is available, else Python),
            ``"native"`` or ``"python"``.
        profile: measure the wall time spent inside each FMU's fmi2DoStep
            (``fmu_step_seconds``), to separate FMU compute from master overhead.
    """

    def __init__(self, base_step: float, start_time: float = 0.0, coupling: str = "jacobi",
                 engine: str = "auto", profile: bool = False) -> None:
        if isinstance(base_step, bool) or not isinstance(base_step, (int, float)) or not base_step > 0 \
                or not math.isfinite(base_step):
            raise MasterConfigError(f"base_step: expected a positive number of seconds, got {base_step!r}")
        if coupling not in COUPLINGS:
            raise MasterConfigError(f"coupling: expected one of {COUPLINGS}, got {coupling!r}")
        if engine not in ENGINES:
            raise MasterConfigError(f"engine: expected one of {ENGINES}, got {engine!r}")
        self.base_step = float(base_step)
        self.start_time = float(start_time)
        self.coupling = coupling
        self.engine_choice = engine
        self.profile = bool(profile)
        self._fmus: dict[str, Fmu] = {}
        self._step_ticks: dict[str, int] = {}  # instance -> its communication step in base steps
        self._variables: dict[str, _MasterVariable] = {}
        self._connections: dict[str, str] = {}  # destination -> source
        self._exposed: list[str] = []
        self._tasks: list[Task] = []
        self._recorders: list[Recorder] = []
        self._order: list[str] | None = None
        self._initialized = False
        self._closed = False
        self._tick = 0
        self._events_done_tick = -1
        self.stop_time: float | None = None
        self.plan: Plan | None = None
        self.engine: NativeEngine | PythonEngine | None = None
        self._locations: dict[str, tuple[str, int]] = {}
        self._master_var_range: dict[str, tuple[int, int]] = {}
        self.ended_by: dict[str, object] | None = None

    # ------------------------------------------------------------------ building
    def _check_building(self) -> None:
        if self._initialized:
            raise MasterConfigError("the co-simulation is already initialized; add FMUs, variables, "
                                    "connections, tasks and recorders before initialize()")

    def _check_instance_name(self, name: str) -> None:
        if not isinstance(name, str) or not name or "." in name or name != name.strip():
            raise MasterConfigError(f"instance name {name!r}: expected a non-empty name without dots or spaces")

    def add_fmu(self, name: str, path: str | Path, step: float | None = None,
                start_values: dict[str, object] | None = None, debug_logging: bool = False,
                out_of_process: bool = False, step_timeout: float | None = None) -> Fmu:
        """Add an FMI 2.0 or 3.0 co-simulation FMU instance; return its :class:`fmus.fmu.Fmu`
        (instantiated by :meth:`initialize`).

        Args:
            name: instance name (unique, no dots).
            path: the .fmu file.
            step: its communication step in s (a multiple of the base step; default the base step).
            start_values: variable name -> value, type-checked against the modelDescription.
            debug_logging: ``loggingOn`` for fmi2Instantiate.
            out_of_process: run the FMU in a child process (cosim/master/proxy.py): a crash or a hang
                becomes a SimulationError naming it; costs a pipe round trip per step.
            step_timeout: with ``out_of_process``, the longest wall time (s) of one step before the FMU
                counts as hung (default proxy.DEFAULT_STEP_TIMEOUT_S).
        """
        self._check_building()
        self._check_instance_name(name)
        if name in self._fmus or any(v.split(".", 1)[0] == name for v in self._variables):
            raise MasterConfigError(f"instance name {name!r} is already used")
        step_ticks = 1 if step is None else ticks_of(step, self.base_step, f"step of FMU '{name}'")
        if out_of_process:
            from cosim.master.proxy import ProxyFmu

            component = ProxyFmu(path, name, start_values, debug_logging=debug_logging,
                                 step_timeout_s=step_timeout)
        elif step_timeout is not None:
            raise MasterConfigError(f"step_timeout of FMU '{name}': only an out-of-process FMU can be timed out "
                                    f"(out_of_process=True)")
        else:
            component = Fmu(path, name, start_values, debug_logging=debug_logging)
        for var_name, value in component.start_values.items():
            problem = check_start_value(component.variable(var_name), value) \
                or check_declared_range(component.variable(var_name), value)
            if problem:
                raise MasterConfigError(f"start value of '{name}.{var_name}': expected {problem}, got {value!r}")
        self._fmus[name] = component
        self._step_ticks[name] = step_ticks
        return component

    def add_variable(self, signal: str, type: str = "Real", start: object = 0) -> None:
        """Declare a master variable ``"owner.name"`` that tasks write and connections read.

        Variables declared one after another with the same owner and type are contiguous,
        so ``view([...], writable=True)`` returns one writable numpy slice for them.
        """
        self._check_building()
        owner, _ = self._split(signal)
        if owner in self._fmus:
            raise MasterConfigError(f"master variable {signal!r}: owner {owner!r} is an FMU instance name")
        if signal in self._variables:
            raise MasterConfigError(f"master variable {signal!r} is declared twice")
        if type not in BUS_ORDER:
            raise MasterConfigError(f"master variable {signal!r}: type expected one of {BUS_ORDER}, got {type!r}")
        ok = {"Real": isinstance(start, (int, float)) and not isinstance(start, bool),
              "Integer": isinstance(start, int) and not isinstance(start, bool),
              "Boolean": isinstance(start, (bool, int))}[type]
        if not ok:
            raise MasterConfigError(f"master variable {signal!r}: start expected a {type} value, got {start!r}")
        self._variables[signal] = _MasterVariable(signal, type, start)

    def add_variables(self, owner: str, names: Iterable[str], type: str = "Real", start: object = 0) -> list[str]:
        """Declare ``owner.<name>`` for each name (contiguous); return the signal names."""
        signals = [f"{owner}.{n}" for n in names]
        for s in signals:
            self.add_variable(s, type, start)
        return signals

    def connect(self, source: str, destination: str | None = None) -> None:
        """Connect ``source`` (FMU output or master variable) to ``destination`` (FMU input).

        Also accepts one string ``"a.x -> b.y"``. An input has at most one source.
        """
        self._check_building()
        if destination is None:
            try:
                spec = parse_connection(source)
            except ValueError as exc:
                raise MasterConfigError(str(exc)) from None
            source, destination = spec.source, spec.destination
        text = f"{source} -> {destination}"
        dst_inst, dst_var = self._split(destination)
        if dst_inst not in self._fmus:
            raise MasterConfigError(f"connection {text!r}: destination instance {dst_inst!r} is not an FMU "
                                    f"(known: {sorted(self._fmus)})")
        dst = self._fmus[dst_inst].variable(dst_var)
        if source in self._variables:
            problem = check_connection_ends(None, dst, self._variables[source].type)
        else:
            src_inst, src_var = self._split(source)
            if src_inst not in self._fmus:
                raise MasterConfigError(f"connection {text!r}: source {source!r} is neither an FMU output nor "
                                        f"a declared master variable")
            problem = check_connection_ends(self._fmus[src_inst].variable(src_var), dst)
        if problem:
            raise MasterConfigError(f"connection {text!r}: expected {problem}")
        if destination in self._connections:
            raise MasterConfigError(f"connection {text!r}: input {destination!r} is already connected to "
                                    f"{self._connections[destination]!r} (an input has one source)")
        self._connections[destination] = source

    def expose(self, signals: Iterable[str]) -> None:
        """Make FMU variables that are not outputs (locals, parameters, unconnected inputs)
        readable by tasks: they are read at every communication point of their FMU."""
        self._check_building()
        for s in signals:
            self._resolve_fmu_variable(s, "expose")
            if s not in self._exposed:
                self._exposed.append(s)

    def set_order(self, instances: Sequence[str]) -> None:
        """Stepping order of the FMUs (matters for Gauss-Seidel); default: the order added."""
        self._check_building()
        if sorted(instances) != sorted(self._fmus) or len(set(instances)) != len(instances):
            raise MasterConfigError(f"order: expected each FMU instance exactly once ({sorted(self._fmus)}), "
                                    f"got {list(instances)}")
        self._order = list(instances)

    def add_task(self, fn: Callable[[float], None], period: float, phase: float = 0.0, priority: int = 0,
                 name: str | None = None, setup: Callable[["Master"], None] | None = None,
                 timed: bool = False) -> Task:
        """Run ``fn(t)`` every ``period`` s at ``phase`` s (both multiples of the base step).

        At a tick it runs after FMU outputs at t are published and before FMUs step from t;
        among tasks due at the same tick, lower ``priority`` runs first. ``setup(master)`` is
        called at the end of ``initialize`` (get views there). ``timed=True`` keeps the wall
        time of every call in ``Task.durations_s``. Raise ``EndSimulation`` to end the run.
        """
        self._check_building()
        label = name or getattr(fn, "__name__", "task")
        period_ticks = ticks_of(period, self.base_step, f"period of task '{label}'")
        phase_ticks = ticks_of(phase, self.base_step, f"phase of task '{label}'", allow_zero=True)
        if phase_ticks >= period_ticks:
            raise MasterConfigError(f"phase of task '{label}': expected less than its period {period!r} s, "
                                    f"got {phase!r} s")
        task = Task(fn, label, period_ticks, phase_ticks, int(priority), setup, timed)
        self._tasks.append(task)
        return task

    def add_recorder(self, signals: Sequence[str], period: float, sink: Sink, name: str = "recorder",
                     block_rows: int = 1024, flush_interval_s: float = 1.0) -> Recorder:
        """Sample ``signals`` every ``period`` s (from t = start_time) into ``sink``.

        Signals are FMU variables (outputs, inputs, locals, parameters; glob patterns such
        as ``"drive1.*"`` expand to that FMU's outputs) or master variables.
        """
        self._check_building()
        period_ticks = ticks_of(period, self.base_step, f"period of recorder '{name}'")
        expanded = self.expand_signals(signals)
        for s in expanded:
            if s not in self._variables:
                var = self._resolve_fmu_variable(s, f"recorder '{name}'")
                if var.causality not in _RECORDABLE_CAUSALITIES:
                    raise MasterConfigError(f"recorder '{name}': {s!r} has causality {var.causality}, "
                                            f"expected one of {_RECORDABLE_CAUSALITIES}")
        recorder = Recorder(name, expanded, period_ticks, sink, block_rows, flush_interval_s)
        self._recorders.append(recorder)
        return recorder

    def expand_signals(self, signals: Sequence[str]) -> list[str]:
        """Expand wildcards (``*``, ``?``; brackets literal) against FMU outputs (not String) and master variables."""
        out: list[str] = []
        for s in signals:
            if is_pattern(s):
                matches = [f"{n}.{v.name}" for n, c in self._fmus.items() for v in c.bus_variables
                           if v.causality == "output" and v.type in _BUS_FMI_TYPES
                           and matches_pattern(f"{n}.{v.name}", s)]
                matches += [v for v in self._variables if matches_pattern(v, s)]
                if not matches:
                    raise MasterConfigError(f"signal pattern {s!r} matches no FMU output or master variable")
                out.extend(m for m in matches if m not in out)
            elif s not in out:
                out.append(s)
        return out

    def unit(self, signal: str) -> str:
        """The unit an FMU declares for ``signal`` (its ``unit``, else its declared type's),
        ``""`` for master variables and unitless FMU variables."""
        inst, var = self._split(signal)
        if inst not in self._fmus:
            return ""
        variable = self._fmus[inst].variable(var)
        unit = getattr(variable, "unit", None)
        declared = getattr(variable, "declaredType", None)
        return unit or (getattr(declared, "unit", None) if declared is not None else None) or ""

    def _resolve_fmu_variable(self, signal: str, who: str):
        inst, var = self._split(signal)
        if inst not in self._fmus:
            raise MasterConfigError(f"{who}: {signal!r} is neither a variable of an FMU instance "
                                    f"({sorted(self._fmus)}) nor a master variable")
        variable = self._fmus[inst].variable(var)
        try:
            bus_type(variable.type)
        except MasterTypeUnsupported as exc:
            raise MasterConfigError(f"{who}: {signal!r}: {exc}") from None
        return variable

    # ------------------------------------------------------------------ layout
    def _build_plan(self) -> Plan:
        sizes = {t: 0 for t in BUS_ORDER}
        locations: dict[str, tuple[str, int]] = {}

        def allocate(signal: str, t: str) -> int:
            index = sizes[t]
            sizes[t] += 1
            locations[signal] = (t, index)
            return index

        for name, var in self._variables.items():
            allocate(name, var.type)
        order = self._order or list(self._fmus)
        connected = set(self._connections)
        slaves: list[SlavePlan] = []
        for inst in order:
            comp = self._fmus[inst]
            published: dict[str, Exchange] = {}
            n_check = 0
            extra = [s.split(".", 1)[1] for s in self._exposed + [x for r in self._recorders for x in r.signals]
                     if s.split(".", 1)[0] == inst and s not in connected and s not in self._variables]
            for t in BUS_ORDER:
                outputs = [v for v in comp.bus_variables
                           if v.causality == "output" and v.type in _BUS_FMI_TYPES and bus_type(v.type) == t]
                probes = []
                for var_name in extra:
                    v = comp.variables[var_name]
                    if bus_type(v.type) == t and v.causality != "output" and v not in probes:
                        probes.append(v)
                chosen = outputs + probes
                if not chosen:
                    continue
                offset = sizes[t]
                for v in chosen:
                    allocate(f"{inst}.{v.name}", t)
                published[t] = Exchange(np.array([v.valueReference for v in chosen], dtype=np.uint32), offset,
                                        [v.name for v in chosen])
                if t == "Real":
                    n_check = len(outputs)
            slaves.append(SlavePlan(comp, self._step_ticks[inst], {}, published, n_check))
        for slave in slaves:
            inst = slave.component.name
            for t in BUS_ORDER:
                dests = [d for d in self._connections if d.split(".", 1)[0] == inst
                         and bus_type(slave.component.variables[d.split(".", 1)[1]].type) == t]
                if not dests:
                    continue
                offset = sizes[t]
                for d in dests:
                    allocate(d, t)
                variables = [slave.component.variables[d.split(".", 1)[1]] for d in dests]
                slave.inputs[t] = Exchange(np.array([v.valueReference for v in variables], dtype=np.uint32),
                                           offset, [v.name for v in variables])
                slave.gather_dst[t] = np.array([locations[d][1] for d in dests], dtype=np.int64)
                slave.gather_src[t] = np.array([locations[self._connections[d]][1] for d in dests],
                                               dtype=np.int64)
        buses = {t: np.zeros(max(sizes[t], 1), dtype=BUS_DTYPE[t]) for t in BUS_ORDER}
        for name, var in self._variables.items():
            buses[var.type][locations[name][1]] = var.start
        self._locations = locations
        return Plan(slaves, buses, self.start_time, self.base_step, self.coupling == "gauss_seidel")

    # ------------------------------------------------------------------ running
    def initialize(self, stop_time: float | None = None) -> None:
        """Instantiate and initialize every FMU, propagate initial values, publish outputs at t0.

        ``stop_time`` (s) is passed to fmi2SetupExperiment. Raises SimulationError when an
        FMU fails to initialize or starts with NaN/Inf outputs.
        """
        self._check_building()
        if not self._fmus:
            raise MasterConfigError("no FMU added: a co-simulation needs at least one FMU")
        if stop_time is not None:
            ticks_of(stop_time - self.start_time, self.base_step, "stop_time - start_time")
        self.stop_time = stop_time
        self.plan = self._build_plan()
        self._initialized = True
        t0 = self.start_time
        try:
            for slave in self.plan.slaves:
                comp = slave.component
                comp.instantiate(self.plan.stop_at.ctypes.data)
                comp.enter_initialization(t0, stop_time)
            if self._connections:
                for _ in range(len(self.plan.slaves)):  # propagate algebraic chains of initial values
                    for slave in self.plan.slaves:
                        publish(self.plan, slave, 0, check=False)
                    for slave in self.plan.slaves:
                        gather(self.plan, slave)
                        set_inputs(self.plan, slave, 0)
            for slave in self.plan.slaves:
                slave.component.exit_initialization(t0)
            for slave in self.plan.slaves:
                publish(self.plan, slave, 0)
        except BaseException:
            self.close()
            raise
        self.engine = make_engine(self.plan, self.engine_choice, self.profile)
        for recorder in self._recorders:
            locs = [self._locations[s] for s in recorder.signals]
            recorder.bind(self.plan.buses, locs, any(s in self._connections for s in recorder.signals))
        for task in self._tasks:
            if task.setup is not None:
                task.setup(self)

    @property
    def tick(self) -> int:
        """Current base tick n."""
        return self._tick

    @property
    def time(self) -> float:
        """Current simulated time t_n in s."""
        return self.start_time + self._tick * self.base_step

    def _schedule(self) -> list[_Event]:
        events = []
        for seq, task in enumerate(self._tasks):
            first = task.phase_ticks + task.period_ticks * max(0, -(-(self._tick - task.phase_ticks) // task.period_ticks))
            events.append(_Event(first, task.period_ticks, (0, task.priority, seq), task))
        for seq, rec in enumerate(self._recorders):
            first = rec.period_ticks * (-(-self._tick // rec.period_ticks))
            events.append(_Event(first, rec.period_ticks, (1, 0, seq), rec))
        events.sort(key=lambda e: e.order)
        return events

    def flush_recorders(self) -> None:
        """Hand every recorder's buffered rows to its sink and have the sink write them now
        (``sink.sync()`` where it has one, else its ``flush()``): what is on disk then holds every
        sample taken so far."""
        for recorder in self._recorders:
            recorder.flush()
            sync = getattr(recorder.sink, "sync", None)
            if sync is not None:
                sync()

    def run(self, until: float | None = None) -> float:
        """Advance the simulation to time ``until`` (s; default the stop_time given to initialize).

        Runs tasks and recorders due at ``until`` too (FMUs do not step past it); may be
        called again to continue. Returns the reached time. A task raising EndSimulation
        ends the run early (returns the time it stopped at). SimulationError propagates
        after recorders are flushed.
        """
        if not self._initialized or self._closed:
            raise MasterConfigError("run(): call initialize() first (and not after close())")
        if until is None:
            if self.stop_time is None:
                raise MasterConfigError("run(): give 'until' or a stop_time to initialize()")
            until = self.stop_time
        n_end = ticks_of(until - self.start_time, self.base_step, "run(until)", allow_zero=True)
        if self.ended_by is not None:  # an FMU ended the simulation: nothing more to run
            return self.time
        if n_end < self._tick:
            raise MasterConfigError(f"run(until={until!r}): expected a time not before the current time {self.time!r}")
        events = self._schedule()
        advance = self.engine.advance
        try:
            n = self._tick
            while True:
                if n != self._events_done_tick:
                    self._events_done_tick = n
                    target = self._run_events(n, events, n_end)  # and the next event tick
                else:  # resumed run: the events of tick n already ran
                    for e in events:
                        if e.next_tick == n:
                            e.next_tick += e.period
                    target = n_end
                    for e in events:  # the next event tick (a loop: cheaper than min() over a generator)
                        if e.next_tick < target:
                            target = e.next_tick
                if n >= n_end:
                    break
                try:
                    advance(n, target)
                except FmuTerminated as ended:
                    self._end_by_fmi2(ended)
                    break
                except FmuEnded as ended:
                    n = self._tick = ended.tick
                    self._record_end(n)
                    self._events_done_tick = n
                    self._run_events(n, events)
                    self._final_samples(n, events)
                    break
                n = target
                self._tick = n
        except EndSimulation:
            pass
        except SimulationError:
            raise
        finally:
            for recorder in self._recorders:
                recorder.flush()
        return self.time

    def _final_samples(self, n: int, events: list[_Event]) -> None:
        """Recorders that did not sample at the end tick ``n`` (not a multiple of their period) sample now."""
        late = [e.item for e in events if isinstance(e.item, Recorder) and e.next_tick - e.period != n]
        if late:
            for slave in self.plan.slaves:
                if n % slave.step_ticks == 0:
                    gather(self.plan, slave)
            for recorder in late:
                recorder.sample(self.start_time + n * self.base_step)

    def _end_by_fmi2(self, ended: FmuTerminated) -> None:
        """An FMI 2.0 FMU ended the simulation in the step from tick ``ended.tick``: the run ends at that
        communication point; the FMU's outputs at its last successful time are published and every
        recorder samples them once more at that time (the other FMUs hold their values there)."""
        n = self._tick = ended.tick
        self._events_done_tick = n
        t_n = self.start_time + n * self.base_step
        slave = next(s for s in self.plan.slaves if s.component.name == ended.instance)
        publish(self.plan, slave, n, check=False)
        self.ended_by = {"instance": ended.instance, "time": ended.last_successful_time, "status": "fmi2Discard",
                         "last_successful_time": ended.last_successful_time}
        slave.component.messages.append(f"[master] {ended.instance} ended the simulation (fmi2Discard, "
                                        f"fmi2Terminated) at t = {ended.last_successful_time:.9g} s")
        if ended.last_successful_time > t_n + 1e-12 * max(1.0, abs(t_n)):
            for other in self.plan.slaves:
                gather(self.plan, other)
            for recorder in self._recorders:
                recorder.sample(ended.last_successful_time)

    def _record_end(self, tick: int) -> None:
        t = self.start_time + tick * self.base_step
        for comp in self._fmus.values():
            if comp.binding is not None and comp.binding.terminated:
                status = comp.binding.ctx.end_status
                self.ended_by = {"instance": comp.name, "time": t, "status": status_name(status, "fmi3"),
                                 "last_successful_time": comp.binding.ctx.last_successful_time}
                comp.messages.append(f"[master] {comp.name} ended the simulation (terminateSimulation, "
                                     f"{status_name(status, 'fmi3')}) at t = {t:.9g} s")
                return
        self.ended_by = {"instance": None, "time": t, "status": None, "last_successful_time": t}

    def _run_events(self, n: int, events: list[_Event], horizon: int = 0) -> int:
        """Run the tasks and recorders due at tick ``n``; returns the next event tick, at most
        ``horizon``."""
        t = self.start_time + n * self.base_step
        gathered = False
        ending: EndSimulation | None = None
        upcoming = horizon
        for e in events:
            if e.next_tick != n:
                if e.next_tick < upcoming:
                    upcoming = e.next_tick
                continue
            e.next_tick += e.period
            if e.next_tick < upcoming:
                upcoming = e.next_tick
            item = e.item
            if isinstance(item, Task):
                if ending is not None:
                    continue
                item.calls += 1
                w0 = _time.perf_counter() if item.timed else 0.0
                try:
                    item.fn(t)
                except EndSimulation as exc:
                    ending = exc  # recorders of this tick still sample
                except SimulationError:
                    raise
                except Exception as exc:
                    raise SimulationError(item.name, t, f"task raised {type(exc).__name__}: {exc}") from exc
                finally:
                    if item.timed:
                        item.durations_s.append(_time.perf_counter() - w0)
            else:
                if item.needs_gather and not gathered:
                    for slave in self.plan.slaves:
                        if n % slave.step_ticks == 0:
                            gather(self.plan, slave)
                    gathered = True
                item.sample(t)
        if ending is not None:
            raise ending
        return upcoming

    def close(self) -> None:
        """Flush and close recorders, terminate and free every FMU instance (idempotent)."""
        if self._closed:
            return
        self._closed = True
        for recorder in self._recorders:
            try:
                recorder.close()
            except Exception:  # pragma: no cover - keep closing the others
                pass
        for comp in self._fmus.values():
            comp.close(terminate=self._initialized)

    def __enter__(self) -> "Master":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------------ inspection
    @property
    def fmus(self) -> dict[str, Fmu]:
        """Instance name -> its :class:`fmus.fmu.Fmu` (model description, log messages)."""
        return dict(self._fmus)

    @property
    def fmu_step_seconds(self) -> dict[str, float] | None:
        """Instance name -> wall seconds spent inside its fmi2DoStep so far (None unless profile=True)."""
        if self.engine is None or self.engine.step_seconds is None:
            return None
        return {s.component.name: float(v) for s, v in zip(self.plan.slaves, self.engine.step_seconds)}

    @property
    def tasks(self) -> list[Task]:
        return list(self._tasks)

    @property
    def recorders(self) -> list[Recorder]:
        return list(self._recorders)

    @property
    def connections(self) -> dict[str, str]:
        """Destination -> source."""
        return dict(self._connections)


__all__ = ["Master", "SignalReader", "Task", "ticks_of", "load_model_description"]
