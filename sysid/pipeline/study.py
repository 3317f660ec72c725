"""The paper's whole study in one call: campaign -> responses -> two models -> checks -> report.

:func:`run_study` chains the stages at one flight condition, writing everything under one
output folder::

    <out>/campaign.nc          the campaign DataTree (time histories and every result)
    <out>/model_frequency_domain.nc, <out>/model_time_domain.nc
                               each fit's model until the results part merges it into
                               campaign.nc (/models/<method>)
    <out>/frequency_domain.fmu, <out>/time_domain.fmu   the identified models as FMUs
    <out>/comparison.csv       derivative table (paper Tables 2-3)
    <out>/report.html, <out>/figures/   the report

Every stage is a library call on labelled xarray objects in memory: the campaign is flown
(:func:`sysid.flight_test.campaign.run_campaign`), the responses computed
(:func:`sysid.spectral.response.frequency_response`), the fits run
(:mod:`sysid.identify.stages`), the models verified, compared and validated
(:mod:`sysid.assess.stages`, :mod:`sysid.assess.comparison`, :mod:`sysid.assess.validation`)
and the report written from the tree in memory. The ``sysid`` sub-commands call the same
functions. The stages' tables go to ``log`` (a text stream), not to a redirected stdout.

Writes: each stage writes its result groups once, together with its cache stamp (one
:func:`sysid.data.netcdf.update_campaign_groups`), so the campaign file is written once per
stage boundary.

Caching: every stage stamps its result group with a key hashing its settings and the keys of
the stages before it (``workflow_key``) and the seconds it took (``workflow_elapsed_s``,
listed by the report). A re-run skips a stage whose group carries the key it would write, so
changing e.g. the structure re-runs identification and everything after it, but not the
campaign; a re-run with nothing changed writes nothing.

Parts: ``run_study(..., parts=...)`` runs a subset of :data:`PARTS` (data, the two fits,
results); :mod:`sysid.pipeline.batch` runs them as separate Dask tasks. Only one part at a
time writes ``campaign.nc``: ``data`` writes it before the fits start; the fits only read it
and write their own files (``model_<method>.nc``), so they may run at the same time, on one
machine or two, without a file lock; ``results`` merges both models into ``campaign.nc`` and
writes everything after them. (A fit part started before the data part has stored its
results runs the data part itself: do not start such parts side by side.)
"""

from __future__ import annotations

import hashlib
import json
import sys
import time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Callable, Mapping, TextIO

import xarray as xr

import sysid
from sysid.core.errors import InputDataError, SysidError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.core.util import Progress, numeric_settings, start_forkserver
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import group_attrs, read_campaign, update_campaign_groups, write_campaign
from sysid.flight_test.campaign import (Campaign, default_campaign, run_campaign,
                                       with_calm_sweeps)
from sysid.identify.stages import fit_filter_error, fit_frequency_domain, fit_time_domain
from sysid.models import declared_coherence_min, structure_path
from sysid.report.html import write_report
from sysid.spectral.cross_control import campaign_summary
from sysid.spectral.response import (NO_TRANSIENT_GROUP, frequency_response,
                                     siso_frequency_response)
from sysid.assess.coherence import format_coherent_ranges
from sysid.assess.comparison import (compare_models, format_scoreboard, format_sign_agreement,
                                     format_table, write_table_csv)
from sysid.assess.stages import verify_models
from sysid.assess.validation import format_validation, truth_reference, validate_models
from sysid.assess.verification import verification_table
from sysid.truth import build_fmu

__all__ = ["FORWARD_FLIGHT_KT", "FD_COHERENCE_MIN_HOVER", "FD_COHERENCE_MIN_FORWARD",
           "StudySettings", "PARTS", "METHODS", "TIME_DOMAIN_METHODS", "TIME_DOMAIN_AUTO",
           "QUICK_OMITS", "run_study", "study_tree",
           "structure_for", "campaign_from_file"]

#: From this airspeed (kt) up the forward-flight structure and coherence admission are used.
FORWARD_FLIGHT_KT = 30.0

