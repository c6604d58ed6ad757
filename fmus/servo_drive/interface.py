"""The minimal interface of a drive FMU in the robot cell, and its check.

The cell runs six drive FMUs, one per joint, between the fieldbus (CiA 402 telegrams) and
the plant. Any FMI co-simulation FMU with the variables below can be one of them: the
project's ``servo_drive`` has them all, a user's own drive needs only the required ones.
Names, types, causalities and units are the contract (SI units, joint side); the cell
connects every optional variable the FMU has and leaves out the others.

    from fmus.servo_drive.interface import check_drive_fmu
    report = check_drive_fmu("my_drive.fmu", modes=(8, 10))   # DriveInterfaceError if unusable
    report.present                                            # the optional variables it has

:data:`DRIVE_INTERFACE` is the machine-readable list (shown in docs/how-to/own_drive.md by
:func:`reference_markdown`); :func:`check_drive_fmu` checks a ``modelDescription.xml`` (in an
``.fmu``, a folder or the XML file itself) against it and raises
:class:`DriveInterfaceError` naming the file, the variable and what was expected.
"""
from __future__ import annotations

from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path

INPUT, OUTPUT = "input", "output"
REAL, INTEGER = "Real", "Integer"
#: FMI 3.0 types accepted for each FMI 2.0 type of the contract
_TYPE_FAMILIES = {REAL: ("Real", "Float64", "Float32"),
                  INTEGER: ("Integer", "Int32", "Int16", "Int8", "Int64", "UInt16", "UInt32", "UInt8", "UInt64")}


@dataclass(frozen=True)
class DriveVariable:
    """One variable of the drive interface.

    ``required``: every drive FMU must have it. Otherwise ``needed_for`` says when the
    cell needs it after all: a mode of operation (``"mode 9"``, ``"mode 10"``) or a
    controller feature (``"torque feed-forward"``, ``"velocity feed-forward"``,
    ``"mode switching"``), or ``""`` (always optional: the cell records or reports it
    when present)."""

    name: str
    type: str
    causality: str
    unit: str | None
    required: bool
    meaning: str
    needed_for: tuple[str, ...] = ()
    absent: str = ""  # what the cell does without it


DRIVE_INTERFACE: tuple[DriveVariable, ...] = (
    # required
    DriveVariable("q_meas", REAL, INPUT, "rad", True,
                  "measured angle: the motor angle over the gear ratio, from the plant (q_motor; the joint angle "
                  "of a rigid arm)"),
    DriveVariable("qd_meas", REAL, INPUT, "rad/s", True,
                  "measured speed: the motor speed over the gear ratio, from the plant (qd_motor)"),
    DriveVariable("controlword", INTEGER, INPUT, None, True, "CiA 402 0x6040 controlword, from the fieldbus"),
    DriveVariable("target_position", REAL, INPUT, "rad", True,
                  "CiA 402 0x607A target position (cyclic synchronous position, mode 8)"),
    DriveVariable("tau_out", REAL, OUTPUT, "N.m", True, "joint torque applied to the plant"),
    DriveVariable("statusword", INTEGER, OUTPUT, None, True,
                  "CiA 402 0x6041 statusword, to the controller (its state bits drive the enable sequence)"),
    DriveVariable("position_actual", REAL, OUTPUT, "rad", True, "CiA 402 0x6064 position actual, to the controller"),
    # optional set-points
    DriveVariable("torque_offset", REAL, INPUT, "N.m", False, "CiA 402 0x60B2 torque offset (feed-forward)",
                  ("torque feed-forward",), "a controller that sends torque feed-forward is refused"),
    DriveVariable("velocity_offset", REAL, INPUT, "rad/s", False, "CiA 402 0x60B1 velocity offset (feed-forward)",
                  ("velocity feed-forward",), "a controller that sends a velocity offset is refused"),
    DriveVariable("modes_of_operation", INTEGER, INPUT, None, False,
                  "CiA 402 0x6060 modes of operation: 8 position, 9 velocity, 10 torque (cyclic synchronous)",
                  ("mode 9", "mode 10", "mode switching"), "the drive runs in mode 8 only"),
    DriveVariable("target_velocity", REAL, INPUT, "rad/s", False, "CiA 402 0x60FF target velocity (mode 9)",
                  ("mode 9",), "mode 9 is refused"),
    DriveVariable("target_torque", REAL, INPUT, "N.m", False, "CiA 402 0x6071 target torque (mode 10)",
                  ("mode 10",), "mode 10 is refused"),
    DriveVariable("fault_code", INTEGER, INPUT, None, False,
                  "external fault: 0 none, else the 0x603F code to raise (fieldbus threshold reaction 0x8100)",
                  (), "the fieldbus' fault reaction reaches the drive only as a quick-stop controlword"),
    # optional actual values
    DriveVariable("velocity_actual", REAL, OUTPUT, "rad/s", False, "CiA 402 0x606C velocity actual",
                  (), "the controller sees 0"),
    DriveVariable("torque_actual", REAL, OUTPUT, "N.m", False, "CiA 402 0x6077 torque actual (motor)",
                  (), "the controller sees 0"),
    DriveVariable("error_code", INTEGER, OUTPUT, None, False, "CiA 402 0x603F error code of the active fault",
                  (), "the controller sees 0"),
    DriveVariable("modes_of_operation_display", INTEGER, OUTPUT, None, False,
                  "CiA 402 0x6061 the active mode of operation", ("mode switching",),
                  "the controller sees 8"),
    DriveVariable("current_actual", REAL, OUTPUT, "A", False, "motor current", (), "not recorded"),
    DriveVariable("following_error", REAL, OUTPUT, "rad", False, "the drive's own following error",
                  (), "not recorded"),
)
"""The drive interface, in the order of its table in docs/how-to/own_drive.md."""

