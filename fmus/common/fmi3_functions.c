/*
 * FMI 3.0 model exchange and co-simulation, shared by the sysid FMUs: the FMI 3.0 signatures
 * and state machine around the version-independent core (fmu_core.c), the counterpart of
 * fmi2_functions.c. Only Float64 variables exist; the accessors of the other types accept
 * empty requests. Co-simulation has no event mode (hasEventMode="false"), no early return
 * and no intermediate updates; clocks and scheduled execution are not provided.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi3Functions.h"
#include "fmu_model.h"

typedef char fmi3_status_values_match[(fmi3Error == (int)FMU_ERROR &&
                                       fmi3Discard == (int)FMU_DISCARD) ? 1 : -1];

#define ST(x) ((fmi3Status)(x))

void fmu_log(const ModelInstance *comp, FmuStatus status, const char *category,
             const char *format, ...) {
    char message[1024];
    va_list args;
    fmi3LogMessageCallback logger;
    if (!comp || !comp->logger) return;
    if (!comp->loggingOn && status <= FMU_WARNING) return;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    logger = (fmi3LogMessageCallback)comp->logger;
    logger((fmi3InstanceEnvironment)comp->environment, ST(status), category, message);
}

/* ------------------------------------------------------------------------------------------ */
/* common functions                                                                             */

const char *fmi3GetVersion(void) { return fmi3Version; }

fmi3Status fmi3SetDebugLogging(fmi3Instance instance, fmi3Boolean loggingOn, size_t nCategories,
                               const fmi3String categories[]) {
    ModelInstance *comp = (ModelInstance *)instance;
    (void)nCategories;
    (void)categories;
    if (fmu_invalid_phase(comp, "fmi3SetDebugLogging", ALL_ALIVE | PHASE_ERROR)) return fmi3Error;
    comp->loggingOn = loggingOn ? 1 : 0;
    return fmi3OK;
}

static ModelInstance *instantiate(fmi3String instanceName, fmi3String token,
                                  fmi3Boolean loggingOn, fmi3InstanceEnvironment environment,
                                  fmi3LogMessageCallback logMessage, FmuInterface interface,
                                  const char *function) {
    ModelInstance *comp;
    if (!instanceName || !instanceName[0]) {
        if (logMessage) logMessage(environment, fmi3Error, "logError", "missing instance name");
        return NULL;
    }
    if (!token || strcmp(token, MODEL_GUID) != 0) {
        if (logMessage) {
            char message[512];
            snprintf(message, sizeof message, "%s: instantiation token %s does not match this "
                     "binary (%s)", function, token ? token : "(null)", MODEL_GUID);
            logMessage(environment, fmi3Error, "logError", message);
        }
        return NULL;
    }
    comp = fmu_new_instance(instanceName, interface);
    if (!comp) return NULL;
    comp->logger = (void (*)(void))logMessage;
    comp->environment = environment;
    comp->loggingOn = loggingOn ? 1 : 0;
    return comp;
}

fmi3Instance fmi3InstantiateModelExchange(fmi3String instanceName, fmi3String instantiationToken,
                                          fmi3String resourcePath, fmi3Boolean visible,
                                          fmi3Boolean loggingOn,
                                          fmi3InstanceEnvironment instanceEnvironment,
                                          fmi3LogMessageCallback logMessage) {
    (void)resourcePath;
    (void)visible;
#ifdef MODEL_CO_SIMULATION_ONLY
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logError",
                   "fmi3InstantiateModelExchange: this FMU supports co-simulation only");
    (void)instanceName; (void)instantiationToken; (void)loggingOn;
    return NULL;
#else
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment,
                       logMessage, FMU_MODEL_EXCHANGE, "fmi3InstantiateModelExchange");
#endif
}

