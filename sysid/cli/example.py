"""``sysid example-data``: flight-test files written from the truth FMU, for the README's
worked example of ``sysid run --data``."""

from __future__ import annotations

from sysid.flight_test.example import EXAMPLE_SEED, write_example_flight_data


def register(subparsers) -> None:
    p = subparsers.add_parser(
        "example-data", help="write example flight-test files (MAT v7.3) from the truth FMU",
        description="Fly the default hover campaign on the truth FMU and write one file per "
                    "manoeuvre as a test programme would hand it over: p q r phi theta psi, "
                    "accelerometers ax ay az and the four controls, no u v w, on a jittered "
                    "clock (identify them with 'sysid run --data DIR/*.mat --resample auto').")
    p.add_argument("-o", "--output", required=True, metavar="DIR", help="output folder")
    p.add_argument("--seed", type=int, default=EXAMPLE_SEED,
                   help="campaign and clock-jitter seed")
    p.add_argument("--jitter", type=float, default=0.2,
                   help="largest clock error, fraction of the step (default 0.2)")
    p.add_argument("--format", choices=["mat73", "mat5", "hdf5"], default="mat73")
    p.add_argument("-q", "--quiet", action="store_true", help="no progress output")
    p.set_defaults(func=run)


def run(args) -> int:
    paths = write_example_flight_data(args.output, seed=args.seed, jitter=args.jitter,
                                      format=args.format, quiet=args.quiet)
    for path in paths:
        print(path)
    return 0
