"""Four processes on one campaign at once lose nothing (issue 26, "Must show").

One process imports four CSV manoeuvres one after the other (``sysid import``), one computes
the frequency responses (``sysid frequency-response``), one fits a first-order pitch model in
the time domain (``sysid identify-time``) and one exports and validates a stored model
(``sysid validate --no-truth``), all started together on the same campaign file. Every
stage reads the campaign, works, and writes its groups in one locked read-modify-write
(sysid.data.netcdf.campaign_lock), so at the end every group each process wrote is there,
beside everything the campaign held before. Before issue 26, ``sysid import`` wrote outside
the lock and lost the others' groups (or they lost its manoeuvres).

Records are tiny (20 s at 50 Hz) so the test takes seconds, most of it the C compile of
the validated model's FMU.
"""

from __future__ import annotations

import subprocess
import sys
import time
import tomllib

import numpy as np
import xarray as xr
from scipy.signal import lsim

from sysid.data import netcdf
from sysid.models.toml import structure_from_dict

DT = 0.02


def _pitch_record(name: str, seed: int) -> xr.Dataset:
    """q' = -2 q + 1.5 (lon - 50) flown with a 3211-like input, light noise (seeded)."""
    rng = np.random.default_rng(seed)
    t = np.arange(0.0, 20.0, DT)
    u = np.zeros_like(t)
    for start, stop, sign in ((1, 4, 1), (4, 6, -1), (6, 7, 1), (7, 8, -1)):
        u[(t >= start) & (t < stop)] = 5.0 * sign
    _, q, _ = lsim(([1.5], [1.0, 2.0]), u, t)
    lat = 50 + np.cumsum(rng.standard_normal(t.size)) * 0.1
    p = 0.8 * (lat - 50) + 0.05 * rng.standard_normal(t.size)
    return xr.Dataset(
        {"lon": ("time", 50 + u + 0.3 * rng.standard_normal(t.size), {"units": "%"}),
         "lat": ("time", lat, {"units": "%"}),
         "p": ("time", p, {"units": "deg/s"}),
         "q": ("time", q + 0.05 * rng.standard_normal(t.size), {"units": "deg/s"})},
        coords={"time": ("time", t, {"units": "s"})},
        attrs={"maneuver": name, "kind": name.split("_")[0], "axis": "lon",
               "trim_lon": 50.0, "trim_q": 0.0, "trim_lat": 50.0, "trim_p": 0.0})


STRUCTURE = """name = "pitch"
states = ["q"]
inputs = ["lon"]
[A]
"q,q" = -1.0
[B]
"q,lon" = 1.0
"""


def _stored_model() -> xr.Dataset:
    """The pitch model as an earlier fit would have stored it (validated by one process)."""
    structure = structure_from_dict(tomllib.loads(STRUCTURE.replace("-1.0", "-2.0")),
                                    trim={"lon": 50.0, "q": 0.0})
    return structure.to_dataset(attrs={"method": "frequency_domain"})


def _csv(path, seed: int):
    rec = _pitch_record("x", seed)
    lines = ["time [s],lon [%],q [deg/s]"] + [
        f"{t:.3f},{float(lon)!r},{float(q)!r}" for t, lon, q in
        zip(rec["time"].values, rec["lon"].values, rec["q"].values)]
    path.write_text("\n".join(lines) + "\n")
    return path


def test_four_processes_import_fit_and_validate_one_campaign(tmp_path):
    path = tmp_path / "c.nc"
    nodes = {"/": xr.Dataset(attrs={"campaign": "stress"}),
             "/models/frequency_domain": _stored_model(),
             "/notes": xr.Dataset({"kept": ("k", [1.0, 2.0])})}
    for k, name in enumerate(["sweep_lon_1", "sweep_lat_1", "3211_lon_1", "3211_lon_2"]):
        nodes[f"/maneuvers/{name}"] = _pitch_record(name, k)
    netcdf.write_campaign(xr.DataTree.from_dict(nodes), path)
    structure = tmp_path / "pitch.toml"
    structure.write_text(STRUCTURE)
    imports = [_csv(tmp_path / f"2311_lon_{k}.csv", 10 + k) for k in range(4)]
    py = [sys.executable, "-m", "sysid"]
    commands = {
        "import": [sys.executable, "-c",
                   "import sys; from sysid.cli import main\n"
                   "for f in sys.argv[2:]:\n"
                   "    assert main(['import', f, '-o', sys.argv[1], '-q']) == 0\n",
                   str(path), *map(str, imports)],
        "frequency-response": py + ["frequency-response", str(path), "--inputs", "lon,lat",
                                    "--outputs", "p,q", "--maneuvers", "sweep_*",
                                    "--windows", "2,5", "--n-frequencies", "20",
                                    "--transient-states", "", "--quiet"],
        "identify-time": py + ["identify-time", str(path), "--structure", str(structure),
                               "--maneuvers", "3211_*", "--no-reduction", "--quiet"],
        "validate": py + ["validate", str(path), "--no-truth", "--quiet",
                          "--fmu-dir", str(tmp_path / "fmus")],
    }
    procs = {name: subprocess.Popen(cmd, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
             for name, cmd in commands.items()}
    results, start = {}, time.monotonic()
    for name, proc in procs.items():
        out, err = proc.communicate(timeout=600)
        results[name] = (proc.returncode, err.decode()[-2000:])
        print(f"{name}: status {proc.returncode}, done after {time.monotonic() - start:.1f} s")
    for name in ("import", "frequency-response", "identify-time"):
        assert results[name][0] == 0, (name, results[name])
    # validate stores its outcome even when the stored model fails a check
    assert results["validate"][0] in (0, 1), results["validate"]

    tree = netcdf.read_campaign(path)
    assert tree.attrs["campaign"] == "stress"
    assert set(tree["maneuvers"].children) == {
        "sweep_lon_1", "sweep_lat_1", "3211_lon_1", "3211_lon_2",
        "2311_lon_0", "2311_lon_1", "2311_lon_2", "2311_lon_3"}
    assert "frequency_response" in tree.children
    assert set(tree["models"].children) >= {"frequency_domain", "time_domain"}
    assert "frequency_domain" in tree["validation"].children
    assert np.array_equal(tree["notes"]["kept"].values, [1.0, 2.0])
    # the fit found the pitch model the records were made with
    td = tree["models/time_domain"].to_dataset()
    values = dict(zip(map(str, td["parameter"].values), td["value"].values))
    assert abs(values["M_q"] + 2.0) < 0.2 and abs(values["M_lon"] - 1.5) < 0.15, values
    assert not list(tmp_path.glob(".c.nc.*"))
