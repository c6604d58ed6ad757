"""``python -m cosim export-ssp SCENARIO OUT.ssp``: the scenario's FMUs, connections and parameter
values as an SSP 1.0 archive other SSP tools (libcosim, Ecos) load and run as it is (docs/how-to/ssp.md)."""
from __future__ import annotations

import argparse
import sys
from pathlib import Path

NAME = "export-ssp"
HELP = ("Write the scenario's FMUs, connections and parameter values as an SSP 1.0 archive "
        "(SystemStructure.ssd + one .ssv per FMU + the FMUs) that libcosim and Ecos run as it is; FMU inputs "
        "driven by the Python controller and bus are annotated with the master variable that drives them.")

#: Exit codes: 0 written, 2 invalid scenario or output path.
EXIT_OK, EXIT_INVALID = 0, 2


def add_arguments(parser: argparse.ArgumentParser) -> None:
    """SCENARIO and OUT."""
    parser.add_argument("scenario", type=Path, help="scenario TOML file with [[fmus]] tables")
    parser.add_argument("out", type=Path, help="the .ssp file to write")


def run(args: argparse.Namespace) -> int:
    """Validate the scenario, build its FMUs if needed, write the archive; print what it holds."""
    from cosim.scenario import ScenarioError
    from cosim.cell.ssp_export import export_ssp
    from cosim.ssp import SspError, load_ssp

    if args.out.suffix != ".ssp":
        print(f"error: OUT: expected a file name ending in .ssp, got {str(args.out)!r}", file=sys.stderr)
        return EXIT_INVALID
    from cosim.results.exits import InvalidInput

    try:
        out = export_ssp(args.scenario, args.out)
        system = load_ssp(out)
    except (ScenarioError, SspError) as exc:
        print(f"error: {exc}", file=sys.stderr)
        return EXIT_INVALID
    except OSError as exc:  # the archive cannot be written there (named by the user's path, not a temporary one)
        raise InvalidInput(f"OUT {str(args.out)!r}: cannot write the archive ({exc.strerror or type(exc).__name__}); expected a "
                           f"writable file path") from None
    print(f"{out}: system {system.name!r}: {len(system.fmus)} FMUs, {len(system.connections)} connections between "
          f"them, {len(system.inputs_connections)} FMU inputs driven by the Python side, "
          f"{sum(len(f['parameters']) for f in system.fmus)} parameter values; valid against the SSP 1.0 schema")
    return EXIT_OK
