/*
 * The FMI bookkeeping that fmi2_wrapper.c and fmi3_wrapper.c share: logging, mode
 * checks, start values, the range/causality check of a set value, the step itself and
 * FMU state snapshots. Included by exactly one wrapper per build (after fmu_instance.h
 * and, for FMI 3.0, fmi3_variables.h); every function here is static except fmu_log.
 * Each function takes the name of the FMI function it serves (`fn`) for its messages,
 * so both wrappers log exactly what they logged before this file existed.
 *
 * Under -DFMU_FMI3, fmi2Status and the fmi2OK.. names are the FMI 3.0 ones
 * (fmu_instance.h), so the code below is the same for both versions.
 */
#ifndef FMU_WRAPPER_H
#define FMU_WRAPPER_H

#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_instance.h"

#ifdef FMU_FMI3
#define FMU_TOKEN MODEL_TOKEN3 /* instantiationToken (fmi3_variables.h) */
#define FMI_PREFIX "fmi3"
#else
#define FMU_TOKEN MODEL_GUID
#define FMI_PREFIX "fmi2"
#endif

#define MAX_MESSAGE 1024
#define STATE_MAGIC 0x52583133u /* "RX13" */

static const char *const MODE_NAME[] = {"instantiated", "initialization", "step", "terminated", "error"};

void fmu_log(const Instance *inst, fmi2Status status, const char *category, const char *fmt, ...)
{
    char message[MAX_MESSAGE];
    va_list args;
    if (!inst || !inst->functions.logger) return;
    if (status < fmi2Warning && !inst->logging_on) return;
    va_start(args, fmt);
    vsnprintf(message, sizeof message, fmt, args);
    va_end(args);
#ifdef FMU_FMI3
    inst->functions.logger(inst->functions.environment, status, category, message);
#else
    /* "%s" keeps a '%' inside the message from being read as a format directive */
    inst->functions.logger(inst->functions.componentEnvironment, inst->instance_name, status,
                           category, "%s", message);
#endif
}

#define LOG_ERROR(inst, ...) fmu_log((inst), fmi2Error, "logStatusError", __VA_ARGS__)

static fmi2Status reject_mode(Instance *inst, const char *fn)
{
    LOG_ERROR(inst, "%s: not allowed in %s mode", fn, MODE_NAME[inst->d.mode]);
    return fmi2Error;
}

static void set_start_values(Instance *inst)
{
    int k;
    memset(&inst->d, 0, sizeof inst->d);
    inst->d.mode = MODE_INSTANTIATED;
    for (k = 0; k < N_REALS; k++) inst->d.r[k] = REAL_START[k];
    for (k = 0; k < N_INTEGERS; k++) inst->d.i[k] = INTEGER_START[k];
    model_reset(inst);
}

/* A new instance named `name` with the callbacks of `probe` (whose logger reports any
 * failure), at its start values; NULL when out of memory. */
static Instance *new_instance(const Instance *probe, const char *name, int logging_on, const char *fn)
{
    Instance *inst = (Instance *)calloc(1, sizeof *inst);
    if (!inst) {
        LOG_ERROR(probe, "%s: out of memory", fn);
        return NULL;
    }
    inst->instance_name = (char *)malloc(strlen(name) + 1);
    if (!inst->instance_name) {
        free(inst);
        LOG_ERROR(probe, "%s: out of memory", fn);
        return NULL;
    }
    strcpy(inst->instance_name, name);
    inst->functions = probe->functions;
    inst->logging_on = logging_on ? 1 : 0;
    set_start_values(inst);
    return inst;
}

static void free_instance(Instance *inst)
{
    if (!inst) return;
    free(inst->instance_name);
    free(inst);
}

/* Check and set the start time (fmi2SetupExperiment, fmi3EnterInitializationMode). */
static fmi2Status set_start_time(Instance *inst, const char *fn, double startTime, int stopTimeDefined,
                                 double stopTime)
{
    if (!isfinite(startTime)) {
        LOG_ERROR(inst, "%s: startTime=%g is not a finite number", fn, startTime);
        return fmi2Error;
    }
    if (stopTimeDefined && !(stopTime >= startTime)) {
        LOG_ERROR(inst, "%s: stopTime=%g is before startTime=%g", fn, stopTime, startTime);
        return fmi2Error;
    }
    inst->d.start_time = startTime;
    inst->d.time = startTime;
    return fmi2OK;
}

static fmi2Status exit_initialization(Instance *inst, const char *fn)
{
    if (inst->d.mode != MODE_INITIALIZATION) return reject_mode(inst, fn);
    if (model_initialize(inst) != 0) return fmi2Error; /* stays in initialization mode */
    inst->d.mode = MODE_STEP;
    return fmi2OK;
}

