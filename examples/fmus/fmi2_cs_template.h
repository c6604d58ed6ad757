/*
 * A minimal FMI 2.0 co-simulation implementation for small example FMUs (docs/how-to/controller_fmu.md,
 * "Your own FMU"). A model file defines, before including this header:
 *
 *   MODEL_IDENTIFIER   the modelIdentifier of modelDescription.xml (also the .so name)
 *   MODEL_GUID         the guid of modelDescription.xml
 *   N_REAL, N_INTEGER  number of Real / Integer variables; value references 0..N-1 per type,
 *                      in the order of modelDescription.xml
 *   REAL_START[], INTEGER_START[]  start values (static const arrays of that length)
 *   REAL_IS_INPUT_OR_PARAMETER[], INTEGER_IS_INPUT_OR_PARAMETER[]  1 where the importer may set
 *   typedef struct {...} ModelState;          the model's internal state (may hold one dummy field)
 *   and the prototypes of the three functions below (the template calls them)
 *   static int model_init(ModelState *s, double *r, int *i, char *msg);   leave initialization
 *   static void model_outputs(ModelState *s, double *r, int *i, double t);  outputs from inputs at t
 *   static int model_step(ModelState *s, double *r, int *i, double t, double h, char *msg);  t -> t + h
 *
 * model_init/model_step return 0 on success, else write a reason into msg (< 256 chars).
 * Everything else (instances, modes, get/set, logging, the required-but-unsupported calls)
 * is here. Build: gcc -shared -fPIC -O2 -I<fmpy>/c-code model.c -o <MODEL_IDENTIFIER>.so
 */
#ifndef FMI2_CS_TEMPLATE_H
#define FMI2_CS_TEMPLATE_H

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"

typedef struct {
    char name[128];
    fmi2CallbackFunctions cb;
    int initialized;    /* 0: instantiated/initialization, 1: step mode, 2: error */
    double time;
    double r[N_REAL > 0 ? N_REAL : 1];
    int i[N_INTEGER > 0 ? N_INTEGER : 1];
    ModelState s;
} Fmu;

static void fmu_error(Fmu *f, const char *text)
{
    if (f && f->cb.logger) f->cb.logger(f->cb.componentEnvironment, f->name, fmi2Error, "logStatusError", "%s", text);
}

FMI2_Export const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }
FMI2_Export const char *fmi2GetVersion(void) { return fmi2Version; }
FMI2_Export fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean on, size_t n, const fmi2String cat[])
{
    (void)c; (void)on; (void)n; (void)cat;
    return fmi2OK;
}

FMI2_Export fmi2Component fmi2Instantiate(fmi2String name, fmi2Type type, fmi2String guid, fmi2String location,
                                          const fmi2CallbackFunctions *cb, fmi2Boolean visible, fmi2Boolean logging)
{
    Fmu *f;
    (void)location; (void)visible; (void)logging;
    if (type != fmi2CoSimulation || !guid || strcmp(guid, MODEL_GUID) != 0) return NULL;
    f = (Fmu *)calloc(1, sizeof(Fmu));
    if (!f) return NULL;
    snprintf(f->name, sizeof f->name, "%s", name ? name : "instance");
    if (cb) f->cb = *cb;
    if (N_REAL > 0) memcpy(f->r, REAL_START, sizeof(double) * (N_REAL > 0 ? N_REAL : 1));
    if (N_INTEGER > 0) memcpy(f->i, INTEGER_START, sizeof(int) * (N_INTEGER > 0 ? N_INTEGER : 1));
    return f;
}

FMI2_Export void fmi2FreeInstance(fmi2Component c) { free(c); }