#: The study's coherence admission in hover: the paper's 0.6 guideline (the library default),
#: checked by 2311 verification (docs/notes/2026-11-24-study-coherence-admission.md).
FD_COHERENCE_MIN_HOVER = COHERENCE_MIN
#: In forward flight (`forward_6dof`, 80 kt) points down to coherence 0.4 are admitted, with
#: W_gamma weighting the weak ones down: at 0.6 the 80-kt fit ran away (same note).
FD_COHERENCE_MIN_FORWARD = 0.4

#: The identification methods of the study, as stored under ``/models/<method>``.
METHODS = ("frequency_domain", "time_domain")

#: What a quick study (``StudySettings(quick=True)``) leaves out: only what the report shows
#: or what the batch does not collect. Both fits, their bounds and reductions, verification
#: on the 2311 manoeuvres and the derivative comparison run as in the full study.
QUICK_OMITS = (
    "cross-control coherence summary of the campaign (a report figure and guideline check)",
    "SISO and not leakage-conditioned frequency responses (the report's comparison figures)",
    "FMU export and validation against the truth FMU",
    "HTML report (write it afterwards with 'sysid report <folder>/campaign.nc')",
)


#: Estimators of the study's time-domain part (:attr:`StudySettings.time_domain_method`).
TIME_DOMAIN_METHODS = ("output_error", "filter_error")
#: ... and the default, which picks one of them (:attr:`StudySettings.time_domain_estimator`).
TIME_DOMAIN_AUTO = "auto"


def structure_for(airspeed_kt: float) -> str:
    """The built-in structure used at ``airspeed_kt`` when none is named."""
    return "hover_6dof" if airspeed_kt < FORWARD_FLIGHT_KT else "forward_6dof"


def campaign_from_file(path: str | Path, settings: "StudySettings") -> Campaign:
    """A campaign TOML flown as ``settings`` ask: their seed (when given) replaces the
    file's, ``noise=False`` switches its sensor noise and turbulence off; its airspeed must
    be the study's (the structure, the coherence admission and the report follow it)."""
    campaign = Campaign.from_toml(path)
    if settings.seed is not None:
        campaign = replace(campaign, seed=int(settings.seed))
    if not settings.noise:
        campaign = replace(campaign, noise={}, turbulence=0.0)
    if abs(float(campaign.airspeed_kt) - float(settings.airspeed_kt)) > 1e-9:
        raise InputDataError(f"campaign file {path}: it flies at {campaign.airspeed_kt:g} kt, "
                             f"the study is at {settings.airspeed_kt:g} kt; give the "
                             f"matching study or --speed {campaign.airspeed_kt:g}")
    return campaign


