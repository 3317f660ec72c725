"""Tests of sysid.data (netcdf, importers, campaign): exact netCDF round trips, plain-reader compatibility, CSV import errors,
and the ``sysid import`` / ``sysid export-csv`` commands."""

from __future__ import annotations

import netCDF4
import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sysid.data import campaign, importers, netcdf
from sysid.cli import main
from sysid.core.errors import InputDataError
from sysid.core.units import channel_attrs


def _time_history(name="sweep_lon_1", n=300, dt=0.01, seed=0):
    g = np.random.default_rng(seed)
    t = np.arange(n) * dt
    return xr.Dataset(
        {
            "lon": ("time", 50 + g.standard_normal(n), channel_attrs("lon")),
            "q": ("time", g.standard_normal(n), channel_attrs("q")),
            "theta": ("time", g.standard_normal(n).astype(np.float32), channel_attrs("theta")),
        },
        coords={"time": ("time", t, {"units": "s", "long_name": "time"})},
        attrs={"maneuver": name, "kind": "sweep", "axis": "lon", "seed": 7,
               "flight_condition": "hover", "airspeed_kt": 0.0, "trim_lon": 50.0},
    )


def _campaign():
    g = np.random.default_rng(1)
    freq = np.logspace(-1, 1.3, 7)
    fr = xr.Dataset(
        {
            "H": (("output", "input", "frequency"),
                  g.standard_normal((2, 2, 7)) + 1j * g.standard_normal((2, 2, 7))),
            "Gxx": (("input", "input_j", "frequency"),
                    (g.standard_normal((2, 2, 7)) + 1j * g.standard_normal((2, 2, 7)))
                    .astype(np.complex64)),
            "coherence": (("output", "input", "frequency"), g.random((2, 2, 7))),
            "collinear": ("frequency", np.array([True, False] * 3 + [True])),
            "count": ("frequency", np.arange(7, dtype=np.int32)),
        },
        coords={"output": ["u", "q"], "input": ["lon", "lat"], "input_j": ["lon", "lat"],
                "frequency": ("frequency", freq, {"units": "rad/s"})},
        attrs={"conditioned": True, "overlap": 0.8, "windows": [5.0, 10.0, 20.0],
               "note": None, "options": {"C_eps": 0.1, "names": ["a", "b"]},
               "inputs": ["lon", "lat"], "single": [3.0], "pair": (1, 2), "z": 1 - 2j},
    )
    model = xr.Dataset(
        {"A": (("state_dot", "state"), g.standard_normal((2, 2))),
         "free": ("parameter", np.array([True, False])),
         "matrix": ("parameter", np.array(["A", "B"]))},
        coords={"state": ["u", "q"], "state_dot": ["u", "q"], "parameter": ["Xu", "Mq"]},
        attrs={"method": "frequency_domain", "cost": 12.5},
    )
    return xr.DataTree.from_dict({
        "/": xr.Dataset(attrs={"campaign": "test", "seed": 3}),
        "maneuvers/sweep_lon_1": _time_history("sweep_lon_1"),
        "maneuvers/3211_lat_1": _time_history("3211_lat_1", seed=2),
        "frequency_response": fr,
        "models/frequency_domain": model,
        "models/deep/nested/group": xr.Dataset({"x": ("k", [1, 2, 3])}),
    })


# --------------------------------------------------------------------------------------------
# netCDF campaigns


def test_campaign_round_trip_is_exact(tmp_path):
    tree = _campaign()
    path = tmp_path / "c.nc"
    netcdf.write_campaign(tree, path)
    back = netcdf.read_campaign(path)
    xr.testing.assert_identical(back, tree)
    fr, fr0 = back["frequency_response"], tree["frequency_response"]
    assert fr["H"].dtype == np.complex128 and fr["Gxx"].dtype == np.complex64
    assert fr["collinear"].dtype == bool and fr["count"].dtype == np.int32
    assert back["maneuvers/sweep_lon_1"]["theta"].dtype == np.float32
    # bit-exact, not just close
    assert fr["H"].values.tobytes() == fr0["H"].values.tobytes()
    attrs = fr.attrs
    assert attrs["conditioned"] is True and attrs["note"] is None
    assert attrs["options"] == {"C_eps": 0.1, "names": ["a", "b"]}
    assert attrs["single"] == [3.0] and attrs["pair"] == (1, 2) and attrs["z"] == 1 - 2j
    assert "complex" not in fr.dims


