"""The coupling study's co-simulation, run on the master the jobs use (``cosim.master.Master``).

The plant FMU and six drive FMUs exactly as the cell wires them (drive torque -> plant,
plant q, qd -> drive measurement), the 400 us "controller" of :mod:`fmus.coupling` as a
master task writing master variables (targets, torque offsets, controlwords) that
connections carry to the drives, and a recorder sampling the plant's q every 400 us.
The monolithic reference and the commands stay in :mod:`fmus.coupling` (they need no
master); :func:`fmus.coupling.coupling_errors` compares the two.
"""
from __future__ import annotations

import time
from pathlib import Path

import numpy as np

from cosim.master import Master, MemorySink
from fmus.coupling import CONTROLLER_PERIOD, Q0, Commands, Trajectory
from fmus.servo_drive.params import drive_start_values
from robot.joints import N_JOINTS


def cosimulate(fmu_paths: dict[str, Path], commands: Commands, macro_step: float, duration: float,
               drive_overrides: dict[str, float] | None = None, coupling: str = "jacobi",
               engine: str = "auto") -> Trajectory:
    """Co-simulate the plant and six drives on the master at ``macro_step`` (s) for ``duration`` (s).

    ``coupling="jacobi"``: every FMU steps from the outputs at ``t``; ``"gauss_seidel"``: the
    drives step first and the plant gets their torque at ``t + H``. ``drive_overrides``
    replace drive start values on all axes. Returns q (rad) on the 400 us grid from 0 to
    ``duration`` and the wall time of ``Master.run``.
    """
    master = Master(macro_step, coupling=coupling, engine=engine)
    drives = [f"drive{a}" for a in range(1, N_JOINTS + 1)]
    master.add_fmu("plant", fmu_paths["rx130l_plant"],
                   start_values={f"q0[{j + 1}]": float(Q0[j]) for j in range(N_JOINTS)})
    for a, d in enumerate(drives, start=1):
        master.add_fmu(d, fmu_paths["servo_drive"], start_values={**drive_start_values(a), **(drive_overrides or {})})
    targets = master.add_variables("ctrl", [f"target[{a}]" for a in range(1, N_JOINTS + 1)])
    offsets = master.add_variables("ctrl", [f"offset[{a}]" for a in range(1, N_JOINTS + 1)])
    words = master.add_variables("ctrl", [f"controlword[{a}]" for a in range(1, N_JOINTS + 1)], type="Integer")
    for a, d in enumerate(drives, start=1):
        master.connect(f"{d}.tau_out -> plant.tau[{a}]")
        master.connect(f"plant.q[{a}] -> {d}.q_meas")
        master.connect(f"plant.qd[{a}] -> {d}.qd_meas")
        master.connect(f"{targets[a - 1]} -> {d}.target_position")
        master.connect(f"{offsets[a - 1]} -> {d}.torque_offset")
        master.connect(f"{words[a - 1]} -> {d}.controlword")
    if coupling == "gauss_seidel":
        master.set_order([*drives, "plant"])
    views = {}

    def setup(m: Master) -> None:
        views["target"] = m.view(targets, writable=True)
        views["offset"] = m.view(offsets, writable=True)
        views["word"] = m.view(words, writable=True)

    def controller(t: float) -> None:
        target, offset, word = commands.at(t)
        views["target"][:] = target
        views["offset"][:] = offset
        views["word"][:] = word

    master.add_task(controller, CONTROLLER_PERIOD, setup=setup, name="controller")
    sink = MemorySink()
    master.add_recorder([f"plant.q[{j}]" for j in range(1, N_JOINTS + 1)], CONTROLLER_PERIOD, sink, name="q")
    with master:
        master.initialize(duration)
        start = time.perf_counter()
        master.run()
        wall = time.perf_counter() - start
    data = sink.data
    return Trajectory(data[:, 0], data[:, 1:], wall)


__all__ = ["cosimulate"]
