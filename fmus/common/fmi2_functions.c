/*
 * FMI 2.0 model exchange and co-simulation boilerplate shared by the sysid FMUs.
 *
 * Nothing in this file knows about a particular model: the model is reached only through
 * the generated tables in model_variables.h and the functions declared in fmu_model.h.
 * Only Real variables exist; the Integer/Boolean/String accessors accept empty requests.
 */
#include <math.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_model.h"

#define ALL_ALIVE (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | \
                   PHASE_CONTINUOUS_TIME | PHASE_STEP_COMPLETE | PHASE_TERMINATED)
#define BEFORE_INIT (PHASE_INSTANTIATED | PHASE_INITIALIZATION)
#define RUNNING (PHASE_EVENT | PHASE_CONTINUOUS_TIME | PHASE_STEP_COMPLETE)

/* Serialised snapshots start with this tag and the snapshot size, so that a buffer from an
 * other model or build is refused instead of being misread. */
#define SNAPSHOT_MAGIC 0x53595344u /* "SYSD" */

/* ------------------------------------------------------------------------------------------ */
/* logging and state checks                                                                     */

void fmu_log(const ModelInstance *comp, fmi2Status status, const char *category,
             const char *format, ...) {
    char message[1024], escaped[2048];
    va_list args;
    size_t i, j;
    if (!comp || !comp->callbacks.logger) return;
    if (!comp->loggingOn && status <= fmi2Warning) return;
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
    comp->callbacks.logger(comp->callbacks.componentEnvironment, comp->instanceName, status,
                           category, escaped);
}

static int invalid_phase(ModelInstance *comp, const char *function, int allowed) {
    if (!comp) return 1;
    if (!(comp->s.phase & allowed)) {
        fmu_log(comp, fmi2Error, "logStatusError", "%s must not be called in this state",
                function);
        comp->s.phase = PHASE_ERROR;
        return 1;
    }
    return 0;
}

static int null_pointer(ModelInstance *comp, const char *function, const char *argument,
                        const void *p) {
    if (p == NULL) {
        fmu_log(comp, fmi2Error, "logStatusError", "%s: argument %s is NULL", function,
                argument);
        comp->s.phase = PHASE_ERROR;
        return 1;
    }
    return 0;
}

static fmi2Status fail(ModelInstance *comp) {
    comp->s.phase = PHASE_ERROR;
    return fmi2Error;
}

/* Derived constants are recomputed whenever a parameter changed, so that values can also be
 * read in initialisation mode (before fmi2ExitInitializationMode). */
static fmi2Status ensure_derived(ModelInstance *comp) {
    fmi2Status status;
    if (comp->s.derived_valid) return fmi2OK;
    status = model_initialize(comp);
    if (status <= fmi2Warning) comp->s.derived_valid = 1;
    return status;
}

/* ------------------------------------------------------------------------------------------ */
/* default event hooks (fmu_model.h) for models without an input history                       */

#ifndef MODEL_HAS_EVENT_HOOKS
fmi2Status model_inputs_set(ModelInstance *comp) {
    (void)comp;
    return fmi2OK;
}

int model_step_event(const ModelInstance *comp) {
    (void)comp;
    return 0;
}

void model_event_update(ModelInstance *comp) { (void)comp; }
#endif

/* ------------------------------------------------------------------------------------------ */
/* integrator offered to the models                                                             */

static int all_finite(const double *x, int n) {
    int i;
    for (i = 0; i < n; i++)
        if (!isfinite(x[i])) return 0;
    return 1;
}

