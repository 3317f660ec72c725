"""The ``sysid`` command.

Each stage contributes its sub-commands from its own module in this package: a module
``sysid/cli/<stage>.py`` defines ``register(subparsers)`` which adds parsers whose
``func(args) -> int`` does the work. Modules are discovered automatically, so adding a stage
never edits a shared command table.
"""

from __future__ import annotations

import argparse
import importlib
import pkgutil
import sys

from sysid import __version__
from sysid.core.errors import SysidError
from sysid.core.util import numeric_settings


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="sysid",
        description="Rotorcraft system identification on FMI (CIFER-style, open source).",
    )
    parser.add_argument("--version", action="version", version=f"sysid {__version__}")
    subparsers = parser.add_subparsers(dest="command", metavar="COMMAND")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(subparsers)
    return parser


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if not getattr(args, "func", None):
        parser.print_help()
        return 2
    try:
        with numeric_settings():
            return int(args.func(args) or 0)
    except SysidError as exc:
        # A user-caused problem: one clear line, no traceback from inside a library.
        print(f"sysid {args.command}: error: {exc}", file=sys.stderr)
        return 1
    except KeyboardInterrupt:
        print(f"sysid {args.command}: interrupted", file=sys.stderr)
        return 130


if __name__ == "__main__":
    sys.exit(main())
