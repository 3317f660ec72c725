"""``sysid identify-time`` and ``sysid verify``: time-domain output error and verification.

::

    sysid identify-time campaign.nc --maneuvers '3211_*' [--structure S.toml]
                        [--start auto|frequency_domain|linearization|structure]
                        [--outputs u,v,w,...] [--no-reduction] [--no-biases]
                        [--no-initial-state] [--quiet]

fits the structure (default: the built-in ``hover_6dof``) to the selected manoeuvres at once by
maximum-likelihood output error (:func:`sysid.identify.stages.fit_time_domain`),
stores the model in ``/models/time_domain`` and prints the derivative table with Cramer-Rao
bounds, the delays, the estimated noise and biases. Start values (``auto``): the
frequency-domain model when the campaign has one, else ``/linearization``, else the
structure's values.

::

    sysid identify-filter-error campaign.nc --maneuvers '3211_*' [--structure S.toml]
                        [--start ...] [--process-noise auto|measured|diagonal|full|u,v,w,r]
                        [--outputs u,v,w,...] [--noise-starts 0.01:10,1:10]
                        [--no-reduction] [--quiet]

fits the structure by the filter-error method (process and measurement noise; the steady
Kalman predictor's innovations; :func:`sysid.identify.stages.fit_filter_error`, with the
output-error fit's model reduction), stores ``/models/filter_error`` and prints the table
with the innovations' bounds, the bounds corrected for their colour, the noise and the
innovations' whiteness.

::

    sysid verify campaign.nc --model frequency_domain[,time_domain] --maneuvers '2311_*'
                 [--estimate bias,reference_shift] [--quiet]

simulates each model with the recorded inputs of each selected manoeuvre, estimating only
output biases and input reference shifts (:func:`sysid.assess.stages.verify_models`), stores
``/verification/<maneuver>`` (merged with the sources already there) and prints J_rms and
TIC per output with PASS/FAIL against :data:`sysid.assess.metrics.J_RMS_GUIDELINE` and
:data:`sysid.assess.metrics.TIC_GUIDELINE`.
"""

from __future__ import annotations

import argparse
import math

from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign, update_campaign_groups
from sysid.identify.filter_error import NOISE_STARTS
from sysid.identify.stages import (FILTER_ERROR_PROCESS_NOISE, TIME_DOMAIN_STARTS,
                                   fit_filter_error, fit_time_domain)
from sysid.assess.stages import verify_models
from sysid.assess.verification import ESTIMATES, verification_table


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "identify-time",
        help="identify a state-space model with delays from time histories (output error)",
        description="Maximum-likelihood output-error identification on one or more "
                    "manoeuvres (Levenberg-Marquardt, noise covariance re-estimation, "
                    "Cramer-Rao bounds, stepwise model reduction).",
    )
    _fit_arguments(p)
    p.add_argument("--no-reduction", action="store_true", help="skip the model reduction")
    p.add_argument("--no-biases", action="store_true", help="do not estimate output biases")
    p.add_argument("--no-initial-state", action="store_true",
                   help="do not estimate initial states")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=run_identify)

    f = subparsers.add_parser(
        "identify-filter-error",
        help="identify a state-space model from time histories flown in turbulence "
             "(filter error: process and measurement noise)",
        description="Maximum-likelihood filter-error identification on one or more "
                    "manoeuvres (steady-state Kalman predictor, process noise Q = U D U^T, "
                    "analytic sensitivities, Cramer-Rao bounds of the innovations and "
                    "corrected for their colour), then the output-error fit's model "
                    "reduction.",
    )
    _fit_arguments(f)
    f.add_argument("--process-noise", default=FILTER_ERROR_PROCESS_NOISE,
                   help="'auto' (default: the states the structure declares in its "
                        "process_noise key, else 'measured'), 'measured' (one entry per "
                        "equation of a measured state), 'diagonal' (one per state "
                        "equation), 'full' (any covariance) or comma-separated states "
                        "carrying process noise")
    f.add_argument("--noise-starts", default=None,
                   help="noise starts of the first fit as q:r factors of the default Q and "
                        "R start values, comma-separated; the lowest likelihood is kept "
                        "(default: " + ",".join(f"{q:g}:{r:g}" for q, r in NOISE_STARTS)
                        + ")")
    f.add_argument("--no-reduction", action="store_true", help="skip the model reduction")
    f.add_argument("--quiet", action="store_true", help="no progress lines")
    f.set_defaults(func=run_identify_filter_error)

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


