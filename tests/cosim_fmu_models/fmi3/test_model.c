/* FMI 3.0 co-simulation API over a test model's variable table (see test_model.h). */
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "test_model.h"

typedef enum { M_INSTANTIATED, M_INIT, M_STEP, M_EVENT, M_TERMINATED } Mode;

typedef struct {
    char name[128];
    Mode mode;
    double time;
    int logging;
    int event_mode_used;
    fmi3InstanceEnvironment env;
    fmi3LogMessageCallback log;
    fmi3Boolean binary_sizes_ok;
    void *data;
} Inst;

static const size_t SIZE_OF[] = {sizeof(fmi3Float32), sizeof(fmi3Float64), 1, 1, 2, 2, 4, 4, 8, 8,
                                 sizeof(fmi3Boolean), sizeof(BinaryValue), sizeof(fmi3Clock)};

static void logf_(Inst *in, fmi3Status st, const char *msg)
{
    if (in && in->log && (st != fmi3OK || in->logging)) in->log(in->env, st, st == fmi3OK ? "logEvents" : "logStatusError", msg);
}

static fmi3Status fail(Inst *in, const char *fn, const char *why)
{
    char buf[256];
    snprintf(buf, sizeof buf, "%s: %s", fn, why);
    logf_(in, fmi3Error, buf);
    return fmi3Error;
}

static const VarInfo *find(fmi3ValueReference vr)
{
    for (size_t k = 0; k < N_MODEL_VARS; ++k)
        if (MODEL_VARS[k].vr == vr) return MODEL_VARS + k;
    return NULL;
}

static fmi3Status get_values(Inst *in, const char *fn, VarType type, const fmi3ValueReference vr[], size_t nvr,
                             void *values, size_t nValues)
{
    size_t used = 0;
    if (!in) return fmi3Error;
    if (in->mode == M_INSTANTIATED) return fail(in, fn, "not allowed before fmi3EnterInitializationMode");
    for (size_t k = 0; k < nvr; ++k) {
        const VarInfo *v = find(vr[k]);
        if (!v || v->type != type) return fail(in, fn, "unknown value reference for this type");
        if (used + v->count > nValues) return fail(in, fn, "nValues too small");
        memcpy((char *)values + used * SIZE_OF[type], (char *)in->data + v->offset, v->count * SIZE_OF[type]);
        used += v->count;
    }
    if (used != nValues) return fail(in, fn, "nValues does not match the variables");
    return fmi3OK;
}

static fmi3Status set_values(Inst *in, const char *fn, VarType type, const fmi3ValueReference vr[], size_t nvr,
                             const void *values, size_t nValues)
{
    size_t used = 0;
    if (!in) return fmi3Error;
    for (size_t k = 0; k < nvr; ++k) {
        const VarInfo *v = find(vr[k]);
        if (!v || v->type != type) return fail(in, fn, "unknown value reference for this type");
        if (v->settable == SET_NEVER) return fail(in, fn, "variable cannot be set");
        if (v->settable == SET_PARAMETER && in->mode != M_INSTANTIATED && in->mode != M_INIT)
            return fail(in, fn, "a fixed parameter can only be set before fmi3ExitInitializationMode");
        if (used + v->count > nValues) return fail(in, fn, "nValues too small");
        used += v->count;
    }
    if (used != nValues) return fail(in, fn, "nValues does not match the variables");
    used = 0;
    for (size_t k = 0; k < nvr; ++k) {
        const VarInfo *v = find(vr[k]);
        memcpy((char *)in->data + v->offset, (const char *)values + used * SIZE_OF[type], v->count * SIZE_OF[type]);
        used += v->count;
    }
    return fmi3OK;
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance i, fmi3Boolean on, size_t n, const fmi3String c[])
{
    (void)n; (void)c;
    if (!i) return fmi3Error;
    ((Inst *)i)->logging = on;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String a, fmi3String b, fmi3String c, fmi3Boolean d, fmi3Boolean e,
                                          fmi3InstanceEnvironment f, fmi3LogMessageCallback g)
{
    (void)a; (void)b; (void)c; (void)d; (void)e; (void)f; (void)g;
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String token, fmi3String resources,
                                         fmi3Boolean visible, fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed, const fmi3ValueReference req[], size_t nreq,
                                         fmi3InstanceEnvironment env, fmi3LogMessageCallback log,
                                         fmi3IntermediateUpdateCallback update)
{
    Inst *in;
    (void)resources; (void)visible; (void)earlyReturnAllowed; (void)req; (void)nreq; (void)update;
    if (!token || strcmp(token, MODEL_TOKEN) != 0) {
        if (log) log(env, fmi3Error, "logStatusError", "fmi3InstantiateCoSimulation: wrong instantiationToken");
        return NULL;
    }
    in = (Inst *)calloc(1, sizeof *in);
    if (!in) return NULL;
    in->data = calloc(1, MODEL_DATA_SIZE);
    if (!in->data) { free(in); return NULL; }
    snprintf(in->name, sizeof in->name, "%s", instanceName ? instanceName : "?");
    in->logging = loggingOn;
    in->event_mode_used = eventModeUsed;
    in->env = env;
    in->log = log;
    in->mode = M_INSTANTIATED;
    model_start((ModelData *)in->data);
    return in;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String a, fmi3String b, fmi3String c, fmi3Boolean d,
                                               fmi3Boolean e, fmi3InstanceEnvironment f, fmi3LogMessageCallback g,
                                               fmi3ClockUpdateCallback h, fmi3LockPreemptionCallback i,
                                               fmi3UnlockPreemptionCallback j)
{
    (void)a; (void)b; (void)c; (void)d; (void)e; (void)f; (void)g; (void)h; (void)i; (void)j;
    return NULL;
}

