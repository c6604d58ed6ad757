"""What the controller contract costs per bus cycle.

Two measurements:

1. **Port overhead in isolation** (``port_overhead``): a plain-Python user controller
   (:class:`BusyController`: joint PD with numpy plus ``work_us`` of busy-waiting, its own
   time measured inside ``step`` with ``perf_counter_ns``) driven by
   :class:`controller.port.ControllerPort` the way the cell drives it (input bound to the
   observed arrays, output checked - finite, modes - and copied into the set-points); per
   cycle the port's total minus the controller's own time = the overhead of the contract.
   Target: at most 10 µs per cycle (2.5 % of the 400 µs cycle).
2. **Closed loop** (``closed_loop``): 2 s (or ``--sim-time``) of the ISO 9283 cell with the
   built-in ``model_based`` controller and with user controllers of the same scenario
   (:class:`BusyController`: PD about the start pose; and following the path through
   :class:`controller.tracking_clock.TrackingClock`, CSP): real-time factors, wall time per
   400 µs cycle, the controller's own time and the contract's cost in the running cell.

The machine is shared: the load average is printed with every figure.

Usage::

    python benchmarks/bench_controller_port.py [--cycles 20000] [--work-us 20] [--sim-time 2.0] [--no-cell]
"""
from __future__ import annotations

import argparse
import os
import statistics
import tempfile
import time
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
TARGET_OVERHEAD_US = 10.0


class BusyController:
    """A plain-Python user controller: joint PD around the reference in CSP (torque offset),
    plus ``work_us`` of busy-waiting; ``own_ns`` holds its own time per step."""

    def __init__(self, work_us: float = 0.0, kp: float = 20.0, track: bool = False) -> None:
        self.work_ns = int(work_us * 1000)
        self.kp = kp
        self.track = track
        self.own_ns: list[int] = []
        self.clock = None

    def setup(self, info) -> None:
        from controller import ControllerOutput
        from controller.tracking_clock import TrackingClock

        self.out = ControllerOutput.zeros(info.n_joints)
        self.out.controlword[:] = 0x000F
        self.q_start = np.asarray(info.q_start if info.q_start is not None else np.zeros(info.n_joints), float)
        self.out.target_position[:] = self.q_start
        if self.track:
            self.clock = TrackingClock(info, settle_time_s=0.01)

    def step(self, inputs):
        t0 = time.perf_counter_ns()
        out = self.out
        if self.clock is not None:
            tau = self.clock.update(inputs, out.controlword)
            q_d = self.clock.reference(tau)[0]
        else:
            q_d = self.q_start
        out.target_position[:] = q_d
        np.multiply(self.kp, q_d - inputs.position, out=out.torque_offset)
        if self.work_ns:
            end = t0 + self.work_ns
            while time.perf_counter_ns() < end:
                pass
        self.own_ns.append(time.perf_counter_ns() - t0)
        return out

    def close(self) -> None:
        pass

    @property
    def motion_start_s(self):
        return self.clock.motion_start_s if self.clock is not None else None


def port_overhead(cycles: int = 20000, work_us: float = 20.0) -> dict[str, float]:
    """Median per-cycle time of ControllerPort.step, of the controller's own step, and their difference (µs)."""
    from controller import ControllerInfo
    from controller.port import ControllerPort
    from fieldbus import ObservedActuals

    ctrl = BusyController(work_us)
    port = ControllerPort(ctrl, 6, q_start=np.zeros(6))
    port.setup(ControllerInfo(period_s=400e-6, q_start=np.zeros(6)))
    obs = ObservedActuals.zeros(6)
    obs.fresh[:] = True
    total = np.empty(cycles)
    for k in range(cycles):
        obs.position[:] = 1e-6 * k
        t0 = time.perf_counter_ns()
        port.step(k, k * 400e-6, obs)
        total[k] = time.perf_counter_ns() - t0
    own = np.array(ctrl.own_ns, dtype=float)
    diff = total - own
    return {"cycles": cycles, "work_us": work_us, "port_step_p50_us": float(np.median(total)) / 1e3,
            "controller_own_p50_us": float(np.median(own)) / 1e3, "overhead_p50_us": float(np.median(diff)) / 1e3,
            "overhead_p99_us": float(np.percentile(diff, 99)) / 1e3, "load_average": os.getloadavg()[0]}


