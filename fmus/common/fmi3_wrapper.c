/*
 * FMI 3.0 co-simulation API on top of the model_* functions (see fmu_instance.h), built
 * from the same model sources as fmi2_wrapper.c (compiled with -DFMU_FMI3).
 *
 * Variables: fmus/fmi3_spec.py renders the FmuSpec as FMI 3.0 variables in
 * fmi3_variables.h: value reference 0 is the independent variable `time`; value reference
 * j + 1 is variable j, a Float64 or Int32 scalar or array whose elements are the FMI 2.0
 * build's consecutive Reals or Integers (VAR3_FIRST, VAR3_COUNT), so both builds share the
 * model state layout and every range/causality check below.
 *
 * Robustness rules as in fmi2_wrapper.c: a bad call is rejected with fmi3Error and a
 * message through the logger and leaves the instance unchanged; a numerical failure in
 * a step puts the instance into the error mode. The FMU has no event mode
 * (hasEventMode = false), never returns early and never ends the simulation itself.
 */
#include "fmu_instance.h"
#include "fmi3_variables.h"
#include "fmu_wrapper.h"

static fmi3Status unsupported(fmi3Instance instance, const char *fn, const char *why)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    LOG_ERROR(inst, "%s: %s (%s)", fn, why, MODEL_IDENTIFIER_STRING);
    return fmi3Error;
}

/* Common functions ----------------------------------------------------------- */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    Instance *inst = (Instance *)instance;
    (void)nCategories;
    (void)categories;
    if (!inst) return fmi3Error;
    inst->logging_on = loggingOn ? 1 : 0;
    return fmi3OK;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateModelExchange: " MODEL_IDENTIFIER_STRING " supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible; (void)loggingOn;
    (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: " MODEL_IDENTIFIER_STRING " supports co-simulation only");
    return NULL;
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                         fmi3Boolean eventModeUsed, fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate)
{
    Instance probe;
    (void)resourcePath; (void)visible; (void)earlyReturnAllowed; (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    memset(&probe, 0, sizeof probe);
    probe.functions.environment = instanceEnvironment;
    probe.functions.logger = logMessage;
    if (!instanceName || !instanceName[0]) {
        LOG_ERROR(&probe, "fmi3InstantiateCoSimulation: missing instance name");
        return NULL;
    }
    if (!instantiationToken || strcmp(instantiationToken, MODEL_TOKEN3) != 0) {
        LOG_ERROR(&probe, "fmi3InstantiateCoSimulation: instantiationToken %s does not match the binary's %s "
                  "(modelDescription.xml and binary come from different builds)",
                  instantiationToken ? instantiationToken : "(null)", MODEL_TOKEN3);
        return NULL;
    }
    if (eventModeUsed) {
        LOG_ERROR(&probe, "fmi3InstantiateCoSimulation: %s has no event mode (hasEventMode=false); "
                  "instantiate it with eventModeUsed=false", MODEL_IDENTIFIER_STRING);
        return NULL;
    }
    if (nRequiredIntermediateVariables > 0) {
        LOG_ERROR(&probe, "fmi3InstantiateCoSimulation: %s provides no intermediate variables",
                  MODEL_IDENTIFIER_STRING);
        return NULL;
    }
    return new_instance(&probe, instanceName, loggingOn, "fmi3InstantiateCoSimulation");
}

void fmi3FreeInstance(fmi3Instance instance)
{
    free_instance((Instance *)instance);
}

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    Instance *inst = (Instance *)instance;
    (void)toleranceDefined;
    (void)tolerance;
    if (!inst) return fmi3Error;
    if (inst->d.mode != MODE_INSTANTIATED) return reject_mode(inst, "fmi3EnterInitializationMode");
    if (set_start_time(inst, "fmi3EnterInitializationMode", startTime, stopTimeDefined, stopTime) != fmi3OK)
        return fmi3Error;
    inst->d.mode = MODE_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return exit_initialization(inst, "fmi3ExitInitializationMode");
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterEventMode", "no event mode (hasEventMode=false)");
}

fmi3Status fmi3Terminate(fmi3Instance instance)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return terminate(inst, "fmi3Terminate");
}

fmi3Status fmi3Reset(fmi3Instance instance)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    set_start_values(inst);
    return fmi3OK;
}

/* Getting and setting variables ------------------------------------------------ */