def test_campaign_opens_in_plain_netcdf4(tmp_path):
    tree = _campaign()
    path = tmp_path / "c.nc"
    netcdf.write_campaign(tree, path)
    with netCDF4.Dataset(path) as nc:
        h = nc["frequency_response"].variables["H"]
        assert h.dimensions == ("output", "input", "frequency", "complex")
        assert h.getncattr("sysid_complex") == 1
        raw = h[:]
        q = nc["maneuvers/sweep_lon_1"].variables["q"][:]
        assert nc["maneuvers/sweep_lon_1"].variables["q"].getncattr("units") == "deg/s"
    H = tree["frequency_response"]["H"].values
    np.testing.assert_array_equal(raw[..., 0], H.real)
    np.testing.assert_array_equal(raw[..., 1], H.imag)
    np.testing.assert_array_equal(q, tree["maneuvers/sweep_lon_1"]["q"].values)


def test_read_campaign_closes_file_so_it_can_be_replaced(tmp_path):
    path = tmp_path / "c.nc"
    netcdf.write_campaign(_campaign(), path)
    tree = netcdf.read_campaign(path)
    netcdf.update_campaign(path, "models/time_domain", xr.Dataset({"c": 1.0}))
    # the earlier in-memory copy is intact and the new file has the new group
    assert "time_domain" not in tree["models"].children
    assert float(netcdf.read_campaign(path)["models/time_domain"]["c"]) == 1.0
    assert tree["frequency_response"].attrs["overlap"] == 0.8


def test_update_campaign_insert_replace_and_keep_children(tmp_path):
    path = tmp_path / "new" / "c.nc"
    netcdf.append_maneuver(path, "sweep_lon_1", _time_history("sweep_lon_1"))
    netcdf.append_maneuver(path, "sweep_lon_2", _time_history("sweep_lon_2", seed=5))
    netcdf.append_maneuver(path, "sweep_lon_10", _time_history("sweep_lon_10", seed=6))
    netcdf.update_campaign(path, "frequency_response", xr.Dataset({"a": ("f", [1.0, 2.0])}))
    netcdf.update_campaign(path, "frequency_response", xr.Dataset({"b": ("f", [3.0])}))
    # a Dataset on a parent group keeps the children
    netcdf.update_campaign(path, "maneuvers", xr.Dataset(attrs={"count": 3}))
    tree = netcdf.read_campaign(path)
    assert list(tree["frequency_response"].data_vars) == ["b"]
    assert tree["maneuvers"].attrs["count"] == 3
    assert campaign.list_maneuvers(tree) == ["sweep_lon_1", "sweep_lon_2", "sweep_lon_10"]
    assert campaign.list_maneuvers(tree, "sweep_lon_1*") == ["sweep_lon_1", "sweep_lon_10"]
    assert campaign.list_maneuvers(tree, "3211_*") == []
    ds = campaign.maneuvers(tree, "sweep_lon_2")
    xr.testing.assert_identical(ds[0], _time_history("sweep_lon_2", seed=5))
    # a DataTree replaces the whole sub-tree
    sub = xr.DataTree.from_dict({"only": _time_history("only")})
    netcdf.update_campaign(path, "maneuvers", sub)
    assert campaign.list_maneuvers(netcdf.read_campaign(path)) == ["only"]


