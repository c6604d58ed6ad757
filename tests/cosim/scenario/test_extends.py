"""``extends``: a scenario that says only what differs from another (cosim/scenario/inherit.py)."""
from __future__ import annotations

import json
import shutil
import textwrap
from pathlib import Path

import pytest

from cosim.cli import main
from cosim.scenario import ScenarioError, load_scenario
from cosim.scenario.inherit import key_lines

ROOT = Path(__file__).resolve().parents[3]
MAIN_JOB = ROOT / "scenarios" / "iso9283.toml"
LONG_FORMS = ROOT / "tests" / "long_forms"
LONG_MAIN_JOB = LONG_FORMS / "iso9283.toml"  # the main job with the whole cell written out
SHORT = ROOT / "examples" / "my_controller_iso9283.toml"


def _strip(data: dict) -> dict:
    return {k: v for k, v in data.items() if k != "scenario"}


def _long_form(tmp_path: Path, *, modes: str | None = None) -> Path:
    """The main job in its long form (the whole cell written out, no extends) with the example's
    [controller] class added (and its built-in ``modes`` replaced by ``modes``), next to a copy
    of the controller's file."""
    shutil.copy(ROOT / "examples" / "pd_gravity_controller.py", tmp_path)
    text = LONG_MAIN_JOB.read_text()
    assert "extends" not in text
    text = text.replace('[controller]\n', '[controller]\nclass = "pd_gravity_controller.py:PDGravity"\n'
                                        'parameters = { bandwidth_hz = 3.0, model_feedforward = true }\n', 1)
    assert text.count("pd_gravity_controller.py:PDGravity") == 1
    if modes is not None:
        text = text.replace('modes = ["standard", "model_based", "model_based_elastic"]', modes, 1)
        assert modes in text
    path = tmp_path / "long.toml"
    path.write_text(text)
    return path


def test_the_example_is_ten_lines_at_most():
    assert len(SHORT.read_text().splitlines()) <= 10


def test_short_form_validates_to_the_long_form(tmp_path):
    """The ten-line example and the main job copied out with the same [controller] class added
    validate to the same document (every value, defaults and SI conversion included)."""
    short, long = load_scenario(SHORT), load_scenario(_long_form(tmp_path))
    assert short.name == "my_controller_iso9283" and short.job.name == long.job.name == "iso9283"
    assert _same_but_bus(_strip(short.data), _strip(long.data))  # the long form writes the 400 us cycle out
    # the base's relative FMU/URDF paths were made absolute against the base's folder
    assert short.raw["scenario"]["job"] == "iso9283" and "extends" not in short.raw


def test_short_form_runs_with_the_long_forms_figures(tmp_path):
    """The example runs (built-in modes and the user's controller side by side); the user's mode
    gives, digit for digit, the figures of the same controller in the long form run alone."""
    out_short = tmp_path / "short"
    rc_short = main(["run", str(SHORT), "--out", str(out_short), "--quiet"])
    out_long = tmp_path / "long"
    rc_long = main(["run", str(_long_form(tmp_path, modes="modes = []")), "--out", str(out_long), "--quiet"])
    short = json.loads((out_short / "summary.json").read_text())
    long = json.loads((out_long / "summary.json").read_text())
    assert set(short["modes"]) == {"standard", "model_based", "model_based_elastic", "PDGravity"}
    assert set(long["modes"]) == {"PDGravity"}
    mine_short, mine_long = short["modes"]["PDGravity"], long["modes"]["PDGravity"]
    for key in ("tcp_error_max_mm", "tcp_error_rms_mm", "tcp_error_max_noise_free_mm"):
        assert mine_short[key] == mine_long[key] and mine_short[key] > 0
    assert mine_short.get("verdict") == mine_long.get("verdict")
    assert rc_long == (0 if mine_long.get("verdict", "ok") == "ok" else rc_long)
    assert rc_short in (0, 4, 5) and rc_long in (0, 4, 5)


def _write(folder: Path, name: str, text: str) -> Path:
    path = folder / name
    path.write_text(textwrap.dedent(text).lstrip())
    return path


def test_error_in_an_inherited_key_names_the_base_file_and_line(tmp_path):
    base = _write(tmp_path, "base.toml", """
        extends = "iso9283"

        [scenario]
        name = "base"

        [controller]
        period = "-400 us"
        """)
    derived = _write(tmp_path, "derived.toml", """
        extends = "base.toml"
        [scenario]
        name = "derived"
        """)
    with pytest.raises(ScenarioError) as info:
        load_scenario(derived)
    err = info.value
    assert err.file == base.resolve() and err.key == "controller.period" and err.line == 7
    assert err.inherited_by == derived.resolve()
    assert str(err).startswith(f"{base.resolve()}: controller.period: ")
    assert str(err).endswith(f"(line 7, inherited by {derived.resolve()})")


