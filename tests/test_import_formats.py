"""MATLAB v5 / v7.3 and HDF5 time histories (sysid.data.formats, read/write_time_histories,
``sysid import``): round trips of real manoeuvres of the truth FMU through every format, a
MAT v5 in a user's own layout written by scipy, a MAT v7.3 read by an independent reader
(the ``mat73`` package), and the errors bad files get."""

from __future__ import annotations

import dataclasses

import h5py
import numpy as np
import pytest
import scipy.io
import scipy.sparse
import xarray as xr

from sysid.cli import main
from sysid.core.errors import InputDataError
from sysid.data import importers, netcdf
from sysid.data.campaign import first_window_mean
from sysid.data.formats import sniff_format

#: Attributes the import adds (where the data came from).
_ADDED = ("source_file", "time_offset")


@pytest.fixture(scope="module")
def flown(truth_fmu):
    """Three manoeuvres of the truth FMU (a short sweep, a 3211 and a 2311) with sensor noise
    and turbulence, as stored in /maneuvers: ``{name: Dataset}``."""
    from sysid.flight_test.campaign import default_campaign, run_campaign

    c = default_campaign(0.0)
    chosen = [dataclasses.replace(m, duration=20.0, omega_min=1.0) for m in c.maneuvers
              if m.name == "sweep_lon_1"]
    chosen += [m for m in c.maneuvers if m.name in ("3211_lon", "2311_lat")]
    tree = run_campaign(dataclasses.replace(c, maneuvers=chosen), quiet=True, fmu=truth_fmu)
    return {n: tree[f"maneuvers/{n}"].to_dataset() for n in ("sweep_lon_1", "3211_lon",
                                                              "2311_lat")}


def _same_manoeuvre(back: xr.Dataset, original: xr.Dataset) -> None:
    """Values bit-equal, units and every original attribute kept."""
    assert list(back.data_vars) == list(original.data_vars)
    np.testing.assert_array_equal(back.time.values, original.time.values)
    for name, var in original.data_vars.items():
        np.testing.assert_array_equal(back[name].values, var.values, err_msg=name)
        assert back[name].attrs["units"] == var.attrs["units"]
    for key, value in original.attrs.items():
        assert back.attrs[key] == value or (value != value and back.attrs[key] != back.attrs[key]), key
    assert back.attrs["time_offset"] == 0.0


@pytest.mark.fmu
def test_every_format_imports_to_the_same_campaign(flown, tmp_path, capsys):
    """CSV (one file per manoeuvre), MAT v5, MAT v7.3 and HDF5 (one file holding all three)
    give identical campaigns, each manoeuvre bit-equal to the one flown. The files carry
    misleading extensions: the format is sniffed from the content."""
    files = {"csv": [], "mat5": [tmp_path / "flight.dat"], "mat73": [tmp_path / "flight.h5"],
             "hdf5": [tmp_path / "flight.mat"]}
    for name, ds in flown.items():
        files["csv"].append(tmp_path / f"{name}.txt")
        importers.write_time_histories(files["csv"][-1], {name: ds}, format="csv")
    for fmt in ("mat5", "mat73", "hdf5"):
        importers.write_time_histories(files[fmt][0], flown, format=fmt)
        assert sniff_format(files[fmt][0]) == fmt
    campaigns = {}
    for fmt, paths in files.items():
        out = tmp_path / f"campaign_{fmt}.nc"
        assert main(["import", *map(str, paths), "-o", str(out)]) == 0
        assert "imported 3 manoeuvre(s)" in capsys.readouterr().out
        tree = netcdf.read_campaign(out)
        assert sorted(tree["maneuvers"].children) == sorted(flown)
        for name, original in flown.items():
            _same_manoeuvre(tree[f"maneuvers/{name}"].to_dataset(), original)
        campaigns[fmt] = {n: tree[f"maneuvers/{n}"].to_dataset().drop_attrs(deep=False)
                          for n in flown}
    for fmt in ("mat5", "mat73", "hdf5"):
        for name in flown:
            xr.testing.assert_identical(campaigns[fmt][name], campaigns["csv"][name])
    with pytest.raises(InputDataError, match="a CSV file holds one"):
        importers.write_time_histories(tmp_path / "x.csv", flown, format="csv")


