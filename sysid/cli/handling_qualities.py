"""``sysid handling-qualities``: ADS-33E-PRF bandwidth and phase delay, and the holds' margins.

::

    sysid handling-qualities campaign.nc [--response-type rate|attitude]
                             [--describing-function yaw ...] [--no-store]

Runs :func:`sysid.assess.handling_qualities.handling_qualities` (pitch, roll and yaw attitude
responses of the data, the truth linearisations and every identified model) and
:func:`sysid.assess.margins.hold_margins` (crossover and margins of each stabilisation hold
on the truth's full linearisation, when the campaign was flown with holds), prints both and
stores them as ``/handling_qualities`` and ``/hold_margins``. ``--describing-function AXIS``
flies the truth FMU with pure control sinusoids at the campaign's sweep amplitude around the
truth's bandwidth (:func:`sysid.assess.handling_qualities.describing_function`) and adds the
source ``describing_function``: the truth at the amplitude flown.
"""

from __future__ import annotations

import argparse

import numpy as np

from sysid.assess.handling_qualities import (AXES, RESPONSE_TYPES, describing_function,
                                             describing_grid, handling_qualities)
from sysid.assess.margins import flown_campaign, hold_margins
from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign_groups


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "handling-qualities",
        help="ADS-33E-PRF bandwidth / phase delay of the attitude responses, hold margins",
        description="Bandwidth (phase and gain), governing bandwidth, phase delay and "
                    "ADS-33E-PRF Level (hover and low speed) of theta/lon, phi/lat and psi/ped "
                    "from the composite data, the truth linearisations and each identified "
                    "model, with coherence and random-error uncertainty; crossover and margins "
                    "of each stabilisation hold. Stored as /handling_qualities and "
                    "/hold_margins.")
    p.add_argument("campaign", help="campaign netCDF file")
    p.add_argument("--response-type", choices=RESPONSE_TYPES, default="rate",
                   help="which bandwidth governs: rate (bare airframe, default) or attitude "
                        "(ACAH)")
    p.add_argument("--describing-function", action="append", choices=list(AXES), default=[],
                   metavar="AXIS",
                   help="also the truth FMU's describing function on this axis (pitch, roll, "
                        "yaw; repeatable): pure sinusoids at the sweep's amplitude around the "
                        "linearisation's bandwidth, source 'describing_function'")
    p.add_argument("--no-store", action="store_true", help="print only")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run)


def _fmt(value: float, std: float, fmt: str) -> str:
    if not np.isfinite(value):
        return "—"
    return format(value, fmt) + (f" ± {format(std, fmt)}" if np.isfinite(std) else "")


def run(args: argparse.Namespace) -> int:
    progress = Progress(quiet=args.quiet)
    data = CampaignData.read(args.campaign)
    hq = handling_qualities(data, response_type=args.response_type, progress=progress)
    if args.describing_function:
        campaign = flown_campaign(data)
        dfs = []
        for axis in dict.fromkeys(args.describing_function):
            row = hq.sel(axis=axis, source="linearization_full" if "linearization_full"
                         in hq.source.values else "data")
            with progress.stage(f"describing function, {axis}"):
                dfs.append(describing_function(
                    campaign, omega=describing_grid(float(row.bandwidth_phase)), axis=axis,
                    quiet=args.quiet))
        hq = handling_qualities(data, response_type=args.response_type, describing=dfs,
                                progress=progress)
    print(f"{'axis':<6}{'source':<20}{'omega_180':>10}{'BW phase':>10}{'BW gain':>10}"
          f"{'BW':>18}{'tau_p [ms]':>16}{'gamma2 2w180':>13}{'Level trk/oth':>15}")
    for axis in hq["axis"].values:
        for source in hq["source"].values:
            r = hq.sel(axis=axis, source=source)
            print(f"{axis:<6}{source:<20}{float(r.omega_180):>10.3f}"
                  f"{float(r.bandwidth_phase):>10.3f}{float(r.bandwidth_gain):>10.3f}"
                  f"{_fmt(float(r.bandwidth), float(r.bandwidth_std), '.3f'):>18}"
                  f"{_fmt(1e3 * float(r.tau_p), 1e3 * float(r.tau_p_std), '.1f'):>16}"
                  f"{float(r.coherence_tau_p):>13.3f}"
                  f"{int(r.level_tracking):>8}/{int(r.level_other)}")
    groups = {"handling_qualities": hq}
    try:
        margins = hold_margins(data)
    except InputDataError as exc:
        progress.message(f"[sysid] handling-qualities: no hold margins: {exc}")
    else:
        groups["hold_margins"] = margins
        print("\nstabilisation holds broken at their control, other holds closed "
              f"({margins.attrs['model']}):")
        print(f"{'excited':<8}{'hold':<6}{'crossover':>10}{'PM [deg]':>10}{'GM [dB]':>9}"
              f"{'at [rad/s]':>11}{'low GM [dB]':>12}{'at [rad/s]':>11}")
        for e in margins["excited"].values:
            for h in margins["hold"].values:
                r = margins.sel(excited=e, hold=h)
                print(f"{e:<8}{h:<6}{float(r.gain_crossover):>10.3f}"
                      f"{float(r.phase_margin):>10.1f}{float(r.gain_margin_db):>9.1f}"
                      f"{float(r.phase_crossover):>11.3f}{float(r.gain_margin_low_db):>12.1f}"
                      f"{float(r.phase_crossover_low):>11.3f}")
    if not args.no_store:
        update_campaign_groups(args.campaign, groups)
        progress.message(f"[sysid] handling-qualities: stored {', '.join('/' + g for g in groups)}"
                         f" in {args.campaign}")
    return 0
