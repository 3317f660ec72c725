/*
 * The FMI-version-independent part of the boilerplate shared by the sysid FMUs: instance
 * memory, start values, Real value access with its checks, the RK4 integrator, FMU-state
 * snapshots (plain snapshot plus a copy of the model's growable storage), directional
 * derivatives through the model's hook. fmi2_functions.c and fmi3_functions.c wrap these
 * in the signatures and state machines of FMI 2.0 and FMI 3.0.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_model.h"

/* Serialised snapshots start with this tag, the snapshot size and the storage length, so
 * that a buffer from another model or build is refused instead of being misread. */
#define SNAPSHOT_MAGIC 0x53595345u /* "SYSE" */

/* ------------------------------------------------------------------------------------------ */
/* default hooks for models without them                                                       */

#ifndef MODEL_HAS_EVENT_HOOKS
FmuStatus model_inputs_set(ModelInstance *comp) {
    (void)comp;
    return FMU_OK;
}

int model_step_event(const ModelInstance *comp) {
    (void)comp;
    return 0;
}

void model_event_update(ModelInstance *comp) { (void)comp; }
#endif

/* ------------------------------------------------------------------------------------------ */
/* state checks                                                                                 */

int fmu_invalid_phase(ModelInstance *comp, const char *function, int allowed) {
    if (!comp) return 1;
    if (!(comp->s.phase & allowed)) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s must not be called in this state",
                function);
        comp->s.phase = PHASE_ERROR;
        return 1;
    }
    return 0;
}

int fmu_null_pointer(ModelInstance *comp, const char *function, const char *argument,
                     const void *p) {
    if (p == NULL) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s: argument %s is NULL", function,
                argument);
        comp->s.phase = PHASE_ERROR;
        return 1;
    }
    return 0;
}

FmuStatus fmu_fail(ModelInstance *comp) {
    comp->s.phase = PHASE_ERROR;
    return FMU_ERROR;
}

/* ------------------------------------------------------------------------------------------ */
/* instances, storage, start values                                                             */

ModelInstance *fmu_new_instance(const char *instanceName, FmuInterface interface) {
    ModelInstance *comp = (ModelInstance *)calloc(1, sizeof(ModelInstance));
    if (!comp) return NULL;
    comp->instanceName = (char *)malloc(strlen(instanceName) + 1);
    if (!comp->instanceName) {
        free(comp);
        return NULL;
    }
    strcpy(comp->instanceName, instanceName);
    comp->interface = interface;
    fmu_set_start_values(comp);
    comp->s.phase = PHASE_INSTANTIATED;
    return comp;
}

void fmu_free_instance(ModelInstance *comp) {
    if (!comp) return;
    free(comp->store);
    free(comp->instanceName);
    free(comp);
}

int fmu_store_reserve(ModelInstance *comp, size_t n) {
    double *grown;
    size_t capacity;
    if (n <= comp->store_capacity) return 1;
    capacity = comp->store_capacity ? comp->store_capacity : 256;
    while (capacity < n) capacity *= 2;
    grown = (double *)realloc(comp->store, capacity * sizeof(double));
    if (!grown) {
        fmu_log(comp, FMU_ERROR, "logError", "out of memory growing the model storage to %lu "
                "values", (unsigned long)capacity);
        return 0;
    }
    comp->store = grown;
    comp->store_capacity = capacity;
    return 1;
}

void fmu_set_start_values(ModelInstance *comp) {
    int i;
    for (i = 0; i < N_REALS; i++) comp->s.r[i] = MODEL_START[i];
    memset(&comp->s.data, 0, sizeof comp->s.data);
    comp->s.time = 0.0;
    comp->s.dirty = 1;
    comp->s.derived_valid = 0;
    comp->s.store_used = 0;
}

/* Derived constants are recomputed whenever a parameter changed, so that values can also be
 * read in initialisation mode. */
FmuStatus fmu_ensure_derived(ModelInstance *comp) {
    FmuStatus status;
    if (comp->s.derived_valid) return FMU_OK;
    status = model_initialize(comp);
    if (status <= FMU_WARNING) comp->s.derived_valid = 1;
    return status;
}

