"""FMI 3.0 co-simulation FMUs in the master, mixed with FMI 2.0 FMUs.

The FMI 3.0 test FMUs are C sources in tests/cosim_fmu_models/fmi3 (arrays, every integer
type, an FMU with event mode, an output clock and a Binary that ends the simulation
itself), built here with the system compiler against fmpy's FMI 3.0 headers. The FMI 2.0
FMUs are the pythonfmu test models. Outputs through ``python -m cosim run`` must equal
``fmpy.simulate_fmu`` at the same step bit for bit.
"""
from __future__ import annotations

import json
import re
import zipfile

import numpy as np
import pytest
from fmpy import read_model_description, simulate_fmu
from fmpy.validation import validate_fmu

from cosim.cli import main
from cosim.master import Master, MasterConfigError, MemorySink, SimulationError
from cosim.results import read_csv
from cosim_fmu_models.fmi3 import MODELS, build_fmi3_test_fmu

INTEGER_STARTS = {"i8": -120, "u8": 250, "i16": -32000, "u16": 65000, "i32": -2_000_000_000, "u32": 2_000_000_000,
                  "i64": -1_000_000, "u64": 1_000_000, "b": True, "x": 0.1}


@pytest.fixture(scope="module")
def fmi3_dir(tmp_path_factory):
    folder = tmp_path_factory.mktemp("fmi3_fmus")
    for model in MODELS:
        assert validate_fmu(str(build_fmi3_test_fmu(model, folder))) == []
    return folder


def _toml_value(v):
    return ("true" if v else "false") if isinstance(v, bool) else repr(v)


def _scenario(tmp_path, body: str, step: float, engine: str, stop: float = 0.5, top: str = "",
              name: str = "fmi3.toml") -> str:
    path = tmp_path / name
    path.write_text(f"""{top}
[scenario]
name = "fmi3_mixed"
job = "fmus"

[simulation]
stop_time = {stop}
macro_step = {step}
engine = "{engine}"
{body}""")
    return str(path)


def _fmu_table(name, path, params=None) -> str:
    lines = [f"\n[[fmus]]\nname = \"{name}\"\npath = \"{path.as_posix()}\""]
    if params:
        lines.append(f"[fmus.parameters]")
        lines += [f'"{k}" = {_toml_value(v)}' for k, v in params.items()]
    return "\n".join(lines) + "\n"


@pytest.mark.parametrize("engine", ("native", "python"))
def test_fmi3_fmus_in_a_mixed_scenario_equal_simulate_fmu(fmi3_dir, pythonfmu_models_dir, tmp_path, engine):
    step = 0.01
    arrays_params = {"u[1]": 1.0, "u[2]": -0.5, "u[3]": 2.0, "k[2]": 4.0, "y0": 0.25}
    body = (_fmu_table("a", fmi3_dir / "Arrays3.fmu", arrays_params)
            + _fmu_table("i", fmi3_dir / "Integers3.fmu", INTEGER_STARTS)
            + _fmu_table("f2", pythonfmu_models_dir / "Integrator.fmu", {"u": 3.0})
            + '\n[record]\nperiod = 0.01\nsignals = ["a.*", "i.*", "f2.y"]\n')
    out = tmp_path / "out"
    assert main(["run", _scenario(tmp_path, body, step, engine), "--out", str(out), "--quiet"]) == 0
    columns, ours = read_csv(out / "timeseries.csv")
    assert len(ours) == 51
    for inst, fmu, params in (("a", "Arrays3", arrays_params), ("i", "Integers3", INTEGER_STARTS)):
        names = [c.split(".", 1)[1] for c in columns if c.startswith(inst + ".")]
        assert names, inst
        variables = sorted({re.sub(r"\[.*\]$", "", n) for n in names})
        starts = {}
        for k, v in params.items():  # fmpy takes whole arrays
            base = re.sub(r"\[.*\]$", "", k)
            if base != k:
                md = {m.name: m for m in read_model_description(str(fmi3_dir / f"{fmu}.fmu")).modelVariables}
                starts.setdefault(base, [float(x) for x in md[base].start.split()])
                starts[base][int(k[len(base) + 1:-1]) - 1] = v
            else:
                starts[k] = v
        ref = simulate_fmu(str(fmi3_dir / f"{fmu}.fmu"), stop_time=0.5, step_size=step, output_interval=step,
                           start_values=starts, output=variables)
        assert np.array_equal(ours[:, 0], ref["time"])
        for name in names:
            base = re.sub(r"\[.*\]$", "", name)
            column = ours[:, columns.index(f"{inst}.{name}")]
            expected = ref[base]
            if base != name:  # array element: row-major, 1-based
                index = tuple(int(x) - 1 for x in name[len(base) + 1:-1].split(","))
                expected = expected[(slice(None),) + index]
            assert np.array_equal(column, expected.astype(float)), f"{inst}.{name}"
    # the signals vary (not a trivially constant comparison), every integer type took part
    assert np.ptp(ours[:, columns.index("a.y[3]")]) > 0.9
    assert ours[-1, columns.index("i.o_u32")] == 2_000_000_050
    assert ours[-1, columns.index("i.o_i8")] == -70 and ours[-1, columns.index("i.o_u8")] == (250 + 50) % 256
    assert ours[-1, columns.index("i.o_u16")] == (65000 + 50) % 65536


