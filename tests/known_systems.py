"""Known hover-like 6-DoF system flown with multistep inputs, for the time-domain tests.

The truth is the one of ``tests/test_identify_frequency.py`` (Padfield's Bo-105 hover
derivatives in analysis units, the paper's hover trim attitudes for the kinematic terms,
delays of 0.2 s on lon -> p and 0.1 s on lat -> q). Its bare airframe is unstable (a
0.24 +- 0.49j rad/s oscillation), so, as in flight test, a stabilising loop (LQR on the true
state) acts on all four controls while one axis is excited by a 3211 or 2311; the *recorded*
inputs are the total control positions, feedback included. White Gaussian measurement noise,
output biases and input reference offsets are added on request (all seeded).

The loop is stepped sample by sample with exactly the conventions of
:func:`sysid.models.simulate` (zero-order hold, delayed entries fed with
``u(t_n - tau)`` by linear interpolation between samples), so an open-loop simulation of the
truth with the recorded inputs reproduces the recorded (noise-free) outputs.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from test_identify_frequency import (PHI0, THETA0, TRUE_DELAYS, truth_structure,  # noqa: F401
                                     truth_values)

from sysid.identify import identify_time_domain
from sysid.signals.inputs import multistep
from sysid.models import discretize
from sysid.core.units import CHANNELS, CONTROLS, STATES_6DOF

#: Absolute hover trim of the paper's Table 1 (%, deg); velocities and rates zero.
TRIM = {"lon": 66.18, "lat": 52.65, "col": 64.13, "ped": 37.45, "u": 0.0, "v": 0.0, "w": 0.0,
        "p": 0.0, "q": 0.0, "r": 0.0, "phi": PHI0, "theta": THETA0, "psi": 0.0}
#: Measurement-noise standard deviations (ft/s, deg/s, deg): typical flight-test sensors.
NOISE_STD = {"u": 0.1, "v": 0.1, "w": 0.1, "p": 0.2, "q": 0.2, "r": 0.2,
             "phi": 0.05, "theta": 0.05, "psi": 0.05}
#: One multistep per axis: (kind, axis, base width s, amplitude %).
PLAN_3211 = (("3211", "lon", 0.5, 4.0), ("3211", "lat", 0.5, 4.0),
             ("3211", "col", 0.7, 4.0), ("3211", "ped", 0.7, 5.0))
PLAN_2311 = (("2311", "lon", 0.5, 4.0), ("2311", "lat", 0.5, 4.0),
             ("2311", "col", 0.7, 4.0), ("2311", "ped", 0.7, 5.0))


def stabilising_gain(structure, theta=None) -> np.ndarray:
    """LQR state feedback ``u = K x`` (4 x 9) for the delay-free airframe; loose weights so
    the loop only holds the unstable modes and leaves the excitation visible."""
    import control

    A, B, _, _, _ = structure.matrices(theta)
    Q = np.diag([1e-2] * 3 + [1e-4] * 3 + [1e-2] * 3)
    return -np.asarray(control.lqr(A, B, Q, np.eye(4))[0])


def _delayed_sample(U: np.ndarray, n: int, k: int, d: float) -> float:
    """``u_k(t_n - d dt)`` by linear interpolation, held at the first sample before 0."""
    m = int(math.floor(d))
    f = d - m
    a = U[max(n - m, 0), k]
    return a if f == 0 else (1.0 - f) * a + f * U[max(n - m - 1, 0), k]


def closed_loop_response(structure, external: np.ndarray, dt: float, *, theta=None,
                         gain=None, x0=None) -> tuple[np.ndarray, np.ndarray]:
    """Step the truth with ``u[n] = external[n] + K x[n]``.

    Parameters
    ----------
    external : ndarray (N, 4)
        Pilot (excitation) inputs, % from trim.
    dt : float
        Sample interval, s.

    Returns
    -------
    U : ndarray (N, 4)
        Total inputs (what a flight test records), % from trim.
    X : ndarray (N, 9)
        States, analysis units, perturbation from trim.
    """
    A, B, _, _, tau = structure.matrices(theta)
    K = stabilising_gain(structure, theta) if gain is None else gain
    groups = [(k, d / dt, np.where(tau[:, k] == d, B[:, k], 0.0))
              for k in range(B.shape[1]) for d in np.unique(tau[:, k])]
    Phi, Gam = discretize(A, np.stack([g[2] for g in groups], axis=1), dt)
    N = len(external)
    x = np.zeros(A.shape[0]) if x0 is None else np.asarray(x0, float)
    U = np.zeros_like(external, dtype=float)
    X = np.zeros((N, A.shape[0]))
    for n in range(N):
        X[n] = x
        U[n] = external[n] + K @ x
        v = np.array([_delayed_sample(U, n, k, d) for k, d, _ in groups])
        x = Phi @ x + Gam @ v
    return U, X


def multistep_records(structure=None, *, plan=PLAN_3211, dt: float = 0.02,
                      duration: float = 15.0, noise: float = 1.0, seed: int = 0,
                      theta=None, bias=None, input_offset=None, x0=None,
                      name_prefix: str = "") -> list[xr.Dataset]:
    """Time-history Datasets (docs/data_model.md) of the closed-loop truth, one per plan entry.

    Parameters
    ----------
    structure : LinearStructure, optional
        Data-generating system (default: :func:`truth_structure`).
    plan : sequence of (kind, axis, base_width, amplitude)
    dt, duration : float
        Sample interval and record length, s.
    noise : float
        Multiplies :data:`NOISE_STD` (0: noise-free).
    seed : int
        Noise seed; record ``i`` uses ``seed * 1000 + i``.
    bias : mapping, optional
        ``output -> constant offset`` added to the recorded measurements (sensor bias).
    input_offset : mapping, optional
        ``input -> constant`` added to the *recorded* controls (a reference shift: the
        aircraft flies the true inputs, the record is offset).
    x0 : mapping, optional
        Initial state perturbation.

    Returns
    -------
    list of xr.Dataset
        Absolute controls (%) and measurements with ``trim_<channel>`` attributes.
    """
    structure = truth_structure() if structure is None else structure
    bias = dict(bias or {})
    input_offset = dict(input_offset or {})
    states = list(structure.states)
    x0v = None if x0 is None else np.array([float(x0.get(s, 0.0)) for s in states])
    gain = stabilising_gain(structure, theta)
    records = []
    for i, (kind, axis, width, amplitude) in enumerate(plan):
        step = multistep(kind, axis, base_width=width, amplitude=amplitude, dt=dt,
                         lead_in=1.0, lead_out=duration)
        n = int(round(duration / dt)) + 1
        external = np.zeros((n, 4))
        external[:, CONTROLS.index(axis)] = step[axis].values[:n]
        U, X = closed_loop_response(structure, external, dt, theta=theta, gain=gain, x0=x0v)
        t = np.arange(n) * dt
        data = {}
        for k, c in enumerate(CONTROLS):
            data[c] = ("time", TRIM[c] + U[:, k] + input_offset.get(c, 0.0),
                       {"units": CHANNELS[c].unit, "long_name": CHANNELS[c].long_name})
        for j, s in enumerate(states):
            data[s] = ("time", TRIM[s] + X[:, j] + bias.get(s, 0.0),
                       {"units": CHANNELS[s].unit, "long_name": CHANNELS[s].long_name})
        name = f"{name_prefix}{kind}_{axis}_{i + 1}"
        attrs = {"maneuver": name, "kind": kind, "axis": axis, "flight_condition": "hover",
                 "airspeed_kt": 0.0, "seed": int(seed), "fmu_name": "known_linear_system"}
        attrs.update({f"trim_{c}": float(v) for c, v in TRIM.items()})
        records.append(xr.Dataset(data, coords={"time": ("time", t, {"units": "s"})},
                                  attrs=attrs))
    return add_noise(records, noise, seed) if noise else records


def add_noise(records, noise: float, seed: int) -> list[xr.Dataset]:
    """Copies of ``records`` with white Gaussian noise of ``noise * NOISE_STD`` added to the
    measurements; record ``i`` uses seed ``seed * 1000 + i``."""
    out = []
    for i, rec in enumerate(records):
        rng = np.random.default_rng(seed * 1000 + i)
        rec = rec.copy()
        for s in STATES_6DOF:
            if s in rec:
                e = noise * NOISE_STD[s] * rng.standard_normal(rec.sizes["time"])
                rec[s] = rec[s].copy(data=rec[s].values + e)
        rec.attrs["seed"] = int(seed)
        out.append(rec)
    return out


assert tuple(STATES_6DOF) == tuple(truth_structure().states)


def time_domain_bound_ratios(structure, records_of_seed, seeds):
    """Monte Carlo of the time-domain fit from the true values: seed-to-seed scatter of each
    estimate over the mean white-noise and the mean coloured-residual (corrected) Cramer-Rao
    bound, ``{"white": {name: ratio}, "corrected": {...}}`` (1 = calibrated), the mean
    bounds ``{"white": array, "corrected": array}`` and the last fit."""
    estimates, white, corrected = [], [], []
    for seed in seeds:
        result = identify_time_domain(records_of_seed(seed), structure,
                                      start=structure.theta0, reduce=False, tol=1e-6)
        estimates.append(result.theta)
        white.append(result.statistics.cramer_rao)
        corrected.append(result.model["cramer_rao_corrected"].sel(
            parameter=list(structure.free_names)).values)
    scatter = np.std(estimates, axis=0, ddof=1)
    means = {"white": np.mean(white, axis=0), "corrected": np.mean(corrected, axis=0)}
    ratios = {kind: dict(zip(structure.free_names, scatter / bound))
              for kind, bound in means.items()}
    return ratios, means, result
