/*
 * Signal playback: outputs that follow sampled signals with a zero-order hold, so that an
 * importer can feed the same input to several FMUs (the SSP study of sysid export-ssp).
 * Plugged into the shared boilerplate of fmus/common; co-simulation only (model.h).
 *
 *   y(t) = TABLE[k], k = floor((t - T0) / DT), clamped to the first and last sample
 *
 * The table, T0 and DT are in the generated header signal_table.h (sysid.fmi.signal).
 */
#include <math.h>

#include "fmu_model.h"
#include "signal_table.h"

FmuStatus model_initialize(ModelInstance *comp) {
    (void)comp;
    return FMU_OK;
}

void model_derivatives(const ModelInstance *comp, double t, const double *x, double *dx) {
    (void)comp;
    (void)t;
    (void)x;
    (void)dx; /* no states */
}

void model_calculate_values(ModelInstance *comp) {
    /* the tolerance keeps a communication point accumulated in floating point (t0 + k h
     * summed step by step) on its own sample */
    double k = floor((comp->s.time - SIGNAL_T0) / SIGNAL_DT + 1e-6);
    long i = k < 0.0 ? 0 : (k >= SIGNAL_N ? SIGNAL_N - 1 : (long)k);
    int j;
    for (j = 0; j < N_REALS; j++) comp->s.r[j] = SIGNAL_TABLE[i][j];
}

FmuStatus model_do_step(ModelInstance *comp, double h) {
    comp->s.time += h;
    return FMU_OK;
}

void model_reset(ModelInstance *comp) { (void)comp; }