def test_error_in_the_derived_file_names_it_and_its_line(tmp_path):
    derived = _write(tmp_path, "derived.toml", """
        extends = "iso9283"
        [scenario]
        name = "derived"
        [tracker]
        nonsense = 3
        """)
    with pytest.raises(ScenarioError) as info:
        load_scenario(derived)
    assert info.value.file == derived.resolve() and info.value.line == 5 and info.value.inherited_by is None
    assert "unknown key" in str(info.value)


def test_a_value_of_the_main_job_named_by_its_line():
    """Without extends too, an error names the line of the key (here: a key of the main job
    made invalid by an override of the file's text)."""
    lines = key_lines(MAIN_JOB.read_text())
    number = lines[("controller", "settle_time")]
    assert MAIN_JOB.read_text().splitlines()[number - 1].lstrip().startswith("settle_time")


@pytest.mark.parametrize("text, problem", [
    ('extends = "no_such_scenario"\n', "no such scenario"),
    ('extends = 3\n', "expected the path of a scenario"),
    ('extends = "loop.toml"\n', "circular extends"),
])
def test_bad_extends_is_one_clear_error(tmp_path, text, problem, capsys):
    path = tmp_path / "loop.toml"
    path.write_text(text)
    assert main(["run", str(path), "--out", str(tmp_path / "out")]) == 2
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and "loop.toml: extends: " in err and problem in err


def test_a_copy_named_like_its_base_extends_the_projects_base(tmp_path):
    """scenarios/iso9283_rigid.toml copied to cell.toml still extends the project's cell, not itself."""
    copy = tmp_path / "cell.toml"
    copy.write_text((ROOT / "scenarios" / "iso9283_rigid.toml").read_text(encoding="utf-8"), encoding="utf-8")
    assert load_scenario(copy).data == load_scenario(ROOT / "scenarios" / "iso9283_rigid.toml").data


def test_arrays_replace_and_tables_merge(tmp_path):
    derived = _write(tmp_path, "derived.toml", """
        extends = "iso9283"
        [scenario]
        name = "derived"
        [controller]
        compute_budget = "150 us"
        [record]
        signals = ["drive1.current_demand"]
        """)
    base, mine = load_scenario(MAIN_JOB), load_scenario(derived)
    assert mine.data["controller"]["compute_budget"] == pytest.approx(150e-6)
    assert mine.data["controller"]["period"] == base.data["controller"]["period"]
    assert mine.data["controller"]["modes"] == base.data["controller"]["modes"]
    assert mine.data["record"]["signals"] == ["drive1.current_demand"] != base.data["record"]["signals"]
    assert mine.data["record"]["period"] == base.data["record"]["period"]
    assert mine.data["fmus"] == base.data["fmus"]


def test_key_lines_of_arrays_of_tables_and_multiline_values():
    lines = key_lines(textwrap.dedent('''
        top = [
          1,
          2,
        ]
        [[fmus]]
        name = "a"
        [[fmus]]
        name = "b"
        [fmus.parameters]
        k = """x
        y = 3
        """
        m = 1
        [a."b.c"]
        d = {e = 1}
        ''').lstrip())
    assert lines[("top",)] == 1 and lines[("fmus",)] == 5 and lines[("fmus", 0, "name")] == 6
    assert lines[("fmus", 1, "name")] == 8 and lines[("fmus", 1, "parameters", "k")] == 10
    assert lines[("fmus", 1, "parameters", "m")] == 13 and ("fmus", 1, "parameters", "y") not in lines
    assert lines[("a", "b.c", "d")] == 15


# --- the cell's defaults (scenarios/cell.toml, scenarios/cell_elastic.toml) ----------------------

CELL = ROOT / "scenarios" / "cell.toml"
CELL_ELASTIC = ROOT / "scenarios" / "cell_elastic.toml"


@pytest.mark.parametrize("name", sorted(p.stem for p in LONG_FORMS.glob("*.toml")))
def test_long_forms_validate_to_the_project_scenarios(name):
    """tests/long_forms/ holds project scenarios with the whole cell written out (for the tests
    that edit the cell's text): each validates to the same document as its short form."""
    long, short = load_scenario(LONG_FORMS / f"{name}.toml"), load_scenario(ROOT / "scenarios" / f"{name}.toml")
    assert "extends" not in (LONG_FORMS / f"{name}.toml").read_text()
    assert long.name == short.name and long.job.name == short.job.name
    assert _same_but_bus(long.data, short.data)


def _same_but_bus(a: dict, b: dict) -> bool:
    """Equal documents, the [fieldbus] tables compared as the bus configuration they give (a long
    form writes the default cycle_time_us = 400 of fieldbus/powerlink_defaults.toml out)."""
    from fieldbus import FieldbusConfig

    rest = {k: v for k, v in a.items() if k != "fieldbus"} == {k: v for k, v in b.items() if k != "fieldbus"}
    return rest and FieldbusConfig.from_dict(a["fieldbus"]) == FieldbusConfig.from_dict(b["fieldbus"])