fmi3Instance fmi3InstantiateCoSimulation(fmi3String instanceName, fmi3String instantiationToken,
                                         fmi3String resourcePath, fmi3Boolean visible,
                                         fmi3Boolean loggingOn, fmi3Boolean eventModeUsed,
                                         fmi3Boolean earlyReturnAllowed,
                                         const fmi3ValueReference requiredIntermediateVariables[],
                                         size_t nRequiredIntermediateVariables,
                                         fmi3InstanceEnvironment instanceEnvironment,
                                         fmi3LogMessageCallback logMessage,
                                         fmi3IntermediateUpdateCallback intermediateUpdate) {
    (void)resourcePath;
    (void)visible;
    (void)earlyReturnAllowed;
    (void)requiredIntermediateVariables;
    (void)nRequiredIntermediateVariables;
    (void)intermediateUpdate;
    if (eventModeUsed) {
        if (logMessage)
            logMessage(instanceEnvironment, fmi3Error, "logError",
                       "fmi3InstantiateCoSimulation: event mode is not supported "
                       "(hasEventMode=false)");
        return NULL;
    }
    return instantiate(instanceName, instantiationToken, loggingOn, instanceEnvironment,
                       logMessage, FMU_CO_SIMULATION, "fmi3InstantiateCoSimulation");
}

fmi3Instance fmi3InstantiateScheduledExecution(
    fmi3String instanceName, fmi3String instantiationToken, fmi3String resourcePath,
    fmi3Boolean visible, fmi3Boolean loggingOn, fmi3InstanceEnvironment instanceEnvironment,
    fmi3LogMessageCallback logMessage, fmi3ClockUpdateCallback clockUpdate,
    fmi3LockPreemptionCallback lockPreemption, fmi3UnlockPreemptionCallback unlockPreemption) {
    (void)instanceName; (void)instantiationToken; (void)resourcePath; (void)visible;
    (void)loggingOn; (void)clockUpdate; (void)lockPreemption; (void)unlockPreemption;
    if (logMessage)
        logMessage(instanceEnvironment, fmi3Error, "logError",
                   "fmi3InstantiateScheduledExecution: scheduled execution is not provided");
    return NULL;
}

void fmi3FreeInstance(fmi3Instance instance) { fmu_free_instance((ModelInstance *)instance); }

fmi3Status fmi3EnterInitializationMode(fmi3Instance instance, fmi3Boolean toleranceDefined,
                                       fmi3Float64 tolerance, fmi3Float64 startTime,
                                       fmi3Boolean stopTimeDefined, fmi3Float64 stopTime) {
    ModelInstance *comp = (ModelInstance *)instance;
    (void)toleranceDefined;
    (void)tolerance;
    if (fmu_invalid_phase(comp, "fmi3EnterInitializationMode", PHASE_INSTANTIATED))
        return fmi3Error;
    comp->startTime = startTime;
    comp->stopTime = stopTime;
    comp->stopTimeDefined = stopTimeDefined ? 1 : 0;
    comp->s.time = startTime;
    comp->s.phase = PHASE_INITIALIZATION;
    return fmi3OK;
}

fmi3Status fmi3ExitInitializationMode(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3ExitInitializationMode", PHASE_INITIALIZATION))
        return fmi3Error;
    return ST(fmu_exit_initialization(comp));
}

fmi3Status fmi3EnterEventMode(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi3Error;
    comp->s.phase = PHASE_EVENT;
    return fmi3OK;
}

/* Accepted in every running mode and after an error, as in fmi2_functions.c. */
fmi3Status fmi3Terminate(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3Terminate", RUNNING | PHASE_ERROR)) return fmi3Error;
    comp->s.phase = PHASE_TERMINATED;
    return fmi3OK;
}

fmi3Status fmi3Reset(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3Reset", ALL_ALIVE | PHASE_ERROR)) return fmi3Error;
    return ST(fmu_reset(comp));
}

/* ------------------------------------------------------------------------------------------ */
/* variable access                                                                              */

static int value_count(ModelInstance *comp, const char *function, size_t nvr, size_t nValues) {
    if (nvr != nValues) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s: %u value references but %u values "
                "(only scalar variables exist)", function, (unsigned)nvr, (unsigned)nValues);
        return 1;
    }
    return 0;
}

