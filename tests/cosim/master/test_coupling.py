"""Coupling semantics of the co-simulation master: who sees which values when.

The FMUs are small pythonfmu models (tests/cosim_fmu_models) so the expected values are
known exactly: the Integrator integrates its held input with forward Euler, the Sampler
outputs at the end of each step the input it was given for that step and the step's
start time. Every case runs on both engines (compiled kernel and Python reference).
"""
import math

import numpy as np
import pytest

from cosim.master import EndSimulation, Master, MasterConfigError, MemorySink
from cosim_fmu_models import build_test_fmu

ENGINES = ("native", "python")


@pytest.fixture(scope="module")
def fmus(tmp_path_factory):
    d = tmp_path_factory.mktemp("cosim_fmus")
    return {m: build_test_fmu(m, d) for m in ("integrator", "sampler", "faulty")}


def _chain(fmus, engine, coupling, sampler_step):
    """ctrl.u (task: u = 1) -> a (Integrator, y0 = 1) -> s (Sampler at sampler_step)."""
    m = Master(0.1, coupling=coupling, engine=engine)
    m.add_fmu("a", fmus["integrator"], start_values={"y0": 1.0})
    m.add_fmu("s", fmus["sampler"], step=sampler_step, start_values={"offset": 3})
    m.add_variable("ctrl.u", "Real", 0.0)
    m.add_variable("ctrl.i", "Integer", 0)
    m.connect("ctrl.u -> a.u")
    m.connect("a.y", "s.u")
    m.connect("ctrl.i -> s.i_in")
    sink = MemorySink()
    m.add_recorder(["a.y", "a.clock", "s.y", "s.t_seen", "s.steps", "s.i_out", "s.b_out", "s.u", "ctrl.u"], 0.1, sink)
    u = {}

    def controller(t):
        u["u"][0] = 1.0
        u["i"][0] = round(t * 10)

    def setup(master):
        u["u"] = master.view(["ctrl.u"], writable=True)
        u["i"] = master.view(["ctrl.i"], writable=True)

    m.add_task(controller, 0.1, setup=setup)
    m.initialize(1.0)
    m.run()
    m.close()
    return sink


@pytest.mark.parametrize("engine", ENGINES)
def test_jacobi_single_rate_sees_outputs_of_the_same_instant(fmus, engine):
    sink = _chain(fmus, engine, "jacobi", 0.1)
    t = sink.column("time")
    assert np.allclose(t, np.arange(11) * 0.1, rtol=0, atol=1e-12)
    # the task writes u = 1 at t = 0, the integrator holds it over [0, 0.1]
    assert np.allclose(sink.column("a.y"), 1.0 + t, atol=1e-12)
    assert np.allclose(sink.column("a.clock"), t, atol=1e-12)
    # Jacobi: s stepping [t, t+h] is given a.y(t); it outputs that value at t + h
    assert np.allclose(sink.column("s.y")[1:], sink.column("a.y")[:-1], atol=1e-12)
    assert np.allclose(sink.column("s.t_seen")[1:], t[:-1], atol=1e-12)
    # a connected input is recorded as the value applied from the sample time on
    assert np.allclose(sink.column("s.u"), sink.column("a.y"), atol=1e-12)
    # Integer: the task's i = round(10 t) reaches s for the step from t; offset 3 is its start value
    assert np.array_equal(sink.column("s.i_out")[1:], np.arange(10) + 3)
    assert np.array_equal(sink.column("s.steps"), np.arange(11))
    assert np.array_equal(sink.column("s.b_out")[1:], np.ones(10))


@pytest.mark.parametrize("engine", ENGINES)
def test_gauss_seidel_later_fmu_sees_the_stepped_output(fmus, engine):
    sink = _chain(fmus, engine, "gauss_seidel", 0.1)
    # s steps after a in the order added: it is given a.y(t + h) for its step [t, t + h]
    assert np.allclose(sink.column("s.y")[1:], sink.column("a.y")[1:], atol=1e-12)
    assert np.allclose(sink.column("a.y"), 1.0 + sink.column("time"), atol=1e-12)


@pytest.mark.parametrize("engine", ENGINES)
def test_multirate_slow_fmu_holds_input_and_publishes_at_its_communication_points(fmus, engine):
    sink = _chain(fmus, engine, "jacobi", 0.2)
    t = sink.column("time")
    steps = sink.column("s.steps")
    # s steps at 0, 0.2, 0.4, ...: its outputs change only when the clock reaches t + 0.2
    assert np.array_equal(steps, np.floor(np.round(t * 10) / 2))
    y = sink.column("s.y")
    for k in range(1, 11):
        last_start = 0.2 * (math.floor(round(t[k] * 10) / 2) - 1)
        if last_start >= 0:
            assert y[k] == pytest.approx(1.0 + last_start, abs=1e-12)
            assert sink.column("s.t_seen")[k] == pytest.approx(last_start, abs=1e-12)
    # the recorded input of the slow FMU is the value it holds over its current step
    held = 1.0 + 0.2 * np.floor(np.round(t * 10) / 2)
    assert np.allclose(sink.column("s.u"), held, atol=1e-12)


