/*
 * FMI 2.0 co-simulation API on top of the model_* functions (see fmu_instance.h).
 *
 * Robustness rules: every call checks its arguments and the instance mode; a bad
 * call (unknown value reference, non-finite or out-of-range value, setting an output,
 * step size <= 0, communication point that does not match the FMU time, ...) is
 * rejected with fmi2Error and a message through the logger, and leaves the instance
 * unchanged. A numerical failure inside a step (non-finite state) returns fmi2Error
 * and puts the instance into the error mode, from which only fmi2Get*, fmi2Reset,
 * fmi2SetFMUstate and fmi2FreeInstance are accepted.
 */
#include "fmu_wrapper.h"

/* Mode checks ---------------------------------------------------------------- */

static int check_instance(const Instance *inst, const char *fn)
{
    (void)fn;
    return inst != NULL;
}

/* Common functions ----------------------------------------------------------- */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    Instance *inst = (Instance *)c;
    (void)nCategories;
    (void)categories;
    if (!check_instance(inst, "fmi2SetDebugLogging")) return fmi2Error;
    inst->logging_on = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    Instance probe;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions) return NULL;
    memset(&probe, 0, sizeof probe);
    probe.functions = *functions;
    probe.instance_name = (char *)(instanceName ? instanceName : "?");
    if (!instanceName || !instanceName[0]) {
        LOG_ERROR(&probe, "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (fmuType != fmi2CoSimulation) {
        LOG_ERROR(&probe, "fmi2Instantiate: %s supports co-simulation only (fmuType=%d given)",
                  MODEL_IDENTIFIER_STRING, (int)fmuType);
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        LOG_ERROR(&probe, "fmi2Instantiate: GUID %s does not match the binary's %s "
                  "(modelDescription.xml and binary come from different builds)",
                  fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }
    return new_instance(&probe, instanceName, loggingOn, "fmi2Instantiate");
}

void fmi2FreeInstance(fmi2Component c)
{
    free_instance((Instance *)c);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    Instance *inst = (Instance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    if (!check_instance(inst, "fmi2SetupExperiment")) return fmi2Error;
    if (inst->d.mode != MODE_INSTANTIATED) return reject_mode(inst, "fmi2SetupExperiment");
    return set_start_time(inst, "fmi2SetupExperiment", startTime, stopTimeDefined, stopTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2EnterInitializationMode")) return fmi2Error;
    if (inst->d.mode != MODE_INSTANTIATED) return reject_mode(inst, "fmi2EnterInitializationMode");
    inst->d.mode = MODE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2ExitInitializationMode")) return fmi2Error;
    return exit_initialization(inst, "fmi2ExitInitializationMode");
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2Terminate")) return fmi2Error;
    return terminate(inst, "fmi2Terminate");
}

fmi2Status fmi2Reset(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2Reset")) return fmi2Error;
    set_start_values(inst);
    return fmi2OK;
}

/* Getting and setting variables ------------------------------------------------ */

/* The common case of a set, tested inline before check_set (which accepts exactly the same
 * values and says why it refuses the others): an input in Step Mode, finite, within its range. */
#define SET_IS_PLAIN(inst, kind, value, lo, hi) \
    ((kind) == KIND_INPUT && (inst)->d.mode == MODE_STEP && isfinite(value) && (value) >= (lo) && (value) <= (hi))

static int check_vr_args(Instance *inst, const char *fn, const fmi2ValueReference vr[], size_t nvr,
                         const void *values, size_t n_max)
{
    size_t k;
    if (nvr > 0 && (!vr || !values)) {
        LOG_ERROR(inst, "%s: NULL value-reference or value array for nvr=%lu", fn, (unsigned long)nvr);
        return 0;
    }
    for (k = 0; k < nvr; k++) {
        if (vr[k] >= n_max) {
            LOG_ERROR(inst, "%s: unknown value reference %u (this FMU has %lu of this type)", fn,
                      (unsigned)vr[k], (unsigned long)n_max);
            return 0;
        }
    }
    return 1;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!check_instance(inst, "fmi2GetReal")) return fmi2Error;
    if (!check_vr_args(inst, "fmi2GetReal", vr, nvr, value, N_REALS)) return fmi2Error;
    if (!initial_outputs(inst, "fmi2GetReal")) return fmi2Error;
    if (!lazy_outputs(inst, "fmi2GetReal", vr, nvr)) return fmi2Error;
    for (k = 0; k < nvr; k++) value[k] = inst->d.r[vr[k]];
    return fmi2OK;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!check_instance(inst, "fmi2GetInteger")) return fmi2Error;
    if (!check_vr_args(inst, "fmi2GetInteger", vr, nvr, value, N_INTEGERS)) return fmi2Error;
    if (!initial_outputs(inst, "fmi2GetInteger")) return fmi2Error;
    for (k = 0; k < nvr; k++) value[k] = inst->d.i[vr[k]];
    return fmi2OK;
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetBoolean")) return fmi2Error;
    return check_vr_args(inst, "fmi2GetBoolean", vr, nvr, value, 0) ? fmi2OK : fmi2Error;
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetString")) return fmi2Error;
    return check_vr_args(inst, "fmi2GetString", vr, nvr, value, 0) ? fmi2OK : fmi2Error;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!check_instance(inst, "fmi2SetReal")) return fmi2Error;
    if (!check_vr_args(inst, "fmi2SetReal", vr, nvr, value, N_REALS)) return fmi2Error;
    /* check everything first so that a rejected call changes nothing */
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference v = vr[k];
        if (!SET_IS_PLAIN(inst, REAL_KIND[v], value[k], REAL_MIN[v], REAL_MAX[v])
            && !check_set(inst, "fmi2SetReal", REAL_NAME[v], REAL_KIND[v], value[k], REAL_MIN[v], REAL_MAX[v]))
            return fmi2Error;
    }
    for (k = 0; k < nvr; k++) inst->d.r[vr[k]] = value[k];
    inputs_set(inst);
    return fmi2OK;
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    Instance *inst = (Instance *)c;
    size_t k;
    if (!check_instance(inst, "fmi2SetInteger")) return fmi2Error;
    if (!check_vr_args(inst, "fmi2SetInteger", vr, nvr, value, N_INTEGERS)) return fmi2Error;
    for (k = 0; k < nvr; k++) {
        fmi2ValueReference v = vr[k];
        if (!SET_IS_PLAIN(inst, INTEGER_KIND[v], (double)value[k], INTEGER_MIN[v], INTEGER_MAX[v])
            && !check_set(inst, "fmi2SetInteger", INTEGER_NAME[v], INTEGER_KIND[v], (double)value[k],
                          INTEGER_MIN[v], INTEGER_MAX[v]))
            return fmi2Error;
    }
    for (k = 0; k < nvr; k++) inst->d.i[vr[k]] = value[k];
    return fmi2OK;
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2SetBoolean")) return fmi2Error;
    return check_vr_args(inst, "fmi2SetBoolean", vr, nvr, value, 0) ? fmi2OK : fmi2Error;
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2SetString")) return fmi2Error;
    return check_vr_args(inst, "fmi2SetString", vr, nvr, value, 0) ? fmi2OK : fmi2Error;
}