fmi3Status fmi3GetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, fmi3Float64 values[], size_t nValues) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (comp && value_count(comp, "fmi3GetFloat64", nValueReferences, nValues)) return fmi3Error;
    return ST(fmu_get_reals(comp, "fmi3GetFloat64", valueReferences, nValueReferences, values));
}

fmi3Status fmi3SetFloat64(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                          size_t nValueReferences, const fmi3Float64 values[], size_t nValues) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (comp && value_count(comp, "fmi3SetFloat64", nValueReferences, nValues)) return fmi3Error;
    return ST(fmu_set_reals(comp, "fmi3SetFloat64", valueReferences, nValueReferences, values));
}

static fmi3Status no_such_variables(fmi3Instance instance, const char *function, size_t nvr) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, function, ALL_ALIVE | PHASE_ERROR)) return fmi3Error;
    if (nvr == 0) return fmi3OK;
    fmu_log(comp, FMU_ERROR, "logStatusError", "%s: this FMU has no such variables", function);
    return fmi3Error;
}

#define NO_VARIABLES(name, type, qualifier)                                                    \
    fmi3Status name(fmi3Instance instance, const fmi3ValueReference valueReferences[],         \
                    size_t nValueReferences, qualifier type values[], size_t nValues) {        \
        (void)valueReferences;                                                                 \
        (void)values;                                                                          \
        (void)nValues;                                                                         \
        return no_such_variables(instance, #name, nValueReferences);                           \
    }

NO_VARIABLES(fmi3GetFloat32, fmi3Float32, )
NO_VARIABLES(fmi3GetInt8, fmi3Int8, )
NO_VARIABLES(fmi3GetUInt8, fmi3UInt8, )
NO_VARIABLES(fmi3GetInt16, fmi3Int16, )
NO_VARIABLES(fmi3GetUInt16, fmi3UInt16, )
NO_VARIABLES(fmi3GetInt32, fmi3Int32, )
NO_VARIABLES(fmi3GetUInt32, fmi3UInt32, )
NO_VARIABLES(fmi3GetInt64, fmi3Int64, )
NO_VARIABLES(fmi3GetUInt64, fmi3UInt64, )
NO_VARIABLES(fmi3GetBoolean, fmi3Boolean, )
NO_VARIABLES(fmi3GetString, fmi3String, )
NO_VARIABLES(fmi3SetFloat32, fmi3Float32, const)
NO_VARIABLES(fmi3SetInt8, fmi3Int8, const)
NO_VARIABLES(fmi3SetUInt8, fmi3UInt8, const)
NO_VARIABLES(fmi3SetInt16, fmi3Int16, const)
NO_VARIABLES(fmi3SetUInt16, fmi3UInt16, const)
NO_VARIABLES(fmi3SetInt32, fmi3Int32, const)
NO_VARIABLES(fmi3SetUInt32, fmi3UInt32, const)
NO_VARIABLES(fmi3SetInt64, fmi3Int64, const)
NO_VARIABLES(fmi3SetUInt64, fmi3UInt64, const)
NO_VARIABLES(fmi3SetBoolean, fmi3Boolean, const)
NO_VARIABLES(fmi3SetString, fmi3String, const)

fmi3Status fmi3GetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, size_t valueSizes[], fmi3Binary values[],
                         size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return no_such_variables(instance, "fmi3GetBinary", nValueReferences);
}

fmi3Status fmi3SetBinary(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                         size_t nValueReferences, const size_t valueSizes[],
                         const fmi3Binary values[], size_t nValues) {
    (void)valueReferences; (void)valueSizes; (void)values; (void)nValues;
    return no_such_variables(instance, "fmi3SetBinary", nValueReferences);
}

fmi3Status fmi3GetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return no_such_variables(instance, "fmi3GetClock", nValueReferences);
}

