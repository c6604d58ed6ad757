/* What both compiled controller cycles (fast_cycle.c: the IK kernel's cycle; elastic_cycle.c:
 * the elastic feed-forward's cycle) share: the arrays a computing cycle writes and reads, and
 * the steps they do alike, with the floating-point operations of the Python path in its order
 * (bit-identical results; compile with -ffp-contract=off).
 *
 * Mirrored by controller.compiled_cycle.CycleOutputs; included by both sources, which
 * native.build compiles with this header next to them and hashes into their cache key. */
#ifndef CONTROLLER_CYCLE_OUTPUTS_H
#define CONTROLLER_CYCLE_OUTPUTS_H

#include <string.h>

typedef long long int cycle_int;

typedef struct {
    /* drive set-point shaping (controller/drive_compensation.py, SetpointShaper) */
    cycle_int shape;                                      /* shaping on */
    double lead[6], g_over_t[6], denominator[6];
    double *shaper_delta, *shaper_q_prev, *shaper_target;  /* SetpointShaper's arrays (6 each) */
    /* what the cycle writes */
    double *q_d, *qd_d, *qdd_d;                           /* Controller's desired motion (6 each) */
    double *sp_position, *sp_torque;                      /* Setpoints arrays (6 each) */
    cycle_int *sp_controlword;                            /* Setpoints controlwords (int64, 6) */
    cycle_int enable_operation;
    /* what the cycle reads (ObservedActuals, bound by the caller) */
    const cycle_int *statusword;                          /* int64, 6 */
    const unsigned char *node_fault;                      /* bool, 6 */
    const double *q_obs;                                  /* rad, 6 */
} cycle_outputs;

/* The stop check: every drive in Operation enabled (statusword & 0x6F == 0x27), no node fault. */
static int cycle_drives_enabled(const cycle_outputs *o)
{
    int i;
    for (i = 0; i < 6; ++i) {
        if ((o->statusword[i] & 0x6F) != 0x27 || o->node_fault[i]) return 0;
    }
    return 1;
}

/* Position set-points from the drive reference q, qd, qdd (6 each): SetpointShaper.shape
 * (same operation order) when shaping is on, else q; controlwords <- enable operation. */
static void cycle_write_targets(cycle_outputs *o, const double *q, const double *qd, const double *qdd)
{
    int i;
    if (o->shape) {
        for (i = 0; i < 6; ++i) {
            double w = qdd[i] * o->lead[i];
            w += qd[i];
            w -= o->g_over_t[i] * (q[i] - o->shaper_q_prev[i]);
            w += o->g_over_t[i] * o->shaper_delta[i];
            o->shaper_delta[i] = w / o->denominator[i];
            o->shaper_q_prev[i] = q[i];
            o->shaper_target[i] = q[i] + o->shaper_delta[i];
            o->sp_position[i] = o->shaper_target[i];
        }
    } else {
        memcpy(o->sp_position, q, 6 * sizeof(double));
    }
    for (i = 0; i < 6; ++i) o->sp_controlword[i] = o->enable_operation;
}

/* The log row (q_d, qd_d, qdd_d, tau_ff, target, q_obs: 36 doubles), when given. */
static void cycle_write_log(const cycle_outputs *o, double *log_row)
{
    if (!log_row) return;
    memcpy(log_row, o->q_d, 6 * sizeof(double));
    memcpy(log_row + 6, o->qd_d, 6 * sizeof(double));
    memcpy(log_row + 12, o->qdd_d, 6 * sizeof(double));
    memcpy(log_row + 18, o->sp_torque, 6 * sizeof(double));
    memcpy(log_row + 24, o->sp_position, 6 * sizeof(double));
    memcpy(log_row + 30, o->q_obs, 6 * sizeof(double));
}

#endif