FmuStatus fmu_exit_initialization(ModelInstance *comp) {
    FmuStatus status;
    comp->s.derived_valid = 0;
    status = fmu_ensure_derived(comp);
    if (status > FMU_WARNING) return fmu_fail(comp);
    /* the inputs set during initialisation are those in effect at the start time */
    if (model_inputs_set(comp) > FMU_WARNING) return fmu_fail(comp);
    comp->s.dirty = 1;
    comp->s.phase = comp->interface == FMU_MODEL_EXCHANGE ? PHASE_EVENT : PHASE_STEP_COMPLETE;
    return status;
}

FmuStatus fmu_reset(ModelInstance *comp) {
    fmu_set_start_values(comp);
    model_reset(comp);
    comp->s.phase = PHASE_INSTANTIATED;
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* integrator offered to the models                                                             */

static int all_finite(const double *x, int n) {
    int i;
    for (i = 0; i < n; i++)
        if (!isfinite(x[i])) return 0;
    return 1;
}

FmuStatus fmu_integrate_rk4(ModelInstance *comp, double h, double h_max) {
    double *x = comp->s.r + VR_STATE0;
    double k1[N_STATES_ALLOC], k2[N_STATES_ALLOC], k3[N_STATES_ALLOC], k4[N_STATES_ALLOC];
    double xt[N_STATES_ALLOC];
    double t = comp->s.time;
    const double t_end = comp->s.time + h;
    int i;

    if (!(h_max > 0.0)) {
        fmu_log(comp, FMU_ERROR, "logError", "integration step must be positive, got %g", h_max);
        return FMU_ERROR;
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
            /* Discard: the step was computed only up to t_ok (the last successful time). */
            comp->s.time = t_ok;
            fmu_log(comp, FMU_DISCARD, "logStatusDiscard",
                    "state became non-finite at t = %.6g s (simulation diverged)", t);
            return FMU_DISCARD;
        }
    }
    comp->s.time = t_end;
    comp->s.dirty = 1;
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* Real values                                                                                  */

static int check_vr(ModelInstance *comp, const char *function, unsigned int vr) {
    if (vr == VR_TIME) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s: the time (value reference %u) is "
                "the independent variable, not a state, input or output here", function, vr);
        return 1;
    }
    if (vr >= N_REALS) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s: unknown value reference %u", function,
                vr);
        return 1;
    }
    return 0;
}

static FmuStatus refresh(ModelInstance *comp) {
    if (comp->s.dirty && !(comp->s.phase & PHASE_INSTANTIATED)) {
        if (fmu_ensure_derived(comp) > FMU_WARNING) return fmu_fail(comp);
        model_calculate_values(comp);
        comp->s.dirty = 0;
    }
    return FMU_OK;
}

FmuStatus fmu_get_reals(ModelInstance *comp, const char *function, const unsigned int vr[],
                        size_t nvr, double value[]) {
    size_t i;
    if (fmu_invalid_phase(comp, function, ALL_ALIVE | PHASE_ERROR)) return FMU_ERROR;
    if (nvr == 0) return FMU_OK;
    if (fmu_null_pointer(comp, function, "vr[]", vr) ||
        fmu_null_pointer(comp, function, "value[]", value))
        return FMU_ERROR;
    if (refresh(comp) != FMU_OK) return FMU_ERROR;
    for (i = 0; i < nvr; i++) {
        if (vr[i] == VR_TIME) {
            value[i] = comp->s.time;
            continue;
        }
        if (check_vr(comp, function, vr[i])) return fmu_fail(comp);
        value[i] = comp->s.r[vr[i]];
    }
    return FMU_OK;
}

