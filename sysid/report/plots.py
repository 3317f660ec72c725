"""Matplotlib figures of the report, one function per figure kind (headless Agg canvas).

Every function takes plain, already extracted data (numpy arrays keyed by name) and returns a
:class:`matplotlib.figure.Figure` bound to an Agg canvas; :func:`png_bytes` renders it. No
pyplot state is used, so figures are independent of any interactive backend, deterministic
(fixed colours per source, no timestamps in the PNG) and safe to build in a loop.

Figure kinds and the figures of the paper (*Comparison of frequency and time domain identification of a helicopter in hover*) they reproduce:

- :func:`inputs_figure` -- the four controls of one sweep manoeuvre (Figure 1).
- :func:`conditioning_figure` -- conditioned vs unconditioned magnitude or phase of the main
  pairs (Figures 2 and 3), and partial vs ordinary coherence.
- :func:`cross_coherence_figure` -- cross-control coherence of every pair of inputs (Eq. 8).
- :func:`pair_figure` -- Bode magnitude, phase and coherence of one input/output pair with the
  models overlaid, and the Eq. 20 mismatch against the MUAD bounds (Figures 4-15).
- :func:`time_response_figure` -- time-domain verification overlays (Figures 16-19).
"""

from __future__ import annotations

import io
from collections.abc import Mapping, Sequence
from typing import TYPE_CHECKING

import numpy as np

from sysid.core.guidelines import COHERENCE_MIN

if TYPE_CHECKING:  # matplotlib itself is imported at the first figure (new_figure)
    from matplotlib.figure import Figure

__all__ = [
    "DPI",
    "new_figure",
    "color_of",
    "png_bytes",
    "render_png",
    "inputs_figure",
    "conditioning_figure",
    "leakage_figure",
    "cross_coherence_figure",
    "pair_figure",
    "time_response_figure",
    "aligned_phase",
    "source_label",
]

#: Resolution of the PNG files (modest, for a fast report of a few dozen figures).
DPI = 96
#: Coherence guideline drawn on every coherence axis.
COHERENCE_GUIDELINE = COHERENCE_MIN

#: Fixed colours and line styles per source, so every figure uses the same legend.
_STYLE = {
    "data": {"color": "black", "linestyle": "none", "marker": ".", "markersize": 3.0},
    "truth": {"color": "black", "linestyle": "-", "linewidth": 1.4},
    "linearization": {"color": "0.45", "linestyle": "--", "linewidth": 1.3},
    "frequency_domain": {"color": "tab:blue", "linestyle": "-", "linewidth": 1.3},
    "time_domain": {"color": "tab:red", "linestyle": "-.", "linewidth": 1.3},
    "unconditioned": {"color": "tab:orange", "linestyle": "-", "linewidth": 1.0},
}
_EXTRA_COLORS = ("tab:green", "tab:purple", "tab:brown", "tab:pink", "tab:olive", "tab:cyan")
_PALETTE = ("tab:blue", "tab:red", "tab:green", "tab:purple", "tab:brown", "tab:olive",
            "tab:cyan", "tab:pink")
_CONTROL_LABELS = {"lon": "δ_lon", "lat": "δ_lat", "col": "δ_col", "ped": "δ_ped"}


def color_of(name: str, order: Sequence[str] = ()) -> dict:
    """Line style of a source: fixed for the known ones, else by position in ``order``."""
    if name in _STYLE:
        return dict(_STYLE[name])
    k = list(order).index(name) if name in order else sum(map(ord, name))
    return {"color": _EXTRA_COLORS[k % len(_EXTRA_COLORS)], "linestyle": ":", "linewidth": 1.3}


def source_label(name: str) -> str:
    """Legend label of a source name (``linearization`` -> ``truth linearisation``)."""
    return {"linearization": "truth linearisation", "data": "composite data",
            "truth": "truth (measured)"}.get(name, name.replace("_", " "))


