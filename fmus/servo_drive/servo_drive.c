/*
 * One axis of an industrial servo drive (CiA 402 cyclic synchronous modes).
 *
 * Modes of operation (0x6060 input modes_of_operation, 0x6061 output
 * modes_of_operation_display): 8 cyclic synchronous position (CSP), 9 cyclic synchronous
 * velocity (CSV), 10 cyclic synchronous torque (CST). A requested mode takes effect at the
 * next position sample (the sync), bumplessly in Operation enabled (see switch_mode); an
 * unsupported value leaves the active mode and its display unchanged, sets statusword
 * bit 7 (warning) while it is requested, is logged once and counted
 * (unsupported_mode_requests). Quick stop and fault reaction defer a mode change.
 *
 * Three cascaded discrete loops, each at its own sample time inside fmi2DoStep:
 *   position loop (P, Kv) every position_sample_time, plus speed feed-forward from the
 *       difference of consecutive target positions, plus velocity_offset (0x60B1) [CSP];
 *       in CSV the speed set-point is target_velocity + velocity_offset (0x60FF + 0x60B1);
 *   speed loop (PI) every speed_sample_time on the filtered measured speed, plus the
 *       feed-forward current torque_offset / (gear_ratio * torque_constant) (0x60B2)
 *       [CSP, CSV]; in CST the current set-point is
 *       (target_torque + torque_offset) / (N kt) (0x6071 + 0x60B2), the speed PI idle;
 *       current set-point clamped to min(current_limit, torque_limit / (N kt));
 *   current loop (PI with back-EMF compensation) every current_sample_time on the
 *       q-axis winding  L di/dt = u - R i - k_e N qd ; the voltage computed at a sample
 *       is applied from the next sample (computation delay), clamped to U_dc / sqrt(3).
 * The winding ODE is integrated exactly over each current period (u and qd constant).
 * Output torque to the plant (joint side): tau_out = N kt i (rotor inertia and friction
 * are part of the plant).
 *
 * The CiA 402 state machine runs at every position sample. The power stage (current
 * loop) is active in Operation enabled, Quick stop active and Fault reaction active
 * only; elsewhere the current is zero. Quick stop and fault reaction follow an
 * internal ramp to standstill with their decelerations; once the ramp is at zero and
 * the filtered speed has stayed within standstill_velocity (0x606F) for
 * standstill_time (0x6070), quick stop either stays
 * holding position (option code 6) or switches off (option code 2) and the fault
 * reaction ends in Fault (power off). A nonzero fault_code input, or a following
 * error beyond following_error_window, triggers the fault reaction.
 *
 * Holding brake: closed whenever the power stage is off (from initialisation until
 * Operation enabled, and again in Switch on disabled / Fault), opened when it is on;
 * both instantly. Closed, it is an elasto-plastic friction contact evaluated at every
 * current sample: a spring-damper to the position where it closed, its torque limited
 * to brake_holding_torque (beyond, it slips and the anchor is dragged along). A stop ramp
 * that switches the power stage off (fault reaction, quick stop option 2) ends at
 * standstill, then the motor holds the axis for brake_closing_time while the brake engages;
 * the closed brake's spring starts loaded with the motor's last torque (it takes the load
 * over without the axis moving); other switch-offs close it unloaded. Its
 * torque is part of tau_out (brake_torque output); torque_actual is the motor's only.
 *
 * Units: joint side rad, rad/s, N m; motor current A; voltage V; time s.
 */
#include <math.h>
#include <stdio.h>

#include "fmu_instance.h"

enum {
    CIA_NOT_READY = 0,
    CIA_SWITCH_ON_DISABLED,
    CIA_READY_TO_SWITCH_ON,
    CIA_SWITCHED_ON,
    CIA_OPERATION_ENABLED,
    CIA_QUICK_STOP_ACTIVE,
    CIA_FAULT_REACTION_ACTIVE,
    CIA_FAULT
};

static const char *const CIA_NAME[] = {"Not ready to switch on", "Switch on disabled", "Ready to switch on",
                                       "Switched on", "Operation enabled", "Quick stop active",
                                       "Fault reaction active", "Fault"};

#define ERROR_FOLLOWING 0x8611      /* CiA 402: following error */
#define ERROR_POSITION_LIMIT 0x8612 /* CiA 402: reference (software position) limit */
#define ERROR_OVERSPEED 0x8400      /* CiA 402: velocity speed controller (speed beyond max motor speed) */
#define ERROR_I2T 0x2310            /* CiA 301/402: continuous over current (I2t: derated to the rated current) */
/* bits of limit_status / limit_history (spec.py LIMIT_BITS); + 8: the fault reaction it caused */
#define LIMIT_TORQUE 0x01
#define LIMIT_I2T 0x02
#define LIMIT_SPEED 0x04
#define LIMIT_POSITION 0x08
#define LIMIT_FOLLOWING 0x10
#define MODE_CSP 8  /* cyclic synchronous position */
#define MODE_CSV 9  /* cyclic synchronous velocity */
#define MODE_CST 10 /* cyclic synchronous torque */
#define PI 3.14159265358979323846