/* The FMI 3.0 variable of value reference vr (-1: time), or -2 with an error logged. */
static int variable_of(Instance *inst, const char *fn, fmi3ValueReference vr, int type)
{
    if (vr == VR3_TIME && type == 0) return -1;
    if (vr >= 1 && vr <= N_VARS3 && VAR3_TYPE[vr - 1] == type) return (int)vr - 1;
    LOG_ERROR(inst, "%s: unknown value reference %u (not a %s variable of %s)", fn, (unsigned)vr,
              type == 0 ? "Float64" : "Int32", MODEL_IDENTIFIER_STRING);
    return -2;
}

/* Check value references and that nValues equals the sum of their sizes. */
static int check_refs(Instance *inst, const char *fn, const fmi3ValueReference vr[], size_t nvr, const void *values,
                      size_t nValues, int type)
{
    size_t k, total = 0;
    if (nvr > 0 && (!vr || !values)) {
        LOG_ERROR(inst, "%s: NULL value-reference or value array for nValueReferences=%lu", fn, (unsigned long)nvr);
        return 0;
    }
    for (k = 0; k < nvr; k++) {
        int j = variable_of(inst, fn, vr[k], type);
        if (j == -2) return 0;
        total += j < 0 ? 1 : (size_t)VAR3_COUNT[j];
    }
    if (total != nValues) {
        LOG_ERROR(inst, "%s: nValues=%lu, but the %lu variables have %lu values", fn, (unsigned long)nValues,
                  (unsigned long)nvr, (unsigned long)total);
        return 0;
    }
    return 1;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Float64 values[],
                          size_t nValues)
{
    Instance *inst = (Instance *)instance;
    size_t k, n = 0;
    if (!inst) return fmi3Error;
    if (inst->d.mode == MODE_INSTANTIATED) return reject_mode(inst, "fmi3GetFloat64");
    if (!check_refs(inst, "fmi3GetFloat64", vr, nvr, values, nValues, 0)) return fmi3Error;
    if (!initial_outputs(inst, "fmi3GetFloat64")) return fmi3Error;
    if (!lazy_outputs(inst, "fmi3GetFloat64", NULL, 0)) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        int j = variable_of(inst, "fmi3GetFloat64", vr[k], 0), e;
        if (j < 0) { values[n++] = inst->d.time; continue; }
        for (e = 0; e < VAR3_COUNT[j]; e++) values[n++] = inst->d.r[VAR3_FIRST[j] + e];
    }
    return fmi3OK;
}

fmi3Status fmi3GetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Int32 values[],
                        size_t nValues)
{
    Instance *inst = (Instance *)instance;
    size_t k, n = 0;
    if (!inst) return fmi3Error;
    if (inst->d.mode == MODE_INSTANTIATED) return reject_mode(inst, "fmi3GetInt32");
    if (!check_refs(inst, "fmi3GetInt32", vr, nvr, values, nValues, 1)) return fmi3Error;
    if (!initial_outputs(inst, "fmi3GetInt32")) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        int j = variable_of(inst, "fmi3GetInt32", vr[k], 1), e;
        for (e = 0; e < VAR3_COUNT[j]; e++) values[n++] = inst->d.i[VAR3_FIRST[j] + e];
    }
    return fmi3OK;
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                          const fmi3Float64 values[], size_t nValues)
{
    Instance *inst = (Instance *)instance;
    size_t k, n = 0;
    if (!inst) return fmi3Error;
    if (!check_refs(inst, "fmi3SetFloat64", vr, nvr, values, nValues, 0)) return fmi3Error;
    /* check everything first so that a rejected call changes nothing */
    for (k = 0; k < nvr; k++) {
        int j = variable_of(inst, "fmi3SetFloat64", vr[k], 0), e;
        if (j < 0) {
            LOG_ERROR(inst, "fmi3SetFloat64: time is the independent variable and cannot be set");
            return fmi3Error;
        }
        for (e = 0; e < VAR3_COUNT[j]; e++, n++) {
            int x = VAR3_FIRST[j] + e;
            if (!check_set(inst, "fmi3SetFloat64", REAL_NAME[x], REAL_KIND[x], values[n], REAL_MIN[x], REAL_MAX[x]))
                return fmi3Error;
        }
    }
    n = 0;
    for (k = 0; k < nvr; k++) {
        int j = (int)vr[k] - 1, e;
        for (e = 0; e < VAR3_COUNT[j]; e++) inst->d.r[VAR3_FIRST[j] + e] = values[n++];
    }
    inputs_set(inst);
    return fmi3OK;
}

