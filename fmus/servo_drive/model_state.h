/* Internal state of one servo drive axis (see servo_drive.c). Plain data only: the
 * FMI wrapper copies it for fmi2GetFMUstate. Speeds/positions joint side, currents
 * motor q-axis, voltages q-axis. */
#ifndef MODEL_STATE_H
#define MODEL_STATE_H

/* servo_drive.c computes its outputs in Initialization Mode (model_initial_outputs) */
#define MODEL_INITIAL_OUTPUTS 1
/* position_actual latches q_meas when it is set at a position sample (model_inputs_set) */
#define MODEL_INPUTS_SET 1

typedef struct {
    /* timing */
    long long tick;          /* current-loop samples done since the start time */
    int n_speed;             /* current samples per speed sample */
    int n_position;          /* current samples per position sample */

    /* CiA 402 */
    int cia_state;           /* one of the CIA_* values of servo_drive.c */
    int controlword_prev;    /* for the rising edge of the fault-reset bit */
    int error_code;          /* 0x603F */
    int limit_active;        /* current set-point clamped at the last speed sample */
    int following_error_flag;/* |following error| > window at the last position sample */
    int mode;                /* active mode of operation (0x6061): 8 CSP, 9 CSV, 10 CST */
    int mode_rejected;       /* 1 while modes_of_operation (0x6060) holds an unsupported value */
    int mode_rejected_value; /* that value (a new one is counted and logged once) */
    int mode_rejections;     /* number of unsupported mode requests so far */

    /* electrical motor and current loop */
    double current;          /* A */
    double u_applied;        /* V, on the winding during the running current period */
    double u_next;           /* V, computed at the last current sample, applied from the next */
    double current_integral; /* V, PI integral part */

    /* speed loop */
    double speed_filtered;   /* rad/s, actual-speed filter output */
    double speed_integral;   /* A, PI integral part */
    double current_demand;   /* A, current set-point held until the next speed sample */

    /* position loop */
    double speed_demand;     /* rad/s, speed set-point held until the next position sample */
    double target_prev;      /* rad, target at the previous position sample (speed feed-forward) */
    double position_actual;  /* rad, quantised encoder position latched at the last position sample */
    double following_error;  /* rad */
    double ramp_position;    /* rad, quick-stop / fault-reaction reference */
    double ramp_velocity;    /* rad/s */
    int standstill_samples;  /* position samples at standstill since the ramp ended */

    /* holding brake (closed while the power stage is off) */
    int brake_closed;        /* 1 while the brake holds */
    int brake_anchor_pending;/* 1: closed, the anchor is taken at the next current sample */
    double brake_anchor;     /* rad, where the closed brake's spring is relaxed */
    double brake_torque;     /* N m joint side, at the last current sample */
    double brake_preload;    /* N m joint side: the motor's torque when the power stage switched off,
                                taken over by the brake as it closes (0 at power-up) */

    /* protection (docs/explanation/fmus.md "Protection") */
    int active_bits;         /* LIMIT_* bits active as last evaluated */
    int step_bits;           /* LIMIT_* bits active at any sample of the running step */
    int history_bits;        /* every bit limit_status has had since the start */
    int i2t_derated;         /* 1: current limited to rated_current by the I2t monitoring */
    double i2t;              /* A^2 s, integral of (i^2 - rated^2), never below 0 */
    int fe_samples;          /* position samples in a row with the following error beyond its window */

    /* constants derived from the parameters at initialization */
    double counts_per_rad;   /* encoder counts per joint rad */
    double current_max;      /* A, min(current_limit, torque_limit / (N kt)) */
    double i2t_threshold;    /* A^2 s, (current_max^2 - rated_current^2) * peak_current_time (<= 0: off) */
    double voltage_max;      /* V, bus_voltage / sqrt(3) */
    double decay;            /* exp(-R Ts_i / L) */
    double filter_alpha;     /* 1 - exp(-Ts_w / T_filter) */
} ModelState;

#endif
