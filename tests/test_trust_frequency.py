"""Trustworthy estimates by default (issue 21) on a system the project did not fly itself.

The test bed (``tests/trust_system.py``): a coupled 6-DoF-like hover plant with an unstable
pitch-roll oscillation and four input delays, stabilised by a loose state feedback on every
control (so the recorded controls are correlated), flown with seeded sweeps and measured with
white noise; every record is an exact periodic steady state, so the plant's analytic
open-loop response is the truth.

Must show: the *default* composite responses (leakage-free conditioning on) are within
0.3 dB / 2 deg median error of the analytic response over 0.7-15 rad/s for every pair with
partial coherence >= 0.6 (a pair counts when it meets 0.6 over at least half of that band;
the median runs over the points that meet it), and the frequency-domain fit of the true
structure (``tests/structures/coupled_hover_8state.toml``, neutral start values) lands every
parameter within 3 bounds of the truth. Without leakage conditioning both fail (the tests
check that too, so they can see the difference). Responses measured
(docs/notes/2026-11-24-leakage-free-by-default.md): seeds 0-7, 8 of 8 pass.

The fit is judged on the calibrated bound, the one the fidelity scoreboard uses
(``cramer_rao_total``: the spectral random error, 0.74-1.59 times the scatter over 40 seeds,
tests/test_bound_calibration.py, and the point selection's scatter, 0.07-0.17 of it here in
the median, in quadrature), not on the CIFER bound, which is 4-10 times the scatter on this
system (errors within 0.25-0.50 CIFER bounds, seeds 0-7). Measured on the calibrated bound,
seeds 0-7, with the conditioned spectra charged for the other inputs' degrees of freedom
(docs/notes/2026-11-26-conditioning-inputs-charged.md): the rms error is 0.60-1.17 bounds
per seed (0.98 over all 224), 7 of the 8 seeds land every parameter within 3 bounds (5 of 8
before the charge); seed 2 misses with X_q 3.50 and Y_ped 3.002. These are the tails of an
unbiased estimate whose calibrated bound is optimistic for a few parameters, not bias: that
seed is a strict xfail of the within-3-bounds check, and every seed must keep the rms within
the calibration goal (the bound within a factor 2 of the error).
"""

from __future__ import annotations

import os

import numpy as np
import pytest

import trust_system as ts
from sysid.assess.comparison import CALIBRATED_BOUND
from sysid.core.guidelines import BIAS_BOUNDS_MAX, COHERENCE_MIN
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.identify import identify_frequency_domain
from sysid.pipeline.batch import CALIBRATION_GOAL
from sysid.spectral.response import frequency_response

BAND = (0.7, 15.0)                  #: rad/s, where the responses are judged
MAX_DB, MAX_DEG = 0.3, 2.0          #: median error tolerated (issue 21)
OUTPUTS = ("u", "v", "w", "p", "q", "r", "phi", "theta")
#: Seeds whose fit lands a parameter beyond 3 calibrated bounds (module docstring): the tails
#: of an unbiased estimate, not a bias.
TAIL_SEEDS = {2: "X_q 3.50, Y_ped 3.002"}
#: Seeds of the several-seed check: all 8 with SYSID_EXHAUSTIVE=1, one more otherwise.
SEEDS = [pytest.param(s, marks=pytest.mark.xfail(
    strict=True, reason=f"beyond 3 calibrated bounds: {TAIL_SEEDS[s]}")) if s in TAIL_SEEDS
    else s for s in (range(1, 8) if os.environ.get("SYSID_EXHAUSTIVE") == "1" else (1,))]


def pair_errors(fr) -> dict[str, tuple[float, float, int]]:
    """``"out/in" -> (median |dB error|, median |deg error|, points)`` against the analytic
    response, for the pairs coherent (>= 0.6) over at least half of :data:`BAND`."""
    w = fr.frequency.values
    band = (w >= BAND[0]) & (w <= BAND[1])
    G = ts.analytic(w)
    out = {}
    for o in OUTPUTS:
        for i in CONTROLS:
            H = fr.H.sel(output=o, input=i).values
            coherent = band & (fr.partial_coherence.sel(output=o, input=i).values
                               >= COHERENCE_MIN) & np.isfinite(H)
            if coherent.sum() < 0.5 * band.sum():
                continue
            ratio = H[coherent] / G.sel(output=o, input=i).values[coherent]
            out[f"{o}/{i}"] = (float(np.median(np.abs(20 * np.log10(np.abs(ratio))))),
                               float(np.median(np.abs(np.angle(ratio, deg=True)))),
                               int(coherent.sum()))
    return out


def failing(errors) -> dict:
    return {k: v for k, v in errors.items() if v[0] > MAX_DB or v[1] > MAX_DEG}


def fit_errors_in_bounds(fr) -> tuple[dict[str, float], object]:
    """The true structure fitted from its neutral TOML values: ``name -> |error| / bound``
    with the calibrated bound (the fidelity scoreboard's)."""
    st = ts.structure()
    result = identify_frequency_domain(fr, st, reduce=False)
    truth = ts.true_theta(st)
    names = list(result.structure.free_names)
    bound = result.model[CALIBRATED_BOUND["frequency_domain"]].sel(parameter=names).values
    assert np.all(np.isfinite(bound) & (bound > 0)), dict(zip(names, bound))
    z = np.abs(result.theta - truth) / bound
    return dict(zip(names, z)), result


def rms(z: dict[str, float]) -> float:
    return float(np.sqrt(np.mean(np.square(list(z.values())))))


@pytest.fixture(scope="module")
def fitted(flown):
    """Seed 0's fit of the true structure (default start) and its errors in bounds."""
    _, fr = flown
    return fit_errors_in_bounds(fr)


