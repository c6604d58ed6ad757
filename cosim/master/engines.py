"""Stepping engines: advance all FMUs over base ticks between two Python events.

``SlavePlan``/``Plan`` describe, once, what each FMU exchanges per step: value
reference arrays, bus offsets of its inputs and published variables, and the
connection copies (``bus[dst] = bus[src]``) done before it steps. Two engines execute a
plan with identical semantics (see the docstring of cosim/master/master.py):

* ``NativeEngine`` runs whole stretches of ticks in the compiled kernel (kernel.c):
  one ctypes call per stretch, no Python per FMU step.
* ``PythonEngine`` is the readable reference and the fallback when no C compiler is
  available: one ctypes call per FMI function, numpy copies for connections.
"""
from __future__ import annotations

import ctypes
import math
import time
from dataclasses import dataclass, field
from typing import Any
from functools import partial

import numpy as np

from cosim.master.errors import FmuEnded, FmuTerminated, SimulationError
from cosim.master.kernel import (FAIL_ENDED, FAIL_GET, FAIL_NONFINITE, FAIL_SET, FAIL_STEP, CFailure, CPlan, CRefreshSet, CSlave,
                                 load_kernel)
from native.calls import address_of, load_calls
from fmus.fmu import VALUE_DTYPE, VALUE_TYPES, Fmu, status_name

BUS_ORDER = VALUE_TYPES  # the value types an Fmu exchanges, one bus each
BUS_DTYPE = VALUE_DTYPE


def _write_inputs(comp: Any, gathers: Any, sets: Any, t: float) -> None:
    """Copy a slave's connected values into its input buffers and set its inputs (one FMI call per
    variable type); a status above fmi2Warning fails with the time ``t``."""
    for bus, dst, src in gathers:
        bus[dst] = bus[src]
    handle = comp.component
    for fn, vrs, count, address, bus_type in sets:
        status = fn(handle, vrs, count, address)
        if status > 1:
            comp.check(f"{comp.api}Set{bus_type}", t, status)


@dataclass
class Exchange:
    """A contiguous bus slice exchanged with one FMU via one fmi2Set/fmi2Get call."""

    value_references: np.ndarray  # uint32
    offset: int
    names: list[str]

    @property
    def size(self) -> int:
        return len(self.names)


@dataclass
class SlavePlan:
    """What one FMU exchanges at each of its steps (bus type -> Exchange / copies)."""

    component: Fmu
    step_ticks: int
    inputs: dict[str, Exchange]
    published: dict[str, Exchange]
    n_check: int  # the first n_check published Reals are outputs checked for NaN/Inf
    gather_dst: dict[str, np.ndarray] = field(default_factory=dict)  # int64 bus indices
    gather_src: dict[str, np.ndarray] = field(default_factory=dict)


@dataclass
class Plan:
    """All slaves in stepping order plus the buses (one numpy array per bus type)."""

    slaves: list[SlavePlan]
    buses: dict[str, np.ndarray]
    start_time: float
    base_step: float
    gauss_seidel: bool
    #: End time (s) of the run written by an FMI 3.0 FMU that ended the simulation itself (+inf: none).
    stop_at: np.ndarray = field(default_factory=lambda: np.array([np.inf]))

    def ends_after(self, tick: int) -> bool:
        """True when an FMU ended the simulation and the run stops after base tick ``tick`` (same test as the kernel)."""
        return self.start_time + (float(tick) + 1.5) * self.base_step > self.stop_at[0]

    def time(self, tick: int) -> float:
        """Simulated time in s of base tick ``tick`` (same formula as the kernel)."""
        return self.start_time + float(tick) * self.base_step

    def step_size(self, tick: int, slave: SlavePlan) -> float:
        """Communication step in s of ``slave`` starting at ``tick`` (same formula as the kernel)."""
        return (self.start_time + float(tick + slave.step_ticks) * self.base_step) - self.time(tick)


def nonfinite_error(plan: Plan, slave: SlavePlan, tick: int, index: int) -> SimulationError:
    """SimulationError for published Real ``index`` of ``slave`` being NaN/Inf at ``tick``."""
    ex = slave.published["Real"]
    value = plan.buses["Real"][ex.offset + index]
    return slave.component.error(plan.time(tick),
                                 f"output '{ex.names[index]}' is {float(value)!r} (NaN/Inf outputs stop the run)")


