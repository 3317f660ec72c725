"""Options shared by several sub-commands (not a command itself: the leading underscore keeps
it out of the command discovery of :mod:`sysid.cli`)."""

from __future__ import annotations

import argparse

from sysid.pipeline.study import TIME_DOMAIN_AUTO, TIME_DOMAIN_METHODS


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


def add_time_domain_method_option(parser: argparse.ArgumentParser, *, default: str | None,
                                  help: str) -> None:
    """``--time-domain-method`` (auto, output-error, filter-error); read it back with
    :func:`time_domain_method`."""
    parser.add_argument("--time-domain-method", default=default, help=help,
                        choices=[TIME_DOMAIN_AUTO,
                                 *(m.replace("_", "-") for m in TIME_DOMAIN_METHODS)])


def time_domain_method(args: argparse.Namespace) -> str | None:
    """The ``time_domain_method`` argument of the library (None when not given)."""
    method = args.time_domain_method
    return None if method is None else method.replace("-", "_")
