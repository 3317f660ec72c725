"""The study in forward flight (default 80 kt), plus the cross-control coherence section.

Runs the same chain as the hover study at the given airspeed with the forward-flight
structure ``forward_6dof`` into reports/forward_flight/ (same as ``sysid run
forward-flight``), then writes the paper's conclusion 1 as its own section next to the
report, reports/forward_flight/cross_control.html (self-contained) with
cross_control.png and cross_control.csv:

- the campaign's mean cross-control coherence (Eq. 8) per sweep axis (how correlated the
  secondary-axis holds made the controls), in hover and in forward flight;
- its effect: the conditioned (MIMO, Eq. 10-13) and the unconditioned single-input responses
  against the truth linearisation's frequency response for the main input/output pairs,
  as RMS magnitude (dB) and phase (deg) errors over 0.3-8 rad/s where the coherence is at
  least 0.6. The truth linearisation is quasi-steady (no rotor, inflow or actuator lag), so
  both estimates differ from it near the top of the band; the comparison between the two
  columns is what shows the effect of conditioning.

The hover study is read from reports/hover (run there first, cached, when missing).

    python workflows/forward_flight.py [--speed KT] [--hover DIR] [-o DIR] [--quiet]
"""

from __future__ import annotations

import argparse
import base64
import csv
import html
import io
from pathlib import Path

import numpy as np
import xarray as xr

#: (output, input) pairs compared: on-axis responses and the main couplings.
PAIRS = (("q", "lon"), ("p", "lat"), ("w", "col"), ("r", "ped"), ("p", "lon"), ("q", "lat"),
         ("r", "col"), ("v", "ped"))
BAND = (0.3, 8.0)  #: rad/s
COHERENCE_MIN = 0.6


def conditioning_effect(tree: xr.DataTree, pairs=PAIRS, band=BAND,
                        coherence_min=COHERENCE_MIN) -> xr.Dataset:
    """RMS magnitude/phase error of conditioned vs unconditioned responses against truth.

    Returns (estimate = conditioned|unconditioned, pair): ``mag_rms_db``, ``phase_rms_deg``
    and ``n_points`` (frequencies used: in ``band`` with coherence >= ``coherence_min`` in
    the conditioned estimate; the same points for both).
    """
    from sysid.models import frequency_response

    mimo = tree["frequency_response"].to_dataset()
    siso = tree["frequency_response_siso"].to_dataset()
    # The full linearisation (rotor, inflow and actuator states) when the campaign has it:
    # the quasi-steady one lacks their lag, which would swamp the effect of conditioning.
    group = "linearization_full" if "linearization_full" in tree else "linearization"
    lin = tree[group].to_dataset()
    omega = mimo.frequency.values
    truth = frequency_response(lin, omega)
    names, mag, phase, npts = [], [], [], []
    for out, inp in pairs:
        if out not in mimo.output.values or inp not in mimo.input.values:
            continue
        coh_var = "partial_coherence" if "partial_coherence" in mimo else "coherence"
        coh = mimo[coh_var].sel(output=out, input=inp).values
        use = (omega >= band[0]) & (omega <= band[1]) & (coh >= coherence_min)
        t = truth.sel(output=out, input=inp).values[use]
        row_mag, row_phase = [], []
        for est in (mimo, siso.interp(frequency=omega) if not np.array_equal(
                siso.frequency.values, omega) else siso):
            h = est["H"].sel(output=out, input=inp).values[use]
            ok = np.isfinite(h) & (np.abs(h) > 0) & (np.abs(t) > 0)
            dm = 20 * np.log10(np.abs(h[ok]) / np.abs(t[ok]))
            dp = np.degrees(np.angle(h[ok] / t[ok]))
            row_mag.append(float(np.sqrt(np.mean(dm**2))) if dm.size else np.nan)
            row_phase.append(float(np.sqrt(np.mean(dp**2))) if dp.size else np.nan)
        names.append(f"{out}/{inp}")
        mag.append(row_mag)
        phase.append(row_phase)
        npts.append(int(use.sum()))
    dims = ("pair", "estimate")
    return xr.Dataset(
        {"mag_rms_db": (dims, np.array(mag), {"units": "dB"}),
         "phase_rms_deg": (dims, np.array(phase), {"units": "deg"}),
         "n_points": (("pair",), np.array(npts))},
        coords={"pair": names, "estimate": ["conditioned", "unconditioned"]},
        attrs={"band_rad_s": list(band), "coherence_min": coherence_min})


def _png(fig) -> str:
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=90)
    return base64.b64encode(buf.getvalue()).decode()


