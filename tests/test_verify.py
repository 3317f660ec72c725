"""Time-domain verification (CIFER VERIFY) of held models on manoeuvres not used to fit them,
and the ``sysid identify-time`` / ``sysid verify`` commands."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from known_systems import (PLAN_2311, PLAN_3211, TRIM, add_noise, multistep_records,
                           truth_structure)

from sysid.core.errors import IdentificationError, InputDataError
from sysid.assess.metrics import J_RMS_GUIDELINE, TIC_GUIDELINE
from sysid.assess.stages import TRUTH_SOURCE, verify_models
from sysid.data.campaign import CampaignData
from sysid.assess.verification import merge_verifications, verification_table, verify, verify_maneuvers

OUTPUT_BIAS = {"q": 0.7, "u": -0.3, "psi": 1.2}
INPUT_OFFSET = {"lon": 1.5, "ped": -0.8}


@pytest.fixture(scope="module")
def truth_model():
    st = truth_structure()
    return st.to_dataset(attrs={"method": "truth_model"})


@pytest.fixture(scope="module")
def offset_records():
    """2311s whose measurements carry output biases and whose recorded controls are offset
    from the ones the aircraft flew (a rigging/reference offset), noise-free."""
    return multistep_records(plan=PLAN_2311, noise=0.0, bias=OUTPUT_BIAS,
                             input_offset=INPUT_OFFSET)


def test_recovers_injected_bias_and_reference_shift_exactly(truth_model, offset_records):
    for rec in offset_records:
        ds = verify(truth_model, rec, source="model")
        bias = ds["bias"].sel(source="model")
        for out in bias.channel.values:
            assert float(bias.sel(channel=out)) == pytest.approx(OUTPUT_BIAS.get(out, 0.0),
                                                                 abs=1e-9)
        shift = ds["reference_shift"].sel(source="model")
        for inp in shift.input.values:
            # the model must see the recorded input minus the recording offset
            assert float(shift.sel(input=inp)) == pytest.approx(-INPUT_OFFSET.get(inp, 0.0),
                                                                abs=1e-9)
        assert float(ds["j_rms"].sel(source="model")) < 1e-9
        assert float(ds["tic"].sel(source="model").max()) < 1e-9
        # overlays are absolute and equal to the record
        np.testing.assert_allclose(ds["q"].sel(source="truth"), rec["q"])
        np.testing.assert_allclose(ds["q"].sel(source="model"), rec["q"], atol=1e-9)


def test_metrics_equal_hand_computed_values(truth_model, offset_records):
    rec = offset_records[1]
    ds = verify(truth_model, rec, estimate=("bias",), source="model")
    outs = [str(c) for c in ds.channel.values]
    z = np.stack([rec[o].values - TRIM[o] for o in outs])  # perturbations about trim
    y = np.stack([ds[o].sel(source="model").values - TRIM[o] for o in outs])
    n_t = z.shape[1]
    j_rms = math.sqrt(np.sum((z - y) ** 2) / (n_t * len(outs)))
    assert float(ds["j_rms"].sel(source="model")) == pytest.approx(j_rms, rel=1e-12)
    rms = lambda a: np.sqrt(np.mean(a ** 2, axis=1))  # noqa: E731
    tic = rms(z - y) / (rms(z) + rms(y))
    np.testing.assert_allclose(ds["tic"].sel(source="model").values, tic, rtol=1e-12)
    assert j_rms > 0.1  # the reference shift was not estimated: a real error remains
    # only the biases were estimated: they minimise J_rms given the simulation, so each is the
    # mean of that output's error
    sim = verify(truth_model, rec, estimate=(), source="model")
    for j, o in enumerate(outs):
        err = rec[o].values - sim[o].sel(source="model").values
        assert float(ds["bias"].sel(source="model", channel=o)) == pytest.approx(err.mean())
    # weights enter J_rms as W_j
    w = verify(truth_model, rec, estimate=(), source="m", weights={"q": 4.0})
    e = np.stack([rec[o].values - w[o].sel(source="m").values for o in outs])
    wv = np.array([4.0 if o == "q" else 1.0 for o in outs])[:, None]
    assert float(w["j_rms"].sel(source="m")) == pytest.approx(
        math.sqrt(np.sum(wv * e ** 2) / (n_t * len(outs))), rel=1e-12)


def test_merge_several_models_of_one_maneuver(truth_model, offset_records):
    rec = offset_records[0]
    wrong = truth_structure().to_dataset(truth_structure().theta0 * 0.8,
                                         attrs={"method": "wrong"})
    a = verify(truth_model, rec)
    b = verify(wrong, rec)
    b2 = verify(wrong, rec, outputs=["p", "q"])  # verified again, fewer channels
    merged = merge_verifications([a, b])
    assert list(merged.source.values) == ["truth", "truth_model", "wrong"]
    assert merged["q"].dims == ("source", "time")
    assert merged["lon"].dims == ("time",)
    assert float(merged["j_rms"].sel(source="truth")) == 0.0
    assert float(merged["j_rms"].sel(source="wrong")) > float(merged["j_rms"].sel(
        source="truth_model"))
    again = merge_verifications([merged, b2])
    assert list(again.source.values) == ["truth", "truth_model", "wrong"]
    assert math.isnan(float(again["tic"].sel(source="wrong", channel="u")))
    assert float(again["tic"].sel(source="truth", channel="u")) == 0.0
    table = verification_table(merged)
    assert "PASS" in table and "truth_model" in table
    with pytest.raises(InputDataError, match="manoeuvres differ"):
        merge_verifications([a, verify(truth_model, offset_records[1])])
    assert set(verify_maneuvers(truth_model, offset_records[:2])) == {
        r.attrs["maneuver"] for r in offset_records[:2]}


def test_verify_errors(truth_model, offset_records):
    with pytest.raises(InputDataError, match="ped"):
        verify(truth_model, offset_records[0].drop_vars("ped"))
    with pytest.raises(InputDataError, match="cannot estimate"):
        verify(truth_model, offset_records[0], estimate=("gain",))
    with pytest.raises(InputDataError, match="truth"):
        verify(truth_model, offset_records[0], source="truth")


# ---------------------------------------------------------------------------------------------
# Command line: identify on 3211s, verify on 2311s
# ---------------------------------------------------------------------------------------------


def test_a_model_whose_fit_ran_away_is_reported_not_crashed_on(offset_records):
    """A parameter at 1e18 (a fit that ran away) makes the simulated response overflow; the
    verification names the model, the manoeuvre and the parameter instead of failing inside
    the least squares."""
    st = truth_structure()
    theta = st.theta0.copy()
    k = st.free_names.index("L_p")
    theta[k] = 1e18
    runaway = st.to_dataset(theta, attrs={"method": "frequency_domain"})
    with pytest.raises(IdentificationError, match=r"'frequency_domain' gives non-finite "
                       r"outputs on '2311_.*L_p = 1e\+18"):
        verify(runaway, offset_records[0])


def test_cli_identify_time_and_verify(tmp_path, capsys):
    from sysid.data import netcdf as io
    from sysid.cli import main

    path = tmp_path / "campaign.nc"
    records = add_noise(multistep_records(plan=PLAN_3211, noise=0.0, duration=10.0)
                        + multistep_records(plan=PLAN_2311, noise=0.0, duration=10.0), 1.0,
                        seed=5)
    for rec in records:
        io.append_maneuver(path, rec.attrs["maneuver"], rec)
    st = truth_structure()
    io.update_campaign(path, "models/frequency_domain",
                       st.to_dataset(st.theta0 * 1.1, attrs={"method": "frequency_domain"}))
    assert main(["identify-time", str(path), "--maneuvers", "3211_*", "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert "CR %" in printed and "tau_L_lon" in printed and "biases" in printed
    tree = io.read_campaign(path)
    model = tree["models/time_domain"].to_dataset()
    assert model.attrs["method"] == "time_domain"
    assert model.attrs["start"] == "model"  # from /models/frequency_domain
    assert set(model.attrs["records"].split(",")) == {"3211_lon_1", "3211_lat_2", "3211_col_3",
                                                      "3211_ped_4"}
    for name in ("X_u", "Y_v"):  # zero in the truth: removed by the reduction
        assert not bool(model["free"].sel(parameter=name))
    for name, v in zip(st.free_names, st.theta0):
        crb = float(model["cramer_rao"].sel(parameter=name))
        assert abs(float(model["value"].sel(parameter=name)) - v) <= 3.5 * crb, name

    assert main(["verify", str(path), "--model", "time_domain", "--maneuvers", "2311_*",
                 "--quiet"]) == 0
    printed = capsys.readouterr().out
    assert printed.count("verification of 2311_") == 4 and "PASS" in printed
    assert main(["verify", str(path), "--model", "frequency_domain", "--maneuvers",
                 "2311_lon*", "--quiet"]) == 0
    tree = io.read_campaign(path)
    ver = tree["verification/2311_lon_1"].to_dataset()
    assert list(ver.source.values) == ["truth", "time_domain", "frequency_domain"]
    jr = ver["j_rms"]
    assert float(jr.sel(source="time_domain")) <= J_RMS_GUIDELINE
    assert float(ver["tic"].sel(source="time_domain").max()) <= TIC_GUIDELINE
    assert float(jr.sel(source="frequency_domain")) > float(jr.sel(source="time_domain"))
    assert set(tree["verification"].children) == {f"2311_{a}_{i}" for i, a in
                                                  enumerate(("lon", "lat", "col", "ped"), 1)}


def test_cli_errors(tmp_path, capsys):
    from sysid.data import netcdf as io
    from sysid.cli import main

    path = tmp_path / "c.nc"
    rec = multistep_records(plan=PLAN_3211[:1], noise=0.0, duration=5.0)[0]
    io.append_maneuver(path, rec.attrs["maneuver"], rec)
    assert main(["identify-time", str(path), "--maneuvers", "sweep_*", "--quiet"]) == 1
    assert "no manoeuvre matches" in capsys.readouterr().err
    assert main(["verify", str(path), "--model", "time_domain", "--quiet"]) == 1
    assert "/models" in capsys.readouterr().err


def test_verification_group_round_trips_through_netcdf(tmp_path, truth_model, offset_records):
    from sysid.data import netcdf as io

    ds = verify(truth_model, offset_records[0])
    path = tmp_path / "v.nc"
    io.update_campaign(path, "verification/2311_lon_1", ds)
    back = io.read_campaign(path)["verification/2311_lon_1"].to_dataset()
    xr.testing.assert_allclose(back[["q", "tic", "j_rms"]], ds[["q", "tic", "j_rms"]])


def _campaign(records, models: dict, linearization=None) -> CampaignData:
    groups = {f"maneuvers/{r.attrs['maneuver']}": xr.DataTree(r) for r in records}
    groups.update({f"models/{m}": xr.DataTree(ds) for m, ds in models.items()})
    if linearization is not None:
        groups["linearization"] = xr.DataTree(linearization)
    return CampaignData(xr.DataTree.from_dict(groups), source="known system")


def test_a_simulation_campaign_verifies_the_truth_s_own_model_as_the_floor(offset_records):
    """The truth linearisation is verified beside the models: on records the truth itself
    produced (noise-free, offset biases and rigging) it reaches J_rms 0, a model 20 % off
    does not; one source per structure; none without a linearisation (flight data)."""
    st = truth_structure()
    truth = st.to_dataset(attrs={"method": "linearization", "structure": st.name})
    wrong = st.to_dataset(st.theta0 * 0.8, attrs={"method": "frequency_domain",
                                                  "structure": st.name})
    checked = verify_models(_campaign(offset_records, {"frequency_domain": wrong}, truth),
                            maneuvers="2311_*")
    assert len(checked) == len(offset_records)
    for ds in checked.values():
        assert list(ds.source.values) == ["truth", "frequency_domain", TRUTH_SOURCE]
        assert float(ds["j_rms"].sel(source=TRUTH_SOURCE)) < 1e-6
        assert float(ds["j_rms"].sel(source="frequency_domain")) > 0.05
    # two structures: one truth each, named by structure
    other = wrong.assign_attrs(method="time_domain", structure="other")
    two = verify_models(_campaign(offset_records[:1], {"frequency_domain": wrong,
                                                       "time_domain": other}, truth))
    (ds,) = two.values()
    assert sorted(map(str, ds.source.values)) == sorted(
        ["truth", "frequency_domain", "time_domain", f"{TRUTH_SOURCE}_{st.name}",
         f"{TRUTH_SOURCE}_other"])
    # flight data (no linearisation), or asked not to: the models only
    for data, kw in ((_campaign(offset_records[:1], {"frequency_domain": wrong}), {}),
                     (_campaign(offset_records[:1], {"frequency_domain": wrong}, truth),
                      {"truth": False})):
        (ds,) = verify_models(data, **kw).values()
        assert list(ds.source.values) == ["truth", "frequency_domain"]
