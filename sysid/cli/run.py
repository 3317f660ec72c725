"""``sysid run``: the end-to-end studies (hover, forward flight, domain comparison)."""

from __future__ import annotations

from pathlib import Path

from sysid.pipeline.study import StudySettings, run_study
from sysid.cli._options import add_transient_options, transient_states

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
                    "reuses every stage whose inputs did not change.")
    p.add_argument("study", choices=sorted(STUDIES), help="which study")
    p.add_argument("-o", "--output", default=None,
                   help="output folder (default reports/<study>)")
    p.add_argument("--speed", type=float, default=None, help="airspeed, kt")
    p.add_argument("--structure", default=None, help="model structure (TOML or built-in)")
    p.add_argument("--campaign", default=None, help="campaign TOML instead of the built-in")
    p.add_argument("--seed", type=int, default=20261121, help="campaign seed")
    p.add_argument("--no-noise", action="store_true", help="no sensor noise or turbulence")
    add_transient_options(p)
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    speed, structure, folder = STUDIES[args.study]
    settings = StudySettings(
        airspeed_kt=speed if args.speed is None else args.speed,
        structure=args.structure or structure, seed=args.seed, noise=not args.no_noise,
        campaign_file=args.campaign,
        transient_states=transient_states(args))
    report = run_study(Path(args.output or folder), settings, quiet=args.quiet)
    print(report.resolve())
    return 0
