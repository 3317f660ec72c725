/*
 * Nonlinear single-main-rotor helicopter (Bo-105 class at 2800 kg): the physics.
 *
 * Structure after Heffley & Mnich, NASA CR-177476 (1988): 6-DoF rigid body, main rotor with
 * blade-element thrust and uniform inflow, tail rotor of the same form, fuselage flat-plate
 * drag in the rotor wake, stall-limited horizontal and vertical tail. Extended with
 *   - dynamic inflow: each rotor's uniform induced velocity is a state (Pitt & Peters 1981),
 *   - first-order tip-path-plane flapping a1, b1 with hub stiffness, body-rate and advance-
 *     ratio terms, derived by harmonic balance of the centre-spring blade flap equation
 *     (Padfield, Helicopter Flight Dynamics, ch. 3) with the second time derivatives dropped,
 *   - first-order actuators from stick percent to blade angles.
 * Equation numbers below refer to fmus/helicopter/README.md, which also lists every
 * parameter with its source.
 *
 * Axes: body x forward, y starboard, z down; Euler angles 3-2-1. The main rotor turns
 * counter-clockwise seen from above (azimuth psi measured from the tail in the direction of
 * rotation); the tail rotor thrust points to starboard.
 */
#include <math.h>

#include "fmu_model.h"
#include "holds.h"

#ifndef M_PI
#define M_PI 3.14159265358979323846
#endif

#define P(name) (r[VR_##name])

/* Quantities reported as outputs; computed alongside the derivatives. */
typedef struct {
    double ax, ay, az, airspeed, mu, beta_0, T_mr, T_tr, Q_mr, power;
} Outputs;

static double clamp_percent(double x) { return x < 0.0 ? 0.0 : (x > 100.0 ? 100.0 : x); }

/* Stick percent -> blade angle: linear gearing between the angles at 0 % and 100 %, with the
 * stick saturated to its travel. */
static double gearing(double percent, double at0, double at100) {
    return at0 + (at100 - at0) * 0.01 * clamp_percent(percent);
}

