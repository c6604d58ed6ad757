"""The drives' torque-actual sampling bias, measured on the drive FMU itself.

A drive in CSP mode updates its speed set-point once per position cycle (400 us: the
difference of consecutive target positions), while its speed loop runs at 200 us. While the
axis accelerates, the speed set-point is a staircase and the speed loop answers every step
with a current ripple at the cycle frequency whose mean over the cycle is zero (the plant
is accelerated by the mean). ``torque_actual`` (0x6077) is latched at one fixed phase of that
cycle, so every sample carries the ripple's value at that phase: ``b_i qdd_i`` with
``b_i = kappa N_i^2 k_t,i K_p,i T`` and kappa about -0.175 at the end of the cycle (measured
here, the same for all six axes). That term is exactly collinear with the regressor's
rotor-inertia column ``Ia_i qdd_i``: no excitation separates them, and uncorrected the
identification reports ``Ia_i + b_i`` (Ia3: 0.869 - 0.555 kg m^2, -61 %).

:func:`sampled_torque_bias` measures ``b`` per axis the way a commissioning engineer would on
a test bench: the drive FMU (with the scenario's parameters) accelerates its design inertia
(``sqrt(inertia_min inertia_max)``, drive_params.toml) at a constant rate with the exact
torque feed-forward; ``b = (mean of the samples at the fieldbus phase - J a) / a``.
"""
from __future__ import annotations

import math
from typing import Any

import numpy as np

BENCH_ACCELERATION = 2.0    # rad/s^2, joint side: well inside every axis' limit (rx130l_params.toml)
BENCH_DURATION = 0.3        # s of constant acceleration; the first BENCH_SETTLE s are dropped
BENCH_SETTLE = 0.1          # s: the speed loop's integrator has settled after 0.1 s (T_n <= 12 ms)
CURRENT_SAMPLE = 50e-6      # s, the bench's communication step (the drive's current-loop sample)


def sampled_torque_bias(doc_fmus: list[dict[str, Any]], period_s: float) -> dict[str, Any]:
    """``{"bias_Nm_per_rad_s2": [6], "kappa": [6], "bench": ...}`` for the scenario's drives.

    ``bias`` is b_i of the module docstring for torque samples taken at the position-cycle
    boundary (where the fieldbus latches torque actual: checked against the plant's applied
    torque in tests/identification/test_rotor.py); ``kappa`` = b_i / (N^2 k_t K_p T).
    """
    from cosim.cell.wiring import drive_parameters
    from fmus.build import ensure_fmus
    from fmus.servo_drive.axis_bench import simulate_axis
    from fmus.servo_drive.params import load_drive_parameters

    fmu = ensure_fmus()["servo_drive"]
    table = load_drive_parameters()
    bias, kappa, inertia = [], [], []
    for axis, params in enumerate(drive_parameters(doc_fmus), start=1):
        j = math.sqrt(table.axis_value("tuning", "inertia_min", axis) * table.axis_value("tuning", "inertia_max", axis))
        a = BENCH_ACCELERATION
        run = simulate_axis(fmu, axis, j, lambda t: 0.5 * a * t * t, BENCH_DURATION,
                            torque_offset=lambda t, j=j: j * a, overrides=params, step=CURRENT_SAMPLE)
        cycles = run.t / period_s
        at_boundary = (np.abs(cycles - np.round(cycles)) < 1e-6) & (run.t > BENCH_SETTLE)
        b = float((np.mean(run.tau[at_boundary]) - j * a) / a)
        scale = params["gear_ratio"] ** 2 * params["torque_constant"] * params["speed_kp"] * period_s
        bias.append(b)
        kappa.append(b / scale)
        inertia.append(j)
    return {"bias_Nm_per_rad_s2": bias, "kappa": kappa,
            "bench": {"inertia_kg_m2": inertia, "acceleration_rad_s2": BENCH_ACCELERATION,
                      "duration_s": BENCH_DURATION, "settle_s": BENCH_SETTLE,
                      "definition": "drive FMU with the scenario's parameters on its design inertia "
                                    "sqrt(inertia_min inertia_max), constant acceleration with the exact torque "
                                    "feed-forward; b = (mean torque sampled at the position-cycle boundary - J a) / a"}}