@pytest.mark.fmu
def test_mat73_is_read_by_an_independent_reader(flown, tmp_path):
    """The ``mat73`` package (MATLAB v7.3 reader on h5py, not ours) sees one struct per
    manoeuvre with the vectors, the units sub-struct and a valid MATLAB name for 3211_lon;
    the user block holds MATLAB's header."""
    mat73 = pytest.importorskip("mat73")
    path = tmp_path / "flight.mat"
    importers.write_time_histories(path, flown, format="mat73")
    head = path.read_bytes()[:128]
    assert head.startswith(b"MATLAB 7.3 MAT-file") and head[124:128] == b"\x00\x02IM"
    content = mat73.loadmat(str(path))
    assert sorted(content) == ["m2311_lat", "m3211_lon", "sweep_lon_1"]
    s = content["m3211_lon"]
    np.testing.assert_array_equal(np.ravel(s["q"]), flown["3211_lon"]["q"].values)
    np.testing.assert_array_equal(np.ravel(s["time"]), flown["3211_lon"].time.values)
    assert s["units"]["q"] == "deg/s" and s["units"]["lon"] == "%"
    assert '"maneuver": "3211_lon"' in s["sysid_attrs"]


@pytest.mark.fmu
def test_mat5_in_a_users_own_layout(flown, tmp_path):
    """scipy.io.savemat with a struct per manoeuvre, time in field ``t`` on the logger's
    clock, the pitch rate in rad/s under another name: ``--time t --map --units``."""
    structs = {}
    for name, ds in flown.items():
        structs[name.replace("3211", "run3211").replace("2311", "run2311")] = {
            "t": ds.time.values + 1234.5, "DLON": ds.lon.values,
            "Q_RADS": np.radians(ds.q.values), "THETA": ds.theta.values,
            "note": "pilot A"}
    path = tmp_path / "flight12.mat"
    scipy.io.savemat(path, structs)
    out = tmp_path / "c.nc"
    assert main(["import", str(path), "-o", str(out), "--time", "t",
                 "--map", "lon=DLON,q=Q_RADS,theta=THETA", "--units", "q=rad/s",
                 "--kind", "sweep"]) == 0
    tree = netcdf.read_campaign(out)
    assert sorted(tree["maneuvers"].children) == sorted(structs)
    for name, ds in flown.items():
        user = name.replace("3211", "run3211").replace("2311", "run2311")
        back = tree[f"maneuvers/{user}"].to_dataset()
        assert list(back.data_vars) == ["lon", "q", "theta"]
        np.testing.assert_array_equal(back.lon.values, ds.lon.values)
        np.testing.assert_allclose(back.q.values, ds.q.values, rtol=1e-14, atol=1e-12)
        assert back.q.attrs["units"] == "deg/s" and back.q.attrs["source_column"] == "Q_RADS"
        np.testing.assert_allclose(back.time.values, ds.time.values, atol=1e-9)
        assert back.attrs["time_offset"] == pytest.approx(1234.5)
        assert back.attrs["kind"] == "sweep" and back.attrs["maneuver"] == user
        assert back.attrs["trim_theta"] == pytest.approx(
            first_window_mean(ds.time.values, ds.theta.values), rel=1e-12)


def test_flat_vectors_are_one_manoeuvre_named_by_the_file(tmp_path):
    t = np.arange(300) * 0.02
    path = tmp_path / "doublet_ped_7.mat"
    scipy.io.savemat(path, {"time": t, "ped": 50 + np.sin(t), "r": np.cos(t),
                            "units": {"r": "rad/s"}})
    records = importers.read_time_histories(path)
    (ds,) = records.values()
    assert list(records) == ["doublet_ped_7"] and ds.attrs["kind"] == "doublet"
    np.testing.assert_allclose(ds.r.values, np.degrees(np.cos(t)), rtol=1e-14)
    # the same as plain HDF5 datasets with a units attribute
    h5 = tmp_path / "doublet_ped_8.h5"
    with h5py.File(h5, "w") as f:
        f["time"] = t
        f["r"] = np.cos(t)
        f["r"].attrs["units"] = "rad/s"
    ds = importers.read_time_history(h5)
    np.testing.assert_allclose(ds.r.values, np.degrees(np.cos(t)), rtol=1e-14)


