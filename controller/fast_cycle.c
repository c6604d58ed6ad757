/* One whole controller cycle on the compiled path, in one foreign call.
 *
 * Compiled into the same library as the CasADi-generated kernel ``controller_cycle``
 * (controller/compiled_cycle.py). ``fast_cycle_run`` does, for a cycle that computes
 * a reference, exactly what controller.Controller does in Python around the kernel,
 * with the same floating-point operations in the same order (bit-identical results):
 *
 *   1. stop check: every drive in Operation enabled (statusword & 0x6F == 0x27) and no
 *      node fault; otherwise return FAST_STOP_CHECK before touching anything (the Python
 *      path decides what to do);
 *   2. kernel(state, ref, h) -> result, tau, info;
 *   3. acceptance: |e|^2 <= accept2, |dq|^2 <= accept2, hadamard >= singular_tol,
 *      lower <= q <= upper; otherwise return FAST_REJECTED with the state, the shaper,
 *      the set-points and the log untouched (the Python path redoes the cycle);
 *   4. on acceptance: state <- result; the controller's q_d, qd_d, qdd_d <- result;
 *      torque offset <- tau (model-based) or 0; target <- the drive set-point shaping of
 *      controller/drive_compensation.py (SetpointShaper.shape, same operation order) or
 *      q; controlwords <- enable operation; the log row (q_d, qd_d, qdd_d, tau_ff,
 *      target, q_obs: 36 doubles) when given; return 0 (converged, 0 IK iterations
 *      reported) or 1 (one Newton step counted).
 *
 * Compile with -ffp-contract=off so no multiply-add is fused (numpy does not fuse).
 */
#include "cycle_outputs.h"

int controller_cycle(const double **arg, double **res, cycle_int *iw, double *w, int mem);

enum { FAST_STOP_CHECK = 2, FAST_REJECTED = -1 };

typedef struct {
    /* kernel call */
    const double **arg;   /* arg[0] = state, arg[1] = ref (set here), arg[2] = &h */
    double **res;         /* res[0] = result, res[1] = tau, res[2] = info */
    cycle_int *iw;
    double *w;
    double *state;        /* 18: q, qd, qdd of the last accepted cycle */
    double *result;       /* 18 */
    double *tau;          /* 6 */
    double *info;         /* 3: |e|^2, |dq|^2, hadamard */
    /* acceptance */
    double accept2, tol2, singular_tol;
    double lower[6], upper[6];
    /* what the cycle writes */
    cycle_int model_based;   /* torque offset = tau (else 0) */
    cycle_outputs out;       /* shaping, what the cycle writes and reads (cycle_outputs.h) */
} fast_plan;

int fast_cycle_run(fast_plan *p, const double *ref, double *log_row)
{
    int i;
    cycle_outputs *o = &p->out;
    if (!cycle_drives_enabled(o)) return FAST_STOP_CHECK;
    p->arg[1] = ref;
    if (controller_cycle(p->arg, p->res, p->iw, p->w, 0) != 0) return FAST_REJECTED;
    const double *r = p->result;
    const double e2 = p->info[0], s2 = p->info[1], hadamard = p->info[2];
    if (!(e2 <= p->accept2 && s2 <= p->accept2 && hadamard >= p->singular_tol)) return FAST_REJECTED;
    for (i = 0; i < 6; ++i) {
        if (!(p->lower[i] <= r[i] && r[i] <= p->upper[i])) return FAST_REJECTED;
    }
    memcpy(p->state, r, 18 * sizeof(double));
    memcpy(o->q_d, r, 6 * sizeof(double));
    memcpy(o->qd_d, r + 6, 6 * sizeof(double));
    memcpy(o->qdd_d, r + 12, 6 * sizeof(double));
    for (i = 0; i < 6; ++i) o->sp_torque[i] = p->model_based ? p->tau[i] : 0.0;
    cycle_write_targets(o, r, r + 6, r + 12);
    cycle_write_log(o, log_row);
    return e2 <= p->tol2 ? 0 : 1;
}
