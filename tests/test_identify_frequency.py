"""Frequency-domain identification against a known hover-like 6-DoF system.

The truth is Padfield's Helisim Bo-105 hover model (docs/methods.md, "The truth helicopter") converted to
analysis units, with the kinematic terms of the paper's hover trim (theta0 6.76 deg,
phi0 -2.87 deg) and the paper's delays on the lon -> p (0.2 s) and lat -> q (0.1 s) B entries.
Derivatives that the paper's 13 pairs cannot determine to the 20 % Cramer-Rao guideline are
absent from the truth (zero), so every true parameter is identifiable and the model
reduction has a well-defined answer.
"""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
import xarray as xr

from sysid.core.errors import IdentificationError
from sysid.identify import (DEFAULT_PAIRS, cifer_cost, coherence_weight, equation_error_start,
                            identify_frequency_domain, parameter_statistics, select_fit_data)
from sysid.identify.frequency_domain import (W_G, W_P, FitData, _Problem,
                                             coherence_correlation_width,
                                             coherence_random_error, perturbed_coherence,
                                             response_jacobian, response_residuals)
from sysid.identify.statistics import OUTLYING_SCALES, robust_scale
from sysid.models import simulate, six_dof_structure, structure_from_dict
from sysid.core.units import DEG, FT

# Padfield, Helisim Bo-105 hover, SI and rad (Helicopter Flight Dynamics; docs/methods.md).
_STABILITY_SI = dict(X_q=0.7086, Z_w=-0.3220, M_u=0.1045, M_q=-3.7472, M_v=0.0900,
                     Y_p=-0.7365, L_u=0.3402, L_v=-0.4114, L_p=-14.1949, N_u=0.0607,
                     N_p=-2.4296, N_r=-0.3185)
# Control derivatives per rad of blade angle: columns theta_0 (col), theta_1s (lon),
# theta_1c (lat), theta_0TR (ped).
_CONTROL_SI = {"X": {"lon": -8.477}, "Z": {"col": -92.96},
               "M": {"col": -5.682, "lon": 44.997, "lat": -17.559},
               "Y": {"lat": -8.477, "ped": 5.043},
               "L": {"col": 4.993, "lon": -66.37, "lat": -170.08},
               "N": {"col": 19.73, "lon": -11.80, "lat": -30.24, "ped": -15.46}}
# Stick gearing, rad of blade angle per % of travel (GARTEUR AG-06 control ranges / 100, docs/methods.md).
_GEARING = {"lon": 0.155 * DEG, "lat": 0.100 * DEG, "col": 0.160 * DEG, "ped": 0.240 * DEG}
TRUE_DELAYS = {"tau_L_lon": 0.2, "tau_M_lat": 0.1}
DELAY_ENTRIES = {"tau_L_lon": "p,lon", "tau_M_lat": "q,lat"}
THETA0, PHI0 = 6.76, -2.87
#: Entries that are zero in the truth, freed as spurious parameters in the reduction test.
SPURIOUS = ("X_u", "Y_v", "Z_u", "X_w", "L_q", "M_w", "M_p", "N_v", "L_ped", "Y_r")


def truth_values() -> dict[str, float]:
    """Named derivatives of the truth in analysis units (ft/s, deg/s, deg, %)."""
    values = {}
    for name, x in _STABILITY_SI.items():
        row, col = name.split("_")
        factor = 1.0
        if row in "XYZ" and col in "pqr":  # m/s^2 per rad/s -> ft/s^2 per deg/s
            factor = DEG / FT
        if row in "LMN" and col in "uvw":  # rad/s^2 per m/s -> deg/s^2 per ft/s
            factor = FT / DEG
        values[name] = x * factor
    for row, entries in _CONTROL_SI.items():
        for col, x in entries.items():
            values[f"{row}_{col}"] = x * _GEARING[col] / (FT if row in "XYZ" else DEG)
    values.update(TRUE_DELAYS)
    return values


def truth_structure(extra_free=(), values=None):
    """The truth as a 6-DoF structure whose free parameters are the true ones (+ extras)."""
    values = dict(truth_values() if values is None else values)
    free = [k for k in values if k not in TRUE_DELAYS] + list(extra_free)
    return six_dof_structure(theta0=THETA0, phi0=PHI0, free=free, values=values,
                             delays=DELAY_ENTRIES)


