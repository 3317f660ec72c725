"""Reliability under concurrency and bad input: issue 26 items 2-8 and 10 (items 1 and 9,
signals, are in tests/test_interrupt.py; the fuzzers in tests/test_fuzz.py; the
four-process stress test in tests/test_stress.py).

Each test failed on the code of the issue (f5f0d06); the comment on each says how.
"""

from __future__ import annotations

import contextlib
import io
import multiprocessing
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from test_identify_frequency import analytic_response, truth_structure
from known_systems import multistep_records

from sysid.cli import main
from sysid.core import paths
from sysid.core.errors import FMUError, IdentificationError, InputDataError
from sysid.core.units import PHYSICAL_RANGE, physical_range
from sysid.core.util import Progress
from sysid.data import netcdf
from sysid.data.importers import read_time_history, validate_time_history
from sysid.identify import identify_frequency_domain, identify_time_domain
from sysid.models.toml import load_structure
from sysid.spectral.response import frequency_response


def run_cli(argv) -> tuple[int, str, str]:
    out, err = io.StringIO(), io.StringIO()
    with contextlib.redirect_stdout(out), contextlib.redirect_stderr(err):
        code = main([str(a) for a in argv])
    return code, out.getvalue(), err.getvalue()


def record(name: str, *, n: int = 600, seed: int = 0, dt: float = 0.02,
           inputs=("lon", "lat"), outputs=("p", "q")) -> xr.Dataset:
    """A small record: independent random inputs, outputs mixing them, with units."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) * dt
    data = {}
    for k, c in enumerate(inputs):
        data[c] = ("time", 50 + np.cumsum(rng.standard_normal(n)) * 0.2, {"units": "%"})
    for k, c in enumerate(outputs):
        mix = sum((k + j + 1) * (data[i][1] - 50) for j, i in enumerate(inputs))
        data[c] = ("time", mix + 0.1 * rng.standard_normal(n), {"units": "deg/s"})
    return xr.Dataset(data, coords={"time": ("time", t, {"units": "s"})},
                      attrs={"maneuver": name, "kind": name.split("_")[0],
                             "axis": name.split("_")[1]})


def campaign(path: Path, names=("sweep_lon_1", "sweep_lat_1"), **kw) -> Path:
    nodes = {"/": xr.Dataset(attrs={"campaign": "test"})}
    for k, name in enumerate(names):
        nodes[f"/maneuvers/{name}"] = record(name, seed=k, **kw)
    netcdf.write_campaign(xr.DataTree.from_dict(nodes), path)
    return path


def csv_file(path: Path, *, n: int = 300, seed: int = 0, bad: dict | None = None) -> Path:
    rng = np.random.default_rng(seed)
    lines = ["time [s],lon [%],q [deg/s]"]
    for k in range(n):
        lon, q = 50 + rng.standard_normal(), rng.standard_normal()
        if bad and k in bad:
            q = bad[k]
        lines.append(f"{k * 0.02:.2f},{lon!r},{q!r}")
    path.write_text("\n".join(lines) + "\n")
    return path


# --------------------------------------------------------------------------------------------
# item 2: `sysid import` under the campaign lock


def _import_worker(args):
    csv, out = args
    return run_cli(["import", csv, "-o", out, "--quiet"])[0]


def test_concurrent_imports_lose_no_manoeuvre(tmp_path):
    """Before: import read and wrote the campaign outside the lock, so of several imports at
    once only the last writer's manoeuvres survived (every command exited 0)."""
    out = campaign(tmp_path / "c.nc", names=[f"sweep_lon_{k}" for k in range(6)], n=20000)
    files = [csv_file(tmp_path / f"3211_q_{k}.csv", seed=k) for k in range(4)]
    with multiprocessing.get_context("fork").Pool(4) as pool:
        codes = pool.map(_import_worker, [(f, out) for f in files])
    assert codes == [0, 0, 0, 0]
    names = set(netcdf.read_campaign(out)["maneuvers"].children)
    assert names == {f"sweep_lon_{k}" for k in range(6)} | {f"3211_q_{k}" for k in range(4)}


