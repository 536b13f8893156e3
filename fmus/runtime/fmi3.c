/* fmi3.c: the FMI 3.0 interface (Model Exchange and Co-Simulation in one binary) over mt_runtime.
 * Clocks, Scheduled Execution, configuration mode and variable-dependency queries are not
 * supported: those functions return fmi3Error with a log message. */
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "mt_runtime.h"

#define INST ((mt_instance *)instance)
#define ERR(...) mt_log(INST, MT_ERROR, "logStatusError", __VA_ARGS__)
#define CHECK(mask, fn)                                                \
    do {                                                               \
        if (!mt_live(instance, (fn))) return fmi3Error;                \
        if (!mt_allowed(INST, (mask), (fn))) return fmi3Error;         \
    } while (0)
#define CHECK_ME(fn)                                                                          \
    do {                                                                                      \
        if (INST->co_simulation) {                                                            \
            ERR("%s: Model Exchange function called on a Co-Simulation instance", (fn));      \
            return fmi3Error;                                                                 \
        }                                                                                     \
    } while (0)
#define CHECK_CS(fn)                                                                          \
    do {                                                                                      \
        if (!INST->co_simulation) {                                                           \
            ERR("%s: Co-Simulation function called on a Model Exchange instance", (fn));      \
            return fmi3Error;                                                                 \
        }                                                                                     \
    } while (0)
#define NOT_SUPPORTED(fn, what)                                                               \
    do {                                                                                      \
        if (!mt_live(instance, (fn))) return fmi3Error;                                       \
        ERR("%s: not supported by this FMU (%s)", (fn), (what));                              \
        return fmi3Error;                                                                     \
    } while (0)

#define NOT_FAILED (MT_ANY_MODE & ~MT_FAILED)
#define SETTABLE (MT_INSTANTIATED | MT_INIT | MT_EVENT | MT_CONTINUOUS | MT_STEP)
#define EVALUATED (MT_INIT | MT_EVENT | MT_CONTINUOUS | MT_STEP | MT_TERMINATED | MT_FAILED)
/* FMI 3.0.2 state tables: fmi3Get{VariableType} is allowed in every state, in Instantiated for start values only
 * (mt_get_float64); derivatives, nominals and output derivatives only from Initialization Mode on. */

static void emit(mt_instance *inst, int status, const char *category, const char *message)
{
    fmi3LogMessageCallback logger = (fmi3LogMessageCallback)inst->logger;
    if (logger) logger(inst->env, (fmi3Status)status, category, message);
}

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[])
{
    if (!mt_live(instance, __func__)) return fmi3Error;
    return (fmi3Status)mt_set_debug_logging(INST, loggingOn, nCategories, categories);
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage)
{
    (void)resourcePath;
    (void)visible;
    return mt_instantiate(instanceName, instantiationToken, 0, 3, emit, (void (*)(void))logMessage,
                          instanceEnvironment, loggingOn);
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
    mt_instance *inst;
    (void)resourcePath;
    (void)visible;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)intermediateUpdate;
    inst = mt_instantiate(instanceName, instantiationToken, 1, 3, emit, (void (*)(void))logMessage,
                          instanceEnvironment, loggingOn);
    if (inst && nRequiredIntermediateVariables > 0) {
        mt_log(inst, MT_ERROR, "logStatusError", "fmi3InstantiateCoSimulation: intermediate variable access is "
               "not supported (%zu variables requested)", nRequiredIntermediateVariables);
        mt_release(inst, "fmi3InstantiateCoSimulation");
        return NULL;
    }
    if (inst) inst->event_mode_used = eventModeUsed;
    return inst;
}