#define R(name) (inst->d.r[VR_##name])
#define I(name) (inst->d.i[VR_##name])

static int power_on(int state)
{
    return state == CIA_OPERATION_ENABLED || state == CIA_QUICK_STOP_ACTIVE || state == CIA_FAULT_REACTION_ACTIVE;
}

static int statusword(const ModelState *s)
{
    static const int base[] = {0x0000, 0x0040, 0x0021, 0x0023, 0x0027, 0x0007, 0x000F, 0x0008};
    int sw = base[s->cia_state] | 0x0200; /* bit 9: remote */
    if (s->cia_state >= CIA_READY_TO_SWITCH_ON && s->cia_state <= CIA_FAULT_REACTION_ACTIVE)
        sw |= 0x0010; /* bit 4: voltage enabled */
    if (s->mode_rejected || s->i2t_derated) sw |= 0x0080;             /* bit 7: warning (unsupported mode, I2t) */
    if (power_on(s->cia_state) && s->limit_active) sw |= 0x0800;   /* bit 11: internal limit active */
    if (s->cia_state == CIA_OPERATION_ENABLED) sw |= 0x1000;        /* bit 12 (CSx): drive follows the command value */
    if (s->following_error_flag) sw |= 0x2000;                      /* bit 13 (CSP): following error */
    return sw;
}

static double quantise(const ModelState *s, double q)
{
    return floor(q * s->counts_per_rad) / s->counts_per_rad;
}

/* Protection bit `bit` (LIMIT_*) is active (on) or not, as evaluated at this sample: it stays in
 * limit_status until a later evaluation clears it, and shows for the whole step in which it was set. */
static void limit_bit(ModelState *s, int bit, int on)
{
    if (on) {
        s->active_bits |= bit;
        s->step_bits |= bit;
    } else {
        s->active_bits &= ~bit;
    }
}

static void power_off(ModelState *s)
{
    s->current = 0.0;
    s->u_applied = 0.0;
    s->u_next = 0.0;
    s->current_integral = 0.0;
    s->speed_integral = 0.0;
    s->current_demand = 0.0;
    s->speed_demand = 0.0;
    s->limit_active = 0;
    s->following_error = 0.0;
    s->following_error_flag = 0;
    s->active_bits &= LIMIT_I2T; /* the I2t state outlives the power stage */
}

/* Close the brake when the power stage is off (anchored at the next current sample: at
 * initialisation the inputs may not be set yet), open it otherwise. At the end of a stop ramp
 * and the brake's closing time the engaged brake takes over, where the shaft is, the load the
 * motor held the resting axis with: its spring starts stretched by brake_preload /
 * brake_stiffness (the joint is already deflected by that load; locking the motor shaft does
 * not move it). Any other switch-off (power-up, disable voltage) closes it unloaded. */
static void update_brake(Instance *inst)
{
    ModelState *s = &inst->d.s;
    int closed = R(BRAKE_HOLDING_TORQUE) > 0.0 && !power_on(s->cia_state);
    if (closed && !s->brake_closed) s->brake_anchor_pending = 1;
    if (!closed) s->brake_torque = 0.0;
    s->brake_closed = closed;
}

/* Torque of the closed brake from the measured joint position and speed (elasto-plastic contact). */
static void brake_sample(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double k = R(BRAKE_STIFFNESS), limit = R(BRAKE_HOLDING_TORQUE);
    double stretch, tau;
    if (!s->brake_closed) return;
    if (s->brake_anchor_pending) {
        s->brake_anchor = R(Q_MEAS) + s->brake_preload / k; /* spring torque = the motor's last torque */
        s->brake_anchor_pending = 0;
        s->brake_preload = 0.0;
    }
    stretch = R(Q_MEAS) - s->brake_anchor;
    if (k * fabs(stretch) > limit) { /* slipping: the anchor follows at the holding torque */
        s->brake_anchor = R(Q_MEAS) - copysign(limit / k, stretch);
        stretch = R(Q_MEAS) - s->brake_anchor;
    }
    tau = -k * stretch - R(BRAKE_DAMPING) * R(QD_MEAS);
    s->brake_torque = tau > limit ? limit : (tau < -limit ? -limit : tau);
}

