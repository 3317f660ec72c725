"""``sysid import`` into an existing campaign: nothing is lost, nothing is left stale.

A campaign of the truth FMU (three manoeuvres, trim, linearisations) with a frequency
response computed from its sweep and result groups laid out as the stages write them
(frequency- and time-domain models, verification, comparison, validation, handling
qualities, stage stamps). Importing an existing name is refused with the file left
bit-identical, as is a bad file; ``--replace`` removes exactly the groups computed from the
replaced manoeuvre and keeps everything else identical.
"""

from __future__ import annotations

import dataclasses
import shutil

import numpy as np
import pytest
import xarray as xr

from sysid.cli import main
from sysid.data import importers, netcdf
from sysid.data.stale import stale_groups

pytestmark = pytest.mark.fmu

_KEEP_ALWAYS = ("/trim", "/linearization", "/linearization_full", "/closed_loop")


@pytest.fixture(scope="module")
def campaign_file(truth_fmu, tmp_path_factory):
    from sysid.flight_test.campaign import default_campaign, run_campaign
    from sysid.spectral.response import frequency_response

    c = default_campaign(0.0)
    chosen = [dataclasses.replace(m, duration=20.0, omega_min=1.0) for m in c.maneuvers
              if m.name == "sweep_lon_1"]
    chosen += [m for m in c.maneuvers if m.name in ("3211_lon", "2311_lat")]
    path = tmp_path_factory.mktemp("replace") / "campaign.nc"
    tree = run_campaign(dataclasses.replace(c, maneuvers=chosen), path, quiet=True,
                        fmu=truth_fmu)
    fr = frequency_response([tree["maneuvers/sweep_lon_1"].to_dataset()], ["lon"], ["q"],
                            windows=[2.0, 4.0])
    assert list(fr.attrs["records"]) == ["sweep_lon_1"]
    model = xr.Dataset({"value": ("parameter", [1.0, -2.0])},
                       coords={"parameter": ["M_q", "M_lon"]})
    stamp = {"workflow_key": "abc", "workflow_elapsed_s": 1.0}
    groups = {
        "frequency_response": fr,
        "models/frequency_domain": model.assign_attrs(method="frequency_domain"),
        # the time-domain fit records the manoeuvres it used
        "models/time_domain": model.assign_attrs(method="time_domain", records="3211_lon"),
        "verification": xr.Dataset(attrs=stamp),
        "verification/2311_lat": xr.Dataset({"j_rms": ("source", [0.0, 1.0])},
                                            attrs={"maneuver": "2311_lat"}),
        "verification/3211_lon": xr.Dataset({"j_rms": ("source", [0.0, 1.0])},
                                            attrs={"maneuver": "3211_lon"}),
        "comparison": xr.Dataset({"value": ("parameter", [1.0])}),
        "validation": xr.Dataset(attrs=stamp),
        "validation/frequency_domain": xr.Dataset(attrs={"model": "frequency_domain"}),
        "handling_qualities": xr.Dataset({"bandwidth": ("axis", [2.0])}),
        "hold_margins": xr.Dataset({"phase_margin": ("hold", [45.0])},
                                   attrs={"model": "linearization_full"}),
    }
    netcdf.update_campaign_groups(path, groups)
    netcdf.set_group_attrs(path, "maneuvers", stamp)
    return path


@pytest.fixture
def campaign(campaign_file, tmp_path):
    path = tmp_path / "campaign.nc"
    shutil.copyfile(campaign_file, path)
    return path


def _changed(path, name, tmp_path, fmt="hdf5"):
    """A file holding manoeuvre ``name`` of the campaign with q offset by 1 deg/s."""
    ds = netcdf.read_campaign(path)[f"maneuvers/{name}"].to_dataset()
    ds["q"] = ds["q"] + 1.0
    out = tmp_path / f"new_{name}.{'h5' if fmt == 'hdf5' else 'mat'}"
    importers.write_time_histories(out, {name: ds}, format=fmt)
    return out, ds


def _paths(tree):
    return {node.path for node in tree.subtree}


