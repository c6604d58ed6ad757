"""Nonsense given to the FMUs returns fmi2Error with a logged message and never crashes
the process; a non-finite state puts the instance into the error mode; FMU states
round-trip."""
import ctypes

import numpy as np
import pytest
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave

from fmus.build import ensure_fmus
from fmus.errors import FmuConfigError, SimulationError
from fmus.fmu import Fmu
from fmus.servo_drive.params import drive_start_values

FMI2_ERROR = 3


@pytest.fixture(scope="module")
def paths():
    return ensure_fmus()


@pytest.fixture
def plant(paths):
    fmu = Fmu(paths["rx130l_plant"], "plant", real_inputs=[f"tau[{k}]" for k in range(1, 7)],
              real_outputs=[f"q[{k}]" for k in range(1, 7)]).start()
    yield fmu
    fmu.close()


@pytest.fixture
def drive(paths):
    fmu = Fmu(paths["servo_drive"], "drive", drive_start_values(1),
              real_inputs=["target_position", "torque_offset", "q_meas", "qd_meas"],
              real_outputs=["tau_out"], integer_inputs=["controlword"]).start()
    yield fmu
    fmu.close()


def _raw(fmu):
    return fmu.slave.dll, fmu.component


@pytest.mark.parametrize("h", [-1e-3, 0.0, float("nan"), float("inf")])
def test_bad_step_size_is_rejected_and_the_instance_stays_usable(plant, h):
    with pytest.raises(SimulationError, match="communicationStepSize"):
        plant.do_step(0.0, h)
    plant.do_step(0.0, 1e-3)
    assert np.all(np.isfinite(plant.get_outputs()))


def test_gap_between_steps_is_rejected(plant):
    plant.do_step(0.0, 1e-3)
    with pytest.raises(SimulationError, match="does not match the FMU time"):
        plant.do_step(5e-3, 1e-3)


def test_drive_step_not_a_multiple_of_the_current_sample(drive):
    with pytest.raises(SimulationError, match="not a multiple of current_sample_time"):
        drive.do_step(0.0, 75e-6)
    drive.do_step(0.0, 100e-6)


@pytest.mark.parametrize("value", [float("nan"), float("inf"), -float("inf")])
def test_non_finite_input_is_rejected_and_not_stored(drive, value):
    drive.set_inputs([0.1, 0.0, 0.0, 0.0])
    with pytest.raises(SimulationError, match="target_position=.* is not a finite number"):
        drive.set_inputs([value, 0.0, 0.0, 0.0])
    assert drive.get_value("target_position") == 0.1


def test_unknown_value_references(paths, drive):
    dll, component = _raw(drive)
    vr = (ctypes.c_uint * 1)(99999)
    value = (ctypes.c_double * 1)(1.0)
    integer = (ctypes.c_int * 1)(1)
    assert dll.fmi2SetReal(component, vr, 1, value) == FMI2_ERROR
    assert dll.fmi2GetReal(component, vr, 1, value) == FMI2_ERROR
    assert dll.fmi2SetInteger(component, vr, 1, integer) == FMI2_ERROR
    assert dll.fmi2GetInteger(component, vr, 1, integer) == FMI2_ERROR
    # no Boolean or String variables at all: every value reference is unknown
    assert dll.fmi2GetBoolean(component, (ctypes.c_uint * 1)(0), 1, integer) == FMI2_ERROR
    assert sum("unknown value reference 99999" in m for m in drive.messages) == 4


def test_wrong_type_and_wrong_causality(drive):
    with pytest.raises(FmuConfigError, match="is Integer, expected Real"):
        Fmu(drive.path, "typed", real_inputs=["controlword"])
    with pytest.raises(FmuConfigError, match="has no variable 'torque'"):
        Fmu(drive.path, "named", real_outputs=["torque"])
    with pytest.raises(FmuConfigError, match="expected an integer"):
        drive.set_value("controlword", 1.5)
    with pytest.raises(SimulationError, match="tau_out is an output and cannot be set"):
        drive.set_value("tau_out", 1.0)
    with pytest.raises(SimulationError, match="fixed parameter"):
        drive.set_value("position_kv", 10.0)
    with pytest.raises(SimulationError, match="controlword=70000 is outside its range"):
        drive.set_value("controlword", 70000)


