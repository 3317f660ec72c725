"""A correlated, stabilised 4-input linear hover-like system with delays and noise, flown with
seeded sweeps: the test bed of the leakage-free responses and the fit's bounds (issue 21).

The plant is a coupled 6-DoF-like quasi-steady model of its own (not Padfield's Bo-105 and
not any data set of the project): 8 rigid-body states ``u v w p q r phi theta`` (plus the
heading, on which nothing depends), 4 inputs, an unstable pitch-roll oscillation
(0.19 +- 0.51j 1/s) and four input delays (30-90 ms). Its true structure, with neutral start
values, is ``tests/structures/coupled_hover_8state.toml``; :data:`TRUE` holds the truth.

Flight: each record sweeps one axis (Tischler's exponential sweep, 0.3-20 rad/s, seeded start
phase, faded in and out) on top of a loose state feedback on all four controls (LQR; the swept
axis keeps half of its own loop, as a pilot would): the feedback correlates the recorded
controls, which are the totals. A small seeded random remnant moves every control, and white
Gaussian noise (seeded) is added to every measured state.

Exactness: every record is one period of a periodic steady state computed in the frequency
domain, ``U = (I - K G)^-1 R`` and ``X = G U`` on the record's DFT lines with the analytic
``G(j omega)`` of the delayed plant (:meth:`LinearStructure.frequency_response`), so the data
carry no discretisation or delay-approximation error: ``G`` is the exact truth to compare the
estimated responses against. Segments of a record still start and end mid-response, which is
the leakage the transient terms remove. No process noise: with feedback it would correlate the
inputs with the output disturbance (the closed-loop bias), a different problem.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.units import CHANNELS, CONTROLS
from sysid.models import load_structure

STRUCTURE_FILE = Path(__file__).parent / "structures" / "coupled_hover_8state.toml"
TRIM = {"theta": 4.0, "phi": -2.0}  #: trim attitudes, deg (kinematic terms of the model)
#: The truth, analysis units (ft/s, deg/s, deg, %, s).
TRUE = dict(X_u=-0.035, X_q=0.06, Y_v=-0.06, Y_p=-0.05, Z_w=-0.45, L_u=3.0, L_v=-4.5,
            L_p=-8.0, M_u=1.1, M_v=0.8, M_q=-2.2, N_w=0.35, N_p=-1.2, N_r=-0.45,
            X_lon=-0.09, Y_ped=0.07, Z_col=-0.95, L_lon=-5.0, L_lat=-12.0, M_lon=5.0,
            M_lat=-1.3, N_col=2.2, N_lat=-2.0, N_ped=-3.4,
            tau_M_lon=0.09, tau_L_lat=0.06, tau_col=0.03, tau_ped=0.05)
#: Measurement-noise standard deviations (ft/s, deg/s, deg).
NOISE_STD = {"u": 0.2, "v": 0.2, "w": 0.2, "p": 0.4, "q": 0.4, "r": 0.4,
             "phi": 0.1, "theta": 0.1, "psi": 0.1}
SWEEP_AMPLITUDE = {"lon": 6.0, "lat": 6.0, "col": 5.0, "ped": 6.0}  #: %
ON_AXIS = (("q", "lon"), ("p", "lat"), ("w", "col"), ("r", "ped"))


def structure():
    """The true structure about :data:`TRIM`, start values neutral (from its TOML file)."""
    return load_structure(STRUCTURE_FILE, trim=TRIM)


def true_theta(st=None) -> np.ndarray:
    st = structure() if st is None else st
    return np.array([TRUE[n] for n in st.free_names])


def feedback_gain(st=None) -> np.ndarray:
    """Loose LQR state feedback ``u = K x`` (4 x 9) on the delay-free plant."""
    import control  # deferred: only the flight of the test records needs python-control

    st = structure() if st is None else st
    A, B, _, _, _ = st.matrices(true_theta(st))
    Q = np.diag([1e-2] * 3 + [1e-3] * 3 + [1e-1] * 2 + [1e-2])
    return -np.asarray(control.lqr(A, B, Q, np.eye(4))[0])


def sweep(t: np.ndarray, *, omega_min: float = 0.3, omega_max: float = 20.0,
          phase: float = 0.0, fade: float = 2.0) -> np.ndarray:
    """Unit-amplitude exponential sweep ``omega = omega_min + K (omega_max - omega_min)``,
    ``K = 0.0187 (exp(4 t / T) - 1)`` (Tischler's), faded in and out over ``fade`` s."""
    T = t[-1] + (t[1] - t[0])
    K = 0.0187 * (np.exp(4.0 * t / T) - 1.0)
    omega = omega_min + K * (omega_max - omega_min)
    angle = phase + np.cumsum(omega) * (t[1] - t[0])
    ramp = np.clip(np.minimum(t, T - t) / fade, 0.0, 1.0)
    return np.sin(angle) * ramp


def records(seed: int = 0, *, duration: float = 100.0, dt: float = 0.02,
            records_per_axis: int = 2, noise: float = 1.0,
            remnant: float = 0.3) -> list[xr.Dataset]:
    """Seeded closed-loop sweep records (absolute channels with ``trim_<channel>`` attrs).

    ``noise`` scales :data:`NOISE_STD`; ``remnant`` is the RMS (%) of the random remnant on
    every control (band-limited to 0.2-10 rad/s).
    """
    st = structure()
    theta = true_theta(st)
    K = feedback_gain(st)
    n = int(round(duration / dt))
    t = np.arange(n) * dt
    w = 2.0 * np.pi * np.fft.rfftfreq(n, dt)
    G = np.zeros((len(st.states), 4, w.size), complex)
    G[..., 1:] = st.frequency_response(w[1:], theta).values        # DC line unused (no mean)
    rng = np.random.default_rng(seed)
    out = []
    for axis in CONTROLS:
        for k in range(records_per_axis):
            gain = K.copy()
            gain[CONTROLS.index(axis)] *= 0.5       # the swept axis keeps half of its loop
            r = np.zeros((4, n))
            r[CONTROLS.index(axis)] = SWEEP_AMPLITUDE[axis] * sweep(
                t, phase=rng.uniform(0, 2 * np.pi))
            lines = np.where((w > 0.2) & (w < 10.0), 1.0, 0.0)
            for j in range(4):
                c = lines * np.exp(2j * np.pi * rng.random(w.size))
                x = np.fft.irfft(c, n)
                r[j] += remnant * x / x.std()
            R = np.fft.rfft(r, axis=1)
            R[:, 0] = 0.0
            loop = np.eye(4)[None] - np.einsum("ij,jkf->fik", gain, G)   # (f, 4, 4)
            U = np.linalg.solve(loop, R.T[:, :, None])[:, :, 0].T           # (4, f)
            X = np.einsum("skf,kf->sf", G, U)
            u = np.fft.irfft(U, n, axis=1)
            x = np.fft.irfft(X, n, axis=1)
            data = {c: ("time", u[j], {"units": CHANNELS[c].unit}) for j, c in enumerate(CONTROLS)}
            for i, s in enumerate(st.states):
                e = noise * NOISE_STD[s] * rng.standard_normal(n)
                data[s] = ("time", TRIM.get(s, 0.0) + x[i] + e, {"units": CHANNELS[s].unit})
            name = f"sweep_{axis}_{k + 1}"
            attrs = {"maneuver": name, "kind": "sweep", "axis": axis, "seed": int(seed)}
            attrs.update({f"trim_{c}": 0.0 for c in CONTROLS})
            attrs.update({f"trim_{s}": float(TRIM.get(s, 0.0)) for s in st.states})
            out.append(xr.Dataset(data, coords={"time": ("time", t, {"units": "s"})},
                                  attrs=attrs))
    return out


def analytic(frequency) -> xr.DataArray:
    """The open-loop plant's exact response ``(output, input, frequency)`` (delays included)."""
    st = structure()
    return st.frequency_response(np.asarray(frequency, float), true_theta(st))
