/*
 * A linear state-space model with per-entry input delays, plugged into the shared FMI 2.0 /
 * FMI 3.0 boilerplate of fmus/common (fmu_model.h). Generic: every number that belongs to one
 * exported model is in the generated headers linear_dims.h, linear_tables.h and
 * model_variables.h (written by sysid.fmi.export).
 *
 *   x' = A x + sum_k B_ik u_k(t - tau_ik),   y = trim_y + C x + D (u - trim_u)
 *
 * Co-simulation: the states are advanced by the exact zero-order-hold discretisation of the
 * communication step (matrix exponential by Pade scaling and squaring, recomputed when the
 * step changes) and each delay group (one delay acting on some B entries of one input) reads
 * a time-stamped history of past inputs (growing as needed, pruned of samples no delay can
 * reach), linearly interpolated between communication points: the convention of
 * sysid.models.simulate. Model exchange, ME_DELAY_BUFFER = 1 (default): the same history,
 * filled at every input update (fmi2SetReal / fmi3SetFloat64), gives each group a delayed
 * input held from one update to the next - the same convention, so CVode reproduces
 * simulate to its tolerance; an update that changes a delayed input raises a step event.
 * ME_DELAY_BUFFER = 0: each group is an n-th order Pade approximant with its own continuous
 * states. See README.md.
 */
#include <math.h>
#include <stdlib.h>
#include <string.h>

#include "fmu_model.h"
#include "linear_tables.h"

/* The generated tables and the boilerplate must agree on the state vector. */
typedef char state_count_check[(N_STATES == N_X + N_GROUPS * PADE_ORDER) ? 1 : -1];

#define R(comp, vr) ((comp)->s.r[(vr)])

/* ------------------------------------------------------------------------------------------ */
/* initialisation                                                                               */

/* Coefficients of the normalised [n/n] Pade approximant of exp(-p):
 * num(p) = sum (-1)^k c_k p^k, den(p) = sum c_k p^k, c_k = (2n-k)! n! / ((2n)! k! (n-k)!). */
static void pade_realisation(ModelData *d) {
    double c[PADE_ALLOC + 1];
    int n = PADE_ORDER, k;
    if (n <= 0) return;
    c[0] = 1.0;
    for (k = 1; k <= n; k++) c[k] = c[k - 1] * (double)(n - k + 1) / ((double)k * (2 * n - k + 1));
    d->pade_d = (n % 2 == 0) ? 1.0 : -1.0;
    for (k = 0; k < n; k++) {
        double sign_k = (k % 2 == 0) ? 1.0 : -1.0;
        d->pade_a[k] = c[k] / c[n];
        /* remainder num/c_n - d den/c_n, coefficient of p^k */
        d->pade_c[k] = (sign_k - d->pade_d) * c[k] / c[n];
    }
    /* Similarity scaling by a_0: the first state then equals the input at steady state,
     * so that all Pade states are of the size of the input (good for error control). */
    d->pade_b = d->pade_a[0];
    for (k = 0; k < n; k++) d->pade_c[k] /= d->pade_a[0];
}