static void enter(Instance *inst, int state)
{
    ModelState *s = &inst->d.s;
    if (state == s->cia_state) return;
    fmu_log(inst, fmi2OK, "logEvents", "t=%.6f s: %s -> %s", inst->d.time, CIA_NAME[s->cia_state], CIA_NAME[state]);
    if (state == CIA_QUICK_STOP_ACTIVE || state == CIA_FAULT_REACTION_ACTIVE) {
        if (s->cia_state != CIA_QUICK_STOP_ACTIVE) { /* start the ramp where the axis is */
            s->ramp_position = s->position_actual;
            s->ramp_velocity = s->speed_filtered;
        }
        if (s->cia_state == CIA_OPERATION_ENABLED && s->mode == MODE_CST)
            s->speed_integral = s->current_demand; /* the speed loop starts from the torque the motor makes */
        s->standstill_samples = 0;
    }
    if (state == CIA_OPERATION_ENABLED) {
        if (s->cia_state != CIA_QUICK_STOP_ACTIVE) power_off(s); /* fresh controller states */
        s->target_prev = R(TARGET_POSITION);
    }
    s->cia_state = state;
    if (!power_on(state)) power_off(s);
    update_brake(inst);
}

static void raise_fault(Instance *inst, int code)
{
    ModelState *s = &inst->d.s;
    s->error_code = code;
    fmu_log(inst, fmi2OK, "logEvents", "t=%.6f s: fault 0x%04X", inst->d.time, (unsigned)code);
    enter(inst, power_on(s->cia_state) ? CIA_FAULT_REACTION_ACTIVE : CIA_FAULT);
}

/* CiA 402 device control (one evaluation per position sample). */
static void state_machine(Instance *inst)
{
    ModelState *s = &inst->d.s;
    int cw = I(CONTROLWORD);
    int fault_reset_edge = (cw & 0x80) && !(s->controlword_prev & 0x80);
    int shutdown = (cw & 0x87) == 0x06;
    int switch_on = (cw & 0x8F) == 0x07;
    int enable = (cw & 0x8F) == 0x0F;
    int disable_voltage = (cw & 0x82) == 0x00;
    int quick_stop = (cw & 0x86) == 0x02;
    s->controlword_prev = cw;

    if (I(FAULT_CODE) != 0 && s->cia_state != CIA_FAULT && s->cia_state != CIA_FAULT_REACTION_ACTIVE) {
        raise_fault(inst, I(FAULT_CODE));
        return;
    }
    switch (s->cia_state) {
    case CIA_NOT_READY:
        enter(inst, CIA_SWITCH_ON_DISABLED);
        break;
    case CIA_SWITCH_ON_DISABLED:
        if (shutdown) enter(inst, CIA_READY_TO_SWITCH_ON);                        /* 2 */
        break;
    case CIA_READY_TO_SWITCH_ON:
        if (switch_on) enter(inst, CIA_SWITCHED_ON);                               /* 3 */
        else if (enable) enter(inst, CIA_OPERATION_ENABLED);                       /* 3 + 4 */
        else if (disable_voltage || quick_stop) enter(inst, CIA_SWITCH_ON_DISABLED); /* 7 */
        break;
    case CIA_SWITCHED_ON:
        if (enable) enter(inst, CIA_OPERATION_ENABLED);                            /* 4 */
        else if (shutdown) enter(inst, CIA_READY_TO_SWITCH_ON);                    /* 6 */
        else if (disable_voltage || quick_stop) enter(inst, CIA_SWITCH_ON_DISABLED); /* 10 */
        break;
    case CIA_OPERATION_ENABLED:
        if (switch_on) enter(inst, CIA_SWITCHED_ON);                               /* 5 */
        else if (shutdown) enter(inst, CIA_READY_TO_SWITCH_ON);                    /* 8 */
        else if (disable_voltage) enter(inst, CIA_SWITCH_ON_DISABLED);             /* 9 */
        else if (quick_stop) enter(inst, CIA_QUICK_STOP_ACTIVE);                   /* 11 */
        break;
    case CIA_QUICK_STOP_ACTIVE:
        if (disable_voltage) enter(inst, CIA_SWITCH_ON_DISABLED);                  /* 12 */
        else if (enable && I(QUICK_STOP_OPTION_CODE) == 6 && s->ramp_velocity == 0.0)
            enter(inst, CIA_OPERATION_ENABLED);                                    /* 16 */
        break;
    case CIA_FAULT_REACTION_ACTIVE:
        break; /* leaves by itself when the ramp has stopped the axis (14) */
    case CIA_FAULT:
        if (fault_reset_edge) {
            s->error_code = 0;
            enter(inst, CIA_SWITCH_ON_DISABLED);                                   /* 15 */
        }
        break;
    }
}

static int mode_supported(int mode)
{
    return mode == MODE_CSP || mode == MODE_CSV || mode == MODE_CST;
}

