"""``python -m cosim calibrate MEASUREMENTS.csv --out DIR``: geometric calibration from tracker data."""
from __future__ import annotations

import argparse
import math
import sys
from pathlib import Path

NAME = "calibrate"
HELP = ("Identify the 39-parameter geometric error model (its identifiable subset) from tracker "
        "measurements (CSV: q1..q6 rad, x,y,z m, optional alpha,beta,gamma rad) and write "
        "DIR/calibrated.urdf, DIR/parameters.json and DIR/summary.json.")

#: Exit codes (cosim/results/exits.py): 0 ok, 2 invalid input (file, columns, units, too few or
#: rank-deficient poses, option values), 3 the fit failed or is implausible (nothing written).
EXIT_OK, EXIT_INVALID, EXIT_FAILED = 0, 2, 3


def _positive_float(option: str):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > 0):
            raise argparse.ArgumentTypeError(f"expected a finite number > 0, got {text!r}")
        return value
    return parse


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """MEASUREMENTS, --out, --urdf, noise options."""
    parser.add_argument("measurements", type=Path, help="measurement CSV file (see docs/how-to/calibrate.md)")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/calibrate-<csv name>/)")
    parser.add_argument("--urdf", type=Path, default=None,
                        help="nominal robot description to calibrate (default: robot/rx130l.urdf)")
    parser.add_argument("--position-sigma-mm", type=_positive_float("--position-sigma-mm"), default=None,
                        help="tracker position noise per axis in mm, used to weight rows (default 0.1)")
    parser.add_argument("--orientation-sigma-deg", type=_positive_float("--orientation-sigma-deg"), default=None,
                        help="tracker orientation noise in deg, used to weight rows (default 0.04)")


def run(args: argparse.Namespace) -> int:
    """Read, calibrate, check plausibility, write; invalid input -> exit 2, implausible fit -> exit 3
    (no URDF written)."""
    from cosim.results.exits import InvalidInput, RunFailed, describe_decode_error, describe_os_error
    from calibration.measurements import read_measurements_csv
    from calibration.outputs import write_calibration_outputs
    from calibration.plausibility import assess_calibration
    from calibration.solver import calibrate
    from calibration.optical_tracker import TrackerNoise
    from robot.geometric_errors import GeometricErrorModel, default_error_model

    out_dir = args.out or Path("results") / f"calibrate-{args.measurements.stem}"
    try:
        defaults = TrackerNoise()
        noise = TrackerNoise(
            defaults.position_sigma_m if args.position_sigma_mm is None else args.position_sigma_mm * 1e-3,
            defaults.orientation_sigma_rad if args.orientation_sigma_deg is None
            else math.radians(args.orientation_sigma_deg),
        )
        model = default_error_model() if args.urdf is None else GeometricErrorModel(args.urdf)
        measurements = read_measurements_csv(args.measurements)
    except UnicodeDecodeError as exc:
        raise InvalidInput(describe_decode_error(exc, args.measurements)) from None
    except OSError as exc:
        raise InvalidInput(describe_os_error(exc, f"measurement file {str(args.measurements)!r}")) from None
    except ValueError as exc:
        raise InvalidInput(str(exc)) from None
    try:
        result = calibrate(measurements, model=model, noise=noise)
    except ValueError as exc:  # too few poses, rank-deficient data: the input cannot determine the errors
        raise InvalidInput(str(exc)) from None
    assessment = assess_calibration(measurements, result, model)
    if not assessment.ok:
        raise RunFailed(f"calibration of {args.measurements} refused, no URDF written: {assessment.message()}")
    try:
        paths = write_calibration_outputs(result, out_dir, model=model, noise=noise,
                                          source=str(args.measurements))
    except OSError as exc:
        raise InvalidInput(describe_os_error(exc, f"--out {str(out_dir)!r}")) from None
    stats = result.residual_statistics()
    print(
        f"calibrated {len(result.identified)} of {len(result.parameter_names)} parameters from "
        f"{measurements.count} poses in {result.iterations} iterations; position residual max "
        f"{stats['position_norm']['max']:.3f} mm, rms {stats['position_norm']['rms']:.3f} mm; "
        f"sigma_hat {result.sigma_hat:.3g}; wrote {paths['urdf']}, {paths['parameters']}, "
        f"{paths['summary']}",
        file=sys.stderr,
    )
    return EXIT_OK