FmuStatus model_initialize(ModelInstance *comp) {
    ModelData *d = &comp->s.data;
    double A[N_X][N_X], B[N_X][N_U], C[N_Y][N_X], D[N_Y][N_U];
    int i, j, k, g;

    memcpy(A, A0, sizeof A);
    memcpy(B, B0, sizeof B);
    memcpy(C, C0, sizeof C);
    memcpy(D, D0, sizeof D);
    for (g = 0; g < N_GROUPS; g++) d->tau[g] = 0.0;

    /* Fixed parts plus the parameters, in the model's analysis units. */
    for (k = 0; k < N_PAR; k++) {
        double value = R(comp, VR_PAR0 + k);
        int row = PAR_ROW[k], col = PAR_COL[k];
        if (!isfinite(value)) {
            fmu_log(comp, FMU_ERROR, "logError", "parameter %s is not finite", PAR_NAMES[k]);
            return FMU_ERROR;
        }
        switch (PAR_MATRIX[k]) {
        case MATRIX_A: A[row][col] += value; break;
        case MATRIX_B: B[row][col] += value; break;
        case MATRIX_C: C[row][col] += value; break;
        case MATRIX_D: D[row][col] += value; break;
        default: /* MATRIX_DELAY: row is the delay group */
            if (value < 0.0) {
                fmu_log(comp, FMU_ERROR, "logError",
                        "delay parameter %s must be >= 0 s, got %g", PAR_NAMES[k], value);
                return FMU_ERROR;
            }
            d->tau[row] = value;
        }
    }
    for (k = 0; k < N_TIE; k++) { /* the further entries of tied parameters */
        double value = TIE_SCALE[k] * R(comp, VR_PAR0 + TIE_PAR[k]);
        int row = TIE_ROW[k], col = TIE_COL[k];
        switch (TIE_MATRIX[k]) {
        case MATRIX_A: A[row][col] += value; break;
        case MATRIX_B: B[row][col] += value; break;
        case MATRIX_C: C[row][col] += value; break;
        default: D[row][col] += value; break;
        }
    }

    /* Change of units to the FMU's: x_fmu = X_SCALE x, y_fmu = Y_SCALE y (inputs stay %). */
    for (i = 0; i < N_X; i++) {
        for (j = 0; j < N_X; j++) d->A[i][j] = X_SCALE[i] * A[i][j] / X_SCALE[j];
        for (k = 0; k < N_U; k++) d->B[i][k] = X_SCALE[i] * B[i][k];
    }
    for (i = 0; i < N_Y; i++) {
        for (j = 0; j < N_X; j++) d->C[i][j] = Y_SCALE[i] * C[i][j] / X_SCALE[j];
        for (k = 0; k < N_U; k++) d->D[i][k] = Y_SCALE[i] * D[i][k];
    }
    for (k = 0; k < N_U; k++) d->trim_u[k] = R(comp, VR_TRIM_U0 + k);
    for (i = 0; i < N_Y; i++) d->trim_y[i] = R(comp, VR_TRIM_Y0 + i);
    pade_realisation(d);
    /* lookups reach back at most the largest delay; keep twice that (an environment may
     * step back a little in model exchange) */
    d->hist_horizon = 0.0;
    for (g = 0; g < N_GROUPS; g++)
        if (2.0 * d->tau[g] > d->hist_horizon) d->hist_horizon = 2.0 * d->tau[g];
    d->zoh_valid = 0; /* the matrices may have changed */
    return FMU_OK;
}

void model_reset(ModelInstance *comp) {
    /* The boilerplate has zeroed ModelData and emptied the storage: empty history, no
     * cached discretisation. */
    comp->s.data.zoh_valid = 0;
    comp->s.data.hist_first = 0;
    comp->s.data.hist_count = 0;
    comp->s.data.hist_pruned = 0;
    comp->s.data.event_pending = 0;
}

/* ------------------------------------------------------------------------------------------ */
/* continuous-time equations                                                                    */

/* dx = A x + B~ u: entries of B in a delay group take that group's delayed input v[g]. */
static void state_derivative(const ModelData *d, const double *x, const double *u,
                             const double *v, double *dx) {
    int i, j, k;
    for (i = 0; i < N_X; i++) {
        double sum = 0.0;
        for (j = 0; j < N_X; j++) sum += d->A[i][j] * x[j];
        for (k = 0; k < N_U; k++) {
            int g = ENTRY_GROUP[i * N_U + k];
            sum += d->B[i][k] * (g < 0 ? u[k] : v[g]);
        }
        dx[i] = sum;
    }
}

static void perturbation_inputs(const ModelInstance *comp, double *u) {
    int k;
    for (k = 0; k < N_U; k++) u[k] = R(comp, VR_U0 + k) - comp->s.data.trim_u[k];
}

/* ------------------------------------------------------------------------------------------ */
/* input history (co-simulation, and model exchange with ME_DELAY_BUFFER)                      */

/* Record i of the kept samples (0 = oldest): time, N_U absolute inputs, N_GROUPS held
 * delayed inputs (model exchange). */
static double *hist_record(const ModelInstance *comp, long i) {
    return comp->store + (size_t)(comp->s.data.hist_first + i) * HIST_WIDTH;
}

