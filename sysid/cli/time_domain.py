"""``sysid identify-time`` and ``sysid verify``: time-domain output error and verification.

::

    sysid identify-time campaign.nc --maneuvers '3211_*' [--structure S.toml]
                        [--start auto|frequency_domain|linearization|structure]
                        [--outputs u,v,w,...] [--no-reduction] [--no-biases]
                        [--no-initial-state] [--quiet]

fits the structure (default: the built-in ``hover_6dof``) to the selected manoeuvres at once by
maximum-likelihood output error (:func:`sysid.identify.time_domain.identify_time_domain`),
stores the model in ``/models/time_domain`` and prints the derivative table with Cramer-Rao
bounds, the delays, the estimated noise and biases. Start values (``auto``): the
frequency-domain model when the campaign has one, else ``/linearization``, else the
structure's values.

::

    sysid verify campaign.nc --model frequency_domain[,time_domain] --maneuvers '2311_*'
                 [--estimate bias,reference_shift] [--quiet]

simulates each model with the recorded inputs of each selected manoeuvre, estimating only
output biases and input reference shifts (:func:`sysid.assess.verification.verify`), stores
``/verification/<maneuver>`` (merged with the sources already there) and prints J_rms and
TIC per output with PASS/FAIL against :data:`sysid.assess.metrics.J_RMS_GUIDELINE` and
:data:`sysid.assess.metrics.TIC_GUIDELINE`.
"""

from __future__ import annotations

import argparse

from sysid.core.errors import InputDataError


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify-time",
        help="identify a state-space model with delays from time histories (output error)",
        description="Maximum-likelihood output-error identification on one or more "
                    "manoeuvres (Levenberg-Marquardt, noise covariance re-estimation, "
                    "Cramer-Rao bounds, stepwise model reduction).",
    )
    p.add_argument("campaign", help="campaign netCDF file with /maneuvers/<name> groups")
    p.add_argument("--maneuvers", default="*",
                   help="glob selecting the fitted manoeuvres, e.g. '3211_*' (default: all)")
    p.add_argument("--structure", default="hover_6dof",
                   help="structure TOML file or built-in name (default: hover_6dof)")
    p.add_argument("--start", default="auto",
                   choices=("auto", "frequency_domain", "linearization", "structure"),
                   help="start values (default auto: /models/frequency_domain, else "
                        "/linearization, else the structure's values)")
    p.add_argument("--outputs", default=None,
                   help="comma-separated fitted outputs (default: all measured)")
    p.add_argument("--no-reduction", action="store_true", help="skip the model reduction")
    p.add_argument("--no-biases", action="store_true", help="do not estimate output biases")
    p.add_argument("--no-initial-state", action="store_true",
                   help="do not estimate initial states")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run_identify)

    v = subparsers.add_parser(
        "verify",
        help="verify identified models on manoeuvres not used to fit them",
        description="Time-domain verification (CIFER VERIFY): hold the model, estimate only "
                    "output biases and input reference shifts, report J_rms and TIC.",
    )
    v.add_argument("campaign", help="campaign netCDF file")
    v.add_argument("--model", default=None,
                   help="comma-separated model methods under /models (default: all)")
    v.add_argument("--maneuvers", default="*",
                   help="glob selecting the verification manoeuvres, e.g. '2311_*'")
    v.add_argument("--estimate", default="bias,reference_shift",
                   help="constants estimated: 'bias', 'reference_shift', both (default) or "
                        "'none'")
    v.add_argument("--quiet", action="store_true", help="no progress lines")
    v.set_defaults(func=run_verify)


def _trim(records) -> dict[str, float]:
    """``channel -> trim`` from the first record that has ``trim_<channel>``."""
    from sysid.data.campaign import trim_from_attrs

    return trim_from_attrs(records)


def _has(tree, path: str) -> bool:
    """Whether the campaign tree has the group ``path`` (e.g. ``"models/time_domain"``)."""
    node = tree
    for part in path.strip("/").split("/"):
        if part not in node.children:
            return False
        node = node.children[part]
    return True