fmi2Status fmu_integrate_rk4(ModelInstance *comp, double h, double h_max) {
    double *x = comp->s.r + VR_STATE0;
    double k1[N_STATES], k2[N_STATES], k3[N_STATES], k4[N_STATES], xt[N_STATES];
    double t = comp->s.time;
    const double t_end = comp->s.time + h;
    int i;

    if (!(h_max > 0.0)) {
        fmu_log(comp, fmi2Error, "logError", "integration step must be positive, got %g", h_max);
        return fmi2Error;
    }
    while (t < t_end) {
        const double t_ok = t;
        /* Shorten the last sub-step so that the step lands exactly on the communication
         * point; a remainder below 1e-9 of a step is merged into the previous sub-step. */
        double dt = t_end - t;
        if (dt > h_max * (1.0 + 1e-9)) dt = h_max;
        model_derivatives(comp, t, x, k1);
        for (i = 0; i < N_STATES; i++) xt[i] = x[i] + 0.5 * dt * k1[i];
        model_derivatives(comp, t + 0.5 * dt, xt, k2);
        for (i = 0; i < N_STATES; i++) xt[i] = x[i] + 0.5 * dt * k2[i];
        model_derivatives(comp, t + 0.5 * dt, xt, k3);
        for (i = 0; i < N_STATES; i++) xt[i] = x[i] + dt * k3[i];
        model_derivatives(comp, t + dt, xt, k4);
        for (i = 0; i < N_STATES; i++)
            x[i] += dt / 6.0 * (k1[i] + 2.0 * (k2[i] + k3[i]) + k4[i]);
        t = (dt == t_end - t) ? t_end : t + dt;
        if (!all_finite(x, N_STATES)) {
            /* FMI 2.0 fmi2Discard: the step was computed only up to t_ok, which
             * fmi2GetRealStatus(fmi2LastSuccessfulTime) reports. */
            comp->s.time = t_ok;
            fmu_log(comp, fmi2Discard, "logStatusDiscard",
                    "state became non-finite at t = %.6g s (simulation diverged)", t);
            return fmi2Discard;
        }
    }
    comp->s.time = t_end;
    comp->s.dirty = 1;
    return fmi2OK;
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
    if (invalid_phase(comp, "fmi2SetDebugLogging", ALL_ALIVE)) return fmi2Error;
    comp->loggingOn = loggingOn ? 1 : 0;
    return fmi2OK;
}

static void set_start_values(ModelInstance *comp) {
    int i;
    for (i = 0; i < N_REALS; i++) comp->s.r[i] = MODEL_START[i];
    memset(&comp->s.data, 0, sizeof comp->s.data);
    comp->s.time = 0.0;
    comp->s.dirty = 1;
    comp->s.derived_valid = 0;
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
    comp = (ModelInstance *)calloc(1, sizeof(ModelInstance));
    if (!comp) return NULL;
    comp->instanceName = (char *)malloc(strlen(instanceName) + 1);
    if (!comp->instanceName) {
        free(comp);
        return NULL;
    }
    strcpy(comp->instanceName, instanceName);
    comp->type = fmuType;
    comp->callbacks = *functions;
    comp->loggingOn = loggingOn ? 1 : 0;
    set_start_values(comp);
    comp->s.phase = PHASE_INSTANTIATED;
    return comp;
}

void fmi2FreeInstance(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (!comp) return;
    free(comp->instanceName);
    free(comp);
}

fmi2Status fmi2SetupExperiment(fmi2Component c, fmi2Boolean toleranceDefined,
                               fmi2Real tolerance, fmi2Real startTime,
                               fmi2Boolean stopTimeDefined, fmi2Real stopTime) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)toleranceDefined;
    (void)tolerance;
    if (invalid_phase(comp, "fmi2SetupExperiment", PHASE_INSTANTIATED)) return fmi2Error;
    comp->startTime = startTime;
    comp->stopTime = stopTime;
    comp->stopTimeDefined = stopTimeDefined ? 1 : 0;
    comp->s.time = startTime;
    return fmi2OK;
}

fmi2Status fmi2EnterInitializationMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2EnterInitializationMode", PHASE_INSTANTIATED)) return fmi2Error;
    comp->s.phase = PHASE_INITIALIZATION;
    return fmi2OK;
}

fmi2Status fmi2ExitInitializationMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    fmi2Status status;
    if (invalid_phase(comp, "fmi2ExitInitializationMode", PHASE_INITIALIZATION)) return fmi2Error;
    comp->s.derived_valid = 0;
    status = ensure_derived(comp);
    if (status > fmi2Warning) return fail(comp);
    /* the inputs set during initialisation are those in effect at the start time */
    if (model_inputs_set(comp) > fmi2Warning) return fail(comp);
    comp->s.dirty = 1;
    comp->s.phase = comp->type == fmi2ModelExchange ? PHASE_EVENT : PHASE_STEP_COMPLETE;
    return status;
}