def analytic_response(structure, theta=None, *, noise=0.0, seed=0, band=(0.3, 20.0),
                      gamma2=0.9, n_frequency=300):
    """Composite-like Dataset of the exact response, coherence ``gamma2`` in ``band`` and 0.2
    outside; optional multiplicative complex noise of relative RMS ``noise`` (seeded)."""
    omega = np.logspace(-1, 1.6, n_frequency)
    T = structure.frequency_response(omega, theta).values
    g2 = np.where((omega >= band[0]) & (omega <= band[1]), gamma2, 0.2)
    g2 = np.broadcast_to(g2, T.shape).copy()
    if noise:
        rng = np.random.default_rng(seed)
        T = T * (1.0 + noise / math.sqrt(2.0) * (rng.standard_normal(T.shape)
                                                 + 1j * rng.standard_normal(T.shape)))
    dims = ("output", "input", "frequency")
    return xr.Dataset(
        {"H": (dims, T), "partial_coherence": (dims, g2), "coherence": (dims, g2),
         "random_error": (dims, np.full(T.shape, noise))},
        coords={"output": list(structure.outputs), "input": list(structure.inputs),
                "frequency": omega},
        attrs={"trim_theta": THETA0, "trim_phi": PHI0},
    )


def _relative_errors(result, values):
    return {n: (result.value(n) - values[n]) / abs(values[n]) for n in values}


# ---------------------------------------------------------------------------------------------


def test_coherence_weight_is_cifer_formula():
    g2 = np.array([0.0, 0.36, 0.6, 1.0])
    expected = (1.58 * (1.0 - np.exp(-g2))) ** 2  # gamma^2 not squared again
    np.testing.assert_allclose(coherence_weight(g2), expected, rtol=0, atol=1e-15)
    assert coherence_weight(0.6) != pytest.approx((1.58 * (1 - math.exp(-0.36))) ** 2)


def test_cost_matches_hand_computed_formula():
    st = truth_structure()
    fr = analytic_response(st)
    data = select_fit_data(fr, "q/lon,p/lat")
    theta = st.theta0 * 1.1
    costs = cifer_cost(st, data, theta)
    for pair in ("q/lon", "p/lat"):
        out, inp = pair.split("/")
        lo, hi = data.ranges[pair]
        w = np.exp(np.linspace(math.log(lo), math.log(hi), 20))
        Tc = st.frequency_response(w).sel(output=out, input=inp).values
        T = st.frequency_response(w, theta).sel(output=out, input=inp).values
        dmag = 20 * np.log10(np.abs(Tc)) - 20 * np.log10(np.abs(T))
        dph = (np.degrees(np.angle(Tc) - np.angle(T)) + 180) % 360 - 180
        wg = (1.58 * (1 - np.exp(-0.9))) ** 2
        J = 20 / 20 * np.sum(wg * (dmag ** 2 + 0.01745 * dph ** 2))
        assert costs[pair] == pytest.approx(J, rel=1e-6)
    assert costs["J_ave"] == pytest.approx((costs["q/lon"] + costs["p/lat"]) / 2)


def test_fit_range_follows_coherence():
    st = truth_structure()
    fr = analytic_response(st, band=(0.5, 12.0))
    data = select_fit_data(fr)
    omega = fr.frequency.values
    inside = omega[(omega >= 0.5) & (omega <= 12.0)]
    for pair in DEFAULT_PAIRS:
        assert data.ranges[f"{pair[0]}/{pair[1]}"] == (inside[0], inside[-1])
    assert len(data.omega) == 20 * len(DEFAULT_PAIRS)


def test_analytic_jacobian_matches_finite_differences():
    st = truth_structure(extra_free=("Z_u", "L_ped"))
    fr = analytic_response(st)
    prob = _Problem(st, select_fit_data(fr))
    theta = st.theta0 + 0.05
    G = prob.jacobian(theta)
    for j in range(len(theta)):
        h = 1e-6 * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (prob.residuals(tp) - prob.residuals(tm)) / (2 * h)
        np.testing.assert_allclose(G[:, j], fd, rtol=1e-5, atol=1e-6 * np.abs(G).max())


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_noise_free_recovery_from_perturbed_start(seed):
    st = truth_structure()
    values = truth_values()
    fr = analytic_response(st)
    rng = np.random.default_rng(seed)
    start = st.theta0 * (1.0 + rng.uniform(-0.5, 0.5, st.theta0.size))
    result = identify_frequency_domain(fr, st, start=start, reduce=False)
    errors = _relative_errors(result, values)
    assert max(abs(e) for e in errors.values()) < 0.01, errors
    for name, tau in TRUE_DELAYS.items():
        assert abs(result.value(name) - tau) < 0.010
    assert result.restart["same_minimum"]


