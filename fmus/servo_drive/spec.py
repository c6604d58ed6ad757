"""Variables of the ``servo_drive`` FMU (names, causality, units, ranges, defaults).

Defaults are the axis-1 values of :func:`fmus.servo_drive.params.drive_start_values`;
the caller sets the other axes' values as start values.
"""
from __future__ import annotations

from fmus.fmi2_spec import INPUT, OUTPUT, PARAMETER, FmuSpec
from fmus.servo_drive.params import drive_start_values

MODEL_IDENTIFIER = "servo_drive"
SOURCE_FILES = ("fmi2_wrapper.c", "servo_drive.c")

#: (name, unit, min, max, description) of the Real parameters, in value-reference order.
REAL_PARAMETERS: tuple[tuple[str, str, float | None, float | None, str], ...] = (
    ("gear_ratio", "1", 1e-6, None, "gear ratio N (motor rev per joint rev)"),
    ("torque_constant", "N.m/A", 1e-9, None, "motor torque constant k_t (motor side)"),
    ("back_emf_constant", "V.s/rad", 0.0, None, "q-axis back-EMF constant k_e (per motor rad/s)"),
    ("current_limit", "A", 1e-9, None, "peak motor current limit"),
    ("torque_limit", "N.m", 1e-9, None, "joint-side torque limit (current clamp min(I_max, T_max/(N k_t)))"),
    ("velocity_limit", "rad/s", 1e-9, None, "joint-side speed-demand clamp"),
    ("resistance", "Ohm", 1e-9, None, "q-axis winding resistance R"),
    ("inductance", "H", 1e-12, None, "q-axis inductance L"),
    ("bus_voltage", "V", 1e-9, None, "DC-link voltage; the q-voltage limit is bus_voltage/sqrt(3)"),
    ("current_kp", "V/A", 0.0, None, "current PI proportional gain"),
    ("current_tn", "s", 1e-9, None, "current PI integral time"),
    ("speed_kp", "A.s/rad", 0.0, None, "speed PI proportional gain (current per MOTOR speed error)"),
    ("speed_tn", "s", 1e-9, None, "speed PI integral time"),
    ("speed_filter_time", "s", 0.0, None, "first-order actual-speed filter time constant (0: none)"),
    ("position_kv", "1/s", 0.0, None, "position P gain (joint speed demand per position error)"),
    ("speed_feedforward_gain", "1", 0.0, 2.0, "weight of the speed feed-forward from target differences"),
    ("current_sample_time", "s", 1e-7, 1.0, "current-loop sample time"),
    ("speed_sample_time", "s", 1e-7, 1.0, "speed-loop sample time (multiple of current_sample_time)"),
    ("position_sample_time", "s", 1e-7, 1.0, "position-loop sample time (multiple of speed_sample_time)"),
    ("quick_stop_deceleration", "rad/s2", 1e-9, None, "quick-stop ramp deceleration (0x6085)"),
    ("fault_reaction_deceleration", "rad/s2", 1e-9, None, "fault-reaction ramp deceleration"),
    ("following_error_window", "rad", 0.0, None, "following-error window (0x6065), 0 disables the fault"),
    ("standstill_velocity", "rad/s", 0.0, None,
     "velocity threshold (0x606F): a stop ramp ends when the axis is this slow ..."),
    ("standstill_time", "s", 0.0, None, "... for this long (velocity threshold time 0x6070)"),
    ("brake_holding_torque", "N.m", 0.0, None,
     "holding brake, joint side: largest torque it transmits before slipping (0: no brake); closed whenever "
     "the power stage is off"),
    ("brake_stiffness", "N.m/rad", 1e-9, None, "torsional stiffness of the closed brake, joint side"),
    ("brake_damping", "N.m.s/rad", 0.0, None, "damping of the closed brake, joint side"),
)