@dataclass
class StudySettings:
    """What to run; every field enters the cache keys of the stages that use it."""

    airspeed_kt: float = 0.0
    #: Campaign seed; None: the campaign file's own, or the built-in campaign's default.
    seed: int | None = None
    #: Sensor noise and turbulence (off: the campaign, built-in or file, flies without).
    noise: bool = True
    structure: str = "hover_6dof"
    #: Coherence admitting frequency points to the study's frequency-domain fit; None: the
    #: structure's own (TOML ``coherence_min``), else by flight condition,
    #: :data:`FD_COHERENCE_MIN_HOVER` in hover and :data:`FD_COHERENCE_MIN_FORWARD` in
    #: forward flight (see there).
    fd_coherence_min: float | None = None
    time_domain_maneuvers: str = "3211_*"
    #: The time-domain part's estimator (:data:`TIME_DOMAIN_METHODS`): ``"filter_error"``
    #: (process noise for turbulence under feedback, diagonal ``Q``; its bounds are the
    #: calibrated ones; docs/methods.md, "Filter error (process noise)"), ``"output_error"``
    #: (the paper's, about three times faster, its bounds too small under turbulence), or
    #: ``"auto"``: filter error, output error for a ``quick`` study (fast checks over many
    #: conditions). Either model is stored as ``/models/time_domain`` (its ``method``
    #: attribute says which).
    time_domain_method: str = TIME_DOMAIN_AUTO
    verification_maneuvers: str = "2311_*"
    sweep_maneuvers: str = "sweep_*"
    campaign_file: str | None = None  #: a campaign TOML instead of the built-in one
    #: Fly the campaign's sweeps in calm air (:func:`sysid.flight_test.campaign.with_calm_sweeps`;
    #: a hybrid structure's frequency-domain fit needs it, docs/methods.md, "Hybrid structures").
    calm_sweeps: bool = False
    #: Leakage-free conditioning of the frequency responses
    #: (:func:`sysid.spectral.response.frequency_response`): ``"auto"`` conditions out the
    #: segment start/end transients of the measured states among u,v,w,p,q,r,phi,theta;
    #: ``""`` turns it off (the paper's method); or comma-separated states. With it on, the
    #: plain estimate is kept as ``/frequency_response_no_transient`` for the report.
    transient_states: str = "auto"
    #: A reduced study for batches of many conditions: leaves out :data:`QUICK_OMITS`.
    quick: bool = False

    @property
    def time_domain_estimator(self) -> str:
        """The time-domain part's estimator (resolves ``"auto"``); raises
        :class:`SysidError` naming the accepted values for anything else."""
        method = self.time_domain_method
        if method == TIME_DOMAIN_AUTO:
            return "output_error" if self.quick else "filter_error"
        if method not in TIME_DOMAIN_METHODS:
            raise SysidError(f"time_domain_method {method!r}: expected one of "
                             f"{TIME_DOMAIN_METHODS} or {TIME_DOMAIN_AUTO!r}")
        return method

    @property
    def fd_coherence(self) -> float:
        """The coherence admission the frequency-domain fit uses (resolves None)."""
        if self.fd_coherence_min is not None:
            return float(self.fd_coherence_min)
        declared = declared_coherence_min(self.structure)
        if declared is not None:
            return declared
        if self.airspeed_kt < FORWARD_FLIGHT_KT:
            return FD_COHERENCE_MIN_HOVER
        return FD_COHERENCE_MIN_FORWARD


#: Version of what the stages store; bump it when a stored layout changes so that caches
#: written by an older layout are recomputed (2: /linearization_full carries C and D; 3: the
#: manoeuvres carry input_hold and the responses have the hold divided out).
DATA_FORMAT = 3