def test_the_cell_is_a_base_not_a_scenario():
    """scenarios/cell.toml holds the cell and nothing of a job: run alone, one clear error."""
    with pytest.raises(ScenarioError) as info:
        load_scenario(CELL)
    assert info.value.key == "scenario" and "missing required table" in str(info.value)


def test_the_elastic_cells_gains_are_the_tuning_rule():
    """The speed-loop gains of scenarios/cell_elastic.toml are fmus.servo_drive.tuning's, to the bit."""
    from fmus.servo_drive.tuning import elastic_axis_speed_kp

    doc = load_scenario(MAIN_JOB).raw
    kp = [next(f for f in doc["fmus"] if f["name"] == f"drive{i}")["parameters"]["speed_kp"] for i in range(1, 7)]
    assert kp == [float(x) for x in elastic_axis_speed_kp()]


def test_fmus_merge_by_name(tmp_path):
    """[[fmus]] of a derived file merges into the base's FMU of the same name (its parameters key
    by key); a new name is added after the base's FMUs."""
    derived = _write(tmp_path, "derived.toml", """
        extends = "cell_elastic"
        [scenario]
        name = "derived"
        job = "iso9283"
        [simulation]
        stop_time = "1 s"
        [[fmus]]
        name = "drive2"
        [fmus.parameters]
        speed_tn = 0.02
        [[fmus]]
        name = "plant"
        [fmus.parameters]
        integration_step = 5e-5
        """)
    raw = load_scenario(derived).raw
    names = [f["name"] for f in raw["fmus"]]
    assert names == ["plant"] + [f"drive{i}" for i in range(1, 7)]
    by_name = {f["name"]: f for f in raw["fmus"]}
    assert by_name["plant"]["parameters"] == {"integration_step": 5e-5, "elastic_joints": 1}
    assert by_name["plant"]["builtin"] == "rx130l_plant"
    assert by_name["drive2"]["parameters"] == {"speed_kp": 0.605820290362047, "speed_tn": 0.02}
    assert by_name["drive3"]["parameters"] == {"speed_kp": 0.39502959500596646}


def test_error_in_a_merged_fmu_names_the_derived_line(tmp_path):
    """A wrong parameter given for the base's drive3 (FMU 3 of the merged list, FMU 0 of the
    file) is reported at its own line of the derived file."""
    derived = _write(tmp_path, "derived.toml", """
        extends = "cell"
        [scenario]
        name = "derived"
        job = "iso9283"
        [simulation]
        stop_time = "1 s"
        [[fmus]]
        name = "drive3"
        [fmus.parameters]
        speed_feedforward_gain = 1.0
        """)
    with pytest.raises(ScenarioError) as info:
        load_scenario(derived)
    err = info.value
    assert err.key == "fmus[3].parameters.speed_feedforward_gain" and "set by the job" in str(err)
    assert err.file == derived.resolve() and err.line == 10 and err.inherited_by is None


def test_error_in_a_key_of_the_cell_names_the_cell_file_and_line(tmp_path):
    """A key of scenarios/cell.toml that the derived scenario's job does not take is reported at
    cell.toml and its line there, inherited by the file that was run."""
    derived = _write(tmp_path, "derived.toml", """
        extends = "cell"
        [scenario]
        name = "derived"
        job = "fmus"
        [simulation]
        stop_time = "1 s"
        """)
    with pytest.raises(ScenarioError) as info:
        load_scenario(derived)
    err = info.value
    line = key_lines(CELL.read_text())[("true_robot",)]
    assert err.file == CELL and err.key == "true_robot" and err.line == line
    assert err.inherited_by == derived.resolve() and "unknown key" in str(err)


def test_error_in_the_elastic_cell_two_levels_up_names_its_line(tmp_path):
    """drive4 made a plant FMU by the derived file: the speed_kp that scenarios/cell_elastic.toml
    gives it is no parameter of that FMU; the error names cell_elastic.toml and the line of that
    speed_kp, inherited by the file that was run (three files merged into one FMU entry)."""
    derived = _write(tmp_path, "derived.toml", """
        extends = "cell_elastic"
        [scenario]
        name = "derived"
        job = "iso9283"
        [simulation]
        stop_time = "1 s"
        [[fmus]]
        name = "drive4"
        builtin = "rx130l_plant"
        """)
    with pytest.raises(ScenarioError) as info:
        load_scenario(derived)
    err = info.value
    line = 1 + next(i for i, text in enumerate(CELL_ELASTIC.read_text().splitlines())
                    if text.startswith("speed_kp = 0.06539269976263902"))
    assert err.file == CELL_ELASTIC and err.key == "fmus[4].parameters.speed_kp" and err.line == line
    assert err.inherited_by == derived.resolve() and "unknown key" in str(err)
