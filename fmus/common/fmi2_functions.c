/*
 * FMI 2.0 model exchange and co-simulation, shared by the sysid FMUs: the FMI 2.0 signatures
 * and state machine around the version-independent core (fmu_core.c). Nothing in this file
 * knows about a particular model. Only Real variables exist; the Integer/Boolean/String
 * accessors accept empty requests.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmi2Functions.h"
#include "fmu_model.h"

typedef char fmi2_status_values_match[(fmi2Error == (int)FMU_ERROR &&
                                       fmi2Discard == (int)FMU_DISCARD) ? 1 : -1];

#define ST(x) ((fmi2Status)(x))

/* ------------------------------------------------------------------------------------------ */
/* logging                                                                                      */

void fmu_log(const ModelInstance *comp, FmuStatus status, const char *category,
             const char *format, ...) {
    char message[1024], escaped[2048];
    va_list args;
    size_t i, j;
    fmi2CallbackLogger logger;
    if (!comp || !comp->logger) return;
    if (!comp->loggingOn && status <= FMU_WARNING) return;
    va_start(args, format);
    vsnprintf(message, sizeof message, format, args);
    va_end(args);
    /* The message is passed as the format string, '%' escaped: importers that format the
     * variadic logger (C) and importers that cannot (ctypes callbacks) both show it. */
    for (i = 0, j = 0; message[i] && j + 2 < sizeof escaped; i++) {
        if (message[i] == '%') escaped[j++] = '%';
        escaped[j++] = message[i];
    }
    escaped[j] = '\0';
    logger = (fmi2CallbackLogger)comp->logger;
    logger((fmi2ComponentEnvironment)comp->environment, comp->instanceName, ST(status),
           category, escaped);
}

/* ------------------------------------------------------------------------------------------ */
/* common functions                                                                             */

const char *fmi2GetTypesPlatform(void) { return fmi2TypesPlatform; }

const char *fmi2GetVersion(void) { return fmi2Version; }

fmi2Status fmi2SetDebugLogging(fmi2Component c, fmi2Boolean loggingOn, size_t nCategories,
                               const fmi2String categories[]) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)nCategories;
    (void)categories;
    if (fmu_invalid_phase(comp, "fmi2SetDebugLogging", ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    comp->loggingOn = loggingOn ? 1 : 0;
    return fmi2OK;
}

fmi2Component fmi2Instantiate(fmi2String instanceName, fmi2Type fmuType, fmi2String fmuGUID,
                              fmi2String fmuResourceLocation,
                              const fmi2CallbackFunctions *functions, fmi2Boolean visible,
                              fmi2Boolean loggingOn) {
    ModelInstance *comp;
    (void)fmuResourceLocation;
    (void)visible;
    if (!functions || !functions->logger) return NULL;
    if (!instanceName || !instanceName[0]) {
        functions->logger(functions->componentEnvironment, "?", fmi2Error, "logError",
                          "fmi2Instantiate: missing instance name");
        return NULL;
    }
    if (!fmuGUID || strcmp(fmuGUID, MODEL_GUID) != 0) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logError", "fmi2Instantiate: GUID %s does not match this binary (%s)",
                          fmuGUID ? fmuGUID : "(null)", MODEL_GUID);
        return NULL;
    }
#ifdef MODEL_CO_SIMULATION_ONLY
    if (fmuType != fmi2CoSimulation) {
        functions->logger(functions->componentEnvironment, instanceName, fmi2Error,
                          "logError", "fmi2Instantiate: this FMU supports co-simulation only");
        return NULL;
    }
#endif
    comp = fmu_new_instance(instanceName, fmuType == fmi2ModelExchange ? FMU_MODEL_EXCHANGE
                                                                        : FMU_CO_SIMULATION);
    if (!comp) return NULL;
    comp->logger = (void (*)(void))functions->logger;
    comp->environment = functions->componentEnvironment;
    comp->loggingOn = loggingOn ? 1 : 0;
    return comp;
}

void fmi2FreeInstance(fmi2Component c) { fmu_free_instance((ModelInstance *)c); }

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    if (fmu_invalid_phase(comp, "fmi2SetupExperiment", PHASE_INSTANTIATED)) return fmi2Error;
    comp->startTime = startTime;
    comp->stopTime = stopTime;
    comp->stopTimeDefined = stopTimeDefined ? 1 : 0;
    comp->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2EnterInitializationMode", PHASE_INSTANTIATED))
        return fmi2Error;
    comp->s.phase = PHASE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2ExitInitializationMode", PHASE_INITIALIZATION))
        return fmi2Error;
    return ST(fmu_exit_initialization(comp));
}

/* Terminate is accepted in every running mode and also after an error (a refused step, a
 * delay the history cannot answer): it ends the run without computing anything, so an
 * importer that terminates before freeing (libcosim does) gets fmi2OK instead of a second,
 * confusing state error. */
