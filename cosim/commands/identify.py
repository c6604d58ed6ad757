"""``python -m cosim identify DATA.csv [--validate VAL.csv] --out DIR``: dynamic identification from a record."""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path

NAME = "identify"
HELP = ("Identify the base dynamic parameters from a measured record (CSV: t s, q1..q6 rad, tau1..tau6 N m "
        "joint side, optional qd1..qd6, qdd1..qdd6) and write DIR/parameters.json; with --validate, predict the "
        "torques of a second record and write DIR/prediction.csv and DIR/summary.json.")

#: Exit codes (cosim/results/exits.py): 0 ok, 2 invalid input (file, columns, NaN, sampling, too short,
#: not exciting, angles/torques in the wrong unit, option values), 3 the fit is implausible (nothing written).
EXIT_OK, EXIT_INVALID, EXIT_FAILED = 0, 2, 3


def _finite_above(option: str, low: float):
    def parse(text: str) -> float:
        try:
            value = float(text)
        except ValueError:
            value = math.nan
        if not (math.isfinite(value) and value > low):
            raise argparse.ArgumentTypeError(f"expected a finite number > {low:g}, got {text!r}")
        return value
    return parse


def _sampling_bias(text: str):
    """``--torque-sampling-bias``: 'drives', a scenario .toml, or six numbers (N m per rad/s^2)."""
    if text == "drives" or text.endswith(".toml"):
        return text
    parts = [p for p in text.replace(";", ",").split(",") if p.strip()]
    try:
        values = [float(p) for p in parts]
    except ValueError:
        values = []
    if len(values) != 6 or not all(math.isfinite(v) for v in values):
        raise argparse.ArgumentTypeError(
            f"expected 'drives', a scenario file SCENARIO.toml, or 6 comma-separated numbers in N m per rad/s^2 "
            f"(b1,...,b6), got {text!r}")
    return values


def sampling_bias_values(choice, period_s: float | None = None) -> tuple[list[float], str]:
    """The six b_i of ``--torque-sampling-bias`` and where they come from: given numbers as they
    are; 'drives' or SCENARIO.toml measured on the built-in servo-drive FMU (default parameters,
    or that scenario's drive parameters) the way the identification campaign does
    (cosim/jobs/identification_torque_sampling.py)."""
    from cosim.jobs.identification_torque_sampling import sampled_torque_bias

    if isinstance(choice, list):
        return choice, "given (--torque-sampling-bias)"
    if choice == "drives":
        fmus = [{"name": f"drive{i}", "builtin": "servo_drive", "parameters": {}} for i in range(1, 7)]
        source = "the built-in servo drives with their default parameters (fmus/servo_drive/drive_params.toml)"
    else:
        from cosim.scenario import load_scenario

        scenario = load_scenario(choice)
        fmus = scenario.data["fmus"]
        source = f"the servo drives of {choice}"
    from cosim.cell.wiring import drive_parameters

    cycle = period_s or float(drive_parameters(fmus)[0]["position_sample_time"])
    bench = sampled_torque_bias(fmus, cycle)
    return list(bench["bias_Nm_per_rad_s2"]), f"measured on {source} (drive FMU bench, {cycle * 1e6:g} us cycle)"


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """DATA, --validate, --out, --method, --cutoff-hz, --max-condition, --torque-sampling-bias."""
    from identification.defaults import DEFAULT_CUTOFF_HZ, MAX_CONDITION_NUMBER

    parser.add_argument("data", type=Path, help="identification record CSV (see docs/how-to/identify.md)")
    parser.add_argument("--validate", type=Path, default=None, metavar="VAL.csv",
                        help="a second record (same columns) on which the identified model predicts the torques")
    parser.add_argument("--out", type=Path, default=None,
                        help="output folder (default: results/identify-<data name>/)")
    parser.add_argument("--method", choices=("wls", "ols"), default="wls",
                        help="weighted (per-joint noise, default) or ordinary least squares")
    parser.add_argument("--cutoff-hz", type=_finite_above("--cutoff-hz", 0.0), default=DEFAULT_CUTOFF_HZ,
                        help=f"zero-phase low-pass cut-off for differentiating q, Hz (default {DEFAULT_CUTOFF_HZ:g})")
    parser.add_argument("--consistent", action="store_true",
                        help="also fit a physically consistent parameter vector (positive-definite pseudo-inertias) "
                             "and report its validation error")
    parser.add_argument("--max-condition", type=_finite_above("--max-condition", 1.0), default=MAX_CONDITION_NUMBER,
                        help="largest accepted condition number of the column-normalised base regressor "
                             f"(default {MAX_CONDITION_NUMBER:g})")
    parser.add_argument("--torque-sampling-bias", type=_sampling_bias, default=None, metavar="B",
                        help="remove the drives' torque-sampling term b_i qdd_i from the measured torques before "
                             "identifying and validating (a drive that latches its torque in step with its speed "
                             "loop reports b_i qdd_i too; uncorrected the rotor inertias come out as Ia_i + b_i): "
                             "B = six comma-separated b_i in N m per rad/s^2 (e.g. from a test bench; negative values: "
                             "--torque-sampling-bias=-0.2,...), 'drives' "
                             "(measured on the built-in servo-drive FMU with its default parameters) or a scenario "
                             "file SCENARIO.toml (its drives' parameters); see docs/explanation/identification.md")