BY_NAME: dict[str, DriveVariable] = {v.name: v for v in DRIVE_INTERFACE}
REQUIRED: frozenset[str] = frozenset(v.name for v in DRIVE_INTERFACE if v.required)
OPTIONAL: frozenset[str] = frozenset(v.name for v in DRIVE_INTERFACE if not v.required)


class DriveInterfaceError(ValueError):
    """A drive FMU lacks a variable the cell needs, or has it with the wrong type,
    causality or unit. ``path``, ``variable`` and ``expected`` say which and what."""

    def __init__(self, path: str, variable: str, found: str, expected: str) -> None:
        self.path, self.variable, self.found, self.expected = path, variable, found, expected
        super().__init__(f"{path}: drive FMU variable {variable!r}: {found}; expected {expected}")


@dataclass(frozen=True)
class DriveInterfaceReport:
    """What :func:`check_drive_fmu` found: the model identifier, the optional variables
    present (the cell connects exactly the required ones and these), and notes (e.g. a
    variable without a declared unit, taken to be in the contract's unit)."""

    path: str
    model_identifier: str
    present: frozenset[str]
    notes: tuple[str, ...]

    @property
    def modes(self) -> tuple[int, ...]:
        """The modes of operation this drive can run: 8, plus 9 and 10 when it has their variables."""
        out = [8]
        if "modes_of_operation" in self.present:
            out += [m for m, name in ((9, "target_velocity"), (10, "target_torque")) if name in self.present]
        return tuple(out)


def needed_variables(modes: Iterable[int] = (8,), *, torque_feedforward: bool = False,
                     velocity_feedforward: bool = False) -> frozenset[str]:
    """Names a drive must have for a controller that uses ``modes`` (8, 9, 10) and the
    given feed-forward channels: the required ones plus what those features need."""
    modes = set(modes)
    unknown = modes - {8, 9, 10}
    if unknown:
        raise ValueError(f"modes = {sorted(modes)}: expected modes of operation among 8 (cyclic synchronous "
                         "position), 9 (velocity), 10 (torque)")
    wanted = set()
    if 9 in modes:
        wanted.add("mode 9")
    if 10 in modes:
        wanted.add("mode 10")
    if modes - {8} or len(modes) > 1:
        wanted.add("mode switching")
    if torque_feedforward:
        wanted.add("torque feed-forward")
    if velocity_feedforward:
        wanted.add("velocity feed-forward")
    extra = {v.name for v in DRIVE_INTERFACE if not v.required and wanted.intersection(v.needed_for)}
    return REQUIRED | frozenset(extra)