fmi3Status fmi3SetClock(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                        size_t nValueReferences, const fmi3Clock values[]) {
    (void)valueReferences; (void)values;
    return no_such_variables(instance, "fmi3SetClock", nValueReferences);
}

static fmi3Status not_provided(fmi3Instance instance, const char *function) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (!comp) return fmi3Error;
    fmu_log(comp, FMU_ERROR, "logError", "%s is not provided by this FMU", function);
    return fmi3Error;
}

fmi3Status fmi3GetNumberOfVariableDependencies(fmi3Instance instance,
                                               fmi3ValueReference valueReference,
                                               size_t *nDependencies) {
    (void)valueReference; (void)nDependencies;
    return not_provided(instance, "fmi3GetNumberOfVariableDependencies");
}

fmi3Status fmi3GetVariableDependencies(fmi3Instance instance, fmi3ValueReference dependent,
                                       size_t elementIndicesOfDependent[],
                                       fmi3ValueReference independents[],
                                       size_t elementIndicesOfIndependents[],
                                       fmi3DependencyKind dependencyKinds[],
                                       size_t nDependencies) {
    (void)dependent; (void)elementIndicesOfDependent; (void)independents;
    (void)elementIndicesOfIndependents; (void)dependencyKinds; (void)nDependencies;
    return not_provided(instance, "fmi3GetVariableDependencies");
}

/* ------------------------------------------------------------------------------------------ */
/* FMU state and derivatives                                                                    */

fmi3Status fmi3GetFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    return ST(fmu_get_state((ModelInstance *)instance, "fmi3GetFMUState", FMUState));
}

fmi3Status fmi3SetFMUState(fmi3Instance instance, fmi3FMUState FMUState) {
    return ST(fmu_set_state((ModelInstance *)instance, "fmi3SetFMUState", FMUState));
}

fmi3Status fmi3FreeFMUState(fmi3Instance instance, fmi3FMUState *FMUState) {
    if (!instance) return fmi3Error;
    fmu_free_state(FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializedFMUStateSize(fmi3Instance instance, fmi3FMUState FMUState,
                                      size_t *size) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3SerializedFMUStateSize", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3SerializedFMUStateSize", "FMUState", FMUState) ||
        fmu_null_pointer(comp, "fmi3SerializedFMUStateSize", "size", size))
        return fmi3Error;
    *size = fmu_serialized_size(FMUState);
    return fmi3OK;
}

fmi3Status fmi3SerializeFMUState(fmi3Instance instance, fmi3FMUState FMUState,
                                 fmi3Byte serializedState[], size_t size) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3SerializeFMUState", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3SerializeFMUState", "FMUState", FMUState) ||
        fmu_null_pointer(comp, "fmi3SerializeFMUState", "serializedState", serializedState))
        return fmi3Error;
    return ST(fmu_serialize_state(comp, FMUState, serializedState, size));
}

fmi3Status fmi3DeserializeFMUState(fmi3Instance instance, const fmi3Byte serializedState[],
                                   size_t size, fmi3FMUState *FMUState) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3DeserializeFMUState", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3DeserializeFMUState", "serializedState", serializedState) ||
        fmu_null_pointer(comp, "fmi3DeserializeFMUState", "FMUState", FMUState))
        return fmi3Error;
    return ST(fmu_deserialize_state(comp, serializedState, size, FMUState));
}

fmi3Status fmi3GetDirectionalDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                        size_t nUnknowns, const fmi3ValueReference knowns[],
                                        size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                        fmi3Float64 sensitivity[], size_t nSensitivity) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (comp && (nSeed != nKnowns || nSensitivity != nUnknowns)) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "fmi3GetDirectionalDerivative: nSeed must "
                "equal nKnowns and nSensitivity nUnknowns (only scalar variables exist)");
        return ST(fmu_fail(comp));
    }
    return ST(fmu_directional(comp, "fmi3GetDirectionalDerivative", unknowns, nUnknowns, knowns,
                              nKnowns, seed, sensitivity));
}

