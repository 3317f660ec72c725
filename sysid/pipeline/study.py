"""The paper's whole study in one call: campaign -> responses -> two models -> checks -> report.

:func:`run_study` chains the stages at one flight condition, writing everything under one
output folder::

    <out>/campaign.nc          the campaign DataTree (time histories and every result)
    <out>/frequency_domain.fmu, <out>/time_domain.fmu   the identified models as FMUs
    <out>/comparison.csv       derivative table (paper Tables 2-3)
    <out>/report.html, <out>/figures/   the report

Each stage is the same code as its ``sysid`` sub-command (the workflow drives them through
:func:`sysid.cli.main`), so the command line and the workflow cannot drift apart.

Caching: every stage stamps its result group with a key hashing its settings and the key of
the stage before it. A re-run skips a stage whose group carries the key it would write, so
changing e.g. the structure re-runs identification and everything after it, but not the
campaign. Each stamp also records how long the stage took (``workflow_elapsed_s``), and the
report lists those times.

Parts: ``run_study(..., parts=...)`` runs a subset of :data:`PARTS` (data, the two fits,
results). The fits do not read each other, so two processes may run them at once on the
same folder (:func:`sysid.data.netcdf.update_campaign` serialises their writes); :mod:`sysid.pipeline.batch`
does so to keep its workers busy.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import xarray as xr

import sysid
from sysid.core.errors import SysidError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.core.util import Progress

STAGES = ("campaign", "frequency_response", "identify", "identify_time", "verify",
          "compare", "validate", "report")

#: The study's coherence admission in hover: the paper's 0.6 guideline (the library default),
#: checked by 2311 verification (docs/notes/2026-11-24-study-coherence-admission.md).
FD_COHERENCE_MIN_HOVER = COHERENCE_MIN
#: In forward flight (`forward_6dof`, 80 kt) points down to coherence 0.4 are admitted, with
#: W_gamma weighting the weak ones down: at 0.6 the 80-kt fit ran away (same note).
FD_COHERENCE_MIN_FORWARD = 0.4


@dataclass
class StudySettings:
    """What to run; every field enters the cache keys of the stages that use it."""

    airspeed_kt: float = 0.0
    seed: int = 20261121
    noise: bool = True
    structure: str = "hover_6dof"
    #: Coherence admitting frequency points to the study's frequency-domain fit; None: by
    #: flight condition, :data:`FD_COHERENCE_MIN_HOVER` in hover and
    #: :data:`FD_COHERENCE_MIN_FORWARD` in forward flight (see there).
    fd_coherence_min: float | None = None
    time_domain_maneuvers: str = "3211_*"
    verification_maneuvers: str = "2311_*"
    sweep_maneuvers: str = "sweep_*"
    campaign_file: str | None = None  #: a campaign TOML instead of the built-in one

    @property
    def fd_coherence(self) -> float:
        """The coherence admission the frequency-domain fit uses (resolves None)."""
        from sysid.pipeline.batch import FORWARD_FLIGHT_KT  # where the structures change, too

        if self.fd_coherence_min is not None:
            return float(self.fd_coherence_min)
        if self.airspeed_kt < FORWARD_FLIGHT_KT:
            return FD_COHERENCE_MIN_HOVER
        return FD_COHERENCE_MIN_FORWARD


#: Version of what the stages store; bump it when a stored layout changes so that caches
#: written by an older layout are recomputed (2: /linearization_full carries C and D).
DATA_FORMAT = 2


def _key(*parts) -> str:
    text = json.dumps((DATA_FORMAT, *parts), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _group_key(path: Path, group: str) -> str | None:
    """The cache key stamped on ``group``; None when the file or the group is missing or the
    file is unreadable (the stage then runs and rewrites it)."""
    from sysid.data.netcdf import group_attrs

    attrs = group_attrs(path, group)
    return None if attrs is None else attrs.get("workflow_key")


def _stamp(path: Path, group: str, key: str, elapsed_s: float) -> None:
    from sysid.data.netcdf import set_group_attrs

    set_group_attrs(path, group, {"workflow_key": key,
                                  "workflow_elapsed_s": round(float(elapsed_s), 2)})


def _cli(*args: str) -> None:
    from sysid.cli import main

    status = main([str(a) for a in args])
    if status != 0:
        raise SysidError(f"stage 'sysid {args[0]}' failed (exit status {status})")


#: The study's parts, in the order :func:`run_study` runs them. ``data`` is the campaign and
#: its frequency responses; the two identifications need only ``data`` and not each other
#: (the paper compares independent fits), so they may run at the same time, e.g. as separate
#: Dask tasks (:mod:`sysid.pipeline.batch`); ``results`` is verification, comparison, export and
#: validation, and the report.
PARTS = ("data", "frequency_domain", "time_domain", "results")


def run_study(out_dir: str | Path, settings: StudySettings | None = None, *,
              quiet: bool = False, parts: tuple[str, ...] | list[str] = PARTS) -> Path | None:
    """Run the study at one flight condition; return the report path.

    ``parts`` (a subset of :data:`PARTS`) runs only those parts, each reusing what the parts
    before it stored (a part whose inputs are not stored yet computes them first). Returns
    ``None`` when ``results`` is not among them.

    Examples
    --------
    >>> from sysid.pipeline.study import StudySettings, run_study
    >>> run_study("reports/hover_seed1", StudySettings(seed=1))   # the report's path
    """
    from sysid.core.util import blas_threads

    unknown = [p for p in parts if p not in PARTS]
    if unknown:
        raise SysidError(f"run_study: unknown part(s) {unknown}; expected some of {PARTS}")
    with blas_threads():
        study = _Study(out_dir, settings or StudySettings(), quiet=quiet)
        report = None
        for part in PARTS:
            if part in parts:
                report = getattr(study, part)()
        return report


class _Study:
    """The stages of :func:`run_study`. Every stage's cache key hashes its settings and the
    keys of the stages it reads, so each key is known without running anything."""

    def __init__(self, out_dir: str | Path, settings: StudySettings, *, quiet: bool):
        from sysid import truth as fmu
        from sysid.flight_test.campaign import Campaign, default_campaign
        from sysid.models import structure_path

        self.settings = settings
        self.out = Path(out_dir)
        self.out.mkdir(parents=True, exist_ok=True)
        self.path = self.out / "campaign.nc"
        self.quiet = quiet
        self.quiet_flag = ["--quiet"] if quiet else []
        self.progress = Progress(quiet=quiet)
        self.fmu_path = fmu.build_fmu()
        if settings.campaign_file:
            self.campaign = Campaign.from_toml(settings.campaign_file)
        else:
            self.campaign = default_campaign(settings.airspeed_kt, noise=settings.noise,
                                             seed=settings.seed)
        self.key_campaign = _key("campaign", self.campaign.to_toml(), self.fmu_path.name,
                                 sysid.__version__)
        self.key_fr = _key("fr", self.key_campaign, settings.sweep_maneuvers)
        # The structure enters by its text, so that editing its file re-runs the fits.
        structure = (settings.structure, structure_path(settings.structure).read_text())
        self.key_fd = _key("fd", self.key_fr, structure, settings.fd_coherence)
        # The time-domain fit starts from the linearisation, not from the frequency-domain
        # result, so that the two identifications are independent.
        self.key_td = _key("td", self.key_campaign, structure, settings.time_domain_maneuvers)
        self.key_models = _key(self.key_fd, self.key_td)

    def stage(self, name: str, group: str, key: str, work) -> None:
        stored = _group_key(self.path, group)
        if stored == key:
            self.progress.message(f"[sysid] {name}: cached")
            return
        if stored is not None:
            self.progress.message(f"[sysid] {name}: inputs changed, recomputing")
        start = time.perf_counter()
        with self.progress.stage(name):
            work()
        _stamp(self.path, group, key, time.perf_counter() - start)

    def needs(self, group: str, key: str, part: str) -> None:
        """Run ``part`` first unless ``group`` already holds the result of key ``key``."""
        if _group_key(self.path, group) != key:
            getattr(self, part)()

    # 1-2. Campaign (trim and linearisation included) on the truth FMU; conditioned
    #      composite responses, and the unconditioned ones for comparison.
    def data(self) -> None:
        from sysid.spectral.response import siso_frequency_response
        from sysid.data.campaign import maneuvers
        from sysid.data.netcdf import read_campaign, update_campaign
        from sysid.flight_test.campaign import run_campaign
        from sysid.spectral.cross_control import campaign_summary
        from sysid.core.units import CONTROLS, STATES_6DOF

        self.stage("campaign", "maneuvers", self.key_campaign,
                   lambda: run_campaign(self.campaign, self.path, quiet=self.quiet,
                                        fmu=self.fmu_path, summaries=[campaign_summary]))

        def responses():
            _cli("frequency-response", self.path, "--inputs", ",".join(CONTROLS),
                 "--outputs", ",".join(STATES_6DOF), "--maneuvers",
                 self.settings.sweep_maneuvers, *self.quiet_flag)
            records = maneuvers(read_campaign(self.path), self.settings.sweep_maneuvers)
            siso = siso_frequency_response(records, CONTROLS, STATES_6DOF)
            update_campaign(self.path, "frequency_response_siso", siso)

        self.stage("frequency responses", "frequency_response", self.key_fr, responses)

    # 3. Frequency-domain identification with model reduction.
    def frequency_domain(self) -> None:
        settings = self.settings
        self.needs("frequency_response", self.key_fr, "data")
        self.stage("frequency-domain identification", "models/frequency_domain", self.key_fd,
                   lambda: _cli("identify", self.path, "--structure", settings.structure,
                                "--coherence-min", settings.fd_coherence,
                                *self.quiet_flag))

    # 4. Time-domain identification on the multisteps, started from the linearisation.
    def time_domain(self) -> None:
        settings = self.settings
        self.needs("maneuvers", self.key_campaign, "data")
        self.stage("time-domain identification", "models/time_domain", self.key_td,
                   lambda: _cli("identify-time", self.path, "--maneuvers",
                                settings.time_domain_maneuvers, "--structure",
                                settings.structure, "--start", "linearization",
                                *self.quiet_flag))

    # 5-8. Verification, comparison, export and validation, report.
    def results(self) -> Path:
        from sysid.data.netcdf import read_campaign
        from sysid.report.html import write_report

        settings, path, out = self.settings, self.path, self.out
        self.needs("models/frequency_domain", self.key_fd, "frequency_domain")
        self.needs("models/time_domain", self.key_td, "time_domain")
        # 5. Verification of both models on manoeuvres neither was fitted to.
        verify_key = _key("verify", self.key_models, settings.verification_maneuvers)
        first_verified = f"verification/{_first(path, settings.verification_maneuvers)}"
        self.stage("verification", first_verified, verify_key,
                   lambda: _cli("verify", path, "--model", "frequency_domain,time_domain",
                                "--maneuvers", settings.verification_maneuvers,
                                *self.quiet_flag))
        # 6. Derivative comparison (Tables 2-3).
        self.stage("domain comparison", "comparison", _key("compare", self.key_models),
                   lambda: _cli("compare", path, "--csv", out / "comparison.csv"))
        # 7. Export both models as FMUs and validate them against the truth FMU and the data.
        self.stage("FMU export and validation", "validation",
                   _key("validate", self.key_models),
                   lambda: _cli("validate", path, "--fmu-dir", out, *self.quiet_flag))
        # 8. Report (always rewritten: cheap); it lists each stage's stamped time.
        with self.progress.stage("report"):
            return write_report(read_campaign(path), out, quiet=self.quiet)


def _first(path: Path, pattern: str) -> str:
    from sysid.data.campaign import list_maneuvers
    from sysid.data.netcdf import read_campaign

    names = list_maneuvers(read_campaign(path), pattern)
    if not names:
        raise SysidError(f"no manoeuvre in {path} matches {pattern!r} for verification")
    return names[0]


def study_tree(out_dir: str | Path) -> xr.DataTree:
    """The campaign DataTree a study wrote (for scripts and tests)."""
    from sysid.data.netcdf import read_campaign

    return read_campaign(Path(out_dir) / "campaign.nc")
