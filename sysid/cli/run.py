"""``sysid run``: the end-to-end studies (hover, forward flight, domain comparison)."""

from __future__ import annotations

from pathlib import Path

from sysid.core.errors import InputDataError
from sysid.pipeline.flight_data import FLIGHT_DATA_STRUCTURE, run_flight_data
from sysid.pipeline.study import TIME_DOMAIN_AUTO, StudySettings, run_study
from sysid.cli._options import (add_time_domain_method_option, add_transient_options,
                                time_domain_method, transient_states)
from sysid.cli.io import _pairs, _resample, _trim

#: study name -> (default airspeed kt, default structure, default output folder)
STUDIES = {
    "hover": (0.0, "hover_6dof", "reports/hover"),
    "forward-flight": (80.0, "forward_6dof", "reports/forward_flight"),
}


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "run", help="run a whole study: campaign, identification, validation, export, report",
        description="Run the paper's chain at one flight condition and write the campaign, "
                    "the exported FMUs and the HTML report into one folder. Re-running "
                    "reuses every stage whose inputs did not change. With --data FILES, "
                    "the same chain on flight-test files (no truth model; no STUDY).")
    p.add_argument("study", nargs="?", choices=sorted(STUDIES),
                   help="which study (omit with --data)")
    p.add_argument("--data", nargs="+", metavar="FILE", default=None,
                   help="flight-test files (CSV, netCDF, MAT v5/v7.3, HDF5): import, "
                        "responses, both fits on the measured channels, verification, "
                        "export and the report (default output reports/flight)")
    p.add_argument("--map", action="append", metavar="CHANNEL=COLUMN",
                   help="with --data: file column of a sysid channel (as 'sysid import')")
    p.add_argument("--units", action="append", metavar="CHANNEL=UNIT",
                   help="with --data: unit of a channel in the files")
    p.add_argument("--trim", action="append", metavar="CHANNEL=VALUE",
                   help="with --data: trim values in analysis units")
    p.add_argument("--time", default="time", metavar="NAME",
                   help="with --data: name of the time vector (default time)")
    p.add_argument("--resample", default=None, metavar="HZ|auto",
                   help="with --data: put jittered records on a uniform grid")
    p.add_argument("-o", "--output", default=None,
                   help="output folder (default reports/<study>)")
    p.add_argument("--speed", type=float, default=None, help="airspeed, kt")
    p.add_argument("--structure", default=None, help="model structure (TOML or built-in)")
    p.add_argument("--campaign", default=None, help="campaign TOML instead of the built-in")
    p.add_argument("--seed", type=int, default=None,
                   help="campaign seed (default: the built-in campaign's, or the one in "
                        "--campaign's file)")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise or turbulence")
    p.add_argument("--calm-sweeps", action="store_true",
                   help="fly the sweeps in calm air (the other manoeuvres keep the "
                        "campaign's turbulence): what a hybrid structure's frequency-domain "
                        "fit needs")
    add_time_domain_method_option(
        p, default=TIME_DOMAIN_AUTO,
        help="the time-domain estimator: filter error (process noise: turbulence under "
             "stabilising loops; its bounds are calibrated), output error (the paper's, "
             "faster) or auto (default: filter error)")
    add_transient_options(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.data:
        return _run_data(args)
    if args.study is None:
        raise InputDataError("name a study (" + ", ".join(sorted(STUDIES)) + ") or give "
                             "flight-test files with --data")
    speed, structure, folder = STUDIES[args.study]
    settings = StudySettings(
        airspeed_kt=speed if args.speed is None else args.speed,
        structure=args.structure or structure, seed=args.seed, noise=not args.no_noise,
        campaign_file=args.campaign, calm_sweeps=args.calm_sweeps,
        transient_states=transient_states(args),
        time_domain_method=time_domain_method(args))
    report = run_study(Path(args.output or folder), settings, quiet=args.quiet)
    print(report.resolve())
    return 0


def _run_data(args) -> int:
    if args.study is not None:
        raise InputDataError(f"--data runs the chain on flight data; drop the study name "
                             f"{args.study!r}")
    ignored = [opt for opt, given in (("--speed", args.speed is not None),
                                      ("--campaign", args.campaign is not None),
                                      ("--no-noise", args.no_noise),
                                      ("--calm-sweeps", args.calm_sweeps)) if given]
    if ignored:
        raise InputDataError(f"{', '.join(ignored)}: only for the built-in studies, not with "
                             "--data")
    resample = _resample(args.resample)
    report = run_flight_data(args.data, Path(args.output or "reports/flight"),
                             mapping=_pairs(args.map, "--map") or None,
                             units=_pairs(args.units, "--units") or None,
                             trim=_trim(args.trim) or None, time=args.time, resample=resample,
                             structure=args.structure or FLIGHT_DATA_STRUCTURE,
                             transient_states=transient_states(args),
                             time_domain_method=time_domain_method(args),
                             quiet=args.quiet)
    print(report.resolve())
    return 0