def test_noise_free_recovery_from_equation_error_start():
    st = truth_structure()
    values = truth_values()
    fr = analytic_response(st)
    # Start far away: every derivative at 30 % of its value, delays at 0.05 s; the
    # equation-error start replaces them.
    far = st.with_values(st.theta0 * 0.3).replace_parameters(
        {n: {"value": 0.05} for n in TRUE_DELAYS})
    result = identify_frequency_domain(fr, far, reduce=False)
    assert result.start == "equation_error"
    errors = _relative_errors(result, values)
    assert max(abs(e) for e in errors.values()) < 0.01, errors


def test_equation_error_start_is_exact_without_delays():
    values = {k: v for k, v in truth_values().items() if k not in TRUE_DELAYS}
    st = six_dof_structure(theta0=THETA0, phi0=PHI0, free=list(values), values=values)
    fr = analytic_response(st)
    theta = equation_error_start(fr, st.with_values(np.zeros(st.theta0.size)))
    np.testing.assert_allclose(theta, st.theta0, rtol=1e-8, atol=1e-10)


def test_equation_error_start_is_exact_with_tied_entries():
    # a tied A entry (M_w also sets X_w, half of it) and a tied B entry (Z_col also sets the
    # pitch row, scale 0.4): each parameter's start is its entry's estimate over the scale
    st = structure_from_dict(
        {"states": ["u", "w", "q", "theta"], "inputs": ["lon", "col"],
         "outputs": ["u", "w", "q", "theta"],
         "A": {"X_u": -0.02, "Z_w": -0.3, "M_q": -1.0,
               "theta,q": {"value": 1.0, "free": False},
               "u,theta": {"value": -32.17, "free": False},
               "M_w": {"value": 0.02, "also": [["u,w", 0.5]]}},
         "B": {"M_lon": -0.9, "Z_col": {"value": -0.8, "also": [["q,col", 0.4]]}}},
        source="tied")
    fr = analytic_response(st)
    theta = equation_error_start(fr, st.with_values(np.zeros(st.theta0.size)))
    np.testing.assert_allclose(theta, st.theta0, rtol=1e-8, atol=1e-10)


def test_noisy_responses_within_three_cramer_rao_bounds():
    st = truth_structure()
    values = truth_values()
    fr = analytic_response(st, noise=0.08, seed=7)
    rng = np.random.default_rng(11)
    start = st.theta0 * (1.0 + rng.uniform(-0.5, 0.5, st.theta0.size))
    result = identify_frequency_domain(fr, st, start=start, reduce=False)
    stats = result.statistics
    z = (result.theta - st.theta0) / stats.cramer_rao
    assert np.all(np.abs(z) <= 3.0), dict(zip(stats.names, np.round(z, 2)))
    for name, tau in TRUE_DELAYS.items():
        assert abs(result.value(name) - tau) < 0.010
    assert np.all(stats.identifiable)
    # the model Dataset carries the same statistics
    model = result.model
    np.testing.assert_allclose(model["cramer_rao"].sel(parameter=list(stats.names)).values,
                               stats.cramer_rao)
    assert model.attrs["method"] == "frequency_domain"
    assert float(model["cost"].sel(output="q", input="lon")) == pytest.approx(
        result.pair_cost["q/lon"])


def test_reduction_removes_spurious_parameters_and_keeps_true_ones():
    st = truth_structure(extra_free=SPURIOUS)
    values = truth_values()
    fr = analytic_response(st, noise=0.05, seed=3)
    result = identify_frequency_domain(fr, st, reduce=True)
    removed = set(result.reduction.removed)
    assert removed == set(SPURIOUS), result.reduction.table()
    assert set(result.structure.free_names) == set(values)
    for step in result.reduction.steps:
        assert step.cramer_rao_percent > 20 or step.insensitivity_percent > 10
        if step.accepted:
            assert step.cost_after - step.cost_before <= 2.0
        else:  # a true parameter near a guideline whose removal costs more than 2 J_ave
            assert step.parameter in values and step.cost_after - step.cost_before > 2.0
    for name in SPURIOUS:
        assert result.value(name) == 0.0
        assert not bool(result.model["free"].sel(parameter=name))
    stats = result.statistics
    z = {n: (result.value(n) - values[n]) / stats.cramer_rao[k]
         for k, n in enumerate(stats.names)}
    assert all(abs(v) <= 3.0 for v in z.values()), z