fmi2Status fmi2Terminate(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2Terminate", RUNNING)) return fmi2Error;
    comp->s.phase = PHASE_TERMINATED;
    return fmi2OK;
}

fmi2Status fmi2Reset(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2Reset", ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    set_start_values(comp);
    model_reset(comp);
    comp->s.phase = PHASE_INSTANTIATED;
    return fmi2OK;
}

/* ------------------------------------------------------------------------------------------ */
/* variable access                                                                              */

static int check_vr(ModelInstance *comp, const char *function, fmi2ValueReference vr) {
    if (vr >= N_REALS) {
        fmu_log(comp, fmi2Error, "logStatusError", "%s: unknown value reference %u", function,
                (unsigned)vr);
        return 1;
    }
    return 0;
}

fmi2Status fmi2GetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       fmi2Real value[]) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (invalid_phase(comp, "fmi2GetReal", ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (null_pointer(comp, "fmi2GetReal", "vr[]", vr) ||
        null_pointer(comp, "fmi2GetReal", "value[]", value))
        return fmi2Error;
    if (comp->s.dirty && !(comp->s.phase & PHASE_INSTANTIATED)) {
        if (ensure_derived(comp) > fmi2Warning) return fail(comp);
        model_calculate_values(comp);
        comp->s.dirty = 0;
    }
    for (i = 0; i < nvr; i++) {
        if (check_vr(comp, "fmi2GetReal", vr[i])) return fail(comp);
        value[i] = comp->s.r[vr[i]];
    }
    return fmi2OK;
}

fmi2Status fmi2SetReal(fmi2Component c, const fmi2ValueReference vr[], size_t nvr,
                       const fmi2Real value[]) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    int inputs_changed = 0;
    if (invalid_phase(comp, "fmi2SetReal", ALL_ALIVE & ~PHASE_TERMINATED)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    if (null_pointer(comp, "fmi2SetReal", "vr[]", vr) ||
        null_pointer(comp, "fmi2SetReal", "value[]", value))
        return fmi2Error;
    /* Check everything first so that a refused request leaves no partial update. */
    for (i = 0; i < nvr; i++) {
        int kind;
        if (check_vr(comp, "fmi2SetReal", vr[i])) return fmi2Error;
        kind = MODEL_VAR_KIND[vr[i]];
        if (kind == KIND_DERIVATIVE || kind == KIND_OUTPUT) {
            fmu_log(comp, fmi2Error, "logStatusError",
                    "fmi2SetReal: %s is calculated and cannot be set", MODEL_VAR_NAMES[vr[i]]);
            return fmi2Error;
        }
        if ((kind == KIND_PARAMETER || kind == KIND_STATE) && !(comp->s.phase & BEFORE_INIT)) {
            fmu_log(comp, fmi2Error, "logStatusError",
                    "fmi2SetReal: %s can only be set before initialisation ends",
                    MODEL_VAR_NAMES[vr[i]]);
            return fmi2Error;
        }
        if (!isfinite(value[i])) {
            fmu_log(comp, fmi2Error, "logError", "fmi2SetReal: %s must be finite, got %g",
                    MODEL_VAR_NAMES[vr[i]], value[i]);
            return fmi2Error;
        }
    }
    for (i = 0; i < nvr; i++) {
        comp->s.r[vr[i]] = value[i];
        if (MODEL_VAR_KIND[vr[i]] == KIND_PARAMETER) comp->s.derived_valid = 0;
        if (MODEL_VAR_KIND[vr[i]] == KIND_INPUT) inputs_changed = 1;
    }
    comp->s.dirty = 1;
    /* Before initialisation ends the time stands at the start time and parameters may still
     * change: fmi2ExitInitializationMode reports the inputs once instead. */
    if (inputs_changed && (comp->s.phase & RUNNING)) {
        if (model_inputs_set(comp) > fmi2Warning) return fail(comp);
    }
    return fmi2OK;
}

static fmi2Status no_such_variables(ModelInstance *comp, const char *function, size_t nvr) {
    if (invalid_phase(comp, function, ALL_ALIVE)) return fmi2Error;
    if (nvr == 0) return fmi2OK;
    fmu_log(comp, fmi2Error, "logStatusError", "%s: this FMU has no such variables", function);
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
/* FMU state: a snapshot is a heap copy of ModelSnapshot                                        */

fmi2Status fmi2GetFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *comp = (ModelInstance *)c;
    ModelSnapshot *snap;
    if (invalid_phase(comp, "fmi2GetFMUstate", ALL_ALIVE)) return fmi2Error;
    if (null_pointer(comp, "fmi2GetFMUstate", "FMUstate", FMUstate)) return fmi2Error;
    snap = (ModelSnapshot *)*FMUstate;
    if (!snap) {
        snap = (ModelSnapshot *)malloc(sizeof(ModelSnapshot));
        if (!snap) {
            fmu_log(comp, fmi2Error, "logError", "fmi2GetFMUstate: out of memory");
            return fmi2Error;
        }
    }
    *snap = comp->s;
    *FMUstate = snap;
    return fmi2OK;
}

fmi2Status fmi2SetFMUstate(fmi2Component c, fmi2FMUstate FMUstate) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2SetFMUstate", ALL_ALIVE | PHASE_ERROR)) return fmi2Error;
    if (null_pointer(comp, "fmi2SetFMUstate", "FMUstate", FMUstate)) return fmi2Error;
    comp->s = *(const ModelSnapshot *)FMUstate;
    return fmi2OK;
}

