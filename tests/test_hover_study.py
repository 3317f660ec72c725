"""The paper's hover study on the truth FMU, end to end (the README's main command).

The session's run of :func:`sysid.pipeline.study.run_study` (``hover_study`` in conftest.py,
shared with the other modules) with the default campaign
(sensor noise and light turbulence on, fixed seed) feeds every check here but a few, which fly
the campaign's sweeps at other amplitudes and lateral rises, or in the linear regime, to show
where q/lon's former miss of MUAD came from; each assertion is
against independent truth: the truth FMU's own linearisation, its time responses, the MUAD
envelopes and the guideline values of the literature. Takes about 2 min on one core.
"""

from __future__ import annotations

import os
import re

import numpy as np
import pytest
import xarray as xr

from browser import chromium  # noqa: F401  (pytest fixture)

from sysid.core.errors import InputDataError
from sysid.flight_test.campaign import default_campaign
from sysid.pipeline.study import StudySettings, campaign_from_file

pytestmark = pytest.mark.fmu

ON_AXIS = (("q", "lon"), ("p", "lat"), ("w", "col"), ("r", "ped"))
DOMINANT = ("Z_w", "M_q", "L_p", "N_r", "M_lon", "L_lat", "Z_col", "N_ped")
CYCLIC_DELAYS = ("tau_M_lon", "tau_L_lon", "tau_L_lat", "tau_M_lat")


@pytest.fixture(scope="module")
def study(hover_study):
    """The session's hover study (conftest.py), shared with the other modules that read it:
    the suite runs the study once (it ran twice, ~75 s each, when this module had its own)."""
    return hover_study


def _perturbation(ds: xr.Dataset, channel: str) -> np.ndarray:
    return ds[channel].values - ds.attrs[f"trim_{channel}"]


def test_rerun_of_finished_parts_recomputes_nothing(study):
    """Every stage is stamped with its cache key and the seconds it took; a re-run of the
    parts before the results finds them all cached and so leaves the campaign untouched."""
    from sysid.core.errors import SysidError
    from sysid.pipeline.study import PARTS, StudySettings, run_study

    path = study["dir"] / "campaign.nc"
    before = path.stat().st_mtime_ns
    assert run_study(study["dir"], StudySettings(), quiet=True, parts=PARTS[:-1]) is None
    assert path.stat().st_mtime_ns == before
    html = study["report"].read_text()
    for group in ("maneuvers", "frequency_response", "models/frequency_domain",
                  "models/time_domain", "comparison", "validation"):
        assert re.search(rf"{group} [0-9.]+ s", html), group
    with pytest.raises(SysidError, match="unknown part"):
        run_study(study["dir"], StudySettings(), quiet=True, parts=("fit",))


def test_editing_the_structure_file_invalidates_the_fits(tmp_path, truth_fmu):
    """The fits are cached by the structure's text, not its name: an edited structure file
    re-runs both identifications, while the campaign and the spectra stay cached."""
    from sysid.models import structure_path
    from sysid.pipeline.study import StudySettings, _Study

    toml = tmp_path / "mine.toml"
    toml.write_text(structure_path("hover_6dof").read_text())
    before = _Study(tmp_path / "study", StudySettings(structure=str(toml)), quiet=True)
    toml.write_text(toml.read_text().replace("N_r = { value = -0.3185 }",
                                             "N_r = { value = -0.5 }"))
    after = _Study(tmp_path / "study", StudySettings(structure=str(toml)), quiet=True)
    assert (before.key_campaign, before.key_fr) == (after.key_campaign, after.key_fr)
    assert before.key_fd != after.key_fd and before.key_td != after.key_td


# -- Flight-test campaign (issue 3) -------------------------------------------------------
def test_sweeps_stay_near_trim_and_move_every_control(study):
    tree = study["tree"]
    sweeps = [n for n in tree["maneuvers"].children if n.startswith("sweep_")]
    assert len(sweeps) == 8
    for name in sweeps:
        ds = tree[f"maneuvers/{name}"].to_dataset()
        for c in ("phi", "theta"):
            assert np.abs(_perturbation(ds, c)).max() <= 30.0, (name, c)
        for c in ("u", "v", "w"):
            assert np.abs(_perturbation(ds, c)).max() <= 30.0, (name, c)
        primary = ds.attrs["axis"]
        rms = {c: np.std(_perturbation(ds, c)) for c in ("lon", "lat", "col", "ped")}
        for c, value in rms.items():
            if c != primary:
                assert value >= 0.1 * rms[primary], (name, c, value, rms[primary])


