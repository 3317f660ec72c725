"""Options shared by several sub-commands (not a command itself: the leading underscore keeps
it out of the command discovery of :mod:`sysid.cli`)."""

from __future__ import annotations

import argparse


def add_transient_options(parser: argparse.ArgumentParser) -> None:
    """``--transient-states`` and ``--no-transient-states`` of the frequency responses."""
    parser.add_argument("--transient-states", default="auto",
                        help="comma-separated measured states whose segment start/end leakage "
                             "the frequency responses condition out (default 'auto': those of "
                             "u,v,w,p,q,r,phi,theta that the records carry)")
    parser.add_argument("--no-transient-states", action="store_true",
                        help="frequency responses without leakage conditioning (the paper's "
                             "method)")


def transient_states(args: argparse.Namespace) -> str:
    """The ``transient_states`` argument of the library from the parsed options ("" = off)."""
    return "" if args.no_transient_states else args.transient_states