fmi2Status fmi2FreeFMUstate(fmi2Component c, fmi2FMUstate *FMUstate) {
    ModelInstance *comp = (ModelInstance *)c;
    if (!comp) return fmi2Error;
    if (FMUstate && *FMUstate) {
        free(*FMUstate);
        *FMUstate = NULL;
    }
    return fmi2OK;
}

#define SERIAL_HEADER (2 * sizeof(unsigned int))

fmi2Status fmi2SerializedFMUstateSize(fmi2Component c, fmi2FMUstate FMUstate, size_t *size) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2SerializedFMUstateSize", ALL_ALIVE)) return fmi2Error;
    if (null_pointer(comp, "fmi2SerializedFMUstateSize", "size", size)) return fmi2Error;
    (void)FMUstate;
    *size = SERIAL_HEADER + sizeof(ModelSnapshot);
    return fmi2OK;
}

fmi2Status fmi2SerializeFMUstate(fmi2Component c, fmi2FMUstate FMUstate,
                                 fmi2Byte serializedState[], size_t size) {
    ModelInstance *comp = (ModelInstance *)c;
    unsigned int header[2];
    if (invalid_phase(comp, "fmi2SerializeFMUstate", ALL_ALIVE)) return fmi2Error;
    if (null_pointer(comp, "fmi2SerializeFMUstate", "FMUstate", FMUstate) ||
        null_pointer(comp, "fmi2SerializeFMUstate", "serializedState", serializedState))
        return fmi2Error;
    if (size < SERIAL_HEADER + sizeof(ModelSnapshot)) {
        fmu_log(comp, fmi2Error, "logStatusError", "fmi2SerializeFMUstate: buffer too small");
        return fmi2Error;
    }
    header[0] = SNAPSHOT_MAGIC;
    header[1] = (unsigned int)sizeof(ModelSnapshot);
    memcpy(serializedState, header, SERIAL_HEADER);
    memcpy(serializedState + SERIAL_HEADER, FMUstate, sizeof(ModelSnapshot));
    return fmi2OK;
}

fmi2Status fmi2DeSerializeFMUstate(fmi2Component c, const fmi2Byte serializedState[],
                                   size_t size, fmi2FMUstate *FMUstate) {
    ModelInstance *comp = (ModelInstance *)c;
    unsigned int header[2];
    ModelSnapshot *snap;
    if (invalid_phase(comp, "fmi2DeSerializeFMUstate", ALL_ALIVE)) return fmi2Error;
    if (null_pointer(comp, "fmi2DeSerializeFMUstate", "serializedState", serializedState) ||
        null_pointer(comp, "fmi2DeSerializeFMUstate", "FMUstate", FMUstate))
        return fmi2Error;
    if (size != SERIAL_HEADER + sizeof(ModelSnapshot)) {
        fmu_log(comp, fmi2Error, "logError",
                "fmi2DeSerializeFMUstate: %u bytes do not hold a state of this FMU",
                (unsigned)size);
        return fmi2Error;
    }
    memcpy(header, serializedState, SERIAL_HEADER);
    if (header[0] != SNAPSHOT_MAGIC || header[1] != sizeof(ModelSnapshot)) {
        fmu_log(comp, fmi2Error, "logError",
                "fmi2DeSerializeFMUstate: buffer was not serialised by this FMU");
        return fmi2Error;
    }
    snap = (ModelSnapshot *)*FMUstate;
    if (!snap) {
        snap = (ModelSnapshot *)malloc(sizeof(ModelSnapshot));
        if (!snap) return fmi2Error;
    }
    memcpy(snap, serializedState + SERIAL_HEADER, sizeof(ModelSnapshot));
    *FMUstate = snap;
    return fmi2OK;
}

