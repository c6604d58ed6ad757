"""The drive latches its position actual at the sync: q_meas set at a position-sample instant
shows in position_actual at once (direct feedthrough), so the PRes of cycle k carries the
position at t_k; between samples the output holds. In the master, Master.refresher sets the
drives' inputs at t_k before a task reads their outputs (native and Python engines alike)."""
import math

import numpy as np
import pytest

from cosim.master import Master
from fmus.build import ensure_fmus
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

AXIS = 2
REAL_IN = ("target_position", "torque_offset", "q_meas", "qd_meas")


def counts_per_rad(values):
    return values["gear_ratio"] * values["encoder_counts_per_rev"] / (2.0 * math.pi)


def test_position_actual_latches_q_meas_set_at_a_position_sample():
    values = drive_start_values(AXIS)
    cpr = counts_per_rad(values)
    drive = Fmu(ensure_fmus()["servo_drive"], "latch", values, real_inputs=REAL_IN,
                real_outputs=("position_actual",)).start()
    try:
        seen = []
        t, q = 0.0, 0.0123456
        for k in range(3):  # three 400 us cycles of 8 steps of 50 us
            for step in range(8):
                q += 1.37e-4
                drive.set_inputs((0.0, 0.0, q, 0.0))
                seen.append((step, q, float(drive.get_outputs()[0])))
                drive.do_step(t, 50e-6)
                t += 50e-6
        latched = None
        for step, q, position in seen:
            if step == 0:
                latched = math.floor(q * cpr) / cpr
            assert position == latched  # set at the sample: shows at once; later sets: held
    finally:
        drive.close()


@pytest.mark.parametrize("engine", ["native", "python"])
def test_refresher_gives_a_task_the_position_at_its_tick(engine):
    values = drive_start_values(AXIS)
    cpr = counts_per_rad(values)
    master = Master(base_step=1e-4, engine=engine)
    master.add_fmu("drive", ensure_fmus()["servo_drive"], start_values=values)
    master.add_variable("sim.q", "Real")
    master.connect("sim.q", "drive.q_meas")
    got = []

    def q_at(t):
        return 0.3 + 0.2 * math.sin(7.0 * t)

    def source(t):  # every tick: the "plant" position at t_n
        q_view[0] = q_at(t)

    def task(t):
        refresh()
        got.append((t, float(position[0])))

    master.add_task(source, period=1e-4, priority=0, name="source")
    master.add_task(task, period=4e-4, priority=1, name="bus cycle")
    master.initialize(stop_time=0.02)
    q_view = master.view(["sim.q"], writable=True)
    position = master.view(["drive.position_actual"])
    refresh = master.refresher(["drive"])
    master.run(0.02)
    master.close()
    assert len(got) == 51
    for t, p in got[1:]:
        assert p == math.floor(q_at(t) * cpr) / cpr
    with pytest.raises(Exception, match="not FMU instances"):
        master.refresher(["nope"])