def test_campaign_reports_cross_control_coherence(study):
    summary = study["tree"]["cross_control_coherence"].to_dataset()
    mean = summary["mean_cross_coherence"]
    assert set(mean.axis.values) == {"lon", "lat", "col", "ped"}
    diagonal = [float(mean.sel(axis=a, input=a, input_j=a)) for a in mean.axis.values]
    np.testing.assert_allclose(diagonal, 1.0, atol=1e-9)
    off = [float(mean.sel(axis=a, input=a, input_j=b)) for a in mean.axis.values
           for b in mean.axis.values if a != b]
    assert all(0.0 <= v < 1.0 for v in off) and max(off) > 0.05   # the holds correlate them


# -- Frequency responses (issue 4) ----------------------------------------------------------
def test_on_axis_composite_coherence_is_high_from_1_to_10_rad_s(study):
    fr = study["tree"]["frequency_response"].to_dataset()
    band = fr.frequency.where((fr.frequency >= 1.0) & (fr.frequency <= 10.0), drop=True)
    for out, inp in ON_AXIS:
        gamma2 = fr.partial_coherence.sel(output=out, input=inp, frequency=band)
        assert float(gamma2.min()) >= 0.8, (out, inp, float(gamma2.min()))


def test_composite_agrees_with_the_full_linearisation_within_muad(study):
    """Against the FMU's full linearisation (rotor, inflow and actuator states included)."""
    from sysid.models import frequency_response
    from sysid.assess.envelopes import MUAD, check_envelope, mismatch

    tree = study["tree"]
    fr = tree["frequency_response"].to_dataset()
    full = frequency_response(tree["linearization_full"].to_dataset(), fr.frequency.values)
    fractions = {}
    for out, inp in ON_AXIS:
        truth = full.sel(output=out, input=inp)
        # Eq. 20: model (here the linearisation) over the flight data (the composite).
        result = check_envelope(mismatch(truth, fr.H.sel(output=out, input=inp)), MUAD,
                                coherence=fr.partial_coherence.sel(output=out, input=inp))
        fractions[f"{out}/{inp}"] = float(result.fraction_inside)
    # All four inside everywhere the coherence is >= 0.6 (issue 4). q/lon used to leave the
    # gain bound near 0.4 rad/s, where the full-amplitude lateral sweep takes the truth out of
    # its linear range next to the pitch-roll oscillation (the test below); the hover
    # campaign's cubic lateral rise keeps it inside.
    assert all(fraction == 1.0 for fraction in fractions.values()), fractions


# -- Where q/lon's miss comes from, and the campaign without it (issue 4) --------------------
def _sweep_responses(fmu, campaign):
    """Fly ``campaign`` and return it with the conditioned composite responses of u..r."""
    from sysid.spectral.response import frequency_response
    from sysid.data.campaign import maneuvers
    from sysid.flight_test.campaign import run_campaign
    from sysid.core.units import CONTROLS

    tree = run_campaign(campaign, quiet=True, fmu=fmu)
    fr = frequency_response(maneuvers(tree, "sweep_*"), CONTROLS, ["u", "v", "w", "p", "q", "r"])
    return tree, fr


def _mismatch_to_linearisation(tree, fr, out, inp):
    from sysid.models import frequency_response
    from sysid.assess.envelopes import mismatch

    full = frequency_response(tree["linearization_full"].to_dataset(), fr.frequency.values)
    return mismatch(full.sel(output=out, input=inp), fr.H.sel(output=out, input=inp))


