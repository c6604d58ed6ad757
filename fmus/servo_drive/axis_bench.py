"""Single-axis test bench: the servo-drive FMU driving a rigid inertia.

Used by the drive's step/ramp tests and the figures of docs/explanation/fmus.md. The load is
``J qdd = tau_out - load_torque(t)``, integrated exactly over each communication step
(torque constant over the step). The drive is enabled with the CiA 402 sequence
shutdown (0x06) then enable operation (0x0F) during the first two position samples;
motion starts at ``motion_start`` (default 2 ms).
"""
from __future__ import annotations

from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

INPUTS = ("target_position", "torque_offset", "q_meas", "qd_meas")
OUTPUTS = ("tau_out", "position_actual", "velocity_actual", "current_actual", "following_error")


@dataclass(frozen=True)
class AxisRun:
    """Time series of one run, arrays of shape (n,): s, rad, rad/s, N m, A; statusword ints.

    Row k holds the state at the end of communication step k and the target at that time.
    """

    t: np.ndarray
    target: np.ndarray
    q: np.ndarray
    qd: np.ndarray
    tau: np.ndarray
    current: np.ndarray
    position_actual: np.ndarray
    statusword: np.ndarray


def simulate_axis(fmu_path: str | Path, axis: int, inertia: float, target: Callable[[float], float],
                  duration: float, *, torque_offset: Callable[[float], float] | None = None,
                  load_torque: Callable[[float], float] | None = None,
                  overrides: Mapping[str, float | int] | None = None, step: float = 50e-6,
                  motion_start: float = 2e-3) -> AxisRun:
    """Run the drive of ``axis`` (1..6) on a joint-side ``inertia`` (kg m^2) for ``duration`` s.

    ``target(t)`` and ``torque_offset(t)`` are sampled at the communication points
    (t measured from ``motion_start``; zero before it); ``overrides`` replace FMU start values.
    """
    start_values = dict(drive_start_values(axis))
    start_values.update(overrides or {})
    drive = Fmu(fmu_path, f"axis{axis}", start_values, real_inputs=INPUTS, real_outputs=OUTPUTS,
                integer_inputs=("controlword",), integer_outputs=("statusword",)).start()
    n = int(round(duration / step))
    rows = np.zeros((n, 7))
    status = np.zeros(n, dtype=int)
    q = qd = 0.0
    inputs = np.zeros(4)
    try:
        for k in range(n):
            t = k * step
            drive.set_integer_inputs((0x06 if t < 4e-4 - 1e-12 else 0x0F,))
            tm = t - motion_start
            inputs[0] = target(tm) if tm >= -1e-12 else 0.0
            inputs[1] = torque_offset(tm) if (torque_offset and tm >= -1e-12) else 0.0
            inputs[2], inputs[3] = q, qd
            drive.set_inputs(inputs)
            drive.do_step(t, step)
            tau, pos_act, _, current, _ = drive.get_outputs()
            acc = (tau - (load_torque(t) if load_torque else 0.0)) / inertia
            q += qd * step + 0.5 * acc * step * step
            qd += acc * step
            t_next = tm + step  # the target at the row's time, for a consistent following error
            recorded_target = target(t_next) if t_next >= -1e-12 else 0.0
            rows[k] = (t + step, recorded_target, q, qd, tau, current, pos_act)
            status[k] = drive.get_integer_outputs()[0]
    finally:
        drive.close()
    return AxisRun(*(rows[:, j].copy() for j in range(7)), statusword=status)


def step_metrics(t: np.ndarray, y: np.ndarray, amplitude: float, t0: float) -> dict[str, float]:
    """Rise time 10-90 % (s), overshoot (% of amplitude), 2 % settling time (s) after ``t0``."""
    mask = t >= t0
    tt, yy = t[mask] - t0, y[mask]
    rise = tt[np.argmax(yy >= 0.9 * amplitude)] - tt[np.argmax(yy >= 0.1 * amplitude)]
    outside = np.nonzero(np.abs(yy - amplitude) > 0.02 * abs(amplitude))[0]
    settle = tt[outside[-1] + 1] if outside.size and outside[-1] + 1 < tt.size else (0.0 if not outside.size else np.inf)
    return {"rise_time": float(rise), "overshoot_percent": float((yy.max() - amplitude) / amplitude * 100.0),
            "settling_time": float(settle)}