def test_mat73_as_matlab_lays_it_out(tmp_path):
    """A v7.3 file built by hand as MATLAB stores it: column vectors as (1, n) datasets, a
    row vector as (n, 1), single and int16 classes, char units as uint16 code units."""
    t = np.arange(100) * 0.05
    path = tmp_path / "any_name.bin"
    with h5py.File(path, "w", userblock_size=512) as f:
        g = f.create_group("flight_3")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        for name, data, cls in (("time", t.reshape(1, -1), "double"),
                                ("q", np.sin(t).astype(np.float32).reshape(-1, 1), "single"),
                                ("lon", (50 + 10 * np.cos(t)).astype(np.int16).reshape(1, -1),
                                 "int16")):
            g[name] = data
            g[name].attrs["MATLAB_class"] = np.bytes_(cls)
        u = g.create_group("units")
        u.attrs["MATLAB_class"] = np.bytes_("struct")
        u["q"] = np.array([ord(c) for c in "rad/s"], dtype=np.uint16).reshape(-1, 1)
        u["q"].attrs["MATLAB_class"] = np.bytes_("char")
        u["q"].attrs["MATLAB_int_decode"] = np.int32(2)
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file, Platform: GLNXA64".ljust(116) + bytes(8) + b"\x00\x02IM")
    assert sniff_format(path) == "mat73"
    ds = importers.read_time_histories(path)["flight_3"]
    np.testing.assert_allclose(ds.q.values, np.degrees(np.sin(t).astype(np.float32).astype(float)),
                               rtol=1e-15)
    np.testing.assert_array_equal(ds.lon.values, (50 + 10 * np.cos(t)).astype(np.int16))
    assert ds.attrs["kind"] == "imported"


# -- errors --------------------------------------------------------------------------------


def _mat5(tmp_path, content, name="f.mat"):
    path = tmp_path / name
    scipy.io.savemat(path, content)
    return path


def test_errors_name_the_struct_the_field_and_the_sample(tmp_path):
    t = np.arange(50) * 0.1
    path = _mat5(tmp_path, {"run1": {"T_S": t, "Q": t}})
    with pytest.raises(InputDataError, match=r"struct 'run1': no time field 'time'; "
                                             r"fields: \['T_S', 'Q'\].*--time NAME"):
        importers.read_time_histories(path)
    with pytest.raises(InputDataError, match=r"struct 'run1': field\(s\) \['QQ'\] not found "
                                             r".*'q': 'QQ'.*fields in the file: \['T_S', 'Q'\]"):
        importers.read_time_histories(path, time="T_S", mapping={"q": "QQ"})
    bad = t.copy()
    bad[17] = np.nan
    path = _mat5(tmp_path, {"run1": {"time": t, "q": bad}})
    with pytest.raises(InputDataError, match=r"struct 'run1', sample 17, field 'q'.*not finite"):
        importers.read_time_histories(path)
    back = t.copy()
    back[30] = back[28]
    path = _mat5(tmp_path, {"run1": {"time": back, "q": t}})
    with pytest.raises(InputDataError, match="not strictly increasing at sample 30"):
        importers.read_time_histories(path)
    jitter = t.copy()
    jitter[22] += 0.01
    path = _mat5(tmp_path, {"run1": {"time": jitter, "q": t}})
    with pytest.raises(InputDataError, match="not uniform at sample 22.*--resample"):
        importers.read_time_histories(path)
    with pytest.raises(InputDataError, match=r"field 'q' has shape \(2, 25\); expected a "
                                             "vector of 50"):
        importers.read_time_histories(_mat5(tmp_path, {"run1": {"time": t, "q": t.reshape(
            2, 25)}}), mapping={"q": "q"})