def test_q_lon_miss_near_the_pitch_roll_oscillation_shrinks_with_amplitude(truth_fmu):
    """Noise-free and calm, so no estimator sees noise: if the composite's excess over the
    linearisation at 0.3-0.5 rad/s were the estimator's (leakage, conditioning), it would not
    depend on the amplitude flown. With the linear lateral rise (the campaign whose q/lon
    left MUAD) it falls from about 4.4 dB at the default amplitude to about 0.5 dB at a
    quarter of it: the truth model is nonlinear there at the flown amplitudes. The default
    hover campaign's cubic lateral rise keeps the lateral sweep small near the pitch-roll
    oscillation and takes the full-amplitude excess to about 3.3 dB. (Measured on the
    leakage-free responses, the default since issue 21; the plain estimate gave 5.4, 1.8 and
    3.9 dB: part of the excess was leakage, the amplitude dependence remains.)"""
    import dataclasses

    from sysid.flight_test.campaign import LINEAR_LATERAL_RISE, default_campaign

    cubic = default_campaign(0.0, noise=False).select("sweep_*")
    fraction, full_omega, shape = LINEAR_LATERAL_RISE
    linear = dataclasses.replace(cubic, maneuvers=[
        dataclasses.replace(m, low_frequency_fraction=fraction, full_amplitude_omega=full_omega,
                            amplitude_shape=shape) if m.axis == "lat" else m
        for m in cubic.maneuvers])
    excess = {}
    for label, sweeps, scale in (("linear", linear, 1.0), ("linear", linear, 0.25),
                                 ("cubic", cubic, 1.0)):
        campaign = dataclasses.replace(sweeps, maneuvers=[
            dataclasses.replace(m, amplitude=scale * m.amplitude) for m in sweeps.maneuvers])
        tree, fr = _sweep_responses(truth_fmu, campaign)
        error = _mismatch_to_linearisation(tree, fr, "q", "lon")
        band = error.magnitude.sel(frequency=slice(0.3, 0.5))
        excess[label, scale] = float(-band.min())   # model / data in dB: data above -> < 0
    print(f"q/lon excess over the linearisation at 0.3-0.5 rad/s: {excess}")
    assert excess["linear", 1.0] > 4.0             # the effect is there to be explained
    assert excess["linear", 0.25] < 0.5 * excess["linear", 1.0]
    assert excess["cubic", 1.0] < 0.8 * excess["linear", 1.0]


def _check_linear_regime_campaign(fmu, seed):
    """Fly :func:`sysid.flight_test.campaign.linear_regime_campaign` with ``seed`` and assert issue 4's
    check; returns the per-pair inside fractions and minimum coherence over 1-10 rad/s."""
    from sysid.flight_test.campaign import linear_regime_campaign
    from sysid.assess.envelopes import MUAD, check_envelope

    tree, fr = _sweep_responses(fmu, linear_regime_campaign(0.0, seed=seed))
    assert float(tree.attrs["airspeed_kt"]) == 0.0 and "turbulence = 0.0" in tree.attrs[
        "campaign_toml"]
    measured = {}
    for out, inp in ON_AXIS:
        coherence = fr.partial_coherence.sel(output=out, input=inp)
        result = check_envelope(_mismatch_to_linearisation(tree, fr, out, inp), MUAD,
                                coherence=coherence)
        measured[f"{out}/{inp}"] = (float(result.fraction_inside),
                                    float(coherence.sel(frequency=slice(1.0, 10.0)).min()))
    print(f"linear-regime campaign, seed {seed}: (inside MUAD, min coherence 1-10 rad/s) "
          f"{measured}")
    for pair, (inside, coherence_min) in measured.items():
        assert coherence_min >= 0.8, (seed, pair, coherence_min)
        assert inside == 1.0, (seed, pair, inside)
    return measured


def test_linear_regime_campaign_agrees_with_the_full_linearisation_within_muad(truth_fmu):
    """Issue 4's check where the truth is close to linear (sysid.flight_test.campaign.
    linear_regime_campaign: cyclic and pedal sweeps at half amplitude, calm air, sensor noise
    on): every on-axis pair has coherence >= 0.8 over 1-10 rad/s and lies inside MUAD
    wherever its coherence is >= 0.6. q/lon is still 3-7 dB high at 0.3-0.5 rad/s."""
    _check_linear_regime_campaign(truth_fmu, 20261121)


#: Other noise seeds of the linear-regime check: one in the default (reduced) run, seven with
#: SYSID_EXHAUSTIVE=1.
#: Seed 3 fails since the leakage-free default (issue 21, open): q/lon at 0.37-0.49 rad/s,
#: next to the unstable pitch-roll oscillation, is 24-28 deg outside the MUAD phase bound at
#: coherence 0.63-0.75 with any set of transient states, and inside with the plain estimate
#: (docs/notes/2026-11-24-leakage-free-by-default.md). Strict: it fails once it passes again.
#: Seed 4 the same (found 2026-11-27, with and without the zero-order hold divided out): q/lon
#: at 0.40-0.41 rad/s, coherence 0.62-0.66, 4.3 deg outside the phase bound.
_NEAR_OSCILLATION = pytest.mark.xfail(
    strict=True, reason="leakage-free q/lon phase near the pitch-roll oscillation, issue 21")