fmi3Status fmi3GetAdjointDerivative(fmi3Instance instance, const fmi3ValueReference unknowns[],
                                    size_t nUnknowns, const fmi3ValueReference knowns[],
                                    size_t nKnowns, const fmi3Float64 seed[], size_t nSeed,
                                    fmi3Float64 sensitivity[], size_t nSensitivity) {
    (void)unknowns; (void)nUnknowns; (void)knowns; (void)nKnowns; (void)seed; (void)nSeed;
    (void)sensitivity; (void)nSensitivity;
    return not_provided(instance, "fmi3GetAdjointDerivative");
}

fmi3Status fmi3EnterConfigurationMode(fmi3Instance instance) {
    return not_provided(instance, "fmi3EnterConfigurationMode");
}

fmi3Status fmi3ExitConfigurationMode(fmi3Instance instance) {
    return not_provided(instance, "fmi3ExitConfigurationMode");
}

fmi3Status fmi3GetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, fmi3Float64 intervals[],
                                  fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals; (void)qualifiers;
    return not_provided(instance, "fmi3GetIntervalDecimal");
}

fmi3Status fmi3GetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, fmi3UInt64 counters[],
                                   fmi3UInt64 resolutions[], fmi3IntervalQualifier qualifiers[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    (void)qualifiers;
    return not_provided(instance, "fmi3GetIntervalFraction");
}

fmi3Status fmi3GetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return not_provided(instance, "fmi3GetShiftDecimal");
}

fmi3Status fmi3GetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, fmi3UInt64 counters[],
                                fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return not_provided(instance, "fmi3GetShiftFraction");
}

fmi3Status fmi3SetIntervalDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                  size_t nValueReferences, const fmi3Float64 intervals[]) {
    (void)valueReferences; (void)nValueReferences; (void)intervals;
    return not_provided(instance, "fmi3SetIntervalDecimal");
}

fmi3Status fmi3SetIntervalFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                   size_t nValueReferences, const fmi3UInt64 counters[],
                                   const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return not_provided(instance, "fmi3SetIntervalFraction");
}

fmi3Status fmi3SetShiftDecimal(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                               size_t nValueReferences, const fmi3Float64 shifts[]) {
    (void)valueReferences; (void)nValueReferences; (void)shifts;
    return not_provided(instance, "fmi3SetShiftDecimal");
}

fmi3Status fmi3SetShiftFraction(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                size_t nValueReferences, const fmi3UInt64 counters[],
                                const fmi3UInt64 resolutions[]) {
    (void)valueReferences; (void)nValueReferences; (void)counters; (void)resolutions;
    return not_provided(instance, "fmi3SetShiftFraction");
}

fmi3Status fmi3EvaluateDiscreteStates(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3EvaluateDiscreteStates", RUNNING)) return fmi3Error;
    return fmi3OK; /* no discrete states */
}

fmi3Status fmi3UpdateDiscreteStates(fmi3Instance instance, fmi3Boolean *discreteStatesNeedUpdate,
                                    fmi3Boolean *terminateSimulation,
                                    fmi3Boolean *nominalsOfContinuousStatesChanged,
                                    fmi3Boolean *valuesOfContinuousStatesChanged,
                                    fmi3Boolean *nextEventTimeDefined,
                                    fmi3Float64 *nextEventTime) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3UpdateDiscreteStates", PHASE_EVENT)) return fmi3Error;
    /* No discrete states and no time events; a model with an input history only learns
     * here that its pending step event is being handled. */
    model_event_update(comp);
    if (discreteStatesNeedUpdate) *discreteStatesNeedUpdate = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (nominalsOfContinuousStatesChanged) *nominalsOfContinuousStatesChanged = fmi3False;
    if (valuesOfContinuousStatesChanged) *valuesOfContinuousStatesChanged = fmi3False;
    if (nextEventTimeDefined) *nextEventTimeDefined = fmi3False;
    if (nextEventTime) *nextEventTime = 0.0;
    return fmi3OK;
}

/* ------------------------------------------------------------------------------------------ */
/* model exchange                                                                               */

