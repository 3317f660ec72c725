"""The fidelity scoreboard (issue 21): each estimate's error against a known truth in units of
its own bound, flagged beyond 3 bounds; its text form (``sysid compare``) and its report
section with the guideline marks of the derivative tables.

The models are built by hand, so the expected errors in bounds are known exactly.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from test_identify_frequency import TRUE_DELAYS, analytic_response, truth_structure, truth_values

from sysid.assess.comparison import (BEYOND_MISFIT_REASON, BIAS_MEANING, BIAS_REASONS,
                                     DATA_REASON, MISFIT_REASON, STRUCTURE_REASON,
                                     compare_models, fidelity_scoreboard, format_scoreboard,
                                     quasi_steady_equivalents, truth_in_band)
from sysid.core.guidelines import BIAS_BOUNDS_MAX
from sysid.data.campaign import CampaignData
from sysid.identify.frequency_domain import identify_frequency_domain
from sysid.models import structure_from_dict

NAMES = ["Z_w", "M_q", "tau_M_lon"]
TRUTH = xr.Dataset({"value": ("parameter", [-0.30, -3.0])},
                   coords={"parameter": ["Z_w", "M_q"]})


def model(method, value, bound, corrected=None, free=(True, True, True), noise=None):
    ds = xr.Dataset({"value": ("parameter", np.asarray(value, float)),
                     "free": ("parameter", np.asarray(free)),
                     "cramer_rao": ("parameter", np.asarray(bound, float)),
                     "cramer_rao_percent": ("parameter",
                                            100 * np.abs(np.asarray(bound) / np.asarray(value)))},
                    coords={"parameter": NAMES}, attrs={"method": method})
    if corrected is not None:
        ds["cramer_rao_corrected"] = ("parameter", np.asarray(corrected, float))
    if noise is not None:
        ds["cramer_rao_noise"] = ("parameter", np.asarray(noise, float))
    return ds


def test_errors_are_measured_in_the_bound_each_model_reports():
    fd = model("frequency_domain", [-0.325, -3.9, 0.1], [0.01, 0.2, 0.01])
    # time domain: the corrected bound where finite, else the white-noise one
    td = model("time_domain", [-0.40, -3.1, 0.1], [0.01, 0.01, 0.01],
               corrected=[0.05, np.nan, 0.02])
    board = fidelity_scoreboard({"frequency_domain": fd, "time_domain": td}, TRUTH)
    z = board["error_in_bounds"]
    np.testing.assert_allclose(z.sel(model="frequency_domain", parameter="Z_w"), 2.5)
    np.testing.assert_allclose(z.sel(model="frequency_domain", parameter="M_q"), 4.5)
    np.testing.assert_allclose(z.sel(model="time_domain", parameter="Z_w"), 2.0)   # 0.1 / 0.05
    np.testing.assert_allclose(z.sel(model="time_domain", parameter="M_q"), 10.0)  # white bound
    kinds = board["bound_kind"].sel(parameter="Z_w").values.tolist()
    assert kinds == ["cifer", "corrected"]
    assert str(board["bound_kind"].sel(model="time_domain", parameter="M_q").values) == "white"
    flag = board["bias_flag"]
    # 2.5 and 2 bounds are within the threshold; 4.5 and 10 are beyond it
    assert not bool(flag.sel(model="frequency_domain", parameter="Z_w"))
    assert bool(flag.sel(model="frequency_domain", parameter="M_q"))
    assert bool(flag.sel(model="time_domain", parameter="M_q"))
    assert not bool(flag.sel(model="time_domain", parameter="Z_w"))
    # no truth for the delay: no error, no flag
    assert np.isnan(float(z.sel(model="time_domain", parameter="tau_M_lon")))
    assert not bool(flag.sel(parameter="tau_M_lon").any())
    assert board.attrs["bias_bounds_max"] == BIAS_BOUNDS_MAX == 3.0
    text = format_scoreboard(board)
    assert BIAS_MEANING in text and "flagged: frequency_domain 1, time_domain 1" in text
    row = next(line for line in text.splitlines() if line.startswith("M_q"))
    assert row.count("!") == 2


def test_a_parameter_one_model_does_not_estimate_is_left_blank():
    fd = model("frequency_domain", [-0.31, -3.5, 0.1], [0.01, 0.1, 0.01],
               free=(True, False, True))
    td = model("time_domain", [-0.31, -3.5, 0.1], [0.01, 0.1, 0.01])
    board = fidelity_scoreboard({"frequency_domain": fd, "time_domain": td}, TRUTH)
    assert np.isnan(float(board["value"].sel(parameter="M_q", model="frequency_domain")))
    assert not bool(board["bias_flag"].sel(parameter="M_q", model="frequency_domain"))
    assert bool(board["bias_flag"].sel(parameter="M_q", model="time_domain"))      # 5 bounds
    np.testing.assert_allclose(board["error_in_bounds"].sel(parameter="Z_w"), 1.0)
    # a parameter no model estimates is not on the board
    alone = fidelity_scoreboard({"frequency_domain": fd}, TRUTH)
    assert "M_q" not in alone.parameter.values


def test_frequency_domain_is_judged_on_the_random_error_bound_with_the_reason():
    """Frequency domain: the bound from the spectral random error (the one that matches the
    seed-to-seed scatter) where finite, else the residual-scaled one, else CIFER; a flag
    says whether the fit's own residuals (the structure's misfit) cover the error."""
    #                         Z_w: 0.025 off     M_q: 0.9 off       delay
    fd = model("frequency_domain", [-0.325, -3.9, 0.1], [0.05, 1.0, 0.01],
               corrected=[0.05, 0.2, 0.01], noise=[0.005, np.nan, 0.001])
    td = model("time_domain", [-0.40, -3.1, 0.1], [0.01, 0.01, 0.01],
               corrected=[0.02, 0.05, 0.02])
    board = fidelity_scoreboard({"frequency_domain": fd, "time_domain": td}, TRUTH)
    fd_board = board.sel(model="frequency_domain")
    # Z_w: 0.025 / 0.005 = 5 random-error bounds (flag), 0.5 residual-scaled bounds
    np.testing.assert_allclose(fd_board["error_in_bounds"].sel(parameter="Z_w"), 5.0)
    assert str(fd_board["bound_kind"].sel(parameter="Z_w").values) == "random_error"
    np.testing.assert_allclose(fd_board["cramer_rao"].sel(parameter="Z_w"), 0.05)
    assert str(fd_board["bias_reason"].sel(parameter="Z_w").values) == MISFIT_REASON
    # M_q: no random-error bound, so the residual-scaled one: 0.9 / 0.2 = 4.5 (flag)
    np.testing.assert_allclose(fd_board["error_in_bounds"].sel(parameter="M_q"), 4.5)
    assert str(fd_board["bound_kind"].sel(parameter="M_q").values) == "scaled"
    assert str(fd_board["bias_reason"].sel(parameter="M_q").values) == BIAS_MEANING
    # time domain: Z_w 0.1 / 0.02 = 5 corrected bounds, M_q 0.1 / 0.05 = 2 (no flag)
    td_board = board.sel(model="time_domain")
    assert str(td_board["bias_reason"].sel(parameter="Z_w").values) == BIAS_REASONS["corrected"]
    assert not bool(td_board["bias_flag"].sel(parameter="M_q"))
    assert str(td_board["bias_reason"].sel(parameter="M_q").values) == ""
    # an error beyond 3 residual-scaled bounds as well: not the misfit
    fd_far = model("frequency_domain", [-0.45, -3.0, 0.1], [0.05, 1.0, 0.01],
                   corrected=[0.04, 0.2, 0.01], noise=[0.005, 0.1, 0.001])
    far = fidelity_scoreboard({"frequency_domain": fd_far}, TRUTH)
    assert str(far["bias_reason"].sel(parameter="Z_w", model="frequency_domain").values) \
        == BEYOND_MISFIT_REASON
    assert not bool(far["bias_flag"].sel(parameter="M_q", model="frequency_domain"))
    text = format_scoreboard(board)
    assert "random_error" in text and MISFIT_REASON in text
    assert "frequency_domain: Z_w: " + MISFIT_REASON in text


def test_a_flag_s_reason_comes_from_the_truth_fitted_in_the_same_band():
    """With the truth fitted in the estimate's band known, a flagged estimate within 3 bounds
    of it is off by the structure's error, beyond them by the data's."""
    fd = model("frequency_domain", [-0.325, -3.9, 0.1], [0.005, 0.1, 0.01])
    names = {"parameter": NAMES, "model": ["frequency_domain"]}
    # Z_w 5 bounds, M_q 9 bounds off the truth: both flagged
    near = xr.DataArray([[-0.33], [-3.0], [np.nan]], dims=("parameter", "model"), coords=names)
    board = fidelity_scoreboard({"frequency_domain": fd}, TRUTH, in_band=near)
    cell = board.sel(model="frequency_domain")
    np.testing.assert_allclose(cell["band_error_in_bounds"].sel(parameter="Z_w"), 1.0)
    np.testing.assert_allclose(cell["band_error_in_bounds"].sel(parameter="M_q"), 9.0)
    assert str(cell["bias_reason"].sel(parameter="Z_w").values) == STRUCTURE_REASON
    assert str(cell["bias_reason"].sel(parameter="M_q").values) == DATA_REASON
    np.testing.assert_allclose(cell["truth_in_band"].sel(parameter="Z_w"), -0.33)
    # without it, the residual-based reasons as before
    plain = fidelity_scoreboard({"frequency_domain": fd}, TRUTH)
    assert np.isnan(plain["truth_in_band"]).all()
    assert str(plain["bias_reason"].sel(model="frequency_domain", parameter="Z_w").values) \
        == BIAS_MEANING


def test_truth_in_band_recovers_a_truth_the_structure_contains():
    """Known 6-DoF system whose structure contains the truth: the estimate from noisy
    responses is off by the noise, the structure fitted to the truth's exact responses at the
    estimate's own points returns the truth (so the scoreboard's band error is the whole
    error); for a time-domain model or without a linearisation there is none."""
    st = truth_structure()
    values = truth_values()
    truth = st.to_dataset(attrs={"method": "linearization"})
    measured = analytic_response(st, noise=0.05, seed=4)
    estimate = identify_frequency_domain(measured, st, reduce=False).model
    groups = {"frequency_response": xr.DataTree(measured),
              "models/frequency_domain": xr.DataTree(estimate)}
    without = CampaignData(xr.DataTree.from_dict(groups), source="no truth")
    data = CampaignData(xr.DataTree.from_dict({**groups, "linearization": xr.DataTree(truth)}),
                        source="known system")
    band = truth_in_band(data, estimate)
    errors = {n: abs(float(band["value"].sel(parameter=n)) / values[n] - 1) for n in values
              if n not in TRUE_DELAYS}
    assert max(errors.values()) < 1e-4, errors
    for name, tau in TRUE_DELAYS.items():
        assert abs(float(band["value"].sel(parameter=name)) - tau) < 1e-4
    off = max(abs(float(estimate["value"].sel(parameter=n)) / values[n] - 1) for n in errors)
    assert off > 1e-3  # the noise did move the estimate
    table = compare_models(data)
    fd = table.sel(model="frequency_domain")
    np.testing.assert_allclose(fd["band_error_in_bounds"], fd["error_in_bounds"], rtol=1e-3,
                               atol=1e-3)
    assert truth_in_band(without, estimate) is None
    assert truth_in_band(data, estimate.assign_attrs(method="time_domain")) is None
    # a band fit that cannot run (here no point reaches the coherence limit) leaves the table
    # without it and says why
    broken = estimate.assign_attrs(coherence_min=0.99)
    tree = data.tree.copy()
    tree["models/frequency_domain"] = xr.DataTree(broken)
    table = compare_models(CampaignData(tree, source="broken"))
    assert np.isnan(table["truth_in_band"]).all()
    assert "coheren" in table.attrs["truth_in_band_failed"]
    assert table["error_in_bounds"].notnull().any()


# --- Quasi-steady equivalents of a higher-order model ----------------------------------------

FLAP = {"states": ["p", "phi", "b1"], "inputs": ["lat"], "outputs": ["p", "phi"],
        "A": {"L_p": -1.5, "L_b1": 150.0, "b1,b1": -14.0, "phi,p": {"value": 1.0, "free": False},
              "b1,p": {"value": -1.0, "free": False}},
        "B": {"L_lat": 0.5, "b1,lat": 12.0}}
RIGID = {"states": ["p", "phi"], "inputs": ["lat"], "outputs": ["p", "phi"],
         "A": {"L_p": -10.0, "phi,p": {"value": 1.0, "free": False}}, "B": {"L_lat": 10.0}}


def test_quasi_steady_equivalents_of_a_flapping_model_and_their_bounds():
    """Roll with first-order flapping, b1' = A_bb b1 - p + B_b lat, residualised: the
    equivalents are L_p + L_b1 / A_bb and L_lat - L_b1 B_b / A_bb (b1 = (p - B_b lat) / A_bb),
    and their bounds the first-order propagation with the analytic gradients."""
    hybrid = structure_from_dict(FLAP, source="flap")
    theta = np.array([-1.2, 160.0, -12.5, 0.3, 11.0])
    names = list(hybrid.free_names)
    assert names == ["L_p", "L_b1", "A[b1,b1]", "L_lat", "B[b1,lat]"]
    Lp, Lb, Abb, Llat, Bb = theta
    sigma = np.array([0.05, 4.0, 0.6, 0.02, 0.5])
    R = np.eye(5)
    R[1, 2] = R[2, 1] = 0.8      # flapping spring and time constant correlated, as in fits
    R[0, 1] = R[1, 0] = -0.3
    m = hybrid.to_dataset(theta)
    at = [list(m.parameter.values).index(n) for n in names]  # fixed entries are parameters too

    def over_all(v):
        full = np.full(m.sizes["parameter"], np.nan)
        full[at] = v
        return ("parameter", full)

    m["cramer_rao"] = over_all(sigma)
    m["cramer_rao_corrected"] = over_all(2 * sigma)
    corr = np.full((m.sizes["parameter"],) * 2, np.nan)
    corr[np.ix_(at, at)] = R
    m["correlation"] = (("parameter", "parameter_j"), corr)
    rigid = structure_from_dict(RIGID, source="rigid").to_dataset()
    eq = quasi_steady_equivalents(m, rigid)
    assert list(eq.parameter.values) == ["L_p", "L_lat"]
    assert eq.attrs["residualized"] == "b1"
    np.testing.assert_allclose(eq["value"].values, [Lp + Lb / Abb, Llat - Lb * Bb / Abb],
                               rtol=1e-12)
    G = np.array([[1.0, 1 / Abb, -Lb / Abb ** 2, 0.0, 0.0],
                  [0.0, -Bb / Abb, Lb * Bb / Abb ** 2, 1.0, -Lb / Abb]])
    for name, s in (("cramer_rao", sigma), ("cramer_rao_corrected", 2 * sigma)):
        cov = G @ (np.outer(s, s) * R) @ G.T
        np.testing.assert_allclose(eq[name].values, np.sqrt(np.diag(cov)), rtol=1e-6)
    assert "cramer_rao_total" not in eq  # only the bounds the model has
    # a bound the model could not give (NaN) leaves the equivalents that depend on it NaN
    m["cramer_rao"] = over_all(np.array([0.05, 4.0, 0.6, 0.02, np.nan]))
    eq = quasi_steady_equivalents(m, rigid, names=["L_p", "L_lat"])
    assert np.isfinite(eq["cramer_rao"].sel(parameter="L_p")) and np.isnan(
        eq["cramer_rao"].sel(parameter="L_lat"))
