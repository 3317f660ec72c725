"""Many flight conditions (and Monte Carlo seeds) on Dask: the whole study per condition.

:func:`run_batch` runs :func:`sysid.pipeline.study.run_study` once per :class:`Condition` (airspeed,
seed, noise, structure), independently of the others and in its own folder. Each study is
four Dask tasks, one per part of :data:`sysid.pipeline.study.PARTS`: the data (campaign and
frequency responses), then the frequency- and the time-domain fits side by side, then the
results (verification, comparison, export, report); the driver submits each part when the
parts it needs have ended, longest chain first (:data:`PART_PRIORITY`)::

    <out>/<condition>/          the condition's study (campaign.nc, FMUs, report.html; a
                                quick condition has no FMUs or report: Condition)
    <out>/<condition>/condition.json   what ran and how it ended (the resume marker)
    <out>/<condition>/study_<part>.log the stages' tables, one log per part
    <out>/batch.nc              every condition's results on one ``condition`` dimension
    <out>/batch_derivatives.png every derivative against airspeed: identified values with
                                Cramer-Rao bars, the truth linearisation overlaid
    <out>/monte_carlo.nc, monte_carlo.txt   with several seeds of a setting (seed_groups):
                                observed scatter of each estimate against its mean bound
    <out>/batch_calibration.png with several seeds of a setting: scatter / mean bound of each
                                dominant derivative, both domains, and the 0.5-2 goal band
    <out>/batch_summary.txt     one line per condition (status, time, J_ave, error)

Where it runs: a :class:`distributed.LocalCluster` of ``n_workers`` processes with one thread
each by default; with ``scheduler="tcp://host:port"`` the tasks go to that existing Dask
scheduler instead (its workers need ``sysid`` installed and must see ``out`` at the same path,
e.g. a shared file system; their nannies should be configured as :data:`WORKER_CONFIG`, since
distributed's default trim threshold slows every part 1.6x). No file lock is needed across
machines: within a condition the data part writes ``campaign.nc`` before the fits start,
each fit writes its own ``model_<method>.nc``, and the results part alone merges them
(:mod:`sysid.pipeline.study`); different conditions use different folders.

Fault tolerance: a task catches every exception of its condition (trim failure, diverging
simulation, non-converging fit) and returns it as a failure record (the exception's type and
first line of its message, e.g. ``IdentificationError: ...``; the stages are library calls,
so that is the stage's own exception),
so one bad condition never stops the others; a worker that dies is reported the same way.
Resume: a condition whose folder holds a completed study with the same settings and input
files (its ``condition.json`` says ``ok`` with the same digest of its campaign and structure
TOML, and, unless quick, ``report.html`` exists) is not recomputed;
a failed or interrupted one is re-run, and :func:`run_study`'s per-stage cache reuses
whatever it had finished (e.g. the campaign).

Structures: below :data:`FORWARD_FLIGHT_KT` the quasi-steady hover structure ``hover_6dof``,
from there the forward-flight structure ``forward_6dof`` (the speed-dependent derivatives
M_w, Z_u, L_v, N_v ... free); a condition or a speeds file can name another.

The ``batch.nc`` Dataset (dims ``condition``, ``model`` (the identification method), ``parameter``):

- coords on ``condition``: ``airspeed_kt``, ``seed``, ``noise`` (0/1), ``quick`` (0/1),
  ``calm_sweeps`` (0/1), ``campaign`` (the campaign TOML flown, "" for the built-in one),
  ``structure``,
  ``time_domain_method`` (the estimator of the ``time_domain`` model: output or filter
  error), ``status`` (``ok``/``failed``), ``error`` (type: message, "" when ok),
  ``elapsed_s``;
- ``value``, ``cramer_rao`` (absolute), ``cramer_rao_percent`` (condition, model, parameter):
  identified parameters (derivatives and delays), NaN where a method did not estimate it;
  ``cramer_rao_corrected`` (same dims): the bound corrected for coloured residuals (time
  domain) or scaled by the fit residuals (frequency domain, over its fitted points);
  ``cramer_rao_noise``: the frequency-domain bound from the spectral random error;
  ``cramer_rao_selection``: its robust scatter over point re-selections and
  ``selection_outlying`` the fraction of re-selections beyond 3 of it; ``cramer_rao_total``:
  the two bounds in quadrature (the one the fidelity scoreboard judges on);
- ``group`` (condition): :attr:`Condition.group`, the name without the seed;
- the Monte Carlo calibration of the bounds (:func:`calibration`; with at least two
  successful seeds of one group, :func:`seed_groups`), dims ``calibration_group`` (coordinate
  ``calibration_kt``, the airspeed) x ``dominant`` (the dominant
  derivatives, :data:`sysid.assess.comparison.DOMINANT`) x ``bound``
  (:data:`CALIBRATION_BOUNDS`): ``calibration_scatter``, ``calibration_bound``,
  ``calibration_ratio``, ``calibration_mean``, ``calibration_truth``, ``calibration_n_seeds``;
- ``truth`` (condition, parameter): the truth model's quasi-steady linearisation at the
  condition, for a higher-order structure (flapping) the linearisation reduced to its states
  (:func:`sysid.assess.comparison.truth_for_model`); NaN for delays;
- ``J_ave`` (condition, model); ``j_rms`` (condition, model): mean verification J_rms;
  ``truth_in_band`` (condition, model, parameter): the frequency-domain model's structure
  fitted to the truth's exact responses at its own points and weights (the structure's part
  of its error; :func:`sysid.assess.comparison.truth_in_band`);
  ``j_rms_truth`` (condition): the same of the truth linearisation reduced to the structure
  (:func:`sysid.assess.stages.truth_references`), the floor the data's turbulence and noise
  set.
"""

from __future__ import annotations

import contextlib
import dataclasses
import hashlib
import heapq
import itertools
import json
import math
import sys
import time
import threading
import tomllib
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Sequence

import numpy as np
import xarray as xr

from sysid.assess.comparison import DOMINANT, dominant_equivalents, truth_for_model
from sysid.assess.stages import TRUTH_SOURCE
from sysid.core import errors
from sysid.core.errors import InputDataError, SysidError
from sysid.core.units import CONTROLS
from sysid.core.util import Progress, atomic_path
from sysid.data.netcdf import read_campaign
from sysid.flight_test.campaign import Campaign, default_campaign
from sysid.identify.statistics import OUTLYING_SCALES
from sysid.models import parameter_values
from sysid.models.toml import structure_path
from sysid.pipeline.study import (FORWARD_FLIGHT_KT, METHODS, PARTS, QUICK_OMITS,
                                  TIME_DOMAIN_AUTO, TIME_DOMAIN_METHODS, StudySettings,
                                  run_study, structure_for)
from sysid.truth import build_fmu