static const char *mode_name(int mode)
{
    return mode == MODE_CSP ? "CSP" : mode == MODE_CSV ? "CSV" : mode == MODE_CST ? "CST" : "unsupported";
}

/* Make `mode` the active one. In Operation enabled the switch is bumpless: the speed set-point
 * continues from velocity actual, the position loop's reference starts from position actual
 * (position_sample: zero position error at the switch sample) and the speed feed-forward
 * from the target of this sample; leaving CST, the speed integrator takes over the current
 * set-point the motor runs on; entering CST it is cleared (the current set-point follows
 * the target torque from the next speed sample). Returns 1 for a switch in Operation enabled. */
static int switch_mode(Instance *inst, int mode)
{
    ModelState *s = &inst->d.s;
    int live = s->cia_state == CIA_OPERATION_ENABLED;
    fmu_log(inst, fmi2OK, "logEvents", "t=%.6f s: mode of operation %d (%s) -> %d (%s)", inst->d.time, s->mode,
            mode_name(s->mode), mode, mode_name(mode));
    if (live) {
        if (s->mode == MODE_CST)
            s->speed_integral = s->current_demand - R(TORQUE_OFFSET) / (R(GEAR_RATIO) * R(TORQUE_CONSTANT));
        if (mode == MODE_CST) s->speed_integral = 0.0;
        s->speed_demand = s->speed_filtered;
        s->target_prev = R(TARGET_POSITION);
    }
    s->mode = mode;
    return live;
}

/* Take a supported modes_of_operation (0x6060) request (deferred during quick stop and fault
 * reaction); report an unsupported one. Returns 1 when the mode changed in Operation enabled. */
static int select_mode(Instance *inst)
{
    ModelState *s = &inst->d.s;
    int requested = I(MODES_OF_OPERATION);
    if (!mode_supported(requested)) {
        if (!s->mode_rejected || requested != s->mode_rejected_value) {
            s->mode_rejections++;
            fmu_log(inst, fmi2Warning, "logStatusWarning",
                    "t=%.6f s: modes_of_operation (0x6060) = %d is not supported (8 = CSP, 9 = CSV, 10 = CST): "
                    "the drive stays in mode %d (%s)", inst->d.time, requested, s->mode, mode_name(s->mode));
        }
        s->mode_rejected = 1;
        s->mode_rejected_value = requested;
        return 0;
    }
    s->mode_rejected = 0;
    if (requested == s->mode || s->cia_state == CIA_QUICK_STOP_ACTIVE || s->cia_state == CIA_FAULT_REACTION_ACTIVE)
        return 0;
    return switch_mode(inst, requested);
}

/* Software position limits (0x607D) and max motor speed (0x6080), at every position sample with
 * the power stage on: the limit bit while the axis is beyond; in Operation enabled the fault
 * reaction (fault 0x8612 / 0x8400: stop on the fault-reaction ramp, then the brake closes). */
static void supervise(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double lo = R(POSITION_LIMIT_MIN), hi = R(POSITION_LIMIT_MAX), p = s->position_actual;
    int beyond_position, overspeed;
    if (!power_on(s->cia_state)) return;
    beyond_position = lo < hi && (p < lo || p > hi);
    overspeed = fabs(s->speed_filtered) > R(MAX_MOTOR_SPEED);
    limit_bit(s, LIMIT_POSITION, beyond_position);
    limit_bit(s, LIMIT_SPEED, overspeed);
    if (s->cia_state != CIA_OPERATION_ENABLED) return;
    if (beyond_position) {
        fmu_log(inst, fmi2Warning, "logStatusWarning",
                "t=%.6f s: position actual %.6g rad outside the software position limits [%.6g, %.6g] rad (0x607D): "
                "fault 0x%04X", inst->d.time, p, lo, hi, ERROR_POSITION_LIMIT);
        raise_fault(inst, ERROR_POSITION_LIMIT);
    } else if (overspeed) {
        fmu_log(inst, fmi2Warning, "logStatusWarning",
                "t=%.6f s: velocity actual %.6g rad/s beyond the max motor speed %.6g rad/s (0x6080): fault 0x%04X",
                inst->d.time, s->speed_filtered, R(MAX_MOTOR_SPEED), ERROR_OVERSPEED);
        raise_fault(inst, ERROR_OVERSPEED);
    }
}

/* I2t monitoring at every speed sample: the integral of (i^2 - rated^2) (never below 0, so it
 * cools at rated^2 with the power off) reaching (I_max^2 - rated^2) * peak_current_time derates
 * the current limit to rated_current (warning 0x2310 in 0x603F, statusword bit 7) until it has
 * fallen below i2t_release of that threshold. Returns the current limit to apply now. */
