/*
 * Interface between the shared FMI boilerplate and one model, independent of the FMI version.
 *
 * Every FMU compiles fmu_core.c (integrator, value access, FMU-state snapshots, directional
 * derivatives, growable model storage) and exactly one of fmi2_functions.c (FMI 2.0) or
 * fmi3_functions.c (FMI 3.0), which own the version's state machine and function signatures.
 * A model provides, in its own folder:
 *
 *   model_variables.h  generated from the model's variables at build time: value references
 *                      (VR_<name>), start values, names and kinds of all Real variables.
 *                      States have the value references 0..N_STATES-1 and their derivatives
 *                      N_STATES..2*N_STATES-1, so the state vector is r[0..N_STATES).
 *   model.h            the type ModelData: model-private memory (derived constants, indices
 *                      into the growable storage, ...). It is part of the FMU state snapshot.
 *   model.c            the five functions declared below (and, optionally, the hooks).
 *
 * See fmus/common/README.md for the full contract.
 */
#ifndef SYSID_FMU_MODEL_H
#define SYSID_FMU_MODEL_H

#include <stddef.h>

#include "model_variables.h"
#include "model.h"

/* Status of a model function; the values equal fmi2Status and fmi3Status (OK .. Fatal). */
typedef enum {
    FMU_OK = 0,
    FMU_WARNING = 1,
    FMU_DISCARD = 2, /* the call could not complete; the caller may retry (smaller step) */
    FMU_ERROR = 3,
    FMU_FATAL = 4
} FmuStatus;

/* The interface an instance was created for. */
typedef enum { FMU_MODEL_EXCHANGE = 0, FMU_CO_SIMULATION = 1 } FmuInterface;

/* Kinds of variables in the generated tables (MODEL_VAR_KIND). */
enum {
    KIND_PARAMETER = 0,  /* causality parameter, variability fixed: settable before initialisation */
    KIND_INPUT = 1,      /* causality input, continuous: settable at any time */
    KIND_STATE = 2,      /* continuous state, start value settable before initialisation */
    KIND_DERIVATIVE = 3, /* der(state), calculated */
    KIND_OUTPUT = 4      /* calculated output */
};

/* Phases of the state machine (bit flags so that permissions are cheap masks); FMI 3.0's
 * Step Mode is PHASE_STEP_COMPLETE. */
typedef enum {
    PHASE_INSTANTIATED = 1 << 0,
    PHASE_INITIALIZATION = 1 << 1,
    PHASE_EVENT = 1 << 2,           /* model exchange */
    PHASE_CONTINUOUS_TIME = 1 << 3, /* model exchange */
    PHASE_STEP_COMPLETE = 1 << 4,   /* co-simulation */
    PHASE_TERMINATED = 1 << 5,
    PHASE_ERROR = 1 << 6
} ModelPhase;

/* Everything an FMU-state snapshot must restore besides the growable storage: plain data. */
typedef struct {
    double time;
    double r[N_REALS]; /* all Real variables, indexed by value reference */
    ModelData data;    /* model-private memory */
    int phase;
    int dirty;         /* outputs must be recomputed before the next value access */
    int derived_valid; /* data holds constants derived from the current parameters */
    size_t store_used; /* doubles of the growable storage in use (saved with the snapshot) */
} ModelSnapshot;

typedef struct {
    ModelSnapshot s;
    FmuInterface interface;
    char *instanceName;
    /* the environment's logger and its context, as the FMI version passes them (cast by
     * fmi2_functions.c / fmi3_functions.c in fmu_log) */
    void (*logger)(void);
    void *environment;
    int loggingOn;
    double startTime;
    double stopTime;
    int stopTimeDefined;
    /* Growable storage of doubles for the model (e.g. an input history that grows with the
     * number of steps); s.store_used of them are saved in FMU-state snapshots. */
    double *store;
    size_t store_capacity;
} ModelInstance;

/* ---- services of the boilerplate, available to models ---- */

/* Log a message through the environment's logger (category "logError", "logWarning", ...).
 * Messages of status FMU_DISCARD or worse are always logged, others only with logging on.
 * Defined by the FMI-version file (fmi2_functions.c or fmi3_functions.c). */
void fmu_log(const ModelInstance *comp, FmuStatus status, const char *category,
             const char *format, ...);

/* Advance the states r[0..N_STATES) from comp->s.time by h with classical 4th-order
 * Runge-Kutta sub-steps of at most h_max; the last sub-step is shortened so that the step
 * lands exactly on comp->s.time + h. Inputs are held constant over the step. Returns
 * FMU_DISCARD (time = the last good sub-step) if a state becomes non-finite. */
FmuStatus fmu_integrate_rk4(ModelInstance *comp, double h, double h_max);

