"""The minimal drive interface (fmus/servo_drive/interface.py): our servo drive satisfies
it in full; deliberately incomplete or wrong drive FMUs are refused with the file, the
variable and what was expected."""
import zipfile
from dataclasses import replace

import pytest

from fmus.build import ensure_fmus
from fmus.fmi2_spec import FmuSpec
from fmus.servo_drive.interface import (DRIVE_INTERFACE, OPTIONAL, REQUIRED, DriveInterfaceError, check_drive_fmu,
                                        needed_variables)
from fmus.servo_drive.spec import servo_drive_spec


def _variant(tmp_path, name, drop=(), change=None):
    """An FMU file whose modelDescription is the servo drive's minus ``drop``, with
    ``change(variable) -> variable`` applied (the binary is irrelevant to the check)."""
    spec = servo_drive_spec()
    variables = [v for v in spec.variables if v.name not in drop]
    if change:
        variables = [change(v) for v in variables]
    kept = {v.name for v in variables}
    variables = [replace(v, depends_on=tuple(n for n in v.depends_on if n in kept)) for v in variables]
    variant = FmuSpec(spec.model_identifier, spec.description, spec.source_files, spec.default_step,
                      spec.default_stop, variables)
    path = tmp_path / f"{name}.fmu"
    with zipfile.ZipFile(path, "w") as zf:
        zf.writestr("modelDescription.xml", variant.model_description_xml())
    return path


def _replace(name, **fields):
    return lambda v: replace(v, **fields) if v.name == name else v


def test_the_servo_drive_has_the_whole_interface():
    report = check_drive_fmu(ensure_fmus()["servo_drive"], modes=(8, 9, 10), torque_feedforward=True,
                             velocity_feedforward=True)
    assert report.present == OPTIONAL and report.notes == ()
    assert report.modes == (8, 9, 10) and report.model_identifier == "servo_drive"


def test_the_interface_lists_are_consistent():
    spec = {v.name: v for v in servo_drive_spec().variables}
    for v in DRIVE_INTERFACE:  # every contract variable is one of the servo drive, same type/causality/unit
        assert (spec[v.name].type, spec[v.name].causality, spec[v.name].unit) == (v.type, v.causality, v.unit), v.name
    assert REQUIRED == {"q_meas", "qd_meas", "controlword", "target_position", "tau_out", "statusword",
                        "position_actual"}
    assert needed_variables((8,)) == REQUIRED
    assert needed_variables((8, 10), torque_feedforward=True) == REQUIRED | {
        "modes_of_operation", "modes_of_operation_display", "target_torque", "torque_offset"}
    with pytest.raises(ValueError, match=r"modes = \[7, 8\]: expected modes of operation among 8"):
        needed_variables((7, 8))


def test_a_minimal_drive_passes_for_csp(tmp_path):
    path = _variant(tmp_path, "minimal", drop=OPTIONAL)
    report = check_drive_fmu(path)
    assert report.present == frozenset() and report.modes == (8,)
    with pytest.raises(DriveInterfaceError, match=r"minimal.fmu: drive FMU variable 'modes_of_operation': "
                                                  r"missing \(needed for mode 9 / mode 10 / mode switching\); "
                                                  r"expected a Integer input"):
        check_drive_fmu(path, modes=(8, 10))
    with pytest.raises(DriveInterfaceError, match="'torque_offset': missing .needed for torque feed-forward.; "
                                                  "expected a Real input in N.m"):
        check_drive_fmu(path, torque_feedforward=True)


@pytest.mark.parametrize("missing", ["tau_out", "q_meas", "statusword", "target_position"])
def test_a_drive_without_a_required_variable_is_refused(tmp_path, missing):
    path = _variant(tmp_path, "incomplete", drop=(missing,))
    with pytest.raises(DriveInterfaceError) as error:
        check_drive_fmu(path)
    assert error.value.variable == missing and str(path) in str(error.value)
    assert f"drive FMU variable {missing!r}: missing (required); expected a " in str(error.value)


def test_wrong_type_causality_and_unit_are_named(tmp_path):
    wrong_type = _variant(tmp_path, "wrong_type", change=_replace("controlword", type="Real", unit=None, min=None,
                                                                    max=None))
    with pytest.raises(DriveInterfaceError, match="wrong_type.fmu: drive FMU variable 'controlword': declared as "
                                                  "Real; expected a Integer input .CiA 402 0x6040"):
        check_drive_fmu(wrong_type)
    wrong_causality = _variant(tmp_path, "wrong_causality", change=_replace("tau_out", causality="local",
                                                                             start=0.0))
    with pytest.raises(DriveInterfaceError, match="'tau_out': has causality 'local'; expected a Real output in N.m"):
        check_drive_fmu(wrong_causality)
    degrees = _variant(tmp_path, "degrees", change=_replace("q_meas", unit="1"))
    with pytest.raises(DriveInterfaceError, match="'q_meas': has unit '1'; expected a Real input in rad"):
        check_drive_fmu(degrees)
    no_unit = _variant(tmp_path, "no_unit", change=_replace("qd_meas", unit=None))
    assert check_drive_fmu(no_unit).notes == ("qd_meas: no unit declared, taken as rad/s",)


def test_not_an_fmu(tmp_path):
    with pytest.raises(DriveInterfaceError, match="does not exist"):
        check_drive_fmu(tmp_path / "nothing.fmu")
    junk = tmp_path / "junk.fmu"
    junk.write_bytes(b"not a zip")
    with pytest.raises(DriveInterfaceError, match=r"junk.fmu: drive FMU variable '\(modelDescription.xml\)': "
                                                  "unreadable"):
        check_drive_fmu(junk)


def test_the_documented_table_is_the_machine_readable_list():
    """docs/how-to/own_drive.md shows the table generated from DRIVE_INTERFACE (mkdocs_hooks.py):
    one row per variable, in order, with its type, causality, unit and whether it is required."""
    import re
    from pathlib import Path

    from fmus.servo_drive.interface import reference_markdown
    from mkdocs_hooks import DRIVE_INTERFACE_MARKER, MARKERS

    page = Path(__file__).resolve().parents[2] / "docs" / "how-to" / "own_drive.md"
    text = MARKERS["how-to/own_drive.md"](page.read_text(encoding="utf-8"))
    assert DRIVE_INTERFACE_MARKER not in text and reference_markdown() in text
    section = text.split("## The minimal interface", 1)[1].split("\n## ", 1)[0]
    rows = re.findall(r"^\| `(\w+)` \| (\w+) (\w+) \| ([^|]*) \| ([^|]*) \|", section, flags=re.M)
    assert [(name, type_, causality, unit.strip() or None, "required" in need) for name, type_, causality, unit, need
            in rows] == [(v.name, v.type, v.causality, v.unit, v.required) for v in DRIVE_INTERFACE]


def test_the_fmi3_build_of_the_servo_drive_passes_too():
    from fmus.build import build_fmu

    path, _ = build_fmu("servo_drive", fmi=3)
    report = check_drive_fmu(path, modes=(8, 9, 10), torque_feedforward=True, velocity_feedforward=True)
    assert report.present == OPTIONAL and report.modes == (8, 9, 10)
