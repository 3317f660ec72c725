"""Hybrid (flapping) structures against the truth FMU's linearisation.

Independent checks: the FMU's accelerometer outputs (specific force computed inside model.c)
against its own state derivatives (u' minus the gravity and velocity terms), the hybrid
reduction residualised once more against the quasi-steady 6-DoF linearisation computed by
the original path, and the flapping normalisation of truth_for_structure.
"""

import os

import numpy as np
import pytest
import xarray as xr

from sysid.assess.metrics import J_RMS_GUIDELINE
from sysid.assess.comparison import DOMINANT, quasi_steady_equivalents, truth_for_model
from sysid.assess.envelopes import MUAD
from sysid.assess.stages import verify_models
from sysid.core.util import Progress
from sysid.data.netcdf import write_campaign
from sysid.pipeline.batch import condition_summary
from sysid.report.figures import Context
from sysid.report.sections import section_derivatives, section_fidelity
from sysid.assess.verification import verify
from sysid.core.kinematics import rigid_body_terms
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.data.campaign import CampaignData
from sysid.flight_test.campaign import default_campaign, run_campaign
from sysid.spectral.response import frequency_response as spectral_response
from sysid.identify.stages import fit_filter_error, fit_frequency_domain, fit_time_domain
from sysid.models import load_structure, residualize_model
from sysid.pipeline.study import StudySettings
from sysid.truth import linearize as truth_linearize, trim as truth_trim
from sysid.truth.linearize import truth_for_structure
from sysid.core.errors import InputDataError
from sysid.identify.frequency_domain import identify_frequency_domain
from sysid.identify.time_domain import OutputErrorModel, prepare_records
from sysid.models import frequency_response, model_from_dataset, simulate, structure_from_dict

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def hover_lin(hover_trim):
    from sysid.truth import linearize

    return linearize(hover_trim)


def test_accelerometer_rows_are_specific_force(hover_lin, hover_trim):
    """C[ax] = (A - A_kin)[u] and D[ax] = B[u] on the full model (and likewise ay/v, az/w):
    the FMU's accelerometer output, differentiated, equals its force equation without the
    gravity and velocity cross-product terms."""
    full = hover_lin.full
    vals = hover_trim.channel_values()
    states = [str(s) for s in full.state.values]
    K = np.zeros((len(states), len(states)))
    k6 = rigid_body_terms(theta0=vals["theta"], phi0=vals["phi"], u0=vals["u"], v0=vals["v"],
                          w0=vals["w"]).values
    idx = [states.index(s) for s in STATES_6DOF]
    K[np.ix_(idx, idx)] = k6
    A, B = full["A"].values, full["B"].values
    for out, row in (("ax", "u"), ("ay", "v"), ("az", "w")):
        i = states.index(row)
        c = full["C"].sel(output=out).values
        d = full["D"].sel(output=out).values
        scale = np.abs(A[i] - K[i]).max()
        np.testing.assert_allclose(c, A[i] - K[i], atol=1e-5 * scale)
        np.testing.assert_allclose(d, B[i], atol=1e-5 * np.abs(B[i]).max())


def test_hybrid_truth_reduces_to_the_quasi_steady_linearisation(hover_lin, hover_trim):
    from sysid.truth.linearize import truth_for_structure

    st = load_structure("hover_hybrid", trim=hover_trim.channel_values())
    tr = truth_for_structure(hover_lin.full, st)
    # the normalisation holds the structure's fixed flapping entries exactly
    A = tr["A"].to_pandas()
    assert A.loc["a1", "q"] == pytest.approx(-1.0, abs=1e-9)
    assert A.loc["b1", "p"] == pytest.approx(-1.0, abs=1e-9)
    assert A.loc["a1", "p"] == pytest.approx(0.0, abs=1e-9)
    assert A.loc["b1", "q"] == pytest.approx(0.0, abs=1e-9)
    # parameters read back: value = entry minus fixed part
    values = dict(zip(tr.parameter.values, tr.value.values))
    assert values["L_b1"] == pytest.approx(A.loc["p", "b1"], rel=1e-12)
    # one flapping time constant (A[a1,a1] also sets A[b1,b1]): the truth's two entries
    # agree (the premise of the tie) and the parameter is their mean
    assert A.loc["a1", "a1"] == pytest.approx(A.loc["b1", "b1"], rel=1e-3)
    assert values["A[a1,a1]"] == pytest.approx((A.loc["a1", "a1"] + A.loc["b1", "b1"]) / 2,
                                               rel=1e-12)
    # flapping time constant near Padfield's 16/(gamma Omega) estimate for this rotor
    tau_f = -1.0 / values["A[a1,a1]"]
    assert 0.05 < tau_f < 0.09, tau_f
    # residualising the flapping of the hybrid truth gives the original quasi-steady model
    qs = residualize_model(tr, list(STATES_6DOF))
    ref = hover_lin.quasi_steady
    for key in ("A", "B"):
        a = qs[key].values
        b = ref[key].sel(state_dot=list(STATES_6DOF)).values
        if key == "A":
            b = ref[key].sel(state_dot=list(STATES_6DOF), state=list(STATES_6DOF)).values
        np.testing.assert_allclose(a, b, atol=1e-8 * np.abs(b).max())
    # the hybrid keeps the full model's low-frequency modes (flap-roll and slower)
    ev_h = np.sort(np.abs(np.linalg.eigvals(tr["A"].values)))
    ev_f = np.sort(np.abs(hover_lin.eigenvalues_full))
    for e in ev_h[ev_h > 0.1]:
        assert np.min(np.abs(ev_f - e)) < 0.03 * e, e