FmuStatus fmu_set_reals(ModelInstance *comp, const char *function, const unsigned int vr[],
                        size_t nvr, const double value[]) {
    size_t i;
    int inputs_changed = 0;
    if (fmu_invalid_phase(comp, function, ALL_ALIVE & ~PHASE_TERMINATED)) return FMU_ERROR;
    if (nvr == 0) return FMU_OK;
    if (fmu_null_pointer(comp, function, "vr[]", vr) ||
        fmu_null_pointer(comp, function, "value[]", value))
        return FMU_ERROR;
    /* Check everything first so that a refused request leaves no partial update. */
    for (i = 0; i < nvr; i++) {
        int kind;
        if (check_vr(comp, function, vr[i])) return FMU_ERROR;
        kind = MODEL_VAR_KIND[vr[i]];
        if (kind == KIND_DERIVATIVE || kind == KIND_OUTPUT) {
            fmu_log(comp, FMU_ERROR, "logStatusError", "%s: %s is calculated and cannot be set",
                    function, MODEL_VAR_NAMES[vr[i]]);
            return FMU_ERROR;
        }
        if ((kind == KIND_PARAMETER || kind == KIND_STATE) && !(comp->s.phase & BEFORE_INIT)) {
            fmu_log(comp, FMU_ERROR, "logStatusError",
                    "%s: %s can only be set before initialisation ends", function,
                    MODEL_VAR_NAMES[vr[i]]);
            return FMU_ERROR;
        }
        if (!isfinite(value[i])) {
            fmu_log(comp, FMU_ERROR, "logError", "%s: %s must be finite, got %g", function,
                    MODEL_VAR_NAMES[vr[i]], value[i]);
            return FMU_ERROR;
        }
    }
    for (i = 0; i < nvr; i++) {
        comp->s.r[vr[i]] = value[i];
        if (MODEL_VAR_KIND[vr[i]] == KIND_PARAMETER) comp->s.derived_valid = 0;
        if (MODEL_VAR_KIND[vr[i]] == KIND_INPUT) inputs_changed = 1;
    }
    comp->s.dirty = 1;
    /* Before initialisation ends the time stands at the start time and parameters may still
     * change: exiting initialisation reports the inputs once instead. */
    if (inputs_changed && (comp->s.phase & RUNNING)) {
        if (model_inputs_set(comp) > FMU_WARNING) return fmu_fail(comp);
    }
    return FMU_OK;
}

FmuStatus fmu_check_state_count(ModelInstance *comp, const char *function, size_t n) {
    if (n != N_STATES) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "%s: expected %d states, got %u", function,
                N_STATES, (unsigned)n);
        return fmu_fail(comp);
    }
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* co-simulation step                                                                           */

FmuStatus fmu_do_step(ModelInstance *comp, const char *function, double t, double h) {
    FmuStatus status;
    if (!(h > 0.0)) {
        fmu_log(comp, FMU_ERROR, "logStatusError",
                "%s: communication step size must be positive, got %g", function, h);
        return fmu_fail(comp);
    }
    if (fabs(t - comp->s.time) > 1e-9 * (1.0 + fabs(comp->s.time))) {
        fmu_log(comp, FMU_ERROR, "logStatusError",
                "%s: communication point %.12g s does not match the FMU time %.12g s",
                function, t, comp->s.time);
        return fmu_fail(comp);
    }
    if (fmu_ensure_derived(comp) > FMU_WARNING) return fmu_fail(comp);
    status = model_do_step(comp, h);
    if (status == FMU_DISCARD) {
        /* diverged: values and the last successful time stay readable, stepping on does not */
        comp->s.phase = PHASE_ERROR;
        return FMU_DISCARD;
    }
    if (status > FMU_WARNING) return fmu_fail(comp);
    comp->s.dirty = 1;
    return status;
}

/* ------------------------------------------------------------------------------------------ */
/* directional derivatives                                                                      */