fmi3Instance fmi3InstantiateScheduledExecution(fmi3String instanceName, fmi3String instantiationToken,
                                               fmi3String resourcePath, fmi3Boolean visible, fmi3Boolean loggingOn,
                                               fmi3InstanceEnvironment instanceEnvironment,
                                               fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
                                               fmi3LockPreemptionCallback lockPreemption,
                                               fmi3UnlockPreemptionCallback unlockPreemption)
{
    (void)instantiationToken;
    (void)resourcePath;
    (void)visible;
    (void)loggingOn;
    (void)clockUpdate;
    (void)lockPreemption;
    (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logStatusError",
                   "fmi3InstantiateScheduledExecution: Scheduled Execution is not supported by this FMU");
    (void)instanceName;
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { mt_release(instance, "fmi3FreeInstance"); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined, fmi3Float64 tolerance,
                                       fmi3Float64 startTime, fmi3Boolean stopTimeDefined, fmi3Float64 stopTime)
{
    fmi3Status status;
    CHECK(MT_INSTANTIATED, "fmi3EnterInitializationMode");
    if (stopTimeDefined && stopTime < startTime) {
        ERR("fmi3EnterInitializationMode: stop time %g is before start time %g", stopTime, startTime);
        return fmi3Error;
    }
    status = (fmi3Status)mt_setup(INST, toleranceDefined, tolerance, startTime);
    if (status == fmi3OK) INST->mode = MT_INIT;
    return status;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance)
{
    fmi3Status status;
    CHECK(MT_INIT, "fmi3ExitInitializationMode");
    status = (fmi3Status)mt_exit_initialization(INST);
    if (status == fmi3OK && INST->co_simulation && INST->event_mode_used) INST->mode = MT_EVENT;
    return status;
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance)
{
    CHECK(MT_EVENT | MT_CONTINUOUS | MT_STEP, "fmi3EnterEventMode");
    if (INST->co_simulation && !INST->event_mode_used) {
        ERR("fmi3EnterEventMode: the instance was created with eventModeUsed = false");
        return fmi3Error;
    }
    INST->mode = MT_EVENT;
    return fmi3OK;
}

fmi3Status fmi3Terminate(fmi3Instance instance)
{
    CHECK(MT_EVENT | MT_CONTINUOUS | MT_STEP, "fmi3Terminate");
    return (fmi3Status)mt_terminate(INST);
}

fmi3Status fmi3Reset(fmi3Instance instance)
{
    if (!mt_live(instance, __func__)) return fmi3Error;
    mt_reset(INST);
    return fmi3OK;
}

/* Variables: all are Float64 scalars. */

static fmi3Status check_counts(fmi3Instance instance, size_t nvr, size_t nValues, const char *fn)
{
    if (nvr != nValues) {
        ERR("%s: %zu values for %zu value references (all variables are scalars)", fn, nValues, nvr);
        return fmi3Error;
    }
    return fmi3OK;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          fmi3Float64 values[], size_t nValues)
{
    CHECK(MT_ANY_MODE, "fmi3GetFloat64");
    if (check_counts(instance, nValueReferences, nValues, "fmi3GetFloat64")) return fmi3Error;
    return (fmi3Status)mt_get_float64(INST, valueReferences, nValueReferences, values, "fmi3GetFloat64");
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                          const fmi3Float64 values[], size_t nValues)
{
    CHECK(SETTABLE, "fmi3SetFloat64");
    if (check_counts(instance, nValueReferences, nValues, "fmi3SetFloat64")) return fmi3Error;
    return (fmi3Status)mt_set_float64(INST, valueReferences, nValueReferences, values, "fmi3SetFloat64");
}

#define WRONG_TYPE_GET(T, CT)                                                                                  \
    fmi3Status fmi3Get##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                  \
                          size_t nValueReferences, CT values[], size_t nValues)                               \
    {                                                                                                          \
        (void)values;                                                                                          \
        (void)nValues;                                                                                         \
        CHECK(MT_ANY_MODE, "fmi3Get" #T);                                                                      \
        return (fmi3Status)mt_wrong_type(INST, valueReferences, nValueReferences, #T, "fmi3Get" #T);          \
    }
#define WRONG_TYPE_SET(T, CT)                                                                                  \
    fmi3Status fmi3Set##T(fmi3Instance instance, const fmi3ValueReference valueReferences[],                  \
                          size_t nValueReferences, const CT values[], size_t nValues)                         \
    {                                                                                                          \
        (void)values;                                                                                          \
        (void)nValues;                                                                                         \
        CHECK(SETTABLE, "fmi3Set" #T);                                                                         \
        return (fmi3Status)mt_wrong_type(INST, valueReferences, nValueReferences, #T, "fmi3Set" #T);          \
    }
#define WRONG_TYPE(T, CT) WRONG_TYPE_GET(T, CT) WRONG_TYPE_SET(T, CT)

WRONG_TYPE(Float32, fmi3Float32)
WRONG_TYPE(Int8, fmi3Int8)
WRONG_TYPE(UInt8, fmi3UInt8)
WRONG_TYPE(Int16, fmi3Int16)
WRONG_TYPE(UInt16, fmi3UInt16)
WRONG_TYPE(Int32, fmi3Int32)
WRONG_TYPE(UInt32, fmi3UInt32)
WRONG_TYPE(Int64, fmi3Int64)
WRONG_TYPE(UInt64, fmi3UInt64)
WRONG_TYPE(Boolean, fmi3Boolean)
WRONG_TYPE(String, fmi3String)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         size_t valueSizes[], fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    CHECK(MT_ANY_MODE, "fmi3GetBinary");
    return (fmi3Status)mt_wrong_type(INST, valueReferences, nValueReferences, "Binary", "fmi3GetBinary");
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                         const size_t valueSizes[], const fmi3Binary values[], size_t nValues)
{
    (void)valueSizes;
    (void)values;
    (void)nValues;
    CHECK(SETTABLE, "fmi3SetBinary");
    return (fmi3Status)mt_wrong_type(INST, valueReferences, nValueReferences, "Binary", "fmi3SetBinary");
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        fmi3Clock values[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)values;
    NOT_SUPPORTED("fmi3GetClock", "the FMU has no clocks");
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[], size_t nValueReferences,
                        const fmi3Clock values[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)values;
    NOT_SUPPORTED("fmi3SetClock", "the FMU has no clocks");
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance, fmi3ValueReference valueReference,
                                               size_t *nDependencies)
{
    (void)valueReference;
    (void)nDependencies;
    NOT_SUPPORTED("fmi3GetNumberOfVariableDependencies", "see ModelStructure in modelDescription.xml");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[], fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[], fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies)
{
    (void)dependent;
    (void)elementIndicesOfDependent;
    (void)independents;
    (void)elementIndicesOfIndependents;
    (void)dependencyKinds;
    (void)nDependencies;
    NOT_SUPPORTED("fmi3GetVariableDependencies", "see ModelStructure in modelDescription.xml");
}

/* FMU state */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    mt_snapshot *s;
    CHECK(NOT_FAILED, "fmi3GetFMUState");
    if (!FMUState) {
        ERR("fmi3GetFMUState: null pointer");
        return fmi3Error;
    }
    s = mt_snapshot_take(INST, (mt_snapshot *)*FMUState);
    *FMUState = s;
    return s ? fmi3OK : fmi3Error;
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState)
{
    const mt_snapshot *s = FMUState;
    CHECK(MT_ANY_MODE, "fmi3SetFMUState");
    if (!s) {
        ERR("fmi3SetFMUState: null FMU state");
        return fmi3Error;
    }
    return (fmi3Status)mt_snapshot_restore(INST, s->data, s->size, 1, "fmi3SetFMUState");
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState)
{
    if (!mt_live(instance, __func__)) return fmi3Error;
    if (FMUState) {
        free(*FMUState);
        *FMUState = NULL;
    }
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState, size_t *size)
{
    CHECK(MT_ANY_MODE, "fmi3SerializedFMUStateSize");
    if (!FMUState || !size) {
        ERR("fmi3SerializedFMUStateSize: null pointer");
        return fmi3Error;
    }
    *size = ((const mt_snapshot *)FMUState)->size;
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState, fmi3Byte serializedState[],
                                 size_t size)
{
    const mt_snapshot *s = FMUState;
    CHECK(MT_ANY_MODE, "fmi3SerializeFMUState");
    if (!s || !serializedState || size < s->size) {
        ERR("fmi3SerializeFMUState: null pointer or buffer of %zu bytes smaller than the state (%zu bytes)", size,
            s ? s->size : 0);
        return fmi3Error;
    }
    memcpy(serializedState, s->data, s->size);
    return fmi3OK;
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[], size_t size,
                                   fmi3FMUState *FMUState)
{
    mt_snapshot *s;
    CHECK(MT_ANY_MODE, "fmi3DeserializeFMUState");
    if (!FMUState || mt_snapshot_restore(INST, serializedState, size, 0, "fmi3DeserializeFMUState") != MT_OK)
        return fmi3Error;
    s = malloc(sizeof *s + size);
    if (!s) {
        ERR("fmi3DeserializeFMUState: out of memory");
        return fmi3Error;
    }
    s->size = size;
    memcpy(s->data, serializedState, size);
    free(*FMUState);
    *FMUState = s;
    return fmi3OK;
}

/* Partial derivatives */

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                        const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                        size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    CHECK(EVALUATED, "fmi3GetDirectionalDerivative");
    return (fmi3Status)mt_derivatives(INST, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                                      nSensitivity, 0, "fmi3GetDirectionalDerivative");
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[], size_t nUnknowns,
                                    const fmi3ValueReference knowns[], size_t nKnowns, const fmi3Float64 seed[],
                                    size_t nSeed, fmi3Float64 sensitivity[], size_t nSensitivity)
{
    CHECK(EVALUATED, "fmi3GetAdjointDerivative");
    return (fmi3Status)mt_derivatives(INST, unknowns, nUnknowns, knowns, nKnowns, seed, nSeed, sensitivity,
                                      nSensitivity, 1, "fmi3GetAdjointDerivative");
}