FMI2_Export fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean tol_defined, fmi2Real tol, fmi2Real start,
                                           fmi2Boolean stop_defined, fmi2Real stop)
{
    (void)tol_defined; (void)tol; (void)stop_defined; (void)stop;
    ((Fmu *)c)->time = start;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2EnterInitializationMode(fmi2Component c) { (void)c; return fmi2OK; }

FMI2_Export fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Fmu *f = (Fmu *)c;
    char msg[256] = "";
    if (model_init(&f->s, f->r, f->i, msg) != 0) {
        fmu_error(f, msg);
        f->initialized = 2;
        return fmi2Error;
    }
    f->initialized = 1;
    model_outputs(&f->s, f->r, f->i, f->time);
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2Terminate(fmi2Component c) { (void)c; return fmi2OK; }

FMI2_Export fmi2Status fmi2Reset(fmi2Component c)
{
    Fmu *f = (Fmu *)c;
    if (N_REAL > 0) memcpy(f->r, REAL_START, sizeof(double) * (N_REAL > 0 ? N_REAL : 1));
    if (N_INTEGER > 0) memcpy(f->i, INTEGER_START, sizeof(int) * (N_INTEGER > 0 ? N_INTEGER : 1));
    memset(&f->s, 0, sizeof f->s);
    f->initialized = 0;
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Real value[])
{
    Fmu *f = (Fmu *)c;
    size_t k;
    if (f->initialized == 1) model_outputs(&f->s, f->r, f->i, f->time);
    for (k = 0; k < n; k++) {
        if (vr[k] >= (fmi2ValueReference)N_REAL) { fmu_error(f, "fmi2GetReal: unknown value reference"); return fmi2Error; }
        value[k] = f->r[vr[k]];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Integer value[])
{
    Fmu *f = (Fmu *)c;
    size_t k;
    if (f->initialized == 1) model_outputs(&f->s, f->r, f->i, f->time);
    for (k = 0; k < n; k++) {
        if (vr[k] >= (fmi2ValueReference)N_INTEGER) { fmu_error(f, "fmi2GetInteger: unknown value reference"); return fmi2Error; }
        value[k] = f->i[vr[k]];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Real value[])
{
    Fmu *f = (Fmu *)c;
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= (fmi2ValueReference)N_REAL || !REAL_IS_INPUT_OR_PARAMETER[vr[k]]) {
            fmu_error(f, "fmi2SetReal: not an input or parameter");
            return fmi2Error;
        }
        if (!isfinite(value[k])) { fmu_error(f, "fmi2SetReal: non-finite value"); return fmi2Error; }
        f->r[vr[k]] = value[k];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Integer value[])
{
    Fmu *f = (Fmu *)c;
    size_t k;
    for (k = 0; k < n; k++) {
        if (vr[k] >= (fmi2ValueReference)N_INTEGER || !INTEGER_IS_INPUT_OR_PARAMETER[vr[k]]) {
            fmu_error(f, "fmi2SetInteger: not an input or parameter");
            return fmi2Error;
        }
        f->i[vr[k]] = value[k];
    }
    return fmi2OK;
}

FMI2_Export fmi2Status fmi2DoStep(fmi2Component c, fmi2Real t, fmi2Real h, fmi2Boolean no_prior)
{
    Fmu *f = (Fmu *)c;
    char msg[256] = "";
    (void)no_prior;
    if (f->initialized != 1) { fmu_error(f, "fmi2DoStep: not in step mode"); return fmi2Error; }
    if (!(h > 0.0) || fabs(t - f->time) > 1e-9 * (1.0 + fabs(t))) {
        fmu_error(f, "fmi2DoStep: step size <= 0 or communication point != FMU time");
        return fmi2Error;
    }
    if (model_step(&f->s, f->r, f->i, t, h, msg) != 0) {
        fmu_error(f, msg);
        f->initialized = 2;
        return fmi2Error;
    }
    f->time = t + h;
    return fmi2OK;
}

/* Required by the standard, not supported by these small FMUs. */
FMI2_Export fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2Boolean v[])
{ (void)vr; (void)v; if (n) { fmu_error((Fmu *)c, "no Boolean variables"); return fmi2Error; } return fmi2OK; }
FMI2_Export fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2Boolean v[])
{ (void)vr; (void)v; if (n) { fmu_error((Fmu *)c, "no Boolean variables"); return fmi2Error; } return fmi2OK; }
FMI2_Export fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, fmi2String v[])
{ (void)vr; (void)v; if (n) { fmu_error((Fmu *)c, "no String variables"); return fmi2Error; } return fmi2OK; }
FMI2_Export fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t n, const fmi2String v[])
{ (void)vr; (void)v; if (n) { fmu_error((Fmu *)c, "no String variables"); return fmi2Error; } return fmi2OK; }
FMI2_Export fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
FMI2_Export fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate s) { (void)c; (void)s; return fmi2Error; }
FMI2_Export fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *s) { (void)c; (void)s; return fmi2Error; }
FMI2_Export fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate s, size_t *n)
{ (void)c; (void)s; (void)n; return fmi2Error; }
FMI2_Export fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate s, fmi2Byte b[], size_t n)
{ (void)c; (void)s; (void)b; (void)n; return fmi2Error; }
FMI2_Export fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte b[], size_t n, fmi2FMUstate *s)
{ (void)c; (void)b; (void)n; (void)s; return fmi2Error; }
FMI2_Export fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference u[], size_t nu,
                                                    const fmi2ValueReference z[], size_t nz, const fmi2Real du[],
                                                    fmi2Real dz[])
{ (void)c; (void)u; (void)nu; (void)z; (void)nz; (void)du; (void)dz; return fmi2Error; }
FMI2_Export fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                   const fmi2Integer order[], const fmi2Real value[])
{ (void)c; (void)vr; (void)n; (void)order; (void)value; return fmi2Error; }
FMI2_Export fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t n,
                                                    const fmi2Integer order[], fmi2Real value[])
{ (void)c; (void)vr; (void)n; (void)order; (void)value; return fmi2Error; }
FMI2_Export fmi2Status fmi2CancelStep(fmi2Component c) { (void)c; return fmi2Error; }
FMI2_Export fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind k, fmi2Status *v)
{ (void)c; (void)k; (void)v; return fmi2Discard; }
FMI2_Export fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind k, fmi2Real *v)
{ (void)c; (void)k; (void)v; return fmi2Discard; }
FMI2_Export fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind k, fmi2Integer *v)
{ (void)c; (void)k; (void)v; return fmi2Discard; }
FMI2_Export fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind k, fmi2Boolean *v)
{ (void)c; (void)k; (void)v; return fmi2Discard; }
FMI2_Export fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind k, fmi2String *v)
{ (void)c; (void)k; (void)v; return fmi2Discard; }

#endif