# --------------------------------------------------------------------------------------------
# item 3: validate fails before touching /validation


@pytest.mark.parametrize("case", ["malformed", "missing", "not_utf8", "fmu_dir_is_a_file"])
def test_validate_with_bad_arguments_keeps_earlier_results(tmp_path, case):
    """Before: every model's validation raised inside the per-model guard and the command
    replaced the existing /validation/<model> groups with empty ones carrying an error."""
    path = campaign(tmp_path / "c.nc")
    netcdf.update_campaign_groups(path, {
        "models/frequency_domain": xr.Dataset({"theta": ("k", [1.0])}),
        "validation/frequency_domain": xr.Dataset({"j_rms": ("maneuver", [0.5])},
                                                  coords={"maneuver": ["3211_lon"]})})
    before = path.read_bytes()
    envelope = tmp_path / "bad.toml"
    argv = ["validate", path, "--no-truth", "--quiet"]
    if case == "malformed":
        envelope.write_text("name = 'x'\n[magnitude.upper\n")
        argv += ["--envelope", envelope]
    elif case == "missing":
        argv += ["--envelope", tmp_path / "none.toml"]
    elif case == "not_utf8":
        envelope.write_bytes(b"name = '\xff\xfe'\n")
        argv += ["--envelope", envelope]
    else:
        (tmp_path / "afile").write_text("x")
        argv += ["--fmu-dir", tmp_path / "afile"]
    code, _, err = run_cli(argv)
    assert code == 1
    assert err.count("\n") == 1 and "Traceback" not in err
    assert ("afile" if case == "fmu_dir_is_a_file" else "envelope file") in err
    assert path.read_bytes() == before


# --------------------------------------------------------------------------------------------
# item 4: non-physical values and bounded fits


def test_physical_range_table_converts_units():
    lo, hi = PHYSICAL_RANGE["q"]
    assert physical_range("q", "rad/s") == pytest.approx((np.deg2rad(lo), np.deg2rad(hi)))
    assert physical_range("q", "ft/s") is None and physical_range("xyz") is None


def test_import_refuses_a_non_physical_sample_naming_line_and_channel(tmp_path):
    """Before: import accepted 1e300 and identify-time then ran for ever."""
    path = csv_file(tmp_path / "3211_lon_1.csv", bad={57: 1e300})
    with pytest.raises(InputDataError, match=r"line 59, channel 'q'.*physically possible"):
        read_time_history(path)
    # a plausible value in another unit is converted before the check, not refused
    ok = csv_file(tmp_path / "3211_lon_2.csv", bad={57: 30.0})
    assert float(read_time_history(ok)["q"].max()) == pytest.approx(30.0)


def test_time_domain_fit_refuses_non_physical_records_and_is_time_bounded():
    records = multistep_records(noise=0.01)
    bad = records[0].copy(deep=True)
    bad["q"].values[40] = 1e300
    with pytest.raises(InputDataError, match="channel 'q'.*physically possible"):
        validate_time_history(bad, ["q"])
    with pytest.raises(InputDataError, match="physically possible"):
        identify_time_domain([bad, *records[1:]], truth_structure(), quiet=True)
    # a limit no fit can meet, so the check does not depend on the machine's speed (a 0.2 s
    # limit stopped being exceeded once the fit got faster on a quiet machine)
    with pytest.raises(IdentificationError, match=r"did not finish within 0\.001 s"):
        identify_time_domain(records, truth_structure(), time_limit=1e-3, quiet=True)


def test_frequency_domain_fit_is_time_bounded():
    st = truth_structure()
    fr = analytic_response(st, noise=0.05)
    with pytest.raises(IdentificationError,
                       match=r"frequency-domain fit did not finish within 0\.001 s"):
        identify_frequency_domain(fr, st, time_limit=1e-3, reduce=False, quiet=True)


