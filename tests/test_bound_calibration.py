"""Monte Carlo calibration of the reported bounds on known linear systems (issue 21).

Over noise seeds, each estimate's seed-to-seed scatter is set against the bound the fit
reports (ratio scatter / mean bound; 1 for an honest bound, goal 0.5-2), on systems whose
truth is exact, so a miss is the bound's convention and not the data's model.

Frequency domain (``tests/trust_system.py``: the coupled, stabilised 4-input hover plant with
delays and white measurement noise; the true structure fitted from the truth, no reduction):
the CIFER bound (``H = G^T G``, unscaled) is not a standard deviation, it assumes residuals of
unit weighted variance (``J_ave`` near 40); these fits reach ``J_ave`` 0.3-1.1 and scatter
far less than it says, by a factor that follows the noise level (not a constant such as
``sqrt 2``). The bound scaled by the fit's residuals (``cramer_rao_corrected``,
:func:`sysid.identify.frequency_domain.residual_scaled_bounds`) matches the scatter.

Time domain (``tests/known_systems.py``: the Bo-105-like hover system in closed loop with
3211s on every axis, output-error fit): with low-pass filtered (coloured) output noise the
white-noise Cramer-Rao bound is too small and the Morelli-Klein corrected bound matches.

Measured (docs/notes/2026-11-24-bound-convention-monte-carlo.md). The default suite runs a
reduced form of the frequency-domain check (a pooled check: the rms of the errors in bounds
over every parameter and seed; the time domain's reduced form is the two-state coloured-noise
Monte Carlo of tests/test_identify_time.py); ``-m slow`` the per-parameter ratios over 40
seeds in both domains.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

import known_systems as ks
import trust_system as ts
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.identify import identify_frequency_domain
from sysid.identify.frequency_domain import SELECTION_DRAWS
from sysid.spectral.response import frequency_response

GOAL = (0.5, 2.0)           #: scatter / mean bound of an honest bound (issue 21)
#: Pooled rms of the errors in bounds taken as calibrated in the reduced checks: within
#: 1.5x of 1 (a few seeds x many parameters; the slow checks hold each parameter to GOAL).
POOLED = (1 / 1.5, 1.5)


def frequency_domain_runs(seeds, noise: float = 1.0, selection_draws: int = 0):
    """Per seed: estimates, CIFER bounds, residual-scaled bounds and random-error bounds of
    the true structure fitted (from the truth, no reduction) to the default responses of the
    trust system; with ``selection_draws`` the random-error bounds include the point
    selection's scatter (``cramer_rao_total``)."""
    st = ts.structure()
    truth = ts.true_theta(st)
    est, cifer, scaled, noise_bounds = [], [], [], []
    variable = "cramer_rao_total" if selection_draws else "cramer_rao_noise"
    for seed in seeds:
        fr = frequency_response(ts.records(seed, noise=noise), CONTROLS, STATES_6DOF)
        result = identify_frequency_domain(fr, st, start=truth, reduce=False,
                                           selection_draws=selection_draws)
        est.append(result.theta)
        cifer.append(result.statistics.cramer_rao)
        scaled.append(result.model["cramer_rao_corrected"].sel(
            parameter=list(st.free_names)).values)
        assert np.allclose(result.scaled.cramer_rao, scaled[-1])
        noise_bounds.append(result.model[variable].sel(
            parameter=list(st.free_names)).values)
    return truth, np.array(est), np.array(cifer), np.array(scaled), np.array(noise_bounds)


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_frequency_domain_scaled_bounds_match_the_errors_cifer_bounds_are_too_large():
    """Reduced form: 6 seeds x 28 parameters, errors against the truth in units of each
    bound. Measured on seeds 0-39 in blocks of 6: rms 1.00-1.14 in scaled bounds,
    1.15-1.19 in random-error bounds, 0.16-0.20 in CIFER bounds; on seeds 0-5 1.01 in the
    scoreboard's bounds (random error and point selection: the selection adds little on an
    exact structure, 0.07-0.17 of the random error in the median; 1.13 before the
    conditioned spectra were charged for the other inputs)."""
    truth, est, cifer, scaled, noise_bounds = frequency_domain_runs(
        range(6), selection_draws=SELECTION_DRAWS)
    z_scaled, z_cifer = (est - truth) / scaled, (est - truth) / cifer
    z_noise = (est - truth) / noise_bounds
    print(f"rms error in scaled bounds {_rms(z_scaled):.2f}, in random-error + selection "
          f"bounds {_rms(z_noise):.2f}, in CIFER bounds {_rms(z_cifer):.3f}")
    assert POOLED[0] <= _rms(z_scaled) <= POOLED[1]
    assert POOLED[0] <= _rms(z_noise) <= POOLED[1]
    assert _rms(z_cifer) < 0.5
    assert np.all(scaled < cifer)         # J_ave far below 40: the CIFER bound overstates