@pytest.fixture(scope="module")
def flown():
    """Seed 0: records and the default (leakage-free) composite responses."""
    records = ts.records(0)
    return records, frequency_response(records, CONTROLS, STATES_6DOF)


def test_default_responses_are_leakage_free_and_match_the_analytic_plant(flown):
    records, fr = flown
    assert fr.attrs["transient_choice"] == "auto"
    assert list(fr.attrs["transient_states"]) == list(OUTPUTS)      # psi is not used
    errors = pair_errors(fr)
    print({k: (round(a, 3), round(b, 2), n) for k, (a, b, n) in errors.items()})
    assert all(p in errors for p in ("q/lon", "p/lat", "w/col", "r/ped"))
    assert len(errors) >= 12
    assert not failing(errors), failing(errors)
    # the feedback moves every secondary control (8-55 % of the swept one's RMS) and
    # correlates the controls (pooled cross-coherence up to 0.37 lat-lon, 0.49 lat-ped)
    for rec in records:
        axis = rec.attrs["axis"]
        assert min(float(rec[c].std() / rec[axis].std()) for c in CONTROLS) > 0.08
    assert float(fr.cross_coherence.sel(input="lat", input_j="lon").max()) > 0.3
    assert float(fr.cross_coherence.sel(input="lat", input_j="ped").max()) > 0.4
    # the paper's plain conditioned estimate of the same records misses (the test can see it)
    plain = frequency_response(records, CONTROLS, list(OUTPUTS), transient_states=())
    plain_errors = pair_errors(plain)
    assert failing(plain_errors), plain_errors


def test_fit_of_the_true_structure_from_neutral_starts_is_unbiased_in_calibrated_bounds(
        fitted):
    """Default start (no truth available): the equation error of the leakage-free responses,
    from the structure's neutral values. The errors in calibrated bounds have an rms within
    the calibration goal (measured 1.15 on seed 0)."""
    z, result = fitted
    print({k: round(float(v), 2) for k, v in z.items()}, f"J_ave {result.J_ave:.2f}",
          f"rms {rms(z):.2f}")
    assert result.start == "equation_error"
    assert len(z) == 28
    assert rms(z) <= CALIBRATION_GOAL[1], z


def test_fit_of_the_true_structure_from_neutral_starts_lands_within_3_bounds(fitted):
    z, _ = fitted
    assert max(z.values()) <= BIAS_BOUNDS_MAX, {k: v for k, v in z.items() if v > 3}


def test_cifer_bounds_do_not_depend_on_the_number_of_fitted_points(flown):
    """The CIFER convention (docs/methods.md, "Accuracy"): the (20 / n_omega) normalisation
    makes the information matrix, hence the bounds, independent of how densely each pair is
    sampled; an unscaled least-squares Hessian would shrink them by sqrt(2) at twice the
    points."""
    _, fr = flown
    st = ts.structure()
    start = ts.true_theta(st)
    a = identify_frequency_domain(fr, st, start=start, reduce=False, n_points=20)
    b = identify_frequency_domain(fr, st, start=start, reduce=False, n_points=40)
    ratio = b.statistics.cramer_rao / a.statistics.cramer_rao
    print(f"CR(40 points) / CR(20 points): {ratio.min():.3f}..{ratio.max():.3f}")
    assert np.all(np.abs(ratio - 1.0) < 0.1)


@pytest.mark.slow
@pytest.mark.parametrize("seed", SEEDS)
def test_several_seeds_default_responses_and_fit(seed):
    records = ts.records(seed)
    fr = frequency_response(records, CONTROLS, STATES_6DOF)
    errors = pair_errors(fr)
    assert len(errors) >= 12 and not failing(errors), failing(errors)
    z, _ = fit_errors_in_bounds(fr)
    # without leakage conditioning the same fit is biased beyond its bounds
    plain = frequency_response(records, CONTROLS, STATES_6DOF, transient_states=())
    z_plain, _ = fit_errors_in_bounds(plain)
    assert max(z_plain.values()) > BIAS_BOUNDS_MAX
    assert rms(z) <= CALIBRATION_GOAL[1], z
    assert max(z.values()) <= BIAS_BOUNDS_MAX, {k: v for k, v in z.items() if v > 3}


def test_time_domain_start_comes_from_the_leakage_free_responses(flown):
    """Without a truth linearisation or a frequency-domain model, the time-domain fit starts
    from the equation error of the campaign's (leakage-free) responses, not from the
    structure's neutral values."""
    import xarray as xr

    from sysid.data.campaign import CampaignData
    from sysid.identify.stages import _start_source, start_values

    records, fr = flown
    tree = xr.DataTree.from_dict({**{f"maneuvers/{r.attrs['maneuver']}": r for r in records},
                                  "frequency_response": fr})
    data = CampaignData(tree, source="trust_system")
    st = ts.structure()
    start = start_values(data, st, "auto", fit="time_domain")
    assert isinstance(start, np.ndarray)
    assert _start_source(data, start, "time_domain") == "equation error of /frequency_response"
    truth, neutral = ts.true_theta(st), st.theta0
    dominant = [st.free_names.index(n) for n in ("Z_w", "L_p", "M_q", "N_r", "Z_col", "L_lat",
                                                  "M_lon", "N_ped")]
    err = np.abs(start[dominant] - truth[dominant]) / np.abs(truth[dominant])
    print(dict(zip(np.asarray(st.free_names)[dominant], np.round(err, 3))))
    assert np.all(err < 0.2)
    # the neutral values are far off (on average; Z_col's -1 happens to be close)
    assert np.mean(np.abs(neutral[dominant] - truth[dominant]) / np.abs(truth[dominant])) > 0.5