fmi2Status fmi2Terminate(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2Terminate", RUNNING | PHASE_ERROR)) return fmi2Error;
    comp->s.phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2Reset", ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    return ST(fmu_reset(comp));
}

/* ------------------------------------------------------------------------------------------ */
/* variable access                                                                              */

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    return ST(fmu_get_reals((ModelInstance *)c, "fmi2GetReal", vr, nvr, value));
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    return ST(fmu_set_reals((ModelInstance *)c, "fmi2SetReal", vr, nvr, value));
}

static fmi2Status no_such_variables(ModelInstance *comp, const char *function, size_t nvr) {
    if (fmu_invalid_phase(comp, function, ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    fmu_log(comp, FMU_ERROR, "logStatusError", "%s: this FMU has no such variables", function);
    return fmi2Error;
}

fmi2Status fmi2GetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2GetInteger", nvr);
}

fmi2Status fmi2GetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2GetBoolean", nvr);
}

fmi2Status fmi2GetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2GetString", nvr);
}

fmi2Status fmi2SetInteger(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Integer value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2SetInteger", nvr);
}

fmi2Status fmi2SetBoolean(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                          const fmi2Boolean value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2SetBoolean", nvr);
}

fmi2Status fmi2SetString(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                         const fmi2String value[]) {
    (void)vr;
    (void)value;
    return no_such_variables((ModelInstance *)c, "fmi2SetString", nvr);
}

/* ------------------------------------------------------------------------------------------ */
/* FMU state                                                                                    */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    return ST(fmu_get_state((ModelInstance *)c, "fmi2GetFMUstate", FMUstate));
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    return ST(fmu_set_state((ModelInstance *)c, "fmi2SetFMUstate", FMUstate));
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    if (!c) return fmi2Error;
    fmu_free_state(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2SerializedFMUstateSize", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (fmu_null_pointer(comp, "fmi2SerializedFMUstateSize", "FMUstate", FMUstate) ||
        fmu_null_pointer(comp, "fmi2SerializedFMUstateSize", "size", size))
        return fmi2Error;
    *size = fmu_serialized_size(FMUstate);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2SerializeFMUstate", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (fmu_null_pointer(comp, "fmi2SerializeFMUstate", "FMUstate", FMUstate) ||
        fmu_null_pointer(comp, "fmi2SerializeFMUstate", "serializedState", serializedState))
        return fmi2Error;
    return ST(fmu_serialize_state(comp, FMUstate, (unsigned char *)serializedState, size));
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2DeSerializeFMUstate", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (fmu_null_pointer(comp, "fmi2DeSerializeFMUstate", "serializedState", serializedState) ||
        fmu_null_pointer(comp, "fmi2DeSerializeFMUstate", "FMUstate", FMUstate))
        return fmi2Error;
    return ST(fmu_deserialize_state(comp, (const unsigned char *)serializedState, size,
                                    FMUstate));
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    return ST(fmu_directional((ModelInstance *)c, "fmi2GetDirectionalDerivative", vUnknown_ref,
                              nUnknown, vKnown_ref, nKnown, dvKnown, dvUnknown));
}

/* ------------------------------------------------------------------------------------------ */
/* model exchange                                                                               */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    comp->s.phase = PHASE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2NewDiscreteStates", PHASE_EVENT)) return fmi2Error;
    if (fmu_null_pointer(comp, "fmi2NewDiscreteStates", "eventInfo", eventInfo))
        return fmi2Error;
    /* No discrete states and no time events; a model with an input history only learns
     * here that its pending step event is being handled. */
    model_event_update(comp);
    eventInfo->newDiscreteStatesNeeded = fmi2False;
    eventInfo->terminateSimulation = fmi2False;
    eventInfo->nominalsOfContinuousStatesChanged = fmi2False;
    eventInfo->valuesOfContinuousStatesChanged = fmi2False;
    eventInfo->nextEventTimeDefined = fmi2False;
    eventInfo->nextEventTime = 0.0;
    return fmi2OK;
}