def reference_markdown() -> str:
    """:data:`DRIVE_INTERFACE` as a Markdown table (the docs site puts it into
    docs/how-to/own_drive.md, mkdocs_hooks.py): name, type and causality, unit, whether it is
    required or what needs it, meaning, and what the cell does without it."""
    rows = ["| variable | type, causality | unit | | meaning | without it |", "|---|---|---|---|---|---|"]
    for v in DRIVE_INTERFACE:
        need = "**required**" if v.required else "optional" + (
            f"; needed for {', '.join(v.needed_for)}" if v.needed_for else "")
        rows.append(f"| `{v.name}` | {v.type} {v.causality} | {v.unit or ''} | {need} | {v.meaning} | {v.absent} |")
    return "\n".join(rows) + "\n"


def _describe(v: DriveVariable) -> str:
    unit = f" in {v.unit}" if v.unit else ""
    return f"a {v.type} {v.causality}{unit} ({v.meaning})"


def check_drive_fmu(path: str | Path, modes: Iterable[int] = (8,), *, torque_feedforward: bool = False,
                    velocity_feedforward: bool = False) -> DriveInterfaceReport:
    """Check that the drive FMU at ``path`` (``.fmu``, unpacked folder or
    ``modelDescription.xml``) can be a drive of the cell for a controller using ``modes``
    and the given feed-forward channels.

    Every variable of :data:`DRIVE_INTERFACE` the FMU declares must have the contract's
    type (FMI 2.0 Real/Integer or an FMI 3.0 float/integer type), causality and, if it
    declares one, unit; the required ones and those the controller needs must exist.
    Raises :class:`DriveInterfaceError` at the first problem (in the order of
    :data:`DRIVE_INTERFACE`), naming the file, the variable and what was expected.
    """
    import fmpy

    shown = str(path)
    if not Path(path).exists():
        raise DriveInterfaceError(shown, "(file)", "the file does not exist",
                                  "an FMU (.fmu), an unpacked FMU folder or a modelDescription.xml")
    try:
        md = fmpy.read_model_description(str(path), validate=False)
    except Exception as error:  # fmpy raises many kinds (zip, XML, schema): all mean "not an FMU"
        raise DriveInterfaceError(shown, "(modelDescription.xml)", f"unreadable ({type(error).__name__}: {error})",
                                  "an FMI 2.0 or 3.0 model description") from None
    if md.coSimulation is None:
        raise DriveInterfaceError(shown, "(CoSimulation)", "the FMU offers no co-simulation interface",
                                  "an FMI co-simulation FMU (the cell steps its drives at the master's step)")
    needed = needed_variables(modes, torque_feedforward=torque_feedforward, velocity_feedforward=velocity_feedforward)
    variables = {v.name: v for v in md.modelVariables}
    present, notes = set(), []
    for spec in DRIVE_INTERFACE:
        var = variables.get(spec.name)
        if var is None:
            if spec.name in needed:
                why = "required" if spec.required else "needed for " + " / ".join(spec.needed_for)
                raise DriveInterfaceError(shown, spec.name, f"missing ({why})", _describe(spec))
            continue
        if var.type not in _TYPE_FAMILIES[spec.type]:
            raise DriveInterfaceError(shown, spec.name, f"declared as {var.type}", _describe(spec))
        if var.causality != spec.causality:
            raise DriveInterfaceError(shown, spec.name, f"has causality {var.causality!r}", _describe(spec))
        unit = var.unit or (var.declaredType.unit if var.declaredType is not None else None)
        if spec.unit is not None:
            if unit is None:
                notes.append(f"{spec.name}: no unit declared, taken as {spec.unit}")
            elif unit != spec.unit:
                raise DriveInterfaceError(shown, spec.name, f"has unit {unit!r}", _describe(spec))
        if not spec.required:
            present.add(spec.name)
    identifier = md.coSimulation.modelIdentifier
    return DriveInterfaceReport(shown, identifier, frozenset(present), tuple(notes))