def test_tunable_parameters_are_set_between_steps_and_checked(drive):
    """0x6065/0x6066 (fieldbus/asynchronous.py: an SDO write between two steps) are tunable, the rest fixed."""
    from fmus.servo_drive.spec import TUNABLE_PARAMETERS, servo_drive_spec

    tunable = {v.name for v in servo_drive_spec().variables if v.variability == "tunable"}
    assert tunable == TUNABLE_PARAMETERS == {"following_error_window", "following_error_time"}
    drive.do_step(0.0, 1e-4)
    drive.set_value("following_error_window", 1e-3)
    assert drive.get_value("following_error_window") == 1e-3
    with pytest.raises(SimulationError, match="following_error_window=-1 is outside its range"):
        drive.set_value("following_error_window", -1.0)


def test_parameter_range_and_consistency_checked_at_initialization(paths):
    with pytest.raises(SimulationError, match="gear_ratio=-1 is outside its range"):
        Fmu(paths["servo_drive"], "bad", {"gear_ratio": -1.0}).start()
    with pytest.raises(SimulationError, match="must be integer multiples of"):
        Fmu(paths["servo_drive"], "bad", {"speed_sample_time": 130e-6}).start()
    with pytest.raises(SimulationError, match="quick_stop_option_code=4"):
        Fmu(paths["servo_drive"], "bad", {"quick_stop_option_code": 4}).start()
    with pytest.raises(SimulationError, match="payload_mass=-2 is outside"):
        Fmu(paths["rx130l_plant"], "bad", {"payload_mass": -2.0}).start()


def test_calls_in_the_wrong_mode(paths):
    md = read_model_description(str(paths["rx130l_plant"]))
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(paths["rx130l_plant"])),
                    modelIdentifier="rx130l_plant", instanceName="modes")
    fmu.instantiate()
    dll, component = fmu.dll, fmu.component
    assert dll.fmi2DoStep(component, 0.0, 1e-3, 1) == FMI2_ERROR  # not initialised
    assert dll.fmi2ExitInitializationMode(component) == FMI2_ERROR
    assert dll.fmi2Terminate(component) == FMI2_ERROR
    fmu.freeInstance()


def test_guid_mismatch_refuses_to_instantiate(paths):
    md = read_model_description(str(paths["servo_drive"]))
    fmu = FMU2Slave(guid="{00000000-0000-0000-0000-000000000000}", unzipDirectory=extract(str(paths["servo_drive"])),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="guid")
    with pytest.raises(Exception, match="Failed to instantiate"):
        fmu.instantiate()
    fmu.freeLibrary()


def test_non_finite_state_is_an_error_mode_until_reset(plant):
    plant.set_inputs([1e308] * 6)
    with pytest.raises(SimulationError, match="became non-finite"):
        plant.do_step(0.0, 1e-3)
    with pytest.raises(SimulationError, match="not allowed in error mode"):
        plant.do_step(1e-3, 1e-3)
    dll, component = _raw(plant)
    assert dll.fmi2Reset(component) == 0
    assert dll.fmi2EnterInitializationMode(component) == 0
    assert dll.fmi2ExitInitializationMode(component) == 0
    plant.set_inputs([0.0] * 6)
    plant.do_step(0.0, 1e-3)
    assert np.all(np.isfinite(plant.get_outputs()))


def test_fmu_state_get_set_and_serialize_round_trip(paths, drive):
    dll, component = _raw(drive)
    drive.set_integer_inputs([0x06])
    drive.do_step(0.0, 4e-4)
    drive.set_integer_inputs([0x0F])
    drive.set_inputs([1e-3, 10.0, 0.0, 0.0])
    drive.do_step(4e-4, 4e-4)
    state = ctypes.c_void_p()
    assert dll.fmi2GetFMUstate(component, ctypes.byref(state)) == 0
    size = ctypes.c_size_t()
    assert dll.fmi2SerializedFMUstateSize(component, state, ctypes.byref(size)) == 0
    buffer = (ctypes.c_char * size.value)()
    assert dll.fmi2SerializeFMUstate(component, state, buffer, size) == 0
    drive.do_step(8e-4, 4e-4)
    first = drive.get_outputs().copy()
    restored = ctypes.c_void_p()
    assert dll.fmi2DeSerializeFMUstate(component, buffer, size, ctypes.byref(restored)) == 0
    assert dll.fmi2SetFMUstate(component, restored) == 0
    drive.do_step(8e-4, 4e-4)
    np.testing.assert_array_equal(drive.get_outputs(), first)
    assert dll.fmi2DeSerializeFMUstate(component, buffer, 3, ctypes.byref(restored)) == FMI2_ERROR
    for handle in (state, restored):
        assert dll.fmi2FreeFMUstate(component, ctypes.byref(handle)) == 0