# --------------------------------------------------------------------------------------------
# item 5: collinear inputs


def test_collinear_inputs_are_named_and_no_response_is_written(tmp_path):
    """Before: an all-NaN /frequency_response with exit status 0 and a RuntimeWarning."""
    path = tmp_path / "c.nc"
    nodes = {"/": xr.Dataset()}
    for k, name in enumerate(["sweep_lon_1", "sweep_lat_1"]):
        ds = record(name, seed=k, inputs=("lon", "lat", "col"))
        nodes[f"/maneuvers/{name}"] = ds.assign(lat=2 * ds["lon"] - 50)
    netcdf.write_campaign(xr.DataTree.from_dict(nodes), path)
    before = path.read_bytes()
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        code, _, err = run_cli(["frequency-response", path, "--inputs", "lon,lat,col",
                                "--outputs", "p,q", "--windows", "2,4", "--n-frequencies",
                                "12", "--transient-states", "", "--quiet"])
    assert code == 1, err
    assert "inputs lon, lat are collinear" in err and "rad/s" in err
    assert path.read_bytes() == before


def test_partly_collinear_inputs_are_reported_with_their_band():
    """lat = 2 lon plus an independent part above 6 rad/s only: collinear below (H NaN
    there, said in a warning and the ``collinear_note`` attribute), usable above."""
    rng = np.random.default_rng(3)
    n, dt = 6000, 0.02
    w = 2 * np.pi * np.fft.rfftfreq(n, dt)
    records = {}
    for k in range(2):
        x1, e2 = rng.standard_normal(n), np.fft.rfft(rng.standard_normal(n))
        e2[w < 6.0] = 0
        x2 = 2 * x1 + np.fft.irfft(e2, n)
        records[f"sweep_{k}"] = xr.Dataset(
            {"lon": ("time", x1), "lat": ("time", x2),
             "q": ("time", x1 + 0.5 * x2 + 0.1 * rng.standard_normal(n))},
            coords={"time": np.arange(n) * dt})
    log = io.StringIO()
    fr = frequency_response(records, ["lon", "lat"], ["q"], windows=[4, 8], n_frequencies=40,
                            transient_states=(), progress=Progress(stream=log))
    flagged = fr["frequency"].values[fr["collinear"].values]
    assert 0 < flagged.size < fr.sizes["frequency"] and flagged.max() < 6.0
    assert bool(fr["H"].sel(frequency=flagged).isnull().all())
    assert bool(np.isfinite(fr["H"].sel(frequency=fr["frequency"] > 8.0)).all())
    assert fr.attrs["collinear_note"].startswith("inputs lon, lat are collinear")
    assert "warning: inputs lon, lat are collinear" in log.getvalue()


def test_identify_names_collinearity_when_no_pair_is_coherent():
    st = truth_structure()
    fr = analytic_response(st)
    fr["partial_coherence"] = fr["partial_coherence"] * 0
    fr["collinear"] = ("frequency", np.ones(fr.sizes["frequency"], bool))
    fr.attrs["collinear_note"] = "inputs lon, lat are collinear at 300 of 300 frequencies"
    with pytest.raises(IdentificationError, match="inputs lon, lat are collinear"):
        identify_frequency_domain(fr, st, quiet=True)


# --------------------------------------------------------------------------------------------
# item 6: structure TOML types


BASE = 'states = ["q"]\ninputs = ["lon"]\n'


