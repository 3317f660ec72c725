/*
 * Model-private data of the helicopter: constants derived from the parameters once per
 * initialisation (model_initialize in model.c), so that the derivative function, called four
 * times per RK4 sub-step, does only the flight-dependent arithmetic.
 */
#ifndef HELICOPTER_MODEL_H
#define HELICOPTER_MODEL_H

#include "holds.h"

typedef struct {
    /* rigid body */
    double inv_mass;
    double inv_det_xz; /* 1 / (Ixx Izz - Ixz^2) */
    /* main rotor */
    double mr_omega_r;     /* tip speed Omega R, m/s */
    double mr_force;       /* rho pi R^2 (Omega R)^2, N: thrust per unit C_T */
    double mr_half_sa;     /* sigma a / 2 */
    double mr_sigma;       /* solidity N_b c / (pi R) */
    double mr_lock;        /* Lock number gamma = rho a c R^4 / I_beta */
    double mr_lb2;         /* flap frequency ratio squared, 1 + K_beta / (I_beta Omega^2) */
    double mr_k_hub;       /* hub moment per radian of tip-path-plane tilt, N_b K_beta / 2 */
    double mr_inv_mass_a;  /* 1 / apparent mass of the inflow, 1/kg */
    double mr_two_rho_a;   /* 2 rho pi R^2 */
    double mr_root_pitch;  /* root pitch minus 0.75 R pitch, -0.75 theta_tw, rad */
    double cos_shaft, sin_shaft;
    /* tail rotor */
    double tr_omega_r, tr_force, tr_half_sa, tr_sigma, tr_inv_mass_a, tr_two_rho_a;
    double tr_root_pitch;
    /* empennage: lift limits and incidence terms */
    double ht_cl_max, ht_cos2i, ht_sin2i, ht_cos_i, ht_sin_i;
    double vt_cl_max, vt_cos2i, vt_sin2i, vt_cos_i, vt_sin_i;
    double half_rho;
    /* stabilisation holds of the flight-test campaign (holds.c) */
    HoldsData holds;
} ModelData;

#endif
