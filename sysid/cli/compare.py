"""``sysid compare``: frequency- vs time-domain derivatives beside the truth (Tables 2-3)."""

from __future__ import annotations

from pathlib import Path


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "compare", help="derivative table of every identified model beside the truth",
        description="Tabulate the derivatives and Cramer-Rao bounds of every model in "
                    "/models (frequency_domain, time_domain, ...) beside the truth model's "
                    "quasi-steady linearisation, like the paper's Tables 2-3; store it as "
                    "/comparison and optionally as CSV.")
    p.add_argument("campaign", help="campaign netCDF file with /models/<method> groups")
    p.add_argument("--csv", default=None, help="also write the table to this CSV file")
    p.set_defaults(func=run)


def run(args) -> int:
    from sysid.assess.comparison import derivative_table, format_table, sign_agreement
    from sysid.core.errors import InputDataError
    from sysid.data.netcdf import read_campaign, update_campaign
    from sysid.core.util import atomic_path

    tree = read_campaign(args.campaign)
    if "models" not in tree or not tree["models"].children:
        raise InputDataError(f"{args.campaign} has no identified models (/models/<method>); "
                             "run 'sysid identify' and/or 'sysid identify-time' first")
    models = {name: node.to_dataset(inherit=False)
              for name, node in tree["models"].children.items()}
    truth = tree["linearization"].to_dataset() if "linearization" in tree else None
    table = derivative_table(models, truth)
    update_campaign(args.campaign, "comparison", table)
    print(format_table(table))
    agree = sign_agreement(table)
    if agree.size:
        differing = [str(p) for p, ok in zip(agree.parameter.values, agree.values) if not ok]
        print("dominant derivatives with the same sign in every method: "
              + ("all" if not differing else f"all but {', '.join(differing)}"))
    if args.csv:
        with atomic_path(Path(args.csv)) as tmp:
            frame = table.to_dataframe().reset_index()
            frame.to_csv(tmp, index=False)
        print(f"wrote {args.csv}")
    return 0