def new_figure(width: float, height: float) -> Figure:
    """A Figure (inches) on an Agg canvas. matplotlib is imported here, at the first figure:
    a process that draws none (a batch worker of a quick study) does not pay its 0.3 s."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg
    from matplotlib.figure import Figure

    fig = Figure(figsize=(width, height), dpi=DPI)
    FigureCanvasAgg(fig)
    return fig


def png_bytes(fig: Figure) -> bytes:
    """The figure as PNG bytes (no metadata timestamp, so equal inputs give equal bytes)."""
    buf = io.BytesIO()
    fig.savefig(buf, format="png", dpi=DPI, metadata={"Software": None})
    return buf.getvalue()


def render_png(builder, args: tuple) -> bytes:
    """PNG bytes of ``builder(*args)``, one of this module's figure functions.

    Module-level so that the report can hand it, with plain data, to worker processes. The
    figure is left to the garbage collector: clearing it first (every axis reset) took a
    quarter of a Bode figure's time for 7 MiB less peak over 25 figures.
    """
    return png_bytes(builder(*args))


def aligned_phase(phase_deg: np.ndarray, reference_deg: np.ndarray | None = None) -> np.ndarray:
    """Unwrapped phase (deg), shifted by whole turns to lie on the branch of ``reference_deg``.

    NaN points are kept as NaN and skipped by the unwrapping. Without a reference the first
    valid point is put in (-180, 180].
    """
    phase = np.asarray(phase_deg, dtype=float)
    out = np.full_like(phase, np.nan)
    ok = np.isfinite(phase)
    if not ok.any():
        return out
    out[ok] = np.degrees(np.unwrap(np.radians(phase[ok])))
    if reference_deg is not None:
        diff = out - np.asarray(reference_deg, dtype=float)
        diff = diff[np.isfinite(diff)]
        shift = np.round(np.median(diff) / 360.0) if diff.size else 0.0
    else:
        first = out[ok][0]
        shift = np.ceil((first - 180.0) / 360.0)
    return out - 360.0 * shift


def inputs_figure(time: np.ndarray, controls: Mapping[str, np.ndarray], title: str) -> Figure:
    """The four controls of one manoeuvre, one axis each (paper Figure 1)."""
    names = list(controls)
    fig = new_figure(7.5, 1.35 * len(names) + 0.6)
    axes = fig.subplots(len(names), 1, sharex=True, squeeze=False)[:, 0]
    for ax, name in zip(axes, names):
        ax.plot(time, controls[name], color="tab:blue", linewidth=0.8)
        ax.set_ylabel(f"{_CONTROL_LABELS.get(name, name)} [%]")
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.11, right=0.98, top=0.93, bottom=0.09, hspace=0.12)
    return fig


def conditioning_figure(panels: Mapping[str, Mapping[str, np.ndarray]], omega: np.ndarray,
                        quantity: str) -> Figure:
    """Conditioned vs unconditioned responses of the main pairs (paper Figures 2-3).

    ``panels`` maps a pair name (``"q/lon"``) to curves: ``conditioned``, ``unconditioned``
    and optionally ``linearization`` (complex responses) for ``quantity`` ``"magnitude"``
    (dB) or ``"phase"`` (deg); or ``partial`` and ``ordinary`` coherences for
    ``quantity == "coherence"``.
    """
    n = len(panels)
    ncol = 3 if n > 4 else 2 if n > 1 else 1
    nrow = -(-n // ncol)
    height = 2.4 * nrow + 0.6
    fig = new_figure(3.3 * ncol + 0.4, height)
    axes = fig.subplots(nrow, ncol, squeeze=False).ravel()
    for ax, (pair, curves) in zip(axes, panels.items()):
        out, inp = pair.split("/")
        if quantity == "coherence":
            ax.plot(omega, curves["partial"], label="partial (conditioned)",
                    **color_of("frequency_domain"))
            ax.plot(omega, curves["ordinary"], label="ordinary (SISO)",
                    **color_of("unconditioned"))
            ax.axhline(COHERENCE_GUIDELINE, color="0.5", linewidth=0.8, linestyle=":")
            ax.set_ylim(0.0, 1.05)
            ax.set_ylabel("γ²")
        else:
            ref = None
            for key, label in (("conditioned", "conditioned"),
                               ("unconditioned", "unconditioned (SISO)"),
                               ("linearization", "truth linearisation")):
                if key not in curves:
                    continue
                style = color_of({"conditioned": "frequency_domain"}.get(key, key))
                H = np.asarray(curves[key])
                if quantity == "magnitude":
                    y = 20.0 * np.log10(np.abs(H))
                else:
                    y = aligned_phase(np.angle(H, deg=True), ref)
                    ref = y if ref is None else ref
                ax.plot(omega, y, label=label, **style)
            ax.set_ylabel("magnitude [dB]" if quantity == "magnitude" else "phase [deg]")
        ax.set_xscale("log")
        ax.set_title(f"{out}/{_CONTROL_LABELS.get(inp, inp)}", fontsize=9)
        ax.grid(True, which="both", alpha=0.25)
        ax.set_xlabel("ω [rad/s]")
    for ax in axes[n:]:
        ax.set_visible(False)
    axes[0].legend(fontsize=7, loc="best")
    fig.subplots_adjust(left=0.08, right=0.98, top=1.0 - 0.3 / height, bottom=0.5 / height,
                        hspace=0.55, wspace=0.32)
    return fig


def leakage_figure(panels: Mapping[str, Mapping[str, np.ndarray]], omega: np.ndarray,
                   coherence: Mapping[str, np.ndarray]) -> Figure:
    """Composite responses with and without leakage conditioning, one column per pair:
    magnitude (dB) above phase (deg).

    ``panels`` maps a pair (``"q/lon"``) to complex curves ``leakage_free`` (the default
    estimate), ``plain`` (without the transient terms) and optionally ``linearization``;
    ``coherence`` maps the pair to the default estimate's partial coherence, whose points
    below the guideline are drawn faint.
    """
    n = len(panels)
    height = 5.0
    fig = new_figure(3.0 * n + 0.5, height)
    axes = fig.subplots(2, n, squeeze=False)
    styles = (("linearization", "truth linearisation", color_of("linearization")),
              ("plain", "without leakage conditioning", color_of("unconditioned")),
              ("leakage_free", "leakage-free (default)", color_of("frequency_domain")))
    for col, (pair, curves) in enumerate(panels.items()):
        out, inp = pair.split("/")
        weak = np.asarray(coherence.get(pair, np.ones_like(omega))) < COHERENCE_GUIDELINE
        ref = None
        for key, label, style in styles:
            if key not in curves:
                continue
            H = np.asarray(curves[key])
            mag = 20.0 * np.log10(np.abs(H))
            phase = aligned_phase(np.angle(H, deg=True), ref)
            ref = phase if ref is None else ref
            if key != "linearization":
                mag, phase = np.where(weak, np.nan, mag), np.where(weak, np.nan, phase)
            axes[0, col].plot(omega, mag, label=label, **style)
            axes[1, col].plot(omega, phase, label=label, **style)
        axes[0, col].set_title(f"{out}/{_CONTROL_LABELS.get(inp, inp)}", fontsize=9)
        axes[0, col].set_ylabel("magnitude [dB]")
        axes[1, col].set_ylabel("phase [deg]")
        for ax in axes[:, col]:
            ax.set_xscale("log")
            ax.grid(True, which="both", alpha=0.25)
        axes[1, col].set_xlabel("ω [rad/s]")
    axes[0, 0].legend(fontsize=7, loc="best")
    fig.subplots_adjust(left=0.06, right=0.99, top=0.94, bottom=0.1, hspace=0.3, wspace=0.35)
    return fig


def cross_coherence_figure(omega: np.ndarray, curves: Mapping[str, np.ndarray],
                           threshold: float = 0.5) -> Figure:
    """Cross-control coherence (Eq. 8) of every pair of inputs, with the 0.5 guideline."""
    fig = new_figure(7.5, 3.2)
    ax = fig.add_subplot(1, 1, 1)
    for k, (name, values) in enumerate(curves.items()):
        ax.plot(omega, values, label=name, color=_PALETTE[k % len(_PALETTE)], linewidth=1.0)
    ax.axhline(threshold, color="0.4", linestyle=":", linewidth=0.9,
               label=f"guideline {threshold:g}")
    ax.set_xscale("log")
    ax.set_ylim(0.0, 1.05)
    ax.set_xlabel("ω [rad/s]")
    ax.set_ylabel("cross-control coherence")
    ax.grid(True, which="both", alpha=0.25)
    ax.legend(fontsize=7, ncol=4, loc="upper left")
    fig.subplots_adjust(left=0.09, right=0.98, top=0.95, bottom=0.15)
    return fig


def pair_figure(pair: str, omega: np.ndarray, data: np.ndarray,
                coherence: Mapping[str, np.ndarray], models: Mapping[str, np.ndarray],
                mismatch: Mapping[str, tuple[np.ndarray, np.ndarray]],
                bounds: Mapping[str, np.ndarray], counted: np.ndarray | None = None) -> Figure:
    """Identification of one input/output pair (paper Figures 4-15).

    Top to bottom: magnitude (dB) and phase (deg) of the composite data with every model
    overlaid; coherence (``coherence`` maps a label to values, e.g. partial and ordinary);
    the Eq. 20 mismatch magnitude and phase of each model with the envelope ``bounds``
    (``magnitude_upper``, ``magnitude_lower``, ``phase_upper``, ``phase_lower``). Data points
    below the coherence guideline are drawn faded; ``counted`` marks the frequencies that
    count for the envelope check.
    """
    order = list(models)
    fig = new_figure(7.5, 9.4)
    gs = fig.add_gridspec(5, 1, height_ratios=[1.2, 1.2, 0.7, 0.9, 0.9], hspace=0.12)
    ax_m, ax_p, ax_c, ax_em, ax_ep = (fig.add_subplot(gs[k]) for k in range(5))
    for ax in (ax_m, ax_p, ax_c, ax_em):
        ax.sharex(ax_ep)
        ax.tick_params(labelbottom=False)
    data = np.asarray(data)
    good = np.ones(omega.shape, bool) if counted is None else np.asarray(counted, bool)
    mag = 20.0 * np.log10(np.abs(data))
    ph = aligned_phase(np.angle(data, deg=True))
    faded = dict(color_of("data"), alpha=0.25)
    ax_m.plot(omega[~good], mag[~good], **faded)
    ax_p.plot(omega[~good], ph[~good], **faded)
    ax_m.plot(omega[good], mag[good], label=source_label("data"), **color_of("data"))
    ax_p.plot(omega[good], ph[good], **color_of("data"))
    for name, H in models.items():
        style = color_of(name, order)
        H = np.asarray(H)
        ax_m.plot(omega, 20.0 * np.log10(np.abs(H)), label=source_label(name), **style)
        ax_p.plot(omega, aligned_phase(np.angle(H, deg=True), ph), **style)
    for k, (label, values) in enumerate(coherence.items()):
        ax_c.plot(omega, values, label=label,
                  color=("black", "tab:orange", "tab:green")[k % 3], linewidth=1.0)
    ax_c.axhline(COHERENCE_GUIDELINE, color="0.5", linestyle=":", linewidth=0.8)
    ax_c.set_ylim(0.0, 1.05)
    for key, ax in (("magnitude", ax_em), ("phase", ax_ep)):
        ax.fill_between(omega, bounds[f"{key}_lower"], bounds[f"{key}_upper"],
                        color="tab:green", alpha=0.12, linewidth=0, label="MUAD")
        ax.plot(omega, bounds[f"{key}_upper"], color="tab:green", linewidth=0.8)
        ax.plot(omega, bounds[f"{key}_lower"], color="tab:green", linewidth=0.8)
    for name, (emag, eph) in mismatch.items():
        style = color_of(name, order)
        ax_em.plot(omega, np.where(good, emag, np.nan), **style)
        ax_ep.plot(omega, np.where(good, eph, np.nan), **style)
    _limit(ax_em, bounds["magnitude_lower"], bounds["magnitude_upper"], mismatch, 0)
    _limit(ax_ep, bounds["phase_lower"], bounds["phase_upper"], mismatch, 1)
    out, inp = pair.split("/")
    ax_m.set_title(f"{out}/{_CONTROL_LABELS.get(inp, inp)}", fontsize=10)
    ax_m.set_ylabel("magnitude [dB]")
    ax_p.set_ylabel("phase [deg]")
    ax_c.set_ylabel("γ²")
    ax_em.set_ylabel("mismatch [dB]")
    ax_ep.set_ylabel("mismatch [deg]")
    ax_ep.set_xlabel("ω [rad/s]")
    ax_ep.set_xscale("log")
    for ax in (ax_m, ax_p, ax_c, ax_em, ax_ep):
        ax.grid(True, which="both", alpha=0.25)
    ax_m.legend(fontsize=7, loc="best")
    ax_c.legend(fontsize=7, loc="lower left")
    ax_em.legend(fontsize=7, loc="upper left")
    fig.subplots_adjust(left=0.11, right=0.98, top=0.96, bottom=0.06)
    return fig


def _limit(ax, lower, upper, mismatch, index) -> None:
    """Y-limits that show the whole envelope and the mismatch curves, clipped to 3x the
    envelope span so one diverging model does not flatten the plot."""
    lo = float(np.nanmin(lower))
    hi = float(np.nanmax(upper))
    values = [np.asarray(m[index], float) for m in mismatch.values()]
    finite = np.concatenate([v[np.isfinite(v)] for v in values]) if values else np.array([])
    span = hi - lo
    if finite.size:
        lo = max(min(lo, float(finite.min())), lo - 1.5 * span)
        hi = min(max(hi, float(finite.max())), hi + 1.5 * span)
    pad = 0.05 * (hi - lo)
    ax.set_ylim(lo - pad, hi + pad)


def time_response_figure(time: np.ndarray, inputs: Mapping[str, np.ndarray],
                         channels: Mapping[str, Mapping[str, np.ndarray]],
                         units: Mapping[str, str], title: str,
                         tic: Mapping[str, Mapping[str, float]] | None = None) -> Figure:
    """Time-domain verification of one manoeuvre (paper Figures 16-19).

    ``inputs`` maps a control name to its time history (drawn first); ``channels`` maps an
    output channel to ``{source: values}`` (``truth`` is the measured/FMU response, the other
    sources the models). ``tic`` (``{source: {channel: TIC}}``) is written into the legend.
    """
    n = len(inputs) + len(channels)
    fig = new_figure(7.5, 1.45 * n + 0.7)
    axes = fig.subplots(n, 1, sharex=True, squeeze=False)[:, 0]
    k = 0
    for name, values in inputs.items():
        axes[k].plot(time, values, color="tab:blue", linewidth=0.9)
        axes[k].set_ylabel(f"{_CONTROL_LABELS.get(name, name)} [%]")
        k += 1
    for name, sources in channels.items():
        ax = axes[k]
        order = list(sources)
        for source, values in sources.items():
            label = source_label(source)
            if tic and source in tic and name in tic[source]:
                label += f" (TIC {tic[source][name]:.3f})"
            style = color_of(source, order)
            style.pop("marker", None)
            style.pop("markersize", None)
            ax.plot(time, values, label=label, **style)
        ax.set_ylabel(f"{name} [{units.get(name, '')}]")
        ax.legend(fontsize=6.5, loc="upper right")
        k += 1
    for ax in axes:
        ax.grid(True, alpha=0.3)
    axes[-1].set_xlabel("time [s]")
    fig.suptitle(title, fontsize=10)
    fig.subplots_adjust(left=0.11, right=0.98, top=1.0 - 0.35 / (1.45 * n + 0.7),
                        bottom=0.45 / (1.45 * n + 0.7), hspace=0.12)
    return fig