def test_a_hybrid_is_judged_against_its_structure_s_truth_and_as_quasi_steady_equivalents(
        hover_lin, hover_trim, tmp_path):
    """The report's fidelity scoreboard compares a flapping model with the truth reduced to
    its structure (as the derivative table and `sysid compare` do), not with the quasi-steady
    linearisation, whose speed derivatives differ from the hybrid's (the flapping
    residualised into them: L_v -6.69 against -0.39). The model is the structure's truth
    itself with 5 % bounds: every error 0."""
    st = load_structure("hover_hybrid", trim=hover_trim.channel_values())
    truth = truth_for_structure(hover_lin.full, st)
    model = truth.copy()
    model["cramer_rao"] = 0.05 * np.abs(model["value"])
    model["free"] = model["free"].astype(bool)
    model.attrs["method"] = "frequency_domain"
    tree = xr.DataTree.from_dict({"/linearization": hover_lin.quasi_steady,
                                  "/linearization_full": hover_lin.full,
                                  "/models/frequency_domain": model})
    html = section_fidelity(Context(tree, tmp_path, Progress(quiet=True), MUAD, None))
    qs = dict(zip(map(str, hover_lin.quasi_steady.parameter.values),
                  hover_lin.quasi_steady.value.values))
    values = dict(zip(map(str, truth.parameter.values), truth.value.values))
    for name in ("L_v", "N_v", "M_u"):  # the two truths differ here (flapping in them)
        assert abs(values[name] - qs[name]) > 0.4 * abs(values[name]), name
    n = int(np.sum(truth["free"].values.astype(bool)
                   & ~np.isin(truth["matrix"].values, ["delay"])))
    assert f"frequency_domain: 0 of {n} flagged" in html, html[:2000]
    assert 'class="fail"' not in html
    assert "linearisation reduced to the model's states" in html
    html = section_derivatives(Context(tree, tmp_path, Progress(quiet=True), MUAD, None))
    assert "extra states (a1, b1, theta_1c, theta_1s) residualised" in html
    table = html[html.index('id="table-derivatives-equivalent"'):]
    # one row per dominant derivative, also those the hybrid has as parameters itself (an
    # inflow model's Z_w is the thrust's, not the quasi-steady one)
    assert table.count("<tr>") == 1 + len(DOMINANT)
    # the one rule behind it (also the batch's truth column): a quasi-steady model gets the
    # quasi-steady linearisation, a tree without one no truth
    np.testing.assert_allclose(truth_for_model(tree, model)["value"].values,
                               truth["value"].values, rtol=1e-9, atol=1e-12)
    assert truth_for_model(tree, hover_lin.quasi_steady) is not None
    assert set(map(str, truth_for_model(tree, hover_lin.quasi_steady).parameter.values)) == \
        set(map(str, hover_lin.quasi_steady.parameter.values))
    assert truth_for_model(xr.DataTree.from_dict({"/models/x": model}), model) is None
    # the hybrid truth's quasi-steady equivalents are the quasi-steady linearisation's values
    eq = quasi_steady_equivalents(model, hover_lin.quasi_steady, names=DOMINANT)
    assert set(map(str, eq.parameter.values)) == set(DOMINANT)
    for name in DOMINANT:
        assert float(eq["value"].sel(parameter=name)) == pytest.approx(qs[name], rel=1e-6), name
    assert np.all(eq["cramer_rao"].values > 0)  # propagated from the model's 5 % bounds
    # ... and a batch condition of a hybrid study reports them where the model has none,
    # against the quasi-steady truth, and its own parameters against the structure's truth
    write_campaign(tree, tmp_path / "campaign.nc")
    summary = condition_summary(tmp_path)
    row = summary.sel(model="frequency_domain")
    for name in DOMINANT:
        assert float(row["value"].sel(parameter=name)) == pytest.approx(
            float(summary["truth"].sel(parameter=name)), rel=1e-6), name
    assert float(summary["truth"].sel(parameter="L_p")) == pytest.approx(qs["L_p"])
    assert float(summary["truth"].sel(parameter="L_v")) == pytest.approx(values["L_v"])
    assert np.isfinite(row["cramer_rao"].sel(parameter=list(DOMINANT))).all()


# --- One parameter on several entries (the shared flapping time constant) -------------------

TIED = {"states": ["u", "w", "q", "theta", "a1", "b1"], "inputs": ["lon", "col"],
        "outputs": ["u", "w", "q", "theta"],
        "A": {"X_u": -0.02, "Z_w": -0.3, "M_a1": 40.0, "theta,q": {"value": 1.0, "free": False},
              "a1,q": {"value": -1.0, "free": False},
              "a1,a1": {"value": -14.0, "also": ["b1,b1"]},
              "a1,b1": {"value": 1.0, "also": [["b1,a1", -1.0]]},
              "u,theta": {"value": -32.17, "free": False}, "q,u": 0.1},
        "B": {"a1,lon": 2.0, "Z_col": {"value": -0.7, "also": [["q,col", -0.4]]},
              "b1,col": 0.3}}


def _tied_and_untied():
    tied = structure_from_dict(TIED, source="tied")
    spec = {**TIED, "A": {**TIED["A"], "a1,a1": -14.0, "b1,b1": -14.0, "a1,b1": 1.0},
            "B": {**TIED["B"], "Z_col": -0.7, "q,col": 0.28}}
    spec["A"]["b1,a1"] = -1.0
    return tied, structure_from_dict(spec, source="untied")


