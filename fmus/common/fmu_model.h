/*
 * Interface between the shared FMI 2.0 boilerplate (fmi2_functions.c) and one model.
 *
 * The boilerplate owns the FMI state machine, argument checking, logging, value access,
 * FMU-state snapshots and the fixed-step RK4 integrator. A model provides, in its own folder:
 *
 *   model_variables.h  generated from the model's variables.csv at build time: value
 *                      references (VR_<name>), start values, names and kinds of all Real
 *                      variables. States have the value references 0..N_STATES-1 and their
 *                      derivatives N_STATES..2*N_STATES-1, so the state vector is r[0..N_STATES).
 *   model.h            the type ModelData: model-private memory (derived constants, delay
 *                      buffers, ...). It is part of the FMU state snapshot.
 *   model.c            the five functions declared below (and, optionally, the event hooks).
 *
 * See fmus/common/README.md for the full contract.
 */
#ifndef SYSID_FMU_MODEL_H
#define SYSID_FMU_MODEL_H

#include <stddef.h>

#include "fmi2Functions.h"
#include "model_variables.h"
#include "model.h"

/* Kinds of variables in the generated tables (MODEL_VAR_KIND). */
enum {
    KIND_PARAMETER = 0,  /* causality parameter, variability fixed: settable before initialisation */
    KIND_INPUT = 1,      /* causality input, continuous: settable at any time */
    KIND_STATE = 2,      /* continuous state (reported as output), start value settable before init */
    KIND_DERIVATIVE = 3, /* der(state), calculated */
    KIND_OUTPUT = 4      /* calculated output */
};

/* Phases of the FMI 2.0 state machine (bit flags so that permissions are cheap masks). */
typedef enum {
    PHASE_INSTANTIATED = 1 << 0,
    PHASE_INITIALIZATION = 1 << 1,
    PHASE_EVENT = 1 << 2,           /* model exchange */
    PHASE_CONTINUOUS_TIME = 1 << 3, /* model exchange */
    PHASE_STEP_COMPLETE = 1 << 4,   /* co-simulation */
    PHASE_TERMINATED = 1 << 5,
    PHASE_ERROR = 1 << 6
} ModelPhase;

/* Everything an FMU-state snapshot must restore: plain data, copied with one assignment. */
typedef struct {
    double time;
    double r[N_REALS]; /* all Real variables, indexed by value reference */
    ModelData data;    /* model-private memory */
    int phase;
    int dirty;         /* outputs must be recomputed before the next fmi2GetReal */
    int derived_valid; /* data holds constants derived from the current parameters */
} ModelSnapshot;

typedef struct {
    ModelSnapshot s;
    fmi2Type type;
    char *instanceName;
    fmi2CallbackFunctions callbacks;
    int loggingOn;
    double startTime;
    double stopTime;
    int stopTimeDefined;
} ModelInstance;

/* ---- services of the boilerplate, available to models ---- */

/* Log a message through the environment's logger (category "logError", "logWarning", ...).
 * Messages of status fmi2Error/fmi2Fatal are always logged, others only with logging on. */
void fmu_log(const ModelInstance *comp, fmi2Status status, const char *category,
             const char *format, ...);

/* Advance the states r[0..N_STATES) from comp->s.time by h with classical 4th-order
 * Runge-Kutta sub-steps of at most h_max; the last sub-step is shortened so that the step
 * lands exactly on comp->s.time + h. Inputs are held constant over the step. Returns
 * fmi2Error (with a logged message) if a state becomes non-finite. */
fmi2Status fmu_integrate_rk4(ModelInstance *comp, double h, double h_max);

/* ---- functions every model implements ---- */

/* Called by fmi2ExitInitializationMode: validate parameters, fill comp->s.data with derived
 * constants. Return fmi2Error after logging a message naming the offending parameter. */
fmi2Status model_initialize(ModelInstance *comp);

/* State derivatives dx for the states x at time t, with the inputs and parameters in
 * comp->s.r. Must not modify comp (it is called with trial states by the integrator). */
void model_derivatives(const ModelInstance *comp, double t, const double *x, double *dx);

/* Recompute all calculated variables (outputs and derivatives) in comp->s.r from the
 * current states, inputs and parameters. */
void model_calculate_values(ModelInstance *comp);

/* Co-simulation step hook: advance from comp->s.time to comp->s.time + h (h > 0) and update
 * comp->s.time. The helicopter calls fmu_integrate_rk4; an exported linear model can
 * implement an exact zero-order-hold update with delay buffers in comp->s.data instead. */
fmi2Status model_do_step(ModelInstance *comp, double h);

/* Called by fmi2Reset after the start values have been restored, so that the model can
 * clear comp->s.data (e.g. delay buffers). */
void model_reset(ModelInstance *comp);

/* ---- optional event hooks ----
 * A model whose model.h defines MODEL_HAS_EVENT_HOOKS implements the three functions below;
 * for any other model (the helicopter) fmi2_functions.c supplies no-op defaults, so existing
 * models build and behave unchanged. They let a model keep a history of its inputs in model
 * exchange (e.g. exact input delays) and tell the integrator when that history makes the
 * derivatives jump. */

/* Called by fmi2SetReal after input values were stored while the FMU runs (event,
 * continuous-time or step-complete mode), and once by fmi2ExitInitializationMode (after
 * model_initialize) so that the model sees the inputs in effect at the start time. May update
 * comp->s.data; return fmi2Error after logging a message to refuse the call. */
fmi2Status model_inputs_set(ModelInstance *comp);

/* Called by fmi2CompletedIntegratorStep: nonzero asks the environment to enter event mode
 * (step event), e.g. because the derivatives jumped at the current time. */
int model_step_event(const ModelInstance *comp);

/* Called by fmi2NewDiscreteStates in event mode: the environment handles the event now (it
 * will restart its integrator), so pending step events can be cleared. */
void model_event_update(ModelInstance *comp);

#endif
