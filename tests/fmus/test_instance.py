"""The one FMU class (fmus/fmu.py) under both the co-simulation master and hand-written loops:
the master's instances are ``fmus.fmu.Fmu`` objects, and the FMU's messages reach the instance
that logged them, also with several instances of one FMU (fmpy's logging proxy keeps one
process-wide Python callback)."""
from __future__ import annotations

import gc

import numpy as np
import pytest

from cosim.master import Master
from fmus import instance
from fmus.build import ensure_fmus
from fmus.errors import FmuConfigError, SimulationError
from fmus.fmu import Fmu
from fmus.servo_drive.axis_bench import simulate_axis
from fmus.servo_drive.params import drive_start_values


def test_master_and_hand_loop_use_one_fmu_class_and_route_messages():
    path = ensure_fmus()["servo_drive"]
    master = Master(1e-4)
    components = [master.add_fmu(f"d{a}", path, start_values=drive_start_values(a), debug_logging=True)
                  for a in (1, 2, 3)]
    fast = Fmu(path, "fast", drive_start_values(4), debug_logging=True).start()
    try:
        master.initialize(0.01)
        assert all(type(c) is Fmu for c in components)
        assert all(master.fmus[c.name] is c for c in components)
        for c in components:  # each instance has its own start-up transition, logged once
            assert sum("Not ready to switch on -> Switch on disabled" in m for m in c.messages) == 1, c.name
        assert sum("Not ready to switch on" in m for m in fast.messages) == 1
        fast.set_value("controlword", 0x06)
        fast.do_step(0.0, 1e-4)
        assert any("Ready to switch on" in m for m in fast.messages)
        assert not any("Ready to switch on" in m for c in components for m in c.messages)
    finally:
        master.close()
        fast.close()


def test_hand_loop_life_cycle():
    """Constructed = model description only; start() instantiates and initializes; close() is
    idempotent and a closed instance refuses to step with a clear error."""
    path = ensure_fmus()["rx130l_plant"]
    fmu = Fmu(path, "plant", {"q0[2]": -0.3}, real_inputs=[f"tau[{k}]" for k in range(1, 7)],
              real_outputs=["q[2]", "qd[2]"])
    assert fmu.slave is None and fmu.component is None
    with fmu.start(start_time=1.0) as plant:
        assert plant is fmu and plant.time == 1.0
        assert plant.get_value("q[2]") == pytest.approx(-0.3)
        plant.inputs[:] = 0.0
        plant.push_inputs()
        plant.do_step(1.0, 1e-3)
        q, qd = plant.get_outputs()
        assert plant.time == pytest.approx(1.001) and qd != 0.0  # gravity moves joint 2
        with pytest.raises(SimulationError, match=r"plant at t = 2 s: fmi2DoStep\(t=2 s, h=0.001 s\) returned "
                                                  r"fmi2Error\n  FMU log:\n.*does not match the FMU time 1.001"):
            plant.do_step(2.0, 1e-3)
    assert fmu.slave is None
    fmu.close()  # idempotent
    with pytest.raises(FmuConfigError, match=r"FMU 'plant' \(rx130l_plant.fmu\) is closed"):
        fmu.do_step(1.001, 1e-3)
    with pytest.raises(FmuConfigError, match="is not instantiated yet"):
        Fmu(path, "later").get_value("q[1]")
    routed = len(instance._SINKS)
    Fmu(path, "dropped").start()  # neither kept nor closed: freed (and its log route released) when collected
    gc.collect()
    assert len(instance._SINKS) == routed


def test_fmi3_build_in_a_hand_loop_equals_the_fmi2_build():
    """The same class steps an FMI 3.0 FMU (through the C adapter) in a hand loop: the drive's
    step response on a rigid inertia is bit-identical with the FMI 2.0 and the FMI 3.0 build,
    and array elements of the FMI 3.0 plant are read and set by their flattened names."""
    runs = [simulate_axis(ensure_fmus(fmi=fmi)["servo_drive"], 2, 3.0, lambda t: 0.01, 0.02) for fmi in (2, 3)]
    for field in ("q", "qd", "tau", "current", "position_actual", "statusword"):
        np.testing.assert_array_equal(getattr(runs[0], field), getattr(runs[1], field), err_msg=field)
    assert runs[0].q[-1] > 0.005  # it moved towards the 0.01 rad target
    path3 = ensure_fmus(fmi=3)["rx130l_plant"]
    with Fmu(path3, "plant3", {"q0[2]": -0.3}, real_inputs=[f"tau[{k}]" for k in range(1, 7)],
             real_outputs=["q[2]"]).start() as plant:
        assert plant.fmi3 and plant.get_value("q[2]") == pytest.approx(-0.3)
        plant.set_inputs(np.zeros(6))
        plant.set_value("tau[3]", 1.0)
        assert plant.get_value("tau[3]") == 1.0 and plant.get_value("tau[2]") == 0.0
        plant.do_step(0.0, 1e-3)
        assert plant.get_outputs()[0] != -0.3