/* Configuration mode and clocks: not supported */

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance)
{
    NOT_SUPPORTED("fmi3EnterConfigurationMode", "the FMU has no structural parameters");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance)
{
    NOT_SUPPORTED("fmi3ExitConfigurationMode", "the FMU has no structural parameters");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[], fmi3IntervalQualifier qualifiers[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    (void)qualifiers;
    NOT_SUPPORTED("fmi3GetIntervalDecimal", "the FMU has no clocks");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[],
                                   fmi3IntervalQualifier qualifiers[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    (void)qualifiers;
    NOT_SUPPORTED("fmi3GetIntervalFraction", "the FMU has no clocks");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_SUPPORTED("fmi3GetShiftDecimal", "the FMU has no clocks");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[], fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED("fmi3GetShiftFraction", "the FMU has no clocks");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)intervals;
    NOT_SUPPORTED("fmi3SetIntervalDecimal", "the FMU has no clocks");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED("fmi3SetIntervalFraction", "the FMU has no clocks");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)shifts;
    NOT_SUPPORTED("fmi3SetShiftDecimal", "the FMU has no clocks");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[], const fmi3UInt64 resolutions[])
{
    (void)valueReferences;
    (void)nValueReferences;
    (void)counters;
    (void)resolutions;
    NOT_SUPPORTED("fmi3SetShiftFraction", "the FMU has no clocks");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance)
{
    CHECK(MT_EVENT | MT_STEP, "fmi3EvaluateDiscreteStates");
    return fmi3OK; /* discrete states are updated only at sample instants, in fmi3UpdateDiscreteStates */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation, fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged, fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime)
{
    int defined = 0;
    double next = 0.0;
    fmi3Status status;
    CHECK(MT_EVENT, "fmi3UpdateDiscreteStates");
    status = (fmi3Status)mt_update_discrete(INST, &defined, &next);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = defined ? fmi3True : fmi3False;
    if (nextEventTime) *nextEventTime = next;
    return status;
}