def test_reduction_never_removes_a_kept_parameter():
    """``keep = true`` in a structure: the reduction leaves that parameter free even when it
    breaks the guidelines and costs nothing to remove (a spurious derivative here); the
    others are still removed."""
    st = truth_structure(extra_free=SPURIOUS)
    kept = st.replace_parameters({"L_q": {"keep": True}})
    fr = analytic_response(st, noise=0.05, seed=3)
    result = identify_frequency_domain(fr, kept, reduce=True)
    assert set(result.reduction.removed) == set(SPURIOUS) - {"L_q"}
    assert "L_q" in result.structure.free_names
    assert "L_q" not in {step.parameter for step in result.reduction.steps}
    assert result.statistics.cramer_rao_percent[
        result.statistics.names.index("L_q")] > 20.0       # it does break the guideline


def test_parameter_without_influence_is_reported_unidentifiable():
    st = truth_structure()
    fr = analytic_response(st)
    pairs = [p for p in DEFAULT_PAIRS if p[1] != "ped"]  # nothing about the pedal column
    result = identify_frequency_domain(fr, st, pairs=pairs, reduce=False)
    stats = result.statistics
    for name in ("Y_ped", "N_ped"):
        k = stats.names.index(name)
        assert not stats.identifiable[k]
        assert math.isinf(stats.cramer_rao[k]) and math.isinf(stats.insensitivity[k])
    assert {"Y_ped", "N_ped"} <= set(result.unidentifiable)
    assert np.all(np.isfinite(stats.cramer_rao[stats.identifiable]))
    assert "unidentifiable" in result.table()
    # with reduction they are the first to go
    reduced = identify_frequency_domain(fr, st, pairs=pairs, reduce=True)
    assert {"Y_ped", "N_ped"} <= set(reduced.reduction.removed)
    assert reduced.reduction.steps[0].reason == "unidentifiable"


def test_structure_declared_pairs_are_the_default():
    """Without ``pairs`` the fit uses the structure's own (TOML ``pairs``); given ones win."""
    st = truth_structure()
    fr = analytic_response(st)
    no_pedal = [p for p in DEFAULT_PAIRS if p[1] != "ped"]
    st.attrs["fit_pairs"] = ",".join(f"{o}/{i}" for o, i in no_pedal)
    declared = identify_frequency_domain(fr, st, reduce=False)
    assert list(declared.data.pairs) == no_pedal
    assert {"Y_ped", "N_ped"} <= set(declared.unidentifiable)   # nothing about the pedal
    given = identify_frequency_domain(fr, st, pairs=DEFAULT_PAIRS, reduce=False)
    assert list(given.data.pairs) == list(DEFAULT_PAIRS)
    assert "N_ped" not in given.unidentifiable


def test_structure_declared_coherence_admission_is_the_default():
    """Without ``coherence_min`` the fit admits points down to the structure's own
    (TOML ``coherence_min``), else the 0.6 guideline; a given one wins."""
    st = truth_structure()
    fr = analytic_response(st, gamma2=0.5)        # coherent only at 0.5 in the band
    with pytest.raises(IdentificationError, match="coherent"):
        identify_frequency_domain(fr, st, reduce=False)
    st.attrs["fit_coherence_min"] = 0.4
    declared = identify_frequency_domain(fr, st, reduce=False)
    assert declared.data.coherence_min == 0.4 and len(declared.data.pairs) == 13
    assert declared.model.attrs["coherence_min"] == 0.4
    with pytest.raises(IdentificationError, match="coherent"):
        identify_frequency_domain(fr, st, coherence_min=0.6, reduce=False)


def test_pair_without_coherent_range_is_skipped_and_reported():
    st = truth_structure()
    fr = analytic_response(st)
    fr["partial_coherence"].loc[dict(output="v", input="ped")] = 0.3
    result = identify_frequency_domain(fr, st, reduce=False)
    assert "v/ped" in result.skipped_pairs
    assert ("v", "ped") not in result.data.pairs
    assert "v/ped" in result.table()
    fr["partial_coherence"][:] = 0.1
    with pytest.raises(IdentificationError, match="coherent"):
        identify_frequency_domain(fr, st)