def test_a_tied_parameter_sets_every_entry_with_its_scale():
    """``also`` puts one value on several A (or several B) entries; a tie onto an entry
    another free parameter sets, or onto another matrix's entry, is refused; the model
    Dataset keeps the tie (round trip)."""
    with pytest.raises(InputDataError, match="both set"):
        structure_from_dict({**TIED, "A": {**TIED["A"], "b1,a1": 0.5}}, source="clash")
    with pytest.raises(InputDataError, match="both set"):
        structure_from_dict({**TIED, "B": {**TIED["B"], "q,col": 0.5}}, source="clash")
    with pytest.raises(InputDataError, match="among the inputs"):  # an A entry on a B tie
        structure_from_dict({**TIED, "B": {**TIED["B"], "Z_col": {
            "value": -0.7, "also": ["q,u"]}}}, source="bad")
    tied, untied = _tied_and_untied()
    assert "A[b1,b1]" not in tied.parameter_names and "A[b1,a1]" not in tied.parameter_names
    assert "M_col" not in tied.parameter_names and "M_col" in untied.parameter_names
    theta = tied.theta0 * 1.3
    A, B = tied.matrices(theta)[:2]
    st = list(tied.states)
    a1, b1, q, w = st.index("a1"), st.index("b1"), st.index("q"), st.index("w")
    k = list(tied.free_names)
    assert A[a1, a1] == A[b1, b1] == theta[k.index("A[a1,a1]")]
    assert A[a1, b1] == -A[b1, a1] == theta[k.index("A[a1,b1]")]
    col = list(tied.inputs).index("col")
    assert B[w, col] == theta[k.index("Z_col")] and B[q, col] == -0.4 * B[w, col]
    back, values = model_from_dataset(tied.to_dataset(theta))
    np.testing.assert_array_equal(back.matrices(values)[0], A)
    np.testing.assert_array_equal(back.matrices(values)[1], B)
    assert back.parameter("A[a1,b1]").also == (("b1", "a1", -1.0),)
    assert back.parameter("Z_col").also == (("q", "col", -0.4),)
    # start values from a model whose two entries differ: their mean (over the scale)
    other = tied.to_dataset(theta)
    other["A"].values[b1, b1] += 2.0
    got = dict(zip(tied.free_names, tied.values_from_model(other)))
    assert got["A[a1,a1]"] == pytest.approx(theta[k.index("A[a1,a1]")] + 1.0)


def test_a_held_parameter_adds_a_known_part_to_a_free_tie():
    """Parts on one entry add: a held parameter on the entry a free parameter ties to gives
    ``entry = scale * free + held`` (the inflow row of hover_hybrid_inflow); a parameter may
    not set one entry twice; start values read a tied parameter from the entries only it
    sets, and the truth's held part is the entry less the free part."""
    spec = {**TIED, "B": {**TIED["B"], "q,col": {"value": 0.25, "free": False}}}
    st = structure_from_dict(spec, source="held part")
    theta = st.theta0 * 1.2
    B = st.matrices(theta)[1]
    states, col = list(st.states), list(st.inputs).index("col")
    z_col = theta[list(st.free_names).index("Z_col")]
    assert B[states.index("q"), col] == pytest.approx(-0.4 * z_col + 0.25, rel=1e-15)
    assert B[states.index("w"), col] == z_col
    with pytest.raises(InputDataError, match="both set"):
        structure_from_dict({**TIED, "B": {**TIED["B"], "Z_col": {
            "value": -0.7, "also": [["q,col", -0.4], ["q,col", 1.0]]}}}, source="twice")
    other = st.to_dataset(theta)
    other["B"].values[states.index("q"), col] += 5.0  # the shared entry says nothing of Z_col
    got = dict(zip(st.free_names, st.values_from_model(other)))
    assert got["Z_col"] == pytest.approx(z_col, rel=1e-12)


def test_tied_sensitivities_are_the_sums_of_the_untied_ones():
    """Frequency domain: dT/dtheta against central differences. Time domain: the tied
    parameter's output sensitivity equals the untied entries' sensitivities combined with
    their scales (each computed by the unmodified per-entry path)."""
    tied, untied = _tied_and_untied()
    s = 1j * np.array([0.5, 3.0, 12.0, 20.0])
    oi, ii = np.array([0, 1, 2, 3]), np.array([0, 1, 0, 1])
    theta = tied.theta0 * 1.1
    _, dT = tied.pair_response(theta, s, oi, ii, jacobian=True)
    for j in range(theta.size):
        h = 1e-6 * max(1.0, abs(theta[j]))
        e = np.zeros_like(theta)
        e[j] = h
        num = (tied.pair_response(theta + e, s, oi, ii)
               - tied.pair_response(theta - e, s, oi, ii)) / (2 * h)
        np.testing.assert_allclose(dT[:, j], num, rtol=1e-6, atol=1e-9 * np.abs(dT).max())
    t = np.arange(0.0, 4.0, 0.02)
    rec = xr.Dataset({"lon": ("time", np.where((t > 0.5) & (t < 1.5), 1.0, 0.0)),
                      "col": ("time", np.where((t > 2.0) & (t < 2.6), -1.0, 0.0))},
                     coords={"time": t})
    y = simulate(tied.to_dataset(), rec)
    for o in tied.outputs:
        rec[o] = y[o] + 0.01 * np.sin(7.0 * t)
    rec.attrs.update({"maneuver": "steps", **{f"trim_{c}": 0.0 for c in rec.data_vars}})
    outs = tuple(tied.outputs)
    J = {}
    for name, st in (("tied", tied), ("untied", untied)):
        model = OutputErrorModel(st, prepare_records([rec], st, outs), outs)
        J[name] = dict(zip(st.free_names, model.jacobian(st.theta0).T))
    # to rounding, relative to the sensitivities' scale (the nuisance projection's
    # factorisation rounds differently in the two models' orders of operations)
    atol = 1e-10 * max(np.abs(v).max() for v in J["untied"].values())
    np.testing.assert_allclose(J["tied"]["A[a1,a1]"], J["untied"]["A[a1,a1]"]
                               + J["untied"]["A[b1,b1]"], rtol=1e-10, atol=atol)
    np.testing.assert_allclose(J["tied"]["A[a1,b1]"], J["untied"]["A[a1,b1]"]
                               - J["untied"]["A[b1,a1]"], rtol=1e-10, atol=atol)
    np.testing.assert_allclose(J["tied"]["Z_col"], J["untied"]["Z_col"]
                               - 0.4 * J["untied"]["M_col"], rtol=1e-10, atol=atol)
    np.testing.assert_allclose(J["tied"]["M_a1"], J["untied"]["M_a1"], rtol=1e-12)