static fmi2Status terminate(Instance *inst, const char *fn)
{
    if (inst->d.mode != MODE_STEP && inst->d.mode != MODE_ERROR) return reject_mode(inst, fn);
    inst->d.mode = MODE_TERMINATED;
    return fmi2OK;
}

/* Getting and setting variables ------------------------------------------------ */

/* In Initialization Mode the outputs follow the parameters and inputs set so far (for a
 * model that provides model_initial_outputs; otherwise they keep their start values). */
static int initial_outputs(Instance *inst, const char *fn)
{
#ifdef MODEL_INITIAL_OUTPUTS
    if (inst->d.mode == MODE_INITIALIZATION && model_initial_outputs(inst) != 0) {
        LOG_ERROR(inst, "%s: the outputs cannot be computed in initialization mode (see the message before)", fn);
        return 0;
    }
#else
    (void)inst;
    (void)fn;
#endif
    return 1;
}

/* Outside Initialization Mode, outputs a model leaves stale after a step are computed when
 * they are read (a model that defines MODEL_LAZY_OUTPUTS; vr = NULL: whatever is stale). */
/* After a successful set of Real values: the model's direct feedthrough, if it has one (Step Mode). */
static void inputs_set(Instance *inst)
{
#ifdef MODEL_INPUTS_SET
    if (inst->d.mode == MODE_STEP) model_inputs_set(inst);
#else
    (void)inst;
#endif
}

static int lazy_outputs(Instance *inst, const char *fn, const unsigned int *vr, size_t nvr)
{
#ifdef MODEL_LAZY_OUTPUTS
    if ((inst->d.mode == MODE_STEP || inst->d.mode == MODE_TERMINATED) && model_lazy_outputs(inst, vr, nvr) != 0) {
        LOG_ERROR(inst, "%s: the outputs cannot be computed at t=%.9g (see the message before)", fn, inst->d.time);
        inst->d.mode = MODE_ERROR;
        return 0;
    }
#else
    (void)inst;
    (void)fn;
    (void)vr;
    (void)nvr;
#endif
    return 1;
}

/* May a variable of this kind be set in the current mode? */
static int settable(const Instance *inst, int kind)
{
    int mode = inst->d.mode;
    if (kind == KIND_INPUT) return mode == MODE_INSTANTIATED || mode == MODE_INITIALIZATION || mode == MODE_STEP;
    if (kind == KIND_PARAMETER) return mode == MODE_INSTANTIATED || mode == MODE_INITIALIZATION;
    if (kind == KIND_TUNABLE) return mode == MODE_INSTANTIATED || mode == MODE_INITIALIZATION || mode == MODE_STEP;
    return 0;
}

#ifndef FMU_FMI3
static const char *kind_name(int kind)
{
    switch (kind) {
    case KIND_INPUT: return "input";
    case KIND_OUTPUT: return "output";
    case KIND_PARAMETER: return "fixed parameter";
    case KIND_TUNABLE: return "tunable parameter";
    default: return "local";
    }
}
#endif

/* May `value` be set into the variable `name` of this kind and range now? */
static int check_set(Instance *inst, const char *fn, const char *name, int kind, double value,
                     double lo, double hi)
{
    if (!settable(inst, kind)) {
        if (kind == KIND_PARAMETER)
            LOG_ERROR(inst, "%s: %s is a fixed parameter and can only be set before "
                      FMI_PREFIX "ExitInitializationMode (mode is %s)", fn, name, MODE_NAME[inst->d.mode]);
        else
#ifdef FMU_FMI3
            LOG_ERROR(inst, "%s: %s cannot be set (%s, mode %s)", fn, name,
                      kind == KIND_OUTPUT ? "an output" : "a local", MODE_NAME[inst->d.mode]);
#else
            LOG_ERROR(inst, "%s: %s is an %s and cannot be set (mode %s)", fn, name, kind_name(kind),
                      MODE_NAME[inst->d.mode]);
#endif
        return 0;
    }
    if (!isfinite(value)) {
        LOG_ERROR(inst, "%s: %s=%g is not a finite number", fn, name, value);
        return 0;
    }
    if (value < lo || value > hi) {
        LOG_ERROR(inst, "%s: %s=%.17g is outside its range [%g, %g]", fn, name, value, lo, hi);
        return 0;
    }
    return 1;
}

/* Co-simulation ----------------------------------------------------------------- */