static void hist_used(ModelInstance *comp) {
    comp->s.store_used = (size_t)(comp->s.data.hist_first + comp->s.data.hist_count) * HIST_WIDTH;
}

/* Make room for one more record: drop the samples no lookup can reach any more (sample i
 * goes when sample i + 1 is already at or before t_new - hist_horizon), move the rest to the
 * front, and grow the storage so that at least half of it stays free (amortised O(1) per
 * sample, however small the steps). Returns 0 when memory runs out. */
static int history_make_room(ModelInstance *comp, double t_new) {
    ModelData *d = &comp->s.data;
    const double limit = t_new - d->hist_horizon;
    long drop = 0;
    while (drop + 1 < d->hist_count && hist_record(comp, drop + 1)[0] <= limit) drop++;
    if (drop > 0) d->hist_pruned = 1;
    d->hist_first += drop;
    d->hist_count -= drop;
    if (d->hist_first > 0) {
        memmove(comp->store, hist_record(comp, 0),
                (size_t)d->hist_count * HIST_WIDTH * sizeof(double));
        d->hist_first = 0;
    }
    hist_used(comp);
    return fmu_store_reserve(comp, 2 * (size_t)(d->hist_count + 1) * HIST_WIDTH);
}

/* Append the inputs at time t; a repeated time overwrites the newest sample. */
static int history_append(ModelInstance *comp, double t, const double *u_abs) {
    ModelData *d = &comp->s.data;
    double *rec;
    int k;
    if (d->hist_count > 0) {
        rec = hist_record(comp, d->hist_count - 1);
        if (rec[0] >= t) {
            for (k = 0; k < N_U; k++) rec[1 + k] = u_abs[k];
            return 1;
        }
    }
    if ((size_t)(d->hist_first + d->hist_count + 1) * HIST_WIDTH > comp->store_capacity &&
        !history_make_room(comp, t))
        return 0;
    rec = hist_record(comp, d->hist_count);
    rec[0] = t;
    for (k = 0; k < N_U; k++) rec[1 + k] = u_abs[k];
    for (k = 0; k < N_GROUPS_ALLOC; k++) rec[1 + N_U + k] = 0.0;
    d->hist_count++;
    hist_used(comp);
    return 1;
}

/* Newest kept sample at or before t (the oldest if t precedes them all), -1 if none. */
static long hist_sample_at(const ModelInstance *comp, double t) {
    long lo = 0, hi = comp->s.data.hist_count - 1;
    if (hi < 0) return -1;
    while (lo < hi) {
        long mid = (lo + hi + 1) / 2;
        if (hist_record(comp, mid)[0] <= t) lo = mid;
        else hi = mid - 1;
    }
    return lo;
}

/* Input k (absolute) at time s <= newest sample, linearly interpolated between the kept
 * samples; before the first sample it is held at the first sample. Returns 0 if s lies
 * before the oldest kept sample and older ones were dropped (the history cannot answer). */
static int history_value(const ModelInstance *comp, int k, double s, double *value) {
    long i = hist_sample_at(comp, s);
    const double *a, *b;
    double w;
    if (i < 0) return 0;
    a = hist_record(comp, i);
    if (a[0] > s) { /* before every kept sample */
        if (comp->s.data.hist_pruned) return 0;
        *value = a[1 + k];
        return 1;
    }
    if (i == comp->s.data.hist_count - 1) {
        *value = a[1 + k];
        return 1;
    }
    b = hist_record(comp, i + 1);
    /* u0 + w (u1 - u0) returns u0 exactly between equal samples, so a held input gives a
     * delayed input that does not change in the last bit (model exchange raises an event
     * whenever a delayed input changes) */
    w = (s - a[0]) / (b[0] - a[0]);
    *value = a[1 + k] + w * (b[1 + k] - a[1 + k]);
    return 1;
}

static void history_refused(const ModelInstance *comp, int g, double t) {
    fmu_log(comp, FMU_ERROR, "logError",
            "delay %s = %g s at t = %g s needs the input at t = %g s, before the oldest "
            "input sample kept (t = %g s): the environment went back in time by more than "
            "the largest delay without restoring an FMU state",
            PAR_NAMES[GROUP_PAR[g]], comp->s.data.tau[g], t, t - comp->s.data.tau[g],
            hist_record(comp, 0)[0]);
}