void fmi3FreeInstance(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in) return;
    free(in->data);
    free(in);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance i, fmi3Boolean tolDef, fmi3Float64 tol, fmi3Float64 start,
                                       fmi3Boolean stopDef, fmi3Float64 stop)
{
    Inst *in = (Inst *)i;
    (void)tolDef; (void)tol; (void)stopDef; (void)stop;
    if (!in || in->mode != M_INSTANTIATED) return fail(in, "fmi3EnterInitializationMode", "wrong mode");
    in->time = start;
    in->mode = M_INIT;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in || in->mode != M_INIT) return fail(in, "fmi3ExitInitializationMode", "wrong mode");
    if (model_initialize((ModelData *)in->data, in->time)) return fail(in, "fmi3ExitInitializationMode", "bad parameters");
    in->mode = in->event_mode_used ? M_EVENT : M_STEP;
    return fmi3OK;
}

fmi3Status fmi3EnterEventMode(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in || in->mode != M_STEP || !in->event_mode_used) return fail(in, "fmi3EnterEventMode", "wrong mode");
    in->mode = M_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in) return fmi3Error;
    in->mode = M_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in) return fmi3Error;
    memset(in->data, 0, MODEL_DATA_SIZE);
    model_start((ModelData *)in->data);
    in->mode = M_INSTANTIATED;
    return fmi3OK;
}