#ifdef MODEL_HAS_DIRECTIONAL_DERIVATIVE
FmuStatus fmu_directional(ModelInstance *comp, const char *function,
                          const unsigned int unknowns[], size_t nUnknown,
                          const unsigned int knowns[], size_t nKnown, const double seed[],
                          double sensitivity[]) {
    double dv[N_REALS], out[N_REALS];
    size_t i;
    if (fmu_invalid_phase(comp, function, RUNNING | PHASE_INITIALIZATION)) return FMU_ERROR;
    if (nUnknown == 0) return FMU_OK;
    if (fmu_null_pointer(comp, function, "unknowns[]", unknowns) ||
        fmu_null_pointer(comp, function, "sensitivity[]", sensitivity))
        return FMU_ERROR;
    if (nKnown > 0 && (fmu_null_pointer(comp, function, "knowns[]", knowns) ||
                       fmu_null_pointer(comp, function, "seed[]", seed)))
        return FMU_ERROR;
    memset(dv, 0, sizeof dv);
    for (i = 0; i < nKnown; i++) {
        int kind;
        if (check_vr(comp, function, knowns[i])) return fmu_fail(comp);
        kind = MODEL_VAR_KIND[knowns[i]];
        if (kind != KIND_STATE && kind != KIND_INPUT) {
            fmu_log(comp, FMU_ERROR, "logStatusError",
                    "%s: known %s is not a continuous state or an input", function,
                    MODEL_VAR_NAMES[knowns[i]]);
            return fmu_fail(comp);
        }
        dv[knowns[i]] += seed[i];
    }
    for (i = 0; i < nUnknown; i++) {
        int kind;
        if (check_vr(comp, function, unknowns[i])) return fmu_fail(comp);
        kind = MODEL_VAR_KIND[unknowns[i]];
        if (kind != KIND_DERIVATIVE && kind != KIND_OUTPUT) {
            fmu_log(comp, FMU_ERROR, "logStatusError",
                    "%s: unknown %s is not a state derivative or an output", function,
                    MODEL_VAR_NAMES[unknowns[i]]);
            return fmu_fail(comp);
        }
    }
    if (fmu_ensure_derived(comp) > FMU_WARNING) return fmu_fail(comp);
    memset(out, 0, sizeof out);
    if (model_directional_derivative(comp, dv, out) > FMU_WARNING) return fmu_fail(comp);
    for (i = 0; i < nUnknown; i++) sensitivity[i] = out[unknowns[i]];
    return FMU_OK;
}
#else
FmuStatus fmu_directional(ModelInstance *comp, const char *function,
                          const unsigned int unknowns[], size_t nUnknown,
                          const unsigned int knowns[], size_t nKnown, const double seed[],
                          double sensitivity[]) {
    (void)unknowns; (void)nUnknown; (void)knowns; (void)nKnown; (void)seed; (void)sensitivity;
    if (!comp) return FMU_ERROR;
    fmu_log(comp, FMU_ERROR, "logError", "%s is not provided by this FMU "
            "(providesDirectionalDerivative(s)=false)", function);
    return FMU_ERROR;
}
#endif

/* ------------------------------------------------------------------------------------------ */
/* FMU states: a heap object holding the snapshot and a copy of the used storage               */

typedef struct {
    ModelSnapshot s;
    size_t n;      /* doubles in store */
    double *store; /* NULL when n == 0 */
} FmuState;

FmuStatus fmu_get_state(ModelInstance *comp, const char *function, void **state) {
    FmuState *st;
    if (fmu_invalid_phase(comp, function, ALL_ALIVE | PHASE_ERROR)) return FMU_ERROR;
    if (fmu_null_pointer(comp, function, "FMUstate", state)) return FMU_ERROR;
    st = (FmuState *)*state;
    if (!st) {
        st = (FmuState *)calloc(1, sizeof(FmuState));
        if (!st) {
            fmu_log(comp, FMU_ERROR, "logError", "%s: out of memory", function);
            return FMU_ERROR;
        }
    }
    if (comp->s.store_used != st->n) {
        double *grown = comp->s.store_used
            ? (double *)realloc(st->store, comp->s.store_used * sizeof(double)) : NULL;
        if (comp->s.store_used && !grown) {
            if (!*state) free(st);
            fmu_log(comp, FMU_ERROR, "logError", "%s: out of memory", function);
            return FMU_ERROR;
        }
        if (!comp->s.store_used) free(st->store);
        st->store = grown;
        st->n = comp->s.store_used;
    }
    st->s = comp->s;
    if (st->n) memcpy(st->store, comp->store, st->n * sizeof(double));
    *state = st;
    return FMU_OK;
}