#: Default flight conditions, kt (the issue's list).
DEFAULT_SPEEDS = (0.0, 20.0, 40.0, 60.0, 80.0, 100.0)
@dataclass(frozen=True)
class Condition:
    """One flight condition / Monte Carlo sample.

    ``quick`` flies a reduced campaign (one sweep record per axis instead of two, plus the
    3211 and 2311 multisteps) for faster checks; results are noisier than with the full
    campaign. (Shorter sweeps were tried: 45-s sweeps from 0.3 rad/s left the hover roll
    derivatives unidentifiable.) Its study is the quick one of
    :class:`~sysid.pipeline.study.StudySettings`: both fits and the verification as in the
    full study, without :data:`~sysid.pipeline.study.QUICK_OMITS` (no report: what a batch
    collects is ``batch.nc``).
    """

    airspeed_kt: float
    seed: int = 20261121
    noise: bool = True
    structure: str | None = None
    quick: bool = False
    #: The study's time-domain estimator (:data:`~sysid.pipeline.study.TIME_DOMAIN_METHODS`,
    #: or ``"auto"``: :attr:`~sysid.pipeline.study.StudySettings.time_domain_estimator`).
    time_domain_method: str = TIME_DOMAIN_AUTO
    #: Sweeps flown in calm air, the multisteps in the campaign's turbulence
    #: (:attr:`~sysid.pipeline.study.StudySettings.calm_sweeps`; hybrid structures).
    calm_sweeps: bool = False
    #: A campaign TOML flown instead of the built-in one (``sysid run --campaign``; the
    #: condition's seed and noise apply, its airspeed must be the condition's): Monte Carlo
    #: comparisons of test-input designs.
    campaign: str | None = None

    @property
    def name(self) -> str:
        return f"{self.airspeed_kt:g}kt_seed{self.seed}" + self._settings_suffix()

    @property
    def group(self) -> str:
        """The name without the seed: conditions that differ only in their seed share it
        (what :func:`monte_carlo` and :func:`calibration` pool)."""
        return f"{self.airspeed_kt:g}kt" + self._settings_suffix()

    def _settings_suffix(self) -> str:
        text = ""
        if not self.noise:
            text += "_nonoise"
        if self.quick:
            text += "_quick"
        if self.time_domain_method != TIME_DOMAIN_AUTO:
            text += "_" + self.time_domain_method
        if self.calm_sweeps:
            text += "_calmsweeps"
        if self.campaign:
            text += "_" + Path(self.campaign).stem
        if self.structure:
            text += "_" + Path(str(self.structure)).stem
        return text

    @property
    def structure_name(self) -> str:
        return self.structure or structure_for(self.airspeed_kt)

    @property
    def time_domain_estimator(self) -> str:
        """The estimator the study uses (resolves ``"auto"`` as the study does)."""
        settings = StudySettings(quick=self.quick, time_domain_method=self.time_domain_method)
        return settings.time_domain_estimator

    def to_dict(self) -> dict:
        """The fields (``calm_sweeps`` and ``campaign`` only when set: the resume markers of
        earlier batches, which lack them, still match their conditions)."""
        out = dataclasses.asdict(self)
        for optional in ("calm_sweeps", "campaign"):
            if not out[optional]:
                del out[optional]
        return out

    def check(self) -> None:
        """Raise :class:`~sysid.core.errors.InputDataError` for a campaign file that cannot
        be read or flies at another airspeed (before any work starts)."""
        if not self.campaign:
            return
        flown = Campaign.from_toml(self.campaign).airspeed_kt
        if abs(float(flown) - self.airspeed_kt) > 1e-9:
            raise InputDataError(f"condition {self.name}: campaign file {self.campaign} flies "
                                 f"at {flown:g} kt, the condition is at {self.airspeed_kt:g} kt")

    def inputs_digest(self) -> str:
        """Digest of the files the condition reads (its campaign and structure TOML), kept
        in the resume marker: an edited file re-runs the condition."""
        digest = hashlib.sha256()
        for path in ([Path(self.campaign)] if self.campaign else []) + [
                structure_path(self.structure_name)]:
            digest.update(path.read_bytes() if path.exists() else str(path).encode())
        return digest.hexdigest()[:16]


def conditions(speeds: Iterable[float] = DEFAULT_SPEEDS, seeds: Iterable[int] = (20261121,),
               *, noise: bool = True, quick: bool = False,
               structures: dict[str, tuple[float, float]] | None = None,
               time_domain_method: str = TIME_DOMAIN_AUTO,
               calm_sweeps: bool = False, campaign: str | None = None) -> list[Condition]:
    """Every (speed, seed) combination as a :class:`Condition`.

    ``structures`` maps a structure (built-in name or TOML path) to an airspeed band
    ``[from, to)`` in kt; speeds outside every band use :func:`structure_for`.
    """
    out = []
    for v in speeds:
        structure = None
        for name, (lo, hi) in (structures or {}).items():
            if lo <= v < hi:
                structure = name
                break
        for s in seeds:
            out.append(Condition(float(v), int(s), bool(noise), structure, bool(quick),
                                 time_domain_method, bool(calm_sweeps), campaign))
    return out


def load_conditions(path: str | Path) -> list[Condition]:
    """Conditions from a speeds TOML file::

        speeds = [0, 20, 40, 60, 80, 100]   # kt
        seeds = [20261121, 1, 2]            # one condition per speed and seed (default one)
        noise = true                        # sensor noise and turbulence (default true)
        quick = false                       # reduced campaign and study (default false)
        time_domain_method = "auto"         # "filter_error", "output_error" or "auto" (the
                                            # default: filter error, output error if quick)
        calm_sweeps = false                 # sweeps in calm air, multisteps in turbulence
        campaign = "designs/long_3211.toml" # optional: a campaign TOML instead of the
                                            # built-in one (sysid simulate --print-default)

        [structures]                        # optional: structure -> airspeed band [from, to) kt
        hover_6dof = [0, 30]
        forward_6dof = [30, 200]

        [[conditions]]                      # optional: extra single conditions
        airspeed_kt = 50
        seed = 7
        structure = "my_structure.toml"

    A relative ``campaign`` or structure path is read next to the speeds file when it is
    there (else from the working directory; a structure may also be a built-in name).
    """
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputDataError(f"cannot read speeds file {path}: {exc}") from None
    known = {"speeds", "seeds", "noise", "quick", "structures", "conditions",
             "time_domain_method", "calm_sweeps", "campaign"}
    unknown = set(spec) - known
    if unknown:
        raise InputDataError(f"speeds file {path}: unknown keys {sorted(unknown)}; "
                             f"known: {sorted(known)}")
    try:
        speeds = [float(v) for v in spec.get("speeds", [])]
        seeds = [int(s) for s in spec.get("seeds", [20261121])]
        bands = {str(k): (float(v[0]), float(v[1]))
                 for k, v in dict(spec.get("structures", {})).items()}
    except (TypeError, ValueError, IndexError) as exc:
        raise InputDataError(f"speeds file {path}: speeds must be numbers (kt), seeds "
                             f"integers and structures name = [from, to] in kt ({exc})") from None
    method = str(spec.get("time_domain_method", TIME_DOMAIN_AUTO))
    if method not in (*TIME_DOMAIN_METHODS, TIME_DOMAIN_AUTO):
        raise InputDataError(f"speeds file {path}: time_domain_method {method!r}; expected "
                             f"one of {(*TIME_DOMAIN_METHODS, TIME_DOMAIN_AUTO)}")
    here = path.parent

    def beside(value):  # a relative path next to the speeds file when it is there
        if value is None or Path(value).is_absolute() or not (here / value).exists():
            return value
        return str((here / value).resolve())

    bands = {beside(k): v for k, v in bands.items()}
    campaign = beside(spec.get("campaign"))
    out = conditions(speeds, seeds, noise=bool(spec.get("noise", True)),
                     quick=bool(spec.get("quick", False)), structures=bands,
                     time_domain_method=method, calm_sweeps=bool(spec.get("calm_sweeps", False)),
                     campaign=campaign)
    fields = {f.name for f in dataclasses.fields(Condition)}
    for k, item in enumerate(spec.get("conditions", [])):
        bad = set(item) - fields
        if bad or "airspeed_kt" not in item:
            raise InputDataError(f"speeds file {path}: [[conditions]] entry {k + 1} needs "
                                 f"airspeed_kt and only {sorted(fields)}; got {sorted(item)}")
        item = {**item, **{key: beside(item[key]) for key in ("structure", "campaign")
                           if key in item}}
        out.append(Condition(**item))
    for condition in out:
        condition.check()
    if not out:
        raise InputDataError(f"speeds file {path}: no conditions (give speeds = [...] or "
                             f"[[conditions]])")
    return out


# -----------------------------------------------------------------------------------------
# One condition (runs inside a Dask worker)
# -----------------------------------------------------------------------------------------
def quick_campaign(airspeed_kt: float, *, noise: bool, seed: int,
                   full: Campaign | None = None) -> Campaign:
    """The default campaign (or ``full``) reduced for fast checks (see :class:`Condition`)."""
    full = full or default_campaign(airspeed_kt, noise=noise, seed=seed)
    kept = [m for m in full.maneuvers if m.kind != "sweep" or m.name.endswith("_1")]
    return dataclasses.replace(full, name=full.name + "_quick", maneuvers=kept)