fmi3Status fmi3SetInt32(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Int32 values[],
                        size_t nValues)
{
    Instance *inst = (Instance *)instance;
    size_t k, n = 0;
    if (!inst) return fmi3Error;
    if (!check_refs(inst, "fmi3SetInt32", vr, nvr, values, nValues, 1)) return fmi3Error;
    for (k = 0; k < nvr; k++) {
        int j = (int)vr[k] - 1, e;
        for (e = 0; e < VAR3_COUNT[j]; e++, n++) {
            int x = VAR3_FIRST[j] + e;
            if (!check_set(inst, "fmi3SetInt32", INTEGER_NAME[x], INTEGER_KIND[x], (double)values[n],
                           INTEGER_MIN[x], INTEGER_MAX[x]))
                return fmi3Error;
        }
    }
    n = 0;
    for (k = 0; k < nvr; k++) {
        int j = (int)vr[k] - 1, e;
        for (e = 0; e < VAR3_COUNT[j]; e++) inst->d.i[VAR3_FIRST[j] + e] = values[n++];
    }
    return fmi3OK;
}

#define NO_VARIABLES(Name, CType)                                                                              \
    fmi3Status fmi3Get##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, CType values[],  \
                             size_t nValues)                                                                   \
    {                                                                                                          \
        (void)vr; (void)nvr; (void)values; (void)nValues;                                                      \
        return unsupported(instance, "fmi3Get" #Name, "no " #Name " variables");                               \
    }                                                                                                          \
    fmi3Status fmi3Set##Name(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,                 \
                             const CType values[], size_t nValues)                                             \
    {                                                                                                          \
        (void)vr; (void)nvr; (void)values; (void)nValues;                                                      \
        return unsupported(instance, "fmi3Set" #Name, "no " #Name " variables");                               \
    }

NO_VARIABLES(Float32, fmi3Float32)
NO_VARIABLES(Int8, fmi3Int8)
NO_VARIABLES(UInt8, fmi3UInt8)
NO_VARIABLES(Int16, fmi3Int16)
NO_VARIABLES(UInt16, fmi3UInt16)
NO_VARIABLES(UInt32, fmi3UInt32)
NO_VARIABLES(Int64, fmi3Int64)
NO_VARIABLES(UInt64, fmi3UInt64)
NO_VARIABLES(Boolean, fmi3Boolean)
NO_VARIABLES(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, size_t valueSizes[],
                         fmi3Binary values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)valueSizes; (void)values; (void)nValues;
    return unsupported(instance, "fmi3GetBinary", "no Binary variables");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)valueSizes; (void)values; (void)nValues;
    return unsupported(instance, "fmi3SetBinary", "no Binary variables");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3GetClock", "no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr, const fmi3Clock values[])
{
    (void)vr; (void)nvr; (void)values;
    return unsupported(instance, "fmi3SetClock", "no clocks");
}

/* FMU state ------------------------------------------------------------------- */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *state)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return get_state(inst, "fmi3GetFMUState", state);
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState state)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return set_state(inst, "fmi3SetFMUState", state);
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *state)
{
    if (!instance) return fmi3Error;
    free_state(state);
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState state, size_t *size)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return serialized_state_size(inst, "fmi3SerializedFMUStateSize", state, size);
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState state, fmi3Byte serializedState[], size_t size)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return serialize_state(inst, "fmi3SerializeFMUState", state, serializedState, size);
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *state)
{
    Instance *inst = (Instance *)instance;
    if (!inst) return fmi3Error;
    return deserialize_state(inst, "fmi3DeserializeFMUState", serializedState, size, state);
}

