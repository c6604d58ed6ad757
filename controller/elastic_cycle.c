/* One computing cycle of the elastic feed-forward controller (mode model_based_elastic) in one
 * foreign call; bound and called by controller/elastic.py (ElasticController).
 *
 * For a settling, tracking or finished cycle at knot k of the precomputed references, it does
 * exactly what ElasticController does in Python (Controller.run_cycle around
 * ElasticController._compute), with the same floating-point operations in the same order
 * (bit-identical results):
 *
 *   1. stop check: every drive in Operation enabled (statusword & 0x6F == 0x27) and no node
 *      fault, and 0 <= k < n_knots; otherwise return ELASTIC_PYTHON before touching anything
 *      (the Python path decides what to do);
 *   2. q_d, qd_d, qdd_d <- the link reference at knot k; torque offset <- the motor reference's
 *      torque at k;
 *   3. target <- the drive set-point shaping of controller/drive_compensation.py
 *      (SetpointShaper.shape of the motor reference at k, same operation order: the Python
 *      path's in-order shortcut ElasticController._shape gives the same bits), or the motor
 *      reference's q at k without shaping;
 *   4. controlwords <- enable operation; the log row (q_d, qd_d, qdd_d, tau_ff, target, q_obs:
 *      36 doubles) when given; return 0.
 *
 * Compile with -ffp-contract=off so no multiply-add is fused (numpy does not fuse).
 */
#include <string.h>

typedef long long int ec_int;

enum { ELASTIC_PYTHON = 2 };

typedef struct {
    ec_int n_knots;
    /* references, (n_knots, 6) C-contiguous doubles each */
    const double *link_q, *link_qd, *link_qdd;
    const double *motor_q, *motor_qd, *motor_qdd, *motor_torque;
    /* drive set-point shaping */
    ec_int shape;
    double lead[6], g_over_t[6], denominator[6];
    double *shaper_delta, *shaper_q_prev, *shaper_target;  /* SetpointShaper's arrays (6 each) */
    /* what the cycle writes */
    double *q_d, *qd_d, *qdd_d;                           /* Controller's desired motion (6 each) */
    double *sp_position, *sp_torque;                      /* Setpoints arrays (6 each) */
    ec_int *sp_controlword;                               /* Setpoints controlwords (int64, 6) */
    ec_int enable_operation;
    /* what the cycle reads (ObservedActuals, bound by the caller) */
    const ec_int *statusword;                             /* int64, 6 */
    const unsigned char *node_fault;                      /* bool, 6 */
    const double *q_obs;                                  /* rad, 6 */
} elastic_plan;

int elastic_cycle_run(elastic_plan *p, ec_int k, double *log_row)
{
    int i;
    for (i = 0; i < 6; ++i) {
        if ((p->statusword[i] & 0x6F) != 0x27 || p->node_fault[i]) return ELASTIC_PYTHON;
    }
    if (k < 0 || k >= p->n_knots) return ELASTIC_PYTHON;
    const ec_int row = 6 * k;
    memcpy(p->q_d, p->link_q + row, 6 * sizeof(double));
    memcpy(p->qd_d, p->link_qd + row, 6 * sizeof(double));
    memcpy(p->qdd_d, p->link_qdd + row, 6 * sizeof(double));
    memcpy(p->sp_torque, p->motor_torque + row, 6 * sizeof(double));
    if (p->shape) {
        const double *q = p->motor_q + row, *qd = p->motor_qd + row, *qdd = p->motor_qdd + row;
        for (i = 0; i < 6; ++i) {
            double w = qdd[i] * p->lead[i];
            w += qd[i];
            w -= p->g_over_t[i] * (q[i] - p->shaper_q_prev[i]);
            w += p->g_over_t[i] * p->shaper_delta[i];
            p->shaper_delta[i] = w / p->denominator[i];
            p->shaper_q_prev[i] = q[i];
            p->shaper_target[i] = q[i] + p->shaper_delta[i];
            p->sp_position[i] = p->shaper_target[i];
        }
    } else {
        memcpy(p->sp_position, p->motor_q + row, 6 * sizeof(double));
    }
    for (i = 0; i < 6; ++i) p->sp_controlword[i] = p->enable_operation;
    if (log_row) {
        memcpy(log_row, p->q_d, 6 * sizeof(double));
        memcpy(log_row + 6, p->qd_d, 6 * sizeof(double));
        memcpy(log_row + 12, p->qdd_d, 6 * sizeof(double));
        memcpy(log_row + 18, p->sp_torque, 6 * sizeof(double));
        memcpy(log_row + 24, p->sp_position, 6 * sizeof(double));
        memcpy(log_row + 30, p->q_obs, 6 * sizeof(double));
    }
    return 0;
}