fmi3Status fmi3EnterContinuousTimeMode(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3EnterContinuousTimeMode", PHASE_EVENT)) return fmi3Error;
    comp->s.phase = PHASE_CONTINUOUS_TIME;
    return fmi3OK;
}

fmi3Status fmi3CompletedIntegratorStep(fmi3Instance instance,
                                       fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi3Boolean *enterEventMode,
                                       fmi3Boolean *terminateSimulation) {
    ModelInstance *comp = (ModelInstance *)instance;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (fmu_invalid_phase(comp, "fmi3CompletedIntegratorStep", PHASE_CONTINUOUS_TIME))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3CompletedIntegratorStep", "enterEventMode", enterEventMode) ||
        fmu_null_pointer(comp, "fmi3CompletedIntegratorStep", "terminateSimulation",
                         terminateSimulation))
        return fmi3Error;
    *enterEventMode = model_step_event(comp) ? fmi3True : fmi3False;
    *terminateSimulation = fmi3False;
    return fmi3OK;
}

fmi3Status fmi3SetTime(fmi3Instance instance, fmi3Float64 time) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3SetTime", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi3Error;
    comp->s.time = time;
    comp->s.dirty = 1;
    return fmi3OK;
}

fmi3Status fmi3SetContinuousStates(fmi3Instance instance, const fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    ModelInstance *comp = (ModelInstance *)instance;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi3SetContinuousStates", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi3Error;
    if (fmu_check_state_count(comp, "fmi3SetContinuousStates", nContinuousStates) != FMU_OK)
        return fmi3Error;
    if (nContinuousStates &&
        fmu_null_pointer(comp, "fmi3SetContinuousStates", "continuousStates[]", continuousStates))
        return fmi3Error;
    for (i = 0; i < nContinuousStates; i++) comp->s.r[VR_STATE0 + i] = continuousStates[i];
    comp->s.dirty = 1;
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStateDerivatives(fmi3Instance instance, fmi3Float64 derivatives[],
                                             size_t nContinuousStates) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3GetContinuousStateDerivatives", RUNNING |
                          PHASE_INITIALIZATION | PHASE_TERMINATED | PHASE_ERROR))
        return fmi3Error;
    if (fmu_check_state_count(comp, "fmi3GetContinuousStateDerivatives", nContinuousStates)
        != FMU_OK)
        return fmi3Error;
    if (nContinuousStates == 0) return fmi3OK;
    if (fmu_null_pointer(comp, "fmi3GetContinuousStateDerivatives", "derivatives[]", derivatives))
        return fmi3Error;
    if (fmu_ensure_derived(comp) > FMU_WARNING) return ST(fmu_fail(comp));
    model_derivatives(comp, comp->s.time, comp->s.r + VR_STATE0, derivatives);
    return fmi3OK;
}

fmi3Status fmi3GetEventIndicators(fmi3Instance instance, fmi3Float64 eventIndicators[],
                                  size_t nEventIndicators) {
    ModelInstance *comp = (ModelInstance *)instance;
    (void)eventIndicators;
    if (fmu_invalid_phase(comp, "fmi3GetEventIndicators", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (nEventIndicators != 0) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "fmi3GetEventIndicators: the model has none");
        return ST(fmu_fail(comp));
    }
    return fmi3OK;
}

fmi3Status fmi3GetContinuousStates(fmi3Instance instance, fmi3Float64 continuousStates[],
                                   size_t nContinuousStates) {
    ModelInstance *comp = (ModelInstance *)instance;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi3GetContinuousStates", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_check_state_count(comp, "fmi3GetContinuousStates", nContinuousStates) != FMU_OK)
        return fmi3Error;
    if (nContinuousStates &&
        fmu_null_pointer(comp, "fmi3GetContinuousStates", "continuousStates[]", continuousStates))
        return fmi3Error;
    for (i = 0; i < nContinuousStates; i++) continuousStates[i] = comp->s.r[VR_STATE0 + i];
    return fmi3OK;
}