def study_settings(condition: Condition, folder: str | Path):
    """The :class:`~sysid.pipeline.study.StudySettings` of ``condition`` (writes the quick campaign
    TOML into ``folder`` when ``quick``)."""
    campaign_file = condition.campaign
    if condition.quick:
        given = Campaign.from_toml(campaign_file) if campaign_file else None
        campaign = quick_campaign(condition.airspeed_kt, noise=condition.noise,
                                  seed=condition.seed, full=given)
        campaign_file = Path(folder) / "campaign.toml"
        campaign_file.parent.mkdir(parents=True, exist_ok=True)
        text = campaign.to_toml()
        if not campaign_file.exists() or campaign_file.read_text() != text:
            with atomic_path(campaign_file) as tmp:
                tmp.write_text(text)
        campaign_file = str(campaign_file)
    return StudySettings(airspeed_kt=condition.airspeed_kt, seed=condition.seed,
                         noise=condition.noise, structure=condition.structure_name,
                         campaign_file=campaign_file, quick=condition.quick,
                         time_domain_method=condition.time_domain_method,
                         calm_sweeps=condition.calm_sweeps)


def _marker(folder: Path) -> Path:
    return folder / "condition.json"


def _write_marker(folder: Path, record: dict) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    with atomic_path(_marker(folder)) as tmp:
        tmp.write_text(json.dumps(record, indent=1))


def completed(condition: Condition, folder: str | Path) -> bool:
    """True when ``folder`` holds a finished study of exactly ``condition``."""
    folder = Path(folder)
    try:
        record = json.loads(_marker(folder).read_text())
    except (OSError, ValueError):
        return False
    return (record.get("status") == "ok" and record.get("condition") == condition.to_dict()
            and record.get("inputs") == condition.inputs_digest()
            and (condition.quick or (folder / "report.html").exists())
            and (folder / "campaign.nc").exists())


def run_condition(spec: dict, folder: str, fail: str | None = None) -> dict:
    """Run one condition's whole study in ``folder``, its parts one after another; never
    raises. Returns the record of :func:`run_condition_part`'s last part."""
    records: dict[str, dict] = {}
    for part in PARTS:
        records[part] = run_condition_part(spec, folder, part, fail,
                                           *(records[n] for n in PART_NEEDS[part]))
    return records[PARTS[-1]]


#: The parts of a study each part needs (``sysid.pipeline.study.PARTS``): the two fits read only
#: the data, so they run as separate tasks at the same time.
PART_NEEDS = {"data": (), "frequency_domain": ("data",), "time_domain": ("data",),
              "results": ("frequency_domain", "time_domain")}


def run_condition_part(spec: dict, folder: str, part: str, fail: str | None = None,
                       *upstream: dict) -> dict:
    """One part of one condition's study in ``folder`` (a Dask task); never raises.

    ``upstream`` are the records of the parts this one needs (:data:`PART_NEEDS`, in Dask
    the results of their tasks): if one of them failed, this part does not run and passes
    that failure on. ``fail`` (for fault-injection tests) raises the named exception class
    of :mod:`sysid.core.errors` before the ``data`` part starts. The ``results`` part writes the
    resume marker ``condition.json``, also for a failure that happened upstream.

    Returns ``{"name", "condition", "status": "ok"|"failed", "error_type", "message",
    "part_elapsed_s": {part: s}, "elapsed_s" (their sum), "summary": Dataset|None}``.
    """
    import dask  # deferred: an optional heavy dependency, needed only inside a Dask task

    condition = Condition(**spec)
    folder_path = Path(folder)
    part_elapsed: dict[str, float] = {}
    for previous in upstream:
        part_elapsed.update(previous.get("part_elapsed_s", {}))
    record = {"name": condition.name, "condition": condition.to_dict(), "status": "ok",
              "error_type": "", "message": "", "summary": None,
              "inputs": condition.inputs_digest()}
    failed = [r for r in upstream if r["status"] != "ok"]
    start = time.perf_counter()
    if failed:
        record.update({k: failed[0][k] for k in ("status", "error_type", "message")})
    else:
        try:
            if fail and part == "data":
                raise getattr(errors, fail)(f"injected failure for condition {condition.name}")
            folder_path.mkdir(parents=True, exist_ok=True)
            # The stages' tables go to the part's own log, not the worker's terminal. Inside
            # a Dask worker xarray would guard every netCDF access with a lock held by the
            # scheduler (a network round trip per variable): a part took 2.3x as long and
            # kept the scheduler's process busy. The part's own I/O needs no cluster lock
            # (only one part of a condition writes each file at a time: see
            # sysid.pipeline.study), so it runs on the local scheduler.
            with open(folder_path / f"study_{part}.log", "w") as log, \
                    dask.config.set(scheduler="synchronous"):
                run_study(folder_path, study_settings(condition, folder_path), quiet=True,
                          parts=(part,), log=log)
            if part == "results":
                record["summary"] = condition_summary(folder_path)
        except Exception as exc:  # noqa: BLE001 - the batch must survive any condition
            record.update(status="failed", error_type=type(exc).__name__,
                          message=str(exc).splitlines()[0] if str(exc) else repr(exc))
        part_elapsed[part] = time.perf_counter() - start
    record["part_elapsed_s"] = part_elapsed
    record["elapsed_s"] = sum(part_elapsed.values())
    if part == "results":
        try:
            _write_marker(folder_path, {k: v for k, v in record.items() if k != "summary"})
        except OSError:
            pass
    return record