/* Not provided ----------------------------------------------------------------- */

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference vr, size_t *n)
{
    (void)vr; (void)n;
    return unsupported(instance, "fmi3GetNumberOfVariableDependencies", "not provided");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent, size_t a[],
                                       fmi3ValueReference b[], size_t c[], fmi3DependencyKind d[], size_t n)
{
    (void)dependent; (void)a; (void)b; (void)c; (void)d; (void)n;
    return unsupported(instance, "fmi3GetVariableDependencies", "not provided");
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
                                        const fmi3ValueReference c[], size_t d, const fmi3Float64 e[], size_t f,
                                        fmi3Float64 g[], size_t h)
{
    (void)a; (void)b; (void)c; (void)d; (void)e; (void)f; (void)g; (void)h;
    return unsupported(instance, "fmi3GetDirectionalDerivative", "not provided");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
                                    const fmi3ValueReference c[], size_t d, const fmi3Float64 e[], size_t f,
                                    fmi3Float64 g[], size_t h)
{
    (void)a; (void)b; (void)c; (void)d; (void)e; (void)f; (void)g; (void)h;
    return unsupported(instance, "fmi3GetAdjointDerivative", "not provided");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterConfigurationMode", "no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3ExitConfigurationMode", "no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b, fmi3Float64 c[],
                                  fmi3IntervalQualifier d[])
{
    (void)a; (void)b; (void)c; (void)d;
    return unsupported(instance, "fmi3GetIntervalDecimal", "no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b, fmi3UInt64 c[],
                                   fmi3UInt64 d[], fmi3IntervalQualifier e[])
{
    (void)a; (void)b; (void)c; (void)d; (void)e;
    return unsupported(instance, "fmi3GetIntervalFraction", "no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b, fmi3Float64 c[])
{
    (void)a; (void)b; (void)c;
    return unsupported(instance, "fmi3GetShiftDecimal", "no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b, fmi3UInt64 c[],
                                fmi3UInt64 d[])
{
    (void)a; (void)b; (void)c; (void)d;
    return unsupported(instance, "fmi3GetShiftFraction", "no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
                                  const fmi3Float64 c[])
{
    (void)a; (void)b; (void)c;
    return unsupported(instance, "fmi3SetIntervalDecimal", "no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b,
                                   const fmi3UInt64 c[], const fmi3UInt64 d[])
{
    (void)a; (void)b; (void)c; (void)d;
    return unsupported(instance, "fmi3SetIntervalFraction", "no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference a[], size_t b, const fmi3Float64 c[])
{
    (void)a; (void)b; (void)c;
    return unsupported(instance, "fmi3SetShiftDecimal", "no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference a[], size_t b, const fmi3UInt64 c[],
                                const fmi3UInt64 d[])
{
    (void)a; (void)b; (void)c; (void)d;
    return unsupported(instance, "fmi3SetShiftFraction", "no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EvaluateDiscreteStates", "no event mode");
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *a, fmi3Boolean *b, fmi3Boolean *c,
                                    fmi3Boolean *d, fmi3Boolean *e, fmi3Float64 *f)
{
    (void)a; (void)b; (void)c; (void)d; (void)e; (void)f;
    return unsupported(instance, "fmi3UpdateDiscreteStates", "no event mode");
}

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterContinuousTimeMode", "co-simulation only");
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean a, fmi3Boolean *b, fmi3Boolean *c)
{
    (void)a; (void)b; (void)c;
    return unsupported(instance, "fmi3CompletedIntegratorStep", "co-simulation only");
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    (void)time;
    return unsupported(instance, "fmi3SetTime", "co-simulation only");
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 x[], size_t n)
{
    (void)x; (void)n;
    return unsupported(instance, "fmi3SetContinuousStates", "co-simulation only");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 x[], size_t n)
{
    (void)x; (void)n;
    return unsupported(instance, "fmi3GetContinuousStateDerivatives", "co-simulation only");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 x[], size_t n)
{
    (void)x; (void)n;
    return unsupported(instance, "fmi3GetEventIndicators", "co-simulation only");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t n)
{
    (void)x; (void)n;
    return unsupported(instance, "fmi3GetContinuousStates", "co-simulation only");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 x[], size_t n)
{
    (void)x; (void)n;
    return unsupported(instance, "fmi3GetNominalsOfContinuousStates", "co-simulation only");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *n)
{
    (void)n;
    return unsupported(instance, "fmi3GetNumberOfEventIndicators", "co-simulation only");
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *n)
{
    (void)n;
    return unsupported(instance, "fmi3GetNumberOfContinuousStates", "co-simulation only");
}

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    return unsupported(instance, "fmi3EnterStepMode", "no event mode: the FMU is in step mode after initialization");
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference vr[], size_t nvr,
                                    const fmi3Int32 order[], fmi3Float64 values[], size_t nValues)
{
    (void)vr; (void)nvr; (void)order; (void)values; (void)nValues;
    return unsupported(instance, "fmi3GetOutputDerivatives", "no output derivatives (maxOutputDerivativeOrder=0)");
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference; (void)activationTime;
    return unsupported(instance, "fmi3ActivateModelPartition", "co-simulation only");
}

/* Co-simulation ----------------------------------------------------------------- */

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    Instance *inst = (Instance *)instance;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!inst) return fmi3Error;
    if (!eventHandlingNeeded || !terminateSimulation || !earlyReturn || !lastSuccessfulTime) {
        LOG_ERROR(inst, "fmi3DoStep: NULL output argument");
        return fmi3Error;
    }
    *eventHandlingNeeded = fmi3False;
    *terminateSimulation = fmi3False;
    *earlyReturn = fmi3False;
    *lastSuccessfulTime = inst->d.time;
    if (do_step(inst, "fmi3DoStep", currentCommunicationPoint, communicationStepSize) != fmi3OK)
        return fmi3Error;
    *lastSuccessfulTime = inst->d.time;
    return fmi3OK;
}