def servo_drive_spec() -> FmuSpec:
    """The full variable list of the servo drive FMU with axis-1 defaults."""
    defaults = drive_start_values(1)
    spec = FmuSpec(
        model_identifier=MODEL_IDENTIFIER,
        description="One axis of a CiA 402 servo drive, modes of operation 8 (cyclic synchronous position), "
                    "9 (velocity) and 10 (torque): P position loop, PI speed loop, PI current loop on a q-axis "
                    "R-L-EMF motor model, velocity and torque feed-forward, limits, encoder quantisation, state "
                    "machine with quick-stop and fault ramps, holding brake while the power stage is off. "
                    f"Communication step: any positive integer multiple of current_sample_time (default "
                    f"{defaults['current_sample_time']:g} s); other steps are rejected with fmi2Error",
        source_files=SOURCE_FILES,
        default_step=defaults["current_sample_time"],
        default_stop=0.1,
    )
    spec.add("target_position", "Real", INPUT, "CiA 402 0x607A target position, joint side", unit="rad", start=0.0)
    spec.add("torque_offset", "Real", INPUT, "CiA 402 0x60B2 torque feed-forward, joint side", unit="N.m", start=0.0)
    spec.add("q_meas", "Real", INPUT, "measured joint position from the plant", unit="rad", start=0.0)
    spec.add("qd_meas", "Real", INPUT, "measured joint speed from the plant (resolver evaluation)",
             unit="rad/s", start=0.0)
    spec.add("tau_out", "Real", OUTPUT, "joint-side motor torque N k_t i applied to the plant", unit="N.m")
    spec.add("position_actual", "Real", OUTPUT,
             "CiA 402 0x6064 position actual: quantised encoder position latched at the last position sample "
             "(q_meas set at a position-sample instant shows at once: the latch at the sync)",
             unit="rad", depends_on=("q_meas", "gear_ratio", "encoder_counts_per_rev"))
    spec.add("velocity_actual", "Real", OUTPUT, "CiA 402 0x606C velocity actual: filtered measured speed",
             unit="rad/s", depends_on=("qd_meas",))
    spec.add("current_actual", "Real", OUTPUT, "motor q-axis current", unit="A")
    spec.add("current_demand", "Real", OUTPUT, "current set-point (speed PI + feed-forward, limited)", unit="A")
    spec.add("torque_actual", "Real", OUTPUT, "CiA 402 0x6077 torque actual, joint side N k_t i", unit="N.m")
    spec.add("following_error", "Real", OUTPUT, "reference minus position actual at the last position sample",
             unit="rad")
    for name, unit, lo, hi, text in REAL_PARAMETERS:
        spec.add(name, "Real", PARAMETER, text, unit=unit, start=defaults[name], min=lo, max=hi,
                 tunable=name in TUNABLE_PARAMETERS)
    spec.add("brake_torque", "Real", OUTPUT,
             "joint-side torque of the holding brake (part of tau_out; 0 while the power stage is on)", unit="N.m")
    spec.add("controlword", "Integer", INPUT, "CiA 402 0x6040 controlword", start=0, min=0, max=65535)
    spec.add("fault_code", "Integer", INPUT,
             "external fault (e.g. fieldbus threshold reaction): 0 none, otherwise the 0x603F error code "
             "to raise", start=0, min=0, max=65535)
    spec.add("statusword", "Integer", OUTPUT, "CiA 402 0x6041 statusword", depends_on=("modes_of_operation",))
    spec.add("error_code", "Integer", OUTPUT, "CiA 402 0x603F error code of the active fault (0: none)")
    spec.add("encoder_counts_per_rev", "Integer", PARAMETER, "encoder counts per motor revolution",
             start=defaults["encoder_counts_per_rev"], min=1, max=2**30)
    spec.add("quick_stop_option_code", "Integer", PARAMETER,
             "CiA 402 0x605A: 2 = ramp then switch on disabled, 6 = ramp then hold in quick stop",
             start=defaults["quick_stop_option_code"], min=2, max=6)
    # added after the original variables so that every earlier value reference stays the same
    spec.add("target_velocity", "Real", INPUT, "CiA 402 0x60FF target velocity, joint side (CSV)", unit="rad/s",
             start=0.0)
    spec.add("velocity_offset", "Real", INPUT,
             "CiA 402 0x60B1 velocity offset, joint side: added to the speed set-point (CSP, CSV)", unit="rad/s",
             start=0.0)
    spec.add("target_torque", "Real", INPUT, "CiA 402 0x6071 target torque, joint side (CST)", unit="N.m",
             start=0.0)
    spec.add("modes_of_operation", "Integer", INPUT,
             "CiA 402 0x6060 modes of operation: 8 cyclic synchronous position, 9 velocity, 10 torque; "
             "takes effect at the next position sample; another value is refused (mode kept, statusword "
             "bit 7, counted in unsupported_mode_requests)", start=8, min=-128, max=127)
    spec.add("modes_of_operation_display", "Integer", OUTPUT, "CiA 402 0x6061 active mode of operation",
             depends_on=("modes_of_operation",))
    spec.add("unsupported_mode_requests", "Integer", OUTPUT,
             "how many times modes_of_operation was set to a value the drive does not support",
             depends_on=("modes_of_operation",))
    spec.add("brake_closing_time", "Real", PARAMETER,
             "holding brake closing time: at the end of a stop ramp that switches the power stage off (fault "
             "reaction, quick stop option 2) the brake is commanded closed and the motor holds the axis this "
             "long more before its power stage switches off; the brake then takes over the motor's torque",
             unit="s", start=defaults["brake_closing_time"], min=0.0, max=10.0)
    _add_protection(spec, defaults)
    return spec


