/*
 * FMI 3.0 co-simulation FMUs behind the FMI 2.0-shaped call interface of fmus.fmu.Fmu.
 *
 * Fmu's per-step calls and the master's engines (cosim/master/kernel.c,
 * engines.PythonEngine) exchange values with an FMU
 * through functions of the form set(component, refs[], n, values[]) on three buses
 * (Real = double, Integer = int, Boolean = int) and step it with do_step(component, t,
 * h, noSetFMUStatePriorToCurrentPoint). For an FMI 3.0 FMU, `component` is an a3_ctx
 * and `refs` are indices into its table of bus elements: one entry per scalar or per
 * array element, knowing its FMI 3.0 type, value reference and place in the array.
 *
 * Setting converts the bus value into the variable's own type in a shadow copy of the
 * whole variable (an array is set as a whole, with its other elements as last set), and
 * refuses a value the type cannot hold; getting reads the whole variable and converts
 * each element onto the bus, refusing a 64-bit or UInt32 value outside the Integer bus
 * (32-bit int). Clocks travel on the Boolean bus (1 = ticked at the last communication
 * point's event), Binary variables on the Integer bus as their size in bytes.
 *
 * Stepping calls fmi3DoStep; an FMU that asks for event handling (instantiated with
 * eventModeUsed when it has an event mode) gets fmi3EnterEventMode, its output clocks
 * read, fmi3UpdateDiscreteStates until it needs no more, and fmi3EnterStepMode. An FMU
 * that sets terminateSimulation (with fmi3OK, fmi3Warning or fmi3Discard) is not an error:
 * the adapter writes the end of that step into *stop_at, which the engines read after
 * each base tick to end the run normally, and steps it no more. earlyReturn is never
 * allowed (earlyReturnAllowed = false); an FMU returning early anyway fails the step.
 */
#include <float.h>
#include <math.h>
#include <stdbool.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <string.h>

enum { F32 = 0, F64, I8, U8, I16, U16, I32, U32, I64, U64, BOOLEAN, BINARY, CLOCK };
#define N_VALUE_TYPES 11

typedef int (*set_fn)(void *, const unsigned *, size_t, const void *, size_t);
typedef int (*get_fn)(void *, const unsigned *, size_t, void *, size_t);
typedef int (*get_binary_fn)(void *, const unsigned *, size_t, size_t *, const uint8_t **, size_t);
typedef int (*get_clock_fn)(void *, const unsigned *, size_t, bool *);
typedef int (*do_step_fn)(void *, double, double, bool, bool *, bool *, bool *, double *);
typedef int (*mode_fn)(void *);
typedef int (*update_fn)(void *, bool *, bool *, bool *, bool *, bool *, double *);

typedef struct {
    unsigned vr;        /* FMI 3.0 value reference of the variable */
    int type;           /* F32 .. CLOCK */
    long long count;    /* elements of the variable (1 for a scalar) */
    long long element;  /* this entry's element (row-major) */
    long long shadow;   /* byte offset of the variable's shadow copy */
} a3_entry;

typedef struct {
    void *instance;
    void *set[N_VALUE_TYPES];
    void *get[N_VALUE_TYPES];
    void *get_binary;
    void *get_clock;
    void *do_step;
    void *enter_event_mode;
    void *update_discrete_states;
    void *enter_step_mode;
    a3_entry *entries;
    long long n_entries;
    unsigned char *shadow;
    const unsigned *clock_vrs; /* output clocks read in event mode */
    const long long *clock_shadow;
    long long n_clocks;
    int event_mode_used;
    double *stop_at;           /* shared with the engines; +inf until an FMU ends the run */
    /* filled in by the adapter */
    int terminated;
    int end_status;
    double last_successful_time;
    long long events;
    long long failed_entry;
    char message[256];
} a3_ctx;

static const size_t SIZE_OF[] = {4, 8, 1, 1, 2, 2, 4, 4, 8, 8, sizeof(bool), sizeof(size_t), sizeof(bool)};
static const char *const TYPE_NAME[] = {"Float32", "Float64", "Int8", "UInt8", "Int16", "UInt16", "Int32",
                                        "UInt32", "Int64", "UInt64", "Boolean", "Binary", "Clock"};

