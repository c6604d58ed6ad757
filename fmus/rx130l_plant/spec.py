"""Variables of the ``rx130l_plant`` FMU (names, causality, units, defaults).

Defaults are the nominal robot: the URDF inertias and the parameter file's rotor
inertia and friction (``robot.dynamics.nominal_parameter_vector``) and its nominal
payload. ``p[k]`` is element ``k-1`` of the 78-vector of :mod:`robot.dynamics`
(description attribute: its name in ``PARAMETER_NAMES``).
"""
from __future__ import annotations

from fmus.fmi2_spec import INPUT, OUTPUT, PARAMETER, FmuSpec
from robot.dynamics import PARAMETER_NAMES, PARAMETER_UNITS, nominal_parameter_vector
from robot.parameters import load_parameters

MODEL_IDENTIFIER = "rx130l_plant"
SOURCE_FILES = ("fmi2_wrapper.c", "rx130l_plant.c", "rx130l_plant_fd.c")
DEFAULT_INTEGRATION_STEP = 50e-6  # s, see docs/fmus.md (accuracy against solve_ivp)
_FMI_UNIT = {"kg": "kg", "kg m": "kg.m", "kg m^2": "kg.m2", "N m s/rad": "N.m.s/rad", "N m": "N.m"}


def plant_spec() -> FmuSpec:
    """The full variable list of the plant FMU with the nominal robot as defaults."""
    robot = load_parameters()
    p = nominal_parameter_vector(parameters=robot)
    spec = FmuSpec(
        model_identifier=MODEL_IDENTIFIER,
        description="RX130L-class arm: rigid-body dynamics (CasADi ABA) with rotor inertia, viscous and "
                    "smoothed Coulomb friction and a point-mass payload; fixed-step RK4 inside fmi2DoStep",
        source_files=SOURCE_FILES,
        default_step=1e-3,
        default_stop=1.0,
    )
    zeros = [0.0] * 6
    spec.add_array("tau", zeros, INPUT, "joint torque applied by drive", unit="N.m",
                   descriptions=[f"joint {k} torque from the drive (joint side)" for k in range(1, 7)])
    spec.add_array("q", zeros, OUTPUT, "", unit="rad", descriptions=[f"joint {k} position" for k in range(1, 7)])
    spec.add_array("qd", zeros, OUTPUT, "", unit="rad/s", descriptions=[f"joint {k} speed" for k in range(1, 7)])
    spec.add_array("qdd", zeros, OUTPUT, "", unit="rad/s2",
                   descriptions=[f"joint {k} acceleration at the end of the step (with the step's torque)"
                                 for k in range(1, 7)])
    spec.add_array("q0", zeros, PARAMETER, "", unit="rad",
                   descriptions=[f"joint {k} initial position" for k in range(1, 7)])
    spec.add_array("qd0", zeros, PARAMETER, "", unit="rad/s",
                   descriptions=[f"joint {k} initial speed" for k in range(1, 7)])
    spec.add_array("p", [float(x) for x in p], PARAMETER, "", descriptions=[
        f"dynamic parameter {name} ({unit}; robot.dynamics.PARAMETER_NAMES[{k}])"
        for k, (name, unit) in enumerate(zip(PARAMETER_NAMES, PARAMETER_UNITS))],
        units=[_FMI_UNIT[unit] for unit in PARAMETER_UNITS])
    spec.add("payload_mass", "Real", PARAMETER, "point-mass payload fixed to tool0", unit="kg",
             start=float(robot.payload_mass), min=0.0)
    spec.add_array("payload_com", [float(x) for x in robot.payload_com], PARAMETER, "", unit="m",
                   descriptions=[f"payload centre of mass, {axis} in tool0" for axis in "xyz"])
    spec.add("integration_step", "Real", PARAMETER,
             "largest RK4 sub-step inside fmi2DoStep (each step is split into equal sub-steps)",
             unit="s", start=DEFAULT_INTEGRATION_STEP, min=1e-7, max=1e-2)
    return spec