def condition_summary(folder: str | Path) -> xr.Dataset:
    """Identified parameters, CR bounds, costs and truth of one finished study.

    Dims ``model`` (method) and ``parameter``; see the module docstring for the variables.
    """
    tree = read_campaign(Path(folder) / "campaign.nc")
    models = {}
    for method in METHODS:
        try:
            models[method] = tree[f"models/{method}"].to_dataset()
        except KeyError:
            continue
    if not models:
        raise SysidError(f"{folder}: the study has no identified model")
    truth = truth_for_model(tree, next(iter(models.values())))
    names: list[str] = []
    for model in models.values():
        names += [str(p) for p, f in zip(model.parameter.values, model["free"].values)
                  if bool(f) and str(p) not in names]
    if truth is not None:
        names += [str(p) for p in truth.parameter.values if str(p) not in names]
    methods = list(models)
    value = np.full((len(methods), len(names)), np.nan)
    bounds = {name: np.full_like(value, np.nan) for name in _BOUND_VARIABLES}
    j_ave = np.full(len(methods), np.nan)
    for i, (method, model) in enumerate(models.items()):
        index = {str(p): k for k, p in enumerate(model.parameter.values)}
        for j, name in enumerate(names):
            k = index.get(name)
            if k is None or not bool(model["free"].values[k]):
                continue
            value[i, j] = float(model["value"].values[k])
            for variable, table in bounds.items():
                if variable in model:
                    table[i, j] = float(model[variable].values[k])
        j_ave[i] = float(model.attrs.get("J_ave", np.nan))
    truth_values = parameter_values(truth, names)
    # a higher-order model (flapping) has no L_p, M_q, L_lat, M_lon of its own: its
    # quasi-steady equivalents stand in for them, against the quasi-steady truth
    equivalents = dominant_equivalents(tree, models)
    if equivalents:
        extra = [n for n in DOMINANT if n not in names and any(
            n in eq.parameter.values for eq in equivalents.values())]
        names += extra
        pad = np.full((len(methods), len(extra)), np.nan)
        value = np.hstack([value, pad])
        bounds = {k: np.hstack([v, pad]) for k, v in bounds.items()}
        truth_values = np.concatenate([truth_values, parameter_values(
            tree["linearization"].to_dataset(inherit=False), extra)])
        for i, method in enumerate(methods):
            eq = equivalents.get(method)
            for j, name in enumerate(names):
                if eq is None or name not in extra or name not in eq.parameter.values:
                    continue
                value[i, j] = float(eq["value"].sel(parameter=name))
                for variable, table in bounds.items():
                    if variable in eq:
                        table[i, j] = float(eq[variable].sel(parameter=name))
                if "cramer_rao" in eq:
                    bounds["cramer_rao_percent"][i, j] = 100 * abs(
                        float(eq["cramer_rao"].sel(parameter=name)) / value[i, j])
    j_rms = np.full(len(methods), np.nan)
    try:
        verification = [child.to_dataset() for child in tree["verification"].children.values()]
    except KeyError:
        verification = []
    for i, method in enumerate(methods):
        values = [float(v["j_rms"].sel(source=method)) for v in verification
                  if "j_rms" in v and method in v["j_rms"].source.values]
        if values:
            j_rms[i] = float(np.mean(values))
    floor = [float(v["j_rms"].sel(source=TRUTH_SOURCE)) for v in verification
             if "j_rms" in v and TRUTH_SOURCE in v["j_rms"].source.values]
    in_band = np.full_like(value, np.nan)
    if "comparison" in tree.children and "truth_in_band" in tree["comparison"].ds:
        band = tree["comparison"].to_dataset(inherit=False)["truth_in_band"]
        in_band = band.reindex(model=methods, parameter=names).transpose(
            "model", "parameter").values.astype(float)
    dims = ("model", "parameter")
    return xr.Dataset(
        {"value": (dims, value),
         **{name: (dims, bounds[name], attrs) for name, attrs in _BOUND_VARIABLES.items()},
         "truth": (("parameter",), truth_values,
                   {"long_name": "truth model's linearisation (quasi-steady, or reduced to "
                                 "a higher-order structure's states)"}),
         "truth_in_band": (dims, in_band,
                           {"long_name": "the structure fitted to the truth's exact responses "
                                         "in the frequency-domain estimate's band, points and "
                                         "weights (sysid.assess.comparison.truth_in_band)"}),
         "J_ave": (("model",), j_ave, {"long_name": "average frequency-domain cost"}),
         "j_rms": (("model",), j_rms,
                   {"long_name": "mean J_rms over the verification manoeuvres"}),
         "j_rms_truth": ((), float(np.mean(floor)) if floor else np.nan,
                         {"long_name": "mean J_rms of the truth linearisation (reduced to "
                                       "the structure) over the same manoeuvres"})},
        coords={"model": methods, "parameter": names})


#: The bounds a condition's models carry into batch.nc (absolute unless said), with their
#: attributes, and the point selection's outlying fraction beside them.
_BOUND_VARIABLES = {
    "cramer_rao": {"long_name": "plain Cramer-Rao bound"},
    "cramer_rao_percent": {"units": "%"},
    "cramer_rao_corrected": {"long_name": "Cramer-Rao bound corrected for coloured residuals"},
    "cramer_rao_noise": {"long_name": "frequency-domain bound from the spectral random error"},
    "cramer_rao_selection": {"long_name": "frequency-domain scatter over point re-selections"},
    "cramer_rao_total": {"long_name": "frequency-domain random-error and selection bounds in "
                                      "quadrature"},
    "selection_outlying": {"long_name": f"fraction of the point re-selections more than "
                                        f"{OUTLYING_SCALES:g} selection bounds from their "
                                        f"median", "units": "1"},
}


# -----------------------------------------------------------------------------------------
# The batch
# -----------------------------------------------------------------------------------------
@dataclass
class BatchResult:
    """What :func:`run_batch` produced."""

    dataset: xr.Dataset
    records: list[dict]
    wall_time_s: float
    out_dir: Path
    monte_carlo: xr.Dataset | None = None
    figure: Path | None = None

    @property
    def failures(self) -> list[dict]:
        return [r for r in self.records if r["status"] != "ok"]

    @property
    def succeeded(self) -> list[str]:
        return [r["name"] for r in self.records if r["status"] == "ok"]


#: Dask settings of the batch's own LocalCluster (a scheduler given by address keeps its
#: own). One BLAS thread per worker process: the workers already use every core. Without
#: distributed's default ``MALLOC_TRIM_THRESHOLD_=65536``, which fixes glibc's trim and mmap
#: thresholds so that every large numpy array is mapped and unmapped again (the 80-kt
#: time-domain fit 9.8 s in a plain process, 15.9 s with it), and without the workers'
#: statistical profiler, which samples the task's stack every 10 ms (a further ~10 %):
#: docs/notes/2026-11-26-batch-worker-malloc-trim.md. On Linux the workers are forked from
#: the driver, which has imported the study's modules, rather than spawned (each importing
#: them again): the cluster starts in 0.11 s instead of 1.7 s on an idle machine, serial
#: time in every batch (docs/notes/2026-11-27-batch-forked-workers.md); a forked worker
#: keeps the driver's BLAS thread pool, and every part limits it again (``run_study``). The
#: event loops' blocked-loop tick (every 20 ms by default) and system monitor (every 0.5 s)
#: run every 1 s and 2 s: in a worker they woke the loop beside the task's thread (four quick
#: conditions: 8 200-8 600 involuntary context switches of the workers against 2 200-3 500,
#: and 1-3 s more of their CPU; docs/notes/2026-11-28-batch-ratio-after-faster-parts.md).
WORKER_CONFIG = {
    "distributed.nanny.pre-spawn-environ": {
        "OPENBLAS_NUM_THREADS": 1, "OMP_NUM_THREADS": 1, "MKL_NUM_THREADS": 1},
    "distributed.worker.profile.enabled": False,
    "distributed.admin.tick.interval": "1s",
    "distributed.admin.system-monitor.interval": "2s",
    "distributed.worker.multiprocessing-method":
        "fork" if sys.platform.startswith("linux") else "spawn",
}


def _client(scheduler: str | None, n_workers: int, quiet: bool,
            settings: contextlib.ExitStack):
    """A client of ``scheduler``, or of a new LocalCluster whose :data:`WORKER_CONFIG` is
    entered into ``settings`` for the cluster's whole life (a worker that dies is started
    again as the first ones were); the caller closes ``settings`` after the cluster."""
    import logging

    import dask
    # imported before the settings: leaving dask.config.set deletes the config sections that
    # did not exist when it was entered, distributed's defaults among them
    from distributed import Client, LocalCluster  # deferred: optional heavy dependency

    if scheduler:
        return Client(scheduler), None
    settings.enter_context(dask.config.set(WORKER_CONFIG))
    cluster = LocalCluster(n_workers=n_workers, threads_per_worker=1, processes=True,
                           dashboard_address=":0",
                           silence_logs=logging.ERROR if quiet else logging.WARNING)
    return Client(cluster), cluster


#: Priority of each part (higher first) in the driver's queue of ready parts: the parts that
#: start the longest chain of work go first (critical path first: the campaign, then the
#: frequency-domain fit, the longer and more variable of the two fits, 3-13 s of CPU on a
#: quick 80-kt condition against the time domain's 2-6 s), so the batch ends on short
#: result parts on both workers rather than on one condition's fits and results on one
#: worker (docs/notes/2026-11-26-batch-frequency-domain-first.md).
PART_PRIORITY = {"data": 3, "frequency_domain": 2, "time_domain": 1, "results": 0}


class _ReadyParts:
    """Parts whose inputs have arrived, waiting for a free worker thread: :meth:`pop` gives
    the highest :data:`PART_PRIORITY` first, then the one that became ready first."""

    def __init__(self) -> None:
        self._heap: list = []  # (-priority, order, condition, part)
        self._order = itertools.count()

    def add(self, condition: Condition, part: str) -> None:
        heapq.heappush(self._heap, (-PART_PRIORITY[part], next(self._order), condition, part))

    def pop(self) -> tuple[Condition, str]:
        _, _, condition, part = heapq.heappop(self._heap)
        return condition, part

    def __len__(self) -> int:
        return len(self._heap)


