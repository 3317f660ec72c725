"""``sysid batch``: the whole identification chain at many flight conditions on Dask."""

from __future__ import annotations

import dataclasses
from pathlib import Path

from sysid.pipeline.batch import (default_conditions, format_calibration, format_summary,
                                  load_conditions, run_batch)
from sysid.cli._options import add_time_domain_method_option, time_domain_method


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "batch", help="run the study at many flight conditions / seeds on Dask",
        description="Run the full identification chain for a list of flight conditions and "
                    "noise seeds as independent Dask tasks (a local cluster of processes by "
                    "default, an existing scheduler with --scheduler), combine the results "
                    "into one netCDF file with a condition dimension, plot every derivative "
                    "against airspeed and summarise the Monte Carlo scatter (with several "
                    "seeds of a setting: scatter over seeds / mean bound of each dominant "
                    "derivative in both domains, batch_calibration.png). A failing "
                    "condition is reported and the others complete; re-running resumes from "
                    "what is on disk.")
    p.add_argument("speeds", nargs="?", default=None,
                   help="speeds TOML (speeds = [...], seeds = [...], noise, quick, "
                        "time_domain_method, calm_sweeps, campaign, [structures], "
                        "[[conditions]]); default: 0, 20, 40, 60, 80, 100 kt, one seed")
    p.add_argument("-o", "--output", default="reports/batch", help="output folder")
    p.add_argument("--scheduler", default=None, metavar="tcp://host:port",
                   help="address of an existing Dask scheduler (default: a LocalCluster)")
    p.add_argument("--workers", type=int, default=2,
                   help="worker processes of the local cluster (default 2)")
    p.add_argument("--quick", action="store_true",
                   help="reduced campaign and study per condition (fast check; noisier "
                        "results; no per-condition report, FMUs or validation)")
    add_time_domain_method_option(
        p, default=None,
        help="the time-domain estimator of every condition (default: the speeds file's, "
             "else auto: filter error, whose bounds are calibrated, and output error for "
             "--quick conditions)")
    p.add_argument("--calm-sweeps", action="store_true",
                   help="every condition's sweeps in calm air, its multisteps in the "
                        "campaign's turbulence (what a hybrid structure's frequency-domain "
                        "fit needs)")
    p.add_argument("--campaign", default=None, metavar="FILE",
                   help="campaign TOML flown by every condition instead of the built-in one "
                        "(as 'sysid run --campaign'; each condition's seed and noise apply, "
                        "its airspeed must be the condition's): Monte Carlo comparison of "
                        "test-input designs")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    if args.speeds:
        conditions = load_conditions(args.speeds)
    else:
        conditions = default_conditions()
    if args.quick:
        conditions = [dataclasses.replace(c, quick=True) for c in conditions]
    if args.calm_sweeps:
        conditions = [dataclasses.replace(c, calm_sweeps=True) for c in conditions]
    if args.campaign:
        conditions = [dataclasses.replace(c, campaign=str(Path(args.campaign).resolve()))
                      for c in conditions]
    method = time_domain_method(args)
    if method:
        conditions = [dataclasses.replace(c, time_domain_method=method) for c in conditions]
    result = run_batch(conditions, args.output, scheduler=args.scheduler,
                       n_workers=args.workers, quiet=args.quiet)
    print(format_summary(result.dataset))
    if "calibration_ratio" in result.dataset:
        print(format_calibration(result.dataset))
    print(result.out_dir / "batch.nc")
    return 0 if not result.failures else 3
