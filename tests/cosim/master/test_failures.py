"""A failing FMU stops the run cleanly; wiring mistakes are clear ValueErrors before anything runs."""
import numpy as np
import pytest

from cosim.master import Master, MasterConfigError, MemorySink, SimulationError
from cosim_fmu_models import build_test_fmu


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("cosim_fmus")
    return {m: build_test_fmu(m, d) for m in ("integrator", "sampler", "faulty")}


def _run_faulty(fmus, engine, mode, debug_logging=True):
    m = Master(0.1, engine=engine)
    m.add_fmu("ok", fmus["integrator"])
    m.add_fmu("bad", fmus["faulty"], start_values={"fail_time": 0.5, "mode": mode}, debug_logging=debug_logging)
    sink = MemorySink()
    m.add_recorder(["bad.y", "ok.clock"], 0.1, sink, block_rows=2)
    m.initialize(1.0)
    with pytest.raises(SimulationError) as info:
        m.run()
    m.close()
    return info.value, sink


@pytest.mark.parametrize("engine", ("native", "python"))
@pytest.mark.parametrize("mode, time, status", [(1, 0.4, "fmi2Discard"), (4, 0.4, "fmi2Fatal")])
def test_error_status_names_component_time_and_log(fmus, engine, mode, time, status):
    err, sink = _run_faulty(fmus, engine, mode)
    assert err.component == "bad"
    assert err.time == pytest.approx(time)
    assert status in err.reason and "fmi2DoStep" in err.reason
    expected_log = "solver diverged at t=0.500000" if mode == 1 else "model exploded at t=0.500000"
    assert any(expected_log in msg for msg in err.messages)
    # everything recorded up to the failure was handed to the sink
    assert np.allclose(sink.column("time"), [0.0, 0.1, 0.2, 0.3, 0.4], atol=1e-12)
    assert np.allclose(sink.column("bad.y")[1:], [0.1, 0.2, 0.3, 0.4], atol=1e-12)


@pytest.mark.parametrize("engine", ("native", "python"))
@pytest.mark.parametrize("mode, text", [(2, "nan"), (3, "inf")])
def test_non_finite_output_stops_the_run(fmus, engine, mode, text):
    err, sink = _run_faulty(fmus, engine, mode)
    assert err.component == "bad" and err.time == pytest.approx(0.5)
    assert f"output 'y' is {text}" in str(err)
    assert sink.column("time")[-1] == pytest.approx(0.4)


def test_without_logging_the_error_says_how_to_get_the_log(fmus):
    err, _ = _run_faulty(fmus, "native", 1, debug_logging=False)
    assert "debug_logging=True" in str(err)


def test_task_exception_becomes_simulation_error(fmus):
    m = Master(0.1)
    m.add_fmu("a", fmus["integrator"])

    def broken(t):
        if t > 0.25:
            raise ZeroDivisionError("oops")

    m.add_task(broken, 0.1, name="controller")
    m.initialize(1.0)
    with pytest.raises(SimulationError, match=r"controller at t = 0.3 s: task raised ZeroDivisionError: oops"):
        m.run()
    m.close()


@pytest.mark.parametrize("build, match", [
    (lambda m, f: m.add_fmu("a", f["integrator"], start_values={"nope": 1.0}), "has no variable 'nope'"),
    (lambda m, f: m.add_fmu("a", f["integrator"], start_values={"k": "2"}), r"expected a finite number.*got '2'"),
    (lambda m, f: m.add_fmu("a", f["sampler"], start_values={"offset": 1.5}), "expected an integer"),
    (lambda m, f: m.add_fmu("a", f["integrator"], step=0.15), r"integer multiple of the base step 0.1 s, got 0.15"),
    (lambda m, f: m.add_fmu("a.b", f["integrator"]), "without dots"),
    (lambda m, f: m.add_fmu("a", "missing.fmu"), "does not exist"),
    (lambda m, f: m.add_task(print, 0.25), "period of task 'print'"),
    (lambda m, f: m.add_task(print, 0.2, phase=0.2), "less than its period"),
])
def test_configuration_errors_are_value_errors(fmus, build, match):
    m = Master(0.1)
    with pytest.raises(MasterConfigError, match=match):
        build(m, fmus)
    assert issubclass(MasterConfigError, ValueError)


def test_connection_errors(fmus):
    m = Master(0.1)
    m.add_fmu("a", fmus["integrator"])
    m.add_fmu("s", fmus["sampler"])
    m.add_variable("ctrl.flag", "Boolean", False)
    with pytest.raises(MasterConfigError, match="has no variable 'q'"):
        m.connect("a.q -> s.u")
    with pytest.raises(MasterConfigError, match="an input as destination"):
        m.connect("a.y -> s.y")
    with pytest.raises(MasterConfigError, match="an output as source"):
        m.connect("a.u -> s.u")
    with pytest.raises(MasterConfigError, match="matching types.*Real.*Integer"):
        m.connect("a.y -> s.i_in")
    with pytest.raises(MasterConfigError, match="matching types.*Boolean.*Real"):
        m.connect("ctrl.flag -> a.u")
    with pytest.raises(MasterConfigError, match="form 'a.x -> b.y'"):
        m.connect("a.y => s.u")
    m.connect("a.y -> s.u")
    with pytest.raises(MasterConfigError, match="already connected"):
        m.connect("a.clock -> s.u")
    with pytest.raises(MasterConfigError, match="matches no FMU output"):
        m.add_recorder(["zz.*"], 0.1, MemorySink())