#define GETSET(Name, Tag, CType)                                                                              \
    fmi3Status fmi3Get##Name(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, CType values[], size_t n) \
    {                                                                                                         \
        return get_values((Inst *)i, "fmi3Get" #Name, Tag, vr, nvr, values, n);                               \
    }                                                                                                         \
    fmi3Status fmi3Set##Name(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const CType values[], \
                             size_t n)                                                                        \
    {                                                                                                         \
        return set_values((Inst *)i, "fmi3Set" #Name, Tag, vr, nvr, values, n);                               \
    }

GETSET(Float32, T_FLOAT32, fmi3Float32)
GETSET(Float64, T_FLOAT64, fmi3Float64)
GETSET(Int8, T_INT8, fmi3Int8)
GETSET(UInt8, T_UINT8, fmi3UInt8)
GETSET(Int16, T_INT16, fmi3Int16)
GETSET(UInt16, T_UINT16, fmi3UInt16)
GETSET(Int32, T_INT32, fmi3Int32)
GETSET(UInt32, T_UINT32, fmi3UInt32)
GETSET(Int64, T_INT64, fmi3Int64)
GETSET(UInt64, T_UINT64, fmi3UInt64)
GETSET(Boolean, T_BOOLEAN, fmi3Boolean)

fmi3Status fmi3GetString(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, fmi3String v[], size_t n)
{
    (void)vr; (void)nvr; (void)v; (void)n;
    return fail((Inst *)i, "fmi3GetString", "no String variables");
}

fmi3Status fmi3SetString(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const fmi3String v[], size_t n)
{
    (void)vr; (void)nvr; (void)v; (void)n;
    return fail((Inst *)i, "fmi3SetString", "no String variables");
}

fmi3Status fmi3GetBinary(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, size_t sizes[], fmi3Binary v[],
                         size_t n)
{
    Inst *in = (Inst *)i;
    size_t used = 0;
    if (!in) return fmi3Error;
    for (size_t k = 0; k < nvr; ++k) {
        const VarInfo *var = find(vr[k]);
        if (!var || var->type != T_BINARY) return fail(in, "fmi3GetBinary", "unknown value reference");
        for (size_t e = 0; e < var->count; ++e, ++used) {
            const BinaryValue *b = (const BinaryValue *)((char *)in->data + var->offset) + e;
            if (used >= n) return fail(in, "fmi3GetBinary", "nValues too small");
            sizes[used] = b->size;
            v[used] = b->bytes;
        }
    }
    return used == n ? fmi3OK : fail(in, "fmi3GetBinary", "nValues does not match");
}

fmi3Status fmi3SetBinary(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const size_t sizes[],
                         const fmi3Binary v[], size_t n)
{
    (void)vr; (void)nvr; (void)sizes; (void)v; (void)n;
    return fail((Inst *)i, "fmi3SetBinary", "no Binary inputs");
}

fmi3Status fmi3GetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    Inst *in = (Inst *)i;
    if (!in) return fmi3Error;
    if (in->mode != M_EVENT) return fail(in, "fmi3GetClock", "only in event mode");
    for (size_t k = 0; k < nvr; ++k) {
        const VarInfo *var = find(vr[k]);
        if (!var || var->type != T_CLOCK) return fail(in, "fmi3GetClock", "unknown value reference");
        values[k] = *(const fmi3Clock *)((char *)in->data + var->offset);
    }
    return fmi3OK;
}

fmi3Status fmi3SetClock(fmi3Instance i, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return fail((Inst *)i, "fmi3SetClock", "no input clocks");
}

#define UNSUPPORTED(decl, name) \
    decl { return fail((Inst *)instance, name, "not supported by this test FMU"); }

UNSUPPORTED(fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference vr, size_t *n),
            "fmi3GetNumberOfVariableDependencies")
UNSUPPORTED(fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference d, size_t e[],
            fmi3ValueReference f[], size_t g[], fmi3DependencyKind h[], size_t n), "fmi3GetVariableDependencies")
UNSUPPORTED(fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *s), "fmi3GetFMUState")
UNSUPPORTED(fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState s), "fmi3SetFMUState")
UNSUPPORTED(fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *s), "fmi3FreeFMUState")
UNSUPPORTED(fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState s, size_t *n),
            "fmi3SerializedFMUStateSize")
UNSUPPORTED(fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState s, fmi3Byte b[], size_t n),
            "fmi3SerializeFMUState")
UNSUPPORTED(fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte b[], size_t n, fmi3FMUState *s),
            "fmi3DeserializeFMUState")
UNSUPPORTED(fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3ValueReference c[], size_t d, const fmi3Float64 e[], size_t f, fmi3Float64 g[], size_t h),
            "fmi3GetDirectionalDerivative")
UNSUPPORTED(fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3ValueReference c[], size_t d, const fmi3Float64 e[], size_t f, fmi3Float64 g[], size_t h),
            "fmi3GetAdjointDerivative")