def _submit_part(client, condition: Condition, folder: Path, part: str, fail: str | None,
                 upstream: Sequence[dict]):
    """One part of one condition as a Dask task, the records of the parts it needs
    (:data:`PART_NEEDS`) passed as values, so the task is ready when submitted."""
    return client.submit(run_condition_part, condition.to_dict(), str(folder), part, fail,
                         *upstream, pure=False, priority=PART_PRIORITY[part],
                         key=f"sysid-{part}-{condition.name}-{time.time_ns()}")


def run_batch(conditions: Sequence[Condition], out_dir: str | Path, *,
              scheduler: str | None = None, n_workers: int = 2, quiet: bool = False,
              inject_failure: dict[str, str] | None = None) -> BatchResult:
    """Run every condition's study as a Dask task; combine, plot and summarise (module doc).

    ``inject_failure`` maps a condition name to an exception class name of
    :mod:`sysid.core.errors` raised inside its task (fault-tolerance tests).
    """
    conditions = list(conditions)
    if not conditions:
        raise InputDataError("run_batch: no conditions given")
    names = [c.name for c in conditions]
    duplicated = sorted({n for n in names if names.count(n) > 1})
    if duplicated:
        raise InputDataError(f"run_batch: duplicated conditions {duplicated}")
    if n_workers < 1:
        raise InputDataError(f"run_batch: n_workers must be >= 1, got {n_workers}")
    for c in conditions:
        c.check()
    out = Path(out_dir).resolve()
    out.mkdir(parents=True, exist_ok=True)
    progress = Progress(quiet=quiet)
    inject_failure = dict(inject_failure or {})
    start = time.perf_counter()
    records: dict[str, dict] = {}

    # Resume: finished conditions are read back, not recomputed.
    todo = []
    for c in conditions:
        folder = out / c.name
        if completed(c, folder) and c.name not in inject_failure:
            record = json.loads(_marker(folder).read_text())
            try:
                record["summary"] = condition_summary(folder)
            except Exception:  # noqa: BLE001 - unreadable: recompute it
                todo.append(c)
                continue
            records[c.name] = record
            progress.message(f"[batch] {c.name}: done earlier (resumed from {folder})")
        else:
            todo.append(c)

    settings = contextlib.ExitStack()
    if todo:
        build_fmu()  # once here, so workers never race to build the truth FMU
        try:
            client, cluster = _client(scheduler, n_workers, quiet, settings)
        except BaseException:
            settings.close()
            raise
        try:
            from distributed import as_completed  # deferred: optional heavy dependency

            queue = as_completed()
            tasks: dict = {}  # future key -> (condition, part)
            parts: dict[str, dict] = {c.name: {} for c in todo}  # part -> record, or None
            #                                                       while it waits or runs
            # The driver holds the ready parts and submits one whenever a worker thread is
            # free, highest PART_PRIORITY first (then condition order). Submitted at once,
            # each task was placed on a worker when submitted, and a worker ran its own
            # backlog (a time-domain fit) while a longer frequency-domain fit waited on
            # the other. An external scheduler gets every ready part at once.
            slots = n_workers if scheduler is None else math.inf
            ready = _ReadyParts()

            def make_ready(c: Condition, part: str) -> None:
                parts[c.name][part] = None
                ready.add(c, part)

            def dispatch() -> None:
                while ready and len(tasks) < slots:
                    c, part = ready.pop()
                    if c.name in records:  # the condition ended (its worker died)
                        continue
                    upstream = [parts[c.name][n] for n in PART_NEEDS[part]]
                    fut = _submit_part(client, c, out / c.name, part,
                                       inject_failure.get(c.name), upstream)
                    tasks[fut.key] = (c, part)
                    queue.add(fut)

            for c in todo:
                make_ready(c, PARTS[0])
            dispatch()
            done = 0
            for fut in queue:
                c, part = tasks.pop(fut.key)
                try:  # a worker thread is free: the next ready part goes in `finally`
                    if c.name in records:  # the condition already ended (its worker died)
                        continue
                    try:
                        record = fut.result()
                    except Exception as exc:  # noqa: BLE001 - e.g. a worker died (KilledWorker)
                        record = {"name": c.name, "condition": c.to_dict(), "status": "failed",
                                  "error_type": type(exc).__name__, "message": str(exc),
                                  "elapsed_s": float("nan"), "summary": None}
                    else:
                        mine = parts[c.name]
                        mine[part] = record
                        if part != PARTS[-1]:
                            for later in PARTS:
                                if later not in mine and all(
                                        mine.get(n) is not None for n in PART_NEEDS[later]):
                                    make_ready(c, later)
                            continue
                    records[c.name] = record
                    del parts[c.name]
                    done += 1
                    if record["status"] == "ok":
                        j = record["summary"]["J_ave"]
                        costs = "  ".join(f"J_ave {m} {float(j.sel(model=m)):.1f}"
                                          for m in j.model.values
                                          if np.isfinite(j.sel(model=m)))  # frequency domain only
                        progress.message(f"[batch] {done}/{len(todo)} {c.name}: ok in "
                                         f"{record['elapsed_s']:.0f} s  {costs}")
                    else:
                        progress.message(f"[batch] {done}/{len(todo)} {c.name}: FAILED "
                                         f"{record['error_type']}: {record['message']}")
                finally:
                    dispatch()
        except BaseException:
            _close(client, cluster)
            settings.close()
            raise
        # The workers shut down (~0.5 s) while the driver combines and draws.
        closing = threading.Thread(target=_close, args=(client, cluster),
                                   name="sysid-batch-close")
        closing.start()
    try:
        return _finish(conditions, records, out, scheduler, n_workers, start, progress)
    finally:
        if todo:
            closing.join()
        settings.close()


def _close(client, cluster) -> None:
    client.close()
    if cluster is not None:
        cluster.close()


def _finish(conditions: Sequence[Condition], records: dict[str, dict], out: Path,
            scheduler: str | None, n_workers: int, start: float,
            progress: Progress) -> BatchResult:
    """Combine the records, write batch.nc, the figures and the summaries (module doc)."""
    ordered = [records[c.name] for c in conditions]
    dataset = combine(conditions, ordered)
    calibrated = calibration(dataset)
    if calibrated is not None:
        dataset = dataset.merge(calibrated)
    wall = time.perf_counter() - start
    dataset.attrs.update(wall_time_s=round(wall, 2),
                         n_workers=0 if scheduler else int(n_workers),
                         scheduler=scheduler or "LocalCluster")
    with atomic_path(out / "batch.nc") as tmp:
        dataset.to_netcdf(tmp)
    figure = plot_derivatives(dataset, out / "batch_derivatives.png")
    if calibrated is not None:
        plot_calibration(dataset, out / "batch_calibration.png")
    mc = monte_carlo(dataset)
    if mc is not None:
        with atomic_path(out / "monte_carlo.nc") as tmp:
            mc.to_netcdf(tmp)
        with atomic_path(out / "monte_carlo.txt") as tmp:
            tmp.write_text(format_monte_carlo(mc) + "\n"
                           + ("\n" + format_calibration(dataset) + "\n"
                              if calibrated is not None else ""))
    with atomic_path(out / "batch_summary.txt") as tmp:
        tmp.write_text(format_summary(dataset) + "\n")
    failed = [r for r in ordered if r["status"] != "ok"]
    progress.message(f"[batch] {len(ordered) - len(failed)}/{len(ordered)} conditions ok "
                     f"in {wall:.0f} s; results in {out / 'batch.nc'}")
    return BatchResult(dataset, ordered, wall, out, mc, figure)


