"""Per-cycle cost of a user's controller FMU in the cell (``controller/fmu_controller.py``).

The C controller FMU of ``examples/fmus/feedforward_controller`` with the mapping of
``examples/compare.toml`` (18 Real inputs: reference position, velocity and acceleration;
its Real outputs: target position and torque offset per joint) is stepped through
:class:`controller.fmu_controller.FmuController` as the cell steps it, with the drives
reported in Operation enabled and a joint reference (no IK), for ``--cycles`` cycles after
enabling and settling. Figures: median per cycle of ``step()`` over blocks of 1000 cycles, and
of the same cycles' clock and reference alone (``controller.tracking_clock``), whose
difference is what exchanging values with the FMU and stepping it costs.
Run: python benchmarks/bench_controller_fmu.py [--cycles 20000]
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
import tomllib
from pathlib import Path
from types import SimpleNamespace

import numpy as np

ROOT = Path(__file__).resolve().parents[1]
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

BLOCK = 1000


def _mapping() -> tuple[dict[str, str], dict[str, str]]:
    doc = tomllib.loads((ROOT / "examples" / "compare.toml").read_text(encoding="utf-8"))
    entry = next(c for c in doc["compare"]["controllers"] if c.get("name") == "feedforward_fmu")
    return dict(entry["fmu_inputs"]), dict(entry["fmu_outputs"])


def _info(period: float):
    from controller import JointTrajectory
    from controller.contract import ControllerInfo

    def sampler(t):
        q = np.outer(np.sin(t), np.full(6, 0.3))
        return SimpleNamespace(q=q, qd=np.outer(np.cos(t), np.full(6, 0.3)), qdd=-q)

    reference = JointTrajectory.from_sampler(sampler, 60.0, period)
    return ControllerInfo(period_s=period, q_start=np.zeros(6), reference=reference)


def _controller(path: Path, inputs: dict, outputs: dict):
    from cosim.cell.user_controller import make_controller_fmu

    return make_controller_fmu(path, inputs, outputs, {}, settle_time_s=0.0)


def measure(cycles: int = 20000, period: float = 400e-6) -> dict:
    from controller.contract import ControllerInput, ControllerOutput
    from controller.tracking_clock import TrackingClock
    from fmus.source_fmu import build_source_fmu

    path = build_source_fmu(ROOT / "examples" / "fmus" / "feedforward_controller")
    inputs_map, outputs_map = _mapping()
    info = _info(period)
    ctl = _controller(path, inputs_map, outputs_map)
    ctl.setup(info)
    clock = TrackingClock(info, settle_time_s=0.0)
    cw = ControllerOutput.zeros(6).controlword
    inputs = ControllerInput.zeros(6)
    inputs.statusword[:] = 0x27  # Operation enabled
    try:
        for k in range(3):  # enable and start the motion
            inputs.cycle, inputs.time_s = k, k * period
            ctl.step(inputs)
            clock.update(inputs, cw)
        step_us, clock_us = [], []
        k = 3
        for _ in range(cycles // BLOCK):
            t0 = time.perf_counter_ns()
            for _ in range(BLOCK):
                inputs.cycle, inputs.time_s = k, k * period
                ctl.step(inputs)
                k += 1
            t1 = time.perf_counter_ns()
            k -= BLOCK
            for _ in range(BLOCK):
                inputs.cycle, inputs.time_s = k, k * period
                clock.reference(clock.update(inputs, cw))
                k += 1
            t2 = time.perf_counter_ns()
            step_us.append((t1 - t0) / BLOCK / 1e3)
            clock_us.append((t2 - t1) / BLOCK / 1e3)
        out = ctl.out
        assert np.all(np.isfinite(out.target_position)) and np.any(out.target_position != 0.0)
    finally:
        ctl.close()
    step, clk = float(np.median(step_us)), float(np.median(clock_us))
    result = {"cycles": cycles, "fmu_real_inputs": len(inputs_map), "fmu_real_outputs": len(outputs_map),
              "step_us_median": step, "clock_and_reference_us_median": clk, "fmu_exchange_us_median": step - clk,
              "load_average": os.getloadavg()}
    print(f"controller FMU per cycle: step {step:.2f} us median, of which clock + reference {clk:.2f} us, "
          f"FMU set/doStep/get {step - clk:.2f} us ({len(inputs_map)} inputs, {len(outputs_map)} outputs; "
          f"load average {os.getloadavg()[0]:.2f})")
    return result


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--cycles", type=int, default=20000)
    parser.add_argument("--json", action="store_true", help="print the figures as JSON too")
    args = parser.parse_args(argv)
    result = measure(args.cycles)
    if args.json:
        print(json.dumps(result))
    return result


if __name__ == "__main__":
    main()