def test_an_existing_name_or_a_bad_file_leaves_the_campaign_bit_identical(campaign, tmp_path,
                                                                         capsys):
    before = campaign.read_bytes()
    old = netcdf.read_campaign(campaign)
    new, _ = _changed(campaign, "3211_lon", tmp_path)
    assert main(["import", str(new), "-o", str(campaign)]) == 1
    err = capsys.readouterr().err
    assert "'3211_lon'" in err and "--replace" in err
    assert campaign.read_bytes() == before
    bad = tmp_path / "bad.csv"
    bad.write_text("time [s],q [deg/s]\n0,1\n0.01,nan\n")
    fresh = tmp_path / "fresh.h5"
    ds = netcdf.read_campaign(campaign)["maneuvers/2311_lat"].to_dataset()
    importers.write_time_histories(fresh, {"2311_lat_again": ds}, format="hdf5")
    assert main(["import", str(fresh), str(bad), "-o", str(campaign), "--replace"]) == 1
    assert "line 3" in capsys.readouterr().err
    assert campaign.read_bytes() == before
    # a new name is added and nothing else changes
    assert main(["import", str(fresh), "-o", str(campaign)]) == 0
    assert "removed" not in capsys.readouterr().out
    now = netcdf.read_campaign(campaign)
    assert _paths(now) == _paths(old) | {"/maneuvers/2311_lat_again"}
    for path in _paths(old):
        xr.testing.assert_identical(now[path].to_dataset(inherit=False),
                                    old[path].to_dataset(inherit=False))


@pytest.mark.parametrize("name, removed", [
    # used only by its own verification
    ("2311_lat", {"/verification/2311_lat"}),
    # fitted by the time-domain model: the model and everything built from models
    ("3211_lon", {"/models/time_domain", "/verification", "/comparison", "/validation",
                  "/handling_qualities"}),
    # the frequency response's record: the response, the frequency-domain model and on
    ("sweep_lon_1", {"/frequency_response", "/models/frequency_domain", "/verification",
                     "/comparison", "/validation", "/handling_qualities"}),
])
def test_replace_removes_exactly_what_was_computed_from_the_manoeuvre(campaign, tmp_path,
                                                                      capsys, name, removed):
    old = netcdf.read_campaign(campaign)
    new, ds = _changed(campaign, name, tmp_path)
    assert main(["import", str(new), "-o", str(campaign), "--replace"]) == 0
    out = capsys.readouterr().out
    assert f"replaced {name}" in out
    for group in removed:
        assert f"removed {group} (" in out
    now = netcdf.read_campaign(campaign)
    gone = {p for p in _paths(old) - _paths(now)}
    assert {p for p in gone if not any(p.startswith(r + "/") for r in removed)} == removed
    # the new data are in, everything else is identical (values and attributes)
    np.testing.assert_array_equal(now[f"maneuvers/{name}"]["q"].values, ds["q"].values)
    for path in _paths(now) - {f"/maneuvers/{name}", "/maneuvers", "/verification",
                               "/validation"}:
        xr.testing.assert_identical(now[path].to_dataset(inherit=False),
                                    old[path].to_dataset(inherit=False))
    for path in _KEEP_ALWAYS + ("/hold_margins",):
        assert path in _paths(now)
    # stage stamps that described the old inputs are gone, the rest of the attrs kept
    assert "workflow_key" not in now["maneuvers"].attrs
    for parent in ("/verification", "/validation"):
        if parent in _paths(now):
            lost_children = any(g.startswith(parent + "/") for g in removed)
            assert ("workflow_key" in now[parent].attrs) != lost_children
    assert now.attrs == old.attrs


def test_unknown_groups_are_removed_and_an_untouched_campaign_has_nothing_stale(campaign):
    tree = netcdf.read_campaign(campaign)
    assert stale_groups(tree, ["not_there"]) == {}
    netcdf.update_campaign(campaign, "someone_elses/result", xr.Dataset({"x": ("k", [1.0])}))
    tree = netcdf.read_campaign(campaign)
    assert "/someone_elses" in stale_groups(tree, ["2311_lat"])
    assert "/someone_elses" not in stale_groups(tree, [])
