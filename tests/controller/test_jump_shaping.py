"""A controller that skipped cycles (a split controller that fell behind the cell and answered
the newest PRes) shapes its target over the samples the drives see in between. With the bus's
set-point look-ahead the managing node fills the skipped cycles by linear interpolation
(``fieldbus.nodes``), so the drive's backward difference at the new target spans the whole
jump: the set-point shaper uses ``g / (G T)`` for a jump of G cycles
(``controller.drive_compensation``, "After a jump"). Shaped as if the targets were one sample
apart, the target after a jump of G cycles was off by about ``(G - 1) qd T`` (0.6 mrad on
axis 1 per skipped cycle at path speed), which cost the paced split ISO run 20-30x the
in-process TCP error (the set-point shaper after a jumped cycle)."""
from __future__ import annotations

import numpy as np
import pytest

from controller import Controller, ControllerConfig, ControllerInfo, TcpTrajectory
from planners.iso9283 import ISO_Q_HINT, iso9283_test_path
from robot.dynamics import RobotDynamics
from controller_support import PERIOD, cycles_with_jumps, drive, drive_model

LOOKAHEAD = 4
CYCLES = 2600
JUMPS = {1500: 2, 1700: 3, 1900: 5, 2100: 8}  # cycle -> jump (the last longer than the look-ahead)


@pytest.fixture(scope="module")
def tcp_ref():
    path = iso9283_test_path()
    return TcpTrajectory.from_reference(path.reference, path.duration, PERIOD)


def make(ref, fast: bool, lookahead: int) -> Controller:
    ctrl = Controller(ref, ControllerConfig(mode="model_based", settle_time_s=0.002, fast_cycle=fast,
                                            lead_cycles=2 + lookahead),
                      dynamics=RobotDynamics(), q_hint=np.array(ISO_Q_HINT), drive_model=drive_model())
    ctrl.setup(ControllerInfo(period_s=PERIOD, lookahead_cycles=lookahead))
    return ctrl


def targets(ctrl: Controller, cycles: list[int], total: int = CYCLES) -> tuple[np.ndarray, np.ndarray]:
    """Per cycle 0..CYCLES-1 the target the drives apply (the managing node's linear interpolation
    over a skipped cycle, as with the look-ahead) and q_d of the cycles run (NaN for the others)."""
    out, q_d = np.full((total, 6), np.nan), np.full((total, 6), np.nan)

    def keep(c: Controller, k: int) -> None:
        out[k] = c.setpoints.position
        q_d[k] = c._shaper._q_prev  # the shaped motion (the elastic controller's: the motor's)

    drive(ctrl, cycles, check=keep, half_way=False)
    assert ctrl.fallback_cycles == 0
    if ctrl.config.fast_cycle:  # the compiled whole cycle took the jumps
        assert ctrl.kernel_cycles > len(cycles) - 100
    ran = np.array(cycles)
    for j in range(6):
        out[:, j] = np.interp(np.arange(total), ran, out[ran, j])
    return out, q_d


def speed_demand(r: np.ndarray, x: np.ndarray) -> np.ndarray:
    """The drive's position-loop speed demand Kv (r - x) + g (r_k - r_k-1) / T per cycle."""
    m = drive_model()
    v = np.full_like(r, np.nan)
    v[1:] = m.position_kv * (r[1:] - x[1:]) + m.speed_feedforward_gain * (r[1:] - r[:-1]) / PERIOD
    return v


@pytest.mark.parametrize("fast", [True, False])
def test_after_a_jump_the_drives_speed_demand_is_the_one_without_the_jump(tcp_ref, fast):
    reference, q_d = targets(make(tcp_ref, fast, LOOKAHEAD), list(range(CYCLES)))
    jumped, _ = targets(make(tcp_ref, fast, LOOKAHEAD), cycles_with_jumps(CYCLES, JUMPS))
    v_ref, v_jump = speed_demand(reference, q_d), speed_demand(jumped, q_d)
    for start, gap in JUMPS.items():
        after = start + gap  # the first cycle computed after the jump
        # the speed demand there, with the axes on q_d, is what the shaper aims at: the same as without the jump
        # (measured 1e-12-2e-11 rad/s; shaped over one sample it was 1.0-2.0 rad/s off)
        np.testing.assert_allclose(v_jump[after], v_ref[after], rtol=0, atol=1e-9)
        # targets inside and after the jump: only the linear interpolation of a smooth motion differs
        # (0.6, 1.5, 3.9, 25 urad for jumps of 2, 3, 5, 8, decaying; one-sample shaping: 0.7-3.5 mrad)
        window = slice(start, after + 150)
        assert np.max(np.abs(jumped[window] - reference[window])) < 1e-6 * gap ** 2, (start, gap)


def test_without_lookahead_a_jump_is_shaped_over_one_sample_as_before(tcp_ref):
    """Without the look-ahead nothing interpolates the skipped cycles (the drives hold or
    extrapolate their last target): the shaper keeps its one-sample recursion."""
    reference, _ = targets(make(tcp_ref, True, 0), list(range(CYCLES)))
    jumped, _ = targets(make(tcp_ref, True, 0), cycles_with_jumps(CYCLES, {1500: 3}))
    # one sample's recursion over a 3-cycle jump: the target absorbs about 2 cycles of motion
    assert np.max(np.abs(jumped[1503] - reference[1503])) > 1e-5


def test_the_elastic_controller_shapes_over_the_jump_on_both_paths():
    """The elastic mode's motor-side shaping (its compiled cycle and its Python path, bit for bit
    the same) after jumps of 3 and 4 cycles: the drive's speed demand at the new target is the
    one without the jump."""
    from controller.elastic import ELASTIC_MODE, ElasticController
    from controller.reference import JointTrajectory

    amplitude, omega = np.array([0.3, -0.5, 0.4, 0.8, -0.6, 1.0]), np.array([2.0, 3.0, 1.5, 4.0, 5.0, 3.5])
    q0 = np.array([0.2, -0.6, 1.2, 0.3, 0.8, -0.2])
    t = np.arange(0.0, 0.06 + PERIOD / 2, PERIOD)
    q, qd, qdd = (np.array([amplitude * omega ** n * np.sin(omega * s + n * np.pi / 2) + (q0 if n == 0 else 0.0)
                            for s in t]) for n in range(3))
    ref = JointTrajectory(t, q, qd, qdd, PERIOD)
    total, jumps = 140, {60: 3, 100: 4}

    def make_elastic(fast: bool) -> ElasticController:
        ctrl = ElasticController(ref, ControllerConfig(mode=ELASTIC_MODE, settle_time_s=0.002, fast_cycle=fast,
                                                       lead_cycles=2 + LOOKAHEAD),
                                 dynamics=RobotDynamics(payload=[8.0, 0.0, 0.0, 0.08]), drive_model=drive_model())
        ctrl.setup(ControllerInfo(period_s=PERIOD, lookahead_cycles=LOOKAHEAD))
        return ctrl

    reference, motor = targets(make_elastic(False), list(range(total)), total)
    runs = {fast: targets(make_elastic(fast), cycles_with_jumps(total, jumps), total)[0] for fast in (False, True)}
    np.testing.assert_array_equal(runs[True], runs[False])
    v_ref, v_jump = speed_demand(reference, motor), speed_demand(runs[True], motor)
    for start, gap in jumps.items():
        np.testing.assert_allclose(v_jump[start + gap], v_ref[start + gap], rtol=0, atol=1e-9)
