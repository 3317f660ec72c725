"""``sysid fit-tf``: transfer-function fit of one pair with an equivalent delay (NAVFIT, LOES).

::

    sysid fit-tf campaign.nc --pair theta/lon --order N/D [--delay]
                 [--source data,linearization_full,frequency_domain] [--fix a0=0] [--store]

Runs :func:`sysid.identify.transfer_function.fit_campaign` and prints, per source, the
transfer function, its coefficients with Cramer-Rao bounds and insensitivities, the equivalent
delay, the poles and zeros as frequency/damping/time constant, and the CIFER cost over the
data's coherent band. ``--store`` writes each fit to ``/transfer_functions/<out>_<in>/<source>``.
"""

from __future__ import annotations

import argparse

from sysid.cli.identify import _band
from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign_groups
from sysid.identify.frequency_domain import N_POINTS
from sysid.identify.transfer_function import fit_campaign


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "fit-tf", help="transfer-function fit of one pair with an equivalent delay",
        description="Fit N(s)/D(s) e^(-tau s) to one input/output pair of the composite "
                    "frequency response (or, as a low-order equivalent system, to a model's "
                    "or the truth linearisation's response on the same band) with the CIFER "
                    "cost of the state-space fit; print coefficients with Cramer-Rao bounds, "
                    "the equivalent delay and the modal parameters.")
    p.add_argument("campaign", help="campaign netCDF file with a /frequency_response group")
    p.add_argument("--pair", required=True, help="output/input, e.g. theta/lon or q/lon")
    p.add_argument("--order", default="1/2",
                   help="numerator/denominator degree N/D (default 1/2; the denominator is "
                        "monic)")
    p.add_argument("--delay", action="store_true", help="fit an equivalent delay (0-0.3 s)")
    p.add_argument("--source", default="data",
                   help="comma-separated: data, linearization_full, linearization or a "
                        "/models method (default data)")
    p.add_argument("--fix", default="", metavar="NAME=VALUE,...",
                   help="hold coefficients, e.g. a0=0 for a free integrator (b_k multiplies "
                        "s^k in the numerator, a_k in the denominator)")
    p.add_argument("--coherence-min", type=float, default=COHERENCE_MIN,
                   help=f"coherence defining the fitted band (default {COHERENCE_MIN})")
    p.add_argument("--points", type=int, default=N_POINTS,
                   help=f"log-spaced frequency points (default {N_POINTS})")
    p.add_argument("--frequency-range", default=None, metavar="MIN,MAX",
                   help="limit the band (rad/s)")
    p.add_argument("--store", action="store_true",
                   help="write each fit to /transfer_functions/<out>_<in>/<source>")
    p.set_defaults(func=run)


def _fixed(text: str) -> dict[str, float]:
    out = {}
    for item in (t.strip() for t in text.split(",") if t.strip()):
        name, _, value = item.partition("=")
        try:
            out[name.strip()] = float(value)
        except ValueError:
            raise InputDataError(f"--fix {item!r}: expected NAME=VALUE, e.g. a0=0") from None
    return out


def run(args: argparse.Namespace) -> int:
    sources = [s.strip() for s in args.source.split(",") if s.strip()]
    fits = fit_campaign(CampaignData.read(args.campaign), args.pair, sources=sources,
                        order=args.order, delay=args.delay, fixed=_fixed(args.fix),
                        coherence_min=args.coherence_min, n_points=args.points,
                        frequency_range=_band(args.frequency_range))
    for fit in fits.values():
        print(fit.table())
        print()
    if len(fits) > 1 and args.delay:
        print("equivalent delays: " + ", ".join(f"{s} {1000 * f.delay:.1f} ms"
                                                 for s, f in fits.items()))
    if args.store:
        o, i = args.pair.split("/")
        update_campaign_groups(args.campaign, {f"transfer_functions/{o}_{i}/{s}": f.to_dataset()
                                               for s, f in fits.items()})
        print(f"stored under /transfer_functions/{o}_{i}")
    return 0
