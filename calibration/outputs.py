"""Files a calibration writes: calibrated URDF, identified parameters, residual summary.

* ``calibrated.urdf``: the robot description with the identified errors folded into
  the joint origins (:meth:`robot.geometric_errors.GeometricErrorModel.write_urdf`),
  loadable by pinocchio / ``robot.description.load_model`` for the controller's
  numeric inverse kinematics.
* ``parameters.json``: every error parameter with its value and standard deviation
  (SI and readable units), whether it was identified, and why the others were not.
* ``summary.json``: residual statistics before (p_e = 0) and after calibration,
  convergence, noise assumptions.
"""
from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np

from calibration.solver import CalibrationResult
from calibration.optical_tracker import TrackerNoise
from robot.geometric_errors import GeometricErrorModel, default_error_model, is_angle_parameter


def parameter_unit(name: str) -> tuple[str, str, float]:
    """(SI unit, readable unit, factor SI -> readable) of an error parameter by name."""
    if is_angle_parameter(name):
        return "rad", "deg", 180.0 / math.pi
    return "m", "mm", 1e3


def parameters_document(result: CalibrationResult) -> dict:
    """JSON-ready description of the identified parameters."""
    params = {}
    ident = set(int(i) for i in result.identified)
    for i, name in enumerate(result.parameter_names):
        si, readable, factor = parameter_unit(name)
        std = float(result.std[i]) if i in ident else None
        params[name] = {
            "value": float(result.errors[i]),
            "std": std,
            "unit": si,
            f"value_{readable}": float(result.errors[i] * factor),
            f"std_{readable}": None if std is None else std * factor,
            "identified": i in ident,
        }
    report = result.identifiability
    return {
        "parameters": params,
        "identified": [result.parameter_names[i] for i in result.identified],
        "not_identified": {d.parameter: d.describe() for d in report.dependencies},
        "note": (
            "Parameters not identified are fixed at 0; their effect is carried by the "
            "identified ones they merge into (kappa coefficients above). Standard "
            "deviations from sigma_hat^2 (Theta_w^T Theta_w)^-1 at the solution."
        ),
    }


def summary_document(result: CalibrationResult, noise: TrackerNoise, source: str) -> dict:
    """JSON-ready residual summary of a calibration run."""
    return {
        "measurements": source,
        "poses": int(result.residuals.shape[0]),
        "measured": "position and orientation" if result.has_orientation else "position only",
        "identified_parameters": int(len(result.identified)),
        "total_parameters": len(result.parameter_names),
        "iterations": result.iterations,
        "converged": result.converged,
        "cost_history": list(result.cost_history),
        "sigma_hat": result.sigma_hat,
        "noise_assumed": {
            "position_sigma_mm": noise.position_sigma_m * 1e3,
            "orientation_sigma_deg": math.degrees(noise.orientation_sigma_rad),
        },
        "residuals_uncalibrated": result.residual_statistics("uncalibrated"),
        "residuals_calibrated": result.residual_statistics("calibrated"),
        "note": "residuals: measured minus model at the measured joint angles; orientation as rotation vector (deg)",
    }


def write_calibration_outputs(
    result: CalibrationResult,
    out_dir: str | Path,
    *,
    model: GeometricErrorModel | None = None,
    noise: TrackerNoise | None = None,
    source: str = "array",
) -> dict[str, Path]:
    """Write calibrated.urdf, parameters.json and summary.json into ``out_dir``."""
    model = model or default_error_model()
    noise = noise or TrackerNoise()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    urdf = model.write_urdf(out / "calibrated.urdf", np.asarray(result.errors))
    params = out / "parameters.json"
    params.write_text(json.dumps(parameters_document(result), indent=2), encoding="utf-8")
    summary = out / "summary.json"
    summary.write_text(json.dumps(summary_document(result, noise, source), indent=2), encoding="utf-8")
    return {"urdf": urdf, "parameters": params, "summary": summary}
