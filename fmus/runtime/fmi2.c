/* fmi2.c: the FMI 2.0 interface (Model Exchange and Co-Simulation in one binary) over mt_runtime. */
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "mt_runtime.h"

#define INST ((mt_instance *)c)
#define CHECK(mask, fn)                                                \
    do {                                                               \
        if (!mt_live(c, (fn))) return fmi2Error;                       \
        if (!mt_allowed(INST, (mask), (fn))) return fmi2Error;         \
    } while (0)
#define CHECK_ME(fn)                                                                                     \
    do {                                                                                                 \
        if (INST->co_simulation) {                                                                       \
            mt_log(INST, MT_ERROR, "logStatusError", "%s: Model Exchange function called on a Co-Simulation " \
                   "instance", (fn));                                                                    \
            return fmi2Error;                                                                            \
        }                                                                                                \
    } while (0)
#define CHECK_CS(fn)                                                                                     \
    do {                                                                                                 \
        if (!INST->co_simulation) {                                                                      \
            mt_log(INST, MT_ERROR, "logStatusError", "%s: Co-Simulation function called on a Model Exchange " \
                   "instance", (fn));                                                                    \
            return fmi2Error;                                                                            \
        }                                                                                                \
    } while (0)

#define NOT_FAILED (MT_ANY_MODE & ~MT_FAILED)
#define SETTABLE (MT_INSTANTIATED | MT_INIT | MT_EVENT | MT_CONTINUOUS | MT_STEP)
#define EVALUATED (MT_INIT | MT_EVENT | MT_CONTINUOUS | MT_STEP | MT_TERMINATED | MT_FAILED)
/* The state tables of FMI 2.0 (sections 3.2.3 and 4.2.4): variable getters, directional derivatives and the
 * Model Exchange getters are allowed from Initialization Mode on, not in Instantiated; the status getters of
 * Co-Simulation only after initialisation and not in Error. */
#define STATUS (MT_STEP | MT_TERMINATED)

/* The logger's message is a printf format: protect '%' in the finished text. */
static void emit(mt_instance *inst, int status, const char *category, const char *message)
{
    fmi2CallbackLogger logger = (fmi2CallbackLogger)inst->logger;
    char buf[2048];
    size_t i = 0;
    if (!logger) return;
    for (; *message && i + 2 < sizeof buf; message++) {
        if (*message == '%') buf[i++] = '%';
        buf[i++] = *message;
    }
    buf[i] = '\0';
    logger(inst->env, inst->name, (fmi2Status)status, category, buf);
}

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[])
{
    if (!mt_live(c, __func__)) return fmi2Error;
    return (fmi2Status)mt_set_debug_logging(INST, loggingOn, nCategories, categories);
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation, const fmi2CallbackFunctions *functions,
                              fmi2Boolean visible, fmi2Boolean loggingOn)
{
    (void)fmuResourceLocation;
    (void)visible;
    if (fmuType != fmi2ModelExchange && fmuType != fmi2CoSimulation) {
        if (functions && functions->logger)
            functions->logger(functions->componentEnvironment, instanceName, fmi2Error, "logStatusError",
                              "fmi2Instantiate: unknown fmuType");
        return NULL;
    }
    return mt_instantiate(instanceName, fmuGUID, fmuType == fmi2CoSimulation, 2, emit,
                          functions ? (void (*)(void))functions->logger : NULL,
                          functions ? functions->componentEnvironment : NULL, loggingOn);
}

void fmi2FreeInstance(fmi2Component c) { mt_release(c, "fmi2FreeInstance"); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined, fmi2Real tolerance,
                               fmi2Real startTime, fmi2Boolean stopTimeDefined, fmi2Real stopTime)
{
    CHECK(MT_INSTANTIATED, "fmi2SetupExperiment");
    if (stopTimeDefined && stopTime < startTime) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2SetupExperiment: stop time %g is before start time %g",
               stopTime, startTime);
        return fmi2Error;
    }
    return (fmi2Status)mt_setup(INST, toleranceDefined, tolerance, startTime);
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c)
{
    CHECK(MT_INSTANTIATED, "fmi2EnterInitializationMode");
    INST->mode = MT_INIT;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c)
{
    CHECK(MT_INIT, "fmi2ExitInitializationMode");
    return (fmi2Status)mt_exit_initialization(INST);
}

fmi2Status fmi2Terminate(fmi2Component c)
{
    CHECK(MT_EVENT | MT_CONTINUOUS | MT_STEP, "fmi2Terminate");
    return (fmi2Status)mt_terminate(INST);
}