@pytest.mark.slow
def test_frequency_domain_bound_calibration_over_forty_seeds():
    """Per parameter over 40 seeds: the residual-scaled bound within GOAL of the scatter
    (measured 0.64-1.56), the CIFER bound below it for every parameter (0.10-0.25); at three
    times the noise the CIFER ratio grows (the bound hardly moves, the scatter does: median
    x1.72) while the scaled one stays near 1 (median 1.24). Before the conditioned spectra
    were charged for the other inputs: 0.61-1.57, 0.10-0.26, median 1.14 at 3x."""
    truth, est, cifer, scaled, _ = frequency_domain_runs(range(40))
    scatter = est.std(axis=0, ddof=1)
    ratio_scaled, ratio_cifer = scatter / scaled.mean(axis=0), scatter / cifer.mean(axis=0)
    names = ts.structure().free_names
    report = {"scaled": dict(zip(names, np.round(ratio_scaled, 2))),
              "cifer": dict(zip(names, np.round(ratio_cifer, 3)))}
    print(report)
    assert np.all((ratio_scaled >= GOAL[0]) & (ratio_scaled <= GOAL[1])), report
    assert np.all(ratio_cifer < GOAL[0]), report
    _, est3, cifer3, scaled3, _ = frequency_domain_runs(range(40), noise=3.0)
    scatter3 = est3.std(axis=0, ddof=1)
    growth = np.median(scatter3 / cifer3.mean(axis=0)) / np.median(ratio_cifer)
    ratio_scaled3 = scatter3 / scaled3.mean(axis=0)
    print(f"CIFER ratio x{growth:.2f} at 3x the noise; scaled {np.median(ratio_scaled3):.2f}")
    assert growth > 1.5
    assert GOAL[0] <= np.median(ratio_scaled3) <= GOAL[1]


#: Coloured output noise of the time-domain check: first-order low-pass filtered white noise
#: with this correlation time (s), standard deviation NOISE_LEVEL x known_systems.NOISE_STD.
CORRELATION_TIME = 0.5
NOISE_LEVEL = 3.0


def coloured_noise(records, seed: int, *, correlation_time: float = CORRELATION_TIME,
                   level: float = NOISE_LEVEL):
    """Copies of ``records`` with seeded low-pass filtered Gaussian noise (unit-variance
    filter ``sqrt(1 - a^2) / (1 - a z^-1)``, ``a = exp(-dt / correlation_time)``) on every
    measured state."""
    out = []
    for i, rec in enumerate(records):
        rng = np.random.default_rng(20_000 + 100 * seed + i)
        dt = float(rec.time[1] - rec.time[0])
        a = math.exp(-dt / correlation_time)
        rec = rec.copy()
        for s in STATES_6DOF:
            e = scipy.signal.lfilter([math.sqrt(1.0 - a * a)], [1.0, -a],
                                     rng.standard_normal(rec.sizes["time"]))
            rec[s] = rec[s].copy(data=rec[s].values + level * ks.NOISE_STD[s] * e)
        out.append(rec)
    return out


@pytest.mark.slow
def test_time_domain_corrected_bounds_match_the_scatter_of_coloured_noise():
    """The closed-loop 6-DoF system, four 15-s 3211 records, coloured output noise, 40 seeds:
    the white-noise bound is several times too small for every parameter, the Morelli-Klein
    corrected bound within GOAL of the scatter. Measured: white 4.2-8.0, corrected 1.02-1.70
    (median 1.34: slightly optimistic, the truncated lag sum of short records)."""
    st = ks.truth_structure()
    clean = ks.multistep_records(noise=0.0, duration=15.0)
    ratios, _, _ = ks.time_domain_bound_ratios(st, lambda seed: coloured_noise(clean, seed),
                                               range(40))
    ratio_white = np.array(list(ratios["white"].values()))
    ratio_corrected = np.array(list(ratios["corrected"].values()))
    report = {kind: {k: round(float(v), 2) for k, v in r.items()} for kind, r in ratios.items()}
    print(report)
    assert np.all(ratio_white > GOAL[1]), report
    assert np.all((ratio_corrected >= GOAL[0]) & (ratio_corrected <= GOAL[1])), report