def _key(*parts) -> str:
    text = json.dumps((DATA_FORMAT, *parts), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _group_key(path: Path, group: str) -> str | None:
    """The cache key stamped on ``group``; None when the file or the group is missing or the
    file is unreadable (the stage then runs and rewrites it)."""
    attrs = group_attrs(path, group)
    return None if attrs is None else attrs.get("workflow_key")


def _stamp(key: str, elapsed_s: float) -> dict:
    """The cache stamp a stage puts in its group's attributes."""
    return {"workflow_key": key, "workflow_elapsed_s": round(float(elapsed_s), 2)}


#: The study's parts, in the order :func:`run_study` runs them. ``data`` is the campaign and
#: its frequency responses; the two identifications need only ``data`` and not each other
#: (the paper compares independent fits), so they may run at the same time, e.g. as separate
#: Dask tasks (:mod:`sysid.pipeline.batch`); ``results`` is verification, comparison, export and
#: validation, and the report.
PARTS = ("data", "frequency_domain", "time_domain", "results")


def run_study(out_dir: str | Path, settings: StudySettings | None = None, *,
              quiet: bool = False, parts: tuple[str, ...] | list[str] = PARTS,
              log: TextIO | None = None) -> Path | None:
    """Run the study at one flight condition; return the report path.

    ``parts`` (a subset of :data:`PARTS`) runs only those parts, each reusing what the parts
    before it stored (a part whose inputs are not stored yet computes them first). Returns
    ``None`` when ``results`` is not among them or the study is quick (no report). The
    stages' tables (identification, verification, comparison, validation) go to ``log`` when
    given, else to standard output unless ``quiet``; progress lines go to ``log`` or standard
    error unless ``quiet``.

    Examples
    --------
    >>> from sysid.pipeline.study import StudySettings, run_study
    >>> run_study("reports/hover_seed1", StudySettings(seed=1))   # doctest: +SKIP
    """
    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise SysidError(f"run_study: unknown part(s) {unknown}; expected some of {PARTS}")
    with numeric_settings():
        study = _Study(out_dir, settings or StudySettings(), quiet=quiet, log=log)
        report = None
        for part in PARTS:
            if part in parts:
                report = getattr(study, part)()
        return report


class _Study:
    """The stages of :func:`run_study`. Every stage's cache key hashes its settings and the
    keys of the stages it reads, so each key is known without running anything."""

    #: The responses' outputs, the frequency-domain fit's pairs (None: the paper's) and the
    #: time-domain fit's start (:data:`sysid.identify.stages.TIME_DOMAIN_STARTS`); flight
    #: data without a truth model set others (:mod:`sysid.pipeline.flight_data`).
    outputs: tuple[str, ...] = STATES_6DOF
    fd_pairs: tuple[tuple[str, str], ...] | None = None
    td_start: str = "linearization"
    #: Whether the exported models are run beside the truth FMU (not for flight data).
    with_truth: bool = True

    def __init__(self, out_dir: str | Path, settings: StudySettings, *, quiet: bool,
                 log: TextIO | None = None):
        self.open(out_dir, settings, quiet=quiet, log=log)
        start_forkserver()  # its imports beside the campaign, for the fits' and figures' pools
        self.fmu_path = build_fmu()
        if settings.campaign_file:
            self.campaign = campaign_from_file(settings.campaign_file, settings)
        else:
            seed = {} if settings.seed is None else {"seed": settings.seed}
            self.campaign = default_campaign(settings.airspeed_kt, noise=settings.noise,
                                             **seed)
        if settings.calm_sweeps:
            self.campaign = with_calm_sweeps(self.campaign)
        # (quick enters only when set, so that full studies keep their cache keys)
        quick = ("quick",) if settings.quick else ()
        self.key_campaign = _key("campaign", self.campaign.to_toml(), self.fmu_path.name,
                                 sysid.__version__, *quick)
        self.key_fr = _key("fr", self.key_campaign, settings.sweep_maneuvers,
                           settings.transient_states, *quick)
        # The structure enters by its text, so that editing its file re-runs the fits.
        structure = (settings.structure, structure_path(settings.structure).read_text())
        self.key_fd = _key("fd", self.key_fr, structure, settings.fd_coherence)
        # The time-domain fit starts from the linearisation, not from the frequency-domain
        # result, so that the two identifications are independent.
        # (the estimator enters only when it is not output error, so that output-error
        # studies keep their cache keys)
        estimator = settings.time_domain_estimator
        method = () if estimator == "output_error" else (estimator,)
        self.key_td = _key("td", self.key_campaign, structure, settings.time_domain_maneuvers,
                           *method)
        self.key_models = _key(self.key_fd, self.key_td)
        self.fit_keys = {"frequency_domain": self.key_fd, "time_domain": self.key_td}

    # -- helpers
    def open(self, out_dir: str | Path, settings: StudySettings, *, quiet: bool,
             log: TextIO | None) -> None:
        """The output folder, the campaign file's path, progress and log streams."""
        self.settings = settings
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.path = self.out / "campaign.nc"
        self.quiet = quiet
        self.progress = Progress(quiet=quiet, stream=log if log is not None else sys.stderr)
        self.log = log if log is not None else (None if quiet else sys.stdout)
        self._campaign_data = None

    def print(self, text: str) -> None:
        """A stage's table to the study's log (nothing when quiet without a log)."""
        if self.log is not None:
            print(text, file=self.log, flush=True)

    @property
    def campaign_data(self) -> CampaignData:
        """The campaign as stored: read once, then kept in step with this study's writes."""
        if self._campaign_data is None:
            self._campaign_data = CampaignData(read_campaign(self.path), source=str(self.path))
        return self._campaign_data

    def write(self, groups: Mapping[str, xr.Dataset | xr.DataTree]) -> None:
        """Write ``groups`` to the campaign file at once and keep the copy in memory."""
        update_campaign_groups(self.path, groups)
        if self._campaign_data is not None:
            self._campaign_data = self._campaign_data.with_groups(groups)

    def fit_path(self, method: str) -> Path:
        return self.out / f"model_{method}.nc"

    def stage(self, name: str, path: Path, group: str, key: str,
              work: Callable[[], dict]) -> dict | None:
        """Run ``work`` unless ``group`` of ``path`` holds ``key``; return its groups
        (``{group path: Dataset or DataTree}``) with ``group`` stamped, or None if cached."""
        stored = _group_key(path, group)
        if stored == key:
            self.progress.message(f"[sysid] {name}: cached")
            return None
        if stored is not None:
            self.progress.message(f"[sysid] {name}: inputs changed, recomputing")
        start = time.perf_counter()
        with self.progress.stage(name):
            groups = dict(work())
        stamp = _stamp(key, time.perf_counter() - start)
        if group in groups:
            groups[group] = groups[group].copy()
            groups[group].attrs.update(stamp)
        else:  # the whole tree ("/"): stamp its node ``group``
            groups["/"][group].attrs.update(stamp)
        return groups

    def fitted(self, method: str) -> bool:
        """Whether the campaign or the fit's own file holds the model of the current key."""
        key = self.fit_keys[method]
        return (_group_key(self.path, f"models/{method}") == key
                or _group_key(self.fit_path(method), f"models/{method}") == key)

    # 1-2. Campaign (trim and linearisation included) on the truth FMU; conditioned
    #      composite responses, and the unconditioned ones for comparison.
    def data(self) -> None:
        summaries = [] if self.settings.quick else [campaign_summary]
        self.campaign_stage("campaign", lambda: run_campaign(
            self.campaign, quiet=self.quiet, fmu=self.fmu_path, summaries=summaries))
        self.responses()

    def campaign_stage(self, name: str, make: Callable[[], xr.DataTree]) -> None:
        """The campaign tree (``make()``) unless the file holds the current one."""
        made = self.stage(name, self.path, "maneuvers", self.key_campaign,
                          lambda: {"/": make()})
        if made is not None:
            # A new campaign replaces the file and everything derived from the old one.
            write_campaign(made["/"], self.path)
            self._campaign_data = CampaignData(made["/"], source=str(self.path))

    def responses(self) -> None:
        """Conditioned composite responses of the sweeps, and the unconditioned ones."""
        settings = self.settings

        def responses() -> dict:
            records = self.campaign_data.maneuvers(settings.sweep_maneuvers)
            self.progress.message(f"[sysid] frequency response from {len(records)} "
                                  f"record(s): {', '.join(records)}")
            composite = frequency_response(records, CONTROLS, self.outputs,
                                           progress=self.progress,
                                           transient_states=settings.transient_states)
            states = list(composite.attrs["transient_states"])
            self.print("leakage conditioning: " + (", ".join(states) if states else "off"))
            self.print(format_coherent_ranges(composite))
            if settings.quick:  # the report's comparisons only (QUICK_OMITS)
                return {"frequency_response": composite}
            siso = siso_frequency_response(list(records.values()), CONTROLS, self.outputs)
            groups = {"frequency_response": composite, "frequency_response_siso": siso}
            # The paper's plain conditioned estimate, for the report's comparison; when the
            # default is already plain, an empty group that says so (no stale copy is left).
            groups[NO_TRANSIENT_GROUP] = (
                frequency_response(records, CONTROLS, self.outputs, transient_states=())
                if states else xr.Dataset(attrs={
                    "note": "leakage conditioning off: /frequency_response is this estimate"}))
            return groups

        groups = self.stage("frequency responses", self.path, "frequency_response",
                            self.key_fr, responses)
        if groups is not None:
            self.write(groups)

    def needs_data(self, group: str, key: str) -> None:
        """Run the data part first unless ``group`` already holds the result of ``key``."""
        if _group_key(self.path, group) != key:
            self.data()

    # 3-4. The two identifications, each into its own file (see the module docstring).
    def fit(self, method: str, name: str, work: Callable[[], object]) -> None:
        if self.fitted(method):
            self.progress.message(f"[sysid] {name}: cached")
            return

        def run() -> dict:
            result = work()
            self.print(result.table())
            return {f"models/{method}": result.model}

        groups = self.stage(name, self.fit_path(method), f"models/{method}",
                            self.fit_keys[method], run)
        if groups is not None:
            write_campaign(xr.DataTree.from_dict(groups), self.fit_path(method))

    # 3. Frequency-domain identification with model reduction.
    def frequency_domain(self) -> None:
        settings = self.settings
        self.needs_data("frequency_response", self.key_fr)
        self.fit("frequency_domain", "frequency-domain identification",
                 lambda: fit_frequency_domain(self.campaign_data, structure=settings.structure,
                                              coherence_min=settings.fd_coherence,
                                              pairs=self.fd_pairs,
                                              progress=self.progress))

    # 4. Time-domain identification on the multisteps, started from the linearisation.
    def time_domain(self) -> None:
        settings = self.settings
        self.needs_data("maneuvers", self.key_campaign)
        fit = (fit_filter_error if settings.time_domain_estimator == "filter_error"
               else fit_time_domain)
        self.fit("time_domain", "time-domain identification",
                 lambda: fit(self.campaign_data, maneuvers=settings.time_domain_maneuvers,
                             structure=settings.structure, start=self.td_start,
                             progress=self.progress))

    def merge_models(self) -> None:
        """Both fits' models into the campaign file, in one write (only what changed)."""
        for method in METHODS:  # the parts are named after the methods
            if not self.fitted(method):
                getattr(self, method)()
        stale = {}
        for method in METHODS:
            if _group_key(self.path, f"models/{method}") != self.fit_keys[method]:
                stored = read_campaign(self.fit_path(method))
                stale[f"models/{method}"] = stored[f"models/{method}"].to_dataset()
        if stale:
            self.write(stale)

    # 5-8. Verification, comparison, export and validation, report.
    def results(self) -> Path | None:
        settings, out = self.settings, self.out
        self.merge_models()

        # 5. Verification of both models on manoeuvres neither was fitted to.
        def verification() -> dict:
            checked = verify_models(self.campaign_data, models=METHODS,
                                    maneuvers=settings.verification_maneuvers,
                                    progress=self.progress)
            for ds in checked.values():
                self.print(verification_table(ds))
            return {"verification": xr.Dataset(),
                    **{f"verification/{name}": ds for name, ds in checked.items()}}

        self.save(self.stage("verification", self.path, "verification",
                             _key("verify", self.key_models, settings.verification_maneuvers),
                             verification))

        # 6. Derivative comparison (Tables 2-3).
        def comparison() -> dict:
            table = compare_models(self.campaign_data)
            self.print(format_table(table))
            self.print(format_sign_agreement(table))
            self.print(format_scoreboard(table))
            write_table_csv(table, out / "comparison.csv")
            return {"comparison": table}

        self.save(self.stage("domain comparison", self.path, "comparison",
                             _key("compare", self.key_models), comparison))
        if settings.quick:  # no export, validation or report (QUICK_OMITS)
            return None

        # 7. Export both models as FMUs and validate them against the truth FMU and the data.
        def validation() -> dict:
            truth, trim = (truth_reference(self.campaign_data) if self.with_truth
                           else (None, "none for flight data"))
            if truth is None:
                self.print(f"time-domain comparison with the truth FMU: {trim}")
                trim = None
            checked = validate_models(self.campaign_data, fmu_dir=out, truth=truth, trim=trim,
                                      quiet=self.quiet)
            self.print(format_validation(checked))
            groups = {f"validation/{name}": ds for name, ds in checked.items()}
            if all("error" in ds.attrs for ds in checked.values()):
                self.write(groups)  # stored for the report, but not stamped: re-run next time
                raise SysidError("no model could be validated: " + "; ".join(
                    f"{name}: {ds.attrs['error']}" for name, ds in checked.items()))
            return {"validation": xr.Dataset(), **groups}

        self.save(self.stage("FMU export and validation", self.path, "validation",
                             _key("validate", self.key_models), validation))
        # 8. Report (always rewritten: cheap); it lists each stage's stamped time.
        with self.progress.stage("report"):
            return write_report(self.campaign_data.tree, out, quiet=self.quiet)

    def save(self, groups: dict | None) -> None:
        if groups is not None:
            self.write(groups)


def study_tree(out_dir: str | Path) -> xr.DataTree:
    """The campaign DataTree a study wrote (for scripts and tests)."""
    return read_campaign(Path(out_dir) / "campaign.nc")