def _selected(tree, pattern: str, path: str):
    from sysid.data.campaign import list_maneuvers, maneuvers

    names = list_maneuvers(tree, pattern)
    if not names:
        have = list_maneuvers(tree)
        raise InputDataError(f"campaign {path}: no manoeuvre matches {pattern!r} "
                             f"(manoeuvres: {have or 'none'})")
    return names, maneuvers(tree, pattern)


def _start(tree, structure, kind: str, path: str, progress):
    from sysid.cli.identify import _linearization

    if kind in ("auto", "frequency_domain") and _has(tree, "models/frequency_domain"):
        progress.message("[sysid] identify-time: start values from /models/frequency_domain")
        return tree["models/frequency_domain"].to_dataset()
    if kind == "frequency_domain":
        raise InputDataError(f"campaign {path} has no /models/frequency_domain; run "
                             f"'sysid identify' first or choose another --start")
    if kind in ("auto", "linearization"):
        lin = _linearization(tree, structure.states)
        if lin is not None:
            progress.message("[sysid] identify-time: start values from /linearization")
            return lin
        if kind == "linearization":
            raise InputDataError(f"campaign {path} has no /linearization model over the "
                                 f"states {list(structure.states)}")
    return None


def run_identify(args: argparse.Namespace) -> int:
    from sysid.identify.time_domain import identify_time_domain
    from sysid.data.netcdf import read_campaign, update_campaign
    from sysid.models import load_structure
    from sysid.core.util import Progress

    tree = read_campaign(args.campaign)
    names, records = _selected(tree, args.maneuvers, args.campaign)
    structure = load_structure(args.structure, trim=_trim(records))
    progress = Progress(quiet=args.quiet)
    start = _start(tree, structure, args.start, args.campaign, progress)
    outputs = [o.strip() for o in args.outputs.split(",") if o.strip()] if args.outputs else None
    result = identify_time_domain(records, structure, start=start, outputs=outputs,
                                  biases=not args.no_biases,
                                  initial_state=not args.no_initial_state,
                                  reduce=not args.no_reduction, progress=progress)
    model = result.model
    model.attrs["campaign_file"] = str(args.campaign)
    update_campaign(args.campaign, "models/time_domain", model)
    print(result.table())
    progress.message(f"[sysid] identify-time: model written to {args.campaign} "
                     f"(/models/time_domain), {len(names)} manoeuvre(s)")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    from sysid.data.netcdf import read_campaign, update_campaign
    from sysid.core.util import Progress
    from sysid.assess.verification import ESTIMATES, merge_verifications, verification_table, verify

    progress = Progress(quiet=args.quiet)
    tree = read_campaign(args.campaign)
    available = sorted(tree["models"].children) if "models" in tree else []
    wanted = ([m.strip() for m in args.model.split(",") if m.strip()] if args.model
              else available)
    missing = [m for m in wanted if m not in available]
    if missing or not wanted:
        raise InputDataError(f"campaign {args.campaign}: no model(s) {missing or wanted} under "
                             f"/models (available: {available or 'none'})")
    estimate = () if args.estimate.strip() == "none" else tuple(
        e.strip() for e in args.estimate.split(",") if e.strip())
    bad = set(estimate) - set(ESTIMATES)
    if bad:
        raise InputDataError(f"--estimate: unknown {sorted(bad)}; choose from {ESTIMATES} "
                             f"or 'none'")
    names, records = _selected(tree, args.maneuvers, args.campaign)
    models = {m: tree[f"models/{m}"].to_dataset() for m in wanted}
    for name, rec in zip(names, records):
        rec.attrs.setdefault("maneuver", name)
        parts = []
        group = f"verification/{name}"
        if _has(tree, group):
            parts.append(tree[group].to_dataset())
        for method, model in models.items():
            used = str(model.attrs.get("records", "")).split(",")
            if name in used:
                progress.message(f"[sysid] verify: note: {name} was used to fit {method}; "
                                 f"this is not an independent check")
            parts.append(verify(model, rec, estimate=estimate, source=method))
        merged = merge_verifications(parts)
        update_campaign(args.campaign, group, merged)
        print(verification_table(merged))
    progress.message(f"[sysid] verify: {len(names)} manoeuvre(s) written to {args.campaign} "
                     f"(/verification/<maneuver>)")
    return 0