fmi2Status fmi2GetDirectionalDerivative(fmi2Component c, const fmi2ValueReference vUnknown_ref[],
                                        size_t nUnknown, const fmi2ValueReference vKnown_ref[],
                                        size_t nKnown, const fmi2Real dvKnown[],
                                        fmi2Real dvUnknown[]) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)vUnknown_ref;
    (void)nUnknown;
    (void)vKnown_ref;
    (void)nKnown;
    (void)dvKnown;
    (void)dvUnknown;
    if (!comp) return fmi2Error;
    fmu_log(comp, fmi2Error, "logError",
            "fmi2GetDirectionalDerivative is not provided (providesDirectionalDerivative=false)");
    return fmi2Error;
}

/* ------------------------------------------------------------------------------------------ */
/* model exchange                                                                               */

fmi2Status fmi2EnterEventMode(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2EnterEventMode", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    comp->s.phase = PHASE_EVENT;
    return fmi2OK;
}

fmi2Status fmi2NewDiscreteStates(fmi2Component c, fmi2EventInfo *eventInfo) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2NewDiscreteStates", PHASE_EVENT)) return fmi2Error;
    if (null_pointer(comp, "fmi2NewDiscreteStates", "eventInfo", eventInfo)) return fmi2Error;
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
    if (invalid_phase(comp, "fmi2EnterContinuousTimeMode", PHASE_EVENT)) return fmi2Error;
    comp->s.phase = PHASE_CONTINUOUS_TIME;
    return fmi2OK;
}

fmi2Status fmi2CompletedIntegratorStep(fmi2Component c, fmi2Boolean noSetFMUStatePriorToCurrentPoint,
                                       fmi2Boolean *enterEventMode, fmi2Boolean *terminateSimulation) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (invalid_phase(comp, "fmi2CompletedIntegratorStep", PHASE_CONTINUOUS_TIME)) return fmi2Error;
    if (null_pointer(comp, "fmi2CompletedIntegratorStep", "enterEventMode", enterEventMode) ||
        null_pointer(comp, "fmi2CompletedIntegratorStep", "terminateSimulation", terminateSimulation))
        return fmi2Error;
    *enterEventMode = model_step_event(comp) ? fmi2True : fmi2False;
    *terminateSimulation = fmi2False;
    return fmi2OK;
}

fmi2Status fmi2SetTime(fmi2Component c, fmi2Real time) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2SetTime", PHASE_EVENT | PHASE_CONTINUOUS_TIME)) return fmi2Error;
    comp->s.time = time;
    comp->s.dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2SetContinuousStates(fmi2Component c, const fmi2Real x[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (invalid_phase(comp, "fmi2SetContinuousStates", PHASE_EVENT | PHASE_CONTINUOUS_TIME))
        return fmi2Error;
    if (nx != N_STATES) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2SetContinuousStates: expected %d states, got %u", N_STATES, (unsigned)nx);
        return fail(comp);
    }
    if (null_pointer(comp, "fmi2SetContinuousStates", "x[]", x)) return fmi2Error;
    for (i = 0; i < nx; i++) comp->s.r[VR_STATE0 + i] = x[i];
    comp->s.dirty = 1;
    return fmi2OK;
}

fmi2Status fmi2GetDerivatives(fmi2Component c, fmi2Real derivatives[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    if (invalid_phase(comp, "fmi2GetDerivatives", RUNNING | PHASE_INITIALIZATION |
                      PHASE_TERMINATED | PHASE_ERROR))
        return fmi2Error;
    if (nx != N_STATES) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2GetDerivatives: expected %d states, got %u", N_STATES, (unsigned)nx);
        return fail(comp);
    }
    if (null_pointer(comp, "fmi2GetDerivatives", "derivatives[]", derivatives)) return fmi2Error;
    if (ensure_derived(comp) > fmi2Warning) return fail(comp);
    model_derivatives(comp, comp->s.time, comp->s.r + VR_STATE0, derivatives);
    return fmi2OK;
}