fmi2Status fmi2Reset(fmi2Component c)
{
    if (!mt_live(c, __func__)) return fmi2Error;
    mt_reset(INST);
    return fmi2OK;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Real value[])
{
    CHECK(EVALUATED, "fmi2GetReal");
    return (fmi2Status)mt_get_float64(INST, vr, nvr, value, "fmi2GetReal");
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Integer value[])
{
    (void)value;
    CHECK(EVALUATED, "fmi2GetInteger");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "Integer", "fmi2GetInteger");
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2Boolean value[])
{
    (void)value;
    CHECK(EVALUATED, "fmi2GetBoolean");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "Boolean", "fmi2GetBoolean");
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, fmi2String value[])
{
    (void)value;
    CHECK(EVALUATED, "fmi2GetString");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "String", "fmi2GetString");
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Real value[])
{
    CHECK(SETTABLE, "fmi2SetReal");
    return (fmi2Status)mt_set_float64(INST, vr, nvr, value, "fmi2SetReal");
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Integer value[])
{
    (void)value;
    CHECK(SETTABLE, "fmi2SetInteger");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "Integer", "fmi2SetInteger");
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2Boolean value[])
{
    (void)value;
    CHECK(SETTABLE, "fmi2SetBoolean");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "Boolean", "fmi2SetBoolean");
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr, const fmi2String value[])
{
    (void)value;
    CHECK(SETTABLE, "fmi2SetString");
    return (fmi2Status)mt_wrong_type(INST, vr, nvr, "String", "fmi2SetString");
}

/* FMU state */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    mt_snapshot *s;
    CHECK(NOT_FAILED, "fmi2GetFMUstate");
    if (!FMUstate) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2GetFMUstate: null pointer");
        return fmi2Error;
    }
    s = mt_snapshot_take(INST, (mt_snapshot *)*FMUstate);
    if (!s) {
        *FMUstate = NULL;
        return fmi2Error;
    }
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate)
{
    const mt_snapshot *s = FMUstate;
    CHECK(MT_ANY_MODE, "fmi2SetFMUstate");
    if (!s) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2SetFMUstate: null FMU state");
        return fmi2Error;
    }
    return (fmi2Status)mt_snapshot_restore(INST, s->data, s->size, 1, "fmi2SetFMUstate");
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate)
{
    if (!mt_live(c, __func__)) return fmi2Error;
    if (FMUstate) {
        free(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size)
{
    CHECK(MT_ANY_MODE, "fmi2SerializedFMUstateSize");
    if (!FMUstate || !size) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2SerializedFMUstateSize: null pointer");
        return fmi2Error;
    }
    *size = ((const mt_snapshot *)FMUstate)->size;
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate, fmi2Byte serializedState[], size_t size)
{
    const mt_snapshot *s = FMUstate;
    CHECK(MT_ANY_MODE, "fmi2SerializeFMUstate");
    if (!s || !serializedState || size < s->size) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2SerializeFMUstate: null pointer or buffer of %zu bytes "
               "smaller than the state (%zu bytes)", size, s ? s->size : 0);
        return fmi2Error;
    }
    memcpy(serializedState, s->data, s->size);
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[], size_t size,
                                   fmi2FMUstate *FMUstate)
{
    mt_snapshot *s;
    CHECK(MT_ANY_MODE, "fmi2DeSerializeFMUstate");
    if (!FMUstate ||
        mt_snapshot_restore(INST, (const unsigned char *)serializedState, size, 0, "fmi2DeSerializeFMUstate") != MT_OK)
        return fmi2Error;
    s = malloc(sizeof *s + size);
    if (!s) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2DeSerializeFMUstate: out of memory");
        return fmi2Error;
    }
    s->size = size;
    memcpy(s->data, serializedState, size);
    free(*FMUstate);
    *FMUstate = s;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[], size_t nUnknown,
                                        const fmi2ValueReference vKnown_ref[], size_t nKnown,
                                        const fmi2Real dvKnown[], fmi2Real dvUnknown[])
{
    CHECK(EVALUATED, "fmi2GetDirectionalDerivative");
    return (fmi2Status)mt_derivatives(INST, vUnknown_ref, nUnknown, vKnown_ref, nKnown, dvKnown, nKnown, dvUnknown,
                                      nUnknown, 0, "fmi2GetDirectionalDerivative");
}

/* Model Exchange */

