"""The generated tables of the docs page ``reference/verdicts.md`` (put in by mkdocs_hooks.py).

Each table is built from the code that decides: the exit codes from
:data:`cosim.results.exits.EXIT_CODES`, the violation kinds and the verdict each gives from
:data:`cosim.cell.verdict.VIOLATION_KINDS` (CiA 402 codes and units from
:data:`cosim.cell.protection.KINDS`), the drives' protection limits and stop reactions from the
start values every servo-drive FMU gets (:func:`fmus.servo_drive.params.drive_start_values`,
i.e. ``fmus/servo_drive/drive_params.toml`` with the robot's own numbers) and the plant's end
stops from ``robot/rx130l_params.toml``. :func:`fill` replaces each marker line of the page
(:data:`MARKERS`) with its table.
"""
from __future__ import annotations

from collections.abc import Callable


def _cell(text: str) -> str:
    return str(text).replace("|", "\\|").replace("\n", " ")


def exit_codes_markdown() -> str:
    """The table of every exit code of ``python -m cosim``."""
    from cosim.results.exits import EXIT_CODES

    lines = ["| exit code | name | when | `summary.json` |", "|---|---|---|---|"]
    lines += [f"| {code} | {name} | {_cell(when)} | {_cell(summary)} |" for code, name, when, summary in EXIT_CODES]
    return "\n".join(lines)


def violation_kinds_markdown() -> str:
    """The table of every violation ``kind``: the verdict it gives, its 0x603F code and unit."""
    from cosim.cell.protection import KINDS
    from cosim.cell.verdict import VIOLATION_KINDS

    codes = {"current_limit": (None, "A"), "fault_reaction": ("0x8100 (drive side)", "counts"),
             "end_stop": (None, "rad/s")}
    lines = ["| `kind` | verdict | 0x603F | unit of `value` | what happened |", "|---|---|---|---|---|"]
    for kind, (verdict, text) in VIOLATION_KINDS.items():
        code, unit = (KINDS[kind][0], KINDS[kind][1]) if kind in KINDS else codes.get(kind, (None, None))
        lines.append(f"| `{kind}` | `{verdict}` | {code or ''} | {unit or ''} | {_cell(text)} |")
    return "\n".join(lines)


#: (FMU parameter, CiA 402 object, unit, what the drive does at the limit)
_DRIVE_LIMITS = (
    ("torque_limit", "0x6072", "N·m", "clamps the commanded torque"),
    ("current_limit", "0x6073", "A", "clamps the current"),
    ("rated_current", "0x6075", "A", "I2t: derates the current limit to it after peak_current_time at the peak"),
    ("peak_current_time", "", "s", "I2t: how long the peak current may flow from a cold state"),
    ("max_motor_speed", "0x6080", "rad/s", "fault 0x8400, fault reaction"),
    ("position_limit_min", "0x607D", "rad", "fault 0x8612, fault reaction"),
    ("position_limit_max", "0x607D", "rad", "fault 0x8612, fault reaction"),
    ("following_error_window", "0x6065", "rad", "fault 0x8611 after following_error_time, fault reaction"),
    ("following_error_time", "0x6066", "s", "time-out of the following-error window"),
    ("quick_stop_deceleration", "0x6085", "rad/s²", "ramp of a quick stop (controlword, controller stop)"),
    ("fault_reaction_deceleration", "", "rad/s²", "ramp of a fault reaction; then the brake holds the axis"),
)


def _number(x: float) -> str:
    return f"{x:.4g}"


def drive_protection_markdown() -> str:
    """The drives' protection limits and stop ramps per axis (joint side), and the plant's end stops."""
    from fmus.servo_drive.params import drive_start_values
    from robot.parameters import load_parameters

    axes = [drive_start_values(axis) for axis in range(1, 7)]
    head = "| FMU parameter | object | unit | axis 1 | axis 2 | axis 3 | axis 4 | axis 5 | axis 6 | at the limit |"
    lines = [head, "|---|---|---|" + "---|" * 7]
    for name, obj, unit, reaction in _DRIVE_LIMITS:
        values = " | ".join(_number(float(a[name])) for a in axes)
        lines.append(f"| `{name}` | {obj} | {unit} | {values} | {reaction} |")
    robot = load_parameters()
    for name, stops in (("end_stop_lower", robot.end_stop_lower), ("end_stop_upper", robot.end_stop_upper)):
        values = " | ".join(_number(float(x)) for x in stops)
        lines.append(f"| plant `{name}[k]` | | rad | {values} | the link hits the mechanical stop |")
    return "\n".join(lines)


#: marker line of docs/reference/verdicts.md -> the function building the table in its place
MARKERS: dict[str, Callable[[], str]] = {
    "<!-- generated: exit codes (cosim/results/exits.py) -->": exit_codes_markdown,
    "<!-- generated: violation kinds (cosim/cell/verdict.py) -->": violation_kinds_markdown,
    "<!-- generated: drive protection (fmus/servo_drive/drive_params.toml) -->": drive_protection_markdown,
}


def fill(markdown: str) -> str:
    """``markdown`` with every marker line of :data:`MARKERS` replaced by its table."""
    for marker, build in MARKERS.items():
        if marker not in markdown:
            raise ValueError(f"reference/verdicts.md: the marker {marker!r} is missing")
        markdown = markdown.replace(marker, build())
    return markdown