/* Model Exchange */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance)
{
    CHECK(MT_EVENT, "fmi3EnterContinuousTimeMode");
    CHECK_ME("fmi3EnterContinuousTimeMode");
    INST->mode = MT_CONTINUOUS;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance, fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode, fmi3Boolean *terminateSimulation)
{
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(MT_CONTINUOUS, "fmi3CompletedIntegratorStep");
    CHECK_ME("fmi3CompletedIntegratorStep");
    if (enterEventMode) *enterEventMode = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time)
{
    CHECK(MT_EVENT | MT_CONTINUOUS, "fmi3SetTime");
    CHECK_ME("fmi3SetTime");
    return (fmi3Status)mt_set_time(INST, time);
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates)
{
    CHECK(MT_EVENT | MT_CONTINUOUS, "fmi3SetContinuousStates");
    CHECK_ME("fmi3SetContinuousStates");
    return (fmi3Status)mt_set_states(INST, continuousStates, nContinuousStates, "fmi3SetContinuousStates");
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates)
{
    CHECK(EVALUATED, "fmi3GetContinuousStateDerivatives");
    CHECK_ME("fmi3GetContinuousStateDerivatives");
    return (fmi3Status)mt_get_derivatives(INST, derivatives, nContinuousStates, "fmi3GetContinuousStateDerivatives");
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[], size_t nEventIndicators)
{
    (void)eventIndicators;
    CHECK(EVALUATED, "fmi3GetEventIndicators");
    CHECK_ME("fmi3GetEventIndicators");
    return (fmi3Status)mt_check_event_indicators(INST, nEventIndicators, "fmi3GetEventIndicators");
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[], size_t nContinuousStates)
{
    CHECK(EVALUATED, "fmi3GetContinuousStates");
    CHECK_ME("fmi3GetContinuousStates");
    return (fmi3Status)mt_get_states(INST, continuousStates, nContinuousStates, "fmi3GetContinuousStates");
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[], size_t nContinuousStates)
{
    CHECK(EVALUATED, "fmi3GetNominalsOfContinuousStates");
    CHECK_ME("fmi3GetNominalsOfContinuousStates");
    return (fmi3Status)mt_get_nominals(INST, nominals, nContinuousStates, "fmi3GetNominalsOfContinuousStates");
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators)
{
    CHECK(MT_ANY_MODE, "fmi3GetNumberOfEventIndicators");
    if (!nEventIndicators) return fmi3Error;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates)
{
    CHECK(MT_ANY_MODE, "fmi3GetNumberOfContinuousStates");
    if (!nContinuousStates) return fmi3Error;
    *nContinuousStates = (size_t)INST->m->nx;
    return fmi3OK;
}