@pytest.mark.parametrize("body, message", [
    ('[A]\n"q,q" = { value = -1.0, free = "false" }\n', r"free = 'false': expected true or "),
    ('[A]\n"q,q" = { value = -1.0, keep = "yes" }\n', r"keep = 'yes': expected true or false"),
    ('[A]\n"q,q" = { value = "abc" }\n', r"value = 'abc': expected a number"),
    ('[A]\n"q,q" = "abc"\n', r"value = 'abc': expected a number"),
    ('[A]\n"q,q" = true\n', r"value = True: expected a number"),
    ('[delays]\ntau = { entry = "lon", value = "0.1" }\n', r"\[delays\] tau: value"),
    ('[A]\n"x,q" = 1.0\n', r"row 'x'"),
    ('[kinematics]\ntheta0 = "level"\n', r"theta0 = 'level': expected a number or"),
    ('[trim]\nlon = "50"\n', r"\[trim\] lon = '50'"),
])
def test_structure_types_are_checked_and_errors_name_the_file(tmp_path, body, message):
    """Before: free = "false" meant free, keep = "yes" meant keep, value = "abc" was a
    ValueError traceback, and unknown names came without the file name."""
    path = tmp_path / "s.toml"
    path.write_text(BASE + body)
    with pytest.raises(InputDataError, match=message) as info:
        load_structure(path)
    assert str(path) in str(info.value)


def test_structure_file_not_utf8(tmp_path):
    path = tmp_path / "s.toml"
    path.write_bytes(BASE.encode() + b'description = "\xff\xfe"\n')
    with pytest.raises(InputDataError, match="not UTF-8"):
        load_structure(path)


