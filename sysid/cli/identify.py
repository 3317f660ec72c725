"""``sysid identify``: frequency-domain identification of a campaign's composite responses.

::

    sysid identify campaign.nc [--structure STRUCTURE.toml] [--pairs q/lon,p/lat,...]
                               [--no-reduction] [--quiet]

Runs :func:`sysid.identify.stages.fit_frequency_domain` on the campaign's
``/frequency_response`` (trim from the ``trim_<channel>`` attributes, start values from
``/linearization`` when present), stores the model in ``/models/frequency_domain`` and prints
the derivative table with Cramer-Rao bounds and insensitivities (paper Tables 2-3), the
delays, the cost per pair and J_ave.
"""

from __future__ import annotations

import argparse

from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign
from sysid.identify.stages import FREQUENCY_DOMAIN_STARTS, fit_frequency_domain


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
                        "(default: the structure's own, else the paper's 13 pairs)")
    p.add_argument("--no-reduction", action="store_true", help="skip the model reduction")
    p.add_argument("--coherence-min", type=float, default=None,
                   help="coherence defining each pair's fitted range (default: the "
                        f"structure's coherence_min, else {COHERENCE_MIN})")
    p.add_argument("--points", type=int, default=20,
                   help="log-spaced frequency points per pair (default 20)")
    p.add_argument("--start", choices=FREQUENCY_DOMAIN_STARTS,
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


def run(args: argparse.Namespace) -> int:
    progress = Progress(quiet=args.quiet)
    result = fit_frequency_domain(
        CampaignData.read(args.campaign), structure=args.structure, start=args.start,
        pairs=args.pairs, coherence_min=args.coherence_min, n_points=args.points,
        fallback_coherence_min=args.fallback_coherence_min,
        frequency_range=_band(args.frequency_range), reduce=not args.no_reduction,
        seed=args.seed, progress=progress)
    update_campaign(args.campaign, "models/frequency_domain", result.model)
    print(result.table())
    progress.message(f"[sysid] identify: model written to {args.campaign} "
                     f"(/models/frequency_domain)")
    return 0


def _band(text: str | None) -> tuple[float, float] | None:
    """``"0.1,8"`` -> ``(0.1, 8.0)`` rad/s."""
    if text is None:
        return None
    try:
        lo, hi = (float(v) for v in text.split(","))
    except ValueError:
        raise InputDataError(f"--frequency-range must be MIN,MAX in rad/s, got {text!r}") from None
    if not 0 <= lo < hi:
        raise InputDataError(f"--frequency-range needs 0 <= MIN < MAX, got {text!r}")
    return lo, hi
