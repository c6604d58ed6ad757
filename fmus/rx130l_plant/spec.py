"""Variables of the ``rx130l_plant`` FMU (names, causality, units, defaults).

Defaults are the nominal robot: the URDF inertias and the parameter file's rotor
inertia and friction (``robot.dynamics.nominal_parameter_vector``), its nominal
payload and no geometric errors (``geometric_errors[k]`` = element ``k-1`` of the 39-vector
of :mod:`robot.geometric_errors`, folded into the joint placements of the dynamics). ``p[k]`` is element ``k-1`` of the 78-vector of :mod:`robot.dynamics`
(description attribute: its name in ``PARAMETER_NAMES``).
"""
from __future__ import annotations

from fmus.fmi2_spec import INPUT, OUTPUT, PARAMETER, FmuSpec
from robot.dynamics import PARAMETER_NAMES, PARAMETER_UNITS, nominal_parameter_vector
from robot.parameters import MAX_BACKLASH, load_parameters

MODEL_IDENTIFIER = "rx130l_plant"
SOURCE_FILES = ("fmi2_wrapper.c", "rx130l_plant.c", "rx130l_plant_fd.c")
DEFAULT_INTEGRATION_STEP = 50e-6  # s, see docs/explanation/fmus.md (accuracy against solve_ivp)
_FMI_UNIT = {"kg": "kg", "kg m": "kg.m", "kg m^2": "kg.m2", "N m s/rad": "N.m.s/rad", "N m": "N.m"}


