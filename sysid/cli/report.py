"""``sysid report``: the HTML report of any campaign file, with whatever stages it holds."""

from __future__ import annotations

from pathlib import Path

from sysid.core.errors import InputDataError
from sysid.data.campaign import CampaignData
from sysid.report.html import write_report


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "report", help="write the HTML report of a campaign file",
        description="Write report.html and figures/*.png for CAMPAIGN.nc: imported data "
                    "alone, or with frequency responses, models, verification and the rest. "
                    "Sections whose groups the campaign does not hold are left out.")
    p.add_argument("campaign", metavar="CAMPAIGN.nc")
    p.add_argument("-o", "--output", default=None, metavar="DIR",
                   help="output folder (default: the campaign file's folder)")
    p.add_argument("--title", default=None, help="report title (default from the campaign)")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    path = Path(args.campaign)
    if not path.is_file():
        raise InputDataError(f"campaign file {path} does not exist")
    out = Path(args.output) if args.output else path.resolve().parent
    if out.exists() and not out.is_dir():
        raise InputDataError(f"-o {out} is a file; expected a folder for report.html and "
                             "figures/")
    report = write_report(CampaignData.read(path).tree, out, title=args.title,
                          quiet=args.quiet)
    print(report.resolve())
    return 0
