"""Cost of the FMUs per call: doStep of each FMU and get/set of its I/O, through fmpy's
FMU2Slave API and through the one FMU class (fmus.fmu.Fmu: prepared ctypes
arrays, direct library calls). Prints medians in microseconds.

fmpy and fast-path batches are interleaved so both see the same machine load.

    python benchmarks/bench_fmu.py [--repeats 300]
"""
from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Callable

import numpy as np
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

BATCH = 50  # calls per timed batch
TAU = [f"tau[{k}]" for k in range(1, 7)]
PLANT_OUT = [f"q[{k}]" for k in range(1, 7)] + [f"qd[{k}]" for k in range(1, 7)]
DRIVE_IN = ["target_position", "torque_offset", "q_meas", "qd_meas"]
DRIVE_OUT = ["tau_out", "position_actual", "velocity_actual", "torque_actual"]


def _batch_us(function: Callable[[], object]) -> float:
    start = time.perf_counter_ns()
    for _ in range(BATCH):
        function()
    return (time.perf_counter_ns() - start) / BATCH / 1e3


def paired_medians(slow: Callable[[], object], fast: Callable[[], object], repeats: int) -> tuple[float, float]:
    """Median us per call of two functions timed in alternating batches."""
    a, b = [], []
    for _ in range(repeats):
        a.append(_batch_us(slow))
        b.append(_batch_us(fast))
    return statistics.median(a), statistics.median(b)


def fmpy_slave(path, name, start_values):
    md = read_model_description(str(path))
    vr = {v.name: v for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(path)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName=name)
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.enterInitializationMode()
    for key, value in start_values.items():
        if vr[key].type == "Integer":
            fmu.setInteger([vr[key].valueReference], [int(value)])
        else:
            fmu.setReal([vr[key].valueReference], [float(value)])
    fmu.exitInitializationMode()
    return fmu, {k: v.valueReference for k, v in vr.items()}


class Clock:
    """Consecutive communication points of one instance."""

    def __init__(self, t: float = 0.0) -> None:
        self.t = t

    def advance(self, h: float) -> float:
        t = self.t
        self.t += h
        return t


ELASTIC_PLANT = {"elastic_joints": 1, "integration_step": 1e-4, **{f"q0[{k}]": q for k, q in enumerate(
    (0.3, -0.6, 1.2, 0.4, 0.8, -0.2), start=1)}}
"""Start values of the elastic plant as the main job runs it (elastic joints, one RK4 step per
100 us) at a bent pose (the gears pre-loaded by gravity)."""


def bench_plant(path, repeats: int, start: dict | None = None) -> list[tuple[str, float, float]]:
    """Plant calls; ``start``: start values (default: the FMU's defaults, rigid joints, 50 us sub-steps;
    :data:`ELASTIC_PLANT`: the elastic plant of the main job)."""
    start = dict(start or {})
    slow, vr = fmpy_slave(path, "plant_fmpy", start)
    fast = Fmu(path, "plant_fast", start, real_inputs=TAU, real_outputs=PLANT_OUT).start()
    tau_vr, out_vr = [vr[n] for n in TAU], [vr[n] for n in PLANT_OUT]
    tau_list, tau_array = [0.0] * 6, np.zeros(6)
    rows = [("plant set 6 tau", *paired_medians(lambda: slow.setReal(tau_vr, tau_list),
                                                lambda: fast.set_inputs(tau_array), repeats)),
            ("plant push 6 tau (no copy)", *paired_medians(lambda: slow.setReal(tau_vr, tau_list),
                                                          fast.push_inputs, repeats)),
            ("plant get 12 q, qd", *paired_medians(lambda: slow.getReal(out_vr), fast.get_outputs, repeats))]
    slow_clock, fast_clock = Clock(), Clock()
    for h in (50e-6, 100e-6, 400e-6):
        rows.append((f"plant doStep {h * 1e6:.0f} us",
                     *paired_medians(lambda: slow.doStep(slow_clock.advance(h), h),
                                     lambda: fast.do_step(fast_clock.advance(h), h), repeats)))
    slow.terminate()
    slow.freeInstance()
    fast.close()
    return rows


def bench_drive(path, repeats: int) -> list[tuple[str, float, float]]:
    start = drive_start_values(2)
    slow, vr = fmpy_slave(path, "drive_fmpy", start)
    fast = Fmu(path, "drive_fast", start, real_inputs=DRIVE_IN, real_outputs=DRIVE_OUT,
               integer_inputs=["controlword"]).start()
    for controlword, t in ((0x06, 0.0), (0x0F, 400e-6)):  # operation enabled: all loops run
        slow.setInteger([vr["controlword"]], [controlword])
        slow.doStep(t, 400e-6)
        fast.set_integer_inputs([controlword])
        fast.do_step(t, 400e-6)
    in_vr, out_vr, cw_vr = [vr[n] for n in DRIVE_IN], [vr[n] for n in DRIVE_OUT], [vr["controlword"]]
    values, array, word = [0.0] * 4, np.zeros(4), np.array([0x0F], dtype=np.int32)
    rows = [("drive set 4 inputs", *paired_medians(lambda: slow.setReal(in_vr, values),
                                                   lambda: fast.set_inputs(array), repeats)),
            ("drive get 4 outputs", *paired_medians(lambda: slow.getReal(out_vr), fast.get_outputs, repeats)),
            ("drive set controlword", *paired_medians(lambda: slow.setInteger(cw_vr, [0x0F]),
                                                      lambda: fast.set_integer_inputs(word), repeats))]
    slow_clock, fast_clock = Clock(800e-6), Clock(800e-6)
    for h in (50e-6, 100e-6, 400e-6):
        rows.append((f"drive doStep {h * 1e6:.0f} us",
                     *paired_medians(lambda: slow.doStep(slow_clock.advance(h), h),
                                     lambda: fast.do_step(fast_clock.advance(h), h), repeats)))
    slow.terminate()
    slow.freeInstance()
    fast.close()
    return rows


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--repeats", type=int, default=300, help="timed batches of 50 calls per path")
    args = parser.parse_args()
    paths = ensure_fmus()
    rows = bench_plant(paths["rx130l_plant"], args.repeats) + bench_drive(paths["servo_drive"], args.repeats)
    rows += [(f"elastic {name}", slow, fast) for name, slow, fast in bench_plant(paths["rx130l_plant"], args.repeats,
                                                                                 ELASTIC_PLANT) if "doStep" in name]
    print(f"{'call (median us per call)':<28} {'fmpy':>8} {'fast':>8} {'ratio':>6}")
    for name, slow, fast in rows:
        print(f"{name:<28} {slow:8.2f} {fast:8.2f} {slow / fast:6.1f}")
    lookup = {name: (slow, fast) for name, slow, fast in rows}
    loop = sum(lookup[n][1] for n in ("plant set 6 tau", "plant get 12 q, qd", "plant doStep 100 us")) + 6 * sum(
        lookup[n][1] for n in ("drive set 4 inputs", "drive get 4 outputs", "drive set controlword",
                               "drive doStep 100 us"))
    print(f"fast path, plant + 6 drives, one 100 us macro step: {loop:.1f} us "
          f"({loop / 100:.2f} s wall per simulated s, FMU calls only)")


if __name__ == "__main__":
    main()