FmuStatus model_initialize(ModelInstance *comp) {
    const double *r = comp->s.r;
    ModelData *d = &comp->s.data;
    static const struct { int vr; } positive[] = {
        {VR_mass}, {VR_Ixx}, {VR_Iyy}, {VR_Izz}, {VR_rho}, {VR_R_mr}, {VR_c_mr}, {VR_Nb_mr},
        {VR_Omega_mr}, {VR_a_mr}, {VR_I_beta}, {VR_k_inflow_mass}, {VR_R_tr}, {VR_c_tr},
        {VR_Nb_tr}, {VR_Omega_tr}, {VR_a_tr}, {VR_omega_act}, {VR_h_rk4}, {VR_a_ht},
        {VR_a_vt}, {VR_alpha_stall_ht}, {VR_alpha_stall_vt}};
    double det, area, area_tr;
    size_t i;

    for (i = 0; i < sizeof positive / sizeof positive[0]; i++) {
        if (!(r[positive[i].vr] > 0.0)) {
            fmu_log(comp, FMU_ERROR, "logError", "parameter %s must be positive, got %g",
                    MODEL_VAR_NAMES[positive[i].vr], r[positive[i].vr]);
            return FMU_ERROR;
        }
    }
    if (P(K_beta) < 0.0) {
        fmu_log(comp, FMU_ERROR, "logError", "parameter K_beta must not be negative, got %g",
                P(K_beta));
        return FMU_ERROR;
    }
    det = P(Ixx) * P(Izz) - P(Ixz) * P(Ixz);
    if (!(det > 0.0)) {
        fmu_log(comp, FMU_ERROR, "logError",
                "inertia tensor is not positive definite: Ixx Izz - Ixz^2 = %g", det);
        return FMU_ERROR;
    }
    d->inv_mass = 1.0 / P(mass);
    d->inv_det_xz = 1.0 / det;
    d->half_rho = 0.5 * P(rho);

    area = M_PI * P(R_mr) * P(R_mr);
    d->mr_omega_r = P(Omega_mr) * P(R_mr);
    d->mr_force = P(rho) * area * d->mr_omega_r * d->mr_omega_r;
    d->mr_sigma = P(Nb_mr) * P(c_mr) / (M_PI * P(R_mr));
    d->mr_half_sa = 0.5 * d->mr_sigma * P(a_mr);
    d->mr_lock = P(rho) * P(a_mr) * P(c_mr) * pow(P(R_mr), 4) / P(I_beta);
    d->mr_lb2 = 1.0 + P(K_beta) / (P(I_beta) * P(Omega_mr) * P(Omega_mr));
    d->mr_k_hub = 0.5 * P(Nb_mr) * P(K_beta);
    d->mr_inv_mass_a = 1.0 / (P(k_inflow_mass) * P(rho) * M_PI * pow(P(R_mr), 3));
    d->mr_two_rho_a = 2.0 * P(rho) * area;
    d->mr_root_pitch = -0.75 * P(twist_mr);
    d->cos_shaft = cos(P(shaft_tilt));
    d->sin_shaft = sin(P(shaft_tilt));

    area_tr = M_PI * P(R_tr) * P(R_tr);
    d->tr_omega_r = P(Omega_tr) * P(R_tr);
    d->tr_force = P(rho) * area_tr * d->tr_omega_r * d->tr_omega_r;
    d->tr_sigma = P(Nb_tr) * P(c_tr) / (M_PI * P(R_tr));
    d->tr_half_sa = 0.5 * d->tr_sigma * P(a_tr);
    d->tr_inv_mass_a = 1.0 / (P(k_inflow_mass) * P(rho) * M_PI * pow(P(R_tr), 3));
    d->tr_two_rho_a = 2.0 * P(rho) * area_tr;
    d->tr_root_pitch = -0.75 * P(twist_tr);

    d->ht_cl_max = P(a_ht) * P(alpha_stall_ht);
    d->ht_cos2i = cos(2.0 * P(i_ht));
    d->ht_sin2i = sin(2.0 * P(i_ht));
    d->ht_cos_i = cos(P(i_ht));
    d->ht_sin_i = sin(P(i_ht));
    d->vt_cl_max = P(a_vt) * P(alpha_stall_vt);
    d->vt_cos2i = cos(2.0 * P(i_vt));
    d->vt_sin2i = sin(2.0 * P(i_vt));
    d->vt_cos_i = cos(P(i_vt));
    d->vt_sin_i = sin(P(i_vt));
    {
        char message[256];
        if (holds_initialize(r, &d->holds, message, sizeof message)) {
            fmu_log(comp, FMU_ERROR, "logError", "%s", message);
            return FMU_ERROR;
        }
    }
    return FMU_OK;
}

/*
 * Normal force of a tail surface along its normal, per unit dynamic-pressure area, times V^2:
 * V^2 C_L(alpha + i) + cross-flow drag. The lift curve a sin(alpha) cos(alpha) (= a alpha for
 * small angles, Eq. T1) is limited smoothly to +-cl_max with tanh (the stall clamp), and is
 * pi-periodic so reversed flow is handled without a jump; the cross-flow term
 * cd_90 w_n |w_n| gives the flat-plate normal force when the flow is perpendicular.
 * (u, w): flow components along the chord and the normal (w positive from below).
 */
static double surface_force_v2(double u, double w, double a, double cl_max, double cos2i,
                               double sin2i, double cos_i, double sin_i, double cd_90) {
    const double v2 = u * u + w * w;
    double lift = 0.0, w_n;
    if (v2 > 1e-12) {
        /* sin(2 (alpha + i)) with alpha = atan2(w, u), without trigonometric calls */
        const double s2 = (2.0 * u * w * cos2i + (u * u - w * w) * sin2i) / v2;
        lift = v2 * cl_max * tanh(0.5 * a * s2 / cl_max);
    }
    w_n = u * sin_i + w * cos_i;
    return lift + cd_90 * w_n * fabs(w_n);
}