def cross_control_section(studies: dict[str, xr.DataTree], out_dir: Path) -> Path:
    """Write cross_control.html/.png/.csv for the studies ``{label: campaign tree}``."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from sysid.core.units import CONTROLS

    out_dir.mkdir(parents=True, exist_ok=True)
    effects = {k: conditioning_effect(t) for k, t in studies.items()}
    rows_csv = []
    parts = ["<h1>Cross-control coherence and its effect (paper conclusion 1)</h1>"]
    # 1. Mean cross-control coherence per sweep axis.
    parts.append("<h2>Mean cross-control coherence of the sweeps (Eq. 8, 0.5-10 rad/s; "
                 "guideline &lt; 0.5)</h2>")
    for label, tree in studies.items():
        try:
            mean = tree["cross_control_coherence"].to_dataset()["mean_cross_coherence"]
        except KeyError:
            parts.append(f"<p>{html.escape(label)}: no cross-control summary in the campaign</p>")
            continue
        head = "".join(f"<th>{c}</th>" for c in CONTROLS)
        body = ""
        for axis in mean.axis.values:
            cells = ""
            for other in CONTROLS:
                if other == axis:
                    cells += "<td>-</td>"
                    continue
                v = float(mean.sel(axis=axis, input=axis, input_j=other))
                style = ' style="background:#fdd"' if v >= 0.5 else ""
                cells += f"<td{style}>{v:.2f}</td>"
                rows_csv.append([label, "cross_coherence", f"{axis} sweeps", other, f"{v:.4f}",
                                 ""])
            body += f"<tr><th>{axis} sweeps</th>{cells}</tr>"
        parts.append(f"<h3>{html.escape(label)}</h3><table><tr><th></th>{head}</tr>{body}"
                     "</table>")
    # 2. Effect of conditioning against the truth linearisation.
    parts.append(f"<h2>Conditioned vs unconditioned responses against the truth "
                 f"linearisation ({BAND[0]:g}-{BAND[1]:g} rad/s, coherence &ge; "
                 f"{COHERENCE_MIN:g})</h2>")
    head = ("<tr><th>pair</th>" + "".join(
        f"<th colspan=2>{html.escape(k)}: |H| RMS error dB</th>"
        f"<th colspan=2>{html.escape(k)}: phase RMS error deg</th>" for k in effects) +
        "</tr><tr><th></th>" + "<th>cond.</th><th>uncond.</th>" * 2 * len(effects) + "</tr>")
    pairs = []
    for e in effects.values():
        pairs += [p for p in e.pair.values if p not in pairs]
    body = ""
    for p in pairs:
        cells = ""
        for label, e in effects.items():
            if p not in e.pair.values:
                cells += "<td>-</td>" * 4
                continue
            row = e.sel(pair=p)
            for var in ("mag_rms_db", "phase_rms_deg"):
                c, u = (float(row[var].sel(estimate=k)) for k in ("conditioned",
                                                                  "unconditioned"))
                better = ' style="background:#dfd"' if c < u else ""
                cells += f"<td{better}>{c:.2f}</td><td>{u:.2f}</td>"
                rows_csv.append([label, var, p, "conditioned", f"{c:.4f}",
                                 int(row["n_points"])])
                rows_csv.append([label, var, p, "unconditioned", f"{u:.4f}",
                                 int(row["n_points"])])
        body += f"<tr><th>{p}</th>{cells}</tr>"
    parts.append(f"<table>{head}{body}</table><p>Green: conditioning reduced the error.</p>")
    # Figure: per study, grouped bars of the magnitude and phase errors.
    fig, axes = plt.subplots(2, len(effects), figsize=(6 * len(effects), 6), squeeze=False)
    for j, (label, e) in enumerate(effects.items()):
        x = np.arange(e.sizes["pair"])
        for i, (var, unit) in enumerate((("mag_rms_db", "dB"), ("phase_rms_deg", "deg"))):
            ax = axes[i, j]
            ax.bar(x - 0.2, e[var].sel(estimate="conditioned"), 0.4, label="conditioned")
            ax.bar(x + 0.2, e[var].sel(estimate="unconditioned"), 0.4, label="unconditioned")
            ax.set_xticks(x, e.pair.values, fontsize=8)
            ax.set_ylabel(f"RMS error vs truth, {unit}")
            ax.set_title(f"{label}: {'magnitude' if i == 0 else 'phase'}", fontsize=10)
            ax.legend(fontsize=8)
    fig.tight_layout()
    png = out_dir / "cross_control.png"
    fig.savefig(png, dpi=90)
    parts.append(f'<img alt="conditioning effect" src="data:image/png;base64,{_png(fig)}">')
    plt.close(fig)
    style = ("<style>body{font-family:sans-serif;margin:2em}table{border-collapse:collapse;"
             "margin:1em 0}td,th{border:1px solid #aaa;padding:3px 8px;text-align:right}"
             "</style>")
    page = (f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>Cross-control "
            f"coherence</title>{style}</head><body>{''.join(parts)}</body></html>")
    from sysid.core.util import atomic_path

    path = out_dir / "cross_control.html"
    with atomic_path(path) as tmp:
        tmp.write_text(page)
    with atomic_path(out_dir / "cross_control.csv") as tmp:
        with open(tmp, "w", newline="") as fh:
            w = csv.writer(fh)
            w.writerow(["study", "quantity", "row", "column", "value", "n_points"])
            w.writerows(rows_csv)
    return path


def main(argv=None) -> int:
    from sysid.pipeline.study import StudySettings, run_study, study_tree

    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--speed", type=float, default=80.0)
    parser.add_argument("-o", "--output", default="reports/forward_flight")
    parser.add_argument("--hover", default="reports/hover", help="hover study folder")
    parser.add_argument("--quiet", action="store_true")
    args = parser.parse_args(argv)
    out = Path(args.output)
    report = run_study(out, StudySettings(airspeed_kt=args.speed, structure="forward_6dof"),
                       quiet=args.quiet)
    run_study(args.hover, StudySettings(airspeed_kt=0.0, structure="hover_6dof"),
              quiet=args.quiet)
    studies = {"hover": study_tree(args.hover), f"{args.speed:g} kt": study_tree(out)}
    section = cross_control_section(studies, out)
    print(report.resolve())
    print(section.resolve())
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