def test_statistics_of_a_linear_problem():
    rng = np.random.default_rng(0)
    G = rng.standard_normal((50, 3))
    values = np.array([2.0, -1.0, 0.5])
    stats = parameter_statistics(G, values, ["a", "b", "c"])
    cov = np.linalg.inv(G.T @ G)
    np.testing.assert_allclose(stats.cramer_rao, np.sqrt(np.diag(cov)), rtol=1e-10)
    np.testing.assert_allclose(stats.insensitivity, 1 / np.sqrt(np.diag(G.T @ G)), rtol=1e-12)
    np.testing.assert_allclose(stats.cramer_rao_percent, 100 * stats.cramer_rao / abs(values))
    # zero column and two identical columns: flagged, not crashed on
    G2 = np.column_stack([G, np.zeros(50), G[:, 0]])
    s2 = parameter_statistics(G2, np.r_[values, 1.0, 1.0], list("abcde"))
    assert list(s2.identifiable) == [False, True, True, False, False]
    assert np.all(np.isinf(s2.cramer_rao[[0, 3, 4]]))
    assert math.isinf(s2.insensitivity[3]) and np.isfinite(s2.insensitivity[0])
    np.testing.assert_allclose(s2.cramer_rao[1:3], np.sqrt(np.diag(
        np.linalg.inv(G[:, 1:].T @ G[:, 1:] - (G[:, 1:].T @ G[:, :1]) @ (G[:, :1].T @ G[:, 1:])
                      / (G[:, 0] @ G[:, 0])))), rtol=1e-8)


# ---------------------------------------------------------------------------------------------
# Full chain: simulated correlated sweeps with output noise -> spectra -> identification
# ---------------------------------------------------------------------------------------------


def _closed_loop_records(structure, *, dt=0.01, seed=0):
    """Sweeps on each axis with a stabilising LQR loop on all axes (the bare hover airframe is
    unstable), so every record's inputs are correlated; seeded output noise.

    The loop is stepped here sample by sample (ZOH, delays whole samples); the recorded
    total inputs are checked to reproduce the states through :func:`simulate`.
    """
    control = pytest.importorskip("control")
    from sysid.signals.inputs import frequency_sweep
    from sysid.models import discretize

    A, B, C, D, tau = structure.matrices()
    K = -control.lqr(A, B, np.diag([1e-2] * 3 + [1e-4] * 3 + [1e-2] * 3), np.eye(4))[0]
    groups = [(k, int(round(d / dt)), np.where(tau[:, k] == d, B[:, k], 0.0))
              for k in range(4) for d in np.unique(tau[:, k])]
    Phi, Gam = discretize(A, np.stack([g[2] for g in groups], axis=1), dt)
    noise_std = np.array([0.05, 0.05, 0.05, 0.2, 0.2, 0.2, 0.05, 0.05, 0.05])
    rng = np.random.default_rng(seed)
    model = structure.to_dataset()
    records = []
    for j, axis in enumerate(structure.inputs):
        sweep = frequency_sweep(axis, omega_min=0.3, omega_max=20.0, duration=90.0,
                                amplitude=5.0, perturbation=0.2, dt=dt, seed=seed + 10 + j)
        ext = np.zeros((sweep.sizes["time"], 4))
        ext[:, j] = sweep[axis].values
        x = np.zeros(9)
        U = np.zeros_like(ext)
        X = np.zeros((len(ext), 9))
        for n in range(len(ext)):
            X[n] = x
            U[n] = ext[n] + K @ x
            x = Phi @ x + Gam @ np.array([U[max(n - m, 0), k] for k, m, _ in groups])
        inputs = xr.Dataset({c: ("time", U[:, k]) for k, c in enumerate(structure.inputs)},
                            coords={"time": sweep["time"].values})
        # simulate() runs the *open-loop* model (unstable, e^{0.24 t}) on the recorded inputs,
        # which amplifies rounding by ~1e4 over 40 s (1e10 over the whole record).
        y = simulate(model, inputs.isel(time=slice(0, 4000)))
        for i, s in enumerate(structure.states):
            np.testing.assert_allclose(y[s].values, X[:4000, i], atol=1e-9 * np.abs(X).max())
        Y = X + rng.standard_normal(X.shape) * noise_std
        records.append(inputs.assign({s: ("time", Y[:, i])
                                      for i, s in enumerate(structure.states)}))
    return records


def test_full_chain_simulated_sweeps_within_three_cramer_rao_bounds():
    fr_module = pytest.importorskip("sysid.spectral.response")
    st = truth_structure()
    records = _closed_loop_records(st)
    fr = fr_module.frequency_response(records, list(st.inputs), list(st.states))
    # v/ped and p/col are left out: in this truth they are weak, notched responses whose
    # composite estimates carry outliers at high coherence (reported to the spectra stage).
    pairs = [p for p in DEFAULT_PAIRS if p not in (("v", "ped"), ("p", "col"))]
    result = identify_frequency_domain(fr, st, pairs=pairs, frequency_range=(0.5, 16.0),
                                       reduce=False)
    stats = result.statistics
    truth = st.theta0
    assert np.all(stats.identifiable)
    z = (result.theta - truth) / stats.cramer_rao
    assert np.all(np.abs(z) <= 3.0), dict(zip(stats.names, np.round(z, 2)))
    for name, tau in TRUE_DELAYS.items():
        assert abs(result.value(name) - tau) < 0.010
    assert result.J_ave < 20


