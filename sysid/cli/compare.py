"""``sysid compare``: frequency- vs time-domain derivatives beside the truth (Tables 2-3), and
the fidelity scoreboard: each estimate's error against the truth in units of its bound, flagged
beyond 3 bounds (:func:`sysid.assess.comparison.fidelity_scoreboard`)."""

from __future__ import annotations

from sysid.data.campaign import CampaignData
from sysid.data.netcdf import update_campaign
from sysid.assess.comparison import (compare_models, format_scoreboard, format_sign_agreement,
                                     format_table, sign_agreement, write_table_csv)


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compare", help="derivative table of every identified model beside the truth",
        description="Tabulate the derivatives and Cramer-Rao bounds of every model in "
                    "/models (frequency_domain, time_domain, ...) beside the truth model's "
                    "quasi-steady linearisation, like the paper's Tables 2-3, with a fidelity "
                    "scoreboard (error against the truth in bounds, flagged beyond 3 bounds: "
                    "bias beyond noise); store it as /comparison and optionally as CSV.")
    p.add_argument("campaign", help="campaign netCDF file with /models/<method> groups")
    p.add_argument("--csv", default=None, help="also write the table to this CSV file")
    p.set_defaults(func=run)


def run(args) -> int:
    table = compare_models(CampaignData.read(args.campaign))
    update_campaign(args.campaign, "comparison", table)
    print(format_table(table))
    if sign_agreement(table).size:
        print(format_sign_agreement(table))
    if bool(table["truth"].notnull().any()):
        print(format_scoreboard(table))
    if args.csv:
        write_table_csv(table, args.csv)
        print(f"wrote {args.csv}")
    return 0
