"""``sysid import`` and ``sysid export-csv``: bring flight data from other tools into a campaign
file and take time histories out again."""

from __future__ import annotations

import argparse
from pathlib import Path

from sysid import __version__
from sysid.data.campaign import list_maneuvers
from sysid.data.importers import read_time_history, write_csv
from sysid.data.netcdf import add_maneuvers, read_campaign
from sysid.core.errors import InputDataError


def _pairs(values: list[str] | None, option: str) -> dict[str, str]:
    """``{"lon": "DLON"}`` from ``["lon=DLON,q=Q", ...]`` (repeatable, comma-separated)."""
    out: dict[str, str] = {}
    for value in values or []:
        for item in filter(None, (s.strip() for s in value.split(","))):
            name, sep, rhs = item.partition("=")
            if not sep or not name.strip() or not rhs.strip():
                raise InputDataError(f"{option} {item!r}: expected NAME=VALUE, "
                                     f"e.g. {option} lon=DLON_PCT")
            out[name.strip()] = rhs.strip()
    return out


def _trim(values: list[str] | None) -> dict[str, float]:
    out = {}
    for name, value in _pairs(values, "--trim").items():
        try:
            out[name] = float(value)
        except ValueError:
            raise InputDataError(f"--trim {name}={value!r}: expected a number in the channel's "
                                 "analysis unit (deg, deg/s, ft/s, %)") from None
    return out


def _import(args: argparse.Namespace) -> int:
    mapping = _pairs(args.map, "--map") or None
    units = _pairs(args.units, "--units") or None
    trim = _trim(args.trim) or None
    out = Path(args.output)
    # Read everything first and write once: a bad file leaves no (or the old) output behind.
    datasets = {}
    for file in args.files:
        ds = read_time_history(file, mapping=mapping, units=units, kind=args.kind,
                                  trim=trim)
        name = ds.attrs["maneuver"]
        if name in datasets:
            raise InputDataError(f"{file}: manoeuvre name {name!r} is used by two input files")
        datasets[name] = ds
    if out.is_dir():
        raise InputDataError(f"-o {out} is a directory; expected a campaign file name "
                             "(e.g. -o campaign.nc)")
    # One locked read-modify-write: imports and other stages writing the same campaign at
    # the same time keep each other's groups.
    add_maneuvers(out, datasets, root_attrs={"campaign": out.stem,
                                             "sysid_version": __version__})
    if not args.quiet:
        print(f"{out}: imported {len(datasets)} manoeuvre(s): {', '.join(datasets)}")
    return 0


def _export_csv(args: argparse.Namespace) -> int:
    tree = read_campaign(args.campaign)
    names = list_maneuvers(tree)
    if args.maneuver not in names:
        raise InputDataError(f"{args.campaign}: no manoeuvre {args.maneuver!r}; "
                             f"available: {names}")
    write_csv(tree[f"maneuvers/{args.maneuver}"].to_dataset(), args.output)
    if not args.quiet:
        print(f"{args.output}: wrote {args.maneuver}")
    return 0


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "import",
        help="build a campaign file from time histories written by other tools",
        description=(
            "Read one manoeuvre per FILE (CSV with a header row, or netCDF) and store them as "
            "/maneuvers/<name> in the campaign file (added to it if it exists). The name is "
            "the file stem; the kind is taken from its first token (sweep_, 3211_, 2311_, "
            "doublet_, multisine_) unless --kind is given. Trim defaults to the mean of the "
            "first second of data."),
    )
    p.add_argument("files", nargs="+", metavar="FILE")
    p.add_argument("-o", "--output", required=True, metavar="CAMPAIGN.nc")
    p.add_argument("--map", action="append", metavar="CHANNEL=COLUMN",
                   help="file column of a sysid channel, e.g. lon=DLON_PCT (repeatable or "
                        "comma-separated); only mapped columns are read")
    p.add_argument("--units", action="append", metavar="CHANNEL=UNIT",
                   help="unit of a channel in the file, e.g. q=rad/s; converted to the "
                        "analysis unit (overrides a unit in the header)")
    p.add_argument("--kind", choices=["sweep", "3211", "2311", "doublet", "multisine",
                                      "imported"])
    p.add_argument("--trim", action="append", metavar="CHANNEL=VALUE",
                   help="trim values in analysis units, e.g. theta=2.5,phi=-1.0")
    p.add_argument("-q", "--quiet", action="store_true")
    p.set_defaults(func=_import)

    e = subparsers.add_parser("export-csv", help="write one manoeuvre of a campaign as CSV",
                              description="Write /maneuvers/MANEUVER of CAMPAIGN as CSV "
                                          "(header 'name [unit]', attributes in a comment).")
    e.add_argument("campaign", metavar="CAMPAIGN.nc")
    e.add_argument("maneuver", metavar="MANEUVER")
    e.add_argument("-o", "--output", required=True, metavar="FILE.csv")
    e.add_argument("-q", "--quiet", action="store_true")
    e.set_defaults(func=_export_csv)