@pytest.mark.parametrize("coupling", ("jacobi", "gauss_seidel"))
@pytest.mark.parametrize("sampler_step", (0.1, 0.2, 0.3))
def test_native_and_python_engines_agree_exactly(fmus, coupling, sampler_step):
    a = _chain(fmus, "native", coupling, sampler_step).data
    b = _chain(fmus, "python", coupling, sampler_step).data
    assert a.shape == b.shape == (11, 10)
    assert np.array_equal(a, b)


@pytest.mark.parametrize("engine", ENGINES)
def test_tasks_run_in_priority_order_with_phase_and_see_outputs_at_t(fmus, engine):
    m = Master(0.1, engine=engine)
    m.add_fmu("a", fmus["integrator"], start_values={"k": 2.0})
    m.add_variable("ctrl.u", "Real", 0.0)
    m.connect("ctrl.u -> a.u")
    log = []

    def writer(t):
        m.set_value("ctrl.u", 1.0)
        log.append(("writer", round(t, 9), m.value("a.y")))

    def reader(t):
        log.append(("reader", round(t, 9), m.value("a.y"), m.value("ctrl.u")))

    m.add_task(reader, 0.4, phase=0.2, priority=5, name="reader")
    m.add_task(writer, 0.2, priority=1, name="writer")
    m.initialize(0.8)
    m.run()
    m.close()
    # a.y(t) = 2 * 1 * t once u = 1 from t = 0 on; reader (priority 5) runs after writer at 0.2 and 0.6
    assert log == [
        ("writer", 0.0, 0.0),
        ("writer", 0.2, pytest.approx(0.4)), ("reader", 0.2, pytest.approx(0.4), 1.0),
        ("writer", 0.4, pytest.approx(0.8)),
        ("writer", 0.6, pytest.approx(1.2)), ("reader", 0.6, pytest.approx(1.2), 1.0),
        ("writer", 0.8, pytest.approx(1.6)),
    ]


@pytest.mark.parametrize("engine", ENGINES)
def test_run_can_be_resumed_and_end_early(fmus, engine):
    m = Master(0.1, engine=engine)
    m.add_fmu("a", fmus["integrator"], start_values={"y0": 0.0})
    m.add_variable("ctrl.u", "Real", 1.0)
    m.connect("ctrl.u -> a.u")
    seen = []

    def task(t):
        seen.append(round(t, 9))
        if t > 0.65:
            raise EndSimulation

    m.add_task(task, 0.1, timed=True)
    sink = MemorySink()
    m.add_recorder(["a.y"], 0.2, sink)
    m.initialize(2.0)
    assert m.run(0.3) == pytest.approx(0.3)
    assert m.run(0.5) == pytest.approx(0.5)
    reached = m.run()
    m.close()
    assert reached == pytest.approx(0.7)
    assert seen == [0.0, 0.1, 0.2, 0.3, 0.4, 0.5, 0.6, 0.7]  # tick 0.3 and 0.5 ran once each
    assert len(m.tasks[0].durations_s) == 8
    assert np.allclose(sink.column("time"), [0.0, 0.2, 0.4, 0.6], atol=1e-12)
    assert np.allclose(sink.column("a.y"), [0.0, 0.2, 0.4, 0.6], atol=1e-12)


def test_views_are_live_and_protected(fmus):
    m = Master(0.1)
    m.add_fmu("a", fmus["integrator"])
    m.add_fmu("s", fmus["sampler"])
    m.add_variables("ctrl", ["u", "v"])
    m.connect("ctrl.u -> a.u")
    m.connect("ctrl.v -> s.u")
    m.initialize(0.3)
    out = m.view(["a.y", "a.clock"])
    cmd = m.view(["ctrl.u", "ctrl.v"], writable=True)
    cmd[:] = [2.0, 3.0]
    m.run(0.3)
    assert out[0] == pytest.approx(0.6) and out[1] == pytest.approx(0.3)
    assert m.reader(["s.y", "a.y"]).read().tolist() == pytest.approx([3.0, 0.6])
    with pytest.raises(ValueError):
        out[0] = 1.0
    with pytest.raises(MasterConfigError, match="not master variables"):
        m.view(["a.y"], writable=True)
    with pytest.raises(MasterConfigError, match="not contiguous"):
        m.view(["a.y", "s.y"])
    with pytest.raises(MasterConfigError, match="expose"):
        m.view(["a.k"])
    m.close()


@pytest.mark.parametrize("engine", ENGINES)
def test_expose_and_record_parameters_and_unconnected_inputs(fmus, engine):
    m = Master(0.1, engine=engine)
    m.add_fmu("a", fmus["integrator"], start_values={"k": 3.0, "u": 0.5})
    m.expose(["a.k"])
    sink = MemorySink()
    m.add_recorder(["a.u", "a.y0", "a.y"], 0.1, sink)  # unconnected input and a parameter: read like outputs
    m.initialize(0.2)
    assert m.view(["a.k"])[0] == 3.0
    m.run()
    m.close()
    assert sink.column("a.u").tolist() == [0.5, 0.5, 0.5]
    assert sink.column("a.y0").tolist() == [0.0, 0.0, 0.0]
    assert sink.column("a.y") == pytest.approx([0.0, 0.15, 0.3])