def closed_loop(sim_time: float = 2.0) -> dict[str, dict[str, float]]:
    """The ISO 9283 cell for ``sim_time`` s with the built-in model_based controller, with a
    plain-Python user controller (PD about the start pose, no reference: its own work is a
    few µs) and with the same controller following the path (the reference's IK in Python
    every cycle, :class:`controller.tracking_clock.TrackingClock`): real-time factor, wall µs
    per 400 µs cycle and the controller's own mean µs per cycle. ``overhead_in_cell_us``: the
    user cell's wall per cycle minus the built-in cell's without its controller, minus the user
    controller's own mean (noisy on a loaded machine); ``port_overhead_in_cell_*``: the same measured
    directly in the running cell (:meth:`controller.port.ControllerPort.overhead`)."""
    import bench_closed_loop

    from cosim.execution import run_cell
    from cosim.execution.mode_runs import prepare, user_cell
    from cosim.scenario import RunContext, load_scenario

    out: dict[str, dict[str, float]] = {}
    with tempfile.TemporaryDirectory() as work:
        load = os.getloadavg()[0]
        scenario, cell, controller = bench_closed_loop.build(sim_time, "model_based")
        run = run_cell(cell, controller, RunContext(scenario, Path(work) / "builtin", quiet=True), mode="in_process")
        out["builtin_model_based"] = _figures(run, sim_time, load, controller.timing().mean_us)
        for name, track in (("user_python_pd", False), ("user_python_tracking", True)):
            scenario = load_scenario(ROOT / "scenarios" / "iso9283.toml")
            doc = scenario.data
            doc["simulation"]["stop_time"] = sim_time
            doc["results"]["can_log"] = False
            setup = prepare(doc, str(scenario.path))
            user = BusyController(0.0, track=track)
            load = os.getloadavg()[0]
            run = run_cell(user_cell(setup, user, name), user,
                           RunContext(scenario, Path(work) / name, quiet=True), mode="in_process")
            own = statistics.fmean(user.own_ns) / 1e3 if user.own_ns else float("nan")
            out[name] = _figures(run, sim_time, load, own)
            out[name]["port_overhead_in_cell_p50_us"] = run.port_overhead["p50_us"]
            out[name]["port_overhead_in_cell_mean_us"] = run.port_overhead["mean_us"]
            base = out["builtin_model_based"]
            out[name]["overhead_in_cell_us"] = (out[name]["wall_us_per_cycle"] - own
                                                - (base["wall_us_per_cycle"] - base["controller_own_mean_us"]))
    return out


def _figures(run, sim_time: float, load: float, controller_us: float) -> dict[str, float]:
    if run.failure is not None:
        raise run.failure
    cycles = sim_time / 400e-6
    return {"realtime_factor": run.reached_s / run.loop_wall_time_s,
            "wall_us_per_cycle": run.loop_wall_time_s / cycles * 1e6, "controller_own_mean_us": controller_us,
            "load_average_before": load, "load_average_after": os.getloadavg()[0]}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--cycles", type=int, default=20000)
    parser.add_argument("--work-us", type=float, default=20.0)
    parser.add_argument("--sim-time", type=float, default=2.0)
    parser.add_argument("--no-cell", action="store_true", help="only the isolated port overhead")
    args = parser.parse_args()
    iso = port_overhead(args.cycles, args.work_us)
    print(f"port overhead (load {iso['load_average']:.2f}): port step p50 {iso['port_step_p50_us']:.2f} us, "
          f"controller's own p50 {iso['controller_own_p50_us']:.2f} us -> overhead p50 {iso['overhead_p50_us']:.2f} "
          f"us, p99 {iso['overhead_p99_us']:.2f} us (target <= {TARGET_OVERHEAD_US} us)")
    if not args.no_cell:
        import sys

        sys.path.insert(0, str(ROOT / "benchmarks"))
        for name, f in closed_loop(args.sim_time).items():
            extra = (f", contract in the cell p50 {f['port_overhead_in_cell_p50_us']:.1f} us / mean "
                     f"{f['port_overhead_in_cell_mean_us']:.1f} us (wall difference estimate "
                     f"{f['overhead_in_cell_us']:.1f} us)") if "overhead_in_cell_us" in f else ""
            print(f"{name:22s} real-time factor {f['realtime_factor']:.2f}, {f['wall_us_per_cycle']:.1f} us wall per "
                  f"400 us cycle, controller's own mean {f['controller_own_mean_us']:.1f} us{extra} "
                  f"(load {f['load_average_before']:.2f} -> {f['load_average_after']:.2f})")


if __name__ == "__main__":
    main()
