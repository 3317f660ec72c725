/*
 * Stabilisation holds of the flight-test campaign (see holds.h).
 *
 * Each expression mirrors sysid.flight_test.campaign._hold_commands operation for operation
 * (IEEE double, no contraction into fused multiply-adds: the build does not enable FMA), so
 * the applied controls are bit-identical to the Python reference; tests/test_maneuvers.py
 * checks the bytes. Per control, with d_x = x - x_trim in analysis units:
 *
 *   attitude/heading  delta = -(K_e e + K_r d_rate) / M_delta,  e = d_angle - ref
 *                     (heading error wrapped to [-180, 180) deg; refs from the u/v loops:
 *                     theta_ref = k_v d_u / 2, phi_ref = -k_v d_v / 2, psi_ref = 0)
 *   vertical speed    delta = K_e (hdot - hdot_trim) / Z_col,
 *                     hdot = u sin(theta) - v sin(phi) cos(theta) - w cos(phi) cos(theta)
 *
 * with dead bands (conditional holds) on the errors and rates, then
 * applied = clip(input + delta, 0, 100). K_e and K_r already include the weaker hold of the
 * excited axis; M_delta is the control derivative of the truth linearisation.
 */
#include <math.h>
#include <stdio.h>

#include "model_variables.h"
#include "holds.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define P(name) (r[VR_##name])

/* The factors sysid.core.units.conversion_factor computes from the FMU units to the analysis
 * units (a.factor / b.factor), so that the analysis values are the same doubles as Python's
 * out * factor: 1 / FT with FT = 0.3048 m, and 1 / DEG with DEG = pi / 180 rad. */
static const double FT_PER_M = 1.0 / 0.3048;
static const double DEG_PER_RAD = 1.0 / (M_PI / 180.0);
/* Python's math.radians multiplies by this constant */
static const double RAD_PER_DEG = M_PI / 180.0;

/* Python's float modulo: the result has the sign of the divisor (here 360, positive). */
static double python_mod(double x, double y) {
    double m = fmod(x, y);
    if (m != 0.0) {
        if ((y < 0.0) != (m < 0.0)) m += y;
    } else {
        m = copysign(0.0, y);
    }
    return m;
}

/* campaign._dead_band: copysign(max(|value| - width, 0), value), with Python's max. */
static double dead_band(double value, double width) {
    double excess = fabs(value) - width;
    return copysign((0.0 > excess) ? 0.0 : excess, value);
}

static double climb_rate(double u, double v, double w, double theta_deg, double phi_deg) {
    const double th = theta_deg * RAD_PER_DEG, ph = phi_deg * RAD_PER_DEG;
    return u * sin(th) - v * sin(ph) * cos(th) - w * cos(ph) * cos(th);
}

/* numpy.clip(x, 0, 100): max then min, NaN propagated */
static double clip_percent(double x) {
    double m;
    if (isnan(x)) return x;
    m = x > 0.0 ? x : 0.0;
    return m < 100.0 ? m : 100.0;
}

int holds_initialize(const double *r, HoldsData *h, char *message, size_t size) {
    static const struct { int vr; } derivatives[] = {
        {VR_hold_derivative_lon}, {VR_hold_derivative_lat}, {VR_hold_derivative_col},
        {VR_hold_derivative_ped}};
    size_t i;
    h->held = 0;
    h->hdot0 = climb_rate(P(hold_trim_u), P(hold_trim_v), P(hold_trim_w), P(hold_trim_theta),
                          P(hold_trim_phi));
    if (P(hold_enabled) != 0.0 && P(hold_enabled) != 1.0) {
        snprintf(message, size, "parameter hold_enabled must be 0 or 1, got %g",
                 P(hold_enabled));
        return -1;
    }
    if (P(hold_enabled) == 0.0) return 0;
    for (i = 0; i < sizeof derivatives / sizeof derivatives[0]; i++) {
        const double m = r[derivatives[i].vr];
        if (!(m != 0.0) || !isfinite(m)) {
            snprintf(message, size, "parameter %s (a control derivative) must be finite and "
                     "nonzero when hold_enabled = 1, got %g", MODEL_VAR_NAMES[derivatives[i].vr],
                     m);
            return -1;
        }
    }
    if (!(P(hold_dead_band_attitude) >= 0.0 && P(hold_dead_band_rate) >= 0.0 &&
          P(hold_dead_band_vertical_speed) >= 0.0)) {
        snprintf(message, size, "hold dead bands must be >= 0, got attitude %g, rate %g, "
                 "vertical speed %g", P(hold_dead_band_attitude), P(hold_dead_band_rate),
                 P(hold_dead_band_vertical_speed));
        return -1;
    }
    return 0;
}

