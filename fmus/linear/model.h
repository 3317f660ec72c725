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

/* C has no zero-length arrays: a model without delays still gets one (unused) slot. */
#define N_GROUPS_ALLOC (N_GROUPS > 0 ? N_GROUPS : 1)
#define PADE_ALLOC (PADE_ORDER > 0 ? PADE_ORDER : 1)

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

    /* Ring buffer of the inputs at past input updates: in co-simulation one sample per
     * communication point (fmi2DoStep), in model exchange with ME_DELAY_BUFFER one per
     * fmi2SetReal of the inputs at a new time (an update at the same time overwrites). An
     * instance is either one or the other, so both use the same arrays. */
    double hist_t[HIST_LEN];
    double hist_u[HIST_LEN][N_U];
    int hist_head;    /* index of the newest sample */
    int hist_count;   /* number of valid samples */
    int hist_dropped; /* 1 once the oldest sample has been overwritten */

    /* Model exchange with ME_DELAY_BUFFER: the delayed input (absolute) each group holds from
     * the time of a sample until the next update, u(t_k - tau) interpolated in the history
     * when sample k was recorded; and whether a recorded update changed a delayed input since
     * the last event (the derivatives jumped: fmi2CompletedIntegratorStep asks for an event
     * so that the integrator restarts there). */
    double hist_v[HIST_LEN][N_GROUPS_ALLOC];
    int event_pending;
} ModelData;

#endif
