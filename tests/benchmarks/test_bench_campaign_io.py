"""Benchmark: the cost of one study stage's bookkeeping on a campaign file of the hover
study's size, as ratios against a full rewrite measured in the same run.

A stage adds its result as a new group and stamps its cache key on it; before the append
path every such update reread and rewrote the whole file. Reported in ``extra_info``:
the full rewrite (the baseline), the append of a new group, the stamp, and the cache-key
read, with ``*_ratio`` = baseline / that operation. Runs once as a plain test under
--benchmark-disable on a campaign shaped like the one ``sysid run hover`` writes (16 records
of 150 s at 100 Hz, and about as many groups of results).
"""

from __future__ import annotations

import time

import numpy as np
import xarray as xr

from sysid.data import netcdf as io
from sysid.core.units import channel_attrs

CHANNELS = ("lon", "lat", "col", "ped", "u", "v", "w", "p", "q", "r", "phi", "theta", "psi")


def _campaign(n_records: int = 16, duration: float = 150.0, dt: float = 0.01,
              n_results: int = 24) -> xr.DataTree:
    """A campaign shaped like the hover study's: about 40 groups of about 16 variables
    with a few dozen attributes each. Per variable and attribute, not per byte, is where a
    full rewrite spends its time."""
    rng = np.random.default_rng(0)
    t = np.arange(0.0, duration, dt)
    nodes = {"/": xr.Dataset(attrs={"campaign": "benchmark"})}
    attrs = {f"attr_{k}": float(k) for k in range(25)}
    for k in range(n_records):
        name = f"sweep_{CHANNELS[k % 4]}_{k}"
        nodes[f"/maneuvers/{name}"] = xr.Dataset(
            {c: ("time", rng.standard_normal(t.size), channel_attrs(c)) for c in CHANNELS},
            coords={"time": ("time", t, {"units": "s"})}, attrs={"maneuver": name, **attrs})
    for k in range(n_results):
        nodes[f"/results/group_{k}"] = xr.Dataset(
            {f"var_{j}": (("output", "frequency"), rng.standard_normal((9, 200))
                          + 1j * rng.standard_normal((9, 200))) for j in range(16)},
            coords={"frequency": np.geomspace(0.1, 30.0, 200)}, attrs=attrs)
    return xr.DataTree.from_dict(nodes)


def _timed(fn) -> float:
    start = time.perf_counter()
    fn()
    return time.perf_counter() - start


def test_bench_campaign_updates(benchmark, tmp_path):
    path = tmp_path / "campaign.nc"
    io.write_campaign(_campaign(), path)
    size_mb = path.stat().st_size / 2**20
    model = xr.Dataset({"value": ("parameter", np.arange(40.0))},
                       coords={"parameter": [f"p{k}" for k in range(40)]},
                       attrs={"method": "frequency_domain"})

    def rewrite():  # the baseline: what every update did before the append path
        io._update_campaign(path, "models/rewritten", model)

    def append():
        io.update_campaign(path, "models/appended", model)

    def stamp():
        io.set_group_attrs(path, "models/appended", {"workflow_key": "0123456789abcdef"})

    def key():
        assert io.group_attrs(path, "models/appended")["workflow_key"] == "0123456789abcdef"

    def run():
        return {name: _timed(fn) for name, fn in
                (("rewrite_s", rewrite), ("append_s", append), ("stamp_s", stamp),
                 ("key_read_s", key))}

    times = benchmark.pedantic(run, rounds=1, iterations=1)
    info = benchmark.extra_info
    info["file_MB"] = round(size_mb, 1)
    info.update({k: round(v, 4) for k, v in times.items()})
    for name in ("append", "stamp", "key_read"):
        info[f"{name}_ratio"] = round(times["rewrite_s"] / times[f"{name}_s"], 1)
    print(f"\ncampaign of {size_mb:.1f} MB: {info}")
    tree = io.read_campaign(path)
    assert {"rewritten", "appended"} <= set(tree["models"].children)
    assert tree["models/appended"].attrs["workflow_key"] == "0123456789abcdef"
