"""Example flight-test files: the built-in hover campaign as a test programme hands it over.

:func:`write_example_flight_data` flies the default hover campaign on the truth FMU
(:func:`sysid.flight_test.campaign.run_campaign`, seeded) and writes each manoeuvre as one
MATLAB v7.3 file (:func:`sysid.data.formats.write_groups`) the way flight-test data usually
arrive: rate gyros, attitudes and accelerometers (``p q r phi theta psi ax ay az``) and the
four controls, no ``u v w`` (not measured in hover), no trim or other sysid attributes, and
a data-acquisition clock with random jitter. The files are the input of the README's worked
example (``sysid example-data -o flight`` then ``sysid run --data flight/*.mat --resample
auto``).

Jitter: the files' sample ``k`` is taken at ``t_k = k dt_file + e_k`` with ``e_k`` uniform in
``+-jitter dt_file`` (seeded) and ``dt_file = decimation / sample_rate``; the signals at
``t_k`` are interpolated (cubic) from the campaign's own record, which is ``decimation``
times finer. The files' ``time`` is the jittered clock, so an importer must resample it.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr
from scipy.interpolate import CubicSpline

from sysid.core.errors import InputDataError
from sysid.core.units import ACCELERATIONS, CONTROLS
from sysid.core.util import Progress
from sysid.data.formats import write_groups
from sysid.flight_test.campaign import Campaign, default_campaign, run_campaign

__all__ = ["EXAMPLE_CHANNELS", "EXAMPLE_SEED", "jittered_record", "example_records",
           "write_example_flight_data"]

#: Channels of the example files (no u, v, w).
EXAMPLE_CHANNELS = ("p", "q", "r", "phi", "theta", "psi", *ACCELERATIONS, *CONTROLS)
#: Seed of the example campaign (the default hover study's).
EXAMPLE_SEED = 20261121


def jittered_record(record: xr.Dataset, *, channels=EXAMPLE_CHANNELS, decimation: int = 2,
                    jitter: float = 0.2, rng: np.random.Generator) -> xr.Dataset:
    """``record`` sampled on a jittered clock ``decimation`` times coarser.

    ``jitter`` is the largest clock error as a fraction of the new step (below 0.5, so the
    clock keeps increasing); the channels are interpolated by cubic splines of the record.
    Attributes are dropped except ``maneuver``; units are kept.
    """
    if not 0.0 <= jitter < 0.5:
        raise InputDataError(f"jitter {jitter}: expected a fraction of the step in [0, 0.5)")
    if int(decimation) < 1:
        raise InputDataError(f"decimation {decimation}: expected an integer >= 1")
    missing = [c for c in channels if c not in record]
    if missing:
        raise InputDataError(f"record {record.attrs.get('maneuver', '?')}: no channel(s) "
                             f"{missing}")
    t = np.asarray(record["time"].values, float)
    dt = (t[-1] - t[0]) / (t.size - 1) * int(decimation)
    n = int(np.floor((t[-1] - t[0]) / dt))  # the last jittered sample stays inside
    clock = t[0] + dt * np.arange(n) + dt * rng.uniform(-jitter, jitter, n)
    clock[0] = max(clock[0], t[0])
    data = {c: ("time", CubicSpline(t, np.asarray(record[c].values, float))(clock),
                {"units": record[c].attrs.get("units", "")}) for c in channels}
    return xr.Dataset(data, coords={"time": ("time", clock, {"units": "s"})},
                      attrs={"maneuver": record.attrs.get("maneuver", "")})


def example_records(*, seed: int = EXAMPLE_SEED, decimation: int = 2, jitter: float = 0.2,
                    campaign: Campaign | None = None, quiet: bool = False
                    ) -> dict[str, xr.Dataset]:
    """``{manoeuvre: jittered record}`` of the campaign (default: the hover campaign of
    ``seed``, noise and turbulence on) flown on the truth FMU (:func:`jittered_record`;
    the jitter is seeded with ``seed`` too)."""
    campaign = campaign or default_campaign(0.0, noise=True, seed=seed)
    tree = run_campaign(campaign, quiet=quiet)
    rng = np.random.default_rng([seed, 23])
    return {name: jittered_record(node.to_dataset(), decimation=decimation, jitter=jitter,
                                  rng=rng)
            for name, node in tree["maneuvers"].children.items()}


def write_example_flight_data(out_dir: str | Path, *, seed: int = EXAMPLE_SEED,
                              decimation: int = 2, jitter: float = 0.2,
                              format: str = "mat73", campaign: Campaign | None = None,
                              quiet: bool = False) -> list[Path]:
    """Fly the example campaign and write one file per manoeuvre into ``out_dir``; return
    the paths (``<manoeuvre>.mat``, or ``.h5`` for ``format="hdf5"``).

    ``format`` is ``"mat73"`` (MAT v7.3), ``"mat5"`` or ``"hdf5"``; the rest as
    :func:`example_records`.

    Examples
    --------
    >>> write_example_flight_data("flight")                   # doctest: +SKIP
    [PosixPath('flight/sweep_lon_1.mat'), ...]
    """
    out = Path(out_dir)
    if out.exists() and not out.is_dir():
        raise InputDataError(f"{out} is a file; expected a folder for the example files")
    records = example_records(seed=seed, decimation=decimation, jitter=jitter,
                              campaign=campaign, quiet=quiet)
    out.mkdir(parents=True, exist_ok=True)
    suffix = ".h5" if format == "hdf5" else ".mat"
    paths = []
    for name, ds in records.items():
        fields = {"time": ds["time"].values, **{c: ds[c].values for c in ds.data_vars}}
        units = {"time": "s", **{c: ds[c].attrs["units"] for c in ds.data_vars
                                 if ds[c].attrs.get("units")}}
        path = out / f"{name}{suffix}"
        write_groups(path, {name: {"fields": fields, "units": units,
                                   "attrs": {"maneuver": name}}}, format=format)
        paths.append(path)
    Progress(quiet=quiet).message(f"[sysid] example flight data: {len(paths)} files in {out}")
    return paths