fmi2Status fmi2EnterEventMode(fmi2Component c)
{
    CHECK(MT_EVENT | MT_CONTINUOUS, "fmi2EnterEventMode");
    CHECK_ME("fmi2EnterEventMode");
    INST->mode = MT_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo)
{
    int defined = 0;
    double next = 0.0;
    fmi2Status status;
    CHECK(MT_EVENT, "fmi2NewDiscreteStates");
    CHECK_ME("fmi2NewDiscreteStates");
    if (!eventInfo) {
        mt_log(INST, MT_ERROR, "logStatusError", "fmi2NewDiscreteStates: null eventInfo");
        return fmi2Error;
    }
    status = (fmi2Status)mt_update_discrete(INST, &defined, &next);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = defined ? fmi2True : fmi2False;
    eventInfo->nextEventTime = next;
    return status;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c)
{
    CHECK(MT_EVENT, "fmi2EnterContinuousTimeMode");
    CHECK_ME("fmi2EnterContinuousTimeMode");
    INST->mode = MT_CONTINUOUS;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(MT_CONTINUOUS, "fmi2CompletedIntegratorStep");
    CHECK_ME("fmi2CompletedIntegratorStep");
    if (enterEventMode) *enterEventMode = fmi2False;
    if (terminateSimulation) *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time)
{
    CHECK(MT_EVENT | MT_CONTINUOUS, "fmi2SetTime");
    CHECK_ME("fmi2SetTime");
    return (fmi2Status)mt_set_time(INST, time);
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx)
{
    CHECK(MT_EVENT | MT_CONTINUOUS, "fmi2SetContinuousStates");
    CHECK_ME("fmi2SetContinuousStates");
    return (fmi2Status)mt_set_states(INST, x, nx, "fmi2SetContinuousStates");
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx)
{
    CHECK(EVALUATED, "fmi2GetDerivatives");
    CHECK_ME("fmi2GetDerivatives");
    return (fmi2Status)mt_get_derivatives(INST, derivatives, nx, "fmi2GetDerivatives");
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni)
{
    (void)eventIndicators;
    CHECK(EVALUATED, "fmi2GetEventIndicators");
    CHECK_ME("fmi2GetEventIndicators");
    return (fmi2Status)mt_check_event_indicators(INST, ni, "fmi2GetEventIndicators");
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx)
{
    CHECK(EVALUATED, "fmi2GetContinuousStates");
    CHECK_ME("fmi2GetContinuousStates");
    return (fmi2Status)mt_get_states(INST, x, nx, "fmi2GetContinuousStates");
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx)
{
    CHECK(MT_ANY_MODE, "fmi2GetNominalsOfContinuousStates");
    CHECK_ME("fmi2GetNominalsOfContinuousStates");
    return (fmi2Status)mt_get_nominals(INST, x_nominal, nx, "fmi2GetNominalsOfContinuousStates");
}

/* Co-Simulation */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(MT_INIT | MT_STEP, "fmi2SetRealInputDerivatives");
    CHECK_CS("fmi2SetRealInputDerivatives");
    if (nvr == 0) return fmi2OK;
    mt_log(INST, MT_ERROR, "logStatusError", "fmi2SetRealInputDerivatives: not supported (canInterpolateInputs "
           "is false: inputs are held constant over a communication step)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[])
{
    (void)vr;
    (void)order;
    (void)value;
    CHECK(MT_STEP | MT_TERMINATED | MT_FAILED, "fmi2GetRealOutputDerivatives");
    CHECK_CS("fmi2GetRealOutputDerivatives");
    if (nvr == 0) return fmi2OK;
    mt_log(INST, MT_ERROR, "logStatusError", "fmi2GetRealOutputDerivatives: not supported "
           "(maxOutputDerivativeOrder is 0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint, fmi2Real communicationStepSize,
                      fmi2Boolean noSetFMUStatePriorToCurrentPoint)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(MT_STEP, "fmi2DoStep");
    CHECK_CS("fmi2DoStep");
    return (fmi2Status)mt_do_step(INST, currentCommunicationPoint, communicationStepSize, "fmi2DoStep");
}

fmi2Status fmi2CancelStep(fmi2Component c)
{
    CHECK(MT_STEP, "fmi2CancelStep");
    mt_log(INST, MT_ERROR, "logStatusError", "fmi2CancelStep: no asynchronous step is running (fmi2DoStep never "
           "returns fmi2Pending)");
    return fmi2Error;
}

static fmi2Status no_status(fmi2Component c, const char *fn)
{
    CHECK(STATUS, fn);
    mt_log(INST, MT_DISCARD, "logStatusError", "%s: this status kind is not provided (fmi2DoStep never returns "
           "fmi2Pending)", fn);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value)
{
    CHECK(STATUS, "fmi2GetRealStatus");
    CHECK_CS("fmi2GetRealStatus");
    if (s != fmi2LastSuccessfulTime || !value) return no_status(c, "fmi2GetRealStatus");
    *value = INST->t;
    return fmi2OK;
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value)
{
    CHECK(STATUS, "fmi2GetBooleanStatus");
    CHECK_CS("fmi2GetBooleanStatus");
    if (s != fmi2Terminated || !value) return no_status(c, "fmi2GetBooleanStatus");
    *value = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value)
{
    (void)s;
    (void)value;
    return no_status(c, "fmi2GetStringStatus");
}