# --- Reduced hybrid identification against the truth linearisation (default run) -----------

def _hybrid_truth_of(lin_full, trim):
    st = load_structure(HYBRID, trim=trim)
    return st, truth_for_structure(lin_full, st)


def test_frequency_domain_hybrid_on_the_full_linear_response(hover_lin, hover_trim):
    """The hover_hybrid structure fitted (from its file's start values) to the exact
    0.3-20 rad/s response of the truth's full 17-state linearisation (inflow, actuators,
    flapping): J_ave <= 50 and the issue's derivatives within 15 %, the shared flapping
    time constant within 20 % of the truth reduced to the structure. What is left is the
    structure's own error (actuators as delays, quasi-steady inflow), no noise."""
    st, truth = _hybrid_truth_of(hover_lin.full, hover_trim.channel_values())
    omega = np.logspace(np.log10(0.3), np.log10(20.0), 120)
    H = frequency_response(hover_lin.full, omega).sel(output=list(st.outputs),
                                                       input=list(st.inputs))
    g2 = xr.full_like(H.real, 0.95)
    fr = xr.Dataset({"H": H, "coherence": g2, "partial_coherence": g2,
                     "random_error": xr.full_like(H.real, 0.02)})
    fit = identify_frequency_domain(fr, st, frequency_range=(0.3, 20.0), reduce=False)
    assert fit.J_ave <= J_AVE_MAX
    got, want = _figures(fit.model), _figures(truth)
    for name in ("L_p", "M_q", "L_lat", "M_lon", "Z_w", "Z_col", "N_r", "N_ped"):
        assert _error(got[name], want[name]) <= DERIVATIVE_TOL, (name, got[name], want[name])
    assert got["tau_a1"] == got["tau_b1"]  # one parameter
    assert _error(got["tau_a1"], want["tau_a1"]) <= TAU_F_TOL, (got["tau_a1"], want["tau_a1"])


def test_inflow_hybrid_holds_momentum_theory_and_fits_the_full_linear_response(hover_lin,
                                                                            hover_trim):
    """hover_hybrid_inflow: its held momentum-theory inflow (lambda_i and the ties' mu, from
    the rotor's radius, the mass and the air density) against the truth FMU's own inflow row,
    and its frequency-domain fit to the exact 0.3-20 rad/s response of the full 17-state
    linearisation: a lower J_ave than hover_hybrid's on the same response, its thrust
    derivatives and the issue's derivatives (Z_w, Z_col quasi-steady, with inflow and
    actuator residualised) within 15 % of the truth, the flapping time constant within 20 %."""
    trim = hover_trim.channel_values()
    st = load_structure("hover_hybrid_inflow", trim=trim)
    truth = truth_for_structure(hover_lin.full, st)
    values = dict(zip(truth.parameter.values, truth.value.values))
    # the truth's inflow row, less the free parts the ties give it, is the held part
    assert values["lambda_i"] == pytest.approx(st.parameter("lambda_i").value, rel=0.05)
    A_model = st.matrices(st.values_from_model(truth))[0]
    vi, w = st.states.index("vi_mr"), st.states.index("w")
    A_truth = truth["A"].values
    for col in (w, vi, st.states.index("theta_0")):
        assert A_model[vi, col] == pytest.approx(A_truth[vi, col], rel=0.05), st.states[col]
    assert values["Z_w"] == pytest.approx(-A_truth[w, vi], rel=0.01)  # thrust on w - vi_mr
    omega = np.logspace(np.log10(0.3), np.log10(20.0), 120)
    fits = {}
    for name in (HYBRID, "hover_hybrid_inflow"):
        structure = load_structure(name, trim=trim)
        H = frequency_response(hover_lin.full, omega).sel(output=list(structure.outputs),
                                                           input=list(structure.inputs))
        g2 = xr.full_like(H.real, 0.95)
        fr = xr.Dataset({"H": H, "coherence": g2, "partial_coherence": g2,
                         "random_error": xr.full_like(H.real, 0.02)})
        fits[name] = identify_frequency_domain(fr, structure, frequency_range=(0.3, 20.0),
                                               reduce=False)
    fit = fits["hover_hybrid_inflow"]
    assert fit.J_ave < 0.85 * fits[HYBRID].J_ave, (fit.J_ave, fits[HYBRID].J_ave)
    got = dict(zip(fit.model.parameter.values, fit.model.value.values))
    for name in ("Z_w", "M_w", "Z_theta_0", "M_theta_0", "L_b1", "M_a1", "N_r", "N_ped"):
        assert _error(got[name], values[name]) <= DERIVATIVE_TOL, (name, got[name], values[name])
    qs_fit, qs_truth = residualize_model(fit.model, RIGID), hover_lin.quasi_steady
    for row, col, matrix in (("p", "p", "A"), ("q", "q", "A"), ("p", "lat", "B"),
                             ("q", "lon", "B"), ("w", "w", "A"), ("w", "col", "B")):
        pick = {"state_dot": row, ("state" if matrix == "A" else "input"): col}
        a, b = float(qs_fit[matrix].sel(pick)), float(qs_truth[matrix].sel(pick))
        assert _error(a, b) <= DERIVATIVE_TOL, (matrix, row, col, a, b)
    tau = -1.0 / got["A[a1,a1]"], -1.0 / values["A[a1,a1]"]
    assert _error(*tau) <= TAU_F_TOL, tau