fmi2Status fmi2EnterContinuousTimeMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2EnterContinuousTimeMode", PHASE_EVENT)) return fmi2Error;
    comp->s.phase = PHASE_CONTINUOUS_TIME;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (fmu_invalid_phase(comp, "fmi2CompletedIntegratorStep", PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    if (fmu_null_pointer(comp, "fmi2CompletedIntegratorStep", "enterEventMode", enterEventMode) ||
        fmu_null_pointer(comp, "fmi2CompletedIntegratorStep", "terminateSimulation",
                         terminateSimulation))
        return fmi2Error;
    *enterEventMode = model_step_event(comp) ? fmi2True : fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2SetTime", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    comp->s.time = time;
    comp->s.dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi2SetContinuousStates", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    if (fmu_check_state_count(comp, "fmi2SetContinuousStates", nx) != FMU_OK) return fmi2Error;
    if (nx && fmu_null_pointer(comp, "fmi2SetContinuousStates", "x[]", x)) return fmi2Error;
    for (i = 0; i < nx; i++) comp->s.r[VR_STATE0 + i] = x[i];
    comp->s.dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    if (fmu_invalid_phase(comp, "fmi2GetDerivatives", RUNNING | PHASE_INITIALIZATION |
                          PHASE_TERMINATED | PHASE_ERROR))
        return fmi2Error;
    if (fmu_check_state_count(comp, "fmi2GetDerivatives", nx) != FMU_OK) return fmi2Error;
    if (nx == 0) return fmi2OK;
    if (fmu_null_pointer(comp, "fmi2GetDerivatives", "derivatives[]", derivatives))
        return fmi2Error;
    if (fmu_ensure_derived(comp) > FMU_WARNING) return ST(fmu_fail(comp));
    model_derivatives(comp, comp->s.time, comp->s.r + VR_STATE0, derivatives);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)eventIndicators;
    if (fmu_invalid_phase(comp, "fmi2GetEventIndicators", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (ni != 0) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "fmi2GetEventIndicators: the model has none");
        return ST(fmu_fail(comp));
    }
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi2GetContinuousStates", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (fmu_check_state_count(comp, "fmi2GetContinuousStates", nx) != FMU_OK) return fmi2Error;
    if (nx && fmu_null_pointer(comp, "fmi2GetContinuousStates", "x[]", x)) return fmi2Error;
    for (i = 0; i < nx; i++) x[i] = comp->s.r[VR_STATE0 + i];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (fmu_invalid_phase(comp, "fmi2GetNominalsOfContinuousStates", ALL_ALIVE | PHASE_ERROR))
        return fmi2Error;
    if (fmu_check_state_count(comp, "fmi2GetNominalsOfContinuousStates", nx) != FMU_OK)
        return fmi2Error;
    if (nx && fmu_null_pointer(comp, "fmi2GetNominalsOfContinuousStates", "x_nominal[]",
                               x_nominal))
        return fmi2Error;
    for (i = 0; i < nx; i++) x_nominal[i] = MODEL_STATE_NOMINAL[i];
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------ */
/* co-simulation                                                                                */

fmi2Status fmi2SetRealInputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                       const fmi2Integer order[], const fmi2Real value[]) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)vr;
    (void)order;
    (void)value;
    if (!comp) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    fmu_log(comp, FMU_ERROR, "logError",
            "fmi2SetRealInputDerivatives: inputs are held constant over a step "
            "(canInterpolateInputs=false)");
    return fmi2Error;
}

fmi2Status fmi2GetRealOutputDerivatives(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                                        const fmi2Integer order[], fmi2Real value[]) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)vr;
    (void)order;
    (void)value;
    if (!comp) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    fmu_log(comp, FMU_ERROR, "logError",
            "fmi2GetRealOutputDerivatives is not provided (maxOutputDerivativeOrder=0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (fmu_invalid_phase(comp, "fmi2DoStep", PHASE_STEP_COMPLETE)) return fmi2Error;
    return ST(fmu_do_step(comp, "fmi2DoStep", currentCommunicationPoint,
                          communicationStepSize));
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (!comp) return fmi2Error;
    fmu_log(comp, FMU_ERROR, "logError", "fmi2CancelStep: steps are never asynchronous");
    return fmi2Error;
}

static fmi2Status no_status(ModelInstance *comp, const char *function) {
    if (!comp) return fmi2Error;
    fmu_log(comp, FMU_DISCARD, "logStatusDiscard", "%s: no such status (steps are synchronous)",
            function);
    return fmi2Discard;
}

fmi2Status fmi2GetStatus(fmi2Component c, const fmi2StatusKind s, fmi2Status *value) {
    (void)s;
    (void)value;
    return no_status((ModelInstance *)c, "fmi2GetStatus");
}

fmi2Status fmi2GetRealStatus(fmi2Component c, const fmi2StatusKind s, fmi2Real *value) {
    ModelInstance *comp = (ModelInstance *)c;
    if (comp && s == fmi2LastSuccessfulTime && value) {
        *value = comp->s.time;
        return fmi2OK;
    }
    return no_status(comp, "fmi2GetRealStatus");
}

fmi2Status fmi2GetIntegerStatus(fmi2Component c, const fmi2StatusKind s, fmi2Integer *value) {
    (void)s;
    (void)value;
    return no_status((ModelInstance *)c, "fmi2GetIntegerStatus");
}

fmi2Status fmi2GetBooleanStatus(fmi2Component c, const fmi2StatusKind s, fmi2Boolean *value) {
    (void)s;
    (void)value;
    return no_status((ModelInstance *)c, "fmi2GetBooleanStatus");
}

fmi2Status fmi2GetStringStatus(fmi2Component c, const fmi2StatusKind s, fmi2String *value) {
    (void)s;
    (void)value;
    return no_status((ModelInstance *)c, "fmi2GetStringStatus");
}