def combine(conditions: Sequence[Condition], records: Sequence[dict]) -> xr.Dataset:
    """One Dataset on a ``condition`` dimension from the per-condition records."""
    names = [c.name for c in conditions]
    parts = [r["summary"].expand_dims(condition=[r["name"]]) for r in records
             if r["status"] == "ok" and r.get("summary") is not None]
    if parts:
        ds = xr.concat(parts, dim="condition", join="outer", data_vars="all",
                       coords="different", compat="equals", fill_value=np.nan)
        # Parameters in a physically meaningful order: A derivatives, B, then delays.
        ds = ds.reindex(condition=names, parameter=_order(ds.parameter.values))
    else:
        ds = xr.Dataset(coords={"condition": names})
    by_name = {r["name"]: r for r in records}
    ds = ds.assign_coords(
        airspeed_kt=("condition", [c.airspeed_kt for c in conditions], {"units": "kt"}),
        seed=("condition", [c.seed for c in conditions]),
        noise=("condition", np.array([int(c.noise) for c in conditions], dtype="int8")),
        quick=("condition", np.array([int(c.quick) for c in conditions], dtype="int8")),
        calm_sweeps=("condition", np.array([int(c.calm_sweeps) for c in conditions],
                                           dtype="int8")),
        campaign=("condition", [c.campaign or "" for c in conditions]),
        group=("condition", [c.group for c in conditions]),
        structure=("condition", [c.structure_name for c in conditions]),
        time_domain_method=("condition", [c.time_domain_estimator for c in conditions]),
        status=("condition", [by_name[n]["status"] for n in names]),
        error=("condition", [(f"{by_name[n]['error_type']}: {by_name[n]['message']}"
                              if by_name[n]["status"] != "ok" else "") for n in names]),
        elapsed_s=("condition", [float(by_name[n].get("elapsed_s", np.nan)) for n in names],
                   {"units": "s"}))
    ds.attrs.update(long_name="identification results per flight condition (sysid.pipeline.batch)",
                    n_conditions=len(names), n_failed=int(sum(r["status"] != "ok"
                                                              for r in records)))
    if any(c.quick for c in conditions):
        ds.attrs["quick_omits"] = "; ".join(QUICK_OMITS)
    return ds


def _order(parameters) -> list[str]:
    def key(name: str):
        if name.startswith("tau_"):
            return (2, name)
        letter, _, column = name.partition("_")
        group = 1 if column in CONTROLS else 0
        return (group, "XYZLMN".find(letter) if letter in "XYZLMN" else 9, column, name)

    return sorted((str(p) for p in parameters), key=key)


def estimated_parameters(ds: xr.Dataset) -> list[str]:
    """Parameters some method estimated in some condition."""
    if "value" not in ds:
        return []
    have = ds["value"].notnull().any(("condition", "model"))
    return [str(p) for p in ds.parameter.values if bool(have.sel(parameter=p))]


def group_positions(ds: xr.Dataset, span: float) -> tuple[np.ndarray, list[str]]:
    """x position (kt) of each condition of ``ds`` in :func:`plot_derivatives`: its airspeed,
    moved sideways by ``0.05 span`` per :attr:`Condition.group` when several groups share the
    airspeed (two structures or campaign designs side by side, not on top of each other);
    and the groups so moved, in their left-to-right order."""
    speeds = np.asarray(ds.airspeed_kt.values, dtype=float)
    labels = _group_labels(ds)
    x = speeds.copy()
    moved: list[str] = []
    for speed in np.unique(speeds):
        here = list(dict.fromkeys(labels[speeds == speed]))
        if len(here) < 2:
            continue
        moved += here
        for k, label in enumerate(here):
            x[(speeds == speed) & (labels == label)] += (k - (len(here) - 1) / 2) * 0.05 * span
    return x, moved


def plot_derivatives(ds: xr.Dataset, path: str | Path) -> Path | None:
    """Grid of every estimated parameter against airspeed (CR bars, truth line; groups that
    share an airspeed side by side, :func:`group_positions`); PNG."""
    import matplotlib  # deferred: optional heavy dependency, only for the figure

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    params = estimated_parameters(ds)
    if not params:
        return None
    ok = ds.isel(condition=np.flatnonzero(ds.status.values == "ok"))
    ncols = 6
    nrows = math.ceil(len(params) / ncols)
    fig, axes = plt.subplots(nrows, ncols, figsize=(3.0 * ncols, 2.3 * nrows), squeeze=False)
    span = max(float(np.ptp(ok.airspeed_kt.values)) if ok.sizes["condition"] else 0.0, 40.0)
    speeds, moved = group_positions(ok, span)
    styles = {"frequency_domain": ("C0", "o", -0.012), "time_domain": ("C3", "s", 0.012)}
    for ax, name in zip(axes.flat, params):
        limit = _plot_limit(ok["value"].sel(parameter=name).values,
                            ok["truth"].sel(parameter=name).values)
        off_scale = 0
        for method in ok.model.values:
            color, marker, shift = styles.get(str(method), ("C2", "^", 0.0))
            v = ok["value"].sel(model=method, parameter=name).values
            e = ok["cramer_rao"].sel(model=method, parameter=name).values
            good = np.isfinite(v) & (np.abs(v) <= limit)
            ax.errorbar(speeds[good] + shift * span, v[good],
                        yerr=np.where(np.isfinite(e[good]), e[good], 0.0), fmt=marker,
                        color=color, ms=3.5, capsize=2, lw=0.9,
                        label="FD" if method == "frequency_domain" else
                        "TD" if method == "time_domain" else str(method))
            # Diverged estimates (e.g. 1e9) would flatten the panel: drawn as open
            # triangles on its edge and counted in the title instead.
            far = np.isfinite(v) & (np.abs(v) > limit)
            off_scale += int(far.sum())
            if far.any():
                ax.plot(speeds[far] + shift * span, np.sign(v[far]) * limit,
                        "^" if np.all(v[far] > 0) else "v", mfc="none", color=color, ms=5)
        truth = ok["truth"].sel(parameter=name)
        if truth.notnull().any():  # per position: two structures' truths differ
            t = truth.assign_coords(x=("condition", speeds)).groupby("x").mean()
            ax.plot(t.x.values, t.values, color="k", ls="none" if moved else "-", marker="_",
                    ms=14, lw=1.2, label="truth")
        # A fixed title height and at most 5 ticks per axis: matplotlib otherwise measures
        # every axis to place each title and builds ~8 ticks per axis (together 70 % of
        # the figure's 1.8 s, serial work of the batch driver).
        ax.set_title(name + (f" ({off_scale} off scale)" if off_scale else ""), fontsize=9,
                     y=1.0)
        ax.locator_params(nbins=4)
        ax.tick_params(labelsize=7)
        ax.axhline(0.0, color="0.8", lw=0.6, zorder=0)
    for ax in list(axes.flat)[len(params):]:
        ax.set_visible(False)
    for ax in axes[-1]:
        ax.set_xlabel("airspeed, kt", fontsize=8)
    handles, labels = axes.flat[0].get_legend_handles_labels()
    if handles:
        fig.legend(handles, labels, loc="upper right", fontsize=8, ncol=3)
    failed = [str(c) for c in ds.condition.values[ds.status.values != "ok"]]
    fig.suptitle("Identified parameters against airspeed (bars: Cramer-Rao bound; line: truth "
                 "linearisation)" + (f"; failed: {', '.join(failed)}" if failed else "")
                 + (f"\nside by side, left to right: {', '.join(moved)}" if moved else ""),
                 fontsize=10)
    # Fixed margins (inches, for the fixed panel size) rather than tight_layout, which drew
    # the whole grid twice more: 54 % of the figure's time, serial work of the batch driver.
    height = 2.3 * nrows
    fig.subplots_adjust(left=0.045, right=0.99, bottom=0.45 / height, top=1 - 0.95 / height,
                        wspace=0.38, hspace=0.5)
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


#: Estimates beyond this many times the panel's scale (see _plot_limit) are drawn off scale.
OFF_SCALE_FACTOR = 5.0


