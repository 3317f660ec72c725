"""``sysid simulate``: fly a flight-test campaign on the truth FMU."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from sysid.core.errors import InputDataError
from sysid.flight_test.campaign import (Campaign, default_campaign, linear_regime_campaign,
                                        run_campaign, with_calm_sweeps)
from sysid.spectral.cross_control import campaign_summary


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "simulate",
        help="fly a flight-test campaign (sweeps, 3211, 2311) on the truth FMU",
        description="Fly a campaign on the truth helicopter FMU with secondary-axis "
                    "stabilisation, sensor noise and turbulence; write one netCDF campaign file.",
    )
    p.add_argument("campaign", nargs="?", help="campaign TOML file (default: the built-in "
                                               "hover campaign of the paper)")
    p.add_argument("-o", "--output", help="campaign netCDF file to write (required unless "
                                          "--print-default)")
    p.add_argument("--speed", type=float, default=None,
                   help="airspeed in kt for the built-in campaign (default hover)")
    p.add_argument("--maneuvers", default="*", help="only manoeuvres matching this glob")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise or turbulence")
    p.add_argument("--calm-sweeps", action="store_true",
                   help="fly the sweeps in calm air, the other manoeuvres in the campaign's "
                        "turbulence")
    p.add_argument("--linear-regime", action="store_true",
                   help="the built-in campaign's sweeps for a check against the "
                        "linearisation: cyclic and pedal at half amplitude, calm air")
    p.add_argument("--print-default", action="store_true",
                   help="print the built-in campaign as TOML and exit (a template to edit)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=_simulate)


def _simulate(args) -> int:
    if not args.output and not args.print_default:
        raise InputDataError("sysid simulate: give -o <campaign.nc> (the file to write), or "
                             "--print-default to print the campaign as TOML")
    if args.output and Path(args.output).is_dir():  # said before flying, not after
        raise InputDataError(f"-o {args.output} is a directory; expected a campaign file name "
                             "(e.g. -o campaign.nc)")
    if args.campaign:
        for flag, given in (("--speed", args.speed is not None),
                            ("--linear-regime", args.linear_regime)):
            if given:
                raise InputDataError(f"{flag} applies to the built-in campaign only; edit "
                                     "the campaign file instead")
        campaign = Campaign.from_toml(args.campaign)
        if args.no_noise:
            campaign.noise, campaign.turbulence = {}, 0.0
            campaign.maneuvers = [dataclasses.replace(m, turbulence=None)
                                  for m in campaign.maneuvers]
    elif args.linear_regime:
        campaign = linear_regime_campaign(args.speed or 0.0, noise=not args.no_noise)
    else:
        campaign = default_campaign(args.speed or 0.0, noise=not args.no_noise)
    if args.calm_sweeps:
        campaign = with_calm_sweeps(campaign)
    if args.print_default:
        print(campaign.to_toml(), end="")
        return 0
    campaign = campaign.select(args.maneuvers)
    if not campaign.maneuvers:
        raise InputDataError(f"no manoeuvre matches {args.maneuvers!r}")
    run_campaign(campaign, Path(args.output), quiet=args.quiet, summaries=[campaign_summary])
    if not args.quiet:
        print(Path(args.output).resolve())
    return 0