/* One communication step from t by h: argument checks, model_do_step, output check. */
static fmi2Status do_step(Instance *inst, const char *fn, double t, double h)
{
    int k;
    if (inst->d.mode != MODE_STEP) return reject_mode(inst, fn);
    if (!isfinite(h) || !(h > 0.0)) {
        LOG_ERROR(inst, "%s: communicationStepSize=%g, expected a finite number > 0", fn, h);
        return fmi2Error;
    }
    if (!isfinite(t) || fabs(t - inst->d.time) > 1e-9 * (1.0 + fabs(t))) {
        LOG_ERROR(inst, "%s: currentCommunicationPoint=%.12g does not match the FMU time %.12g "
                  "(steps must follow each other without gaps)", fn, t, inst->d.time);
        return fmi2Error;
    }
    k = model_do_step(inst, inst->d.time, h);
    if (k == MODEL_STEP_REJECTED) return fmi2Error;
    if (k != 0) {
        inst->d.mode = MODE_ERROR;
        return fmi2Error;
    }
    for (k = 0; k < N_REALS; k++) {
        if (REAL_KIND[k] == KIND_OUTPUT && !isfinite(inst->d.r[k])) {
            LOG_ERROR(inst, "%s: output %s became %g at t=%.9g", fn, REAL_NAME[k], inst->d.r[k], t + h);
            inst->d.mode = MODE_ERROR;
            return fmi2Error;
        }
    }
    inst->d.time = t + h;
    return fmi2OK;
}

/* FMU state ------------------------------------------------------------------- */

typedef struct {
    unsigned magic;
    unsigned size;
    char guid[64];
    FmuData d;
} Snapshot;

/* Copy the instance's data into *state (allocated when NULL). */
static fmi2Status get_state(Instance *inst, const char *fn, void **state)
{
    Snapshot *snap;
    if (!state) {
        LOG_ERROR(inst, "%s: NULL state pointer", fn);
        return fmi2Error;
    }
    snap = (Snapshot *)*state;
    if (!snap) {
        snap = (Snapshot *)calloc(1, sizeof *snap);
        if (!snap) {
            LOG_ERROR(inst, "%s: out of memory", fn);
            return fmi2Error;
        }
    }
    snap->magic = STATE_MAGIC;
    snap->size = (unsigned)sizeof(Snapshot);
    strncpy(snap->guid, FMU_TOKEN, sizeof snap->guid - 1);
    snap->d = inst->d;
    *state = snap;
    return fmi2OK;
}

static int valid_snapshot(Instance *inst, const Snapshot *snap, const char *fn)
{
    if (!snap || snap->magic != STATE_MAGIC || snap->size != sizeof(Snapshot) ||
        strncmp(snap->guid, FMU_TOKEN, sizeof snap->guid) != 0) {
        LOG_ERROR(inst, "%s: the FMU state does not come from this FMU (%s)", fn, MODEL_IDENTIFIER_STRING);
        return 0;
    }
    return 1;
}

static fmi2Status set_state(Instance *inst, const char *fn, const void *state)
{
    if (!valid_snapshot(inst, (const Snapshot *)state, fn)) return fmi2Error;
    inst->d = ((const Snapshot *)state)->d;
    return fmi2OK;
}

static void free_state(void **state)
{
    if (state) {
        free(*state);
        *state = NULL;
    }
}

static fmi2Status serialized_state_size(Instance *inst, const char *fn, const void *state, size_t *size)
{
    if (!size) {
        LOG_ERROR(inst, "%s: NULL size pointer", fn);
        return fmi2Error;
    }
    if (!valid_snapshot(inst, (const Snapshot *)state, fn)) return fmi2Error;
    *size = sizeof(Snapshot);
    return fmi2OK;
}

static fmi2Status serialize_state(Instance *inst, const char *fn, const void *state, void *serialized, size_t size)
{
    if (!valid_snapshot(inst, (const Snapshot *)state, fn)) return fmi2Error;
    if (!serialized || size < sizeof(Snapshot)) {
        LOG_ERROR(inst, "%s: buffer of %lu bytes given, %lu needed", fn, (unsigned long)size,
                  (unsigned long)sizeof(Snapshot));
        return fmi2Error;
    }
    memcpy(serialized, state, sizeof(Snapshot));
    return fmi2OK;
}

static fmi2Status deserialize_state(Instance *inst, const char *fn, const void *serialized, size_t size,
                                    void **state)
{
    Snapshot *snap;
    if (!serialized || !state || size != sizeof(Snapshot)) {
        LOG_ERROR(inst, "%s: %lu bytes given, %lu expected", fn, (unsigned long)size,
                  (unsigned long)sizeof(Snapshot));
        return fmi2Error;
    }
    if (!valid_snapshot(inst, (const Snapshot *)serialized, fn)) return fmi2Error;
    snap = (Snapshot *)(*state ? *state : malloc(sizeof(Snapshot)));
    if (!snap) {
        LOG_ERROR(inst, "%s: out of memory", fn);
        return fmi2Error;
    }
    memcpy(snap, serialized, sizeof(Snapshot));
    *state = snap;
    return fmi2OK;
}

#endif