def gather(plan: Plan, slave: SlavePlan) -> None:
    """Copy the slave's connected inputs from their sources on the buses."""
    for bus_type, dst in slave.gather_dst.items():
        bus = plan.buses[bus_type]
        bus[dst] = bus[slave.gather_src[bus_type]]


def set_inputs(plan: Plan, slave: SlavePlan, tick: int) -> None:
    """fmi2Set* the slave's input slices from the buses."""
    comp = slave.component
    for bus_type, ex in slave.inputs.items():
        address = plan.buses[bus_type].ctypes.data + ex.offset * plan.buses[bus_type].itemsize
        status = comp.set_fn[bus_type](comp.component, ex.value_references.ctypes.data, ex.size, address)
        comp.check(f"{comp.api}Set{bus_type}", plan.time(tick), status)


def publish(plan: Plan, slave: SlavePlan, tick: int, check: bool = True) -> None:
    """fmi2Get* the slave's published variables into the buses; check Real outputs are finite
    (``check=False`` during initialization mode, where outputs may not be computed yet)."""
    comp = slave.component
    for bus_type, ex in slave.published.items():
        bus = plan.buses[bus_type]
        status = comp.get_fn[bus_type](comp.component, ex.value_references.ctypes.data, ex.size,
                                       bus.ctypes.data + ex.offset * bus.itemsize)
        if status > 1:
            comp.check(f"{comp.api}Get{bus_type}", plan.time(tick), status)
    if check and slave.n_check:
        ex = slave.published["Real"]
        values = plan.buses["Real"][ex.offset:ex.offset + slave.n_check]
        if not math.isfinite(values.dot(values)):  # NaN or Inf anywhere (or |x| > 1e154: checked below)
            bad = np.flatnonzero(~np.isfinite(values))
            if len(bad):
                raise nonfinite_error(plan, slave, tick, int(bad[0]))


class PythonEngine:
    """Reference engine: the kernel's loop written in Python (one ctypes call per FMI function).

    Each slave's calls are prepared once as (function, component, value references,
    count, bus address) tuples; a status worse than fmi2Warning raises SimulationError.
    """

    name = "python"

    def __init__(self, plan: Plan, profile: bool = False) -> None:
        self.plan = plan
        self._prepared = [self._prepare(slave) for slave in plan.slaves]
        self.step_seconds = np.zeros(len(plan.slaves)) if profile else None

    def _prepare(self, slave: SlavePlan):
        comp = slave.component
        buses = self.plan.buses
        gathers = [(buses[t], dst, slave.gather_src[t]) for t, dst in slave.gather_dst.items()]
        sets = [(comp.set_fn[t], ex.value_references.ctypes.data, ex.size,
                 buses[t].ctypes.data + ex.offset * buses[t].itemsize, t) for t, ex in slave.inputs.items()]
        gets = [(comp.get_fn[t], ex.value_references.ctypes.data, ex.size,
                 buses[t].ctypes.data + ex.offset * buses[t].itemsize, t) for t, ex in slave.published.items()]
        checked = None
        if slave.n_check:
            ex = slave.published["Real"]
            checked = buses["Real"][ex.offset:ex.offset + slave.n_check]
        return slave, comp, gathers, sets, gets, checked

    def _publish(self, prepared, tick: int) -> None:
        slave, comp, _, _, gets, checked = prepared
        handle = comp.component
        for fn, vrs, count, address, bus_type in gets:
            status = fn(handle, vrs, count, address)
            if status > 1:
                comp.check(f"{comp.api}Get{bus_type}", self.plan.time(tick), status)
        if checked is not None and not math.isfinite(checked.dot(checked)):
            bad = np.flatnonzero(~np.isfinite(checked))
            if len(bad):
                raise nonfinite_error(self.plan, slave, tick, int(bad[0]))

    def refresher(self, indices: list[int]):
        """A function ``refresh(tick)`` that sets the inputs of the slaves ``indices`` (stepping
        order) due at ``tick`` as they are on the buses and publishes their outputs again
        (kernel.c, cosim_refresh)."""
        chosen = [self._prepared[k] for k in indices]
        time_of = self.plan.time

        def refresh(tick: int) -> None:
            for prepared in chosen:
                slave, comp, gathers, sets, _, _ = prepared
                if tick % slave.step_ticks:
                    continue
                _write_inputs(comp, gathers, sets, time_of(tick))
                self._publish(prepared, tick)

        return refresh

    def advance(self, n_from: int, n_to: int) -> None:
        """Step all due slaves for ticks n_from .. n_to-1 (see kernel.c for the exact order)."""
        plan = self.plan
        t0, h0 = plan.start_time, plan.base_step
        gauss_seidel = plan.gauss_seidel
        profile = self.step_seconds
        for n in range(n_from, n_to):
            t = t0 + float(n) * h0
            for k, prepared in enumerate(self._prepared):
                slave, comp, gathers, sets, _, _ = prepared
                m = slave.step_ticks
                if n % m:
                    continue
                _write_inputs(comp, gathers, sets, t)
                handle = comp.component
                h = (t0 + float(n + m) * h0) - t
                if profile is not None:
                    w0 = time.perf_counter()
                    status = comp.do_step_fn(handle, t, h, 1)
                    profile[k] += time.perf_counter() - w0
                else:
                    status = comp.do_step_fn(handle, t, h, 1)
                if status > 1:
                    if status == 2 and (last := comp.ended_itself(t, h)) is not None:
                        raise FmuTerminated(n, comp.name, last)
                    comp.check(f"{comp.api}DoStep(t={t:.9g} s, h={h:.9g} s)", t, status)
                if gauss_seidel:
                    self._publish(prepared, n + m)
            if not gauss_seidel:
                for prepared in self._prepared:
                    if (n + 1) % prepared[0].step_ticks == 0:
                        self._publish(prepared, n + 1)
            if plan.ends_after(n):
                raise FmuEnded(n + 1)