def test_connections_between_fmi2_and_fmi3(fmi3_dir, pythonfmu_models_dir):
    """FMI 2.0 Real -> Float64 array element, Float32 -> FMI 2.0 Real, Int16 -> FMI 2.0 Integer ->
    Int8, FMI 2.0 Boolean -> Boolean: the applied inputs are the sources' values at t (Jacobi)."""
    m = Master(0.01)
    m.add_fmu("f2", pythonfmu_models_dir / "Integrator.fmu", start_values={"u": 3.0})
    m.add_fmu("a", fmi3_dir / "Arrays3.fmu", start_values={"k[2]": 4.0})
    m.add_fmu("s", pythonfmu_models_dir / "Sampler.fmu", start_values={"offset": -7})
    m.add_fmu("i", fmi3_dir / "Integers3.fmu")
    for c in ("f2.y -> a.u[2]", "a.total -> s.u", "i.o_i16 -> s.i_in", "s.i_out -> i.i8", "s.b_out -> i.b"):
        m.connect(c)
    sink = MemorySink()
    signals = ["f2.y", "a.u[2]", "a.y[2]", "a.total", "s.u", "s.y", "i.o_i16", "s.i_out", "i.i8", "s.b_out", "i.b"]
    m.add_recorder(signals, 0.01, sink)
    m.initialize(0.3)
    m.run()
    m.close()
    d = {name: sink.column(name) for name in signals}
    assert np.array_equal(d["a.u[2]"], d["f2.y"])          # applied from t on
    assert np.ptp(d["f2.y"]) > 0.8
    n = np.arange(len(d["a.y[2]"]) - 1)
    h = (n + 1) * 0.01 - n * 0.01  # the master's step: t_(n+1) - t_n
    expected = d["a.y[2]"][:-1] + 4.0 * d["a.u[2]"][:-1] * h  # y += k u h, same operation order as the C
    assert np.array_equal(d["a.y[2]"][1:], expected)
    assert np.array_equal(d["s.u"], d["a.total"])          # Float32 widened exactly onto the Real bus
    assert np.array_equal(d["s.y"][1:], d["a.total"][:-1])
    assert np.all(d["a.total"] == d["a.total"].astype(np.float32))
    assert np.array_equal(d["i.i8"], d["s.i_out"]) and np.array_equal(d["i.b"], d["s.b_out"])
    assert d["s.i_out"][-1] == d["i.o_i16"][-2] - 7 and d["i.o_i16"][-1] == 30


