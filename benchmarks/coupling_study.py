"""Coupling study and drive-response figures for docs/explanation/fmus.md.

    MPLBACKEND=Agg python benchmarks/coupling_study.py [--duration 0.6] [--figures docs/figures]

Prints (1) the coupling-error table: plant + six drive FMUs co-simulated (Jacobi and
Gauss-Seidel, drives first) on the master the jobs use (cosim.coupling_study) at macro
steps of 400/200/100/50 us against the monolithic reference (fmus.coupling), (2) tracking
errors of the full arm with and without the model-based torque feed-forward and
without the drives' speed feed-forward, and writes the step/ramp figures.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np

from fmus.build import ensure_fmus
from cosim.coupling_study import cosimulate
from fmus.coupling import controller_commands, coupling_errors, desired_motion, monolithic_reference
from fmus.servo_drive.axis_bench import simulate_axis, step_metrics
from fmus.servo_drive.params import drive_start_values, load_drive_parameters

MACRO_STEPS = (400e-6, 200e-6, 100e-6, 50e-6)


def coupling_table(paths, duration: float) -> None:
    commands = controller_commands(duration)
    reference = monolithic_reference(commands, duration)
    counts = np.array([2 * np.pi / (drive_start_values(a)["gear_ratio"] * 65536) for a in range(1, 7)])
    tracking = np.abs(desired_motion(reference.t)[0] - reference.q).max(axis=0)
    print(f"monolithic reference: {reference.wall_time:.1f} s wall for {duration} s")
    print("| coupling | macro step | max error axis 1..6 (urad) | max (urad) | max / encoder count "
          "| wall time per simulated s |")
    print("|---|---|---|---|---|---|")
    for coupling in ("jacobi", "gauss_seidel"):
        runs = {h: cosimulate(paths, commands, h, duration, coupling=coupling) for h in MACRO_STEPS}
        for h, e in coupling_errors(reference, runs).items():
            print(f"| {coupling} | {h * 1e6:.0f} us | {' / '.join(f'{x * 1e6:.2f}' for x in e)} | "
                  f"{e.max() * 1e6:.2f} | {(e / counts).max():.2f} | {runs[h].wall_time / duration:.2f} s |")
    print(f"tracking error of the reference (urad): {' / '.join(f'{x * 1e6:.2f}' for x in tracking)}")


def tracking_table(paths, duration: float, macro_step: float) -> None:
    print("| configuration | max abs(q_d - q), axis 1..6 (urad) |")
    print("|---|---|")
    for label, feedforward, overrides in (
            ("speed + torque feed-forward (paper's method)", True, None),
            ("speed feed-forward only (standard cascade)", False, None),
            ("no feed-forward (pure P position loop)", False, {"speed_feedforward_gain": 0.0})):
        run = cosimulate(paths, controller_commands(duration, torque_feedforward=feedforward), macro_step, duration,
                         drive_overrides=overrides)
        err = np.abs(desired_motion(run.t)[0] - run.q).max(axis=0)
        print(f"| {label} | {' / '.join(f'{x * 1e6:.1f}' for x in err)} |")


def figures(paths, out: Path) -> None:
    import matplotlib.pyplot as plt

    drive = load_drive_parameters()
    j_design = np.sqrt(drive.get("tuning", "inertia_min") * drive.get("tuning", "inertia_max"))
    fig, axes = plt.subplots(1, 2, figsize=(11, 4))
    print("| axis | rise time (ms) | overshoot (%) | 2 % settling (ms) |")
    print("|---|---|---|---|")
    for axis in range(1, 7):
        run = simulate_axis(paths["servo_drive"], axis, j_design[axis - 1], lambda t: 1e-4, 0.15,
                            overrides={"speed_feedforward_gain": 0.0})
        m = step_metrics(run.t, run.q, 1e-4, 2e-3)
        print(f"| {axis} | {m['rise_time'] * 1e3:.2f} | {m['overshoot_percent']:.2f} | {m['settling_time'] * 1e3:.2f} |")
        axes[0].plot((run.t - 2e-3) * 1e3, run.q * 1e6, label=f"axis {axis}")
    axes[0].set(xlabel="time after the step (ms)", ylabel="joint position (urad)", xlim=(-2, 100),
                title="100 urad position step, J = sqrt(J_min J_max), no feed-forward")
    axes[0].legend()
    axes[0].grid(True)

    def ramp(t, v=1.0, a=5.0):
        ta = v / a
        return 0.5 * a * t * t if t < ta else 0.5 * a * ta * ta + v * (t - ta)

    print("| axis | lag without speed FF (mrad) | = 1/Kv | peak error while accelerating, speed FF (urad) |")
    print("|---|---|---|---|")
    for axis in range(1, 7):
        plain = simulate_axis(paths["servo_drive"], axis, j_design[axis - 1], ramp, 0.5,
                              overrides={"speed_feedforward_gain": 0.0})
        fed = simulate_axis(paths["servo_drive"], axis, j_design[axis - 1], ramp, 0.5)
        late = plain.t > 0.45
        accelerating = fed.t < 0.202
        lag = np.mean(plain.target[late] - plain.q[late])
        peak = np.abs(fed.target[accelerating] - fed.q[accelerating]).max()
        print(f"| {axis} | {lag * 1e3:.3f} | {1e3 / drive.get('position_loop', 'kv')[axis - 1]:.3f} | {peak * 1e6:.2f} |")
        if axis in (1, 2, 4):
            axes[1].plot(plain.t * 1e3, (plain.target - plain.q) * 1e3, label=f"axis {axis}, P only")
            axes[1].plot(fed.t * 1e3, (fed.target - fed.q) * 1e3, "--", label=f"axis {axis}, speed FF")
    axes[1].set(xlabel="time (ms)", ylabel="following error (mrad)",
                title="ramp: 5 rad/s^2 to 1 rad/s")
    axes[1].legend(fontsize=7)
    axes[1].grid(True)
    fig.tight_layout()
    out.mkdir(parents=True, exist_ok=True)
    fig.savefig(out / "fmus_drive_step_ramp.png", dpi=110)
    print(f"wrote {out / 'fmus_drive_step_ramp.png'}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__)
    parser.add_argument("--duration", type=float, default=0.6, help="simulated time of the coupling study, s")
    parser.add_argument("--figures", type=Path, default=Path(__file__).resolve().parents[1] / "docs" / "figures")
    parser.add_argument("--macro-step", type=float, default=100e-6, help="macro step of the tracking table, s")
    args = parser.parse_args()
    paths = ensure_fmus()
    figures(paths, args.figures)
    coupling_table(paths, args.duration)
    tracking_table(paths, args.duration, args.macro_step)


if __name__ == "__main__":
    main()
