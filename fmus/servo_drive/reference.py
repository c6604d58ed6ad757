"""Test oracle: the servo drive's discrete controllers re-implemented in Python.

Written from the drive's specification (docs/explanation/fmus.md), not from the C code, for two
uses: the monolithic reference of the coupling study (the winding current is then a
continuous state integrated together with the arm; the oracle only turns sampled
measurements into the voltage of the next current period) and direct comparison with
the FMU. Covered: the enable sequence of the CiA 402 state machine (power off until
Operation enabled), the position/speed/current loops with speed and torque
feed-forward, limits, anti-windup, encoder quantisation, speed filter, computation
delay and back-EMF compensation, the modes of operation 8/9/10 with their set-points
and the bumpless switch-over in Operation enabled, and the holding brake while the
power stage is off (closed from initialisation until Operation enabled: a spring-damper
to where it closed, torque limited to the holding torque, slipping beyond). Not covered:
quick stop, fault reaction, following-error fault, unsupported mode requests (tested on
the FMU directly).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, field


@dataclass
class DriveReference:
    """One axis. ``params`` holds the FMU parameter names and values (see drive_start_values)."""

    params: dict[str, float]
    tick: int = 0
    enabled: bool = False
    state: str = "switch_on_disabled"
    current_integral: float = 0.0
    speed_integral: float = 0.0
    speed_filtered: float = 0.0
    current_demand: float = 0.0
    speed_demand: float = 0.0
    target_prev: float = 0.0
    position_actual: float = 0.0
    u_next: float = 0.0
    brake_anchor: float | None = None  # None: closed, anchored at the next sample
    brake_torque: float = 0.0
    mode: int = 8  # active mode of operation: 8 CSP, 9 CSV, 10 CST
    _derived: dict[str, float] = field(default_factory=dict)

    def __post_init__(self) -> None:
        p = self.params
        ts_i = p["current_sample_time"]
        self.n_speed = round(p["speed_sample_time"] / ts_i)
        self.n_position = round(p["position_sample_time"] / ts_i)
        self.counts_per_rad = p["gear_ratio"] * p["encoder_counts_per_rev"] / (2.0 * math.pi)
        self.current_max = min(p["current_limit"], p["torque_limit"] / (p["gear_ratio"] * p["torque_constant"]))
        self.voltage_max = p["bus_voltage"] / math.sqrt(3.0)
        tf = p["speed_filter_time"]
        self.alpha = 1.0 - math.exp(-p["speed_sample_time"] / tf) if tf > 0 else 1.0

    def initialize(self, q: float, qd: float, target: float) -> None:
        """State at the end of initialization (drive in Switch on disabled)."""
        self.speed_filtered = qd
        self.position_actual = self._quantise(q)
        self.target_prev = target
        self.brake_anchor = None  # closed; anchored where the axis is at the first sample
        self.brake_torque = 0.0

    def _quantise(self, q: float) -> float:
        return math.floor(q * self.counts_per_rad) / self.counts_per_rad

    def _power_off(self) -> None:
        self.current_integral = self.speed_integral = 0.0
        self.current_demand = self.speed_demand = 0.0
        self.u_next = 0.0

    def _device_control(self, controlword: int, target: float) -> None:
        if self.state == "switch_on_disabled" and (controlword & 0x87) == 0x06:
            self.state = "ready"
        elif self.state in ("ready", "switched_on") and (controlword & 0x8F) == 0x0F:
            self.state = "enabled"
            self._power_off()
            self.target_prev = target
            self.brake_torque = 0.0  # the brake opens
        elif self.state == "ready" and (controlword & 0x8F) == 0x07:
            self.state = "switched_on"
        self.enabled = self.state == "enabled"

    def _select_mode(self, mode: int, target: float, torque_offset: float) -> bool:
        """Take a requested mode of operation 8/9/10 (others are ignored here); in
        Operation enabled bumplessly: the speed set-point continues from the filtered
        speed, leaving CST the speed integrator takes over the current set-point, entering
        CST it is cleared. True when the mode changed in Operation enabled."""
        if mode not in (8, 9, 10) or mode == self.mode:
            return False
        switched = self.enabled
        if switched:
            if self.mode == 10:
                p = self.params
                self.speed_integral = self.current_demand - torque_offset / (p["gear_ratio"] * p["torque_constant"])
            if mode == 10:
                self.speed_integral = 0.0
            self.speed_demand = self.speed_filtered
            self.target_prev = target
        self.mode = mode
        return switched

    def tick_voltage(self, q: float, qd: float, current: float, target: float, torque_offset: float,
                     controlword: int, mode: int = 8, target_velocity: float = 0.0, velocity_offset: float = 0.0,
                     target_torque: float = 0.0) -> tuple[float, bool]:
        """One current sample with the measurements at the sample time.

        Returns ``(u, powered)``: the voltage applied over the coming current period
        (computed one sample earlier) and whether the power stage is on (else the
        current is forced to zero).
        """
        p = self.params
        n = p["gear_ratio"]
        if self.tick % self.n_position == 0:
            self.position_actual = self._quantise(q)
            self._device_control(controlword, target)
            switched = self._select_mode(mode, target, torque_offset)
            limit = p["velocity_limit"]
            if self.enabled and self.mode == 9:  # CSV: speed set-point = target velocity + velocity offset
                self.target_prev = target
                self.speed_demand = max(-limit, min(limit, target_velocity + velocity_offset))
            elif self.enabled and self.mode == 10:  # CST: the speed loop is idle
                self.target_prev = target
                self.speed_demand = self.speed_filtered
            elif self.enabled:
                if switched:  # entering CSP: from position actual, the speed set-point continued
                    reference, ff = self.position_actual, self.speed_demand
                else:
                    reference = target
                    ff = p["speed_feedforward_gain"] * (target - self.target_prev) / p["position_sample_time"]
                self.target_prev = target
                v = p["position_kv"] * (reference - self.position_actual) + ff
                v = v + velocity_offset
                self.speed_demand = max(-limit, min(limit, v))
            else:
                self.target_prev = target
        if self.tick % self.n_speed == 0:
            self.speed_filtered += self.alpha * (qd - self.speed_filtered)
            if self.enabled and self.mode == 10:  # CST: current set-point from the torques
                demand = (target_torque + torque_offset) / (n * p["torque_constant"])
                self.current_demand = max(-self.current_max, min(self.current_max, demand))
            elif self.enabled:
                error = n * (self.speed_demand - self.speed_filtered)
                demand = p["speed_kp"] * error + self.speed_integral + torque_offset / (n * p["torque_constant"])
                limited = max(-self.current_max, min(self.current_max, demand))
                if limited == demand or (demand > 0) != (error > 0):
                    self.speed_integral += p["speed_kp"] * p["speed_sample_time"] / p["speed_tn"] * error
                self.current_demand = limited
        self.tick += 1
        if not self.enabled:
            self._brake(q, qd)
            return 0.0, False
        error = self.current_demand - current
        emf = p["back_emf_constant"] * n * qd
        demand = p["current_kp"] * error + self.current_integral + emf
        limited = max(-self.voltage_max, min(self.voltage_max, demand))
        if limited == demand or (demand > 0) != (error > 0):
            self.current_integral += p["current_kp"] * p["current_sample_time"] / p["current_tn"] * error
        applied, self.u_next = self.u_next, limited
        return applied, True

    def _brake(self, q: float, qd: float) -> None:
        """Torque of the closed holding brake (elasto-plastic contact), N m."""
        p = self.params
        limit, k = p["brake_holding_torque"], p["brake_stiffness"]
        if limit <= 0.0:
            return
        if self.brake_anchor is None:
            self.brake_anchor = q
        stretch = q - self.brake_anchor
        if k * abs(stretch) > limit:  # slipping: the anchor follows at the holding torque
            self.brake_anchor = q - math.copysign(limit / k, stretch)
            stretch = q - self.brake_anchor
        tau = -k * stretch - p["brake_damping"] * qd
        self.brake_torque = limit if tau > limit else (-limit if tau < -limit else tau)

    def current_derivative(self, current: float, u: float, qd: float) -> float:
        """d i / dt of the winding (A/s) for voltage ``u`` and joint speed ``qd``."""
        p = self.params
        return (u - p["resistance"] * current - p["back_emf_constant"] * p["gear_ratio"] * qd) / p["inductance"]

    def advance_current(self, current: float, u: float, qd: float) -> float:
        """Exact winding current after one current period with ``u`` and ``qd`` constant."""
        p = self.params
        i_inf = (u - p["back_emf_constant"] * p["gear_ratio"] * qd) / p["resistance"]
        decay = math.exp(-p["resistance"] * p["current_sample_time"] / p["inductance"])
        return i_inf + (current - i_inf) * decay

    def torque(self, current: float) -> float:
        """Joint-side torque to the arm (N m): motor N k_t i plus the holding brake's torque
        (:attr:`brake_torque`, held over the current period; 0 while the brake is open)."""
        return self.params["gear_ratio"] * self.params["torque_constant"] * current + self.brake_torque