/* Co-Simulation */

fmi3Status fmi3EnterStepMode(fmi3Instance instance)
{
    CHECK(MT_EVENT, "fmi3EnterStepMode");
    CHECK_CS("fmi3EnterStepMode");
    INST->mode = MT_STEP;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[], fmi3Float64 values[],
                                    size_t nValues)
{
    (void)valueReferences;
    (void)orders;
    (void)values;
    (void)nValues;
    CHECK(MT_STEP | MT_TERMINATED | MT_FAILED, "fmi3GetOutputDerivatives");
    if (nValueReferences == 0) return fmi3OK;
    ERR("fmi3GetOutputDerivatives: not supported (maxOutputDerivativeOrder is 0)");
    return fmi3Error;
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint, fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint, fmi3Boolean *eventHandlingNeeded,
                      fmi3Boolean *terminateSimulation, fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime)
{
    fmi3Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    CHECK(MT_STEP, "fmi3DoStep");
    CHECK_CS("fmi3DoStep");
    status = (fmi3Status)mt_do_step(INST, currentCommunicationPoint, communicationStepSize, "fmi3DoStep");
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = INST->t;
    return status;
}

/* Scheduled Execution: not supported */

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime)
{
    (void)clockReference;
    (void)activationTime;
    NOT_SUPPORTED("fmi3ActivateModelPartition", "Scheduled Execution");
}