def run(args: argparse.Namespace) -> int:
    """Read, check units, identify, check the fit, validate, write; invalid input -> exit 2,
    implausible fit -> exit 3 (no parameter file written)."""
    from cosim.results.exits import InvalidInput, RunFailed, describe_os_error
    from identification.data import read_motion_csv
    from identification.identify import identify, validate, write_identification_outputs
    from identification.plausibility import check_fit, check_record_units

    out_dir = args.out or Path("results") / f"identify-{args.data.stem}"
    try:
        record = read_motion_csv(args.data)
        check_record_units(record, str(args.data))
        validation_record = read_motion_csv(args.validate) if args.validate is not None else None
        if validation_record is not None:
            check_record_units(validation_record, str(args.validate))
        nyquist = 0.5 / record.sample_time
        if args.cutoff_hz >= nyquist:
            raise InvalidInput(f"--cutoff-hz {args.cutoff_hz:g}: expected a cut-off below the Nyquist frequency "
                               f"{nyquist:g} Hz of {args.data} (sampled every {record.sample_time:g} s)")
        bias, bias_source = None, None
        if args.torque_sampling_bias is not None:
            choice = args.torque_sampling_bias
            if isinstance(choice, str) and choice != "drives" and not Path(choice).is_file():
                raise InvalidInput(f"--torque-sampling-bias {choice}: no such scenario file")
            bias, bias_source = sampling_bias_values(choice)
        result = identify(record, method=args.method, cutoff_hz=args.cutoff_hz, max_condition=args.max_condition,
                          consistent=args.consistent, torque_acceleration_bias=bias)
    except ValueError as exc:
        raise InvalidInput(str(exc)) from None
    problem = check_fit(result, record, str(args.data))
    if problem is not None:
        raise RunFailed(f"identification refused, no parameter file written: {problem}")
    try:
        validation = (validate(result, validation_record, args.cutoff_hz, torque_acceleration_bias=bias)
                      if validation_record is not None else None)
        extra = {}
        if bias is not None:
            extra["torque_sampling_correction"] = {"bias_Nm_per_rad_s2": bias, "source": bias_source}
        if validation is not None and args.consistent:
            check = validate(result.consistent_model(), validation_record, args.cutoff_hz,
                             torque_acceleration_bias=bias)
            extra["relative_rms_error_consistent_model"] = check.relative_rms_error.tolist()
    except ValueError as exc:
        raise InvalidInput(str(exc)) from None
    try:
        paths = write_identification_outputs(out_dir, result, validation, extra)
    except OSError as exc:
        raise InvalidInput(describe_os_error(exc, f"--out {str(out_dir)!r}")) from None
    text = (f"identified {result.base.count} base parameters ({result.estimate.method}) from {record.samples} "
            f"samples ({record.duration:.3g} s); condition number {result.estimate.condition_number:.3g}; ")
    if validation is not None:
        errors = ", ".join(f"{100 * e:.2f}" for e in validation.relative_rms_error)
        text += f"validation relative RMS error per joint [%]: {errors}; "
    text += "wrote " + ", ".join(str(p) for p in paths.values())
    print(text, file=sys.stderr)
    if validation is not None:
        print(json.dumps({"relative_rms_error": validation.relative_rms_error.tolist()}))
    return EXIT_OK