@pytest.mark.parametrize("engine", ("native", "python"))
@pytest.mark.parametrize("discard", (False, True))
def test_an_fmu_that_ends_itself_ends_the_run_normally(fmi3_dir, pythonfmu_models_dir, tmp_path, engine, discard):
    body = (_fmu_table("e", fmi3_dir / "Ending3.fmu", {"u": 2.0, "discard": discard, "t_end": 0.35})
            + _fmu_table("f2", pythonfmu_models_dir / "Integrator.fmu", {"u": 1.0})
            + '\n[record]\nperiod = 0.02\nsignals = ["e.z", "e.ticks", "e.tick", "e.frame", "f2.y"]\n')
    out = tmp_path / "out"
    assert main(["run", _scenario(tmp_path, body, 0.01, engine, stop=1.0), "--out", str(out), "--quiet"]) == 0
    summary = json.loads((out / "summary.json").read_text())
    assert summary["status"] == "ok"
    assert summary["ended_by"]["instance"] == "e"
    assert summary["ended_by"]["status"] == ("fmi3Discard" if discard else "fmi3OK")
    assert summary["ended_by"]["time"] == pytest.approx(0.35)
    columns, ours = read_csv(out / "timeseries.csv")
    # samples every 0.02 s and one at the end (0.35 s is not on the recorder's grid)
    assert ours[-1, 0] == pytest.approx(0.35) and ours[-2, 0] == pytest.approx(0.34)
    z, ticks = ours[:, columns.index("e.z")], ours[:, columns.index("e.ticks")]
    if not discard:  # fmpy raises on fmi3Discard; with fmi3OK it ends the run the same way
        ref = simulate_fmu(str(fmi3_dir / "Ending3.fmu"), stop_time=1.0, step_size=0.01, output_interval=0.01,
                           start_values={"u": 2.0}, output=["z", "ticks"])
        assert ref["time"][-1] == pytest.approx(0.35)
        picked = np.r_[np.arange(0, 35, 2), 35]
        assert np.array_equal(ours[:, 0], ref["time"][picked])
        assert np.array_equal(z, ref["z"][picked]) and np.array_equal(ticks, ref["ticks"][picked])
    # clock: ticked at the events of steps 5, 10, ...; its column is 1 only right after such an event
    tick = ours[:, columns.index("e.tick")]
    assert set(np.round(ours[tick == 1, 0], 6)) == {0.1, 0.2, 0.3}
    assert np.all(ours[:, columns.index("e.frame")] == 8)      # Binary: its size in bytes
    assert ours[-1, columns.index("f2.y")] == pytest.approx(0.35)  # the FMI 2.0 FMU stepped to the end


def test_binary_bytes_and_ended_by_on_the_master(fmi3_dir):
    m = Master(0.01)
    m.add_fmu("e", fmi3_dir / "Ending3.fmu", start_values={"t_end": 0.1})
    m.initialize(1.0)
    assert m.run() == pytest.approx(0.1)
    assert m.ended_by["instance"] == "e" and m.run() == pytest.approx(0.1)  # nothing more runs
    frame = m.fmus["e"].get_binary("frame")
    assert frame == (10).to_bytes(4, "little") + (2).to_bytes(4, "little")
    m.close()


def test_early_return_is_refused(fmi3_dir):
    m = Master(0.01)
    m.add_fmu("e", fmi3_dir / "Ending3.fmu", start_values={"t_end": 0.05, "early": True})
    m.initialize(1.0)
    with pytest.raises(SimulationError, match="returned early.*earlyReturnAllowed = false"):
        m.run()
    m.close()


def test_a_value_outside_the_destination_type_stops_the_run_naming_it(fmi3_dir, pythonfmu_models_dir):
    m = Master(0.01)
    m.add_fmu("s", pythonfmu_models_dir / "Sampler.fmu", start_values={"offset": 200})
    m.add_fmu("i", fmi3_dir / "Integers3.fmu")
    m.connect("s.i_out -> i.i8")
    m.initialize(1.0)
    with pytest.raises(SimulationError, match=r"variable 'i8': value 200 is outside the range of Int8") as info:
        m.run()
    assert info.value.component == "i" and info.value.time == pytest.approx(0.01)
    m.close()