def _fit_arguments(parser) -> None:
    """The campaign, manoeuvres, structure, start values and outputs of a time-domain fit."""
    parser.add_argument("campaign", help="campaign netCDF file with /maneuvers/<name> groups")
    parser.add_argument("--maneuvers", default="*",
                        help="glob selecting the fitted manoeuvres, e.g. '3211_*' (default: "
                             "all)")
    parser.add_argument("--structure", default="hover_6dof",
                        help="structure TOML file or built-in name (default: hover_6dof)")
    parser.add_argument("--start", default="auto", choices=TIME_DOMAIN_STARTS,
                        help="start values (default auto: /models/frequency_domain, else "
                             "/linearization, else the equation error of "
                             "/frequency_response, else the structure's values)")
    parser.add_argument("--outputs", default=None,
                        help="comma-separated fitted outputs (default: all measured)")


def _outputs(args: argparse.Namespace) -> list[str] | None:
    """``--outputs`` as a list (None: every measured output)."""
    return [o.strip() for o in args.outputs.split(",") if o.strip()] if args.outputs else None


def run_identify(args: argparse.Namespace) -> int:
    progress = Progress(quiet=args.quiet)
    data = CampaignData.read(args.campaign)
    outputs = _outputs(args)
    result = fit_time_domain(data, maneuvers=args.maneuvers, structure=args.structure,
                             start=args.start, outputs=outputs, biases=not args.no_biases,
                             initial_state=not args.no_initial_state,
                             reduce=not args.no_reduction, progress=progress)
    update_campaign(args.campaign, "models/time_domain", result.model)
    print(result.table())
    progress.message(f"[sysid] identify-time: model written to {args.campaign} "
                     f"(/models/time_domain), {len(data.list_maneuvers(args.maneuvers))} "
                     f"manoeuvre(s)")
    return 0


def _noise_starts(text: str) -> tuple[tuple[float, float], ...]:
    """``--noise-starts`` ``"q:r,q:r"`` as pairs of positive factors."""
    starts = []
    for item in (t.strip() for t in text.split(",") if t.strip()):
        try:
            q, r = (float(x) for x in item.split(":"))
        except ValueError:
            q = r = math.nan
        if not (q > 0 and r > 0 and math.isfinite(q) and math.isfinite(r)):
            raise InputDataError(f"--noise-starts: {item!r} is not q:r with two positive "
                                 f"factors, e.g. 0.01:10")
        starts.append((q, r))
    if not starts:
        raise InputDataError(f"--noise-starts {text!r}: give at least one q:r pair")
    return tuple(starts)


def run_identify_filter_error(args: argparse.Namespace) -> int:
    starts = NOISE_STARTS if args.noise_starts is None else _noise_starts(args.noise_starts)
    progress = Progress(quiet=args.quiet)
    data = CampaignData.read(args.campaign)
    outputs = _outputs(args)
    noise = args.process_noise.strip()
    if noise not in ("diagonal", "full", "measured", "auto"):
        noise = [s.strip() for s in noise.split(",") if s.strip()]
    result = fit_filter_error(data, maneuvers=args.maneuvers, structure=args.structure,
                              start=args.start, outputs=outputs, process_noise=noise,
                              reduce=not args.no_reduction, noise_starts=starts,
                              progress=progress)
    update_campaign(args.campaign, "models/filter_error", result.model)
    print(result.table())
    progress.message(f"[sysid] identify-filter-error: model written to {args.campaign} "
                     f"(/models/filter_error)")
    return 0


def run_verify(args: argparse.Namespace) -> int:
    progress = Progress(quiet=args.quiet)
    estimate = () if args.estimate.strip() == "none" else tuple(
        e.strip() for e in args.estimate.split(",") if e.strip())
    bad = set(estimate) - set(ESTIMATES)
    if bad:
        raise InputDataError(f"--estimate: unknown {sorted(bad)}; choose from {ESTIMATES} "
                             f"or 'none'")
    models = [m.strip() for m in args.model.split(",") if m.strip()] if args.model else None
    checked = verify_models(CampaignData.read(args.campaign), models=models,
                            maneuvers=args.maneuvers, estimate=estimate, progress=progress)
    update_campaign_groups(args.campaign, {f"verification/{name}": ds
                                           for name, ds in checked.items()})
    for ds in checked.values():
        print(verification_table(ds))
    progress.message(f"[sysid] verify: {len(checked)} manoeuvre(s) written to {args.campaign} "
                     f"(/verification/<maneuver>)")
    return 0