# --- The hybrid chain on the hover study's campaign (issue 22, "Must show") ------------------
# Both domains' hover_hybrid fits as `sysid run hover --structure hover_hybrid` runs them, on the
# session's hover campaign (seed 20261121), against the truth for that structure. Asserted:
# the figures met on that campaign and on seeds 1 and 2 as well; the misses (frequency domain:
# 2311 J_rms on col and ped; time domain: most derivatives, Z_w and Z_col on every seed) and
# the figures met on some seeds only (frequency-domain N_r) are measured in
# docs/notes/2026-11-24-hover-hybrid-flapping-structure.md and the notes of 2026-11-25 on the
# hybrid (2311 speed derivatives, time-domain restarts).

HYBRID = "hover_hybrid"
RIGID = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]
#: Issue 22's targets: derivatives and domain agreement, flapping time constant, J_ave, J_rms.
DERIVATIVE_TOL, TAU_F_TOL, J_AVE_MAX, J_RMS_MAX = 0.15, 0.20, 50.0, 1.0


def _figures(model):
    """The issue's derivatives (L_p, M_q, L_lat, M_lon as quasi-steady equivalents with the
    flapping residualised) and the flapping time constants -1/A[a1,a1], -1/A[b1,b1] (s)."""
    A, B = model["A"].to_pandas(), model["B"].to_pandas()
    qs = residualize_model(model, RIGID)
    Aq, Bq = qs["A"].to_pandas(), qs["B"].to_pandas()
    return {"L_p": Aq.loc["p", "p"], "M_q": Aq.loc["q", "q"], "L_lat": Bq.loc["p", "lat"],
            "M_lon": Bq.loc["q", "lon"], "Z_w": A.loc["w", "w"], "Z_col": B.loc["w", "col"],
            "N_r": A.loc["r", "r"], "N_ped": B.loc["r", "ped"],
            "tau_a1": -1.0 / A.loc["a1", "a1"], "tau_b1": -1.0 / A.loc["b1", "b1"]}


@pytest.fixture(scope="module")
def hybrid_campaign(hover_study):
    return CampaignData(hover_study["tree"], source="hover study")


@pytest.fixture(scope="module")
def hybrid_truth(hybrid_campaign):
    st = load_structure(HYBRID, trim=hybrid_campaign.trim())
    return _figures(truth_for_structure(
        hybrid_campaign.tree["linearization_full"].to_dataset(), st))


@pytest.fixture(scope="module")
def hybrid_fd(hybrid_campaign):
    return fit_frequency_domain(hybrid_campaign, structure=HYBRID,
                                coherence_min=StudySettings(structure=HYBRID).fd_coherence)


@pytest.fixture(scope="module")
def hybrid_td(hybrid_campaign):
    return fit_time_domain(hybrid_campaign, structure=HYBRID, start="linearization",
                           maneuvers=StudySettings(structure=HYBRID).time_domain_maneuvers)


def _verification(campaign, models):
    """J_rms (maneuver -> method -> value) of ``models`` on the 2311s, verified afresh."""
    tree = campaign.tree.copy()
    if "verification" in tree.children:
        del tree["verification"]
    for method, model in models.items():
        tree[f"models/{method}"] = xr.DataTree(model)
    checked = verify_models(CampaignData(tree, source="hover study, hybrid models"),
                            models=list(models), maneuvers="2311_*")
    return {name: {str(s): float(j) for s, j in zip(ds.source.values, ds["j_rms"].values)}
            for name, ds in checked.items()}


def _error(value, truth):
    return abs(value / truth - 1.0)


@pytest.mark.slow  # needs the session's hover study (minutes); the default run has the
# reduced form above (test_frequency_domain_hybrid_on_the_full_linear_response)
def test_frequency_domain_hybrid_meets_the_targets_it_meets(hybrid_fd, hybrid_truth):
    """Frequency-domain hover_hybrid over 0.3-20 rad/s: J_ave <= 50, six of the eight
    derivatives within 15 % and both flapping time constants within 20 % of the truth."""
    assert hybrid_fd.J_ave <= J_AVE_MAX
    # the wider band: the on-axis rate pairs fitted across the flap-roll mode (> 15 rad/s)
    data = hybrid_fd.data
    for pair in (("q", "lon"), ("p", "lat")):
        assert data.omega[data.pair_index == data.pairs.index(pair)].max() > 15.0, pair
    got = _figures(hybrid_fd.model)
    for name in ("M_q", "L_lat", "M_lon", "Z_w", "Z_col", "N_ped"):
        assert _error(got[name], hybrid_truth[name]) <= DERIVATIVE_TOL, \
            (name, got[name], hybrid_truth[name])
    for name in ("tau_a1", "tau_b1"):
        assert _error(got[name], hybrid_truth[name]) <= TAU_F_TOL, \
            (name, got[name], hybrid_truth[name])


