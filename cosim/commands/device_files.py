"""``python -m cosim device-files OUT``: the drives' device descriptions and the bus's signal database,
generated from the object dictionary (fieldbus/object_dictionary.toml; docs/reference/object_dictionary.md)."""
from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

NAME = "device-files"
HELP = ("Write the six servo drives' device descriptions, EDS (CiA 306) and POWERLINK XDD (EPSG DS 311), "
        "and the bus's signal database (DBC: every cyclic telegram scaled to rad, rad/s, N m) into OUT, "
        "generated from the object dictionary.")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("out", type=Path, help="folder to write servo_drive_node<N>.eds/.xdd and rx130l_bus.dbc into")
    parser.add_argument("--scenario", type=Path, default=None,
                        help="take the [fieldbus] settings and the drives' numeric [fmus.parameters] from this "
                             "scenario (default: fieldbus/powerlink_defaults.toml and the drive parameter files)")
    parser.add_argument("--reference", type=Path, default=None,
                        help="also rewrite the generated table (axis 1) between the BEGIN/END generated markers "
                             "of this Markdown page (the docs site generates its own: docs/reference/object_dictionary.md)")


def _scenario_inputs(path: Path):
    from cosim.results.exits import CommandError
    from cosim.scenario.errors import ScenarioError
    from cosim.scenario.inherit import resolve
    from fieldbus.config import FieldbusConfig

    try:
        with open(path, "rb") as handle:
            doc = tomllib.load(handle)
    except OSError as exc:
        raise CommandError(f"--scenario {str(path)!r}: cannot read it ({exc.strerror or exc}); expected a scenario TOML file") from None
    except tomllib.TOMLDecodeError as exc:
        raise CommandError(f"--scenario {str(path)!r}: not valid TOML ({exc})") from None
    try:  # a scenario that extends another (scenarios/cell_elastic.toml sets the drives' speed gains)
        doc, _ = resolve(doc, path)
    except ScenarioError as exc:
        raise CommandError(str(exc)) from None
    try:
        config = FieldbusConfig.from_dict(doc.get("fieldbus") or {}, source=str(path))
    except ValueError as exc:
        raise CommandError(str(exc)) from None
    overrides: dict[int, dict[str, float]] = {}
    for fmu in doc.get("fmus") or []:
        name = str(fmu.get("name", ""))
        if fmu.get("builtin") == "servo_drive" and name.startswith("drive") and name[5:].isdigit():
            overrides[int(name[5:])] = {k: v for k, v in (fmu.get("parameters") or {}).items()
                                        if isinstance(v, (int, float)) and not isinstance(v, bool)}
    return config, overrides


def run(args: argparse.Namespace) -> int:
    from cosim.results.exits import CommandError
    from fieldbus.device_files import reference_markdown, to_dbc, to_eds, to_xdd
    from fieldbus.object_dictionary import ObjectDictionaryError
    from fmus.servo_drive.object_dictionary import drive_object_dictionary
    from fmus.servo_drive.params import N_AXES

    config, overrides = _scenario_inputs(args.scenario) if args.scenario else (None, {})
    try:
        ods = [drive_object_dictionary(axis, config, overrides=overrides.get(axis)) for axis in range(1, N_AXES + 1)]
    except ObjectDictionaryError as exc:
        raise CommandError(str(exc)) from None
    try:
        args.out.mkdir(parents=True, exist_ok=True)
        written = []
        for od in ods:
            for suffix, text in ((".eds", to_eds(od)), (".xdd", to_xdd(od))):
                target = args.out / f"servo_drive_node{od.node}{suffix}"
                target.write_text(text, encoding="utf-8", newline="")
                written.append(target)
        dbc = args.out / "rx130l_bus.dbc"
        dbc.write_text(to_dbc(ods), encoding="utf-8")
        written.append(dbc)
    except OSError as exc:
        raise CommandError(f"OUT {str(args.out)!r}: cannot write there ({exc.strerror or exc}); expected a writable folder") from None
    if args.reference:
        _rewrite_reference(args.reference, reference_markdown(ods[0]))
    objects = sum(1 for _ in ods[0])
    entries = sum(1 for _ in ods[0].entries())
    print(f"{args.out}: {len(ods)} drives x (EDS + XDD), {objects} objects / {entries} entries each; "
          f"DBC of {sum(len(od.pdos) for od in ods) + 1} cyclic telegrams + {len(ods)} EMCY")
    return 0


BEGIN, END = "<!-- BEGIN generated: python -m cosim device-files OUT --reference docs/reference/object_dictionary.md -->", \
    "<!-- END generated -->"


def _rewrite_reference(page: Path, table: str) -> None:
    from cosim.results.exits import CommandError

    try:
        text = page.read_text(encoding="utf-8")
    except OSError as exc:
        raise CommandError(f"--reference {str(page)!r}: cannot read it ({exc.strerror or exc})") from None
    if BEGIN not in text or END not in text:
        raise CommandError(f"--reference {str(page)!r}: expected the markers {BEGIN!r} and {END!r}")
    head, rest = text.split(BEGIN, 1)
    _, tail = rest.split(END, 1)
    page.write_text(f"{head}{BEGIN}\n{table}{END}{tail}", encoding="utf-8")
