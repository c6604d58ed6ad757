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
#include <string.h>

typedef long long int cc_int;

int controller_cycle(const double **arg, double **res, cc_int *iw, double *w, int mem);

enum { FAST_STOP_CHECK = 2, FAST_REJECTED = -1 };

typedef struct {
    /* kernel call */
    const double **arg;   /* arg[0] = state, arg[1] = ref (set here), arg[2] = &h */
    double **res;         /* res[0] = result, res[1] = tau, res[2] = info */
    cc_int *iw;
    double *w;
    double *state;        /* 18: q, qd, qdd of the last accepted cycle */
    double *result;       /* 18 */
    double *tau;          /* 6 */
    double *info;         /* 3: |e|^2, |dq|^2, hadamard */
    /* acceptance */
    double accept2, tol2, singular_tol;
    double lower[6], upper[6];
    /* what the cycle writes */
    cc_int model_based;   /* torque offset = tau (else 0) */
    cc_int shape;         /* drive set-point shaping on */
    double lead[6], g_over_t[6], denominator[6];
    double *shaper_delta, *shaper_q_prev, *shaper_target;  /* SetpointShaper's arrays (6 each) */
    double *q_d, *qd_d, *qdd_d;                           /* Controller's desired motion (6 each) */
    double *sp_position, *sp_torque;                      /* Setpoints arrays (6 each) */
    cc_int *sp_controlword;                               /* Setpoints controlwords (int64, 6) */
    cc_int enable_operation;
    /* what the cycle reads (ObservedActuals, bound by the caller) */
    const cc_int *statusword;                             /* int64, 6 */
    const unsigned char *node_fault;                      /* bool, 6 */
    const double *q_obs;                                  /* rad, 6 */
} fast_plan;

int fast_cycle_run(fast_plan *p, const double *ref, double *log_row)
{
    int i;
    for (i = 0; i < 6; ++i) {
        if ((p->statusword[i] & 0x6F) != 0x27 || p->node_fault[i]) return FAST_STOP_CHECK;
    }
    p->arg[1] = ref;
    if (controller_cycle(p->arg, p->res, p->iw, p->w, 0) != 0) return FAST_REJECTED;
    const double *r = p->result;
    const double e2 = p->info[0], s2 = p->info[1], hadamard = p->info[2];
    if (!(e2 <= p->accept2 && s2 <= p->accept2 && hadamard >= p->singular_tol)) return FAST_REJECTED;
    for (i = 0; i < 6; ++i) {
        if (!(p->lower[i] <= r[i] && r[i] <= p->upper[i])) return FAST_REJECTED;
    }
    memcpy(p->state, r, 18 * sizeof(double));
    memcpy(p->q_d, r, 6 * sizeof(double));
    memcpy(p->qd_d, r + 6, 6 * sizeof(double));
    memcpy(p->qdd_d, r + 12, 6 * sizeof(double));
    for (i = 0; i < 6; ++i) p->sp_torque[i] = p->model_based ? p->tau[i] : 0.0;
    if (p->shape) {
        for (i = 0; i < 6; ++i) {
            const double q = r[i], qd = r[6 + i], qdd = r[12 + i];
            double w = qdd * p->lead[i];
            w += qd;
            w -= p->g_over_t[i] * (q - p->shaper_q_prev[i]);
            w += p->g_over_t[i] * p->shaper_delta[i];
            p->shaper_delta[i] = w / p->denominator[i];
            p->shaper_q_prev[i] = q;
            p->shaper_target[i] = q + p->shaper_delta[i];
            p->sp_position[i] = p->shaper_target[i];
        }
    } else {
        memcpy(p->sp_position, r, 6 * sizeof(double));
    }
    for (i = 0; i < 6; ++i) p->sp_controlword[i] = p->enable_operation;
    if (log_row) {
        memcpy(log_row, r, 18 * sizeof(double));
        memcpy(log_row + 18, p->sp_torque, 6 * sizeof(double));
        memcpy(log_row + 24, p->sp_position, 6 * sizeof(double));
        memcpy(log_row + 30, p->q_obs, 6 * sizeof(double));
    }
    return e2 <= p->tol2 ? 0 : 1;
}
