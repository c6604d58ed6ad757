/*
 * Native stepping kernel of the co-simulation master (cosim/master/kernel.py builds it).
 *
 * One call advances every FMU of a plan over the base ticks [n_from, n_to): for each
 * tick n (time t = start_time + n * base_step) and each slave in stepping order that is
 * due (n % step_ticks == 0): copy its connected inputs on the buses (bus[dst] = bus[src]),
 * set them with fmi2Set{Real,Integer,Boolean}, call fmi2DoStep(t, h) with
 * h = (start_time + (n + step_ticks) * base_step) - t, and read its published variables
 * (outputs first, then probes) with fmi2Get* when it reaches its next communication
 * point: right after its own step in Gauss-Seidel mode, after all slaves of the tick
 * stepped in Jacobi mode. Real outputs are checked for NaN/Inf when read.
 * cosim_refresh sets the inputs of chosen slaves and reads their outputs again between steps
 * (direct feedthrough at a communication point).
 * The semantics are identical to PythonEngine in engines.py (tested).
 */
#define _POSIX_C_SOURCE 199309L
#include <math.h>
#include <stddef.h>
#include <time.h>

typedef int (*set_real_t)(void *, const unsigned int *, size_t, const double *);
typedef int (*get_real_t)(void *, const unsigned int *, size_t, double *);
typedef int (*set_int_t)(void *, const unsigned int *, size_t, const int *);
typedef int (*get_int_t)(void *, const unsigned int *, size_t, int *);
typedef int (*do_step_t)(void *, double, double, int);

enum { REAL = 0, INTEGER = 1, BOOLEAN = 2 };
enum { FAIL_NONE = 0, FAIL_SET = 1, FAIL_STEP = 2, FAIL_GET = 3, FAIL_NONFINITE = 4, FAIL_ENDED = 5 };

typedef struct {
    void *component;
    do_step_t do_step;
    set_real_t set_real;
    set_int_t set_integer;
    set_int_t set_boolean;
    get_real_t get_real;
    get_int_t get_integer;
    get_int_t get_boolean;
    long long step_ticks;
    long long n_in[3];
    const unsigned int *vr_in[3];
    long long in_offset[3];
    long long n_out[3];
    const unsigned int *vr_out[3];
    long long out_offset[3];
    long long n_check;
    long long n_gather[3];
    const long long *gather_dst[3];
    const long long *gather_src[3];
} cosim_slave;

typedef struct {
    long long n_slaves;
    cosim_slave *slaves;
    double *real_bus;
    int *int_bus;
    int *bool_bus;
    double start_time;
    double base_step;
    int gauss_seidel;
    double *step_seconds; /* when not NULL: wall seconds spent inside fmi2DoStep, per slave (profiling) */
    const double *stop_at; /* when not NULL: an FMU that ended the simulation itself wrote the time the run
                              ends (s) here (+inf otherwise); the run stops after the tick that reaches it */
} cosim_plan;

typedef struct {
    long long slave;
    long long tick;
    int what;
    int status;
    long long variable;
} cosim_failure;

static int fmi_failed(int status) { return status > 1; /* Discard, Error, Fatal, Pending */ }

static int publish(const cosim_plan *p, const cosim_slave *s, long long k, long long n, cosim_failure *f)
{
    int st;
    if (s->n_out[REAL]) {
        double *out = p->real_bus + s->out_offset[REAL];
        st = s->get_real(s->component, s->vr_out[REAL], (size_t)s->n_out[REAL], out);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_GET; f->status = st; f->variable = -1; return 1; }
        for (long long i = 0; i < s->n_check; ++i) {
            if (!isfinite(out[i])) { f->slave = k; f->tick = n; f->what = FAIL_NONFINITE; f->status = 0; f->variable = i; return 1; }
        }
    }
    if (s->n_out[INTEGER]) {
        st = s->get_integer(s->component, s->vr_out[INTEGER], (size_t)s->n_out[INTEGER], p->int_bus + s->out_offset[INTEGER]);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_GET; f->status = st; f->variable = -1; return 1; }
    }
    if (s->n_out[BOOLEAN]) {
        st = s->get_boolean(s->component, s->vr_out[BOOLEAN], (size_t)s->n_out[BOOLEAN], p->bool_bus + s->out_offset[BOOLEAN]);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_GET; f->status = st; f->variable = -1; return 1; }
    }
    return 0;
}