#: the parameters a master may change between steps (variability "tunable": the C code reads them
#: at every position sample; an SDO write of 0x6065 / 0x6066 sets them, fieldbus/asynchronous.py)
TUNABLE_PARAMETERS = frozenset({"following_error_window", "following_error_time"})

#: (name, unit, min, description) of the protection parameters (appended last), docs/explanation/fmus.md "Protection"
PROTECTION_PARAMETERS: tuple[tuple[str, str, float | None, str], ...] = (
    ("rated_current", "A", 1e-9, "CiA 402 0x6075 motor rated current: the I2t monitoring derates the current "
                                 "limit to it"),
    ("peak_current_time", "s", 1e-9, "I2t: how long the peak current may flow from a cold state; the threshold is "
                                     "(I_max^2 - rated_current^2) * peak_current_time, I_max = min(current_limit, "
                                     "torque_limit / (N kt))"),
    ("i2t_release", "1", 0.0, "I2t: the peak current is allowed again below this fraction of the threshold"),
    ("max_motor_speed", "rad/s", 1e-9, "CiA 402 0x6080 max motor speed, joint side: beyond it the drive raises "
                                       "fault 0x8400 (overspeed)"),
    ("position_limit_min", "rad", None, "CiA 402 0x607D software position limit (min), joint side: position "
                                        "actual below it raises fault 0x8612"),
    ("position_limit_max", "rad", None, "CiA 402 0x607D software position limit (max), joint side: position "
                                        "actual above it raises fault 0x8612"),
    ("following_error_time", "s", 0.0, "CiA 402 0x6066 following error time-out: the following error must stay "
                                       "beyond following_error_window this long before fault 0x8611"),
)

LIMIT_BITS: dict[str, int] = {"torque_limit": 0, "i2t": 1, "speed_limit": 2, "position_limit": 3,
                              "following_error": 4}
"""Bit of each protection in the ``limit_status`` / ``limit_history`` outputs; bit + 8: the drive is in
fault reaction or Fault because of it (its code in 0x603F)."""


def _add_protection(spec: FmuSpec, defaults: dict) -> None:
    """The protection parameters and their status outputs (appended: earlier value references stay)."""
    for name, unit, lo, text in PROTECTION_PARAMETERS:
        spec.add(name, "Real", PARAMETER, text, unit=unit, start=defaults[name], min=lo,
                 max=1.0 if name == "i2t_release" else None, tunable=name in TUNABLE_PARAMETERS)
    bits = ", ".join(f"bit {b} {name}" for name, b in LIMIT_BITS.items())
    spec.add("limit_status", "Integer", OUTPUT,
             f"protections active at any sample of the last step: {bits} (the commanded torque - target torque and "
             "torque offset in CST, torque offset in CSP/CSV - beyond max torque/current, "
             "derated by I2t, speed beyond max_motor_speed, position outside the software limits, following error "
             "beyond its window); the same bit + 8 while the drive is in fault reaction or Fault because of it")
    spec.add("limit_history", "Integer", OUTPUT, "every bit limit_status has had since the start (OR)")
    spec.add("i2t_level", "Real", OUTPUT, "I2t integral as a fraction of its threshold (1: derated to rated_current)",
             unit="1")