_SEED_3 = pytest.param(3, marks=_NEAR_OSCILLATION)
OTHER_SEEDS = ([pytest.param(s, marks=_NEAR_OSCILLATION) if s in (3, 4) else s
                for s in range(1, 8)]
               if os.environ.get("SYSID_EXHAUSTIVE") == "1" else (_SEED_3,))


@pytest.mark.slow
@pytest.mark.parametrize("seed", OTHER_SEEDS)
def test_linear_regime_check_holds_for_other_noise_seeds(truth_fmu, seed):
    """The same check with other sensor-noise and pilot-activity seeds, so that the default
    seed's pass is not luck."""
    _check_linear_regime_campaign(truth_fmu, seed)


# -- Frequency-domain identification (issue 5) ---------------------------------------------
def _check_frequency_domain_fit(J_ave, pair_costs, value, truth):
    """Issue 5's check of a hover_6dof fit: J_ave, every pair's cost, the cyclic delays and
    the dominant derivatives against the truth's quasi-steady linearisation."""
    assert J_ave <= 100.0
    assert max(pair_costs.values()) <= 200.0, pair_costs
    for name in CYCLIC_DELAYS:
        assert 0.05 <= value(name) <= 0.3, (name, value(name))
    for name in DOMINANT:
        got, expected = value(name), float(truth.value.sel(parameter=name))
        assert abs(got - expected) <= 0.3 * abs(expected), (name, got, expected)


def test_frequency_domain_identification_matches_the_truth(study):
    """The study's own frequency-domain fit (hover_6dof from the truth's linearisation, with
    reduction, on the study's responses). This test used to repeat that very fit (~20 s of
    CPU; the same J_ave to 1e-10); SYSID_EXHAUSTIVE=1 still does (the test below)."""
    from sysid.report.read import pair_costs

    tree = study["tree"]
    model = tree["models/frequency_domain"].to_dataset()
    assert model.attrs["start_source"] == "/linearization" and model.attrs["reduction"]
    values = dict(zip(map(str, model.parameter.values), model.value.values))
    _check_frequency_domain_fit(float(model.attrs["J_ave"]), pair_costs(model),
                                lambda name: float(values[name]),
                                tree["linearization"].to_dataset())


@pytest.mark.slow
@pytest.mark.skipif(os.environ.get("SYSID_EXHAUSTIVE") != "1",
                    reason="refits the study's frequency-domain model (~20 s of CPU); the "
                    "default run checks the study's own fit; SYSID_EXHAUSTIVE=1 runs it")
def test_frequency_domain_identification_from_the_truth_repeats_the_study(study):
    """The library call on its own (not the study's stage): the same check, and the same
    minimum as the study's fit."""
    from sysid.identify import identify_frequency_domain
    from sysid.models import load_structure

    tree = study["tree"]
    fr = tree["frequency_response"].to_dataset()
    truth = tree["linearization"].to_dataset()
    trim = {k[5:]: v for k, v in tree["maneuvers/sweep_lon_1"].attrs.items()
            if k.startswith("trim_")}
    result = identify_frequency_domain(fr, load_structure("hover_6dof", trim=trim), start=truth)
    _check_frequency_domain_fit(
        result.J_ave, {k: float(v) for k, v in result.pair_cost.items() if "/" in k},
        result.value, truth)
    study_J_ave = float(tree["models/frequency_domain"].attrs["J_ave"])
    assert result.J_ave == pytest.approx(study_J_ave, rel=1e-6)


# -- Time-domain identification, verification, comparison (issue 6) ------------------------
def test_time_domain_model_is_the_reduced_filter_error_model(study):
    """The study's default time-domain estimator is filter error (its bounds are the
    calibrated ones, issue 21): reduced as output error's, its four noise starts recorded,
    process noise on every measured state, its bounds corrected for coloured innovations."""
    import json

    model = study["tree"]["models/time_domain"].to_dataset()
    assert model.attrs["method"] == "filter_error"
    assert model.attrs["reduction"] == 1 and model.attrs["removed_parameters"]
    assert "cramer_rao_corrected" in model and "innovation_covariance" in model
    starts = json.loads(model.attrs["noise_starts"])
    assert len(starts) == 4 and all(len(s) == 3 for s in starts)
    assert json.loads(model.attrs["process_noise_entries"]) == [[s, s] for s in (
        "u", "v", "w", "p", "q", "r", "phi", "theta", "psi")]


