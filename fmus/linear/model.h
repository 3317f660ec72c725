/*
 * Model-private data of an exported linear model (see README.md in this folder).
 *
 * The sizes come from the generated header linear_dims.h. Everything the co-simulation step
 * needs to continue exactly where it left off - the assembled matrices, the cached
 * zero-order-hold discretisation and the input history of the delay buffers - lives here,
 * so that an FMU-state snapshot (a plain copy of ModelData) restores it completely.
 */
#ifndef LINEAR_MODEL_H
#define LINEAR_MODEL_H

#include "linear_dims.h"

/* This model implements the optional event hooks of fmu_model.h (model_inputs_set,
 * model_step_event, model_event_update): model exchange keeps an input history for exact
 * delays when exported with ME_DELAY_BUFFER = 1. */
#define MODEL_HAS_EVENT_HOOKS 1

/* Exact directional derivatives from A, B, C, D (fmus/linear/README.md). */
#define MODEL_HAS_DIRECTIONAL_DERIVATIVE 1

/* C has no zero-length arrays: a model without delays still gets one (unused) slot. */
#define N_GROUPS_ALLOC (N_GROUPS > 0 ? N_GROUPS : 1)
#define PADE_ALLOC (PADE_ORDER > 0 ? PADE_ORDER : 1)
/* doubles per history record: time, inputs, delayed input of each group */
#define HIST_WIDTH (1 + N_U + N_GROUPS_ALLOC)

typedef struct {
    /* State-space matrices in the FMU's units (SI states, % inputs, SI outputs), assembled
     * from the fixed parts and the parameters by model_initialize. */
    double A[N_X][N_X];
    double B[N_X][N_U];
    double C[N_Y][N_X];
    double D[N_Y][N_U];
    double tau[N_GROUPS_ALLOC];  /* delay of each delay group, s */
    double trim_u[N_U];          /* absolute trim inputs, % */
    double trim_y[N_Y];          /* absolute trim outputs, SI */

    /* Model exchange: normalised Pade realisation of exp(-p), p = s tau, shared by all
     * groups (controllable canonical form, states scaled so that z_1 = u at steady state). */
    double pade_a[PADE_ALLOC];   /* monic denominator coefficients a_0 .. a_{n-1} */
    double pade_b;               /* input gain of the last state */
    double pade_c[PADE_ALLOC];   /* output row */
    double pade_d;               /* feed-through, (-1)^n */

    /* Co-simulation: exact zero-order hold for the step h_zoh:
     * Phi = exp(A h), Psi = int_0^h exp(A s) ds (so that Gamma = Psi B). */
    double h_zoh;
    int zoh_valid;
    double Phi[N_X][N_X];
    double Psi[N_X][N_X];

    /* Input history, a time-stamped list that grows with the number of updates and is
     * pruned of samples no delay can reach any more: in co-simulation one sample per
     * communication point (fmi2DoStep / fmi3DoStep), in model exchange with
     * ME_DELAY_BUFFER one per input update at a new time (an update at the same time
     * overwrites). It lives in the boilerplate's growable storage (comp->store, saved with
     * FMU states); sample i of the list is the record of HIST_WIDTH doubles at
     * comp->store[(hist_first + i) * HIST_WIDTH]: time, the N_U absolute inputs and, in
     * model exchange, the delayed input each group holds from that sample on. */
    long hist_first;     /* record index of the oldest kept sample */
    long hist_count;     /* number of kept samples */
    int hist_pruned;     /* 1 once samples have been dropped from the front */
    double hist_horizon; /* how far back any lookup may reach: 2 x the largest delay, s */

    /* Model exchange with ME_DELAY_BUFFER: a recorded update changed a delayed input since
     * the last event (the derivatives jumped: the completed integrator step asks for an
     * event so that the integrator restarts there). */
    int event_pending;
} ModelData;

#endif