def _plot_limit(values: np.ndarray, truth: np.ndarray) -> float:
    """Largest |value| a derivative panel shows: OFF_SCALE_FACTOR times the larger of the
    truth's largest magnitude and the estimates' median magnitude (robust to a few diverged
    fits); infinite when there is nothing to scale by."""
    scales = [np.nanmax(np.abs(truth)) if np.isfinite(truth).any() else 0.0,
              np.nanmedian(np.abs(values)) if np.isfinite(values).any() else 0.0]
    scale = max(scales)
    return OFF_SCALE_FACTOR * scale if scale > 0 else np.inf


def _group_labels(ds: xr.Dataset) -> np.ndarray:
    """:attr:`Condition.group` of each condition of ``ds`` (by airspeed alone in a
    ``batch.nc`` written before the ``group`` coordinate)."""
    if "group" in ds.coords:
        return np.asarray(ds["group"].values, dtype=str)
    return np.array([f"{float(v):g}kt" for v in ds.airspeed_kt.values])


def seed_groups(ds: xr.Dataset) -> list[tuple[str, float, xr.Dataset]]:
    """The successful conditions of a ``batch.nc`` Dataset pooled over seeds: ``(group,
    airspeed_kt, part)`` for every :attr:`Condition.group` (the same airspeed, structure,
    campaign, estimator, noise ...; by airspeed alone in a file written before the ``group``
    coordinate) with at least two, ordered by airspeed. Why: a scatter over seeds is only
    one setting's; two structures or campaigns at one airspeed are not seeds of one."""
    ok = ds.isel(condition=np.flatnonzero(ds.status.values == "ok"))
    labels = _group_labels(ok)
    out = []
    for label in dict.fromkeys(map(str, labels)):
        part = ok.isel(condition=np.flatnonzero(labels == label))
        if part.sizes["condition"] >= 2:
            out.append((label, float(part.airspeed_kt.values[0]), part))
    return sorted(out, key=lambda g: g[1])


def monte_carlo(ds: xr.Dataset) -> xr.Dataset | None:
    """Observed scatter across seeds against the mean Cramer-Rao bound, per
    :func:`seed_groups` group.

    Only groups with at least two successful seeds count. Returns (group, model, parameter),
    coordinate ``airspeed_kt`` (group): ``std`` (sample standard deviation over seeds),
    ``mean``, ``cramer_rao_mean`` and ``ratio = std / cramer_rao_mean`` (about 1 when the
    CR bound is a fair error estimate; CIFER experience puts the observed scatter at 2-3
    times the bound), and ``n_seeds``.
    """
    if "value" not in ds:
        return None
    groups = []
    for label, speed, part in seed_groups(ds):
        std = part["value"].std("condition", ddof=1)
        cr = part["cramer_rao"].mean("condition")
        groups.append(xr.Dataset({
            "std": std, "mean": part["value"].mean("condition"), "cramer_rao_mean": cr,
            "ratio": std / cr,
            "n_seeds": xr.DataArray(part.sizes["condition"])}).expand_dims(
                group=[label]).assign_coords(airspeed_kt=("group", [speed], {"units": "kt"})))
    if not groups:
        return None
    mc = xr.concat(groups, dim="group")
    mc["ratio"].attrs["long_name"] = "observed std over seeds / mean Cramer-Rao bound"
    return mc


def format_monte_carlo(mc: xr.Dataset) -> str:
    lines = ["Monte Carlo: observed std over seeds / mean Cramer-Rao bound"]
    for label in mc.group.values:
        part = mc.sel(group=label)
        lines.append(f"\n{label} ({int(part['n_seeds'])} seeds)")
        lines.append(f"{'parameter':<11}" + "".join(f"{str(m):>30}" for m in mc.model.values))
        lines.append(f"{'':<11}" + "".join(f"{'std':>10}{'CR':>10}{'ratio':>10}"
                                           for _ in mc.model.values))
        for p in mc.parameter.values:
            cells = part.sel(parameter=p)
            if not bool(cells["std"].notnull().any()):
                continue
            row = f"{str(p):<11}"
            for m in mc.model.values:
                c = cells.sel(model=m)
                row += "".join(f"{float(c[v]):>10.3g}" for v in ("std", "cramer_rao_mean",
                                                                  "ratio"))
            lines.append(row)
        ratio = part["ratio"].where(np.isfinite(part["ratio"]))
        lines.append("median ratio: " + ", ".join(
            f"{str(m)} {float(ratio.sel(model=m).median()):.2f}" for m in mc.model.values))
    return "\n".join(lines)


#: The bounds the Monte Carlo calibration judges: the frequency-domain Cramer-Rao bound (CIFER
#: convention), the same scaled by the fit residuals, the one from the spectral random
#: error and that one with the point selection's scatter, the time-domain white-noise bound
#: and the time-domain bound corrected for coloured residuals, as
#: ``name -> (model, batch.nc variable)``.
CALIBRATION_BOUNDS = {
    "frequency_domain": ("frequency_domain", "cramer_rao"),
    "frequency_domain_scaled": ("frequency_domain", "cramer_rao_corrected"),
    "frequency_domain_noise": ("frequency_domain", "cramer_rao_noise"),
    "frequency_domain_total": ("frequency_domain", "cramer_rao_total"),
    "time_domain_white": ("time_domain", "cramer_rao"),
    "time_domain_corrected": ("time_domain", "cramer_rao_corrected"),
}
#: Goal band of the calibration ratio scatter / mean bound (issue 21): a bound within a
#: factor of two of the observed scatter.
CALIBRATION_GOAL = (0.5, 2.0)


def calibration(ds: xr.Dataset, parameters: Sequence[str] = DOMINANT) -> xr.Dataset | None:
    """Monte Carlo calibration of the reported bounds: per :func:`seed_groups` group (at
    least two successful seeds of one setting), per dominant derivative and per bound of
    :data:`CALIBRATION_BOUNDS`, the seed-to-seed scatter of the estimate against the mean
    reported bound.

    ``scatter = std over seeds (ddof=1)`` of the estimate of the bound's model,
    ``bound = mean over seeds`` of the reported bound (absolute), ``ratio = scatter /
    bound`` (1 for an honest bound; the goal is :data:`CALIBRATION_GOAL`). Seeds where a
    derivative was not estimated (removed by the reduction) are left out of both.

    Returns
    -------
    xr.Dataset or None
        Dims ``calibration_group`` (coordinate ``calibration_kt``: airspeed, kt),
        ``dominant``, ``bound``: variables
        ``calibration_scatter``, ``calibration_bound``, ``calibration_ratio``,
        ``calibration_mean`` (mean estimate), ``calibration_truth`` (mean truth value),
        ``calibration_n_seeds`` (seeds with an estimate); None when no group has two
        successful seeds.
    """
    if "value" not in ds or "condition" not in ds.dims:
        return None
    groups = seed_groups(ds)
    if not groups:
        return None
    params = [str(p) for p in parameters]
    bounds = list(CALIBRATION_BOUNDS)
    shape = (len(groups), len(params), len(bounds))
    out = {k: np.full(shape, np.nan) for k in ("scatter", "bound", "mean", "truth")}
    count = np.zeros(shape, dtype=int)
    models = [str(m) for m in ds.model.values]
    present = [str(p) for p in ds.parameter.values]
    for i, (_, _, part) in enumerate(groups):
        for j, name in enumerate(params):
            if name not in present:
                continue
            for k, (model, variable) in enumerate(CALIBRATION_BOUNDS.values()):
                if model not in models or variable not in part:
                    continue
                value = part["value"].sel(model=model, parameter=name).values
                bound = part[variable].sel(model=model, parameter=name).values
                use = np.isfinite(value) & np.isfinite(bound)
                count[i, j, k] = int(use.sum())
                if use.sum() >= 2:
                    out["scatter"][i, j, k] = np.std(value[use], ddof=1)
                    out["bound"][i, j, k] = np.mean(bound[use])
                    out["mean"][i, j, k] = np.mean(value[use])
                if "truth" in part:
                    out["truth"][i, j, k] = float(np.nanmean(
                        part["truth"].sel(parameter=name).values)) if bool(
                        part["truth"].sel(parameter=name).notnull().any()) else np.nan
    with np.errstate(divide="ignore", invalid="ignore"):
        ratio = out["scatter"] / out["bound"]
    dims = ("calibration_group", "dominant", "bound")
    return xr.Dataset(
        {"calibration_scatter": (dims, out["scatter"], {
            "long_name": "standard deviation of the estimate over seeds (ddof=1)"}),
         "calibration_bound": (dims, out["bound"], {
             "long_name": "mean reported bound over seeds (absolute)"}),
         "calibration_ratio": (dims, ratio, {
             "long_name": "scatter / mean bound", "goal": list(CALIBRATION_GOAL)}),
         "calibration_mean": (dims, out["mean"], {"long_name": "mean estimate over seeds"}),
         "calibration_truth": (dims, out["truth"], {
             "long_name": "the truth column's value (mean over seeds)"}),
         "calibration_n_seeds": (dims, count, {"long_name": "seeds with an estimate"})},
        coords={"calibration_group": [g[0] for g in groups],
                "calibration_kt": ("calibration_group", [g[1] for g in groups],
                                   {"units": "kt"}),
                "dominant": params, "bound": bounds})