@pytest.mark.slow  # needs the session's hover study (minutes)
def test_frequency_domain_inflow_hybrid_on_the_hover_study(hybrid_campaign):
    """hover_hybrid_inflow fitted as the study fits it to the hover study's campaign: J_ave
    <= 50, its thrust derivatives Z_w, Z_theta_0, M_w and N_r, N_ped within 15 % of the truth
    for its structure, L_p, M_q, L_lat, M_lon and Z_col (inflow and actuators residualised)
    within 15 % of the quasi-steady truth, the flapping time constant within 20 %."""
    name = "hover_hybrid_inflow"
    fd = fit_frequency_domain(hybrid_campaign, structure=name,
                              coherence_min=StudySettings(structure=name).fd_coherence)
    assert fd.J_ave <= J_AVE_MAX
    tree = hybrid_campaign.tree
    truth = truth_for_structure(tree["linearization_full"].to_dataset(),
                                load_structure(name, trim=hybrid_campaign.trim()))
    got = dict(zip(map(str, fd.model.parameter.values), fd.model.value.values))
    want = dict(zip(map(str, truth.parameter.values), truth.value.values))
    for derivative in ("Z_w", "Z_theta_0", "M_w", "N_r", "N_ped"):
        assert _error(got[derivative], want[derivative]) <= DERIVATIVE_TOL, \
            (derivative, got[derivative], want[derivative])
    quasi_steady = tree["linearization"].to_dataset()
    eq = quasi_steady_equivalents(fd.model, quasi_steady,
                                  names=["L_p", "M_q", "L_lat", "M_lon", "Z_col"])
    qs = dict(zip(map(str, quasi_steady.parameter.values), quasi_steady.value.values))
    for derivative in map(str, eq.parameter.values):
        value = float(eq["value"].sel(parameter=derivative))
        assert _error(value, qs[derivative]) <= DERIVATIVE_TOL, (derivative, value)
    tau = -1.0 / got["A[a1,a1]"], -1.0 / want["A[a1,a1]"]
    assert _error(*tau) <= TAU_F_TOL, tau


@pytest.mark.slow  # the 38-parameter output-error fit: 29 s of CPU, 1-5 min on 2 shared cores
@pytest.mark.skipif(os.environ.get("SYSID_EXHAUSTIVE") != "1",
                    reason="the 38-parameter output-error fit on the hover campaign (29 s of "
                    "CPU; 282 s in a loaded suite run); its tied parameters' sensitivities are "
                    "checked by test_tied_sensitivities_are_the_sums_of_the_untied_ones; "
                    "SYSID_EXHAUSTIVE=1 runs it")
def test_time_domain_hybrid_meets_the_targets_it_meets(hybrid_td, hybrid_fd, hybrid_truth,
                                                      hybrid_campaign):
    """Time-domain hover_hybrid on the 3211s: N_ped within 15 % of the truth, the two domains
    within 15 % of each other on N_ped, 2311 J_rms <= 1 on every axis."""
    td, fd = _figures(hybrid_td.model), _figures(hybrid_fd.model)
    assert _error(td["N_ped"], hybrid_truth["N_ped"]) <= DERIVATIVE_TOL
    assert _error(fd["N_ped"], td["N_ped"]) <= DERIVATIVE_TOL, (fd["N_ped"], td["N_ped"])
    j = _verification(hybrid_campaign, {"time_domain": hybrid_td.model})
    assert set(j) == {"2311_lon", "2311_lat", "2311_col", "2311_ped"}
    for name, per_source in j.items():
        assert per_source["time_domain"] <= J_RMS_MAX, (name, per_source)


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("SYSID_EXHAUSTIVE") != "1",
                    reason="the 38-parameter output-error fit (see above); SYSID_EXHAUSTIVE=1")
@pytest.mark.xfail(strict=True, reason="output error's N_r is 30 % off the truth (-0.364 "
                   "against -0.279), and the frequency domain's, at -0.292 since hover_hybrid "
                   "admits coherence 0.4, no longer meets it halfway; filter error, the "
                   "default, agrees within 15 % (test_filter_error_hybrid_meets_the_targets)")
def test_time_domain_hybrid_yaw_damping_agrees_with_the_frequency_domain(hybrid_td,
                                                                        hybrid_fd):
    """The frequency domain's and output error's N_r within 15 % of each other (issue 22).
    15.4 % apart (FD -0.308, TD -0.364; docs/notes/2026-11-26-profile-likelihood.md) until
    the simulation's zero-order hold was divided out of the responses, about 14.6 % then
    (docs/notes/2026-11-27-zero-order-hold.md), 19.8 % since the FD fit admits coherence 0.4
    (FD -0.292; docs/notes/2026-11-27-hybrid-coherence-admission.md)."""
    td, fd = _figures(hybrid_td.model), _figures(hybrid_fd.model)
    assert _error(fd["N_r"], td["N_r"]) <= DERIVATIVE_TOL, (fd["N_r"], td["N_r"])