FmuStatus fmu_set_state(ModelInstance *comp, const char *function, const void *state) {
    const FmuState *st = (const FmuState *)state;
    if (fmu_invalid_phase(comp, function, ALL_ALIVE | PHASE_ERROR)) return FMU_ERROR;
    if (fmu_null_pointer(comp, function, "FMUstate", state)) return FMU_ERROR;
    if (!fmu_store_reserve(comp, st->n)) return FMU_ERROR;
    comp->s = st->s;
    if (st->n) memcpy(comp->store, st->store, st->n * sizeof(double));
    return FMU_OK;
}

void fmu_free_state(void **state) {
    FmuState *st;
    if (!state || !*state) return;
    st = (FmuState *)*state;
    free(st->store);
    free(st);
    *state = NULL;
}

#define SERIAL_HEADER (3 * sizeof(unsigned long long))

size_t fmu_serialized_size(const void *state) {
    const FmuState *st = (const FmuState *)state;
    return SERIAL_HEADER + sizeof(ModelSnapshot) + (st ? st->n : 0) * sizeof(double);
}

FmuStatus fmu_serialize_state(ModelInstance *comp, const void *state, unsigned char *out,
                              size_t size) {
    const FmuState *st = (const FmuState *)state;
    unsigned long long header[3];
    if (size < fmu_serialized_size(state)) {
        fmu_log(comp, FMU_ERROR, "logStatusError", "serializing the FMU state: buffer too small");
        return FMU_ERROR;
    }
    header[0] = SNAPSHOT_MAGIC;
    header[1] = sizeof(ModelSnapshot);
    header[2] = st->n;
    memcpy(out, header, SERIAL_HEADER);
    memcpy(out + SERIAL_HEADER, &st->s, sizeof(ModelSnapshot));
    if (st->n)
        memcpy(out + SERIAL_HEADER + sizeof(ModelSnapshot), st->store, st->n * sizeof(double));
    return FMU_OK;
}

FmuStatus fmu_deserialize_state(ModelInstance *comp, const unsigned char *in, size_t size,
                                void **state) {
    unsigned long long header[3];
    FmuState *st;
    size_t n;
    if (size < SERIAL_HEADER + sizeof(ModelSnapshot)) {
        fmu_log(comp, FMU_ERROR, "logError",
                "deserializing the FMU state: %u bytes do not hold a state of this FMU",
                (unsigned)size);
        return FMU_ERROR;
    }
    memcpy(header, in, SERIAL_HEADER);
    n = (size_t)header[2];
    if (header[0] != SNAPSHOT_MAGIC || header[1] != sizeof(ModelSnapshot) ||
        size != SERIAL_HEADER + sizeof(ModelSnapshot) + n * sizeof(double)) {
        fmu_log(comp, FMU_ERROR, "logError",
                "deserializing the FMU state: the buffer was not serialised by this FMU");
        return FMU_ERROR;
    }
    st = (FmuState *)*state;
    if (!st) {
        st = (FmuState *)calloc(1, sizeof(FmuState));
        if (!st) return FMU_ERROR;
    }
    free(st->store);
    st->store = NULL;
    st->n = 0;
    if (n) {
        st->store = (double *)malloc(n * sizeof(double));
        if (!st->store) {
            fmu_log(comp, FMU_ERROR, "logError", "deserializing the FMU state: out of memory");
            return FMU_ERROR;
        }
        memcpy(st->store, in + SERIAL_HEADER + sizeof(ModelSnapshot), n * sizeof(double));
    }
    memcpy(&st->s, in + SERIAL_HEADER, sizeof(ModelSnapshot));
    st->n = n;
    *state = st;
    return FMU_OK;
}