def plant_spec() -> FmuSpec:
    """The full variable list of the plant FMU with the nominal robot as defaults."""
    robot = load_parameters()
    p = nominal_parameter_vector(parameters=robot)
    spec = FmuSpec(
        model_identifier=MODEL_IDENTIFIER,
        description="RX130L-class arm: rigid-body dynamics (CasADi ABA) with a point-mass payload; rigid joints "
                    "(rotor inertia, viscous and smoothed Coulomb friction) or elastic joints (motor inertia, gear "
                    "spring/damper/backlash, motor- and link-side friction with Stribeck); fixed-step RK4 inside "
                    "fmi2DoStep",
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
    _add_elastic_variables(spec, robot)
    _add_geometry_variables(spec)
    _add_end_stop_variables(spec, robot)
    _declare_initial_dependencies(spec)
    return spec


def _joint_texts(text: str) -> list[str]:
    return [text.format(k=k) for k in range(1, 7)]


def _add_elastic_variables(spec: FmuSpec, robot) -> None:
    """The external torque input, the motor-side outputs and the elastic-joint parameters
    (appended after the rigid plant's variables, whose value references stay unchanged)."""
    zeros = [0.0] * 6
    spec.add_array("tau_ext", zeros, INPUT, "", unit="N.m", descriptions=_joint_texts(
        "joint {k} external torque acting on the link (joint side; payload, spring or contact FMU), default 0"))
    spec.add_array("q_motor", zeros, OUTPUT, "", unit="rad", descriptions=_joint_texts(
        "motor {k} angle divided by the gear ratio (joint units; = q[{k}] in the rigid model)"))
    spec.add_array("qd_motor", zeros, OUTPUT, "", unit="rad/s", descriptions=_joint_texts(
        "motor {k} speed divided by the gear ratio (joint units; = qd[{k}] in the rigid model)"))
    spec.add_array("tau_gear", zeros, OUTPUT, "", unit="N.m", descriptions=_joint_texts(
        "joint {k} torque the gear passes to the link (elastic: spring + damper; rigid: tau minus rotor "
        "inertia and friction torque)"))
    spec.add("elastic_joints", "Integer", PARAMETER,
             "0 = rigid joints (rotor inertia and friction on the joint), 1 = elastic joints (two-mass model per "
             "axis: motor inertia, gear spring/damper/backlash, link; motor- and link-side friction)",
             start=0, min=0, max=1)
    spec.add_array("stiffness", [float(x) for x in robot.stiffness], PARAMETER, "", unit="N.m/rad", min=0.0,
                   descriptions=_joint_texts("gear {k} stiffness, joint side (linear term; > 0 when elastic)"))
    spec.add_array("stiffness_cubic", [float(x) for x in robot.stiffness_cubic], PARAMETER, "",
                   unit="N.m/rad3", min=0.0,
                   descriptions=_joint_texts("gear {k} stiffening term k3 (torque k d + k3 d^3)"))
    spec.add_array("damping", [float(x) for x in robot.gear_damping], PARAMETER, "", unit="N.m.s/rad", min=0.0,
                   descriptions=_joint_texts("gear {k} damping across the gear, joint side"))
    spec.add_array("backlash", [float(x) for x in robot.backlash], PARAMETER, "", unit="rad", min=0.0,
                   max=MAX_BACKLASH, descriptions=_joint_texts(
                       "gear {k} total lost-motion band width (smoothed dead zone), joint side"))
    spec.add_array("motor_friction_share", [float(x) for x in robot.motor_friction_share], PARAMETER, "",
                   unit="1", min=0.0, max=1.0, descriptions=_joint_texts(
                       "fraction of axis {k} viscous and Coulomb friction (p) acting on the motor side"))
    spec.add_array("stribeck_torque", [float(x) for x in robot.stribeck_torque], PARAMETER, "", unit="N.m",
                   min=0.0, descriptions=_joint_texts("axis {k} static minus Coulomb friction (motor side)"))
    spec.add_array("stribeck_velocity", [float(x) for x in robot.stribeck_velocity], PARAMETER, "",
                   unit="rad/s", min=1e-9, descriptions=_joint_texts("axis {k} Stribeck velocity (joint units)"))
    spec.add("coulomb_smoothing_velocity", "Real", PARAMETER,
             "tanh width of the Coulomb and Stribeck terms of the elastic model (the rigid model's is compiled in)",
             unit="rad/s", start=float(robot.coulomb_smoothing_velocity), min=1e-9)


def _add_geometry_variables(spec: FmuSpec) -> None:
    """The 39 geometric errors of the true arm (appended last: earlier value references stay)."""
    from robot.geometric_errors import ERROR_PARAMETER_NAMES, is_angle_parameter

    spec.add_array("geometric_errors", [0.0] * len(ERROR_PARAMETER_NAMES), PARAMETER, "", descriptions=[
        f"geometric error {name} (robot.geometric_errors.ERROR_PARAMETER_NAMES[{k}]), folded into the joint and "
        f"flange placements of the dynamics" for k, name in enumerate(ERROR_PARAMETER_NAMES)],
        units=["rad" if is_angle_parameter(name) else "m" for name in ERROR_PARAMETER_NAMES])


def _add_end_stop_variables(spec: FmuSpec, robot) -> None:
    """The mechanical end stops (robot/rx130l_params.toml [end_stops]) and their contact outputs
    (appended last: earlier value references stay)."""
    spec.add_array("end_stop_lower", [float(x) for x in robot.end_stop_lower], PARAMETER, "", unit="rad",
                   descriptions=_joint_texts("joint {k} lower mechanical end stop (link angle)"))
    spec.add_array("end_stop_upper", [float(x) for x in robot.end_stop_upper], PARAMETER, "", unit="rad",
                   descriptions=_joint_texts("joint {k} upper mechanical end stop (link angle)"))
    spec.add_array("end_stop_stiffness", [float(x) for x in robot.end_stop_stiffness], PARAMETER, "",
                   unit="N.m/rad", min=0.0, descriptions=_joint_texts("joint {k} end-stop contact stiffness"))
    spec.add_array("end_stop_damping", [float(x) for x in robot.end_stop_damping], PARAMETER, "",
                   unit="N.m.s/rad", min=0.0, descriptions=_joint_texts(
                       "joint {k} end-stop contact damping (the contact never pulls: torque clipped at 0)"))
    zeros = [0.0] * 6
    spec.add_array("end_stop_penetration", zeros, OUTPUT, "", unit="rad", descriptions=_joint_texts(
        "joint {k} distance beyond its end stop at the end of the step (0: no contact)"))
    spec.add_array("end_stop_max_penetration", zeros, OUTPUT, "", unit="rad", descriptions=_joint_texts(
        "joint {k} largest distance beyond an end stop since the start"))
    spec.add_array("end_stop_impact_speed", zeros, OUTPUT, "", unit="rad/s", descriptions=_joint_texts(
        "joint {k} speed (magnitude) at the onset of its last end-stop contact"))
    spec.add_array("end_stop_impact_time", zeros, OUTPUT, "", unit="s", descriptions=_joint_texts(
        "joint {k} time of the onset of its last end-stop contact"))
    spec.add_array("end_stop_contacts", [0] * 6, OUTPUT, "", type_="Integer", descriptions=_joint_texts(
        "joint {k} number of end-stop contacts (onsets) since the start"))


def _declare_initial_dependencies(spec: FmuSpec) -> None:
    """Honest InitialUnknowns: which parameters and inputs each output depends on before
    the first step (the plant computes its outputs in Initialization Mode)."""
    knowns = tuple(v.name for v in spec.variables if v.causality in (INPUT, PARAMETER))
    for k in range(1, 7):
        spec.set_depends_on(f"q[{k}]", (f"q0[{k}]",))
        spec.set_depends_on(f"qd[{k}]", (f"qd0[{k}]",))
        spec.set_depends_on(f"qd_motor[{k}]", (f"qd0[{k}]",))
        # qdd and the gear torque depend on the whole arm and the inputs; so does the
        # motor's start angle (where the gear holds the links at rest)
        for name in ("qdd", "q_motor", "tau_gear"):
            spec.set_depends_on(f"{name}[{k}]", knowns)