static double current_limit_now(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double rated = R(RATED_CURRENT);
    if (s->i2t_threshold <= 0.0) return s->current_max;
    s->i2t += (s->current * s->current - rated * rated) * R(SPEED_SAMPLE_TIME);
    if (s->i2t < 0.0) s->i2t = 0.0;
    if (!s->i2t_derated && s->i2t >= s->i2t_threshold) {
        s->i2t_derated = 1;
        if (s->error_code == 0) s->error_code = ERROR_I2T;
        fmu_log(inst, fmi2Warning, "logStatusWarning",
                "t=%.6f s: I2t %.6g A2s reached its threshold (peak current %.6g A for %.6g s): current limited to the "
                "rated %.6g A, warning 0x%04X", inst->d.time, s->i2t, s->current_max, R(PEAK_CURRENT_TIME), rated,
                ERROR_I2T);
    } else if (s->i2t_derated && s->i2t <= R(I2T_RELEASE) * s->i2t_threshold) {
        s->i2t_derated = 0;
        if (s->error_code == ERROR_I2T) s->error_code = 0;
        fmu_log(inst, fmi2OK, "logEvents", "t=%.6f s: I2t %.6g A2s below %.6g of its threshold: peak current allowed "
                "again", inst->d.time, s->i2t, R(I2T_RELEASE));
    }
    limit_bit(s, LIMIT_I2T, s->i2t_derated);
    if (s->i2t_derated) {
        if (s->error_code == 0) s->error_code = ERROR_I2T; /* again after a fault reset while still derated */
        return fmin(s->current_max, rated);
    }
    return s->current_max;
}

static void position_sample(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double ts = R(POSITION_SAMPLE_TIME);
    double reference, feedforward, error, v;
    int switched;

    s->position_actual = quantise(s, R(Q_MEAS));
    state_machine(inst);
    supervise(inst);
    switched = select_mode(inst);
    if (!power_on(s->cia_state)) {
        s->target_prev = R(TARGET_POSITION);
        return;
    }
    if (s->cia_state == CIA_OPERATION_ENABLED && s->mode != MODE_CSP) {
        s->target_prev = R(TARGET_POSITION);
        s->following_error = 0.0;
        s->following_error_flag = 0;
        s->fe_samples = 0;
        limit_bit(s, LIMIT_FOLLOWING, 0);
        if (s->mode == MODE_CSV) {
            v = R(TARGET_VELOCITY) + R(VELOCITY_OFFSET);
            if (v > R(VELOCITY_LIMIT)) v = R(VELOCITY_LIMIT);
            if (v < -R(VELOCITY_LIMIT)) v = -R(VELOCITY_LIMIT);
            s->speed_demand = v;
        } else {
            s->speed_demand = s->speed_filtered; /* CST: the speed loop is idle */
        }
        return;
    }
    if (s->cia_state == CIA_OPERATION_ENABLED && switched) { /* entering CSP: start from position actual */
        reference = s->position_actual;
        feedforward = s->speed_demand;
        s->target_prev = R(TARGET_POSITION);
    } else if (s->cia_state == CIA_OPERATION_ENABLED) {
        reference = R(TARGET_POSITION);
        feedforward = R(SPEED_FEEDFORWARD_GAIN) * (reference - s->target_prev) / ts;
        s->target_prev = reference;
    } else {
        const double dec = (s->cia_state == CIA_QUICK_STOP_ACTIVE ? R(QUICK_STOP_DECELERATION)
                                                                 : R(FAULT_REACTION_DECELERATION)) * ts;
        double v_old = s->ramp_velocity;
        double v_new = fabs(v_old) <= dec ? 0.0 : v_old - copysign(dec, v_old);
        s->ramp_position += 0.5 * (v_old + v_new) * ts;
        s->ramp_velocity = v_new;
        reference = s->ramp_position;
        feedforward = v_new;
        s->target_prev = R(TARGET_POSITION);
    }
    error = reference - s->position_actual;
    v = R(POSITION_KV) * error + feedforward;
    if (s->cia_state == CIA_OPERATION_ENABLED) v += R(VELOCITY_OFFSET);
    if (v > R(VELOCITY_LIMIT)) v = R(VELOCITY_LIMIT);
    if (v < -R(VELOCITY_LIMIT)) v = -R(VELOCITY_LIMIT);
    s->speed_demand = v;
    s->following_error = error;
    s->following_error_flag = R(FOLLOWING_ERROR_WINDOW) > 0.0 && fabs(error) > R(FOLLOWING_ERROR_WINDOW);
    s->fe_samples = s->following_error_flag ? s->fe_samples + 1 : 0;
    limit_bit(s, LIMIT_FOLLOWING, s->following_error_flag);

    if (s->cia_state == CIA_OPERATION_ENABLED && s->following_error_flag
        && s->fe_samples * ts >= R(FOLLOWING_ERROR_TIME) - 1e-12) { /* window 0x6065 for time 0x6066 */
        fmu_log(inst, fmi2Warning, "logStatusWarning",
                "t=%.6f s: following error %.6g rad beyond the window %.6g rad for %.6g s: fault 0x%04X", inst->d.time,
                error, R(FOLLOWING_ERROR_WINDOW), s->fe_samples * ts, ERROR_FOLLOWING);
        raise_fault(inst, ERROR_FOLLOWING);
    } else if (s->cia_state != CIA_OPERATION_ENABLED) {
        /* standstill: ramp at zero and |speed| <= threshold for standstill_time (0x606F/0x6070);
         * then, before a switch-off, the motor holds the axis for brake_closing_time while the
         * brake engages (counted on whatever the speed does) */
        int still = s->ramp_velocity == 0.0 && fabs(s->speed_filtered) <= R(STANDSTILL_VELOCITY);
        int reached = s->standstill_samples * ts >= R(STANDSTILL_TIME) - 1e-12;
        int closed = s->standstill_samples * ts >= R(STANDSTILL_TIME) + R(BRAKE_CLOSING_TIME) - 1e-12;
        if (!closed) s->standstill_samples = still || reached ? s->standstill_samples + 1 : 0;
        closed = s->standstill_samples * ts >= R(STANDSTILL_TIME) + R(BRAKE_CLOSING_TIME) - 1e-12;
        if (closed && (s->cia_state == CIA_FAULT_REACTION_ACTIVE || I(QUICK_STOP_OPTION_CODE) == 2)) {
            /* the engaged brake takes over the torque the motor holds the resting axis with */
            s->brake_preload = R(GEAR_RATIO) * R(TORQUE_CONSTANT) * s->current;
            if (s->cia_state == CIA_FAULT_REACTION_ACTIVE) enter(inst, CIA_FAULT);          /* 14 */
            else enter(inst, CIA_SWITCH_ON_DISABLED);                                      /* 12 */
        }
    }
}