UNSUPPORTED(fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance), "fmi3EnterConfigurationMode")
UNSUPPORTED(fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance), "fmi3ExitConfigurationMode")
UNSUPPORTED(fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            fmi3Float64 c[], fmi3IntervalQualifier d[]), "fmi3GetIntervalDecimal")
UNSUPPORTED(fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            fmi3UInt64 c[], fmi3UInt64 d[], fmi3IntervalQualifier e[]), "fmi3GetIntervalFraction")
UNSUPPORTED(fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            fmi3Float64 c[]), "fmi3GetShiftDecimal")
UNSUPPORTED(fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            fmi3UInt64 c[], fmi3UInt64 d[]), "fmi3GetShiftFraction")
UNSUPPORTED(fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3Float64 c[]), "fmi3SetIntervalDecimal")
UNSUPPORTED(fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3UInt64 c[], const fmi3UInt64 d[]), "fmi3SetIntervalFraction")
UNSUPPORTED(fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3Float64 c[]), "fmi3SetShiftDecimal")
UNSUPPORTED(fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3UInt64 c[], const fmi3UInt64 d[]), "fmi3SetShiftFraction")
UNSUPPORTED(fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance), "fmi3EvaluateDiscreteStates")
UNSUPPORTED(fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance), "fmi3EnterContinuousTimeMode")
UNSUPPORTED(fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean a, fmi3Boolean *b,
            fmi3Boolean *c), "fmi3CompletedIntegratorStep")
UNSUPPORTED(fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 t), "fmi3SetTime")
UNSUPPORTED(fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t n),
            "fmi3SetContinuousStates")
UNSUPPORTED(fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 x[], size_t n),
            "fmi3GetContinuousStateDerivatives")
UNSUPPORTED(fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 x[], size_t n),
            "fmi3GetEventIndicators")
UNSUPPORTED(fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t n),
            "fmi3GetContinuousStates")
UNSUPPORTED(fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t n),
            "fmi3GetNominalsOfContinuousStates")
UNSUPPORTED(fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n),
            "fmi3GetNumberOfEventIndicators")
UNSUPPORTED(fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n),
            "fmi3GetNumberOfContinuousStates")
UNSUPPORTED(fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
            const fmi3Int32 c[], fmi3Float64 d[], size_t e), "fmi3GetOutputDerivatives")
UNSUPPORTED(fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference c, fmi3Float64 t),
            "fmi3ActivateModelPartition")

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance i, fmi3Boolean *needUpdate, fmi3Boolean *terminate,
                                    fmi3Boolean *nominalsChanged, fmi3Boolean *valuesChanged,
                                    fmi3Boolean *nextDefined, fmi3Float64 *next)
{
    Inst *in = (Inst *)i;
    int term = 0;
    if (!in || in->mode != M_EVENT) return fail(in, "fmi3UpdateDiscreteStates", "only in event mode");
    model_update_discrete((ModelData *)in->data, &term);
    *needUpdate = fmi3False;
    *terminate = term ? fmi3True : fmi3False;
    *nominalsChanged = fmi3False;
    *valuesChanged = fmi3False;
    *nextDefined = fmi3False;
    *next = 0.0;
    return fmi3OK;
}

fmi3Status fmi3EnterStepMode(fmi3Instance i)
{
    Inst *in = (Inst *)i;
    if (!in || in->mode != M_EVENT) return fail(in, "fmi3EnterStepMode", "only from event mode");
    model_enter_step_mode((ModelData *)in->data);
    in->mode = M_STEP;
    return fmi3OK;
}

fmi3Status fmi3DoStep(fmi3Instance i, fmi3Float64 t, fmi3Float64 h, fmi3Boolean noSet, fmi3Boolean *event,
                      fmi3Boolean *terminate, fmi3Boolean *early, fmi3Float64 *last)
{
    Inst *in = (Inst *)i;
    int ev = 0, term = 0, st;
    (void)noSet;
    if (!in || in->mode != M_STEP) return fail(in, "fmi3DoStep", "only in step mode");
    if (!(h > 0.0) || fabs(t - in->time) > 1e-9 * (1.0 + fabs(t))) return fail(in, "fmi3DoStep", "bad time or step");
    st = model_step((ModelData *)in->data, t, h, &ev, &term);
    *early = fmi3False;
    *event = (ev && in->event_mode_used) ? fmi3True : fmi3False;
    *terminate = term ? fmi3True : fmi3False;
    if (st == 3) return fail(in, "fmi3DoStep", "the model failed");
    if (st == 4) {
        *early = fmi3True;
        in->time = t + 0.5 * h;
        *last = in->time;
        return fmi3OK;
    }
    in->time = t + h;
    *last = in->time;
    if (term) logf_(in, st == 2 ? fmi3Discard : fmi3Warning, "the model ends the simulation");
    return st == 2 ? fmi3Discard : fmi3OK;
}