static void *slot(a3_ctx *c, const a3_entry *e) { return c->shadow + e->shadow + e->element * (long long)SIZE_OF[e->type]; }

static int refuse(a3_ctx *c, long long entry, const char *fmt, double value)
{
    c->failed_entry = entry;
    snprintf(c->message, sizeof c->message, fmt, value, TYPE_NAME[c->entries[entry].type]);
    return 3; /* fmi3Error */
}

static int same_variable(const a3_entry *a, const a3_entry *b) { return a->vr == b->vr && a->type == b->type; }

#define BATCH 64 /* scalars of one type set or got with one FMI call */

/* Length of the run of scalars of one type starting at refs[k] (at most BATCH). */
static size_t scalar_run(const a3_ctx *c, const unsigned *refs, size_t n, size_t k)
{
    const a3_entry *e = c->entries + refs[k];
    size_t j = k;
    if (e->count != 1 || e->type == BINARY || e->type == CLOCK) return 0;
    while (j < n && j - k < BATCH) {
        const a3_entry *f = c->entries + refs[j];
        if (f->count != 1 || f->type != e->type) break;
        ++j;
    }
    return j - k;
}

/* Call the FMI 3.0 setters for the variables among refs (after the shadows are filled): one call per
 * run of scalars of one type, one per array (set whole, with its other elements as last set). */
static int flush_sets(a3_ctx *c, const unsigned *refs, size_t n)
{
    unsigned vrs[BATCH];
    unsigned char values[BATCH * 8];
    size_t k = 0;
    while (k < n) {
        const a3_entry *e = c->entries + refs[k];
        size_t m = scalar_run(c, refs, n, k), size = SIZE_OF[e->type];
        int st;
        if (m > 0) {
            for (size_t i = 0; i < m; ++i) {
                const a3_entry *f = c->entries + refs[k + i];
                vrs[i] = f->vr;
                memcpy(values + i * size, c->shadow + f->shadow, size);
            }
            st = ((set_fn)c->set[e->type])(c->instance, vrs, m, values, m);
            if (st > 1) { c->failed_entry = refs[k]; c->message[0] = 0; return st; }
            k += m;
            continue;
        }
        while (k + 1 < n && same_variable(e, c->entries + refs[k + 1])) ++k;
        st = ((set_fn)c->set[e->type])(c->instance, &e->vr, 1, c->shadow + e->shadow, (size_t)e->count);
        if (st > 1) { c->failed_entry = refs[k]; c->message[0] = 0; return st; }
        ++k;
    }
    return 0;
}

/* Set variables whose shadows the caller filled (start values). */
int a3_flush(a3_ctx *c, const unsigned *refs, size_t n) { return flush_sets(c, refs, n); }

int a3_set_real(a3_ctx *c, const unsigned *refs, size_t n, const double *values)
{
    for (size_t k = 0; k < n; ++k) {
        const a3_entry *e = c->entries + refs[k];
        double v = values[k];
        if (e->type == F64) *(double *)slot(c, e) = v;
        else if (isfinite(v) && fabs(v) > FLT_MAX) return refuse(c, refs[k], "value %.17g is outside the range of %s", v);
        else *(float *)slot(c, e) = (float)v;
    }
    return flush_sets(c, refs, n);
}