/* The encoder latch at the sync (SoC): q_meas set at a position-sample instant (before the
 * step that starts there) is what position_actual reports from that instant on, so an importer
 * that sets the inputs at t_k and reads the outputs gets the position at t_k (direct feedthrough,
 * declared in the model structure). The step's position sample latches the same value. */
void model_inputs_set(Instance *inst)
{
    ModelState *s = &inst->d.s;
    if (s->n_position > 0 && s->tick % s->n_position == 0) {
        s->position_actual = quantise(s, R(Q_MEAS));
        R(POSITION_ACTUAL) = s->position_actual;
    }
}

static void speed_sample(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double n = R(GEAR_RATIO), kp = R(SPEED_KP);
    double error, feedforward, demand, limited, imax;

    s->speed_filtered += s->filter_alpha * (R(QD_MEAS) - s->speed_filtered);
    imax = current_limit_now(inst);
    if (!power_on(s->cia_state)) return;
    if (s->cia_state == CIA_OPERATION_ENABLED && s->mode == MODE_CST) {
        demand = (R(TARGET_TORQUE) + R(TORQUE_OFFSET)) / (n * R(TORQUE_CONSTANT));
        limited = demand > imax ? imax : (demand < -imax ? -imax : demand);
        s->limit_active = limited != demand;
        limit_bit(s, LIMIT_TORQUE, s->limit_active); /* the commanded torque is beyond max torque/current */
        s->current_demand = limited;
        return;
    }
    error = n * (s->speed_demand - s->speed_filtered); /* motor side, rad/s */
    feedforward = s->cia_state == CIA_OPERATION_ENABLED ? R(TORQUE_OFFSET) / (n * R(TORQUE_CONSTANT)) : 0.0;
    demand = kp * error + s->speed_integral + feedforward;
    limited = demand > imax ? imax : (demand < -imax ? -imax : demand);
    s->limit_active = limited != demand;
    /* a protection event only when the command itself asks for more (the torque offset 0x60B2):
     * the speed loop's own saturation (e.g. taking the load over when the brake opens) is the
     * drive's regulation, shown in statusword bit 11 only */
    limit_bit(s, LIMIT_TORQUE, fabs(feedforward) > imax);
    /* conditional integration (anti-windup): no integration that drives further into the limit */
    if (!s->limit_active || (demand > 0.0) != (error > 0.0))
        s->speed_integral += kp * R(SPEED_SAMPLE_TIME) / R(SPEED_TN) * error;
    s->current_demand = limited;
}