/* The whole model: state derivatives dx from states x (and outputs if o != NULL). */
static void evaluate(const ModelInstance *comp, const double *x, double *dx, Outputs *o) {
    const double *r = comp->s.r;
    const ModelData *d = &comp->s.data;

    const double u = x[VR_u], v = x[VR_v], w = x[VR_w];
    const double p = x[VR_p], q = x[VR_q], rr = x[VR_r];
    const double phi = x[VR_phi], theta = x[VR_theta], psi = x[VR_psi];
    const double a1 = x[VR_a1], b1 = x[VR_b1];
    const double vi = x[VR_vi_mr], vit = x[VR_vi_tr];

    /* airspeed components at the CG: ground velocity minus wind (gusts in body axes) */
    const double ua = u - P(u_gust), va = v - P(v_gust), wa = w - P(w_gust);
    const double rho2 = d->half_rho;

    double X, Y, Z, L, M, N;

    /* ---------------- actuators (Eq. A1): first-order lags towards the geared stick ---- */
    {
        const double bw = P(omega_act);
        double c[HOLD_CONTROLS]; /* the inputs, or with the holds on what they apply */
        holds_controls(r, &d->holds, x, c);
        dx[VR_theta_0] = bw * (gearing(c[HOLD_COL], P(gear_col_0), P(gear_col_100)) - x[VR_theta_0]);
        dx[VR_theta_1s] = bw * (gearing(c[HOLD_LON], P(gear_lon_0), P(gear_lon_100)) - x[VR_theta_1s]);
        dx[VR_theta_1c] = bw * (gearing(c[HOLD_LAT], P(gear_lat_0), P(gear_lat_100)) - x[VR_theta_1c]);
        dx[VR_theta_tr] = bw * (gearing(c[HOLD_PED], P(gear_ped_0), P(gear_ped_100)) - x[VR_theta_tr]);
    }

    /* ---------------- main rotor ------------------------------------------------------- */
    double T, Q, lam_flow;
    double us, vs, ws, Vn;
    {
        const double ci = d->cos_shaft, si = d->sin_shaft;
        const double OR = d->mr_omega_r, Om = P(Omega_mr);
        const double g = d->mr_lock, l2 = d->mr_lb2, l2m1 = l2 - 1.0, g8 = 0.125 * g;
        const double tw = P(twist_mr);
        /* hub velocity relative to the air (CG airspeed + omega x r_hub), body axes */
        const double uh = ua - q * P(h_hub);
        const double vh = va + rr * P(x_hub) + p * P(h_hub);
        const double wh = wa - q * P(x_hub);
        /* shaft axes: body axes pitched nose-down by the shaft tilt (Eq. R1). The roll rate
         * driving the flapping is p cos(i) plus the yaw-rate component r sin(i) of exact
         * kinematics, weighted by yaw_rate_flapping (default 0). With 0 it is left out, the
         * convention of Heffley & Mnich (body p, q drive the flapping) and of Helisim
         * (Padfield's Bo-105 hover derivatives: L_r is the tail-rotor term alone, about
         * +0.13); with 1 the rotor's roll damping turns a yaw rate into a rolling moment,
         * L_r ~ L_p sin(i) ~ -0.6 1/s (README: yaw_rate_flapping). */
        const double ps = p * ci + P(yaw_rate_flapping) * rr * si;
        double mux, muy, mu2, mu, cx, sx, lam, th0, th1s, th1c, b1c, b1s, pb, qb;
        double b1cw, b1sw, t1cw, t1sw, pw, qw, l1c, R0, Rc, Rs, D1s, D1c, B0, CT, delta;
        double nx, ny, nz, inv_n, Fsx, Fsy, Fsz, Fx, Fy, Fz, Ls, Ms, H, CQ, Vm;
        us = uh * ci + wh * si;
        vs = vh;
        ws = -uh * si + wh * ci;
        mux = us / OR;
        muy = vs / OR;
        mu2 = mux * mux + muy * muy;
        mu = sqrt(mu2);
        /* wind azimuth chi: direction of the in-plane airspeed; any value at mu = 0, where
         * every term below that depends on it is multiplied by mu */
        if (mu > 1e-12) {
            cx = mux / mu;
            sx = muy / mu;
        } else {
            cx = 1.0;
            sx = 0.0;
        }
        lam = (vi - ws) / OR; /* inflow ratio through the shaft plane, positive down */

        /* blade pitch and flapping in Padfield's signs: theta = theta0 + x theta_tw +
         * theta1c cos(psi) + theta1s sin(psi), beta = beta0 + beta1c cos + beta1s sin */
        th0 = x[VR_theta_0] + d->mr_root_pitch; /* root pitch from the 0.75 R value */
        th1s = x[VR_theta_1s];
        th1c = -x[VR_theta_1c]; /* starboard-positive cyclic -> Padfield's theta_1c */
        b1c = -a1;
        b1s = -b1;
        pb = ps / Om;
        qb = q / Om;

        /* rotate first harmonics and rates into hub-wind axes (Eq. R2) */
        b1cw = b1c * cx - b1s * sx;
        b1sw = b1c * sx + b1s * cx;
        t1cw = th1c * cx - th1s * sx;
        t1sw = th1c * sx + th1s * cx;
        pw = pb * cx + qb * sx;
        qw = -pb * sx + qb * cx;

        /* longitudinal induced-inflow gradient of the skewed wake (Eq. I2, Coleman):
         * lambda_i (1 + k_x x cos psi_w) with k_x = tan(chi/2), chi = wake skew angle,
         * tan(chi/2) = mu / (sqrt(mu^2 + lam^2) + lam); more inflow at the rear of the disc.
         * It tilts the disc towards the advancing side in transition (transverse-flow
         * effect). Bounded for the (unmodelled) vortex-ring region where lam <= 0. */
        {
            double den = sqrt(mu2 + lam * lam) + lam;
            l1c = P(k_inflow_skew) * (den > mu / 1.5 ? mu / den : 1.5) * vi / OR;
        }

        /* Harmonic balance of the flap equation (Eq. F1-F4): residuals of the coning, cosine
         * and sine equations without the unknowns beta0, beta1c', beta1s' */
        R0 = g * lam / 6.0 - g * mu * pw / 12.0 - g * mu * t1sw / 6.0 -
             g * th0 * (mu2 + 1.0) / 8.0 - g * tw * (5.0 * mu2 + 6.0) / 60.0;
        Rc = l2m1 * b1cw + g * (mu2 + 2.0) / 16.0 * b1sw + g * (l1c - qw) / 8.0 -
             g * t1cw * (mu2 + 2.0) / 16.0 - 2.0 * pw;
        Rs = g * (mu2 - 2.0) / 16.0 * b1cw + l2m1 * b1sw + g * lam * mu / 4.0 -
             g * mu * th0 / 3.0 - g * mu * tw / 4.0 - g * pw / 8.0 -
             g * t1sw * (3.0 * mu2 + 2.0) / 16.0 + 2.0 * qw;
        /* closed-form solution of the 3x3 linear system (Eq. F5) */
        D1s = (g * mu * R0 / (6.0 * l2) - Rc - 0.5 * g8 * Rs) /
              (2.0 + 0.5 * g8 * g8 - g * g * mu2 / (72.0 * l2));
        D1c = 0.5 * (g8 * D1s + Rs);
        B0 = -(R0 + g * mu / 12.0 * D1s) / l2;
        /* back to shaft axes and to time: d/dt = Omega d/dpsi; a1 = -beta1c, b1 = -beta1s */
        dx[VR_a1] = -Om * (D1c * cx + D1s * sx);
        dx[VR_b1] = -Om * (-D1c * sx + D1s * cx);

        /* blade-element thrust with uniform inflow (Eq. R3) */
        CT = d->mr_half_sa * (th0 * (1.0 / 3.0 + 0.5 * mu2) + 0.25 * tw * (1.0 + mu2) +
                              0.5 * mu * t1sw - 0.5 * lam + 0.25 * mu * pw - 0.25 * mu * D1s);
        T = d->mr_force * CT;

        /* thrust along the tip-path-plane normal (-a1, b1, -1)/|.| (first-order flapping),
         * plus the profile H-force against the in-plane airspeed (Eq. R4) */
        inv_n = 1.0 / sqrt(1.0 + a1 * a1 + b1 * b1);
        nx = -a1 * inv_n;
        ny = b1 * inv_n;
        nz = -inv_n;
        delta = P(delta0_mr) + P(delta2_mr) * CT * CT;
        H = d->mr_force * d->mr_sigma * delta * 0.25;
        Fsx = T * nx - H * mux;
        Fsy = T * ny - H * muy;
        Fsz = T * nz;
        Fx = Fsx * ci - Fsz * si;
        Fy = Fsy;
        Fz = Fsx * si + Fsz * ci;

        /* dynamic inflow (Eq. I1): M_a dvi/dt = T - 2 rho A V_m vi, with Glauert's mass-flow
         * velocity through the tip-path plane; 0.1 m/s keeps it defined if the flow stalls */
        Vn = us * nx + vs * ny + ws * nz; /* hub velocity along the thrust: climb rate */
        Vm = sqrt(us * us + vs * vs + ws * ws + vi * vi + 2.0 * vi * Vn + 0.01);
        dx[VR_vi_mr] = (T - d->mr_two_rho_a * Vm * vi) * d->mr_inv_mass_a;

        /* shaft torque from induced, climb and profile power (Eq. R5) */
        CQ = CT * (P(kappa_mr) * vi + Vn) / OR +
             0.125 * d->mr_sigma * delta * (1.0 + P(k_mu_profile) * mu2);
        Q = d->mr_force * P(R_mr) * CQ;

        /* hub moments: flap stiffness (Eq. R6) and torque reaction, shaft -> body axes,
         * plus the moment of the rotor force about the CG */
        Ls = d->mr_k_hub * b1;
        Ms = d->mr_k_hub * a1;
        X = Fx;
        Y = Fy;
        Z = Fz;
        L = Ls * ci - Q * si + P(h_hub) * Fy;
        M = Ms - P(h_hub) * Fx - P(x_hub) * Fz;
        N = Ls * si + Q * ci + P(x_hub) * Fy;

        lam_flow = vi - ws; /* wake transport velocity through the shaft plane, m/s */
        if (o) {
            o->mu = mu;
            o->beta_0 = B0;
            o->T_mr = T;
            o->Q_mr = Q;
            o->power = Q * Om;
        }
    }

    /* ---------------- tail rotor (Eq. TR1-TR3) ------------------------------------------ */
    {
        const double OR = d->tr_omega_r;
        /* hub velocity relative to the air; thrust axis = +y */
        const double ut = ua + q * P(z_tr);
        const double vt = va + rr * P(x_tr) - p * P(z_tr);
        const double wt = wa - q * P(x_tr);
        const double mu2 = (ut * ut + wt * wt) / (OR * OR);
        const double lam = (vit + vt) / OR; /* moving along the thrust = climbing */
        const double th = x[VR_theta_tr] + d->tr_root_pitch;
        const double CT = d->tr_half_sa * (th * (1.0 / 3.0 + 0.5 * mu2) +
                                           0.25 * P(twist_tr) * (1.0 + mu2) - 0.5 * lam);
        const double Tt = d->tr_force * CT;
        const double Vm = sqrt(ut * ut + vt * vt + wt * wt + vit * vit + 2.0 * vit * vt + 0.01);
        dx[VR_vi_tr] = (Tt - d->tr_two_rho_a * Vm * vit) * d->tr_inv_mass_a;
        Y += Tt;
        L += -P(z_tr) * Tt;
        N += P(x_tr) * Tt;
        if (o) {
            const double delta = P(delta0_tr) + P(delta2_tr) * CT * CT;
            const double CQ = CT * (P(kappa_mr) * vit + vt) / OR +
                              0.125 * d->tr_sigma * delta * (1.0 + P(k_mu_profile) * mu2);
            o->T_tr = Tt;
            o->power += d->tr_force * P(R_tr) * CQ * P(Omega_tr);
        }
    }

    /* ---------------- fuselage (Eq. B1-B3) ---------------------------------------------- */
    {
        /* rotor wake at the fuselage: the wake reaches the fuselage (h_hub below the disc)
         * displaced aft by h_hub * u / (wake velocity); immersion decays with displacement */
        const double wake = sqrt(lam_flow * lam_flow + 1.0);
        const double xi = P(h_hub) * us / (wake * P(R_mr));
        const double k = P(k_wash_fus) / (1.0 + xi * xi);
        const double uf = ua, vf = va, wf = wa - k * vi;
        const double Vf = sqrt(uf * uf + vf * vf + wf * wf);
        X += -rho2 * P(f_x) * uf * Vf;
        Y += -rho2 * P(f_y) * vf * Vf;
        Z += -rho2 * P(f_z) * wf * Vf;
        M += rho2 * (P(C_M0_fus) * uf * uf + P(C_Malpha_fus) * uf * wf);
        N += rho2 * P(C_Nbeta_fus) * uf * vf;
    }

    /* ---------------- horizontal tail (Eq. T1-T2) --------------------------------------- */
    {
        /* immersion in the skewed wake: distance between the tail and the wake centre at the
         * tail's depth below the hub, normalised by R; full wake velocity k_wash_ht * vi */
        const double depth = P(h_hub) + P(z_ht);
        const double wake = sqrt(lam_flow * lam_flow + 1.0);
        const double dist = (P(x_hub) - P(x_ht) - depth * us / wake) / P(R_mr);
        const double d2 = dist * dist;
        const double k = P(k_wash_ht) / (1.0 + d2 * d2);
        const double uht = ua + q * P(z_ht);
        const double wht = wa - q * P(x_ht) - k * vi;
        const double Fn = rho2 * P(S_ht) *
                          surface_force_v2(uht, wht, P(a_ht), d->ht_cl_max, d->ht_cos2i,
                                           d->ht_sin2i, d->ht_cos_i, d->ht_sin_i, P(cd_90));
        Z += -Fn;
        M += P(x_ht) * Fn;
    }

    /* ---------------- vertical fin (Eq. T3) --------------------------------------------- */
    {
        const double uvt = ua + q * P(z_vt);
        const double vvt = va + rr * P(x_vt) - p * P(z_vt);
        const double Fn = rho2 * P(S_vt) *
                          surface_force_v2(uvt, vvt, P(a_vt), d->vt_cl_max, d->vt_cos2i,
                                           d->vt_sin2i, d->vt_cos_i, d->vt_sin_i, P(cd_90));
        Y += -Fn;
        L += P(z_vt) * Fn;
        N += -P(x_vt) * Fn;
    }

    /* ---------------- rigid body (Eq. E1-E4) -------------------------------------------- */
    {
        const double sphi = sin(phi), cphi = cos(phi);
        const double sth = sin(theta), cth = cos(theta);
        const double spsi = sin(psi), cpsi = cos(psi);
        const double gg = P(g), im = d->inv_mass;
        const double Ixx = P(Ixx), Iyy = P(Iyy), Izz = P(Izz), Ixz = P(Ixz);
        const double Lp = L + (Iyy - Izz) * q * rr + Ixz * p * q;
        const double Np = N + (Ixx - Iyy) * p * q - Ixz * q * rr;
        double zdot;
        dx[VR_u] = X * im - gg * sth - (q * w - rr * v);
        dx[VR_v] = Y * im + gg * sphi * cth - (rr * u - p * w);
        dx[VR_w] = Z * im + gg * cphi * cth - (p * v - q * u);
        dx[VR_p] = (Izz * Lp + Ixz * Np) * d->inv_det_xz;
        dx[VR_q] = (M + (Izz - Ixx) * p * rr + Ixz * (rr * rr - p * p)) / Iyy;
        dx[VR_r] = (Ixz * Lp + Ixx * Np) * d->inv_det_xz;
        dx[VR_phi] = p + (q * sphi + rr * cphi) * sth / cth;
        dx[VR_theta] = q * cphi - rr * sphi;
        dx[VR_psi] = (q * sphi + rr * cphi) / cth;
        dx[VR_x_n] = u * cth * cpsi + v * (sphi * sth * cpsi - cphi * spsi) +
                     w * (cphi * sth * cpsi + sphi * spsi);
        dx[VR_y_e] = u * cth * spsi + v * (sphi * sth * spsi + cphi * cpsi) +
                     w * (cphi * sth * spsi - sphi * cpsi);
        zdot = -u * sth + v * sphi * cth + w * cphi * cth;
        dx[VR_h] = -zdot;
        if (o) {
            o->ax = X * im;
            o->ay = Y * im;
            o->az = Z * im;
            o->airspeed = sqrt(ua * ua + va * va + wa * wa);
        }
    }
}

void model_derivatives(const ModelInstance *comp, double t, const double *x, double *dx) {
    (void)t;
    evaluate(comp, x, dx, 0);
}

void model_calculate_values(ModelInstance *comp) {
    double *r = comp->s.r;
    double dx[N_STATES];
    Outputs o;
    int i;
    evaluate(comp, r + VR_STATE0, dx, &o);
    for (i = 0; i < N_STATES; i++) r[VR_DERIV0 + i] = dx[i];
    P(ax) = o.ax;
    P(ay) = o.ay;
    P(az) = o.az;
    P(airspeed) = o.airspeed;
    P(mu) = o.mu;
    P(beta_0) = o.beta_0;
    P(T_mr) = o.T_mr;
    P(T_tr) = o.T_tr;
    P(Q_mr) = o.Q_mr;
    P(power) = o.power;
    holds_outputs(r, &comp->s.data.holds);
}

FmuStatus model_do_step(ModelInstance *comp, double h) {
    holds_sample(comp->s.r, &comp->s.data.holds); /* sample-and-hold over the step */
    return fmu_integrate_rk4(comp, h, comp->s.r[VR_h_rk4]);
}

void model_reset(ModelInstance *comp) { (void)comp; }