def test_unsupported_files_and_classes_are_refused_clearly(tmp_path):
    t = np.arange(50) * 0.1
    v4 = tmp_path / "old.mat"
    scipy.io.savemat(v4, {"time": t, "q": t}, format="4")
    assert sniff_format(v4) == "mat4"
    with pytest.raises(InputDataError, match="MAT v4 file.*-v7"):
        importers.read_time_histories(v4)
    # A channel-name cell beside the vectors is skipped and listed; needed, it is refused.
    cell = _mat5(tmp_path, {"run1": {"time": t, "q": t,
                                     "names": np.array(["a", "bb"], dtype=object)}})
    ds = importers.read_time_histories(cell)["run1"]
    assert list(ds.data_vars) == ["q"] and "names (cell" in ds.attrs["ignored_fields"]
    with pytest.raises(InputDataError, match=r"run1'.names: MATLAB class cell"):
        importers.read_time_histories(cell, mapping={"q": "q", "r": "names"})
    with pytest.raises(InputDataError, match=r"run1'.names: MATLAB class cell"):
        importers.read_time_histories(cell, time="names")
    sparse = _mat5(tmp_path, {"run1": {"time": t, "q": scipy.sparse.csc_matrix(t[:, None])}})
    with pytest.raises(InputDataError, match=r"run1'.q: MATLAB class sparse"):
        importers.read_time_histories(sparse, mapping={"q": "q"})
    path = tmp_path / "cell73.mat"
    with h5py.File(path, "w", userblock_size=512) as f:
        f["#refs#/a"] = np.zeros((1, 1))
        g = f.create_group("run1")
        g.attrs["MATLAB_class"] = np.bytes_("struct")
        g["time"] = t.reshape(1, -1)
        g["time"].attrs["MATLAB_class"] = np.bytes_("double")
        ref = g.create_dataset("names", (1, 1), dtype=h5py.ref_dtype)
        ref[0, 0] = f["#refs#/a"].ref
        ref.attrs["MATLAB_class"] = np.bytes_("cell")
    with open(path, "r+b") as fh:
        fh.write(b"MATLAB 7.3 MAT-file".ljust(116) + bytes(8) + b"\x00\x02IM")
    with pytest.raises(InputDataError, match=r"'run1'.names: MATLAB class 'cell' is not "
                                             "supported"):
        importers.read_time_histories(path, mapping={"q": "names"})
    assert "names (cell)" in importers.read_time_histories(path)["run1"].attrs["ignored_fields"]
    broken = tmp_path / "broken.mat"
    broken.write_bytes(b"MATLAB 5.0 MAT-file" + bytes(200))
    with pytest.raises(InputDataError, match="broken.mat"):
        importers.read_time_histories(broken)


@pytest.mark.parametrize("fmt", ["mat5", "mat73", "hdf5"])
def test_truncated_or_corrupted_files_raise_only_input_data_error(tmp_path, fmt):
    """Seeded byte flips and truncations of a valid file: read cleanly or refused with
    InputDataError, never another exception (h5py and scipy raise many kinds)."""
    t = np.arange(200) * 0.01
    ds = xr.Dataset({"q": ("time", np.sin(t), {"units": "deg/s"})},
                    coords={"time": ("time", t, {"units": "s"})}, attrs={"maneuver": "a"})
    path = tmp_path / "f"
    importers.write_time_histories(path, {"a": ds}, format=fmt)
    raw = path.read_bytes()
    g = np.random.default_rng(23)
    for k in range(40):
        data = bytearray(raw)
        if k % 2:
            data = data[:int(g.integers(1, len(data)))]
        else:
            for i in g.integers(0, len(data), 8):
                data[int(i)] = int(g.integers(0, 256))
        broken = tmp_path / f"broken_{k}"
        broken.write_bytes(bytes(data))
        try:
            importers.read_time_histories(broken)
        except InputDataError:
            pass
