"""The report's handling-qualities section: ADS-33E-PRF bandwidth / phase-delay charts and the
stabilisation holds' crossover and margins.

Reads ``/handling_qualities`` and ``/hold_margins`` (``sysid handling-qualities``) when the
campaign has them, else computes them from the campaign
(:func:`sysid.assess.handling_qualities.handling_qualities`,
:func:`sysid.assess.margins.hold_margins`). The charts are those of ADS-33E-PRF for hover and
low speed (target acquisition and tracking; all other MTEs) for pitch, roll and yaw, with the
Level boundaries of :data:`sysid.assess.handling_qualities.ADS33_BOUNDARIES` and one point per
source (data with one-standard-deviation bars from the random error, the truth linearisations,
the identified models).

References
----------
* ADS-33E-PRF, US Army AMCOM, 21 March 2000, 3.3.2.1 (pitch, roll), 3.3.5.1 (yaw).
* docs/methods.md, "Handling qualities and broken-loop margins".
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

import sysid.report.plots as plots
import sysid.report.read as read
from sysid.assess.handling_qualities import (ADS33_BOUNDARIES, ADS33_SOURCE, AXES, MTES,
                                             boundary_bandwidth, handling_qualities)
from sysid.assess.margins import hold_margins
from sysid.core.errors import InputDataError
from sysid.data.campaign import CampaignData
from sysid.report.figures import Context
from sysid.report.page import esc, html_table, num

if TYPE_CHECKING:  # matplotlib is imported at the first figure (plots.new_figure)
    from matplotlib.figure import Figure

__all__ = ["section_handling_qualities", "hq_chart_figure"]

_MTE_LABEL = {"tracking": "target acquisition and tracking", "other": "all other MTEs"}
_MARKERS = {"data": "o", "linearization_full": "s", "linearization": "D"}


def hq_chart_figure(points: Mapping[str, Mapping[str, tuple[float, float, float, float]]],
                    boundaries: Mapping, source: str) -> Figure:
    """ADS-33E-PRF bandwidth / phase-delay charts: rows MTE class, columns axis.

    ``points[axis][source] = (bandwidth, tau_p, bandwidth_std, tau_p_std)`` (rad/s, s);
    ``boundaries`` as :data:`~sysid.assess.handling_qualities.ADS33_BOUNDARIES`.
    """
    fig = plots.new_figure(11.0, 6.6)
    axes_names = list(AXES)
    order = sorted({s for p in points.values() for s in p})
    handles: dict[str, object] = {}
    for r, mte in enumerate(MTES):
        for c, axis in enumerate(axes_names):
            ax = fig.add_subplot(len(MTES), len(axes_names), r * len(axes_names) + c + 1)
            bounds = boundaries[(axis, mte)]
            wmax = max(6.0, 1.2 * max((p[0] for p in points.get(axis, {}).values()
                                       if np.isfinite(p[0])), default=0.0))
            tmax = max(0.4, 1.2 * max((p[1] for p in points.get(axis, {}).values()
                                       if np.isfinite(p[1])), default=0.0))
            tau = np.linspace(0.0, tmax, 200)
            for level, style in (("L1", "-"), ("L2", "--")):
                ax.plot(boundary_bandwidth(bounds[level], tau), tau, color="0.3",
                        linestyle=style, linewidth=1.0)
            ax.text(0.97, 0.04, "Level 1", transform=ax.transAxes, ha="right", fontsize=7)
            ax.text(0.03, 0.93, "Level 3", transform=ax.transAxes, ha="left", fontsize=7)
            for name in order:
                if name not in points.get(axis, {}):
                    continue
                bw, tp, sbw, stp = points[axis][name]
                if not (np.isfinite(bw) and np.isfinite(tp)):
                    continue
                style = plots.color_of(name, order)
                handles[plots.source_label(name)] = ax.errorbar(
                    [bw], [tp], xerr=[sbw] if np.isfinite(sbw) else None,
                    yerr=[stp] if np.isfinite(stp) else None, marker=_MARKERS.get(name, "^"),
                    color=style["color"], linestyle="none", markersize=5, capsize=2)
            ax.set_xlim(0.0, wmax)
            ax.set_ylim(0.0, tmax)
            ax.grid(True, alpha=0.3)
            ax.set_title(f"{axis}: {_MTE_LABEL[mte]}", fontsize=8)
            if r == len(MTES) - 1:
                ax.set_xlabel("ω_BW [rad/s]", fontsize=8)
            if c == 0:
                ax.set_ylabel("τ_p [s]", fontsize=8)
            ax.tick_params(labelsize=7)
    fig.suptitle("ADS-33E-PRF bandwidth and phase delay, hover and low speed "
                 "(solid: Level 1/2, dashed: Level 2/3)", fontsize=9)
    fig.text(0.5, 0.005, source, ha="center", fontsize=6, color="0.4")
    fig.tight_layout(rect=(0, 0.06, 1, 0.96))
    if handles:
        fig.legend(list(handles.values()), list(handles), loc="lower center",
                   ncol=len(handles), fontsize=7, frameon=False, bbox_to_anchor=(0.5, 0.02))
    return fig


#: Variables each stored group must have to be shown as stored (else it is recomputed).
_REQUIRED = {"handling_qualities": ("bandwidth", "bandwidth_std", "tau_p", "tau_p_std",
                                    "omega_180", "bandwidth_phase", "bandwidth_gain",
                                    "coherence_bandwidth_phase", "coherence_tau_p",
                                    "level_tracking", "level_other", "response_type", "pair"),
             "hold_margins": ("gain_crossover", "phase_margin", "gain_margin_db",
                              "phase_crossover", "gain_margin_low_db", "phase_crossover_low")}


def _group_or(ctx: Context, group: str, compute):
    ds = read.dataset(ctx.tree, group)
    if ds is not None and all(v in ds.variables for v in _REQUIRED[group]):
        return ds, f"/{group}"
    try:
        return compute(CampaignData(ctx.tree)), "computed for this report"
    except InputDataError as exc:
        return exc, ""


def _pm(value: float, std: float, fmt: str) -> str:
    text = num(value, fmt)
    return text + (f" ± {num(std, fmt)}" if np.isfinite(std) and np.isfinite(value) else "")


def _hq_part(ctx: Context, hq: xr.Dataset, where: str) -> str:
    points: dict[str, dict] = {}
    rows = []
    for axis in hq["axis"].values:
        axis = str(axis)
        for source in hq["source"].values:
            source = str(source)
            r = hq.sel(axis=axis, source=source)
            bw, tp = float(r["bandwidth"]), float(r["tau_p"])
            points.setdefault(axis, {})[source] = (bw, tp, float(r["bandwidth_std"]),
                                                   float(r["tau_p_std"]))
            rows.append([f"{axis} ({str(r['pair'].values)})", plots.source_label(source),
                         num(float(r["omega_180"]), ".3f"),
                         num(float(r["bandwidth_phase"]), ".3f"),
                         num(float(r["bandwidth_gain"]), ".3f"),
                         _pm(bw, float(r["bandwidth_std"]), ".3f"),
                         _pm(1e3 * tp, 1e3 * float(r["tau_p_std"]), ".1f"),
                         num(float(r["coherence_bandwidth_phase"]), ".2f"),
                         num(float(r["coherence_tau_p"]), ".2f"),
                         *(str(int(r[f"level_{m}"])) if int(r[f"level_{m}"]) else "—"
                           for m in MTES)])
    caption = "ADS-33E-PRF bandwidth / phase-delay charts (hover and low speed)"
    ctx.anchors["table-handling-qualities"] = "handling qualities"
    hold = float(hq.attrs.get("sample_hold_removed_s", 0.0))
    removed = str(hq.attrs.get("sample_hold_removed_from", ""))
    types = sorted({str(t) for t in hq["response_type"].values})
    intro = (f"<p>Attitude responses θ/δ_lon, φ/δ_lat, ψ/δ_ped ({esc(where)}; "
             f"response type {esc(', '.join(types))}: the governing bandwidth is "
             + ("the lesser of the phase and gain bandwidths" if "rate" in types
                else "the phase bandwidth")
             + "). ± one standard deviation from the composite random error; γ² is the "
             "coherence at the phase bandwidth and at 2ω_180."
             + (f" The campaign's {1e3 * hold:.0f} ms sample-and-hold is divided out of "
                f"{esc(removed.replace(',', ', '))}, so every source describes the continuous "
                "helicopter (docs/methods.md)." if hold and removed else "")
             + f" Level boundaries: {esc(ADS33_SOURCE)}.</p>")
    return (intro + ctx.figure("handling_qualities_ads33", caption, hq_chart_figure, points,
                               ADS33_BOUNDARIES, ADS33_SOURCE)
            + html_table(["axis", "source", "ω_180 [rad/s]", "ω_BW phase", "ω_BW gain",
                          "ω_BW [rad/s]", "τ_p [ms]", "γ² at ω_BW phase", "γ² at 2ω_180",
                          "Level (tracking)", "Level (other MTEs)"], rows, "numeric",
                         table_id="table-handling-qualities"))


def _margins_part(ctx: Context, margins: xr.Dataset, where: str) -> str:
    rows = []
    for e in margins["excited"].values:
        for h in margins["hold"].values:
            r = margins.sel(excited=e, hold=h)
            rows.append([str(e), str(h), num(float(r["gain_crossover"]), ".3f"),
                         num(float(r["phase_margin"]), ".1f"),
                         num(float(r["gain_margin_db"]), ".1f"),
                         num(float(r["phase_crossover"]), ".3f"),
                         num(float(r["gain_margin_low_db"]), ".1f"),
                         num(float(r["phase_crossover_low"]), ".3f")])
    ctx.anchors["table-hold-margins"] = "stabilisation holds: crossover and margins"
    return (f"<h3>Stabilisation holds: crossover and margins</h3><p>Each hold broken at its "
            f"control with the other holds closed, on /{esc(margins.attrs.get('model', ''))} "
            f"({esc(where)}); one configuration per sweep axis (that axis keeps a weaker hold). "
            f"Design crossovers: attitude {num(margins.attrs.get('design_crossover'), 'g')}, "
            f"heading {num(margins.attrs.get('heading_crossover'), 'g')}, vertical speed "
            f"{num(margins.attrs.get('vertical_speed_bandwidth'), 'g')} rad/s. The lower gain "
            "margin (negative dB) is the gain reduction that would destabilise a loop around "
            "the unstable airframe.</p>"
            + html_table(["sweep axis", "hold", "crossover [rad/s]", "phase margin [deg]",
                          "gain margin [dB]", "at [rad/s]", "lower gain margin [dB]",
                          "at [rad/s]"], rows, "numeric", table_id="table-hold-margins"))


def section_handling_qualities(ctx: Context) -> str:
    """ADS-33E-PRF charts and table of the attitude responses, and the holds' margins."""
    parts = []
    hq, where = _group_or(ctx, "handling_qualities", handling_qualities)
    # what the campaign cannot give (e.g. no attitude responses, no holds) is omitted
    if not isinstance(hq, Exception):
        parts.append(_hq_part(ctx, hq, where))
    margins, where = _group_or(ctx, "hold_margins", hold_margins)
    if not isinstance(margins, Exception):
        parts.append(_margins_part(ctx, margins, where))
    return "".join(parts)