# ---------------------------------------------------------------------------------------------
# Command line
# ---------------------------------------------------------------------------------------------


@pytest.mark.parametrize("with_linearization", [False, True])
def test_cli_identify(tmp_path, capsys, with_linearization):
    io = pytest.importorskip("sysid.data.netcdf")
    from sysid.cli import main

    st = truth_structure()
    values = truth_values()
    path = tmp_path / "campaign.nc"
    io.update_campaign(path, "frequency_response", analytic_response(st))
    if with_linearization:
        io.update_campaign(path, "linearization",
                           st.to_dataset(attrs={"method": "linearization"}))
    # The truth here is an exact 6-DoF model, valid at every frequency: fit the whole band
    # rather than the built-in structure's quasi-steady validity band (0.1-8 rad/s).
    assert main(["identify", str(path), "--quiet", "--frequency-range", "0.1,100"]) == 0
    printed = capsys.readouterr().out
    assert "J_ave" in printed and "tau_L_lon" in printed and "CR %" in printed
    model = io.read_campaign(path)["models/frequency_domain"].to_dataset()
    assert model.attrs["method"] == "frequency_domain"
    assert model.attrs["start"] == ("model" if with_linearization else "equation_error")
    assert model.attrs["structure"] == "hover_6dof"
    for name, v in values.items():  # the built-in structure holds every true parameter
        assert float(model["value"].sel(parameter=name)) == pytest.approx(v, rel=0.01)
    for name in ("X_u", "Y_v"):  # zero in the truth: removed by the reduction
        assert float(model["value"].sel(parameter=name)) == 0.0
        assert not bool(model["free"].sel(parameter=name))


def test_cli_identify_errors(tmp_path, capsys):
    io = pytest.importorskip("sysid.data.netcdf")
    from sysid.cli import main

    path = tmp_path / "empty.nc"
    io.update_campaign(path, "maneuvers", xr.Dataset())
    assert main(["identify", str(path), "--quiet"]) == 1
    assert "frequency_response" in capsys.readouterr().err


def test_fallback_coherence_admits_weak_pairs_only():
    """A pair with no range at the guideline is admitted at the fallback threshold and
    reported; pairs that reach the guideline keep their strict range."""
    from sysid.identify.frequency_domain import select_fit_data

    omega = np.logspace(-1, 1.5, 60)
    H = 1.0 / (1j * omega + 1.0)
    strong = np.full(omega.size, 0.9)
    weak = np.where((omega > 1) & (omega < 5), 0.5, 0.2)
    fr = xr.Dataset(
        {"H": (("output", "input", "frequency"), np.stack([[H], [H]])),
         "coherence": (("output", "input", "frequency"), np.stack([[strong], [weak]]))},
        coords={"output": ["q", "p"], "input": ["lon"], "frequency": omega})
    strict = select_fit_data(fr, "q/lon,p/lon")
    assert "p/lon" in strict.skipped and not strict.weak
    relaxed = select_fit_data(fr, "q/lon,p/lon", fallback_coherence_min=0.4)
    assert relaxed.weak == {"p/lon": 0.4} and not relaxed.skipped
    lo, hi = relaxed.ranges["p/lon"]
    assert lo > 1 and hi < 5          # only the part above the fallback threshold
    assert relaxed.ranges["q/lon"] == strict.ranges["q/lon"]


def test_roll_row_running_away_is_anchored_at_the_start_damping():
    """Responses of a quasi-static roll axis (the roll row of the truth times 1e5, as when the
    roll subsidence lies far above the fitted band) determine only the ratios L_x / L_p. The
    unguarded fit slides along that valley to 1e5 times the start values with no usable
    Cramer-Rao bound; the default fit holds L_p at its start value and keeps the row finite."""
    from sysid.identify.frequency_domain import runaway_parameters

    values = {k: v for k, v in truth_values().items() if k not in TRUE_DELAYS}
    row = ("L_u", "L_v", "L_p", "L_lon", "L_lat")
    st = six_dof_structure(theta0=THETA0, phi0=PHI0, free=row, values=values)
    data = analytic_response(st, st.theta0 * 1e5)
    kw = dict(pairs="p/lat,p/lon,v/lat,q/lat", start=st.theta0, reduce=False)
    free = identify_frequency_domain(data, st, anchor_runaways=False, **kw)
    assert set(runaway_parameters(st.free_names, free.theta, st.theta0, free.statistics)) \
        == set(row)
    anchored = identify_frequency_domain(data, st, **kw)
    assert json.loads(anchored.model.attrs["anchored_parameters"]) == {"L_p": values["L_p"]}
    assert anchored.value("L_p") == values["L_p"]
    assert "held at their start values (their row ran away): L_p = " in anchored.table()
    for name in row:
        assert abs(anchored.value(name)) < 2.0 * abs(values[name]), name
    assert not runaway_parameters(anchored.structure.free_names, anchored.theta,
                                  [values[n] for n in anchored.structure.free_names],
                                  anchored.statistics)