fmi3Status fmi3GetNominalsOfContinuousStates(fmi3Instance instance, fmi3Float64 nominals[],
                                             size_t nContinuousStates) {
    ModelInstance *comp = (ModelInstance *)instance;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi3GetNominalsOfContinuousStates", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_check_state_count(comp, "fmi3GetNominalsOfContinuousStates", nContinuousStates)
        != FMU_OK)
        return fmi3Error;
    if (nContinuousStates &&
        fmu_null_pointer(comp, "fmi3GetNominalsOfContinuousStates", "nominals[]", nominals))
        return fmi3Error;
    for (i = 0; i < nContinuousStates; i++) nominals[i] = MODEL_STATE_NOMINAL[i];
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfEventIndicators(fmi3Instance instance, size_t *nEventIndicators) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3GetNumberOfEventIndicators", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3GetNumberOfEventIndicators", "nEventIndicators",
                         nEventIndicators))
        return fmi3Error;
    *nEventIndicators = 0;
    return fmi3OK;
}

fmi3Status fmi3GetNumberOfContinuousStates(fmi3Instance instance, size_t *nContinuousStates) {
    ModelInstance *comp = (ModelInstance *)instance;
    if (fmu_invalid_phase(comp, "fmi3GetNumberOfContinuousStates", ALL_ALIVE | PHASE_ERROR))
        return fmi3Error;
    if (fmu_null_pointer(comp, "fmi3GetNumberOfContinuousStates", "nContinuousStates",
                         nContinuousStates))
        return fmi3Error;
    *nContinuousStates = N_STATES;
    return fmi3OK;
}

/* ------------------------------------------------------------------------------------------ */
/* co-simulation                                                                                */

fmi3Status fmi3EnterStepMode(fmi3Instance instance) {
    ModelInstance *comp = (ModelInstance *)instance;
    /* without event mode the instance is in Step Mode right after initialisation */
    if (fmu_invalid_phase(comp, "fmi3EnterStepMode", PHASE_STEP_COMPLETE)) return fmi3Error;
    return fmi3OK;
}

fmi3Status fmi3GetOutputDerivatives(fmi3Instance instance, const fmi3ValueReference valueReferences[],
                                    size_t nValueReferences, const fmi3Int32 orders[],
                                    fmi3Float64 values[], size_t nValues) {
    (void)valueReferences; (void)orders; (void)values; (void)nValues;
    if (nValueReferences == 0 && instance) return fmi3OK;
    return not_provided(instance, "fmi3GetOutputDerivatives (maxOutputDerivativeOrder=0)");
}

fmi3Status fmi3DoStep(fmi3Instance instance, fmi3Float64 currentCommunicationPoint,
                      fmi3Float64 communicationStepSize,
                      fmi3Boolean noSetFMUStatePriorToCurrentPoint,
                      fmi3Boolean *eventHandlingNeeded, fmi3Boolean *terminateSimulation,
                      fmi3Boolean *earlyReturn, fmi3Float64 *lastSuccessfulTime) {
    ModelInstance *comp = (ModelInstance *)instance;
    FmuStatus status;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (fmu_invalid_phase(comp, "fmi3DoStep", PHASE_STEP_COMPLETE)) return fmi3Error;
    status = fmu_do_step(comp, "fmi3DoStep", currentCommunicationPoint, communicationStepSize);
    if (eventHandlingNeeded) *eventHandlingNeeded = fmi3False;
    if (terminateSimulation) *terminateSimulation = fmi3False;
    if (earlyReturn) *earlyReturn = fmi3False;
    if (lastSuccessfulTime) *lastSuccessfulTime = comp->s.time;
    return ST(status);
}

fmi3Status fmi3ActivateModelPartition(fmi3Instance instance, fmi3ValueReference clockReference,
                                      fmi3Float64 activationTime) {
    (void)clockReference; (void)activationTime;
    return not_provided(instance, "fmi3ActivateModelPartition");
}