static void current_sample(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double ts = R(CURRENT_SAMPLE_TIME), kp = R(CURRENT_KP);
    const double emf = R(BACK_EMF_CONSTANT) * R(GEAR_RATIO) * R(QD_MEAS); /* V */
    double error, demand, limited, i_inf;

    if (!power_on(s->cia_state)) {
        s->current = 0.0;
        brake_sample(inst);
        return;
    }
    error = s->current_demand - s->current;
    demand = kp * error + s->current_integral + emf;
    limited = demand > s->voltage_max ? s->voltage_max : (demand < -s->voltage_max ? -s->voltage_max : demand);
    if (limited == demand || (demand > 0.0) != (error > 0.0))
        s->current_integral += kp * ts / R(CURRENT_TN) * error;
    s->u_applied = s->u_next;
    s->u_next = limited;
    /* exact solution of L di/dt = u - R i - emf over one current period */
    i_inf = (s->u_applied - emf) / R(RESISTANCE);
    s->current = i_inf + (s->current - i_inf) * s->decay;
}

static void write_outputs(Instance *inst)
{
    ModelState *s = &inst->d.s;
    int bits;
    const double torque = R(GEAR_RATIO) * R(TORQUE_CONSTANT) * s->current;
    R(TAU_OUT) = torque + s->brake_torque;
    R(BRAKE_TORQUE) = s->brake_torque;
    R(TORQUE_ACTUAL) = torque;
    R(CURRENT_ACTUAL) = s->current;
    R(CURRENT_DEMAND) = s->current_demand;
    R(POSITION_ACTUAL) = s->position_actual;
    R(VELOCITY_ACTUAL) = s->speed_filtered;
    R(FOLLOWING_ERROR) = s->following_error;
    I(STATUSWORD) = statusword(s);
    I(ERROR_CODE) = s->error_code;
    I(MODES_OF_OPERATION_DISPLAY) = s->mode;
    I(UNSUPPORTED_MODE_REQUESTS) = s->mode_rejections;
    bits = s->active_bits | s->step_bits;
    if (s->cia_state == CIA_FAULT_REACTION_ACTIVE || s->cia_state == CIA_FAULT)
        bits |= s->error_code == ERROR_OVERSPEED ? LIMIT_SPEED << 8
              : s->error_code == ERROR_POSITION_LIMIT ? LIMIT_POSITION << 8
              : s->error_code == ERROR_FOLLOWING ? LIMIT_FOLLOWING << 8 : 0;
    s->history_bits |= bits;
    I(LIMIT_STATUS) = bits;
    I(LIMIT_HISTORY) = s->history_bits;
    R(I2T_LEVEL) = s->i2t_threshold > 0.0 ? s->i2t / s->i2t_threshold : 0.0;
}

void model_reset(Instance *inst)
{
    ModelState *s = &inst->d.s;
    s->cia_state = CIA_NOT_READY;
    s->mode = MODE_CSP;
    write_outputs(inst);
}

/* Is `value` an integer multiple (>= 1) of `base`? Writes the multiple to `n`. */
static int multiple_of(double value, double base, int *n)
{
    double ratio = value / base;
    long k = lround(ratio);
    *n = (int)k;
    return k >= 1 && fabs(ratio - (double)k) <= 1e-6;
}

/* Check the parameters and set the state at the start time from them and the inputs
 * (drive in Switch on disabled, brake closed); compute the outputs. Logs only errors. */