def test_appending_new_groups_gives_the_same_campaign_as_a_full_rewrite(tmp_path, monkeypatch):
    """New groups are appended to a copy of the file instead of rewriting the campaign; the
    file read back must be what writing the whole combined tree gives."""
    path = tmp_path / "c.nc"
    netcdf.write_campaign(_campaign(), path)
    g = np.random.default_rng(4)
    model = xr.Dataset(
        {"A": (("state_dot", "state"), g.standard_normal((2, 2)) + 1j),
         "free": ("parameter", np.array([True, False]))},
        coords={"state": ["u", "q"], "state_dot": ["u", "q"], "parameter": ["Xu", "Mq"]},
        attrs={"method": "time_domain", "flag": True, "names": ["a", "b"], "none": None})
    sub = xr.DataTree.from_dict({"2311_col": xr.Dataset({"j_rms": ("source", [1.0, 2.0])}),
                                 "2311_lon": xr.Dataset(attrs={"note": "empty"})})

    def no_rewrite(*args, **kwargs):
        raise AssertionError("a new group must not rewrite the campaign")

    monkeypatch.setattr(netcdf, "_rewrite_groups", no_rewrite)
    netcdf.update_campaign(path, "models/time_domain", model)
    netcdf.update_campaign(path, "verification", sub)
    netcdf.append_maneuver(path, "2311_ped_1", _time_history("2311_ped_1", seed=9))
    expected = _campaign()
    expected["models/time_domain"] = xr.DataTree(model)
    expected["verification"] = sub
    expected["maneuvers/2311_ped_1"] = xr.DataTree(_time_history("2311_ped_1", seed=9))
    reference = tmp_path / "reference.nc"
    netcdf.write_campaign(expected, reference)
    xr.testing.assert_identical(netcdf.read_campaign(path), netcdf.read_campaign(reference))
    assert netcdf.read_campaign(path)["models/time_domain"].attrs["names"] == ["a", "b"]
    # replacing an existing group still works (through the full rewrite)
    monkeypatch.undo()
    netcdf.update_campaign(path, "models/time_domain", xr.Dataset({"c": 1.0}))
    assert list(netcdf.read_campaign(path)["models/time_domain"].data_vars) == ["c"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc", "reference.nc"]


def test_group_attributes_are_read_and_set_without_touching_the_data(tmp_path):
    path = tmp_path / "c.nc"
    assert netcdf.group_attrs(path, "frequency_response") is None  # no file
    netcdf.write_campaign(_campaign(), path)
    assert netcdf.group_attrs(path, "models/missing") is None
    attrs = netcdf.group_attrs(path, "frequency_response")
    assert attrs["options"] == {"C_eps": 0.1, "names": ["a", "b"]} and attrs["z"] == 1 - 2j
    before = netcdf.read_campaign(path)
    netcdf.set_group_attrs(path, "models/deep/nested/group", {"workflow_key": "abc", "ok": True})
    after = netcdf.read_campaign(path)
    node = after["models/deep/nested/group"]
    assert node.attrs == {"workflow_key": "abc", "ok": True}
    xr.testing.assert_identical(node.to_dataset().drop_attrs(),
                                before["models/deep/nested/group"].to_dataset().drop_attrs())
    netcdf.set_group_attrs(path, "frequency_response", {"overlap": 0.5})
    fr = netcdf.read_campaign(path)["frequency_response"]
    assert fr.attrs["overlap"] == 0.5 and fr.attrs["pair"] == (1, 2)
    xr.testing.assert_identical(fr.to_dataset(), after["frequency_response"].to_dataset()
                                .assign_attrs(overlap=0.5))
    content = path.read_bytes()
    with pytest.raises(InputDataError, match="no group '/models/missing'"):
        netcdf.set_group_attrs(path, "models/missing", {"x": 1})
    with pytest.raises(InputDataError, match="thing"):
        netcdf.set_group_attrs(path, "frequency_response", {"thing": object()})
    assert path.read_bytes() == content
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc"]
    junk = tmp_path / "junk.nc"
    junk.write_bytes(b"not netcdf")
    assert netcdf.group_attrs(junk, "frequency_response") is None


def _update_many(path: str, writer: int, count: int) -> None:
    for k in range(count):
        netcdf.update_campaign(path, f"models/writer{writer}_{k}",
                               xr.Dataset({"value": ("parameter", [float(k)])}))


def test_concurrent_updates_from_processes_keep_every_group(tmp_path):
    """Two processes of one machine each adding groups to one campaign (e.g. two ``sysid``
    commands on one file): every group of both survives. Without the lock in update_campaign each
    read-modify-write can drop the other process's last group."""
    import multiprocessing

    path = tmp_path / "c.nc"
    netcdf.write_campaign(_campaign(), path)
    context = multiprocessing.get_context("spawn")
    workers = [context.Process(target=_update_many, args=(str(path), w, 12)) for w in (0, 1)]
    for w in workers:
        w.start()
    for w in workers:
        w.join(120)
        assert w.exitcode == 0
    written = {n for n in netcdf.read_campaign(path)["models"].children if n.startswith("writer")}
    assert written == {f"writer{w}_{k}" for w in (0, 1) for k in range(12)}
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc"]   # no lock file left


def test_write_failure_leaves_previous_file(tmp_path):
    path = tmp_path / "c.nc"
    netcdf.write_campaign(_campaign(), path)
    before = path.read_bytes()
    bad = xr.Dataset(attrs={"thing": object()})
    with pytest.raises(InputDataError, match="thing"):
        netcdf.update_campaign(path, "bad", bad)
    assert path.read_bytes() == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["c.nc"]


def test_read_campaign_errors(tmp_path):
    with pytest.raises(InputDataError, match="does not exist"):
        netcdf.read_campaign(tmp_path / "missing.nc")
    junk = tmp_path / "junk.nc"
    junk.write_bytes(b"not a netcdf file at all")
    with pytest.raises(InputDataError, match="junk.nc"):
        netcdf.read_campaign(junk)


# --------------------------------------------------------------------------------------------
# validate_time_history


def test_validate_time_history_returns_dt_and_names_problems():
    ds = _time_history()
    assert importers.validate_time_history(ds, ["lon", "q"]) == pytest.approx(0.01, rel=1e-12)
    with pytest.raises(InputDataError, match=r"missing channel\(s\) \['r'\].*available"):
        importers.validate_time_history(ds, ["q", "r"])
    bad = ds.copy(deep=True)
    bad["q"][17] = np.nan
    with pytest.raises(InputDataError, match=r"'q'.*sample 17 \(time 0.17 s\)"):
        importers.validate_time_history(bad, ["q"])
    t = ds.time.values.copy()
    t[40] += 0.003
    with pytest.raises(InputDataError, match="not uniform at sample 40"):
        importers.validate_time_history(ds.assign_coords(time=t))
    t = ds.time.values.copy()
    t[[10, 11]] = t[[11, 10]]
    with pytest.raises(InputDataError, match="not strictly increasing at sample 11"):
        importers.validate_time_history(ds.assign_coords(time=t))
    with pytest.raises(InputDataError, match="no 'time' coordinate"):
        importers.validate_time_history(ds.rename(time="t"))


# --------------------------------------------------------------------------------------------
# CSV


def test_csv_round_trip_values_and_attrs(tmp_path):
    ds = _time_history()
    path = tmp_path / "sweep_lon_1.csv"
    importers.write_csv(ds, path)
    assert path.read_text().splitlines()[1] == "time [s],lon [%],q [deg/s],theta [deg]"
    back = importers.read_time_history(path)
    for ch in ("lon", "q", "theta"):
        np.testing.assert_array_equal(back[ch].values, ds[ch].values.astype(float))
        assert back[ch].attrs["units"] == ds[ch].attrs["units"]
    np.testing.assert_array_equal(back.time.values, ds.time.values)
    for key in ("maneuver", "kind", "axis", "seed", "flight_condition", "trim_lon"):
        assert back.attrs[key] == ds.attrs[key]


def test_read_csv_mapping_units_kind_and_trim(tmp_path):
    t = np.arange(500) * 0.02 + 12.0  # logger time does not start at zero
    q_rad = 0.1 * np.sin(t)
    lines = ["T_S;DLON_PCT;Q_RADS;PHI"]
    lines += [f"{a:.2f};{50 + 0.0 * a:.17g};{b:.17g};{0.5}".replace(".", ",")
              for a, b in zip(t, q_rad)]
    path = tmp_path / "2311_lon_flight12.csv"
    path.write_text("\n".join(lines) + "\n")
    ds = importers.read_time_history(
        path, mapping={"time": "T_S", "lon": "DLON_PCT", "q": "Q_RADS", "phi": "PHI"},
        units={"q": "rad/s", "phi": "rad"}, trim={"phi": 1.25})
    np.testing.assert_allclose(ds.q.values, np.degrees(q_rad), rtol=1e-12)
    assert ds.q.attrs["units"] == "deg/s" and ds.q.attrs["source_column"] == "Q_RADS"
    assert ds.time.values[0] == 0.0 and ds.attrs["time_offset"] == pytest.approx(12.0)
    assert importers.validate_time_history(ds, ["lon", "q"]) == pytest.approx(0.02)
    assert ds.attrs["kind"] == "2311" and ds.attrs["axis"] == "lon"
    assert ds.attrs["maneuver"] == "2311_lon_flight12"
    assert ds.attrs["trim_phi"] == 1.25
    # first-second mean: samples with time < 1 s
    assert ds.attrs["trim_q"] == pytest.approx(np.degrees(q_rad[:50]).mean(), rel=1e-12)
    assert ds.attrs["trim_lon"] == pytest.approx(50.0)
    named = importers.read_time_history(path, mapping={"time": "T_S", "lon": "DLON_PCT"},
                                 kind="sweep", name="flight12_run3")
    assert named.attrs["kind"] == "sweep" and named.attrs["maneuver"] == "flight12_run3"
    assert list(named.data_vars) == ["lon"]


def test_read_whitespace_and_netcdf_from_other_tools(tmp_path):
    t = np.arange(200) * 0.05
    txt = tmp_path / "doublet_ped.txt"
    txt.write_text("time  ped   r\n"
                   + "\n".join(f"{a:.17g} {np.cos(a):.17g}  {a:.17g}" for a in t))
    ds = importers.read_time_history(txt)
    assert ds.attrs["kind"] == "doublet" and ds.attrs["axis"] == "ped"
    np.testing.assert_array_equal(ds.ped.values, np.cos(t))
    nc = tmp_path / "other.nc"
    xr.Dataset({"Q_DEGS": ("time", np.sin(t), {"units": "deg/s"})},
               coords={"time": ("time", t + 100.0, {"units": "seconds since 2024-01-01"})}
               ).to_netcdf(nc)
    ds = importers.read_time_history(nc, mapping={"q": "Q_DEGS"})
    np.testing.assert_array_equal(ds.q.values, np.sin(t))
    np.testing.assert_allclose(ds.time.values, t, atol=1e-12)
    assert ds.attrs["kind"] == "imported"


def _csv(tmp_path, text, name="f.csv"):
    path = tmp_path / name
    path.write_text(text)
    return path


@pytest.mark.parametrize(
    "text, kwargs, pattern",
    [
        ("", {}, "is empty"),
        ("# only a comment\n\n", {}, "is empty"),
        ("time,q\n", {}, "no data rows"),
        ("time|q|r\n0|1|2\n", {}, "single column"),
        ("time,q\n0;1\n", {}, r"line 2: 1 field\(s\), expected 2"),
        ("time,q\n0,1\n0.1,abc\n", {}, r"line 3, column 'q': 'abc' is not a number"),
        ("time,q\n0,1\n0.1,nan\n", {}, r"line 3, column 'q'.*not finite"),
        ("time,q\n0,1\n0.1,\n", {}, r"line 3, column 'q': '' is not a number"),
        ("time,q\n0,1\n0.2,1\n0.1,1\n", {}, "not strictly increasing at line 4"),
        ("time,q\n0,1\n0.1,1\n0.25,1\n0.3,1\n", {}, "not uniform at line 4"),
        ("time,q\n0,1\n0.1,1\n", {"mapping": {"q": "Q_DEGS"}},
         r"\['Q_DEGS'\] not found .*\{'q': 'Q_DEGS'\}"),
        ("x,q\n0,1\n0.1,1\n", {}, "no time column"),
        ("time,q\n0,1\n0.1,1\n", {"units": {"q": "furlong"}}, "unknown unit 'furlong'"),
        ("time,q,q\n0,1,1\n0.1,1,1\n", {}, "duplicate"),
        ("time,q\n0,1\n0.1,1\n", {"trim": {"bogus": 1.0}},
         r"trim given for unknown channel\(s\) \['bogus'\]"),
    ],
)
def test_read_csv_errors_name_the_problem(tmp_path, text, kwargs, pattern):
    path = _csv(tmp_path, text)
    with pytest.raises(InputDataError, match=pattern) as info:
        importers.read_time_history(path, **kwargs)
    assert "f.csv" in str(info.value)


def test_read_binary_garbage_and_missing_file(tmp_path):
    path = tmp_path / "g.csv"
    path.write_bytes(bytes(range(256)))
    with pytest.raises(InputDataError, match="UTF-8"):
        importers.read_time_history(path)
    with pytest.raises(InputDataError, match="does not exist"):
        importers.read_time_history(tmp_path / "nope.csv")
    fake = tmp_path / "fake.nc"
    fake.write_bytes(b"CDF\x01garbage")
    with pytest.raises(InputDataError, match="fake.nc"):
        importers.read_time_history(fake)


_cell = st.one_of(st.floats(allow_nan=True, allow_infinity=True).map(repr),
                  st.text(alphabet=",;\t .-+e0123456789nanif#[]\"'x", max_size=6))


@settings(max_examples=60, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(header=st.lists(st.text(alphabet="tqime,; []", max_size=6), min_size=1, max_size=4),
       rows=st.lists(st.lists(_cell, max_size=4), max_size=5),
       sep=st.sampled_from([",", ";", "\t", " "]))
def test_fuzz_malformed_files_raise_only_input_data_error(tmp_path, header, rows, sep):
    path = tmp_path / "fuzz.csv"
    path.write_text("\n".join([sep.join(header)] + [sep.join(r) for r in rows]))
    try:
        ds = importers.read_time_history(path)
    except InputDataError:
        return
    assert isinstance(ds, xr.Dataset) and ds.sizes["time"] >= 2


@settings(max_examples=40, deadline=None, database=None,
          suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(data=st.binary(max_size=200))
def test_fuzz_binary_files_raise_only_input_data_error(tmp_path, data):
    path = tmp_path / "fuzz.dat"
    path.write_bytes(data)
    try:
        importers.read_time_history(path)
    except InputDataError:
        pass


# --------------------------------------------------------------------------------------------
# command line


def _write_flight_csv(path, n=400, dt=0.01, lon_col="DLON", q_unit="rad/s"):
    t = np.arange(n) * dt
    path.write_text("time [s]," + f"{lon_col} [%],Q [{q_unit}]\n"
                    + "\n".join(f"{a:.17g},{50 + np.sin(a):.17g},{0.01 * np.cos(a):.17g}"
                                for a in t))
    return t


def test_cli_import_and_export(tmp_path, capsys):
    f1, f2 = tmp_path / "sweep_lon_1.csv", tmp_path / "run7.csv"
    t = _write_flight_csv(f1)
    _write_flight_csv(f2)
    out = tmp_path / "campaign.nc"
    rc = main(["import", str(f1), str(f2), "-o", str(out), "--map", "lon=DLON,q=Q",
               "--kind", "3211", "--trim", "theta=2.5,lon=49"])
    assert rc == 0
    tree = netcdf.read_campaign(out)
    assert campaign.list_maneuvers(tree) == ["run7", "sweep_lon_1"]
    ds = tree["maneuvers/sweep_lon_1"].to_dataset()
    assert ds.attrs["kind"] == "3211" and ds.attrs["trim_lon"] == 49.0
    assert ds.attrs["trim_theta"] == 2.5
    # header unit rad/s converted to the analysis unit deg/s
    np.testing.assert_allclose(ds.q.values, np.degrees(0.01 * np.cos(t)), rtol=1e-12)
    assert tree.attrs["campaign"] == "campaign"
    csv = tmp_path / "exported.csv"
    assert main(["export-csv", str(out), "sweep_lon_1", "-o", str(csv)]) == 0
    back = importers.read_time_history(csv)
    np.testing.assert_array_equal(back.q.values, ds.q.values)
    assert back.attrs["maneuver"] == "sweep_lon_1"
    # --units overrides the header unit
    out2 = tmp_path / "c2.nc"
    assert main(["import", str(f1), "-o", str(out2), "--map", "lon=DLON", "--map", "q=Q",
                 "--units", "q=deg/s"]) == 0
    q = netcdf.read_campaign(out2)["maneuvers/sweep_lon_1"]["q"].values
    np.testing.assert_allclose(q, 0.01 * np.cos(t), rtol=1e-12)


def test_cli_failure_leaves_no_output(tmp_path, capsys):
    good, bad = tmp_path / "sweep_lon_1.csv", tmp_path / "bad.csv"
    _write_flight_csv(good)
    bad.write_text("time [s],DLON [%],Q [rad/s]\n0,1,2\n0.01,1,oops\n")
    out = tmp_path / "campaign.nc"
    rc = main(["import", str(good), str(bad), "-o", str(out), "--map", "lon=DLON,q=Q"])
    assert rc == 1
    err = capsys.readouterr().err
    assert "bad.csv" in err and "line 3" in err and "'Q'" in err
    assert not out.exists()
    assert sorted(p.name for p in tmp_path.iterdir()) == ["bad.csv", "sweep_lon_1.csv"]
    assert main(["import", str(good), "-o", str(out), "--map", "lon=MISSING"]) == 1
    assert "MISSING" in capsys.readouterr().err and not out.exists()
    assert main(["import", str(good), "-o", str(out), "--map", "lonDLON"]) == 1
    assert "NAME=VALUE" in capsys.readouterr().err
    # export of an unknown manoeuvre names the available ones and writes nothing
    assert main(["import", str(good), "-o", str(out), "--map", "lon=DLON,q=Q"]) == 0
    csv = tmp_path / "x.csv"
    assert main(["export-csv", str(out), "nope", "-o", str(csv)]) == 1
    assert "sweep_lon_1" in capsys.readouterr().err and not csv.exists()


def test_trim_from_attrs_takes_each_channel_from_the_first_numeric_source():
    trim_from_attrs = campaign.trim_from_attrs
    first = {"trim_lon": 40.0, "trim_q": "n/a"}
    second = xr.Dataset(attrs={"trim_lon": 99.0, "trim_q": 0.5, "trim_theta": 2.7})
    assert trim_from_attrs([first, second]) == {"lon": 40.0, "q": 0.5, "theta": 2.7}
    assert trim_from_attrs([]) == {}


def test_one_trim_rule_for_records_with_and_without_trim_attributes():
    """docs/data_model.md: the ``trim_<channel>`` attribute, else the mean of the first
    second (samples with t < 1 s); the time-domain fit and verification apply it."""
    from sysid.assess.verification import _trim as verification_trim
    from sysid.identify.time_domain import _trim_of
    from sysid.spectral.spectra import perturbations

    ds = _time_history(n=300, dt=0.01)
    del ds.attrs["trim_lon"]
    expected = float(ds["q"].values[:100].mean())   # 0.00 .. 0.99 s
    assert campaign.record_trim(ds, "q") == expected
    assert _trim_of(ds, "q") == expected and verification_trim(ds, "q") == expected
    # the spectra need no trim level: without the attribute they take the record's mean
    signal = perturbations([ds], ["q", "lon"], ["lon"])[0]
    np.testing.assert_allclose(signal.sel(channel="q").values, ds["q"].values
                               - float(ds["q"].values.mean()))
    assert campaign.record_trim(ds, "q", missing="record_mean") == float(ds["q"].values.mean())
    ds.attrs["trim_q"] = 0.25
    assert campaign.record_trim(ds, "q") == 0.25
    ds.attrs["trim_q"] = float("nan")   # not given: the rule's fallback
    assert campaign.record_trim(ds, "q") == expected
    ds.attrs["trim_q"] = "level"
    with pytest.raises(InputDataError, match="trim_q"):
        campaign.record_trim(ds, "q")
