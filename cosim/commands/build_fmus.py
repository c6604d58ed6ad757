"""``python -m cosim build-fmus``: generate, compile and pack the plant and drive FMUs."""
from __future__ import annotations

import argparse
from pathlib import Path

NAME = "build-fmus"
HELP = ("Generate the C code, compile and pack build/fmus/rx130l_plant.fmu and build/fmus/servo_drive.fmu "
        "(FMI 2.0) and their FMI 3.0 builds in build/fmus/fmi3/ (rebuilt only when their inputs changed).")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """``--out DIR``, ``--force`` and ``--fmi {2,3,both}``."""
    parser.add_argument("--out", type=Path, default=None, metavar="DIR",
                        help="output directory (default: build/fmus in the repository)")
    parser.add_argument("--force", action="store_true", help="rebuild even if nothing changed")
    parser.add_argument("--fmi", choices=("2", "3", "both"), default="both",
                        help="FMI version(s) to build (default both; the jobs run the FMI 2.0 builds)")


def run(args: argparse.Namespace) -> int:
    """Build the FMUs, validate them with fmpy and print one line per FMU."""
    from fmpy.validation import validate_fmu

    from fmus.build import build_fmus

    status = 0
    versions = (2, 3) if getattr(args, "fmi", "both") == "both" else (int(args.fmi),)
    for fmi in versions:
        for name, (path, rebuilt) in build_fmus(args.out, force=args.force, fmi=fmi).items():
            problems = validate_fmu(str(path))
            print(f"{name} (FMI {fmi}.0): {path} ({'built' if rebuilt else 'up to date'}; "
                  f"{'valid' if not problems else 'INVALID: ' + '; '.join(problems)})")
            status |= bool(problems)
    return int(status)