static int initial_state(Instance *inst)
{
    ModelState *s = &inst->d.s;
    const double ts_i = R(CURRENT_SAMPLE_TIME);
    int requested = I(MODES_OF_OPERATION);
    if (!multiple_of(R(SPEED_SAMPLE_TIME), ts_i, &s->n_speed) ||
        !multiple_of(R(POSITION_SAMPLE_TIME), ts_i, &s->n_position) ||
        s->n_position % s->n_speed != 0) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "speed_sample_time=%g s and position_sample_time=%g s must be integer multiples of "
                "current_sample_time=%g s, and position_sample_time a multiple of speed_sample_time",
                R(SPEED_SAMPLE_TIME), R(POSITION_SAMPLE_TIME), ts_i);
        return 1;
    }
    if (I(QUICK_STOP_OPTION_CODE) != 2 && I(QUICK_STOP_OPTION_CODE) != 6) {
        fmu_log(inst, fmi2Error, "logStatusError", "quick_stop_option_code=%d, expected 2 or 6",
                I(QUICK_STOP_OPTION_CODE));
        return 1;
    }
    if (!(R(POSITION_LIMIT_MIN) <= R(POSITION_LIMIT_MAX)) || !(R(RATED_CURRENT) > 0.0) ||
        !(R(PEAK_CURRENT_TIME) > 0.0) || !(R(MAX_MOTOR_SPEED) > 0.0) || !(R(FOLLOWING_ERROR_TIME) >= 0.0) ||
        !(R(I2T_RELEASE) >= 0.0 && R(I2T_RELEASE) < 1.0)) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "protection parameters: position_limit_min=%g rad must not exceed position_limit_max=%g rad; "
                "rated_current=%g A, peak_current_time=%g s and max_motor_speed=%g rad/s must be > 0, "
                "following_error_time=%g s >= 0, i2t_release=%g in [0, 1)", R(POSITION_LIMIT_MIN),
                R(POSITION_LIMIT_MAX), R(RATED_CURRENT), R(PEAK_CURRENT_TIME), R(MAX_MOTOR_SPEED),
                R(FOLLOWING_ERROR_TIME), R(I2T_RELEASE));
        return 1;
    }
    s->tick = 0;
    s->counts_per_rad = R(GEAR_RATIO) * (double)I(ENCODER_COUNTS_PER_REV) / (2.0 * PI);
    s->current_max = fmin(R(CURRENT_LIMIT), R(TORQUE_LIMIT) / (R(GEAR_RATIO) * R(TORQUE_CONSTANT)));
    s->i2t_threshold = (s->current_max * s->current_max - R(RATED_CURRENT) * R(RATED_CURRENT)) * R(PEAK_CURRENT_TIME);
    s->i2t = 0.0;
    s->i2t_derated = 0;
    s->step_bits = 0;
    s->active_bits = 0;
    s->history_bits = 0;
    s->fe_samples = 0;
    s->voltage_max = R(BUS_VOLTAGE) / sqrt(3.0);
    s->decay = exp(-R(RESISTANCE) * ts_i / R(INDUCTANCE));
    s->filter_alpha = R(SPEED_FILTER_TIME) > 0.0 ? 1.0 - exp(-R(SPEED_SAMPLE_TIME) / R(SPEED_FILTER_TIME)) : 1.0;
    s->speed_filtered = R(QD_MEAS);
    s->controlword_prev = I(CONTROLWORD);
    s->error_code = 0;
    power_off(s);
    s->brake_closed = 0;
    s->brake_anchor_pending = 0;
    s->brake_torque = 0.0;
    s->brake_preload = 0.0;
    s->cia_state = CIA_SWITCH_ON_DISABLED; /* automatic after initialisation */
    update_brake(inst);                    /* closes the brake */
    s->position_actual = quantise(s, R(Q_MEAS));
    s->target_prev = R(TARGET_POSITION);
    s->mode = mode_supported(requested) ? requested : MODE_CSP;
    s->mode_rejected = !mode_supported(requested);
    s->mode_rejected_value = requested;
    s->mode_rejections = s->mode_rejected;
    write_outputs(inst);
    return 0;
}

int model_initial_outputs(Instance *inst)
{
    return initial_state(inst);
}

int model_initialize(Instance *inst)
{
    ModelState *s = &inst->d.s;
    if (initial_state(inst) != 0) return 1;
    fmu_log(inst, fmi2OK, "logEvents", "t=%.6f s: %s -> %s", inst->d.time, CIA_NAME[CIA_NOT_READY],
            CIA_NAME[s->cia_state]);
    if (s->mode_rejected)
        fmu_log(inst, fmi2Warning, "logStatusWarning",
                "t=%.6f s: modes_of_operation (0x6060) = %d is not supported (8 = CSP, 9 = CSV, 10 = CST): "
                "the drive starts in mode %d (%s)", inst->d.time, s->mode_rejected_value, s->mode, mode_name(s->mode));
    return 0;
}

int model_do_step(Instance *inst, double t, double h)
{
    ModelState *s = &inst->d.s;
    int n_steps, k;
    if (!multiple_of(h, R(CURRENT_SAMPLE_TIME), &n_steps)) {
        fmu_log(inst, fmi2Error, "logStatusError",
                "fmi2DoStep: communicationStepSize=%.9g s is not a multiple of current_sample_time=%g s: "
                "this drive accepts positive integer multiples of its current-loop sample time only", h,
                R(CURRENT_SAMPLE_TIME));
        return MODEL_STEP_REJECTED;
    }
    s->step_bits = 0;
    for (k = 0; k < n_steps; k++) {
        if (s->tick % s->n_position == 0) position_sample(inst);
        if (s->tick % s->n_speed == 0) speed_sample(inst);
        current_sample(inst);
        s->tick++;
    }
    if (!isfinite(s->current) || !isfinite(s->speed_integral) || !isfinite(s->current_integral)) {
        fmu_log(inst, fmi2Error, "logStatusError", "fmi2DoStep: drive state became non-finite at t=%.9g s", t + h);
        return MODEL_STEP_FAILED;
    }
    write_outputs(inst);
    return 0;
}
