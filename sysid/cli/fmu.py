"""``sysid build``, ``sysid trim`` and ``sysid linearize``: the truth helicopter FMU."""

from __future__ import annotations

import argparse

from sysid.core.kinematics import FORCE_LETTER
from sysid.truth import build_fmu, linearize, trim

#: Order of the derivative tables: force/moment rows, state and control columns.
_ROWS = ("u", "v", "w", "p", "q", "r")
_CONTROLS = ("lon", "lat", "col", "ped")


def _cmd_build(args: argparse.Namespace) -> int:
    print(build_fmu(force=args.force, fmi_version=args.fmi))
    return 0


def _cmd_trim(args: argparse.Namespace) -> int:
    print(trim(args.speed).table())
    return 0


def _table(ds, columns, title: str) -> list[str]:
    value = ds["value"]
    lines = [title, f"{'':>4}" + "".join(f"{c:>12}" for c in columns)]
    for row in _ROWS:
        cells = []
        for col in columns:
            name = f"{FORCE_LETTER[row]}_{col}"
            cells.append(f"{float(value.sel(parameter=name)):12.4g}")
        lines.append(f"{FORCE_LETTER[row]:>4}" + "".join(cells))
    return lines


def _eigen_lines(ev, title: str) -> list[str]:
    lines = [title]
    for e in ev:
        wn = abs(e)
        zeta = -e.real / wn if wn > 0 else float("nan")
        kind = f"wn {wn:7.3f} rad/s, zeta {zeta:6.3f}" if abs(e.imag) > 1e-9 else ""
        lines.append(f"  {e.real:10.4f} {e.imag:+10.4f}j   {kind}")
    return lines


def _cmd_linearize(args: argparse.Namespace) -> int:
    lin = linearize(trim(args.speed))
    ds = lin.quasi_steady
    out = [f"Quasi-steady 6-DoF derivatives at {ds.attrs['flight_condition']} "
           "(analysis units: ft/s, deg/s, deg, %; rigid-body terms removed)", ""]
    out += _table(ds, _ROWS, "Stability derivatives")
    out.append("")
    out += _table(ds, _CONTROLS, "Control derivatives (per % of travel)")
    out.append("")
    full = lin.full
    out += _eigen_lines(lin.eigenvalues_reduced, "Eigenvalues, quasi-steady 6-DoF model (1/s)")
    out.append("")
    out += _eigen_lines(lin.eigenvalues_full,
                        f"Eigenvalues, full model ({full.sizes['state']} states) (1/s)")
    print("\n".join(out))
    return 0


def register(subparsers) -> None:
    """Add ``build``, ``trim`` and ``linearize`` to the ``sysid`` command."""
    p = subparsers.add_parser("build", help="build the truth helicopter FMU and print its path",
                              description="Build the truth helicopter FMU from fmus/ with the "
                                          "machine's C compiler (cached by source hash).")
    p.add_argument("--force", action="store_true", help="rebuild even if cached")
    p.add_argument("--fmi", type=int, choices=(2, 3), default=2,
                   help="FMI version of the FMU (default 2; both carry ME and CS)")
    p.set_defaults(func=_cmd_build)

    p = subparsers.add_parser("trim", help="trim the helicopter and print the trim table",
                              description="Steady, level, zero-sideslip trim (paper Table 1).")
    p.add_argument("--speed", type=float, default=0.0, metavar="KT",
                   help="true airspeed in knots (default 0: hover)")
    p.set_defaults(func=_cmd_trim)

    p = subparsers.add_parser("linearize", help="print derivative and eigenvalue tables",
                              description="Linearise at trim: quasi-steady 6-DoF derivatives "
                                          "and the eigenvalues of the full and reduced models.")
    p.add_argument("--speed", type=float, default=0.0, metavar="KT",
                   help="true airspeed in knots (default 0: hover)")
    p.set_defaults(func=_cmd_linearize)


__all__ = ["register"]
