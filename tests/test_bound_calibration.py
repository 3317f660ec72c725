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
reduced form of each (a pooled check: the rms of the errors in bounds over every parameter
and seed); ``-m slow`` the per-parameter ratios over 40 seeds.
"""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal

import known_systems as ks
import trust_system as ts
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.identify import identify_frequency_domain, identify_time_domain
from sysid.spectral.response import frequency_response

GOAL = (0.5, 2.0)           #: scatter / mean bound of an honest bound (issue 21)
#: Pooled rms of the errors in bounds taken as calibrated in the reduced checks: within
#: 1.5x of 1 (a few seeds x many parameters; the slow checks hold each parameter to GOAL).
POOLED = (1 / 1.5, 1.5)


def frequency_domain_runs(seeds, noise: float = 1.0):
    """Per seed: estimates, CIFER bounds and residual-scaled bounds of the true structure
    fitted (from the truth, no reduction) to the default responses of the trust system."""
    st = ts.structure()
    truth = ts.true_theta(st)
    est, cifer, scaled = [], [], []
    for seed in seeds:
        fr = frequency_response(ts.records(seed, noise=noise), CONTROLS, STATES_6DOF)
        result = identify_frequency_domain(fr, st, start=truth, reduce=False)
        est.append(result.theta)
        cifer.append(result.statistics.cramer_rao)
        scaled.append(result.model["cramer_rao_corrected"].sel(
            parameter=list(st.free_names)).values)
        assert np.allclose(result.scaled.cramer_rao, scaled[-1])
    return truth, np.array(est), np.array(cifer), np.array(scaled)


def _rms(x) -> float:
    return float(np.sqrt(np.mean(np.square(x))))


def test_frequency_domain_scaled_bounds_match_the_errors_cifer_bounds_are_too_large():
    """Reduced form: 6 seeds x 28 parameters, errors against the truth in units of each
    bound. Measured on seeds 0-39 in blocks of 6: rms 1.00-1.14 in scaled bounds,
    0.16-0.20 in CIFER bounds."""
    truth, est, cifer, scaled = frequency_domain_runs(range(6))
    z_scaled, z_cifer = (est - truth) / scaled, (est - truth) / cifer
    print(f"rms error in scaled bounds {_rms(z_scaled):.2f}, in CIFER bounds {_rms(z_cifer):.3f}")
    assert POOLED[0] <= _rms(z_scaled) <= POOLED[1]
    assert _rms(z_cifer) < 0.5
    assert np.all(scaled < cifer)         # J_ave far below 40: the CIFER bound overstates


@pytest.mark.slow
def test_frequency_domain_bound_calibration_over_forty_seeds():
    """Per parameter over 40 seeds: the residual-scaled bound within GOAL of the scatter, the
    CIFER bound below it for every parameter; at three times the noise the CIFER ratio grows
    (the bound hardly moves, the scatter does) while the scaled one stays."""
    truth, est, cifer, scaled = frequency_domain_runs(range(40))
    scatter = est.std(axis=0, ddof=1)
    ratio_scaled, ratio_cifer = scatter / scaled.mean(axis=0), scatter / cifer.mean(axis=0)
    names = ts.structure().free_names
    report = {"scaled": dict(zip(names, np.round(ratio_scaled, 2))),
              "cifer": dict(zip(names, np.round(ratio_cifer, 3)))}
    print(report)
    assert np.all((ratio_scaled >= GOAL[0]) & (ratio_scaled <= GOAL[1])), report
    assert np.all(ratio_cifer < GOAL[0]), report
    _, est3, cifer3, scaled3 = frequency_domain_runs(range(40), noise=3.0)
    scatter3 = est3.std(axis=0, ddof=1)
    growth = np.median(scatter3 / cifer3.mean(axis=0)) / np.median(ratio_cifer)
    ratio_scaled3 = scatter3 / scaled3.mean(axis=0)
    print(f"CIFER ratio x{growth:.2f} at 3x the noise; scaled {np.median(ratio_scaled3):.2f}")
    assert growth > 1.5
    assert np.all((ratio_scaled3 >= GOAL[0]) & (ratio_scaled3 <= GOAL[1]))