@pytest.mark.slow  # the filter-error hover_hybrid fit: 36 s of CPU on the default seed
@pytest.mark.skipif(os.environ.get("SYSID_EXHAUSTIVE") != "1",
                    reason="the filter-error hover_hybrid fit (36 s of CPU); its "
                    "sensitivities are checked against central differences in "
                    "tests/test_identify_filter_error.py; SYSID_EXHAUSTIVE=1 runs it")
def test_filter_error_hybrid_meets_the_targets(hybrid_campaign, hybrid_fd, hybrid_truth):
    """Time domain by filter error (process noise where the structure says the gusts enter)
    with hover_hybrid on the 3211s: all eight derivatives within 15 % of the truth for the
    structure, the flapping time constant within 20 %, within 15 % of the frequency-domain
    model on the eight, 2311 J_rms <= 1 on every axis (default seed: 10.1 % at most (L_p),
    9.7 % between the domains, J_rms 0.36-0.86; docs/notes/2026-11-27-hybrid-process-noise.md,
    which also has seeds 1-4, where Z_w and the domains' agreement miss on three)."""
    fe = fit_filter_error(hybrid_campaign, maneuvers="3211_*", structure=HYBRID,
                          start="linearization")
    got, fd = _figures(fe.model), _figures(hybrid_fd.model)
    for name in ("L_p", "M_q", "L_lat", "M_lon", "Z_w", "Z_col", "N_r", "N_ped"):
        assert _error(got[name], hybrid_truth[name]) <= DERIVATIVE_TOL, \
            (name, got[name], hybrid_truth[name])
        assert _error(fd[name], got[name]) <= DERIVATIVE_TOL, (name, fd[name], got[name])
    for name in ("tau_a1", "tau_b1"):
        assert _error(got[name], hybrid_truth[name]) <= TAU_F_TOL, \
            (name, got[name], hybrid_truth[name])
    j = _verification(hybrid_campaign, {"filter_error": fe.model})
    assert set(j) == {"2311_lon", "2311_lat", "2311_col", "2311_ped"}
    for name, per_source in j.items():
        assert per_source["filter_error"] <= J_RMS_MAX, (name, per_source)


# --- 2311 verification of the frequency-domain hybrid model (issue 22) -----------------------
# docs/notes/2026-11-25-hybrid-2311-speed-derivatives.md: on the default campaign's 2311s the
# truth's own linearisation (17 states, or reduced to hover_hybrid) reaches J_rms 0.24-0.84 on
# five seeds, so the target is the model, not the FMU's nonlinearity; the frequency-domain
# model missed it because the reduction dropped the speed derivatives, which the structure
# now keeps. Seed 1 (before: J_rms 2.13, 0.67, 1.32, 1.53 on lon, lat, col, ped).

#: hover_hybrid's speed derivatives kept through the reduction, as (row, column) of A.
SPEED_ENTRIES = (("p", "v"), ("q", "u"), ("q", "w"), ("r", "v"), ("a1", "u"), ("a1", "v"),
                 ("b1", "u"), ("b1", "v"))


@pytest.fixture(scope="module")
def seed1_campaign():
    """The default hover campaign flown with seed 1 and its composite responses (about 10 s
    of CPU), as the study computes them."""
    tree = run_campaign(default_campaign(0.0, seed=1), quiet=True)
    tree["frequency_response"] = xr.DataTree(spectral_response(
        CampaignData(tree).maneuvers("sweep_*"), CONTROLS, STATES_6DOF,
        transient_states=StudySettings().transient_states))
    return CampaignData(tree, source="hover campaign, seed 1")


def test_2311_verification_of_the_frequency_domain_hybrid(seed1_campaign):
    """On the four 2311s (models held, biases and reference shifts estimated): the truth's
    linearisation reduced to hover_hybrid meets J_rms <= 1 on every axis (the set-up can be
    met on these records); the frequency-domain hover_hybrid model keeps its speed
    derivatives through the reduction and meets J_rms <= 1 on lon and lat, and the code's
    guideline (2) on col and ped, where it is still above 1 on some seeds (the note)."""
    data = seed1_campaign
    st = load_structure(HYBRID, trim=data.trim())
    truth = truth_for_structure(data.tree["linearization_full"].to_dataset(), st)
    fd = fit_frequency_domain(data, structure=HYBRID,
                              coherence_min=StudySettings(structure=HYBRID).fd_coherence)
    A = fd.model["A"].to_pandas()
    for entry in SPEED_ENTRIES:
        assert A.loc[entry] != 0.0, entry
    records = data.maneuvers("2311_*")
    assert set(records) == {"2311_lon", "2311_lat", "2311_col", "2311_ped"}
    for name, record in records.items():
        record.attrs.setdefault("maneuver", name)
        j = {label: float(verify(model, record, outputs=RIGID, source=label)["j_rms"]
                          .sel(source=label))
             for label, model in (("linearisation", truth), ("fd", fd.model))}
        assert j["linearisation"] <= J_RMS_MAX, (name, j)
        limit = J_RMS_MAX if name in ("2311_lon", "2311_lat") else J_RMS_GUIDELINE
        assert j["fd"] <= limit, (name, j)


# --- forward_hybrid (80 kt) against the truth's exact response -------------------------------
# docs/notes/2026-11-25-forward-hybrid-first-fit.md: with M_a1 free the fit ran into M_a1 -> 0
# while the a1 drives grew to 1e5 (30 min, M_q -100 %); the structure now ties M_a1 to L_b1 by
# the inertia ratio.

