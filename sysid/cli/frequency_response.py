"""``sysid frequency-response``: composite conditioned frequency responses of a campaign.

Reads the manoeuvres ``/maneuvers/<name>`` of a campaign file matching ``--maneuvers``
(default ``sweep_*``), concatenates them CIFER-style, computes the conditioned composite
frequency responses of every input/output pair (:func:`sysid.spectral.response.frequency_response`)
and writes them to the group ``/frequency_response`` of the same file (atomically), plus the
per-window results to ``/frequency_response_windows`` with ``--keep-windows``. Prints one line
per pair: the frequency range where the (partial) coherence is at least 0.6 and its mean.
"""

from __future__ import annotations

from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign_groups
from sysid.spectral.response import frequency_response
from sysid.spectral.spectra import DEFAULT_C_EPS
from sysid.assess.coherence import format_coherent_ranges
from sysid.cli._options import add_transient_options, transient_states


def _floats(text: str) -> list[float]:
    try:
        return [float(v) for v in text.split(",") if v.strip()]
    except ValueError as exc:
        raise InputDataError(f"--windows: expected comma-separated seconds, got {text!r}") from exc


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "frequency-response",
        help="composite conditioned frequency responses of a campaign's sweeps",
        description=__doc__.split("\n\n")[1].replace("\n", " "),
    )
    p.add_argument("campaign", help="campaign netCDF file (updated in place)")
    p.add_argument("--inputs", required=True, help="comma-separated inputs, e.g. lon,lat,col,ped")
    p.add_argument("--outputs", required=True,
                   help="comma-separated outputs, e.g. u,v,w,p,q,r,phi,theta,psi")
    p.add_argument("--maneuvers", default="sweep_*",
                   help="glob selecting /maneuvers/<name> records (default: sweep_*)")
    p.add_argument("--windows", type=_floats, default=None,
                   help="comma-separated window lengths in s (default: 5 from the record lengths)")
    p.add_argument("--n-windows", type=int, default=5, help="number of windows (default 5)")
    p.add_argument("--overlap", type=float, default=0.8, help="segment overlap (default 0.8)")
    p.add_argument("--omega-min", type=float, default=None, help="lowest frequency, rad/s")
    p.add_argument("--omega-max", type=float, default=None, help="highest frequency, rad/s")
    p.add_argument("--n-frequencies", type=int, default=200,
                   help="log-spaced frequency points (default 200)")
    p.add_argument("--C-eps", dest="C_eps", type=float, default=None,
                   help="random-error constant of Eq. 9 (default 0.7)")
    p.add_argument("--unconditioned", action="store_true",
                   help="single-input estimates instead of MIMO conditioning")
    add_transient_options(p)
    p.add_argument("--keep-windows", action="store_true",
                   help="also store the per-window results in /frequency_response_windows")
    p.add_argument("--quiet", action="store_true", help="no progress or summary output")
    p.set_defaults(func=run)


def run(args) -> int:
    progress = Progress(quiet=args.quiet)
    data = CampaignData.read(args.campaign)
    if "maneuvers" not in data.tree.children:
        raise InputDataError(f"campaign {args.campaign} has no /maneuvers group")
    records = data.maneuvers(args.maneuvers)
    progress.message(f"[sysid] frequency response from {len(records)} record(s): "
                     f"{', '.join(records)}")
    result = frequency_response(
        records, args.inputs, args.outputs, n_windows=args.n_windows, windows=args.windows,
        overlap=args.overlap, n_frequencies=args.n_frequencies, omega_min=args.omega_min,
        omega_max=args.omega_max,
        C_eps=DEFAULT_C_EPS if args.C_eps is None else args.C_eps,
        conditioned=not args.unconditioned, keep_windows=args.keep_windows, progress=progress,
        transient_states=transient_states(args))
    composite, per_window = result if args.keep_windows else (result, None)
    groups = {"frequency_response": composite}
    if per_window is not None:
        groups["frequency_response_windows"] = per_window
    update_campaign_groups(args.campaign, groups)
    if not args.quiet:
        states = list(composite.attrs.get("transient_states", []))
        choice = composite.attrs.get("transient_choice", "")
        print("leakage conditioning: "
              + (f"{', '.join(states)} ({choice})" if states else "off"))
        print(format_coherent_ranges(composite))
        print(f"wrote {' and '.join('/' + g for g in groups)} to {args.campaign}")
    return 0