/* Make the growable storage hold at least n doubles (contents kept); returns 0 (after
 * logging) when memory runs out. comp->store may move: keep indices, not pointers. */
int fmu_store_reserve(ModelInstance *comp, size_t n);

/* ---- functions every model implements ---- */

/* Validate parameters, fill comp->s.data with derived constants. Return FMU_ERROR after
 * logging a message naming the offending parameter. */
FmuStatus model_initialize(ModelInstance *comp);

/* State derivatives dx for the states x at time t, with the inputs and parameters in
 * comp->s.r. Must not modify comp (it is called with trial states by the integrator). */
void model_derivatives(const ModelInstance *comp, double t, const double *x, double *dx);

/* Recompute all calculated variables (outputs and derivatives) in comp->s.r. */
void model_calculate_values(ModelInstance *comp);

/* Co-simulation step: advance from comp->s.time to comp->s.time + h (h > 0) and update
 * comp->s.time. */
FmuStatus model_do_step(ModelInstance *comp, double h);

/* Called on reset after the start values have been restored and the storage emptied. */
void model_reset(ModelInstance *comp);

/* ---- optional event hooks (model.h defines MODEL_HAS_EVENT_HOOKS) ----
 * Without them fmu_core.c supplies no-op defaults. */

/* After input values were stored while the FMU runs, and once when initialisation ends. */
FmuStatus model_inputs_set(ModelInstance *comp);

/* At a completed integrator step: nonzero asks the environment for a step event. */
int model_step_event(const ModelInstance *comp);

/* When the environment handles an event (it restarts its integrator). */
void model_event_update(ModelInstance *comp);

/* ---- optional directional derivatives (model.h defines MODEL_HAS_DIRECTIONAL_DERIVATIVE) ----
 * seed[N_REALS]: a direction in the states and inputs (zero elsewhere), indexed by value
 * reference; fill sensitivity[vr] for every derivative and output with the exact partial
 * derivative of its value at the current point along seed. Without the hook the FMU
 * declares providesDirectionalDerivative(s)="false". */
FmuStatus model_directional_derivative(const ModelInstance *comp, const double *seed,
                                       double *sensitivity);

/* ---- shared implementation in fmu_core.c used by both FMI-version files ---- */

#define ALL_ALIVE (PHASE_INSTANTIATED | PHASE_INITIALIZATION | PHASE_EVENT | \
                   PHASE_CONTINUOUS_TIME | PHASE_STEP_COMPLETE | PHASE_TERMINATED)
#define BEFORE_INIT (PHASE_INSTANTIATED | PHASE_INITIALIZATION)
#define RUNNING (PHASE_EVENT | PHASE_CONTINUOUS_TIME | PHASE_STEP_COMPLETE)

int fmu_invalid_phase(ModelInstance *comp, const char *function, int allowed);
int fmu_null_pointer(ModelInstance *comp, const char *function, const char *argument,
                     const void *p);
FmuStatus fmu_fail(ModelInstance *comp);
ModelInstance *fmu_new_instance(const char *instanceName, FmuInterface interface);
void fmu_free_instance(ModelInstance *comp);
void fmu_set_start_values(ModelInstance *comp);
FmuStatus fmu_ensure_derived(ModelInstance *comp);
FmuStatus fmu_exit_initialization(ModelInstance *comp);
FmuStatus fmu_reset(ModelInstance *comp);
FmuStatus fmu_get_reals(ModelInstance *comp, const char *function, const unsigned int vr[],
                        size_t nvr, double value[]);
FmuStatus fmu_set_reals(ModelInstance *comp, const char *function, const unsigned int vr[],
                        size_t nvr, const double value[]);
FmuStatus fmu_directional(ModelInstance *comp, const char *function,
                          const unsigned int unknowns[], size_t nUnknown,
                          const unsigned int knowns[], size_t nKnown, const double seed[],
                          double sensitivity[]);
FmuStatus fmu_do_step(ModelInstance *comp, const char *function, double t, double h);
FmuStatus fmu_check_state_count(ModelInstance *comp, const char *function, size_t n);
/* FMU states: an opaque heap object holding a snapshot and a copy of the storage */
FmuStatus fmu_get_state(ModelInstance *comp, const char *function, void **state);
FmuStatus fmu_set_state(ModelInstance *comp, const char *function, const void *state);
void fmu_free_state(void **state);
size_t fmu_serialized_size(const void *state);
FmuStatus fmu_serialize_state(ModelInstance *comp, const void *state, unsigned char *out,
                              size_t size);
FmuStatus fmu_deserialize_state(ModelInstance *comp, const unsigned char *in, size_t size,
                                void **state);

#endif
