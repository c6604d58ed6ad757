"""What the controller cycle tests share: the drive loop model of the ISO cell's drives and a
controller run against six CiA 402 state machines."""
from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

from controller import DriveLoopModel, speed_comparison_lead
from fieldbus import Cia402DriveModel, ObservedActuals

PERIOD = 400e-6


def drive_model() -> DriveLoopModel:
    """The drives' position loops (kv per axis, speed feed-forward, the speed comparison's lead)."""
    lead = speed_comparison_lead(PERIOD, 200e-6, 0.25e-3)
    return DriveLoopModel(position_kv=np.array([54.6, 168.7, 311.3, 306.7, 317.7, 317.7]),
                          speed_feedforward_gain=np.ones(6), lead_s=np.full(6, lead), period_s=PERIOD)


def drive(ctrl, cycles: Iterable[int], *, fault_at: int | None = None, fault_node: int = 2, half_way: bool = True,
          check: Callable | None = None, observed: ObservedActuals | None = None) -> None:
    """Run ``ctrl`` on the cycle numbers ``cycles`` against six CiA 402 state machines: drive
    ``fault_node`` (0-based) faults from cycle ``fault_at`` on; each observed position moves
    half way to its set-point per cycle (``half_way``) or takes it; ``check(ctrl, cycle)``
    after each cycle; ``observed``: the arrays the controller reads (default: zeros)."""
    drives = [Cia402DriveModel() for _ in range(6)]
    obs = observed if observed is not None else ObservedActuals.zeros(6)
    obs.fresh[:] = True
    obs.position[:] = ctrl.q_start
    obs.statusword[:] = [d.statusword for d in drives]
    for k in cycles:
        sp = ctrl.run_cycle(k, k * PERIOD, obs)
        if check is not None:
            check(ctrl, k)
        for i, d in enumerate(drives):
            d.step(int(sp.controlword[i]), fault=(fault_at is not None and k >= fault_at and i == fault_node))
        obs.statusword[:] = [d.statusword for d in drives]
        obs.position[:] = 0.5 * (obs.position + sp.position) if half_way else sp.position


def cycles_with_jumps(total: int, jumps: dict[int, int]) -> list[int]:
    """Cycle numbers 0..total-1 run by a controller that jumps ``jumps[k]`` cycles after cycle k."""
    out, k = [], 0
    while k < total:
        out.append(k)
        k += jumps.get(k, 1)
    return out


def logged(ctrl) -> dict:
    """The controller's log columns without the compute times (they differ run to run)."""
    log = ctrl.log.columns()
    log.pop("compute_us")
    return log