def test_a_parameter_a_thousand_times_its_start_ran_away_whatever_its_bound():
    """Far along the valley the bound relative to the value shrinks (full 100-kt campaign:
    L_p at 6e8 with a bound under 100 %): beyond RUNAWAY_FAR_FACTOR times its start a
    parameter counts as run away even with a small bound; below it only with a large one."""
    from types import SimpleNamespace

    from sysid.identify.frequency_domain import (RUNAWAY_FACTOR, RUNAWAY_FAR_FACTOR,
                                                 runaway_parameters)

    names = ["L_p", "L_lat", "M_q", "N_r"]
    start = np.array([-11.0, 13.8, -3.2, -0.9])
    theta = start * np.array([2 * RUNAWAY_FAR_FACTOR, 2 * RUNAWAY_FACTOR,
                              2 * RUNAWAY_FACTOR, 1.0])
    stats = SimpleNamespace(identifiable=np.array([True, True, True, True]),
                            cramer_rao_percent=np.array([5.0, 5.0, 500.0, 500.0]))
    # L_p: far, small bound -> ran away; L_lat: large, small bound -> not; M_q: large and
    # undetermined -> ran away; N_r: at its start -> not
    assert runaway_parameters(names, theta, start, stats) == ["L_p", "M_q"]


def test_jacobian_is_finite_where_the_model_response_vanishes():
    """A trial point whose response is exactly zero (or whose slope overflows) gets zero
    slope, as its residual is clamped to a constant; finite points keep the analytic
    d dB = (20/ln 10) Re(dT/T), d deg = (180/pi) Im(dT/T)."""
    n = 3
    data = FitData(pairs=(("q", "lon"),), skipped={}, pair_index=np.zeros(n, int),
                   omega=np.array([1.0, 2.0, 3.0]), mag_db=np.zeros(n), phase_deg=np.zeros(n),
                   coherence=np.ones(n), random_error=np.zeros(n), weight=np.ones(n),
                   ranges={"q/lon": (1.0, 3.0)}, n_points=n, coherence_min=0.6,
                   coherence_variable="partial_coherence")
    T = np.array([0.0, 1.0 + 1.0j, 1e-300])
    dT = np.array([[1.0 + 0j], [0.5 + 0.25j], [1e300 + 0j]])
    J = response_jacobian(T, dT, data)
    assert np.all(np.isfinite(J)) and np.all(np.isfinite(response_residuals(T, data)))
    assert J[0, 0] == 0.0 and J[n, 0] == 0.0 and J[2, 0] == 0.0
    rel = dT[1, 0] / T[1]
    np.testing.assert_allclose(J[1, 0], math.sqrt(W_G) * 20 / math.log(10) * rel.real)
    np.testing.assert_allclose(J[n + 1, 0], math.sqrt(W_P) * 180 / math.pi * rel.imag)


def test_selection_bound_is_zero_without_coherence_error():
    """Noise-free responses (random error 0): the coherence cannot move, every re-selection
    fits the same points, so the point-selection bound is exactly 0 and the scoreboard's
    bound equals the random-error one."""
    st = truth_structure()
    result = identify_frequency_domain(analytic_response(st), st, reduce=False,
                                       start=st.theta0, selection_draws=4)
    names = list(st.free_names)
    assert result.model.attrs["selection_draws_fitted"] == 4
    np.testing.assert_array_equal(result.model["cramer_rao_selection"].sel(parameter=names), 0)
    np.testing.assert_array_equal(result.model["cramer_rao_total"].sel(parameter=names),
                                  result.model["cramer_rao_noise"].sel(parameter=names))