/* The law at the states x (SI, indexed like r) and the current inputs: clip(input + delta). */
static void hold_law(const double *r, const HoldsData *h, const double *x,
                     double u[HOLD_CONTROLS]) {
    const double y_u = x[VR_u] * FT_PER_M, y_v = x[VR_v] * FT_PER_M, y_w = x[VR_w] * FT_PER_M;
    const double y_theta = x[VR_theta] * DEG_PER_RAD, y_phi = x[VR_phi] * DEG_PER_RAD;
    const double d_u = y_u - P(hold_trim_u), d_v = y_v - P(hold_trim_v);
    const double d_p = x[VR_p] * DEG_PER_RAD - P(hold_trim_p);
    const double d_q = x[VR_q] * DEG_PER_RAD - P(hold_trim_q);
    const double d_r = x[VR_r] * DEG_PER_RAD - P(hold_trim_r);
    const double d_phi = y_phi - P(hold_trim_phi), d_theta = y_theta - P(hold_trim_theta);
    const double d_psi = x[VR_psi] * DEG_PER_RAD - P(hold_trim_psi);
    const double k_v = P(hold_velocity);
    const double theta_ref = k_v != 0.0 ? k_v * d_u * 0.5 : 0.0;
    const double phi_ref = k_v != 0.0 ? -k_v * d_v * 0.5 : 0.0;
    const double band_angle = P(hold_dead_band_attitude), band_rate = P(hold_dead_band_rate);
    double e, hdot;

    e = dead_band(d_theta - theta_ref, band_angle);
    u[HOLD_LON] = -(P(hold_k_error_lon) * e + P(hold_k_rate_lon) * dead_band(d_q, band_rate))
                  / P(hold_derivative_lon);
    e = dead_band(d_phi - phi_ref, band_angle);
    u[HOLD_LAT] = -(P(hold_k_error_lat) * e + P(hold_k_rate_lat) * dead_band(d_p, band_rate))
                  / P(hold_derivative_lat);
    hdot = climb_rate(y_u, y_v, y_w, y_theta, y_phi);
    e = dead_band(hdot - h->hdot0, P(hold_dead_band_vertical_speed));
    u[HOLD_COL] = P(hold_k_error_col) * e / P(hold_derivative_col);
    e = dead_band(python_mod(d_psi - 0.0 + 180.0, 360.0) - 180.0, band_angle);
    u[HOLD_PED] = -(P(hold_k_error_ped) * e + P(hold_k_rate_ped) * dead_band(d_r, band_rate))
                  / P(hold_derivative_ped);

    u[HOLD_LON] = clip_percent(P(lon) + u[HOLD_LON]);
    u[HOLD_LAT] = clip_percent(P(lat) + u[HOLD_LAT]);
    u[HOLD_COL] = clip_percent(P(col) + u[HOLD_COL]);
    u[HOLD_PED] = clip_percent(P(ped) + u[HOLD_PED]);
}

void holds_controls(const double *r, const HoldsData *h, const double *x,
                    double u[HOLD_CONTROLS]) {
    int i;
    if (P(hold_enabled) == 0.0) {
        u[HOLD_LON] = P(lon);
        u[HOLD_LAT] = P(lat);
        u[HOLD_COL] = P(col);
        u[HOLD_PED] = P(ped);
    } else if (h->held) {
        for (i = 0; i < HOLD_CONTROLS; i++) u[i] = h->applied[i];
    } else {
        hold_law(r, h, x, u);
    }
}

void holds_sample(const double *r, HoldsData *h) {
    if (P(hold_enabled) == 0.0) return;
    hold_law(r, h, r + VR_STATE0, h->applied);
    h->held = 1;
}

void holds_outputs(double *r, const HoldsData *h) {
    double u[HOLD_CONTROLS];
    holds_controls(r, h, r + VR_STATE0, u);
    P(lon_applied) = clip_percent(u[HOLD_LON]);
    P(lat_applied) = clip_percent(u[HOLD_LAT]);
    P(col_applied) = clip_percent(u[HOLD_COL]);
    P(ped_applied) = clip_percent(u[HOLD_PED]);
}