/* FMU state ------------------------------------------------------------------- */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetFMUstate")) return fmi2Error;
    return get_state(inst, "fmi2GetFMUstate", FMUstate);
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2SetFMUstate")) return fmi2Error;
    return set_state(inst, "fmi2SetFMUstate", FMUstate);
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2FreeFMUstate")) return fmi2Error;
    free_state(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2SerializedFMUstateSize")) return fmi2Error;
    return serialized_state_size(inst, "fmi2SerializedFMUstateSize", FMUstate, size);
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2SerializeFMUstate")) return fmi2Error;
    return serialize_state(inst, "fmi2SerializeFMUstate", FMUstate, serializedState, size);
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2DeSerializeFMUstate")) return fmi2Error;
    return deserialize_state(inst, "fmi2DeSerializeFMUstate", serializedState, size, FMUstate);
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    Instance *inst = (Instance *)c;
    (void)vUnknown_ref; (void)nUnknown; (void)vKnown_ref; (void)nKnown; (void)dvKnown; (void)dvUnknown;
    if (!check_instance(inst, "fmi2GetDirectionalDerivative")) return fmi2Error;
    LOG_ERROR(inst, "fmi2GetDirectionalDerivative: not provided by %s", MODEL_IDENTIFIER_STRING);
    return fmi2Error;
}

/* Co-simulation ----------------------------------------------------------------- */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    (void)vr; (void)nvr; (void)order; (void)value;
    if (!check_instance(inst, "fmi2SetRealInputDerivatives")) return fmi2Error;
    LOG_ERROR(inst, "fmi2SetRealInputDerivatives: %s holds its inputs constant over a step "
              "(canInterpolateInputs=false)", MODEL_IDENTIFIER_STRING);
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    Instance *inst = (Instance *)c;
    (void)vr; (void)nvr; (void)order; (void)value;
    if (!check_instance(inst, "fmi2GetRealOutputDerivatives")) return fmi2Error;
    LOG_ERROR(inst, "fmi2GetRealOutputDerivatives: %s provides no output derivatives "
              "(maxOutputDerivativeOrder=0)", MODEL_IDENTIFIER_STRING);
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    Instance *inst = (Instance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (!check_instance(inst, "fmi2DoStep")) return fmi2Error;
    return do_step(inst, "fmi2DoStep", currentCommunicationPoint, communicationStepSize);
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2CancelStep")) return fmi2Error;
    LOG_ERROR(inst, "fmi2CancelStep: %s steps synchronously; there is nothing to cancel", MODEL_IDENTIFIER_STRING);
    return fmi2Error;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetStatus")) return fmi2Error;
    if (!value || s != fmi2DoStepStatus) {
        LOG_ERROR(inst, "fmi2GetStatus: status kind %d is not provided", (int)s);
        return fmi2Discard;
    }
    *value = inst->d.mode == MODE_ERROR ? fmi2Error : fmi2OK;
    return fmi2OK;
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetRealStatus")) return fmi2Error;
    if (!value || s != fmi2LastSuccessfulTime) {
        LOG_ERROR(inst, "fmi2GetRealStatus: status kind %d is not provided", (int)s);
        return fmi2Discard;
    }
    *value = inst->d.time;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    Instance *inst = (Instance *)c;
    (void)value;
    if (!check_instance(inst, "fmi2GetIntegerStatus")) return fmi2Error;
    LOG_ERROR(inst, "fmi2GetIntegerStatus: status kind %d is not provided", (int)s);
    return fmi2Discard;
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    Instance *inst = (Instance *)c;
    if (!check_instance(inst, "fmi2GetBooleanStatus")) return fmi2Error;
    if (!value || s != fmi2Terminated) {
        LOG_ERROR(inst, "fmi2GetBooleanStatus: status kind %d is not provided", (int)s);
        return fmi2Discard;
    }
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    Instance *inst = (Instance *)c;
    (void)value;
    if (!check_instance(inst, "fmi2GetStringStatus")) return fmi2Error;
    LOG_ERROR(inst, "fmi2GetStringStatus: status kind %d is not provided", (int)s);
    return fmi2Discard;
}
