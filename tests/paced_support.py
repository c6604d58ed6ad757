"""What the paced cell side tests share (``DriveEndpoint.run_cycle_paced`` on a virtual clock):
the clock and a run of a managing node and the cell's drive endpoint on one simulated bus."""
from __future__ import annotations

from collections.abc import Callable, Collection
from pathlib import Path

from fieldbus import DriveActuals, DriveEndpoint, JointScaling, ManagingNodeEndpoint, Setpoints
from fieldbus.simbus import unique_channel


class Clock:
    """Wall time that moves only when told: every window has already closed."""

    def __init__(self) -> None:
        self.t = 0.0

    def __call__(self) -> float:
        return self.t


def paced_run(config: dict, scaling: JointScaling, cycles: int, setpoint: Callable[[int, Setpoints], None],
              late: Collection[int] = (), skip: Collection[int] = (), log_path: Path | None = None):
    """``cycles`` cycles of 400 us: the controller (a managing node) sends ``setpoint(k, sp)``
    (controlword 0x0F, drives in Operation enabled) before the cell's window, after it in the
    ``late`` cycles (the frames arrive in the next window), not at all in the ``skip``
    cycles (it keeps its own numbering). Returns the drive endpoint (closed) and per cycle
    the applied (position, torque offset, fresh) copies."""
    channel = unique_channel("hil")
    mn = ManagingNodeEndpoint(config, scaling, channel=channel)
    cn = DriveEndpoint(config, scaling, channel=channel, log_path=log_path)
    clock = Clock()
    sp, act = Setpoints.zeros(6), DriveActuals.zeros(6)
    applied = []
    for k in range(cycles):
        sp.controlword[:] = 0x0F
        setpoint(k, sp)
        act.statusword[:] = 0x27
        if k not in late and k not in skip:
            mn.send_setpoints(k, sp)
        clock.t = k * 4e-4 + 2e-4
        a = cn.run_cycle_paced(k, act, deadline=clock.t, clock=clock)
        applied.append((a.position.copy(), a.torque_offset.copy(), a.fresh.copy()))
        if k in late:
            mn.send_setpoints(k, sp)  # after the window: arrives in the next one
        if k in skip:
            mn._begin(k)  # the controller skipped this cycle entirely (keeps its own numbering)
        mn.collect_actuals(k)
    cn.close()
    mn.close()
    return cn, applied
