"""PNG figures of the ISO 9283 job, after the paper's Figure 2 (matplotlib, Agg backend).

* ``figure2a_lag_errors.png`` - lag errors ``q_d - q`` of axes 1-3 over the path time,
  standard against model-based (paper Figure 2a; also the cascade with the drives'
  speed feed-forward when that mode ran).
* ``figure2b_tcp_error.png`` - TCP error (measured vs commanded, true kinematics) along
  the path (arc length), standard against model-based (paper Figure 2b), log scale.
* ``tcp_error_vs_desired_path.png`` - the error against the programmed path, which
  adds the geometric error of the controller's (uncalibrated) kinematic model.
* ``vibration.png`` - the TCP error spectrum over the path (log-log) and the residual
  vibration after the motion ends (noise-free TCP error, settling band).
"""
from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np


COLOURS = {"standard": "tab:red", "standard_speed_ff": "tab:orange", "model_based": "tab:blue",
           "model_based_elastic": "tab:green"}
LABELS = {"standard": "standard (drive cascade, position set-points)",
          "standard_speed_ff": "cascade + drive speed feed-forward",
          "model_based": "model-based (eq. 7 feed-forward)",
          "model_based_elastic": "model-based, elastic gears (flatness feed-forward)"}


def _pyplot():
    os.environ.setdefault("MPLBACKEND", "Agg")
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def write_figures(out_dir: Path, results: dict[str, Any], path: Any) -> list[Path]:
    """Write the figures for the modes in ``results`` (mode -> TrackingResult); return the files."""
    plt = _pyplot()
    written: list[Path] = []
    # the built-in modes in their order, then any other run (a user's controller)
    modes = [m for m in [*COLOURS, *(r for r in results if r not in COLOURS)] if m in results and results[m].t.size]
    if not modes:
        return written

    fig, axes = plt.subplots(3, 1, figsize=(9, 7.5), sharex=True)
    for j, ax in enumerate(axes):
        for mode in modes:
            r = results[mode]
            ax.plot(r.t - r.t[0], r.lag[:, j] * 1e3, color=COLOURS.get(mode, "tab:green"), lw=0.8,
                    label=LABELS.get(mode, mode))
        ax.set_ylabel(f"axis {j + 1} lag [mrad]")
        ax.grid(True, alpha=0.3)
    axes[0].legend(loc="upper right", fontsize=8)
    axes[-1].set_xlabel("path time [s]")
    fig.suptitle("Lag errors q_d - q of axes 1-3 on the ISO 9283 path (cf. paper Fig. 2a)")
    fig.tight_layout()
    written.append(_save(fig, out_dir / "figure2a_lag_errors.png", plt))

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for mode in modes:
        r = results[mode]
        ax.plot(r.arc_length, r.tcp_error * 1e3, color=COLOURS.get(mode, "tab:green"), lw=0.8,
                label=f"{LABELS.get(mode, mode)}: max {r.tcp_error.max() * 1e3:.3f} mm")
    _segment_marks(ax, path)
    ax.set_yscale("log")  # the modes differ by orders of magnitude (docs/main_job.md)
    ax.set_xlabel("path length [m]")
    ax.set_ylabel("TCP error [mm] (log scale)")
    ax.set_title("TCP error along the ISO 9283 path, laser tracker at 1 ms (cf. paper Fig. 2b)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    written.append(_save(fig, out_dir / "figure2b_tcp_error.png", plt))

    fig, ax = plt.subplots(figsize=(9, 4.5))
    for mode in modes:
        r = results[mode]
        ax.plot(r.arc_length, r.path_error * 1e3, color=COLOURS.get(mode, "tab:green"), lw=0.8,
                label=f"{LABELS.get(mode, mode)}: max {r.path_error.max() * 1e3:.3f} mm")
    _segment_marks(ax, path)
    ax.set_xlabel("path length [m]")
    ax.set_ylabel("error to the programmed path [mm]")
    ax.set_title("Measured TCP vs programmed path (dynamic + geometric error of the controller's model)")
    ax.grid(True, alpha=0.3)
    ax.legend(fontsize=8)
    fig.tight_layout()
    written.append(_save(fig, out_dir / "tcp_error_vs_desired_path.png", plt))

    fig, (ax_f, ax_r) = plt.subplots(2, 1, figsize=(9, 7.5))
    for mode in sorted(modes, key=lambda m: -float(results[m].tcp_error.max())):  # largest first: none hidden
        r = results[mode]
        if r.spectrum_hz.size > 1:
            ax_f.loglog(r.spectrum_hz[1:], r.spectrum_m[1:] * 1e3, color=COLOURS[mode], lw=0.8, label=LABELS[mode])
        if r.residual_t.size:
            res = r.residual
            ax_r.semilogy(r.residual_t * 1e3, np.maximum(r.residual_error * 1e3, 1e-6), color=COLOURS[mode], lw=0.9,
                          label=f"{LABELS[mode]}: peak {res.get('peak_mm', float('nan')):.4f} mm, settled "
                                f"{_ms(res.get('settling_time_s'))}, static offset "
                                f"{res.get('static_offset_mm', float('nan')):.3f} mm")
    band = next((results[m].residual.get("band_mm") for m in modes if results[m].residual), None)
    if band is not None:
        ax_r.axhline(band, color="0.4", lw=0.8, ls="--", label=f"settling band {band:.3f} mm")
    ax_f.set_xlabel("frequency [Hz]")
    ax_f.set_ylabel("TCP error amplitude [mm]")
    ax_f.set_title("Spectrum of the noise-free TCP error over the ISO 9283 path (Hann window)")
    ax_f.grid(True, which="both", alpha=0.3)
    ax_f.legend(fontsize=8)
    ax_r.set_xlabel("time after the end of the motion [ms]")
    ax_r.set_ylabel("distance from the final pose [mm] (log)")
    ax_r.set_title("Residual vibration after the motion ends (noise-free TCP, about the attained final pose)")
    ax_r.grid(True, which="both", alpha=0.3)
    ax_r.legend(fontsize=8)
    fig.tight_layout()
    written.append(_save(fig, out_dir / "vibration.png", plt))
    return written


def _ms(seconds: float | None) -> str:
    if seconds is None or not np.isfinite(seconds):
        return "not within the recording"
    return f"after {seconds * 1e3:.0f} ms"


def _segment_marks(ax: Any, path: Any) -> None:
    for seg in path.segments[1:]:
        ax.axvline(seg.arc_start, color="0.7", lw=0.5, ls=":")


def _save(fig: Any, file: Path, plt: Any) -> Path:
    fig.savefig(file, dpi=110)
    plt.close(fig)
    return file