class NativeEngine:
    """Engine running stretches of ticks in the compiled kernel (one ctypes call per stretch)."""

    name = "native"

    def __init__(self, plan: Plan, library: ctypes.CDLL, profile: bool = False) -> None:
        self.plan = plan
        self.step_seconds = np.zeros(len(plan.slaves)) if profile else None
        self._advance = library.cosim_advance
        self._library = library
        n = len(plan.slaves)
        self._slaves = (CSlave * max(n, 1))()
        for k, slave in enumerate(plan.slaves):
            self._fill(self._slaves[k], slave)
        self._plan = CPlan(n_slaves=n, slaves=ctypes.cast(self._slaves, ctypes.POINTER(CSlave)),
                           real_bus=plan.buses["Real"].ctypes.data, int_bus=plan.buses["Integer"].ctypes.data,
                           bool_bus=plan.buses["Boolean"].ctypes.data, start_time=plan.start_time,
                           base_step=plan.base_step, gauss_seidel=int(plan.gauss_seidel),
                           step_seconds=None if self.step_seconds is None else self.step_seconds.ctypes.data,
                           stop_at=plan.stop_at.ctypes.data)
        self._plan_ref = ctypes.byref(self._plan)
        self._failure = CFailure()
        self._failure_ref = ctypes.byref(self._failure)
        calls = load_calls()
        if calls is not None:  # the kernel called by address: the same call without ctypes' conversions
            self._step = partial(calls.int_p_ll_ll_p, address_of(self._advance), ctypes.addressof(self._plan))
            self._failure_arg = ctypes.addressof(self._failure)
        else:
            self._step = partial(self._advance, self._plan_ref)
            self._failure_arg = self._failure_ref

    def refresher(self, indices: list[int]):
        """As :meth:`PythonEngine.refresher`, one compiled call (kernel.c, cosim_refresh)."""
        which = np.array(indices, dtype=np.int64)
        chosen = CRefreshSet(plan=ctypes.pointer(self._plan), slaves=which.ctypes.data, n=len(which))
        library = self._library
        calls = load_calls()
        if calls is not None:
            call = partial(calls.int_p_ll_p, address_of(library.cosim_refresh), ctypes.addressof(chosen))
            failure = ctypes.addressof(self._failure)
        else:
            call, failure = partial(library.cosim_refresh, ctypes.byref(chosen)), self._failure_ref
        keep = (which, chosen)  # alive as long as the function

        def refresh(tick: int, _keep=keep) -> None:
            if call(tick, failure):
                raise self._error()

        return refresh

    @staticmethod
    def _fill(c: CSlave, slave: SlavePlan) -> None:
        comp = slave.component
        c.component = comp.component
        c.do_step = comp.fn_address["DoStep"]
        for bus_type, attr in zip(BUS_ORDER, ("real", "integer", "boolean")):
            setattr(c, "set_" + attr, comp.fn_address["Set" + bus_type])
            setattr(c, "get_" + attr, comp.fn_address["Get" + bus_type])
        c.step_ticks = slave.step_ticks
        for i, bus_type in enumerate(BUS_ORDER):
            ex = slave.inputs.get(bus_type)
            if ex is not None:
                c.n_in[i], c.vr_in[i], c.in_offset[i] = ex.size, ex.value_references.ctypes.data, ex.offset
            ex = slave.published.get(bus_type)
            if ex is not None:
                c.n_out[i], c.vr_out[i], c.out_offset[i] = ex.size, ex.value_references.ctypes.data, ex.offset
            dst = slave.gather_dst.get(bus_type)
            if dst is not None and len(dst):
                src = slave.gather_src[bus_type]
                c.n_gather[i], c.gather_dst[i], c.gather_src[i] = len(dst), dst.ctypes.data, src.ctypes.data
        c.n_check = slave.n_check

    def advance(self, n_from: int, n_to: int) -> None:
        """Step all due slaves for ticks n_from .. n_to-1 in C; raise SimulationError on failure
        (FmuEnded when an FMU ended the simulation itself)."""
        rc = self._step(n_from, n_to, self._failure_arg)
        if rc:
            f = self._failure
            if f.what == FAIL_ENDED:
                raise FmuEnded(int(f.tick))
            if f.what == FAIL_STEP and f.status == 2:
                slave = self.plan.slaves[f.slave]
                comp = slave.component
                last = comp.ended_itself(self.plan.time(f.tick), self.plan.step_size(f.tick, slave))
                if last is not None:
                    raise FmuTerminated(int(f.tick), comp.name, last)
            raise self._error()

    def _error(self) -> SimulationError:
        f = self._failure
        slave = self.plan.slaves[f.slave]
        comp = slave.component
        plan = self.plan
        if f.status == 4:
            comp.failed_fatally = True
        if f.what == FAIL_NONFINITE:
            return nonfinite_error(plan, slave, f.tick, f.variable)
        t = plan.time(f.tick)
        if f.what == FAIL_STEP:
            what = f"{comp.api}DoStep(t={t:.9g} s, h={plan.step_size(f.tick, slave):.9g} s)"
        elif f.what == FAIL_SET:
            what = f"{comp.api}Set* of its inputs"
        elif f.what == FAIL_GET:
            what = f"{comp.api}Get* of its outputs"
        else:  # pragma: no cover
            what = "an FMI call"
        return comp.error(t, f"{what} returned {status_name(f.status, comp.api)}")


def make_engine(plan: Plan, engine: str, profile: bool = False) -> PythonEngine | NativeEngine:
    """``"native"``, ``"python"`` or ``"auto"`` (native when the kernel can be built).

    ``profile``: accumulate the wall time spent inside each FMU's fmi2DoStep in
    ``engine.step_seconds`` (one entry per slave, stepping order).
    """
    if engine == "python":
        return PythonEngine(plan, profile)
    library = load_kernel()
    if library is None:
        if engine == "native":
            raise OSError("the native co-simulation kernel could not be built (no C compiler?)")
        return PythonEngine(plan, profile)
    return NativeEngine(plan, library, profile)


__all__ = ["BUS_DTYPE", "BUS_ORDER", "Exchange", "NativeEngine", "Plan", "PythonEngine", "SlavePlan",
           "gather", "make_engine", "publish", "set_inputs"]