def test_structure_booleans_still_work(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(BASE + '[A]\n"q,q" = { value = -1, free = false, keep = true }\n')
    (param,) = load_structure(path).parameters
    assert (param.value, param.free, param.keep) == (-1.0, False, True)


# --------------------------------------------------------------------------------------------
# item 7: a campaign path that is a symbolic link


def test_writes_through_a_symbolic_link_keep_the_link(tmp_path):
    """Before: the link was replaced by a regular file and its target never updated."""
    target = campaign(tmp_path / "data" / "real.nc")
    link = tmp_path / "c.nc"
    link.symlink_to(Path("data") / "real.nc")
    netcdf.update_campaign(link, "extra", xr.Dataset({"x": ("k", [1.0, 2.0])}))
    code, _, err = run_cli(["import", csv_file(tmp_path / "3211_lon_7.csv"), "-o", link, "-q"])
    assert code == 0, err
    assert link.is_symlink() and link.resolve() == target.resolve()
    tree = netcdf.read_campaign(target)
    assert "extra" in tree.children and "3211_lon_7" in tree["maneuvers"].children
    assert not list(tmp_path.glob(".c.nc.*")) and not list(target.parent.glob(".real.nc.*"))


# --------------------------------------------------------------------------------------------
# item 8: a time gap at the right line


def test_time_gap_is_reported_at_its_line(tmp_path):
    """Before: the mean step was stretched by the gap, so line 3 was blamed."""
    lines = ["time,lon,q"] + [f"{(k * 0.01 + (0.5 if k >= 500 else 0.0)):.4f},50,0"
                              for k in range(1000)]
    path = tmp_path / "gap.csv"
    path.write_text("\n".join(lines) + "\n")
    # sample k is on line k + 2 (the header is line 1): the gap is before sample 500
    with pytest.raises(InputDataError, match=r"not uniform at line 502: step 0\.5"):
        read_time_history(path)


# --------------------------------------------------------------------------------------------
# item 10: text channels, -o naming a directory, corrupt FMUs, the FMU cache


def test_text_channel_gives_a_clear_error(tmp_path):
    """Before: ValueError traceback from the spectra."""
    path = tmp_path / "c.nc"
    rec = record("sweep_lon_1")
    rec["q"] = ("time", np.array(["x"] * rec.sizes["time"]))
    netcdf.write_campaign(xr.DataTree.from_dict({"/maneuvers/sweep_lon_1": rec}), path)
    code, _, err = run_cli(["frequency-response", path, "--inputs", "lon,lat", "--outputs",
                            "p,q", "--quiet"])
    assert code == 1 and "channel 'q'" in err and "expected numbers" in err


def test_output_naming_a_directory(tmp_path):
    """Before: IsADirectoryError tracebacks, or "does not exist" for an existing folder."""
    folder = tmp_path / "out"
    folder.mkdir()
    path = campaign(tmp_path / "c.nc")
    for argv in (["import", csv_file(tmp_path / "3211_lon_1.csv"), "-o", folder],
                 ["export-csv", path, "sweep_lon_1", "-o", folder],
                 ["frequency-response", folder, "--inputs", "lon", "--outputs", "q"],
                 ["simulate", "-o", folder, "--no-noise"]):
        code, _, err = run_cli(argv)
        assert code == 1 and "is a directory" in err, (argv, err)
    with pytest.raises(InputDataError, match="is a directory"):
        netcdf.write_campaign(netcdf.read_campaign(path), folder)
    assert list(folder.iterdir()) == []


@pytest.fixture(scope="module")
def exported_fmu(tmp_path_factory):
    from test_export import _model

    from sysid.fmi.export import export_fmu
    return export_fmu(_model(), tmp_path_factory.mktemp("fmu") / "m.fmu")


def test_corrupt_exported_fmu_raises_fmu_error(exported_fmu, tmp_path):
    """Before: zipfile.BadZipFile (bad CRC) or zlib.error from fmpy's extraction."""
    from sysid.assess.exported import simulate_exported

    good = exported_fmu.read_bytes()
    inputs = xr.Dataset({"lon": ("time", np.zeros(20))}, coords={"time": np.arange(20) * 0.05})
    rng = np.random.default_rng(10)
    for k in range(12):  # seeded byte flips and truncations
        data = bytearray(good)
        if k % 3 == 0:
            data = data[: int(rng.integers(10, len(data)))]
        else:
            for i in rng.integers(0, len(data), size=int(rng.integers(1, 10))):
                data[i] ^= 0xFF
        path = tmp_path / f"c{k}.fmu"
        path.write_bytes(bytes(data))
        with pytest.raises(FMUError):
            simulate_exported(path, inputs, mode="cs" if k % 2 else "me")


def test_fmu_cache_is_capped_and_clearable(exported_fmu, tmp_path, monkeypatch):
    """Before: every extracted FMU stayed in ~/.cache/sysid/unzipped for ever."""
    from sysid.fmi.runtime import load_fmu

    monkeypatch.setenv("SYSID_CACHE_DIR", str(tmp_path / "cache"))
    unzipped = tmp_path / "cache" / "unzipped"
    # two different archives (the second a copy with an extra member)
    import shutil
    import zipfile
    other = tmp_path / "other.fmu"
    shutil.copyfile(exported_fmu, other)
    with zipfile.ZipFile(other, "a") as zf:
        zf.writestr("documentation/readme.txt", "x" * 1000)
    load_fmu(exported_fmu)
    first = sorted(unzipped.iterdir())
    assert len(first) == 1
    size = sum(f.stat().st_size for f in first[0].rglob("*") if f.is_file())
    monkeypatch.setenv("SYSID_CACHE_MAX_BYTES", str(int(1.5 * size)))
    os.utime(first[0], (1, 1))  # the first one is the least recently used
    load_fmu(other)
    assert [p.name for p in unzipped.iterdir()] != [first[0].name]
    assert len(list(unzipped.iterdir())) == 1  # the cap kept only the newest
    code, out, _ = run_cli(["cache"])
    assert code == 0 and str(tmp_path / "cache") in out
    code, out, _ = run_cli(["cache", "--clear"])
    assert code == 0 and list((tmp_path / "cache").iterdir()) == []
    monkeypatch.setenv("SYSID_CACHE_MAX_BYTES", "lots")
    with pytest.raises(InputDataError, match="SYSID_CACHE_MAX_BYTES"):
        paths.cache_max_bytes()