int a3_set_integer(a3_ctx *c, const unsigned *refs, size_t n, const int *values)
{
    for (size_t k = 0; k < n; ++k) {
        const a3_entry *e = c->entries + refs[k];
        long long v = values[k];
        void *p = slot(c, e);
        switch (e->type) {
        case I8: if (v < INT8_MIN || v > INT8_MAX) goto range; *(int8_t *)p = (int8_t)v; break;
        case U8: if (v < 0 || v > UINT8_MAX) goto range; *(uint8_t *)p = (uint8_t)v; break;
        case I16: if (v < INT16_MIN || v > INT16_MAX) goto range; *(int16_t *)p = (int16_t)v; break;
        case U16: if (v < 0 || v > UINT16_MAX) goto range; *(uint16_t *)p = (uint16_t)v; break;
        case I32: *(int32_t *)p = (int32_t)v; break;
        case U32: if (v < 0) goto range; *(uint32_t *)p = (uint32_t)v; break;
        case I64: *(int64_t *)p = (int64_t)v; break;
        case U64: if (v < 0) goto range; *(uint64_t *)p = (uint64_t)v; break;
        default: return refuse(c, refs[k], "value %g cannot be set into a %s variable", (double)v);
        }
        continue;
    range:
        return refuse(c, refs[k], "value %.0f is outside the range of %s", (double)v);
    }
    return flush_sets(c, refs, n);
}

int a3_set_boolean(a3_ctx *c, const unsigned *refs, size_t n, const int *values)
{
    for (size_t k = 0; k < n; ++k) {
        const a3_entry *e = c->entries + refs[k];
        if (e->type != BOOLEAN) return refuse(c, refs[k], "value %g cannot be set into a %s variable", values[k]);
        *(bool *)slot(c, e) = values[k] != 0;
    }
    return flush_sets(c, refs, n);
}

/* Read the variables among refs into their shadows: one call per run of scalars of one type, one per
 * array or Binary; clocks are read in event mode only (a3_event_iteration). */
static int fetch(a3_ctx *c, const unsigned *refs, size_t n)
{
    unsigned vrs[BATCH];
    unsigned char values[BATCH * 8];
    size_t k = 0;
    while (k < n) {
        const a3_entry *e = c->entries + refs[k];
        size_t m = scalar_run(c, refs, n, k), size = SIZE_OF[e->type];
        int st = 0;
        if (m > 0) {
            for (size_t i = 0; i < m; ++i) vrs[i] = c->entries[refs[k + i]].vr;
            st = ((get_fn)c->get[e->type])(c->instance, vrs, m, values, m);
            if (st > 1) { c->failed_entry = refs[k]; c->message[0] = 0; return st; }
            for (size_t i = 0; i < m; ++i) memcpy(c->shadow + c->entries[refs[k + i]].shadow, values + i * size, size);
            k += m;
            continue;
        }
        while (k + 1 < n && same_variable(e, c->entries + refs[k + 1])) ++k;
        if (e->type == BINARY) {
            const uint8_t *data[64]; /* the bytes stay the FMU's; the bus carries each value's size */
            size_t count = (size_t)e->count;
            if (count > 64) { c->failed_entry = refs[k]; snprintf(c->message, sizeof c->message, "Binary arrays of more than 64 elements are not supported"); return 3; }
            st = ((get_binary_fn)c->get_binary)(c->instance, &e->vr, 1, (size_t *)(c->shadow + e->shadow), data, count);
        } else if (e->type != CLOCK) {
            st = ((get_fn)c->get[e->type])(c->instance, &e->vr, 1, c->shadow + e->shadow, (size_t)e->count);
        }
        if (st > 1) { c->failed_entry = refs[k]; c->message[0] = 0; return st; }
        ++k;
    }
    return 0;
}

int a3_get_real(a3_ctx *c, const unsigned *refs, size_t n, double *values)
{
    int st = fetch(c, refs, n);
    if (st) return st;
    for (size_t k = 0; k < n; ++k) {
        const a3_entry *e = c->entries + refs[k];
        values[k] = e->type == F64 ? *(double *)slot(c, e) : (double)*(float *)slot(c, e);
    }
    return 0;
}

