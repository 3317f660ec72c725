"""``sysid export-ssp``: the truth FMU and the identified models in one SSP 1.0 package."""

from __future__ import annotations

import argparse

from sysid.assess.exchange import export_study_ssp


def _cmd_export_ssp(args: argparse.Namespace) -> int:
    print(export_study_ssp(args.campaign, args.output, axis=args.axis, dt=args.step,
                           quiet=args.quiet))
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export-ssp", help="write the truth FMU and the identified models as an SSP package",
        description="Write an SSP 1.0 package (SystemStructure.ssd + resources/*.fmu): a "
                    "signal FMU playing a 2311 multistep about the truth trim, the truth "
                    "helicopter FMU started at its trim and every /models/<name> of the "
                    "campaign exported as an FMI 2.0 FMU, all fed the same lon lat col ped. "
                    "libcosim (libcosimpy CosimExecution.from_ssp_file) and other SSP tools "
                    "run it.")
    p.add_argument("campaign", help="campaign netCDF file with identified models")
    p.add_argument("-o", "--output", default="study.ssp", help="package to write (.ssp)")
    p.add_argument("--axis", choices=("lon", "lat"), default="lon", help="axis of the 2311")
    p.add_argument("--step", type=float, default=0.01,
                   help="sample interval of the input and suggested communication step, s")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_export_ssp)