/* Copy the slave's connected inputs on the buses and set them (fmi2Set*). */
static int set_inputs(const cosim_plan *p, const cosim_slave *s, long long k, long long n, cosim_failure *f)
{
    int st;
    for (long long i = 0; i < s->n_gather[REAL]; ++i) p->real_bus[s->gather_dst[REAL][i]] = p->real_bus[s->gather_src[REAL][i]];
    for (long long i = 0; i < s->n_gather[INTEGER]; ++i) p->int_bus[s->gather_dst[INTEGER][i]] = p->int_bus[s->gather_src[INTEGER][i]];
    for (long long i = 0; i < s->n_gather[BOOLEAN]; ++i) p->bool_bus[s->gather_dst[BOOLEAN][i]] = p->bool_bus[s->gather_src[BOOLEAN][i]];
    if (s->n_in[REAL]) {
        st = s->set_real(s->component, s->vr_in[REAL], (size_t)s->n_in[REAL], p->real_bus + s->in_offset[REAL]);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_SET; f->status = st; f->variable = -1; return 1; }
    }
    if (s->n_in[INTEGER]) {
        st = s->set_integer(s->component, s->vr_in[INTEGER], (size_t)s->n_in[INTEGER], p->int_bus + s->in_offset[INTEGER]);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_SET; f->status = st; f->variable = -1; return 1; }
    }
    if (s->n_in[BOOLEAN]) {
        st = s->set_boolean(s->component, s->vr_in[BOOLEAN], (size_t)s->n_in[BOOLEAN], p->bool_bus + s->in_offset[BOOLEAN]);
        if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_SET; f->status = st; f->variable = -1; return 1; }
    }
    return 0;
}

static int step(const cosim_plan *p, const cosim_slave *s, long long k, long long n, cosim_failure *f)
{
    int st;
    if (set_inputs(p, s, k, n, f)) return 1;
    double t = p->start_time + (double)n * p->base_step;
    double h = (p->start_time + (double)(n + s->step_ticks) * p->base_step) - t;
    if (p->step_seconds) {
        struct timespec a, b;
        clock_gettime(CLOCK_MONOTONIC, &a);
        st = s->do_step(s->component, t, h, 1);
        clock_gettime(CLOCK_MONOTONIC, &b);
        p->step_seconds[k] += (double)(b.tv_sec - a.tv_sec) + 1e-9 * (double)(b.tv_nsec - a.tv_nsec);
    } else {
        st = s->do_step(s->component, t, h, 1);
    }
    if (fmi_failed(st)) { f->slave = k; f->tick = n; f->what = FAIL_STEP; f->status = st; f->variable = -1; return 1; }
    return 0;
}

/* Slaves whose outputs depend directly on their inputs (cosim_refresh). */
typedef struct {
    const cosim_plan *plan;
    const long long *slaves; /* indices into plan->slaves */
    long long n;
} cosim_refresh_set;

/* At tick n, between steps: set the connected inputs of each listed slave at its communication
 * point (n % step_ticks == 0) as they are on the buses now, and publish its outputs again (FMI
 * direct feedthrough: outputs that depend on the inputs at the same instant). */
int cosim_refresh(const cosim_refresh_set *r, long long n, cosim_failure *fail)
{
    const cosim_plan *p = r->plan;
    for (long long i = 0; i < r->n; ++i) {
        long long k = r->slaves[i];
        const cosim_slave *s = p->slaves + k;
        if (n % s->step_ticks) continue;
        if (set_inputs(p, s, k, n, fail)) return 1;
        if (publish(p, s, k, n, fail)) return 1;
    }
    return 0;
}

/* Advance all slaves over ticks [n_from, n_to). Returns 0, 1 with *fail filled in, or 2 when an FMU
 * ended the simulation itself (fail->tick: the tick the run ends at, fail->what = FAIL_ENDED). */
int cosim_advance(const cosim_plan *p, long long n_from, long long n_to, cosim_failure *fail)
{
    for (long long n = n_from; n < n_to; ++n) {
        for (long long k = 0; k < p->n_slaves; ++k) {
            const cosim_slave *s = p->slaves + k;
            if (n % s->step_ticks) continue;
            if (step(p, s, k, n, fail)) return 1;
            if (p->gauss_seidel && publish(p, s, k, n + s->step_ticks, fail)) return 1;
        }
        if (!p->gauss_seidel) {
            for (long long k = 0; k < p->n_slaves; ++k) {
                const cosim_slave *s = p->slaves + k;
                if ((n + 1) % s->step_ticks) continue;
                if (publish(p, s, k, n + 1, fail)) return 1;
            }
        }
        if (p->stop_at && p->start_time + ((double)n + 1.5) * p->base_step > *p->stop_at) {
            fail->slave = -1; fail->tick = n + 1; fail->what = FAIL_ENDED; fail->status = 0; fail->variable = -1;
            return 2;
        }
    }
    return 0;
}