def format_calibration(ds: xr.Dataset) -> str:
    """Text table of :func:`calibration` (from a ``batch.nc`` Dataset that carries it)."""
    lines = [f"Calibration of the bounds: scatter over seeds / mean reported bound "
             f"(goal {CALIBRATION_GOAL[0]:g}-{CALIBRATION_GOAL[1]:g})"]
    bounds = [str(b) for b in ds.bound.values]
    for label in ds.calibration_group.values:
        part = ds.sel(calibration_group=label)
        n = int(part["calibration_n_seeds"].max())
        lines.append(f"\n{label} (up to {n} seeds); bias = (mean - truth) / scatter")
        lines.append(f"{'parameter':<10}" + "".join(f"{b:>24}" for b in bounds)
                     + f"{'bias FD':>9}{'bias TD':>9}")
        lines.append(f"{'':<10}" + "".join(f"{'scatter':>9}{'bound':>9}{'ratio':>6}"
                                           for _ in bounds))
        for name in ds.dominant.values:
            c = part.sel(dominant=name)
            row = f"{str(name):<10}"
            for b in bounds:
                cb = c.sel(bound=b)
                row += (f"{float(cb['calibration_scatter']):>9.3g}"
                        f"{float(cb['calibration_bound']):>9.3g}"
                        f"{float(cb['calibration_ratio']):>6.2f}")
            for b in ("frequency_domain", "time_domain_white"):
                cb = c.sel(bound=b)
                bias = (float(cb["calibration_mean"]) - float(cb["calibration_truth"])) / \
                    float(cb["calibration_scatter"])
                row += f"{bias:>9.1f}"
            lines.append(row)
        inside = ((part["calibration_ratio"] >= CALIBRATION_GOAL[0])
                  & (part["calibration_ratio"] <= CALIBRATION_GOAL[1]))
        lines.append("inside the goal band: " + ", ".join(
            f"{b} {int(inside.sel(bound=b).sum())}/{ds.sizes['dominant']}" for b in bounds))
    return "\n".join(lines)


def plot_calibration(ds: xr.Dataset, path: str | Path) -> Path | None:
    """Scatter / mean bound per dominant derivative, one marker per bound of
    :data:`CALIBRATION_BOUNDS`, one panel per group, log scale, the goal band shaded; PNG."""
    import matplotlib  # deferred: optional heavy dependency, only for the figure

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    if "calibration_ratio" not in ds:
        return None
    groups = ds.calibration_group.values
    fig, axes = plt.subplots(1, len(groups), figsize=(7.5 * len(groups), 3.8), squeeze=False)
    styles = {"frequency_domain": ("C0", "o", "FD: CR bound (CIFER)"),
              "frequency_domain_scaled": ("C9", "v", "FD: scaled by the residuals"),
              "frequency_domain_noise": ("C1", "x", "FD: from the spectral random error"),
              "frequency_domain_total": ("C4", "*", "FD: random error + point selection"),
              "time_domain_white": ("C3", "s", "TD: white-noise CR bound"),
              "time_domain_corrected": ("C2", "D", "TD: corrected for coloured residuals")}
    names = [str(n) for n in ds.dominant.values]
    x = np.arange(len(names))
    for ax, group in zip(axes[0], groups):
        part = ds["calibration_ratio"].sel(calibration_group=group)
        ax.axhspan(*CALIBRATION_GOAL, color="0.9", zorder=0, label="goal 0.5-2")
        ax.axhline(1.0, color="0.6", lw=0.8, zorder=0)
        for k, bound in enumerate(ds.bound.values):
            color, marker, label = styles.get(str(bound), ("C1", "^", str(bound)))
            r = part.sel(bound=bound).values
            offset = (k - (ds.sizes["bound"] - 1) / 2) * 0.15
            ax.plot(x + offset, np.where(r > 0, r, np.nan), marker, color=color,
                    ms=6, ls="none", label=label)
        ax.set_yscale("log")
        ax.set_xticks(x, names, fontsize=8)
        n = int(ds["calibration_n_seeds"].sel(calibration_group=group).max())
        ax.set_title(f"{group}, {n} seeds: scatter over seeds / mean reported bound",
                     fontsize=9)
        ax.set_ylabel("ratio", fontsize=8)
        ax.legend(fontsize=7, loc="best")
    fig.tight_layout()
    path = Path(path)
    with atomic_path(path) as tmp:
        fig.savefig(tmp, dpi=90)
    plt.close(fig)
    return path


def format_summary(ds: xr.Dataset) -> str:
    lines = [f"{'condition':<32}{'kt':>6}{'seed':>10}  {'structure':<14}{'status':<8}"
             f"{'time s':>8}{'J_ave FD':>10}{'J_ave TD':>10}  error"]
    for k, name in enumerate(ds.condition.values):
        row = ds.isel(condition=k)
        j = {}
        if "J_ave" in ds:
            for m in ("frequency_domain", "time_domain"):
                j[m] = (float(row["J_ave"].sel(model=m)) if m in ds.model.values
                        else float("nan"))
        lines.append(f"{str(name):<32}{float(row.airspeed_kt):>6g}{int(row.seed):>10}  "
                     f"{str(row.structure.values):<14}{str(row.status.values):<8}"
                     f"{float(row.elapsed_s):>8.1f}"
                     f"{j.get('frequency_domain', float('nan')):>10.2f}"
                     f"{j.get('time_domain', float('nan')):>10.2f}  {str(row.error.values)}")
    if "wall_time_s" in ds.attrs:
        lines.append(f"wall time {ds.attrs['wall_time_s']} s on {ds.attrs.get('scheduler')}"
                     f" ({ds.attrs.get('n_workers')} workers)")
    return "\n".join(lines)


def read_batch(out_dir: str | Path) -> xr.Dataset:
    """The combined ``batch.nc`` of a finished batch."""
    path = Path(out_dir) / "batch.nc"
    if not path.exists():
        raise InputDataError(f"no batch results at {path}")
    with xr.open_dataset(path) as ds:
        return ds.load()


def default_conditions(*, quick: bool = False) -> list[Condition]:
    """The issue's six airspeeds, one seed each."""
    return conditions(DEFAULT_SPEEDS, quick=quick)


__all__ = ["Condition", "BatchResult", "conditions", "load_conditions", "default_conditions",
           "run_batch", "run_condition", "run_condition_part", "condition_summary", "combine",
           "plot_derivatives", "group_positions", "seed_groups", "monte_carlo",
           "calibration", "format_calibration", "plot_calibration", "CALIBRATION_BOUNDS",
           "CALIBRATION_GOAL", "structure_for", "quick_campaign", "read_batch",
           "DEFAULT_SPEEDS", "FORWARD_FLIGHT_KT"]