def test_a_64_bit_value_beyond_the_integer_bus_is_an_error(fmi3_dir):
    m = Master(0.01)
    m.add_fmu("i", fmi3_dir / "Integers3.fmu", start_values={"i64": 2**40})
    with pytest.raises(SimulationError, match=r"'o_i64': value 1099511627776 of a Int64 output does not fit"):
        m.initialize(1.0)
    m.close()


def test_start_values_are_checked_against_the_fmi3_type(fmi3_dir):
    m = Master(0.01)
    with pytest.raises(MasterConfigError, match=r"an integer in \[-128, 127\] for Int8 variable 'i8'"):
        m.add_fmu("i", fmi3_dir / "Integers3.fmu", start_values={"i8": 300})
    with pytest.raises(MasterConfigError, match="has no variable 'u'"):
        m.add_fmu("a", fmi3_dir / "Arrays3.fmu", start_values={"u": 1.0})  # arrays are set per element


def _rewrite(fmi3_dir, tmp_path, model, old, new):
    md = (zipfile.ZipFile(fmi3_dir / f"{model}.fmu").read("modelDescription.xml").decode())
    assert old in md
    return build_fmi3_test_fmu(model, tmp_path, md.replace(old, new))


@pytest.mark.parametrize("interface, words", (
    ('<ModelExchange modelIdentifier="Arrays3"/>', "model exchange interface only"),
    ('<ScheduledExecution modelIdentifier="Arrays3"/>', "scheduled execution interface only"),
))
def test_model_exchange_or_scheduled_execution_only_fmus_are_refused(fmi3_dir, tmp_path, capsys, interface, words):
    fmu = _rewrite(fmi3_dir, tmp_path, "Arrays3",
                   '<CoSimulation modelIdentifier="Arrays3" canHandleVariableCommunicationStepSize="true" '
                   'hasEventMode="false"/>', interface)
    with pytest.raises(MasterConfigError, match=words):
        Master(0.01).add_fmu("a", fmu)
    body = _fmu_table("a", fmu)
    assert main(["run", _scenario(tmp_path, body, 0.01, "auto"), "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "fmi3.toml: fmus[0].path:" in err and words in err
    assert "expected an FMI 2.0 or FMI 3.0 co-simulation FMU" in err
    assert err.count("expected") == 1  # said once, not repeated


def test_clock_and_binary_cannot_be_connected(fmi3_dir, pythonfmu_models_dir, tmp_path, capsys):
    body = _fmu_table("e", fmi3_dir / "Ending3.fmu") + _fmu_table("s", pythonfmu_models_dir / "Sampler.fmu")
    path = _scenario(tmp_path, body, 0.01, "auto", top='connections = ["e.frame -> s.i_in"]', name="bad.toml")
    assert main(["run", path, "--out", str(tmp_path / "o"), "--quiet"]) == 2
    err = capsys.readouterr().err
    assert "bad.toml: connections[0]:" in err and "'frame' is an FMI 3.0 Binary" in err
    m = Master(0.01)
    m.add_fmu("e", fmi3_dir / "Ending3.fmu")
    m.add_fmu("s", pythonfmu_models_dir / "Sampler.fmu")
    m.add_fmu("a", fmi3_dir / "Arrays3.fmu")
    with pytest.raises(MasterConfigError, match="'tick' is an FMI 3.0 Clock"):
        m.connect("e.tick -> s.b_in")
    with pytest.raises(MasterConfigError, match="variables of type String cannot be connected"):
        m.connect("a.label -> s.u")
    with pytest.raises(MasterConfigError, match="'label' is an FMI 3.0 String"):
        Master(0.01).add_fmu("a", fmi3_dir / "Arrays3.fmu", start_values={"label": "x"})
