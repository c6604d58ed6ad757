"""Scenario files are validated before anything runs: each mistake is a ScenarioError
(a ValueError) naming the file, the key path, the value given and what was expected."""

import pytest

from cosim.cli import main
from cosim.scenario import ScenarioError, load_scenario

GOOD = """
connections = ["a.y -> s.u"]

[scenario]
name = "chain"
job = "fmus"

[simulation]
stop_time = 1.0
macro_step = "100 ms"

[[fmus]]
name = "a"
path = "Integrator.fmu"
[fmus.parameters]
k = 2.0

[[fmus]]
name = "s"
path = "Sampler.fmu"
step = 0.2
[fmus.parameters]
offset = 3

[record]
period = 0.1
signals = ["a.y", "s.*"]
"""


@pytest.fixture
def write(fmu_workdir):
    def _write(text: str):
        path = fmu_workdir / "scenario.toml"
        path.write_text(text)
        return path
    return _write


def test_good_scenario_is_normalized(write):
    s = load_scenario(write(GOOD))
    assert s.name == "chain" and s.job.name == "fmus"
    sim = s.data["simulation"]
    assert sim["macro_step"] == pytest.approx(0.1) and sim["coupling"] == "jacobi" and sim["engine"] == "auto"
    assert s.data["fmus"][0]["path"].is_absolute() and s.data["fmus"][1]["step"] == 0.2
    assert s.data["record"]["file"] == "timeseries"  # -> timeseries.parquet (or .csv with --timeseries csv)


CASES = [
    # (replace this, with that), key path, words expected in the message
    (('job = "fmus"', 'job = "fmus"\ncolour = "red"'), "scenario.colour", "unknown key; expected one of the keys name"),
    (('job = "fmus"', 'job = "iso"'), "scenario.job", "one of the registered job types"),
    (('name = "chain"', 'name = "my chain"'), "scenario.name", "of letters, digits"),
    (('macro_step = "100 ms"', 'macro_step = "100 mm"'), "simulation.macro_step", "a number in s or a string like '400 us'"),
    (('macro_step = "100 ms"', 'macro_step = -0.1'), "simulation.macro_step", "> 0"),
    (('macro_step = "100 ms"', 'macro_step = true'), "simulation.macro_step", "got True"),
    (('stop_time = 1.0', 'stop_time = 1.05'), "simulation.stop_time", "integer multiple of macro_step"),
    (('stop_time = 1.0\n', ''), "simulation.stop_time", "missing required key"),
    (('path = "Integrator.fmu"', 'path = "Missing.fmu"'), "fmus[0].path", "does not exist"),
    (('path = "Integrator.fmu"', 'path = "Integrator.zip"'), "fmus[0].path", "not a .fmu file"),
    (('path = "Integrator.fmu"', 'builtin = "no_such_fmu"\npath = "Integrator.fmu"'), "fmus[0]",
     "exactly one of the keys path, builtin"),
    (('name = "a"', 'name = "s"'), "fmus[1].name", "a unique instance name"),
    (('step = 0.2', 'step = 0.25'), "fmus[1].step", "integer multiple of macro_step"),
    (('step = 0.2', 'step = "0.2 s"\nstep_size = 1'), "fmus[1].step_size", "unknown key"),
    (('k = 2.0', 'k = "fast"'), "fmus[0].parameters.k", "a finite number"),
    (('k = 2.0', 'Kp = 2.0'), "fmus[0].parameters.Kp", "a variable of Integrator.fmu (parameters: k, y0)"),
    (('offset = 3', 'offset = 3.5'), "fmus[1].parameters.offset", "an integer"),
    (('["a.y -> s.u"]', '["a.z -> s.u"]'), "connections[0]", "unknown variable 'z'"),
    (('["a.y -> s.u"]', '["a.y -> t.u"]'), "connections[0]", "unknown instance 't'"),
    (('["a.y -> s.u"]', '["a.y -> s.i_in"]'), "connections[0]", "matching types"),
    (('["a.y -> s.u"]', '["s.u -> a.u"]'), "connections[0]", "an output as source"),
    (('["a.y -> s.u"]', '["a.y -> s.u", "a.clock -> s.u"]'), "connections[1]", "second source"),
    (('["a.y -> s.u"]', '["a.y => s.u"]'), "connections[0]", "'instance.output -> instance.input'"),
    (('period = 0.1', 'period = 0.15'), "record.period", "integer multiple of macro_step"),
    (('["a.y", "s.*"]', '["a.y", "q.*"]'), "record.signals[1]", "a pattern matching"),
    (('["a.y", "s.*"]', '["a.yy"]'), "record.signals[0]", "unknown variable 'yy'"),
    (('["a.y", "s.*"]', '[]'), "record.signals", "at least 1 items"),
]


@pytest.mark.parametrize("edit, key, words", CASES, ids=[c[1] + ":" + c[0][1][:20] for c in CASES])
def test_mistake_names_file_key_and_expectation(write, edit, key, words):
    old, new = edit
    assert old in GOOD
    path = write(GOOD.replace(old, new, 1))
    with pytest.raises(ScenarioError) as info:
        load_scenario(path)
    err = info.value
    assert isinstance(err, ValueError)
    assert err.file == path.resolve() and err.key == key
    assert str(err).startswith(f"{path.resolve()}: {key}: ")
    assert words in str(err)


def test_toml_trap_top_level_key_after_a_table_is_explained(write):
    text = GOOD.replace('connections = ["a.y -> s.u"]\n', "").replace(
        "offset = 3", 'offset = 3\nconnections = ["a.y -> s.u"]')
    with pytest.raises(ScenarioError, match="before the first \\[table\\] header") as info:
        load_scenario(write(text))
    assert info.value.key == "fmus[1].parameters.connections"


def test_toml_syntax_error(write):
    with pytest.raises(ScenarioError, match="expected valid TOML"):
        load_scenario(write("[scenario\nname = 1"))


def test_run_command_rejects_invalid_file_before_running(write, tmp_path, capsys):
    path = write(GOOD.replace('["a.y -> s.u"]', '["a.q -> s.u"]'))
    out = tmp_path / "results"
    assert main(["run", str(path), "--out", str(out), "--quiet"]) == 2
    assert "connections[0]" in capsys.readouterr().err
    assert not out.exists()  # nothing ran, nothing written
