"""The paper's comparison section: frequency- against time-domain identification (hover).

Runs the hover study with the paper's time-domain estimator, output error (or reuses it:
every stage is cached in reports/hover_output_error; ``--time-domain-method filter-error``,
the toolkit's default, compares against the filter-error model of reports/hover instead),
and writes reports/compare_domains/:

- comparison.txt: the derivative table (paper Tables 2-3: value and Cramer-Rao % per method,
  truth linearisation), sign agreement of the dominant derivatives (conclusion 8), the
  time-domain verification of both models on the 2311 manoeuvres (J_rms and TIC per
  channel), and the fraction of frequencies inside the MUAD envelope per input/output pair
  (from /validation/<model>);
- derivatives.csv, verification.csv, muad.csv: the same numbers for other tools.

    python workflows/compare_domains.py [--time-domain-method output-error|filter-error]
                                        [--study DIR] [-o DIR] [--quiet]
"""

from __future__ import annotations

import argparse
import csv
from pathlib import Path

import numpy as np
import xarray as xr

METHODS = ("frequency_domain", "time_domain")


def comparison(tree: xr.DataTree, verification: str = "2311_*") -> dict:
    """The section's numbers from a finished study's campaign tree."""
    from sysid.assess.comparison import derivative_table, relative_error, sign_agreement
    from sysid.data.campaign import list_maneuvers

    models = {m: tree[f"models/{m}"].to_dataset() for m in METHODS
              if f"models/{m}" in _paths(tree)}
    truth = tree["linearization"].to_dataset() if "linearization" in tree.children else None
    table = derivative_table(models, truth)
    names = [n for n in list_maneuvers(tree, verification) if n in
             tree["verification"].children] if "verification" in tree.children else []
    j_rms = {}
    tic = {}
    for name in names:
        ds = tree[f"verification/{name}"].to_dataset()
        for m in models:
            if m in ds["j_rms"].source.values:
                j_rms[(name, m)] = float(ds["j_rms"].sel(source=m))
                tic[(name, m)] = {str(c): float(ds["tic"].sel(source=m, channel=c))
                                  for c in ds["tic"].channel.values}
    muad = {}
    for m in models:
        try:
            v = tree[f"validation/{m}"].to_dataset()
        except KeyError:
            continue
        if "fraction_inside" not in v:  # validation failed for this model (error attr)
            continue
        frac = v["fraction_inside"].sel(envelope="MUAD")
        for o in frac.output.values:
            for i in frac.input.values:
                val = float(frac.sel(output=o, input=i))
                if np.isfinite(val):
                    muad[(f"{o}/{i}", m)] = val
    return {"table": table, "relative_error": relative_error(table),
            "signs": sign_agreement(table), "j_rms": j_rms, "tic": tic, "muad": muad,
            "maneuvers": names, "models": list(models)}


def _paths(tree: xr.DataTree) -> set[str]:
    return {node.path.lstrip("/") for node in tree.subtree}


def format_comparison(c: dict) -> str:
    from sysid.assess.comparison import format_table

    lines = ["Frequency- against time-domain identification (paper Tables 2-3)", "",
             format_table(c["table"]), ""]
    signs = c["signs"]
    lines.append("Dominant derivatives with the same sign in every method: " + ", ".join(
        f"{p} {'yes' if bool(signs.sel(parameter=p)) else 'NO'}" for p in signs.parameter.values))
    err = c["relative_error"]
    lines.append("Median |error| against the truth linearisation: " + ", ".join(
        f"{m} {100 * float(np.nanmedian(np.abs(err.sel(model=m)))):.0f} %"
        for m in err.model.values))
    lines += ["", "Time-domain verification (guidelines J_rms <= 2, TIC <= 0.25)",
              f"{'manoeuvre':<12}" + "".join(f"{m:>20}" for m in c["models"])]
    for name in c["maneuvers"]:
        lines.append(f"{name:<12}" + "".join(
            f"{c['j_rms'].get((name, m), float('nan')):>20.3f}" for m in c["models"]))
    for m in c["models"]:
        vals = [c["j_rms"][(n, m)] for n in c["maneuvers"] if (n, m) in c["j_rms"]]
        if vals:
            lines.append(f"mean J_rms {m}: {np.mean(vals):.3f}")
    lines += ["", "Fraction of frequencies inside the MUAD envelope per pair",
              f"{'pair':<10}" + "".join(f"{m:>20}" for m in c["models"])]
    pairs = sorted({p for p, _ in c["muad"]})
    for p in pairs:
        lines.append(f"{p:<10}" + "".join(
            f"{c['muad'].get((p, m), float('nan')):>20.2f}" for m in c["models"]))
    return "\n".join(lines)


def write_comparison(c: dict, out: Path) -> Path:
    from sysid.core.util import atomic_path

    out.mkdir(parents=True, exist_ok=True)
    text_path = out / "comparison.txt"
    with atomic_path(text_path) as tmp:
        tmp.write_text(format_comparison(c) + "\n")
    table = c["table"]
    rows = [["parameter", "model", "value", "cramer_rao_percent", "truth"]]
    for p in table.parameter.values:
        for m in table.model.values:
            cell = table.sel(parameter=p, model=m)
            rows.append([str(p), str(m), float(cell["value"]),
                         float(cell["cramer_rao_percent"]), float(table["truth"].sel(parameter=p))])
    _csv(out / "derivatives.csv", rows)
    channels = sorted({ch for d in c["tic"].values() for ch in d})
    rows = [["maneuver", "model", "j_rms", *[f"tic_{ch}" for ch in channels]]]
    for (n, m), j in c["j_rms"].items():
        rows.append([n, m, j, *[c["tic"][(n, m)].get(ch, "") for ch in channels]])
    _csv(out / "verification.csv", rows)
    _csv(out / "muad.csv", [["pair", "model", "fraction_inside"]] +
         [[p, m, v] for (p, m), v in sorted(c["muad"].items())])
    return text_path


def _csv(path: Path, rows) -> None:
    from sysid.core.util import atomic_path

    with atomic_path(path) as tmp:
        with open(tmp, "w", newline="") as fh:
            csv.writer(fh).writerows(rows)


def main(argv=None) -> int:
    from sysid.pipeline.study import StudySettings, run_study, study_tree

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--time-domain-method", default="output-error",
                        choices=("output-error", "filter-error"),
                        help="time-domain estimator (default: output error, the paper's)")
    parser.add_argument("--study", default=None, help="hover study folder (default "
                        "reports/hover_output_error, or reports/hover for filter error)")
    parser.add_argument("-o", "--output", default="reports/compare_domains")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    method = args.time_domain_method.replace("-", "_")
    study = args.study or ("reports/hover_output_error" if method == "output_error"
                           else "reports/hover")
    run_study(study, StudySettings(airspeed_kt=0.0, structure="hover_6dof",
                                   time_domain_method=method), quiet=args.quiet)
    c = comparison(study_tree(study))
    path = write_comparison(c, Path(args.output))
    print(format_comparison(c))
    print(path.resolve())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
