"""``sysid export`` and ``sysid validate``: identified models out as FMUs, and their checks."""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

from sysid.core.errors import InputDataError
from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign_groups
from sysid.fmi.export import export_fmu
from sysid.assess.envelopes import MUAD
from sysid.assess.validation import format_validation, truth_reference, validate_models


def _cmd_export(args: argparse.Namespace) -> int:
    models = CampaignData.read(args.campaign).models()
    if not models:
        raise InputDataError("the campaign has no identified models (/models/<name>); run "
                             "'sysid identify' first")
    if args.model not in models:
        raise InputDataError(f"model {args.model!r} is not in {args.campaign} (has "
                             f"{sorted(models)})")
    out = args.output or f"{args.model}.fmu"
    path = export_fmu(models[args.model], out, fmi_version=args.fmi,
                      model_name=args.name or f"sysid_{args.model}", step_size=args.step,
                      me_delay=args.me_delay, pade_order=args.pade_order, quiet=args.quiet)
    print(path)
    return 0


def _cmd_validate(args: argparse.Namespace) -> int:
    data = CampaignData.read(args.campaign)
    truth, trim = (None, "skipped (--no-truth)") if args.no_truth else truth_reference(data)
    if truth is None:
        print(f"time-domain comparison with the truth FMU: {trim}")
        trim = None
    if data.frequency_response() is None:
        print("no /frequency_response in the campaign: envelope check skipped")
    with tempfile.TemporaryDirectory(prefix="sysid-validate-") as tmp:
        results = validate_models(data, fmu_dir=Path(args.fmu_dir) if args.fmu_dir else Path(tmp),
                                  truth=truth, trim=trim, envelopes=[MUAD, *args.envelope],
                                  quiet=args.quiet)
    update_campaign_groups(args.campaign, {f"validation/{name}": ds
                                           for name, ds in results.items()})
    print(format_validation(results))
    if all("error" in ds.attrs for ds in results.values()):
        return 1
    print(f"Results stored under /validation/<model> in {args.campaign}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "export", help="export an identified model of a campaign as an FMU",
        description="Write a campaign model (/models/<name>) as one FMI 2.0 or 3.0 FMU "
                    "(model exchange and co-simulation, exact directional derivatives, C "
                    "sources included), in the truth FMU's absolute units.")
    p.add_argument("campaign", help="campaign netCDF file")
    p.add_argument("--model", required=True, help="model group name, e.g. frequency_domain")
    p.add_argument("-o", "--output", help="FMU file to write (default <model>.fmu)")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2, help="FMI version (default 2)")
    p.add_argument("--name", help="model name in the FMU (default sysid_<model>)")
    p.add_argument("--step", type=float, default=0.01, help="default communication step, s")
    p.add_argument("--me-delay", choices=("buffer", "pade"), default="buffer",
                   help="delays in model exchange: input history held between input updates "
                        "(exact, default) or Pade approximants (see fmus/linear/README.md)")
    p.add_argument("--pade-order", type=int, default=6,
                   help="order of the Pade delays with --me-delay pade (default 6)")
    p.add_argument("--quiet", action="store_true", help="no progress lines")
    p.set_defaults(func=_cmd_export)

    v = subparsers.add_parser(
        "validate", help="export every campaign model and validate it",
        description="For every /models/* model: export it as an FMU, compare the FMU with "
                    "sysid.models.simulate (co-simulation and model exchange), with the truth "
                    "FMU from trim (3211/2311 inputs, J_rms and TIC) and check its mismatch "
                    "against /frequency_response with MUAD and user envelopes. Results go to "
                    "/validation/<model>.")
    v.add_argument("campaign", help="campaign netCDF file")
    v.add_argument("--envelope", action="append", default=[],
                   help="user envelope TOML file (e.g. AEE); may be repeated")
    v.add_argument("--fmu-dir", help="keep the exported FMUs in this folder")
    v.add_argument("--no-truth", action="store_true",
                   help="skip the time-domain comparison with the truth FMU")
    v.add_argument("--quiet", action="store_true", help="no progress lines")
    v.set_defaults(func=_cmd_validate)