def test_both_models_predict_2311_responses_they_were_not_fitted_to(study):
    tree = study["tree"]
    primary = {"lon": "q", "lat": "p", "col": "w", "ped": "r"}
    verified = [n for n in tree["verification"].children if n.startswith("2311_")]
    assert len(verified) == 4
    for name in verified:
        ds = tree[f"verification/{name}"].to_dataset()
        axis = tree[f"maneuvers/{name}"].attrs["axis"]
        assert float(ds.j_rms.sel(source="time_domain")) <= 1.5, name
        assert float(ds.tic.sel(source="time_domain", channel=primary[axis])) <= 0.25, name
        assert float(ds.j_rms.sel(source="frequency_domain")) <= 2.0, name
    fitted = tree["models/time_domain"].attrs["records"]
    assert "2311" not in str(fitted)


def test_comparison_table_is_written_and_dominant_signs_agree(study):
    from sysid.assess.comparison import sign_agreement

    table = study["tree"]["comparison"].to_dataset()
    assert set(table.model.values) == {"frequency_domain", "time_domain"}
    assert (study["dir"] / "comparison.csv").stat().st_size > 0
    agree = sign_agreement(table)
    assert bool(agree.all()), dict(zip(agree.parameter.values, agree.values))
    for name in ("M_q", "L_p", "Z_w", "N_r"):   # damping derivatives: negative, as physics says
        assert (table.value.sel(parameter=name) < 0).all()


# -- Export and validation against the truth FMU (issue 7) --------------------------------
def test_exported_models_run_beside_the_truth_fmu(study):
    tree = study["tree"]
    for model in ("frequency_domain", "time_domain"):
        assert (study["dir"] / f"{model}.fmu").exists()
        ds = tree[f"validation/{model}"].to_dataset()
        assert float(ds.roundtrip_cs.max()) <= 1e-6     # FMU vs sysid's own simulation
        assert float(ds.roundtrip_me.max()) <= 1e-3
        assert np.all(np.isfinite(ds.j_rms.values)) and float(ds.j_rms.mean()) <= 2.0
        assert np.all(np.isfinite(ds.tic.values))


# -- Report (issue 8) -----------------------------------------------------------------------
def test_report_opens_in_a_browser_with_every_figure(study, chromium):  # noqa: F811
    from pathlib import Path

    report = study["report"]
    html = report.read_text()
    assert "http://" not in html and "https://" not in html
    for table in ("Table 1", "Table 2", "Table 3"):
        assert table in html
    dom = chromium.dump_dom(report)
    m = re.search(r'id="image-check"[^>]*data-loaded="(\d+)"[^>]*data-total="(\d+)"', dom)
    assert m, "the load script did not run"
    loaded, total = int(m.group(1)), int(m.group(2))
    assert total >= 25 and loaded == total
    numbers = re.findall(r"<td[^>]*>\s*-?\d+\.\d+", dom)
    assert len(numbers) > 100
    artifacts = Path(__file__).resolve().parent.parent / "test-artifacts"
    chromium.screenshot(report, artifacts / "hover_report.png", size=(1280, 3000))


def test_a_campaign_file_takes_the_study_s_seed_and_noise_and_must_match_its_airspeed(
        tmp_path):
    # `sysid run hover --campaign FILE --seed 3` flies the file's campaign with seed 3 (the
    # seed was silently the file's before); --no-noise switches its noise off; a file at
    # another airspeed than the study's is refused, naming both.
    path = tmp_path / "mine.toml"
    path.write_text(default_campaign(0.0, seed=1).to_toml())
    assert campaign_from_file(path, StudySettings()).seed == 1
    flown = campaign_from_file(path, StudySettings(seed=3, noise=False))
    assert flown.seed == 3 and flown.noise == {} and flown.turbulence == 0.0
    assert campaign_from_file(path, StudySettings(seed=3)).turbulence == 0.3
    with pytest.raises(InputDataError, match="flies at 0 kt, the study is at 80 kt"):
        campaign_from_file(path, StudySettings(airspeed_kt=80.0))