@pytest.fixture(scope="module")
def forward_lin(truth_fmu):
    trimmed = truth_trim(80.0, fmu=truth_fmu)
    return trimmed, truth_linearize(trimmed)


def test_forward_hybrid_on_the_full_linear_response(forward_lin):
    """forward_hybrid fitted (from its file's values, no reduction) to the exact 0.3-20 rad/s
    response of the truth's full 80-kt linearisation: the premise of the M_a1 = 0.2668 L_b1
    tie holds on the truth (within 2 %), and L_p, M_q, L_lat, M_lon come within 15 %, the
    flapping time constant within 20 % of the truth reduced to the structure. Measured and
    not asserted: Z_w -1 %, Z_col +55 %, N_r +14 % (the note)."""
    trimmed, lin = forward_lin
    st = load_structure("forward_hybrid", trim=trimmed.channel_values())
    truth = truth_for_structure(lin.full, st)
    A = truth["A"].to_pandas()
    assert A.loc["q", "a1"] / A.loc["p", "b1"] == pytest.approx(0.2668, rel=0.02)
    omega = np.logspace(np.log10(0.3), np.log10(20.0), 120)
    H = frequency_response(lin.full, omega).sel(output=list(st.outputs), input=list(st.inputs))
    g2 = xr.full_like(H.real, 0.95)
    fr = xr.Dataset({"H": H, "coherence": g2, "partial_coherence": g2,
                     "random_error": xr.full_like(H.real, 0.02)})
    pairs = [("q", "lon"), ("p", "lon"), ("u", "lon"), ("w", "lon"), ("p", "lat"),
             ("q", "lat"), ("v", "lat"), ("r", "lat"), ("w", "col"), ("r", "col"),
             ("p", "col"), ("q", "col"), ("u", "col"), ("r", "ped"), ("v", "ped"), ("p", "ped")]
    fit = identify_frequency_domain(fr, st, pairs=pairs, frequency_range=(0.3, 20.0),
                                    reduce=False, time_limit=300.0)
    assert fit.J_ave <= J_AVE_MAX
    got, want = _figures(fit.model), _figures(truth)
    for name in ("L_p", "M_q", "L_lat", "M_lon"):
        assert _error(got[name], want[name]) <= DERIVATIVE_TOL, (name, got[name], want[name])
    assert _error(got["tau_a1"], want["tau_a1"]) <= TAU_F_TOL, (got["tau_a1"], want["tau_a1"])


# --- The whole hybrid study with the sweeps flown in calm air (issue 22) ---------------------
# docs/notes/2026-11-27-hybrid-turbulence-lateral-speed-terms.md: in the default campaign's
# turbulence v/ped has no coherent range and the frequency-domain hybrid's lateral speed terms
# go undetermined (2311_col 0.91-1.95 on five seeds); with the sweeps flown in calm air (the
# 3211s and 2311s keep the turbulence) both models meet the issue's figures on the default
# seed (docs/notes/2026-11-27-hybrid-calm-sweeps.md).


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("SYSID_EXHAUSTIVE") != "1",
                    reason="a whole hover_hybrid study (about 60 s on 2 cores); "
                    "SYSID_EXHAUSTIVE=1 runs it")
def test_hybrid_study_with_calm_sweeps_meets_the_issue_figures(tmp_path):
    """`sysid run hover --structure hover_hybrid --calm-sweeps`, default seed: both domains'
    eight derivatives within 15 % of the truth for the structure and of each other, J_ave
    <= 50, flapping time constants within 20 %, 2311 J_rms <= 1 on every axis for both
    models, on 2311s flown in the campaign's turbulence."""
    from sysid.data.netcdf import read_campaign
    from sysid.pipeline.study import run_study

    run_study(tmp_path, StudySettings(structure=HYBRID, calm_sweeps=True), quiet=True)
    tree = read_campaign(tmp_path / "campaign.nc")
    assert tree["maneuvers/sweep_ped_1"].attrs["turbulence_m_s"] == 0.0
    assert tree["maneuvers/2311_col"].attrs["turbulence_m_s"] > 0.0
    truth = _figures(truth_for_structure(tree["linearization_full"].to_dataset(),
                                         load_structure(HYBRID,
                                                        trim=CampaignData(tree).trim())))
    models = {m: tree[f"models/{m}"].to_dataset() for m in ("frequency_domain", "time_domain")}
    assert models["frequency_domain"].attrs["J_ave"] <= J_AVE_MAX
    got = {m: _figures(ds) for m, ds in models.items()}
    for name in ("L_p", "M_q", "L_lat", "M_lon", "Z_w", "Z_col", "N_r", "N_ped"):
        for m in models:
            assert _error(got[m][name], truth[name]) <= DERIVATIVE_TOL, (m, name)
        assert _error(got["frequency_domain"][name],
                      got["time_domain"][name]) <= DERIVATIVE_TOL, name
    for name in ("tau_a1", "tau_b1"):
        for m in models:
            assert _error(got[m][name], truth[name]) <= TAU_F_TOL, (m, name)
    for maneuver in ("2311_lon", "2311_lat", "2311_col", "2311_ped"):
        ds = tree[f"verification/{maneuver}"].to_dataset()
        for m in models:
            assert float(ds["j_rms"].sel(source=m)) <= J_RMS_MAX, (maneuver, m)
