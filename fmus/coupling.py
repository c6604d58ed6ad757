"""Coupling study: plant FMU + six drive FMUs at a fixed macro step against a monolithic
solve of the same equations.

Both sides get the same commands from a 400 us "controller": a smooth rest-to-rest
joint move sampled and held every 400 us (CSP target) and, optionally, the model-based
torque feed-forward ``M(q_d) qdd_d + C qd_d + g + friction`` of the nominal arm
(0x60B2), plus the CiA 402 enable sequence (shutdown in the first 400 us, then enable).

- Co-simulation: ``cosim.coupling_study.cosimulate``, on the master the jobs use
  (``cosim.master.Master``, Jacobi or Gauss-Seidel): the plant holds the drives' torque
  and the drives hold the measured ``q, qd`` over the macro step. It lives in ``cosim/``
  because the master does; this module keeps what needs no master (commands, the
  monolithic reference, the error measure).
- Monolithic reference: the drives' discrete controllers as Python oracles
  (:class:`fmus.servo_drive.reference.DriveReference`) sampled every 50 us with the exact
  state, zero-order-hold voltages between samples; the six winding currents and the
  arm (pinocchio ABA + rotor inertia + friction via :class:`robot.dynamics.RobotDynamics`)
  integrated together, continuously, by scipy ``solve_ivp`` (DOP853, rtol 1e-10,
  atol 1e-12). Differences to the co-simulation are therefore coupling errors (held
  torques, held measurements) plus the plant's RK4 error (< 1e-10 rad).
"""
from __future__ import annotations

import time
from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy.integrate import solve_ivp

from fmus.servo_drive.params import drive_start_values
from fmus.servo_drive.reference import DriveReference
from robot.dynamics import RobotDynamics

CONTROLLER_PERIOD = 400e-6  # s, the paper's base sample time
TICK = 50e-6  # s, the drives' current sample time (finest clock of the system)
Q0 = np.array([0.2, -0.5, 1.0, 0.3, 0.6, -0.4])  # rad, a working pose
STROKE = np.array([0.25, 0.25, -0.30, 0.40, 0.40, 0.50])  # rad
MOVE_START, MOVE_DURATION = 0.02, 0.5  # s
DRIVE_INPUTS = ("target_position", "torque_offset", "q_meas", "qd_meas")


@dataclass(frozen=True)
class Commands:
    """Controller commands on the 400 us grid: targets and torque offsets (n, 6), controlword (n,)."""

    target: np.ndarray
    torque_offset: np.ndarray
    controlword: np.ndarray

    def at(self, t: float) -> tuple[np.ndarray, np.ndarray, int]:
        k = min(int(np.floor(t / CONTROLLER_PERIOD + 1e-9)), len(self.controlword) - 1)
        return self.target[k], self.torque_offset[k], int(self.controlword[k])


@dataclass(frozen=True)
class Trajectory:
    """Positions (n, 6) in rad at the times ``t`` (n,) in s, and the wall time of the run."""

    t: np.ndarray
    q: np.ndarray
    wall_time: float


def desired_motion(t: np.ndarray | float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Rest-to-rest quintic move of all joints: q_d, qd_d, qdd_d (rad, rad/s, rad/s^2).

    Peaks: joint speeds 1.875 * STROKE / 0.5 s (0.94..1.9 rad/s), accelerations
    5.77 * STROKE / 0.25 s^2 (5.8..11.5 rad/s^2), about the paper's 1 m/s, 5 m/s^2 path.
    """
    s = np.clip((np.atleast_1d(t) - MOVE_START) / MOVE_DURATION, 0.0, 1.0)[:, None]
    pos = 10 * s**3 - 15 * s**4 + 6 * s**5
    vel = (30 * s**2 - 60 * s**3 + 30 * s**4) / MOVE_DURATION
    acc = (60 * s - 180 * s**2 + 120 * s**3) / MOVE_DURATION**2
    return Q0 + STROKE * pos, STROKE * vel, STROKE * acc


def controller_commands(duration: float, torque_feedforward: bool = True,
                        dynamics: RobotDynamics | None = None) -> Commands:
    """The 400 us controller's commands for ``duration`` s (feed-forward from the nominal model)."""
    dynamics = dynamics or RobotDynamics()
    grid = np.arange(int(np.ceil(duration / CONTROLLER_PERIOD)) + 1) * CONTROLLER_PERIOD
    q, qd, qdd = desired_motion(grid)
    offset = np.zeros_like(q)
    if torque_feedforward:
        offset = np.array([dynamics.inverse_dynamics(*row) for row in zip(q, qd, qdd)])
    controlword = np.where(grid < CONTROLLER_PERIOD - 1e-12, 0x06, 0x0F)
    return Commands(q, offset, controlword)


def monolithic_reference(commands: Commands, duration: float, dynamics: RobotDynamics | None = None,
                         rtol: float = 1e-10, atol: float = 1e-12) -> Trajectory:
    """The same system solved as one ODE with the drive controllers as discrete oracles."""
    dynamics = dynamics or RobotDynamics()
    values = [drive_start_values(a) for a in range(1, 7)]
    oracles = [DriveReference(dict(v)) for v in values]
    target0, _, _ = commands.at(0.0)
    for j, oracle in enumerate(oracles):
        oracle.initialize(Q0[j], 0.0, target0[j])
    gear = np.array([v["gear_ratio"] for v in values])
    torque_constant = np.array([v["torque_constant"] for v in values])
    emf = np.array([v["back_emf_constant"] for v in values]) * gear
    resistance = np.array([v["resistance"] for v in values])
    inductance = np.array([v["inductance"] for v in values])

    x = np.concatenate((Q0, np.zeros(12)))  # q, qd, winding currents
    u = np.zeros(6)
    powered = np.zeros(6, dtype=bool)
    brake = np.zeros(6)  # holding-brake torques, held over a tick (closed until Operation enabled)

    def rhs(_t: float, s: np.ndarray) -> np.ndarray:
        qd, current = s[6:12], s[12:]
        di = np.where(powered, (u - resistance * current - emf * qd) / inductance, 0.0)
        qdd = dynamics.forward_dynamics(s[:6], qd, gear * torque_constant * current + brake)
        return np.concatenate((qd, qdd, di))

    ticks = int(round(duration / TICK))
    record_every = int(round(CONTROLLER_PERIOD / TICK))
    times, positions = [], []
    start = time.perf_counter()
    for k in range(ticks):
        t = k * TICK
        if k % record_every == 0:
            times.append(t)
            positions.append(x[:6].copy())
        target, offset, controlword = commands.at(t)
        for j, oracle in enumerate(oracles):
            u[j], powered[j] = oracle.tick_voltage(x[j], x[6 + j], x[12 + j], target[j], offset[j], controlword)
            brake[j] = oracle.brake_torque
        x[12:][~powered] = 0.0
        x = solve_ivp(rhs, (t, t + TICK), x, method="DOP853", rtol=rtol, atol=atol).y[:, -1]
    return Trajectory(np.array(times), np.array(positions), time.perf_counter() - start)


def coupling_errors(reference: Trajectory, runs: dict[Any, Trajectory]) -> dict[Any, np.ndarray]:
    """Per run (keyed e.g. by macro step): max over time of |q_cosim - q_ref| per joint (rad), shape (6,)."""
    n = len(reference.t)
    return {h: np.abs(run.q[:n] - reference.q[: len(run.q)]).max(axis=0) for h, run in runs.items()}
