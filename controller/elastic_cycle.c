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
#include "cycle_outputs.h"

enum { ELASTIC_PYTHON = 2 };

typedef struct {
    cycle_int n_knots;
    /* references, (n_knots, 6) C-contiguous doubles each */
    const double *link_q, *link_qd, *link_qdd;
    const double *motor_q, *motor_qd, *motor_qdd, *motor_torque;
    cycle_outputs out;  /* shaping, what the cycle writes and reads (cycle_outputs.h) */
} elastic_plan;

int elastic_cycle_run(elastic_plan *p, cycle_int k, double *log_row)
{
    cycle_outputs *o = &p->out;
    if (!cycle_drives_enabled(o)) return ELASTIC_PYTHON;
    if (k < 0 || k >= p->n_knots) return ELASTIC_PYTHON;
    const cycle_int row = 6 * k;
    memcpy(o->q_d, p->link_q + row, 6 * sizeof(double));
    memcpy(o->qd_d, p->link_qd + row, 6 * sizeof(double));
    memcpy(o->qdd_d, p->link_qdd + row, 6 * sizeof(double));
    memcpy(o->sp_torque, p->motor_torque + row, 6 * sizeof(double));
    cycle_write_targets(o, p->motor_q + row, p->motor_qd + row, p->motor_qdd + row);
    cycle_write_log(o, log_row);
    return 0;
}
