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
campaign.
"""

from __future__ import annotations

import hashlib
import json
import time
from dataclasses import dataclass
from pathlib import Path

import xarray as xr

import sysid
from sysid.errors import SysidError
from sysid.util import Progress

STAGES = ("campaign", "frequency_response", "identify", "identify_time", "verify",
          "compare", "validate", "report")


@dataclass
class StudySettings:
    """What to run; every field enters the cache keys of the stages that use it."""

    airspeed_kt: float = 0.0
    seed: int = 20261121
    noise: bool = True
    structure: str = "hover_6dof"
    #: Coherence admitting frequency points to the frequency-domain fit of the study, below
    #: the 0.6 guideline (the library default) on purpose, with W_gamma weighting the weak
    #: points down. Decided by time-domain verification on unseen 2311 data (the paper's
    #: conclusion 4), measured on the default hover campaign: at 0.6 the weak collective ->
    #: roll/pitch pairs drop out and L_col absorbs the yaw-response phase (-11 vs truth +0.8),
    #: J_rms 2.9 on 2311_col; admitting only those pairs at 0.4 gives 3.4; admitting every pair
    #: at 0.4 gives J_rms <= 1.7 on all four 2311 manoeuvres.
    fd_coherence_min: float = 0.4
    time_domain_maneuvers: str = "3211_*"
    verification_maneuvers: str = "2311_*"
    sweep_maneuvers: str = "sweep_*"
    campaign_file: str | None = None  #: a campaign TOML instead of the built-in one


#: Version of what the stages store; bump it when a stored layout changes so that caches
#: written by an older layout are recomputed (2: /linearization_full carries C and D).
DATA_FORMAT = 2


def _key(*parts) -> str:
    text = json.dumps((DATA_FORMAT, *parts), sort_keys=True, default=str)
    return hashlib.sha256(text.encode()).hexdigest()[:16]


def _group_key(path: Path, group: str) -> str | None:
    from sysid.io import read_campaign

    if not path.exists():
        return None
    try:
        tree = read_campaign(path)
    except SysidError:
        return None
    try:  # ``in`` only sees direct children; nested paths need a lookup
        node = tree[group]
    except KeyError:
        return None
    return node.attrs.get("workflow_key")


def _stamp(path: Path, group: str, key: str) -> None:
    from sysid.io import read_campaign, update_campaign

    tree = read_campaign(path)
    node = tree[group]
    ds = node.to_dataset(inherit=False)
    ds.attrs["workflow_key"] = key
    update_campaign(path, group, ds)


def _cli(*args: str) -> None:
    from sysid.cli import main

    status = main([str(a) for a in args])
    if status != 0:
        raise SysidError(f"stage 'sysid {args[0]}' failed (exit status {status})")


def run_study(out_dir: str | Path, settings: StudySettings | None = None, *,
              quiet: bool = False) -> Path:
    """Run every stage at one flight condition; return the report path."""
    from sysid.util import blas_threads

    with blas_threads():
        return _run_study(out_dir, settings, quiet=quiet)


def _run_study(out_dir: str | Path, settings: StudySettings | None, *, quiet: bool) -> Path:
    from sysid import fmu
    from sysid.frequency_response import siso_frequency_response
    from sysid.io import maneuvers, read_campaign, update_campaign
    from sysid.maneuvers import Campaign, default_campaign, run_campaign
    from sysid.report import write_report
    from sysid.units import CONTROLS, STATES_6DOF

    settings = settings or StudySettings()
    out = Path(out_dir)
    out.mkdir(parents=True, exist_ok=True)
    path = out / "campaign.nc"
    progress = Progress(quiet=quiet)
    quiet_flag = ["--quiet"] if quiet else []
    timings: dict[str, float] = {}

    def stage(name: str, group: str, key: str, work) -> str:
        start = time.perf_counter()
        stored = _group_key(path, group)
        if stored == key:
            progress.message(f"[sysid] {name}: cached")
        else:
            if stored is not None:
                progress.message(f"[sysid] {name}: inputs changed, recomputing")
            with progress.stage(name):
                work()
            _stamp(path, group, key)
        timings[name] = time.perf_counter() - start
        return key

    # 1. Campaign (trim and linearisation included) on the truth FMU.
    fmu_path = fmu.build_fmu()
    if settings.campaign_file:
        campaign = Campaign.from_toml(settings.campaign_file)
    else:
        campaign = default_campaign(settings.airspeed_kt, noise=settings.noise,
                                    seed=settings.seed)
    key = _key("campaign", campaign.to_toml(), fmu_path.name, sysid.__version__)
    key = stage("campaign", "maneuvers", key,
                lambda: run_campaign(campaign, path, quiet=quiet, fmu=fmu_path))

    # 2. Conditioned composite responses, and the unconditioned ones for comparison.
    def responses():
        _cli("frequency-response", path, "--inputs", ",".join(CONTROLS),
             "--outputs", ",".join(STATES_6DOF), "--maneuvers", settings.sweep_maneuvers,
             *quiet_flag)
        records = maneuvers(read_campaign(path), settings.sweep_maneuvers)
        siso = siso_frequency_response(records, CONTROLS, STATES_6DOF)
        update_campaign(path, "frequency_response_siso", siso)

    key = stage("frequency responses", "frequency_response",
                _key("fr", key, settings.sweep_maneuvers), responses)

    # 3. Frequency-domain identification with model reduction.
    key_fd = stage("frequency-domain identification", "models/frequency_domain",
                   _key("fd", key, settings.structure, settings.fd_coherence_min),
                   lambda: _cli("identify", path, "--structure", settings.structure,
                                "--coherence-min", settings.fd_coherence_min, *quiet_flag))

    # 4. Time-domain identification on the multisteps, started from the linearisation so
    #    that it is independent of the frequency-domain result (the paper compares two
    #    independent identifications).
    key_td = stage("time-domain identification", "models/time_domain",
                   _key("td", key, settings.structure, settings.time_domain_maneuvers),
                   lambda: _cli("identify-time", path, "--maneuvers",
                                settings.time_domain_maneuvers, "--structure",
                                settings.structure, "--start", "linearization", *quiet_flag))

    # 5. Verification of both models on manoeuvres neither was fitted to.
    key_models = _key(key_fd, key_td)
    verify_key = _key("verify", key_models, settings.verification_maneuvers)
    first_verified = f"verification/{_first(path, settings.verification_maneuvers)}"
    stage("verification", first_verified, verify_key,
          lambda: _cli("verify", path, "--model", "frequency_domain,time_domain",
                       "--maneuvers", settings.verification_maneuvers, *quiet_flag))

    # 6. Derivative comparison (Tables 2-3).
    stage("domain comparison", "comparison", _key("compare", key_models),
          lambda: _cli("compare", path, "--csv", out / "comparison.csv"))

    # 7. Export both models as FMUs and validate them against the truth FMU and the data.
    stage("FMU export and validation", "validation", _key("validate", key_models),
          lambda: _cli("validate", path, "--fmu-dir", out, *quiet_flag))

    # 8. Report (always rewritten: cheap, and it records this run's timings).
    with progress.stage("report"):
        tree = read_campaign(path)
        tree.attrs["stage_timings_s"] = json.dumps({k: round(v, 2) for k, v in timings.items()})
        report = write_report(tree, out, quiet=quiet)
    return report


def _first(path: Path, pattern: str) -> str:
    from sysid.io import list_maneuvers, read_campaign

    names = list_maneuvers(read_campaign(path), pattern)
    if not names:
        raise SysidError(f"no manoeuvre in {path} matches {pattern!r} for verification")
    return names[0]


def study_tree(out_dir: str | Path) -> xr.DataTree:
    """The campaign DataTree a study wrote (for scripts and tests)."""
    from sysid.io import read_campaign

    return read_campaign(Path(out_dir) / "campaign.nc")