int a3_get_integer(a3_ctx *c, const unsigned *refs, size_t n, int *values)
{
    int st = fetch(c, refs, n);
    if (st) return st;
    for (size_t k = 0; k < n; ++k) {
        const a3_entry *e = c->entries + refs[k];
        void *p = slot(c, e);
        long long v;
        switch (e->type) {
        case I8: v = *(int8_t *)p; break;
        case U8: v = *(uint8_t *)p; break;
        case I16: v = *(int16_t *)p; break;
        case U16: v = *(uint16_t *)p; break;
        case I32: v = *(int32_t *)p; break;
        case U32: v = *(uint32_t *)p; break;
        case I64: v = *(int64_t *)p; break;
        case U64:
            if (*(uint64_t *)p > (uint64_t)INT32_MAX) return refuse(c, refs[k], "value %.0f of a %s output does not fit the master's 32-bit Integer bus", (double)*(uint64_t *)p);
            v = (long long)*(uint64_t *)p;
            break;
        case BINARY: v = (long long)*(size_t *)p; break;
        default: return refuse(c, refs[k], "%g: a %s variable is not on the Integer bus", 0.0);
        }
        if (v < INT32_MIN || v > INT32_MAX) return refuse(c, refs[k], "value %.0f of a %s output does not fit the master's 32-bit Integer bus", (double)v);
        values[k] = (int)v;
    }
    return 0;
}

int a3_get_boolean(a3_ctx *c, const unsigned *refs, size_t n, int *values)
{
    int st = fetch(c, refs, n);
    if (st) return st;
    for (size_t k = 0; k < n; ++k) values[k] = *(bool *)slot(c, c->entries + refs[k]) ? 1 : 0;
    return 0;
}

static void end_run(a3_ctx *c, int status, double at)
{
    c->terminated = 1;
    c->end_status = status;
    c->last_successful_time = at;
    if (c->stop_at && at < *c->stop_at) *c->stop_at = at;
}

/* Event mode after a step (or after initialization): clocks, discrete-state iteration, step mode. */
int a3_event_iteration(a3_ctx *c, double t, int enter)
{
    int st;
    bool need = true, terminate = false, nominals, values, next_defined;
    double next;
    if (enter) {
        st = ((mode_fn)c->enter_event_mode)(c->instance);
        if (st > 1) { snprintf(c->message, sizeof c->message, "fmi3EnterEventMode failed"); return st; }
    }
    c->events += 1;
    for (long long i = 0; i < c->n_clocks; ++i) {
        bool active = false;
        st = ((get_clock_fn)c->get_clock)(c->instance, c->clock_vrs + i, 1, &active);
        if (st > 1) { snprintf(c->message, sizeof c->message, "fmi3GetClock failed"); return st; }
        *(bool *)(c->shadow + c->clock_shadow[i]) = active;
    }
    for (int iteration = 0; need; ++iteration) {
        if (iteration == 100) { snprintf(c->message, sizeof c->message, "fmi3UpdateDiscreteStates still asks for an update after 100 iterations"); return 3; }
        st = ((update_fn)c->update_discrete_states)(c->instance, &need, &terminate, &nominals, &values, &next_defined, &next);
        if (st > 1) { snprintf(c->message, sizeof c->message, "fmi3UpdateDiscreteStates failed"); return st; }
        if (terminate) { end_run(c, st, t); break; }
    }
    st = ((mode_fn)c->enter_step_mode)(c->instance);
    if (st > 1) { snprintf(c->message, sizeof c->message, "fmi3EnterStepMode failed"); return st; }
    return 0;
}

int a3_do_step(a3_ctx *c, double t, double h, int no_set_prior)
{
    bool event = false, terminate = false, early = false;
    double last = t;
    int st;
    if (c->terminated) return 0; /* ended itself: the run stops at the end of this tick */
    for (long long i = 0; i < c->n_clocks; ++i) *(bool *)(c->shadow + c->clock_shadow[i]) = false;
    st = ((do_step_fn)c->do_step)(c->instance, t, h, no_set_prior != 0, &event, &terminate, &early, &last);
    if (terminate && st <= 2) {
        end_run(c, st, early ? last : t + h);
        return 0;
    }
    if (st > 1) { c->message[0] = 0; return st; }
    if (early) {
        snprintf(c->message, sizeof c->message, "fmi3DoStep returned early (earlyReturn = true at t = %.9g s) although "
                 "the master instantiated it with earlyReturnAllowed = false", last);
        return 3;
    }
    if (event && c->event_mode_used) {
        int est = a3_event_iteration(c, t + h, 1);
        if (est > 1) return est;
    }
    return st;
}
