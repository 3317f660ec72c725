"""``sysid identify``: frequency-domain identification of a campaign's composite responses.

::

    sysid identify campaign.nc [--structure STRUCTURE.toml] [--pairs q/lon,p/lat,...]
                               [--no-reduction] [--quiet]

Reads ``/frequency_response`` of the campaign, takes the trim from the attributes
(``trim_<channel>`` of the frequency-response group, the root or the first manoeuvre) and start
values from ``/linearization`` (the truth model's quasi-steady linearisation) when present,
identifies the structure (default: the built-in ``hover_6dof``), stores the model in
``/models/frequency_domain`` and prints the derivative table with Cramer-Rao bounds and
insensitivities (paper Tables 2-3), the delays, the cost per pair and J_ave.
"""

from __future__ import annotations

import argparse

from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify",
        help="identify a state-space model with delays from composite frequency responses",
        description="Frequency-domain output-error identification (CIFER-style cost, "
                    "Levenberg-Marquardt, Cramer-Rao bounds, stepwise model reduction).",
    )
    p.add_argument("campaign", help="campaign netCDF file with a /frequency_response group")
    p.add_argument("--structure", default="hover_6dof",
                   help="structure TOML file or built-in name (default: hover_6dof)")
    p.add_argument("--pairs", default=None,
                   help="comma-separated output/input pairs, e.g. q/lon,p/lat "
                        "(default: the paper's 13 pairs)")
    p.add_argument("--no-reduction", action="store_true", help="skip the model reduction")
    p.add_argument("--coherence-min", type=float, default=COHERENCE_MIN,
                   help=f"coherence defining each pair's fitted range (default {COHERENCE_MIN})")
    p.add_argument("--points", type=int, default=20,
                   help="log-spaced frequency points per pair (default 20)")
    p.add_argument("--start", choices=("auto", "linearization", "equation-error", "structure"),
                   default="auto",
                   help="start values: the campaign's /linearization when present (auto), or "
                        "the frequency-domain equation error, or the structure's values")
    p.add_argument("--fallback-coherence-min", type=float, default=None,
                   help="admit a pair with no range at --coherence-min at this lower "
                        "coherence instead of skipping it (weak off-axis responses)")
    p.add_argument("--frequency-range", default=None, metavar="MIN,MAX",
                   help="fit band in rad/s for every pair (default: the structure's own "
                        "validity band, e.g. 0.1,8 for hover_6dof)")
    p.add_argument("--seed", type=int, default=0, help="seed of the restart perturbation")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _trim(tree) -> dict[str, float]:
    """``channel -> trim`` from the frequency-response group, the root or a manoeuvre."""
    from sysid.data.campaign import trim_from_attrs

    sources = [tree[g].attrs for g in ("frequency_response",) if g in tree] + [tree.attrs]
    if "maneuvers" in tree and tree["maneuvers"].children:
        sources.append(next(iter(tree["maneuvers"].children.values())).attrs)
    return trim_from_attrs(sources)


def _linearization(tree, states):
    """The quasi-steady linearisation (a model Dataset over ``states``) or None."""
    if "linearization" not in tree:
        return None
    candidates = []
    for node in tree["linearization"].subtree:
        ds = node.to_dataset(inherit=False)
        if "A" not in ds or "B" not in ds or "state" not in ds["A"].dims:
            continue
        have = [str(s) for s in ds["A"].state.values]
        if not all(s in have for s in states):
            continue
        rank = (0 if "quasi" in node.path else 1, len(have) - len(states))
        candidates.append((rank, ds))
    if not candidates:
        return None
    candidates.sort(key=lambda c: c[0])
    return candidates[0][1]


def run(args: argparse.Namespace) -> int:
    # sysid.data.io is owned by another stage; imported lazily so the CLI loads without it.
    from sysid.identify.frequency_domain import identify_frequency_domain
    from sysid.data.netcdf import read_campaign, update_campaign
    from sysid.models import load_structure
    from sysid.core.util import Progress

    tree = read_campaign(args.campaign)
    if "frequency_response" not in tree:
        raise InputDataError(f"campaign {args.campaign} has no /frequency_response group; "
                             f"compute the composite frequency responses first")
    fr = tree["frequency_response"].to_dataset()
    trim = _trim(tree)
    structure = load_structure(args.structure, trim=trim)
    progress = Progress(quiet=args.quiet)
    start = None
    if args.start in ("auto", "linearization"):
        start = _linearization(tree, structure.states)
        if start is None and args.start == "linearization":
            raise InputDataError(f"campaign {args.campaign} has no /linearization model over "
                                 f"the states {list(structure.states)}")
        if start is not None:
            progress.message("[sysid] identify: start values from /linearization")
    elif args.start == "structure":
        start = structure.theta0
    result = identify_frequency_domain(fr, structure, pairs=args.pairs, start=start,
                                       frequency_range=_band(args.frequency_range),
                                       fallback_coherence_min=args.fallback_coherence_min,
                                       coherence_min=args.coherence_min, n_points=args.points,
                                       reduce=not args.no_reduction, seed=args.seed,
                                       progress=progress)
    model = result.model
    model.attrs["campaign_file"] = str(args.campaign)
    update_campaign(args.campaign, "models/frequency_domain", model)
    print(result.table())
    progress.message(f"[sysid] identify: model written to {args.campaign} "
                     f"(/models/frequency_domain)")
    return 0


def _band(text: str | None) -> tuple[float, float] | None:
    """``"0.1,8"`` -> ``(0.1, 8.0)`` rad/s."""
    if text is None:
        return None
    from sysid.core.errors import InputDataError

    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise InputDataError(f"--frequency-range must be MIN,MAX in rad/s, got {text!r}") from None
    if not 0 <= lo < hi:
        raise InputDataError(f"--frequency-range needs 0 <= MIN < MAX, got {text!r}")
    return lo, hi
