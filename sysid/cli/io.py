"""``sysid import`` and ``sysid export-csv``: bring flight data from other tools into a campaign
file and take time histories out again."""

from __future__ import annotations

import argparse
from pathlib import Path

from sysid import __version__
from sysid.data.campaign import list_maneuvers
from sysid.data.importers import read_time_histories, write_csv
from sysid.data.netcdf import add_maneuvers, read_campaign
from sysid.core.errors import InputDataError
from sysid.core.guidelines import GAP_MAX_STEPS


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


def _resample(value: str | None):
    """``None``, ``"auto"`` or a positive rate in Hz from ``--resample``."""
    if value is None or value == "auto":
        return value
    try:
        rate = float(value)
    except ValueError:
        rate = float("nan")
    if not rate > 0 or rate == float("inf"):
        raise InputDataError(f"--resample {value!r}: expected a rate in Hz (e.g. 50) or "
                             "'auto' (the logger's own rate)")
    return rate


def _import(args: argparse.Namespace) -> int:
    mapping = _pairs(args.map, "--map") or None
    units = _pairs(args.units, "--units") or None
    trim = _trim(args.trim) or None
    resample = _resample(args.resample)
    out = Path(args.output)
    if out.is_dir():
        raise InputDataError(f"-o {out} is a directory; expected a campaign file name "
                             "(e.g. -o campaign.nc)")
    # Read everything first and write once: a bad file leaves no (or the old) output behind.
    datasets, notes = {}, []
    for file in args.files:
        records = read_time_histories(file, mapping=mapping, units=units, kind=args.kind,
                                      trim=trim, time=args.time, resample=resample)
        for name, ds in records.items():
            if name in datasets:
                raise InputDataError(f"{file}: manoeuvre name {name!r} is used by two input "
                                     "files")
            datasets[name] = ds
            if "resample_rate_hz" in ds.attrs:
                notes.append(_resample_note(name, ds.attrs))
    # One locked read-modify-write: imports and other stages writing the same campaign at
    # the same time keep each other's groups.
    result = add_maneuvers(out, datasets, root_attrs={"campaign": out.stem,
                                                      "sysid_version": __version__},
                           replace=args.replace)
    if not args.quiet:
        for note in dict.fromkeys(notes):
            print(note)
        added = ", ".join(result["added"]) or "none"
        print(f"{out}: imported {len(datasets)} manoeuvre(s): {', '.join(datasets)} "
              f"(new: {added})")
        if result["replaced"]:
            print(f"{out}: replaced {', '.join(result['replaced'])}")
        for group, reason in result["removed"].items():
            print(f"{out}: removed {group} ({reason})")
    return 0


def _resample_note(name: str, attrs) -> str:
    """One line saying what resampling did to a record."""
    filled, split = attrs["resample_gaps_filled"], attrs["resample_gaps_split"]
    text = (f"{attrs.get('split_from', name)}: resampled to {attrs['resample_rate_hz']:g} Hz "
            f"(median step {attrs['resample_source_step_s']:g} s, largest jitter "
            f"{100 * attrs['resample_max_jitter']:.1f} % of the step; "
            f"{len(filled)} gap(s) interpolated")
    if filled:
        text += " at " + ", ".join(f"{a:g} s ({b:g} s long)" for a, b in filled)
    if split:
        pieces = attrs["resample_pieces"]
        text += (f"; split into {pieces} manoeuvres at " +
                 ", ".join(f"{a:g} s ({b:g} s gap)" for a, b in split))
    return text + f"; filter: {attrs['resample_filter']})"


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
            "Read every manoeuvre of each FILE and store them as /maneuvers/<name> in the "
            "campaign file (added to it if it exists). Formats are recognised from the "
            "content: CSV with a header row or netCDF (one manoeuvre, named by the file "
            "stem), MATLAB v5/v7 and v7.3 and HDF5 (one manoeuvre per top-level struct or "
            "group, named by it, or one of flat vectors named by the file). The kind is "
            "taken from the name's first token (sweep_, 3211_, 2311_, doublet_, "
            "multisine_) unless --kind is given. Trim defaults to the mean of the first "
            "second of data. A name the campaign already holds is refused unless --replace; "
            "with it, the results computed from the old data (frequency responses, models, "
            "verification, ...) are removed."),
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
    p.add_argument("--time", default="time", metavar="NAME",
                   help="name of the time column/field (default: time, or t)")
    p.add_argument("--resample", metavar="RATE|auto",
                   help="put records with clock jitter or missing samples on a uniform grid "
                        "at RATE Hz (auto: the logger's own rate), anti-aliased when RATE "
                        "is below the data rate; a gap longer than "
                        f"{GAP_MAX_STEPS:g} steps splits the record into NAME_a, NAME_b")
    p.add_argument("--replace", action="store_true",
                   help="replace manoeuvres the campaign already holds and remove the "
                        "results computed from them")
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