/* Delayed inputs (perturbations) of all groups at time t from the history. */
static FmuStatus delayed_inputs(const ModelInstance *comp, double t, double *v) {
    const ModelData *d = &comp->s.data;
    int g;
    for (g = 0; g < N_GROUPS; g++) {
        int k = GROUP_INPUT[g];
        double value;
        if (d->hist_count == 0) {
            value = R(comp, VR_U0 + k);
        } else if (!history_value(comp, k, t - d->tau[g], &value)) {
            history_refused(comp, g, t);
            return FMU_ERROR;
        }
        v[g] = value - d->trim_u[k];
    }
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* model exchange                                                                               */

#if ME_DELAY_BUFFER
/* Record the inputs at the current time and the delayed input each group holds from now on.
 *
 * Convention (that of sysid.models.simulate and of model_do_step): the environment sets the
 * inputs at its sample instants t_k and they are held until the next update; a group with
 * delay tau then sees, on [t_k, t_k+1), the recorded samples linearly interpolated at
 * t_k - tau (before the first sample: the first sample). Every update at a new time is a
 * sample, also when the values did not change, because the interpolation is between
 * neighbouring samples; an update at the time of the newest sample replaces it (the value
 * after an input event at t_k wins over the left limit set just before), and an update at an
 * earlier time (the environment went back without restoring an FMU state) drops the samples
 * after it. */
static FmuStatus me_record_inputs(ModelInstance *comp) {
    ModelData *d = &comp->s.data;
    const double t = comp->s.time;
    double u_abs[N_U], before[N_GROUPS_ALLOC], held[N_GROUPS_ALLOC];
    double *rec;
    int g, k, had_before;

    while (d->hist_count > 0 && hist_record(comp, d->hist_count - 1)[0] > t) d->hist_count--;
    hist_used(comp);
    had_before = d->hist_count > 0;
    for (g = 0; g < N_GROUPS; g++)
        before[g] = had_before ? hist_record(comp, d->hist_count - 1)[1 + N_U + g] : 0.0;
    for (k = 0; k < N_U; k++) u_abs[k] = R(comp, VR_U0 + k);
    if (!history_append(comp, t, u_abs)) return FMU_ERROR;
    for (g = 0; g < N_GROUPS; g++) {
        double value = u_abs[GROUP_INPUT[g]];
        if (d->tau[g] > 0.0 && !history_value(comp, GROUP_INPUT[g], t - d->tau[g], &value)) {
            history_refused(comp, g, t);
            return FMU_ERROR;
        }
        held[g] = value;
        /* An undelayed group reads the live input like an undelayed entry; a delayed one
         * makes the derivatives jump here if its held value changed. */
        if (d->tau[g] > 0.0 && had_before && value != before[g]) d->event_pending = 1;
    }
    rec = hist_record(comp, d->hist_count - 1);
    for (g = 0; g < N_GROUPS; g++) rec[1 + N_U + g] = held[g];
    return FMU_OK;
}
#endif

FmuStatus model_inputs_set(ModelInstance *comp) {
#if ME_DELAY_BUFFER
    if (comp->interface == FMU_MODEL_EXCHANGE && N_GROUPS > 0) return me_record_inputs(comp);
#else
    (void)comp;
#endif
    return FMU_OK; /* co-simulation samples the inputs in model_do_step */
}

int model_step_event(const ModelInstance *comp) { return comp->s.data.event_pending; }

void model_event_update(ModelInstance *comp) { comp->s.data.event_pending = 0; }

/* dx = A x + B~ u with perturbation inputs u. The delayed inputs are the held values of the
 * input history (model exchange with ME_DELAY_BUFFER), the interpolated history
 * (co-simulation) or the outputs of the Pade states (ME_DELAY_BUFFER = 0). With
 * `homogeneous` the function is the linear part only, the map (x, u) -> dx whose values are
 * the directional derivatives: a delayed input depends on past inputs only, so a delayed B
 * entry contributes nothing (the Pade states are states, so there it is their rows). */
static void linear_rhs(const ModelInstance *comp, double t, const double *x, const double *u,
                       int homogeneous, double *dx) {
    const ModelData *d = &comp->s.data;
    double v[N_GROUPS_ALLOC] = {0.0}; /* zeroed: a model without delays reads none */
    int g, i;
    if (comp->interface == FMU_CO_SIMULATION || ME_DELAY_BUFFER) {
        long idx = (!homogeneous && comp->interface == FMU_MODEL_EXCHANGE && N_GROUPS > 0)
            ? hist_sample_at(comp, t) : -1;
        for (g = 0; g < N_GROUPS; g++) {
            int k = GROUP_INPUT[g];
            double value;
            if (d->tau[g] <= 0.0) {
                v[g] = u[k];
            } else if (homogeneous) {
                v[g] = 0.0;
            } else if (comp->interface == FMU_MODEL_EXCHANGE) {
                /* before the first update (e.g. in initialisation mode) there is no history */
                v[g] = idx >= 0 ? hist_record(comp, idx)[1 + N_U + g] - d->trim_u[k] : u[k];
            } else {
                v[g] = (d->hist_count > 0 && history_value(comp, k, t - d->tau[g], &value))
                    ? value - d->trim_u[k] : u[k];
            }
        }
        for (i = N_X; i < N_STATES; i++) dx[i] = 0.0; /* Pade states unused */
    } else {
        for (g = 0; g < N_GROUPS; g++) {
            const double *z = x + N_X + g * PADE_ORDER;
            double *dz = dx + N_X + g * PADE_ORDER;
            double ug = u[GROUP_INPUT[g]];
            if (d->tau[g] > 0.0) {
                /* dz/dt = (Ac z + b e_n u) / tau, v = c z + d u (time scaled by tau) */
                double rate = 1.0 / d->tau[g], last = d->pade_b * ug, out = d->pade_d * ug;
                for (i = 0; i < PADE_ORDER; i++) {
                    last -= d->pade_a[i] * z[i];
                    out += d->pade_c[i] * z[i];
                    if (i + 1 < PADE_ORDER) dz[i] = rate * z[i + 1];
                }
                dz[PADE_ORDER - 1] = rate * last;
                v[g] = out;
            } else {
                /* no delay: the group passes its input, its states decay (they start at 0) */
                for (i = 0; i < PADE_ORDER; i++) dz[i] = -z[i];
                v[g] = ug;
            }
        }
    }
    state_derivative(d, x, u, v, dx);
}

void model_derivatives(const ModelInstance *comp, double t, const double *x, double *dx) {
    double u[N_U];
    perturbation_inputs(comp, u);
    linear_rhs(comp, t, x, u, 0, dx);
}

/* Exact directional derivatives: der(x) and y are affine in (x, u) for a given input
 * history, so the partial derivatives along the seed are the linear part evaluated at the
 * seed: A dx + B~ du (delayed entries excluded, see linear_rhs) and C dx + D du. */
FmuStatus model_directional_derivative(const ModelInstance *comp, const double *seed,
                                       double *sensitivity) {
    const ModelData *d = &comp->s.data;
    double dx[N_STATES_ALLOC], du[N_U], ddx[N_STATES_ALLOC];
    int i, j, k;
    for (i = 0; i < N_STATES; i++) dx[i] = seed[VR_STATE0 + i];
    for (k = 0; k < N_U; k++) du[k] = seed[VR_U0 + k];
    linear_rhs(comp, comp->s.time, dx, du, 1, ddx);
    for (i = 0; i < N_STATES; i++) sensitivity[VR_DERIV0 + i] = ddx[i];
    for (i = 0; i < N_Y; i++) {
        double y = 0.0;
        for (j = 0; j < N_X; j++) y += d->C[i][j] * dx[j];
        for (k = 0; k < N_U; k++) y += d->D[i][k] * du[k];
        sensitivity[VR_Y0 + i] = y;
    }
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* co-simulation: exact discretisation                                                          */

/* LU solve of M X = Y in place (M n x n, Y n x n, row-major), partial pivoting. */
static int solve_in_place(double *M, double *Y, int n) {
    int i, j, k, p;
    for (k = 0; k < n; k++) {
        double big = fabs(M[k * n + k]);
        p = k;
        for (i = k + 1; i < n; i++)
            if (fabs(M[i * n + k]) > big) { big = fabs(M[i * n + k]); p = i; }
        if (big == 0.0) return 0;
        if (p != k) {
            for (j = 0; j < n; j++) {
                double tmp = M[k * n + j]; M[k * n + j] = M[p * n + j]; M[p * n + j] = tmp;
                tmp = Y[k * n + j]; Y[k * n + j] = Y[p * n + j]; Y[p * n + j] = tmp;
            }
        }
        for (i = k + 1; i < n; i++) {
            double f = M[i * n + k] / M[k * n + k];
            if (f == 0.0) continue;
            for (j = k; j < n; j++) M[i * n + j] -= f * M[k * n + j];
            for (j = 0; j < n; j++) Y[i * n + j] -= f * Y[k * n + j];
        }
    }
    for (k = n - 1; k >= 0; k--) {
        for (j = 0; j < n; j++) {
            double sum = Y[k * n + j];
            for (i = k + 1; i < n; i++) sum -= M[k * n + i] * Y[i * n + j];
            Y[k * n + j] = sum / M[k * n + k];
        }
    }
    return 1;
}

static void matmul(const double *X, const double *Y, double *Z, int n) {
    int i, j, k;
    for (i = 0; i < n; i++)
        for (j = 0; j < n; j++) {
            double sum = 0.0;
            for (k = 0; k < n; k++) sum += X[i * n + k] * Y[k * n + j];
            Z[i * n + j] = sum;
        }
}

/* E = exp(M), n x n, by the [6/6] Pade approximant with scaling and squaring: M is scaled by
 * 2^-s so that its 1-norm is <= 1/2, where the [6/6] approximant's relative error bound is
 * about 3e-16 (Moler & Van Loan 2003), then squared s times. Returns 0 on failure. */
static int expm(const double *M, double *E, int n) {
    const int q = 6;
    size_t bytes = sizeof(double) * (size_t)n * (size_t)n;
    double *X = malloc(bytes), *P = malloc(bytes), *N = malloc(bytes), *Dn = malloc(bytes);
    double norm = 0.0, c = 1.0, scale;
    int i, j, k, s = 0, ok = 0;
    if (!X || !P || !N || !Dn) goto done;
    for (j = 0; j < n; j++) {
        double col = 0.0;
        for (i = 0; i < n; i++) col += fabs(M[i * n + j]);
        if (col > norm) norm = col;
    }
    if (!isfinite(norm)) goto done;
    if (norm > 0.5) s = (int)ceil(log2(norm / 0.5));
    scale = ldexp(1.0, -s);
    for (i = 0; i < n * n; i++) X[i] = M[i] * scale;
    /* N = sum c_k X^k, Dn = sum (-1)^k c_k X^k, P holds X^k */
    memset(N, 0, bytes);
    memset(Dn, 0, bytes);
    for (i = 0; i < n; i++) N[i * n + i] = Dn[i * n + i] = 1.0;
    memcpy(P, X, bytes);
    for (k = 1; k <= q; k++) {
        c *= (double)(q - k + 1) / ((double)k * (2 * q - k + 1));
        for (i = 0; i < n * n; i++) {
            N[i] += c * P[i];
            Dn[i] += ((k % 2) ? -c : c) * P[i];
        }
        if (k < q) {
            matmul(P, X, E, n);
            memcpy(P, E, bytes);
        }
    }
    if (!solve_in_place(Dn, N, n)) goto done; /* N <- Dn^-1 N */
    for (k = 0; k < s; k++) {
        matmul(N, N, E, n);
        memcpy(N, E, bytes);
    }
    memcpy(E, N, bytes);
    ok = 1;
done:
    free(X); free(P); free(N); free(Dn);
    return ok;
}

/* Phi = exp(A h) and Psi = int_0^h exp(A s) ds from one exponential of the block matrix
 * [[A h, I h], [0, 0]] (Van Loan): exp = [[Phi, Psi], [0, I]]. */
static FmuStatus discretise(ModelInstance *comp, double h) {
    ModelData *d = &comp->s.data;
    const int n = 2 * N_X;
    double *M = calloc((size_t)n * n, sizeof(double));
    double *E = calloc((size_t)n * n, sizeof(double));
    int i, j, ok = 0;
    if (M && E) {
        for (i = 0; i < N_X; i++) {
            for (j = 0; j < N_X; j++) M[i * n + j] = d->A[i][j] * h;
            M[i * n + N_X + i] = h;
        }
        ok = expm(M, E, n);
        if (ok) {
            for (i = 0; i < N_X; i++)
                for (j = 0; j < N_X; j++) {
                    d->Phi[i][j] = E[i * n + j];
                    d->Psi[i][j] = E[i * n + N_X + j];
                }
        }
    }
    free(M);
    free(E);
    if (!ok) {
        fmu_log(comp, FMU_ERROR, "logError",
                "matrix exponential for the step %g s failed (non-finite A?)", h);
        return FMU_ERROR;
    }
    d->h_zoh = h;
    d->zoh_valid = 1;
    return FMU_OK;
}

FmuStatus model_do_step(ModelInstance *comp, double h) {
    ModelData *d = &comp->s.data;
    double u_abs[N_U], u[N_U], v[N_GROUPS_ALLOC] = {0.0}, f[N_X], x_new[N_X];
    double *x = comp->s.r + VR_STATE0;
    int i, j, k;

    /* Reuse the discretisation for steps equal to rounding (a time grid t0 + k h gives
     * steps that differ in the last bits); the effect of such a difference is below 1e-13. */
    if (!d->zoh_valid || fabs(h - d->h_zoh) > 1e-13 * h) {
        if (discretise(comp, h) != FMU_OK) return FMU_ERROR;
    }
    for (k = 0; k < N_U; k++) {
        u_abs[k] = R(comp, VR_U0 + k);
        u[k] = u_abs[k] - d->trim_u[k];
    }
    if (N_GROUPS > 0 && !history_append(comp, comp->s.time, u_abs)) return FMU_ERROR;
    if (delayed_inputs(comp, comp->s.time, v) != FMU_OK) return FMU_ERROR;
    /* forcing B~ u held over the step, then x+ = Phi x + Psi (B~ u) */
    for (i = 0; i < N_X; i++) {
        double sum = 0.0;
        for (k = 0; k < N_U; k++) {
            int g = ENTRY_GROUP[i * N_U + k];
            sum += d->B[i][k] * (g < 0 ? u[k] : v[g]);
        }
        f[i] = sum;
    }
    for (i = 0; i < N_X; i++) {
        double sum = 0.0;
        for (j = 0; j < N_X; j++) sum += d->Phi[i][j] * x[j] + d->Psi[i][j] * f[j];
        x_new[i] = sum;
    }
    for (i = 0; i < N_X; i++) {
        if (!isfinite(x_new[i])) {
            /* discard: nothing of this step was computed; time stays */
            fmu_log(comp, FMU_DISCARD, "logStatusDiscard",
                    "state became non-finite at t = %.6g s (unstable model?)", comp->s.time + h);
            return FMU_DISCARD;
        }
        x[i] = x_new[i];
    }
    comp->s.time += h;
    return FMU_OK;
}

/* ------------------------------------------------------------------------------------------ */
/* outputs                                                                                      */

void model_calculate_values(ModelInstance *comp) {
    const ModelData *d = &comp->s.data;
    const double *x = comp->s.r + VR_STATE0;
    double *dx = comp->s.r + VR_DERIV0;
    double u[N_U];
    int i, j, k;

    perturbation_inputs(comp, u);
    /* co-simulation has no Pade states: der(x) uses the interpolated input history */
    linear_rhs(comp, comp->s.time, x, u, 0, dx);
    for (i = 0; i < N_Y; i++) {
        double y = d->trim_y[i];
        for (j = 0; j < N_X; j++) y += d->C[i][j] * x[j];
        for (k = 0; k < N_U; k++) y += d->D[i][k] * u[k];
        R(comp, VR_Y0 + i) = y;
    }
}