fmi2Status fmi2GetEventIndicators(fmi2Component c, fmi2Real eventIndicators[], size_t ni) {
    ModelInstance *comp = (ModelInstance *)c;
    (void)eventIndicators;
    if (invalid_phase(comp, "fmi2GetEventIndicators", ALL_ALIVE)) return fmi2Error;
    if (ni != 0) {
        fmu_log(comp, fmi2Error, "logStatusError", "fmi2GetEventIndicators: the model has none");
        return fail(comp);
    }
    return fmi2OK;
}

fmi2Status fmi2GetContinuousStates(fmi2Component c, fmi2Real x[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (invalid_phase(comp, "fmi2GetContinuousStates", ALL_ALIVE)) return fmi2Error;
    if (nx != N_STATES) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2GetContinuousStates: expected %d states, got %u", N_STATES, (unsigned)nx);
        return fail(comp);
    }
    if (null_pointer(comp, "fmi2GetContinuousStates", "x[]", x)) return fmi2Error;
    for (i = 0; i < nx; i++) x[i] = comp->s.r[VR_STATE0 + i];
    return fmi2OK;
}

fmi2Status fmi2GetNominalsOfContinuousStates(fmi2Component c, fmi2Real x_nominal[], size_t nx) {
    ModelInstance *comp = (ModelInstance *)c;
    size_t i;
    if (invalid_phase(comp, "fmi2GetNominalsOfContinuousStates", ALL_ALIVE)) return fmi2Error;
    if (nx != N_STATES) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2GetNominalsOfContinuousStates: expected %d states", N_STATES);
        return fail(comp);
    }
    if (null_pointer(comp, "fmi2GetNominalsOfContinuousStates", "x_nominal[]", x_nominal))
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
    fmu_log(comp, fmi2Error, "logError",
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
    fmu_log(comp, fmi2Error, "logError",
            "fmi2GetRealOutputDerivatives is not provided (maxOutputDerivativeOrder=0)");
    return fmi2Error;
}

fmi2Status fmi2DoStep(fmi2Component c, fmi2Real currentCommunicationPoint,
                      fmi2Real communicationStepSize, fmi2Boolean noSetFMUStatePriorToCurrentPoint) {
    ModelInstance *comp = (ModelInstance *)c;
    fmi2Status status;
    (void)noSetFMUStatePriorToCurrentPoint;
    if (invalid_phase(comp, "fmi2DoStep", PHASE_STEP_COMPLETE)) return fmi2Error;
    if (!(communicationStepSize > 0.0)) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2DoStep: communication step size must be positive, got %g",
                communicationStepSize);
        return fail(comp);
    }
    if (fabs(currentCommunicationPoint - comp->s.time) >
        1e-9 * (1.0 + fabs(comp->s.time))) {
        fmu_log(comp, fmi2Error, "logStatusError",
                "fmi2DoStep: communication point %.12g s does not match the FMU time %.12g s",
                currentCommunicationPoint, comp->s.time);
        return fail(comp);
    }
    status = model_do_step(comp, communicationStepSize);
    if (status == fmi2Discard) {
        /* diverged: values and fmi2GetRealStatus stay readable, stepping on does not */
        comp->s.phase = PHASE_ERROR;
        return fmi2Discard;
    }
    if (status > fmi2Warning) return fail(comp);
    comp->s.dirty = 1;
    return status;
}

fmi2Status fmi2CancelStep(fmi2Component c) {
    ModelInstance *comp = (ModelInstance *)c;
    if (!comp) return fmi2Error;
    fmu_log(comp, fmi2Error, "logError", "fmi2CancelStep: steps are never asynchronous");
    return fmi2Error;
}

static fmi2Status no_status(ModelInstance *comp, const char *function) {
    if (!comp) return fmi2Error;
    fmu_log(comp, fmi2Discard, "logStatusDiscard", "%s: no such status (steps are synchronous)",
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