def test_selection_bound_grows_where_the_coherence_sits_at_the_threshold():
    """A structure that misses the true delays (so the estimate depends on the points) fitted
    to the same noisy responses twice: with the coherence far above the 0.6 threshold the
    fitted points hardly move between re-selections; with a plateau at the threshold above
    3 rad/s the upper edge moves from draw to draw and the selection bound grows. Measured
    over noise seeds 1-4 x bootstrap seeds 5, 9: median selection / random-error bound
    0.10-0.18 far above the threshold, 0.54-0.86 at it (3.3-8.8 times more)."""
    values = truth_values()
    truth = truth_structure()
    misfit = six_dof_structure(theta0=THETA0, phi0=PHI0,
                               values={k: v for k, v in values.items() if k not in TRUE_DELAYS},
                               free=[k for k in values if k not in TRUE_DELAYS])
    fr = analytic_response(truth, noise=0.05, seed=3)
    names = list(misfit.free_names)
    ratio = {}
    for plateau in (0.9, 0.6):
        g2 = fr["partial_coherence"]
        upper = (fr["frequency"] > 3.0) & (g2 > 0.5)
        data = fr.assign(partial_coherence=g2.where(~upper, plateau))
        model = identify_frequency_domain(data, misfit, reduce=False, start=misfit.theta0,
                                          selection_draws=10, seed=5).model
        assert model.attrs["selection_draws_fitted"] >= 8
        ratio[plateau] = float(np.median(model["cramer_rao_selection"].sel(parameter=names)
                                         / model["cramer_rao_noise"].sel(parameter=names)))
    print("median selection / random-error bound:", ratio)
    assert ratio[0.6] > 2.5 * ratio[0.9]
    assert ratio[0.6] > 0.4


def test_robust_scale_is_the_standard_deviation_of_normal_draws_and_ignores_jumps():
    """The selection bound's scale (1.4826 MAD): on 20000 normal draws per column within 3 %
    of the true standard deviation (the MAD's sampling error there is about 1.2 %); with two
    draws in twenty moved 40 standard deviations (a refit that jumped) it stays within the
    spread of clean 20-draw samples while the plain standard deviation grows tenfold, and the
    two count as outlying (beyond 3 scales of the median)."""
    rng = np.random.default_rng(11)
    sigma = np.array([0.5, 2.0, 7.0])
    big = rng.standard_normal((20000, 3)) * sigma
    scale, outlying = robust_scale(big, axis=0)
    np.testing.assert_allclose(scale, sigma, rtol=0.03)
    assert np.all(outlying < 0.01)          # normal tail beyond 3 sigma: 0.27 %
    clean = rng.standard_normal((200, 20))
    clean_scale = robust_scale(clean, axis=1)[0]
    jumped = clean.copy()
    jumped[:, :2] += 40.0
    jumped_scale, jumped_out = robust_scale(jumped, axis=1)
    assert np.median(jumped_scale) < np.percentile(clean_scale, 90)
    assert np.all(jumped.std(axis=1, ddof=1) > 8.0 * clean.std(axis=1, ddof=1))
    assert np.all(jumped_out >= 2 / 20)
    assert OUTLYING_SCALES == 3.0
    # equal draws (a noise-free re-selection): zero scale, nothing outlying
    assert robust_scale(np.ones((5, 2)), axis=0)[0].tolist() == [0.0, 0.0]
    assert robust_scale(np.ones((5, 2)), axis=0)[1].tolist() == [0.0, 0.0]


def test_perturbed_coherence_has_the_coherence_error_and_its_correlation_width():
    """400 draws of the coherence: standard deviation within 15 % of
    ``coherence_random_error`` at every frequency (four times the 3.5 % sampling error of a
    standard deviation from 400 draws), correlated over the resolution of the
    shortest trusted window (neighbouring grid points > 0.8) and not beyond it (five widths
    apart < 0.25)."""
    st = truth_structure()
    fr = analytic_response(st, noise=0.1, gamma2=0.5, band=(0.05, 100.0)).assign_attrs(
        windows=[10.0, 40.0])
    draws = np.stack([perturbed_coherence(fr, seed=k)["partial_coherence"]
                      .sel(output="q", input="lon").values for k in range(400)])
    sigma = coherence_random_error(fr).sel(output="q", input="lon").values
    np.testing.assert_allclose(draws.std(axis=0), sigma, rtol=0.15)
    omega = fr["frequency"].values
    width = coherence_correlation_width(fr)
    assert width[np.argmin(abs(omega - 0.3))] == pytest.approx(2 * math.pi / 40.0)
    assert width[np.argmin(abs(omega - 2.0))] == pytest.approx(2 * math.pi / 10.0)
    corr = np.corrcoef(draws.T)
    k = np.argmin(abs(omega - 2.0))
    far = np.argmin(abs(omega - (omega[k] + 5 * width[k])))
    assert corr[k, k + 1] > 0.8
    assert abs(corr[k, far]) < 0.25
