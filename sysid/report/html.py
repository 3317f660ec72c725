"""Self-contained HTML report of a campaign: the paper's figures and tables from a DataTree.

:func:`write_report` reads the campaign groups of ``docs/data_model.md`` and writes
``out_dir/report.html`` -- one file, every plot embedded as a base64 PNG, inline CSS and one
inline script, no external resources, so it opens offline -- plus every plot as a PNG file in
``out_dir/figures/`` with a stable descriptive name. Everything is built in a temporary
directory and moved into place at the end: a failure leaves no half-written report.

Sections (each only when its groups exist; "not available" otherwise), with the items of
the paper (*Comparison of frequency and time domain identification of a helicopter in hover*) they reproduce:

========================  ==========================================================
section                   paper item, source groups
========================  ==========================================================
Trim                      Table 1; ``/trim`` or the ``trim_*`` attrs of a manoeuvre
Inputs                    Figure 1; ``/maneuvers/sweep_*``
Conditioning              Figures 2-3; ``/frequency_response`` vs
                          ``/frequency_response_siso``, ``cross_coherence``
Input/output pairs        Figures 4-15; ``/frequency_response``, ``/models/*``,
                          ``/linearization``; MUAD mismatch (Eq. 20)
Time-domain verification  Figures 16-19; ``/verification/<maneuver>``
Derivatives               Tables 2 (stability) and 3 (control, delays); ``/models/*``
Guidelines                cost and accuracy guidelines of ``docs/methods.md``
Model reduction           ``/models/<method>/reduction`` or the model's ``reduction_steps``
Provenance                versions, seeds, FMU, campaign settings
========================  ==========================================================

Guideline thresholds (:data:`GUIDELINES`, Tischler & Remple 2012; docs/methods.md, "Guidelines"):
``J_ave <= 100``, every pair ``J <= 200``, Cramer-Rao bound ``<= 20 %``, insensitivity
``<= 10 %``, ``J_rms <= 2``, ``TIC <= 0.25``, composite coherence ``>= 0.6`` over the fitted
range, cross-control coherence ``<= 0.5``.
"""

from __future__ import annotations

import base64
import concurrent.futures
import datetime as _dt
import html
import json
import multiprocessing
import os
import platform
import re
import shutil
import tempfile
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from sysid import __version__
from sysid.report import plots
from sysid.core.errors import InputDataError
from sysid.models import frequency_response
from sysid.core.units import CHANNELS, CONTROLS, STATES_6DOF
from sysid.core.util import Progress
from sysid.assess.envelopes import MUAD, Envelope, check_envelope, mismatch
from sysid.core.guidelines import GUIDELINES

__all__ = ["write_report", "PAPER_PAIRS", "GUIDELINES", "build_html"]

#: The paper's input/output pairs, in its order (section "Mathematical model structure").
PAPER_PAIRS = ("q/lon", "p/lon", "u/lon", "p/lat", "q/lat", "v/lat", "r/lat", "w/col", "r/col",
               "p/col", "q/col", "r/ped", "v/ped")
#: Pairs shown in the conditioning figures (paper Figures 2-3): on-axis and cyclic coupling.
CONDITIONING_PAIRS = ("q/lon", "p/lon", "p/lat", "q/lat", "w/col", "r/ped")
#: Paper figure numbers of each pair (Figures 4-7: frequency-domain identification;
#: Figures 8-15: comparison of the frequency- and time-domain models).
PAIR_FIGURES = {"p/lon": (4, 8), "q/lon": (5, 9), "p/lat": (6, 10), "q/lat": (7, 11),
                "w/col": (12,), "r/col": (13,), "v/ped": (14,), "r/ped": (15,)}
#: Paper figure number of the time-domain verification per excited control (Figures 16-19).
TIME_FIGURES = {"lon": 16, "lat": 17, "col": 18, "ped": 19}

#: Greek symbols of the attitudes, as in the paper's Table 1.
_SYMBOL = {"phi": "φ", "theta": "θ", "psi": "ψ"}
#: Labels of the model sources.
_TRUTH = "linearization"
_DASH = "—"


# --------------------------------------------------------------------------------------------
# Reading the tree
# --------------------------------------------------------------------------------------------


def _node(tree: xr.DataTree, path: str) -> xr.DataTree | None:
    try:
        return tree[path]
    except KeyError:
        return None


def _dataset(tree: xr.DataTree, path: str) -> xr.Dataset | None:
    """The group's own Dataset (no inherited coordinates), or None when absent or empty."""
    node = _node(tree, path)
    if node is None:
        return None
    ds = node.to_dataset(inherit=False)
    return ds if (ds.data_vars or ds.attrs) else None


def _complex(da: xr.DataArray) -> xr.DataArray:
    """A complex variable, rebuilt from a trailing ``complex`` (real, imag) dim if stored so."""
    if "complex" in da.dims:
        return da.sel(complex="real", drop=True) + 1j * da.sel(complex="imag", drop=True)
    return da


def _children(tree: xr.DataTree, path: str) -> dict[str, xr.DataTree]:
    node = _node(tree, path)
    return dict(node.children) if node is not None else {}


def _models(tree: xr.DataTree) -> dict[str, xr.Dataset]:
    """``/models/<method>`` Datasets that hold a state-space model, by method."""
    out = {}
    for name, node in _children(tree, "models").items():
        ds = node.to_dataset(inherit=False)
        if "A" in ds and "B" in ds:
            out[name] = ds
    return out


def _linearization(tree: xr.DataTree) -> xr.Dataset | None:
    ds = _dataset(tree, "linearization")
    return ds if ds is not None and "A" in ds and "B" in ds else None


def _maneuvers(tree: xr.DataTree) -> dict[str, xr.Dataset]:
    return {name: node.to_dataset(inherit=False)
            for name, node in sorted(_children(tree, "maneuvers").items(),
                                     key=lambda kv: _natural(kv[0]))}


def _natural(name: str):
    """Sort key: the paper's control order (lon, lat, col, ped) first, then natural order."""
    rank = min((CONTROLS.index(p) for p in re.split(r"[_\W]", name) if p in CONTROLS),
               default=len(CONTROLS))
    return [rank] + [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def _pair_costs(model: xr.Dataset) -> dict[str, float]:
    """Cost per pair (``"q/lon" -> J``): ``pair_cost`` (pair) or ``cost`` (output, input)."""
    if "pair_cost" in model:
        da = model["pair_cost"]
        dim = da.dims[0]
        return {str(p): float(v) for p, v in zip(da[dim].values, da.values) if np.isfinite(v)}
    if "cost" in model and set(model["cost"].dims) == {"output", "input"}:
        da = model["cost"].transpose("output", "input")
        return {f"{o}/{i}": float(da.sel(output=o, input=i))
                for o in da.output.values for i in da.input.values
                if np.isfinite(float(da.sel(output=o, input=i)))}
    return {}


def _j_ave(model: xr.Dataset) -> float | None:
    if "J_ave" in model.attrs:
        return float(model.attrs["J_ave"])
    costs = _pair_costs(model)
    return float(np.mean(list(costs.values()))) if costs else None


def _reduction(tree: xr.DataTree, method: str, model: xr.Dataset) -> list[dict]:
    """Reduction steps of a model: the ``reduction`` sub-group (dim ``step``) or the model's
    ``reduction_steps`` JSON attribute; one dict per step."""
    ds = _dataset(tree, f"models/{method}/reduction")
    if ds is not None and "step" in ds.dims:
        names = [v for v in ds.data_vars if ds[v].dims == ("step",)]
        return [{v: _py(ds[v].values[k]) for v in names} for k in range(ds.sizes["step"])]
    raw = model.attrs.get("reduction_steps")
    if isinstance(raw, str) and raw.strip():
        try:
            steps = json.loads(raw)
        except json.JSONDecodeError:
            raise InputDataError(f"model /models/{method}: attribute 'reduction_steps' is not "
                                 f"valid JSON") from None
        return [dict(s) for s in steps if isinstance(s, Mapping)]
    return []


def _py(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def _dropped(tree: xr.DataTree, method: str, model: xr.Dataset) -> set[str]:
    """Parameters removed by model reduction."""
    out = {s.strip() for s in str(model.attrs.get("removed_parameters", "")).split(",")
           if s.strip()}
    for step in _reduction(tree, method, model):
        name = step.get("dropped", step.get("parameter"))
        if name is not None and bool(step.get("accepted", True)):
            out.add(str(name))
    return out


def _pairs_present(fr: xr.Dataset) -> list[str]:
    """Paper pairs whose output and input are in the frequency response and carry data."""
    out = []
    H = _complex(fr["H"])
    for pair in PAPER_PAIRS:
        o, i = pair.split("/")
        if o in H.output.values and i in H.input.values:
            if np.any(np.isfinite(H.sel(output=o, input=i).values)):
                out.append(pair)
    return out


def _coherence(fr: xr.Dataset) -> xr.DataArray:
    """The coherence that goes with the conditioned ``H``: partial, else ordinary."""
    return fr["partial_coherence"] if "partial_coherence" in fr else fr["coherence"]


# --------------------------------------------------------------------------------------------
# HTML helpers
# --------------------------------------------------------------------------------------------


def _esc(x) -> str:
    return html.escape(str(x), quote=True)


def _anchor(text: str) -> str:
    return "".join(c if c.isalnum() else "-" for c in text.lower()).strip("-")


def _num(value, fmt: str = ".4g") -> str:
    if value is None:
        return _DASH
    value = float(value)
    if np.isnan(value):
        return _DASH
    if np.isinf(value):
        return "∞"
    return format(value, fmt)


def _verdict(ok: bool | None) -> str:
    return {True: "PASS", False: "FAIL", None: "n/a"}[ok]


def _verdict_cell(value_text: str, ok: bool | None, **data) -> str:
    attrs = " ".join(f'data-{k}="{_esc(v)}"' for k, v in data.items())
    cls = {True: "pass", False: "fail", None: "na"}[ok]
    return (f'<td class="verdict {cls}" {attrs}><span class="value">{_esc(value_text)}</span> '
            f'<b>{_verdict(ok)}</b></td>')


def _table(header: list[str], rows: list[list[str]], cls: str = "", raw: bool = False,
           table_id: str = "") -> str:
    """An HTML table; cells are escaped text unless ``raw`` (then each is a full ``<td>``)."""
    head = "".join(f"<th>{_esc(h)}</th>" for h in header)
    body = []
    for row in rows:
        cells = "".join(c if raw and c.startswith("<td") else f"<td>{_esc(c)}</td>" for c in row)
        body.append(f"<tr>{cells}</tr>")
    tid = f' id="{table_id}"' if table_id else ""
    return (f'<table class="{cls}"{tid}><thead><tr>{head}</tr></thead>'
            f'<tbody>{"".join(body)}</tbody></table>')


def _not_available(what: str) -> str:
    return f'<p class="na">Not available: {_esc(what)}</p>'


# --------------------------------------------------------------------------------------------
# The report builder
# --------------------------------------------------------------------------------------------


#: Worker processes that render the report's figures (``SYSID_REPORT_PROCESSES`` overrides;
#: 1 renders in the calling process). Drawing is most of a report's time (about 0.9 s a
#: figure, 25 figures for the hover study) and pure Python, so only processes help.
MAX_REPORT_PROCESSES = 4


def report_processes() -> int:
    """How many processes render figures: ``SYSID_REPORT_PROCESSES``, else the usable cores
    up to :data:`MAX_REPORT_PROCESSES`; 1 inside a daemonic process (a Dask worker), which
    may not start children."""
    value = os.environ.get("SYSID_REPORT_PROCESSES")
    if value:
        try:
            return max(1, int(value))
        except ValueError:
            raise InputDataError(f"SYSID_REPORT_PROCESSES must be an integer, got "
                                 f"{value!r}") from None
    if multiprocessing.current_process().daemon:
        return 1
    try:
        cores = len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        cores = os.cpu_count() or 1
    return max(1, min(cores, MAX_REPORT_PROCESSES))


class _Renderer:
    """Renders figures in a process pool, or inline with one process; figures are queued
    while the sections are built and collected when the page is assembled."""

    def __init__(self, processes: int):
        self._pool = None
        if processes > 1:
            # forkserver: a clean child, not a fork of a process that may hold threads.
            self._pool = concurrent.futures.ProcessPoolExecutor(
                processes, mp_context=multiprocessing.get_context("forkserver"))

    def submit(self, builder, args: tuple) -> concurrent.futures.Future:
        if self._pool is not None:
            return self._pool.submit(plots.render_png, builder, args)
        done: concurrent.futures.Future = concurrent.futures.Future()
        done.set_result(plots.render_png(builder, args))
        return done

    def close(self) -> None:
        if self._pool is not None:
            self._pool.shutdown(wait=True, cancel_futures=True)


@dataclass
class _Context:
    """Shared state of one report: the tree, where figures go, the index of anchors."""

    tree: xr.DataTree
    figure_dir: Path
    progress: Progress
    envelope: Envelope
    renderer: _Renderer
    figures: list[str] = field(default_factory=list)
    anchors: dict[str, str] = field(default_factory=dict)  # anchor -> caption
    _model_fr: dict = field(default_factory=dict)
    _pending: dict = field(default_factory=dict)  # slot token -> (name, path, caption, future)

    def figure(self, name: str, caption: str, builder, *args) -> str:
        """Queue ``builder(*args)`` (a :mod:`sysid.report.plots` figure function) for
        ``figures/<name>.png``; return a slot token that :meth:`embed_figures` replaces
        with the embedded ``<figure>``."""
        path = self.figure_dir / f"{name}.png"
        self.figures.append(path.name)
        self.anchors[f"fig-{name}"] = caption
        token = f"\x00figure:{name}\x00"
        self._pending[token] = (name, path, caption, self.renderer.submit(builder, args))
        return token

    def embed_figures(self, text: str) -> str:
        """Write every queued figure and put its ``<figure>`` in place of its slot token."""
        for token, (name, path, caption, future) in self._pending.items():
            data = future.result()
            path.write_bytes(data)
            b64 = base64.b64encode(data).decode("ascii")
            text = text.replace(
                token,
                f'<figure id="fig-{name}"><img alt="{_esc(caption)}" '
                f'src="data:image/png;base64,{b64}"><figcaption>{_esc(caption)} '
                f'<span class="file">(figures/{_esc(path.name)})</span></figcaption></figure>')
        self._pending.clear()
        return text

    def model_response(self, name: str, model: xr.Dataset, omega: np.ndarray) -> xr.DataArray:
        """Frequency response of a model on the data grid, computed once per model."""
        if name not in self._model_fr:
            self._model_fr[name] = frequency_response(model, omega)
        return self._model_fr[name]


def _sources(ctx: _Context) -> dict[str, xr.Dataset]:
    """All models to overlay: the truth linearisation first, then ``/models/*``."""
    out = {}
    lin = _linearization(ctx.tree)
    if lin is not None:
        out[_TRUTH] = lin
    out.update(_models(ctx.tree))
    return out


# -- Table 1 ---------------------------------------------------------------------------------


def _trim_values(tree: xr.DataTree) -> tuple[dict[str, float], dict, str] | None:
    ds = _dataset(tree, "trim")
    if ds is not None:
        values = {k: float(ds[k]) for k in (*STATES_6DOF, *CONTROLS) if k in ds}
        return values, dict(ds.attrs), "/trim"
    for name, m in _maneuvers(tree).items():
        values = {k: float(m.attrs[f"trim_{k}"]) for k in (*STATES_6DOF, *CONTROLS)
                  if f"trim_{k}" in m.attrs}
        if values:
            return values, dict(m.attrs), f"trim_* attributes of /maneuvers/{name}"
    return None


def section_trim(ctx: _Context) -> str:
    """Trim table like the paper's Table 1."""
    found = _trim_values(ctx.tree)
    if found is None:
        return _not_available("no /trim group and no trim_* attributes on any manoeuvre")
    values, attrs, source = found
    ctx.anchors["table-trim"] = "Table 1 — trim"
    left = [(f"{_SYMBOL.get(k, k)}₀", f"{_num(values[k], '.2f')} {CHANNELS[k].unit}")
            for k in STATES_6DOF if k in values]
    right = [(f"δ_{k}₀", f"{_num(values[k], '.2f')} %") for k in CONTROLS if k in values]
    if "mass_kg" in attrs:
        right.append(("total mass", f"{_num(attrs['mass_kg'], '.1f')} kg"))
    if "airspeed_kt" in attrs:
        right.append(("airspeed", f"{_num(attrs['airspeed_kt'], '.1f')} kt"))
    if "residual" in attrs:
        right.append(("trim residual", _num(attrs["residual"], ".2e")))
    n = max(len(left), len(right))
    rows = []
    for k in range(n):
        a = left[k] if k < len(left) else ("", "")
        b = right[k] if k < len(right) else ("", "")
        rows.append([*a, *b])
    return (f'<p>Source: {_esc(source)}.</p>'
            + _table(["Parameter", "Value", "Parameter", "Value"], rows, "numeric",
                     table_id="table-trim"))


# -- Figure 1 --------------------------------------------------------------------------------


def section_inputs(ctx: _Context) -> str:
    """The four controls of each sweep manoeuvre (paper Figure 1)."""
    sweeps = {n: m for n, m in _maneuvers(ctx.tree).items()
              if m.attrs.get("kind") == "sweep" or n.startswith("sweep")}
    if not sweeps:
        return _not_available("no sweep manoeuvres under /maneuvers")
    parts = []
    for name, m in sweeps.items():
        controls = {k: m[k].values for k in CONTROLS if k in m}
        if not controls or "time" not in m.coords:
            parts.append(_not_available(f"/maneuvers/{name} has no controls on a time axis"))
            continue
        axis = m.attrs.get("axis", "")
        title = f"{name}: frequency sweep" + (f" on {axis}" if axis else "")
        parts.append(ctx.figure(f"fig01_inputs_{name}", f"Figure 1 — {title}",
                                plots.inputs_figure, m["time"].values, controls, title))
    return "".join(parts)


# -- Figures 2-3 and cross-control coherence ------------------------------------------------


def section_conditioning(ctx: _Context) -> str:
    """Conditioned vs unconditioned responses (paper Figures 2-3), partial vs ordinary
    coherence, and the cross-control coherence (Eq. 8)."""
    fr = _dataset(ctx.tree, "frequency_response")
    siso = _dataset(ctx.tree, "frequency_response_siso")
    if fr is None or "H" not in fr:
        return _not_available("no /frequency_response group")
    parts = []
    omega = fr["frequency"].values
    pairs = [p for p in CONDITIONING_PAIRS if p in _pairs_present(fr)]
    lin = _linearization(ctx.tree)
    H = _complex(fr["H"])
    if siso is not None and "H" in siso and pairs:
        Hs = _complex(siso["H"]).interp(frequency=omega) if not np.array_equal(
            siso["frequency"].values, omega) else _complex(siso["H"])
        Hl = ctx.model_response(_TRUTH, lin, omega) if lin is not None else None
        panels = {}
        for pair in pairs:
            o, i = pair.split("/")
            curves = {"conditioned": H.sel(output=o, input=i).values}
            if o in Hs.output.values and i in Hs.input.values:
                curves["unconditioned"] = Hs.sel(output=o, input=i).values
            if Hl is not None and o in Hl.output.values and i in Hl.input.values:
                curves["linearization"] = Hl.sel(output=o, input=i).values
            panels[pair] = curves
        parts.append(ctx.figure("fig02_conditioning_magnitude",
                                "Figure 2 — magnitude before (SISO) and after conditioning",
                                plots.conditioning_figure, panels, omega, "magnitude"))
        parts.append(ctx.figure("fig03_conditioning_phase",
                                "Figure 3 — phase before (SISO) and after conditioning",
                                plots.conditioning_figure, panels, omega, "phase"))
    else:
        parts.append(_not_available("no /frequency_response_siso group: the unconditioned "
                                    "responses of Figures 2-3 cannot be shown"))
    if pairs and "coherence" in fr and "partial_coherence" in fr:
        panels = {p: {"partial": fr["partial_coherence"].sel(output=p.split("/")[0],
                                                              input=p.split("/")[1]).values,
                      "ordinary": fr["coherence"].sel(output=p.split("/")[0],
                                                      input=p.split("/")[1]).values}
                  for p in pairs}
        parts.append(ctx.figure("fig03b_partial_vs_ordinary_coherence",
                                "Partial (conditioned) vs ordinary coherence of the main pairs",
                                plots.conditioning_figure, panels, omega, "coherence"))
    parts.append(_cross_coherence(ctx, fr if "cross_coherence" in fr else siso))
    return "".join(parts)


def _cross_coherence(ctx: _Context, ds: xr.Dataset | None) -> str:
    if ds is None or "cross_coherence" not in ds:
        return _not_available("no cross_coherence variable in /frequency_response")
    cc = ds["cross_coherence"]
    jdim = [d for d in cc.dims if d not in ("input", "frequency")][0]
    inputs = [str(x) for x in cc["input"].values]
    omega = ds["frequency"].values
    curves, rows = {}, []
    limit = GUIDELINES["cross_coherence"]
    for a in range(len(inputs)):
        for b in range(a + 1, len(inputs)):
            v = cc.sel(input=inputs[a], **{jdim: inputs[b]}).values.astype(float)
            name = f"{inputs[a]}–{inputs[b]}"
            curves[name] = v
            mean = float(np.nanmean(v)) if np.isfinite(v).any() else np.nan
            frac = float(np.mean(v[np.isfinite(v)] > limit)) if np.isfinite(v).any() else np.nan
            rows.append([name, _num(mean, ".3f"), _num(np.nanmax(v), ".3f"),
                         _num(100 * frac, ".0f"),
                         _verdict_cell(_num(mean, ".3f"), None if np.isnan(mean)
                                       else mean <= limit, pair=name)])
    return (ctx.figure("fig03c_cross_control_coherence",
                       "Cross-control coherence of the inputs (Eq. 8)",
                       plots.cross_coherence_figure, omega, curves, limit)
            + _table(["inputs", "mean", "max", f"% of frequencies > {limit:g}",
                      f"mean ≤ {limit:g}"], rows, "numeric", raw=True,
                     table_id="table-cross-coherence"))


# -- Figures 4-15 ----------------------------------------------------------------------------


@dataclass
class _PairResult:
    """Envelope check and costs of one pair, kept for the guideline summary."""

    fraction_inside: dict[str, float]
    coherence_min: float
    coherence_fraction: float
    fit_range: tuple[float, float] | None


def _fit_range(models: Mapping[str, xr.Dataset], pair: str) -> tuple[float, float] | None:
    o, i = pair.split("/")
    for model in models.values():
        if "omega_min" in model and "omega_max" in model:
            try:
                lo = float(model["omega_min"].sel(output=o, input=i))
                hi = float(model["omega_max"].sel(output=o, input=i))
            except KeyError:
                continue
            if np.isfinite(lo) and np.isfinite(hi):
                return lo, hi
    return None


def section_pairs(ctx: _Context, results: dict[str, _PairResult]) -> str:
    """Per pair: Bode plot of data and models, coherence, and the MUAD mismatch
    (paper Figures 4-15). Fills ``results`` for the guideline summary."""
    fr = _dataset(ctx.tree, "frequency_response")
    if fr is None or "H" not in fr:
        return _not_available("no /frequency_response group")
    pairs = _pairs_present(fr)
    if not pairs:
        return _not_available("none of the paper's input/output pairs in /frequency_response")
    omega = fr["frequency"].values
    H = _complex(fr["H"])
    coh = _coherence(fr)
    sources = _sources(ctx)
    models = _models(ctx.tree)
    bounds_ds = ctx.envelope.bounds(omega)
    bounds = {k: bounds_ds[k].values for k in bounds_ds.data_vars}
    responses = {n: ctx.model_response(n, m, omega) for n, m in sources.items()}
    min_coh = GUIDELINES["coherence"]
    parts = [f"<p>Mismatch (Eq. 20) of each model against the composite data, judged against "
             f"the {_esc(ctx.envelope.name)} bounds ({_esc(ctx.envelope.citation)}) at the "
             f"frequencies where the {_esc(coh.name.replace('_', ' '))} is ≥ {min_coh:g}. "
             f"Faded data points are below that coherence.</p>"]
    for pair in ctx.progress.bar(pairs, label="[sysid]   pairs"):
        o, i = pair.split("/")
        data = H.sel(output=o, input=i)
        gamma = coh.sel(output=o, input=i)
        curves, errs, rows = {}, {}, []
        for name, T in responses.items():
            if o not in T.output.values or i not in T.input.values:
                continue
            model_pair = T.sel(output=o, input=i).assign_coords(frequency=data.frequency)
            curves[name] = model_pair.values
            err = mismatch(model_pair, data)
            check = check_envelope(err, ctx.envelope, coherence=gamma, min_coherence=min_coh)
            errs[name] = (err["magnitude"].values, err["phase"].values)
            frac = float(check["fraction_inside"])
            results.setdefault(pair, _PairResult({}, np.nan, np.nan, None))
            results[pair].fraction_inside[name] = frac
            cost = _pair_costs(sources[name]).get(pair)
            rows.append([plots.source_label(name), _num(cost, ".2f"),
                         _num(100 * frac, ".0f"),
                         _num(float(check["worst_magnitude_excess"]), ".2f"),
                         _num(float(check["worst_phase_excess"]), ".1f")])
        counted = (gamma.values >= min_coh) & np.isfinite(data.values)
        coherence_curves = {"partial γ² (conditioned)" if coh.name == "partial_coherence"
                            else "γ²": gamma.values}
        if coh.name == "partial_coherence" and "coherence" in fr:
            coherence_curves["ordinary γ²"] = fr["coherence"].sel(output=o, input=i).values
        numbers = PAIR_FIGURES.get(pair, ())
        label = (f"Figure{'s' if len(numbers) > 1 else ''} "
                 f"{', '.join(map(str, numbers))} — " if numbers else "")
        caption = f"{label}identification of {o}/δ_{i}"
        rng = _fit_range(models, pair)
        sel = np.ones(omega.shape, bool) if rng is None else (omega >= rng[0]) & (omega <= rng[1])
        g = gamma.values[sel]
        g = g[np.isfinite(g)]
        res = results.setdefault(pair, _PairResult({}, np.nan, np.nan, None))
        res.coherence_min = float(g.min()) if g.size else np.nan
        res.coherence_fraction = float(np.mean(g >= min_coh)) if g.size else np.nan
        res.fit_range = rng
        anchor = f"pair-{_anchor(pair)}"
        ctx.anchors[anchor] = caption
        parts.append(f'<section class="pair" id="{anchor}"><h3>{_esc(o)}/δ_{_esc(i)}</h3>'
                     + ctx.figure(f"pair_{o}_{i}", caption, plots.pair_figure, pair, omega,
                                  data.values, coherence_curves, curves, errs, bounds, counted)
                     + _table(["model", "pair cost J",
                               f"% of coherent band inside {ctx.envelope.name}",
                               "worst magnitude excess [dB]", "worst phase excess [deg]"],
                              rows, "numeric") + "</section>")
    return "".join(parts)


# -- Figures 16-19 ---------------------------------------------------------------------------


def _excited_axis(name: str, ds: xr.Dataset, maneuver: xr.Dataset | None) -> str:
    for attrs in (ds.attrs, maneuver.attrs if maneuver is not None else {}):
        axis = str(attrs.get("axis", ""))
        if axis in CONTROLS:
            return axis
    for c in CONTROLS:
        if c in name.split("_"):
            return c
    return ""


def section_time(ctx: _Context) -> dict:
    """Time-domain overlays of each verification manoeuvre (paper Figures 16-19).

    Returns ``{"html": ..., "j_rms": {source: [values]}, "tic": {source: [values]}}`` for
    the guideline summary.
    """
    nodes = _children(ctx.tree, "verification")
    out = {"html": "", "j_rms": {}, "tic": {}}
    if not nodes:
        out["html"] = _not_available("no /verification groups")
        return out
    maneuvers = _maneuvers(ctx.tree)
    parts = []
    for name in sorted(nodes, key=_natural):
        ds = nodes[name].to_dataset(inherit=False)
        channels = [v for v in ds.data_vars if set(ds[v].dims) == {"source", "time"}]
        if not channels or "time" not in ds.coords:
            parts.append(_not_available(f"/verification/{name} has no (source, time) channels"))
            continue
        t = ds["time"].values
        sources = [str(s) for s in ds["source"].values]
        man = maneuvers.get(name)
        axis = _excited_axis(name, ds, man)
        inputs = {}
        for c in CONTROLS:
            if c in ds and ds[c].dims == ("time",):
                inputs[c] = ds[c].values
            elif man is not None and c in man and "time" in man.coords and c == axis:
                inputs[c] = np.interp(t, man["time"].values, man[c].values)
        if axis and axis in inputs:
            inputs = {axis: inputs[axis]}
        tic = {}
        if "tic" in ds:
            tic_da = ds["tic"]
            cdim = [d for d in tic_da.dims if d != "source"][0]
            for s in sources:
                tic[s] = {str(c): float(tic_da.sel(source=s, **{cdim: c}))
                          for c in tic_da[cdim].values}
        curves = {ch: {s: ds[ch].sel(source=s).values for s in sources} for ch in channels}
        units = {ch: CHANNELS[ch].unit if ch in CHANNELS else str(ds[ch].attrs.get("units", ""))
                 for ch in channels}
        number = TIME_FIGURES.get(axis)
        kind = ds.attrs.get("kind") or (man.attrs.get("kind") if man is not None else "")
        title = f"{name}" + (f" ({kind} on {axis})" if kind and axis else "")
        caption = (f"Figure {number} — " if number else "") + f"time-domain verification: {title}"
        anchor = f"time-{_anchor(name)}"
        ctx.anchors[anchor] = caption
        rows = []
        models_here = [s for s in sources if s != "truth"]
        for s in models_here:
            jr = float(ds["j_rms"].sel(source=s)) if "j_rms" in ds else np.nan
            if np.isfinite(jr):
                out["j_rms"].setdefault(s, []).append(jr)
            row = [plots.source_label(s),
                   _verdict_cell(_num(jr, ".3f"), None if np.isnan(jr)
                                 else jr <= GUIDELINES["j_rms"], source=s, metric="j_rms")]
            for ch in channels:
                v = tic.get(s, {}).get(ch, np.nan)
                if np.isfinite(v):
                    out["tic"].setdefault(s, []).append(v)
                row.append(_verdict_cell(_num(v, ".3f"), None if np.isnan(v)
                                         else v <= GUIDELINES["tic"], source=s, channel=ch))
            rows.append(row)
        table = _table(["model", f"J_rms (≤ {GUIDELINES['j_rms']:g})"]
                       + [f"TIC {ch} (≤ {GUIDELINES['tic']:g})" for ch in channels],
                       rows, "numeric", raw=True)
        parts.append(f'<section class="time" id="{anchor}"><h3>{_esc(name)}</h3>'
                     + ctx.figure(f"time_{name}", caption, plots.time_response_figure, t,
                                  inputs, curves, units, title, tic)
                     + table + "</section>")
    out["html"] = "".join(parts)
    return out


# -- Tables 2-3 ------------------------------------------------------------------------------


def _truth_value(lin: xr.Dataset | None, name: str, ref: xr.Dataset) -> float:
    """Truth value of a parameter: the linearisation's ``value`` for the same name, else its
    matrix entry minus the fixed part of ``ref`` (an identified model with that parameter)."""
    if lin is None:
        return np.nan
    if "value" in lin and "parameter" in lin.dims and name in lin["parameter"].values:
        return float(lin["value"].sel(parameter=name))
    if "parameter" not in ref.dims or name not in ref["parameter"].values or "matrix" not in ref:
        return np.nan
    p = ref.sel(parameter=name)
    matrix, row, col = str(p["matrix"].values), str(p["row"].values), str(p["column"].values)
    try:
        if matrix == "delay":
            d = lin["delay"] if "delay" in lin else None
            if d is None:
                return 0.0
            return float(d.sel(input=col).max() if row == "*" else d.sel(state_dot=row,
                                                                          input=col))
        dims = {"A": ("state_dot", "state"), "B": ("state_dot", "input"),
                "C": ("output", "state"), "D": ("output", "input")}[matrix]
        sel = {dims[0]: row, dims[1]: col}
        fixed = float(ref[matrix].sel(sel)) - float(p["value"])
        return float(lin[matrix].sel(sel)) - fixed
    except KeyError:
        return np.nan


def _derivative_rows(ctx: _Context, models: dict[str, xr.Dataset], kinds: tuple[str, ...]
                     ) -> tuple[list[str], list[list[str]]]:
    """Rows of a derivative table for the parameters of matrices ``kinds``."""
    lin = _linearization(ctx.tree)
    dropped = {m: _dropped(ctx.tree, m, ds) for m, ds in models.items()}
    names: list[str] = []
    owner: dict[str, str] = {}
    for m, ds in models.items():
        if "parameter" not in ds.dims:
            continue
        for k, nm in enumerate(ds["parameter"].values):
            nm = str(nm)
            matrix = str(ds["matrix"].values[k]) if "matrix" in ds else "A"
            free = bool(ds["free"].values[k]) if "free" in ds else True
            value = float(ds["value"].values[k])
            shown = free or nm in dropped[m] or value != 0.0
            if matrix in kinds and shown and nm not in owner:
                names.append(nm)
                owner[nm] = m
    header = ["parameter", "truth"]
    for m in models:
        header += [f"{m}: value", f"{m}: CR %", f"{m}: I %"]
    rows = []
    for nm in names:
        row = [nm, _num(_truth_value(lin, nm, models[owner[nm]]))]
        for m, ds in models.items():
            if "parameter" not in ds.dims or nm not in ds["parameter"].values:
                row += [_DASH, _DASH, _DASH]
                continue
            p = ds.sel(parameter=nm)
            free = bool(p["free"]) if "free" in ds else True
            value = float(p["value"])
            if nm in dropped[m]:
                row += ["dropped", _DASH, _DASH]
            elif not free:
                row += [_num(value) if value != 0.0 else _DASH, "fixed", "fixed"]
            else:
                cr = float(p["cramer_rao_percent"]) if "cramer_rao_percent" in ds else np.nan
                ins = (float(p["insensitivity_percent"]) if "insensitivity_percent" in ds
                       else np.nan)
                row += [_num(value), _num(cr, ".1f"), _num(ins, ".1f")]
        rows.append(row)
    return header, rows


def section_derivatives(ctx: _Context) -> str:
    """Stability (Table 2) and control derivatives with delays (Table 3) of every model, with
    Cramer-Rao bounds and insensitivities in percent, and the truth linearisation's value."""
    models = _models(ctx.tree)
    if not any("parameter" in m.dims for m in models.values()):
        return _not_available("no identified models with parameters under /models")
    parts = ['<p>Values in analysis units (ft/s, deg/s, deg, % of travel; delays in s). '
             'CR %: Cramer-Rao bound, I %: insensitivity, both in percent of |value|; '
             '"dropped": removed by model reduction; "fixed": held at the value shown; '
             f'"{_DASH}": not in that model.</p>']
    for table_id, title, kinds in (
            ("table-derivatives-stability", "Table 2 — stability derivatives", ("A",)),
            ("table-derivatives-control", "Table 3 — control derivatives and time delays",
             ("B", "C", "D", "delay"))):
        header, rows = _derivative_rows(ctx, models, kinds)
        anchor = table_id
        ctx.anchors[anchor] = title
        parts.append(f'<h3 id="{anchor}-title">{_esc(title)}</h3>')
        parts.append(_table(header, rows, "numeric derivatives", table_id=anchor) if rows
                     else _not_available(f"no parameters for {title}"))
    return "".join(parts)


# -- Guidelines ------------------------------------------------------------------------------


def _worst(ds: xr.Dataset, var: str) -> tuple[float, str]:
    """Largest value of ``var`` over the free parameters (inf when not identifiable)."""
    if var not in ds or "parameter" not in ds.dims:
        return np.nan, ""
    da = ds[var]
    if "free" in ds:
        da = da.where(ds["free"].astype(bool))
    vals = da.values.astype(float)
    free = ds["free"].values.astype(bool) if "free" in ds else np.ones(vals.shape, bool)
    if not free.any() or np.all(np.isnan(vals[free])):
        return np.nan, ""
    v = np.where(np.isnan(vals) & free, np.inf, vals)
    v = np.where(free, v, -np.inf)
    k = int(np.argmax(v))
    return float(v[k]), str(ds["parameter"].values[k])


def section_guidelines(ctx: _Context, pair_results: dict[str, _PairResult], time: dict) -> str:
    """Cost, accuracy and verification guidelines per model, and the coherence of the data,
    as PASS/FAIL tables."""
    models = _models(ctx.tree)
    columns = list(models) + [s for s in time["j_rms"] if s not in models]
    if not columns and not pair_results:
        return _not_available("no models, verification or frequency-response data")
    g = GUIDELINES
    rows = []

    def row(key: str, label: str, cells: list[str]):
        rows.append(f'<tr data-guideline="{_esc(key)}"><th>{_esc(label)}</th>'
                    + "".join(cells) + "</tr>")

    def cell(value: float | None, ok: bool | None, model: str, text: str | None = None):
        shown = text if text is not None else _num(value, ".3g")
        return _verdict_cell(shown, None if value is None or np.isnan(value) else ok,
                             model=model)

    cells = []
    for m in columns:
        ja = _j_ave(models[m]) if m in models else None
        cells.append(cell(ja, ja is not None and ja <= g["J_ave"], m))
    row("J_ave", f"J_ave ≤ {g['J_ave']:g}", cells)
    cells = []
    for m in columns:
        costs = _pair_costs(models[m]) if m in models else {}
        if costs:
            worst = max(costs, key=costs.get)
            cells.append(cell(costs[worst], costs[worst] <= g["pair_J"], m,
                              f"max {costs[worst]:.3g} ({worst})"))
        else:
            cells.append(cell(None, None, m))
    row("pair_J", f"every pair J ≤ {g['pair_J']:g}", cells)
    for key, label in (("cramer_rao_percent", "Cramer-Rao bound"),
                       ("insensitivity_percent", "insensitivity")):
        cells = []
        for m in columns:
            v, name = _worst(models[m], key) if m in models else (np.nan, "")
            cells.append(cell(v, v <= g[key], m, f"max {_num(v, '.3g')} % ({name})"
                              if name else None))
        row(key, f"{label} ≤ {g[key]:g} % (free parameters)", cells)
    for key, label in (("j_rms", f"J_rms ≤ {g['j_rms']:g} (worst manoeuvre)"),
                       ("tic", f"TIC ≤ {g['tic']:g} (worst manoeuvre and channel)")):
        cells = []
        for m in columns:
            vals = time[key].get(m, [])
            v = max(vals) if vals else None
            cells.append(cell(v, v is not None and v <= g[key], m))
        row(key, label, cells)
    cells = []
    for m in columns:
        fr = [r.fraction_inside[m] for r in pair_results.values()
              if m in r.fraction_inside and np.isfinite(r.fraction_inside[m])]
        v = float(np.mean(fr)) * 100 if fr else None
        cells.append(cell(v, None, m, f"{v:.0f} % (mean over pairs)" if fr else None))
    row("muad", f"inside {ctx.envelope.name} bounds (coherent band; information)", cells)
    head = "".join(f"<th>{_esc(plots.source_label(m))}</th>" for m in columns)
    model_table = (f'<table class="numeric guidelines" id="table-guidelines"><thead><tr>'
                   f'<th>guideline</th>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>')
    data_rows = []
    for pair, r in pair_results.items():
        rng = (f"{r.fit_range[0]:.3g}–{r.fit_range[1]:.3g}" if r.fit_range
               else "whole data range")
        data_rows.append([pair, rng, _num(r.coherence_min, ".3f"),
                          _num(100 * r.coherence_fraction, ".0f"),
                          _verdict_cell(_num(r.coherence_min, ".3f"),
                                        None if np.isnan(r.coherence_min)
                                        else r.coherence_min >= g["coherence"], pair=pair)])
    data_table = (_table(["pair", "fit range [rad/s]", "min γ²", f"% ≥ {g['coherence']:g}",
                          f"min γ² ≥ {g['coherence']:g}"], data_rows, "numeric", raw=True,
                         table_id="table-coherence")
                  if data_rows else _not_available("no composite frequency responses"))
    return ("<p>Thresholds from the rotorcraft system-identification guidelines "
            "(Tischler &amp; Remple 2012; sysid's docs/methods.md, Guidelines). "
            "n/a: the quantity is not in the campaign.</p>"
            + (model_table if columns else _not_available("no models"))
            + f"<h3>Composite coherence over the fitted range (γ² ≥ {g['coherence']:g})</h3>"
            + data_table)


# -- Model reduction -------------------------------------------------------------------------


def section_reduction(ctx: _Context) -> str:
    """Model reduction steps of each model, one row per step."""
    models = _models(ctx.tree)
    parts = []
    for m, ds in models.items():
        steps = _reduction(ctx.tree, m, ds)
        if not steps:
            continue
        keys = []
        for s in steps:
            keys += [k for k in s if k not in keys]
        rows = [[str(k + 1)] + [_format_cell(s.get(key)) for key in keys]
                for k, s in enumerate(steps)]
        parts.append(f"<h3>{_esc(m)}</h3>" + _table(["step"] + keys, rows, "numeric"))
    return "".join(parts) or _not_available("no model reduction recorded under /models")


def _format_cell(value) -> str:
    if value is None:
        return _DASH
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        return _num(value, ".4g")
    return str(value)


# -- Provenance ------------------------------------------------------------------------------


def section_provenance(ctx: _Context) -> str:
    """Versions, seeds, FMU identity, campaign settings and creation time."""
    import matplotlib

    root = ctx.tree.to_dataset(inherit=False).attrs
    rows = [["report created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")],
            ["sysid version (report)", __version__],
            ["sysid version (campaign)", str(root.get("sysid_version", _DASH))],
            ["campaign", str(root.get("campaign", root.get("name", _DASH)))],
            ["flight condition", str(root.get("flight_condition", _DASH))],
            ["campaign seed", str(root.get("seed", _DASH))],
            ["python", platform.python_version()], ["numpy", np.__version__],
            ["xarray", xr.__version__], ["matplotlib", matplotlib.__version__]]
    fmus = {}
    seeds = []
    for name, m in _maneuvers(ctx.tree).items():
        if "fmu_name" in m.attrs or "fmu_guid" in m.attrs:
            fmus[(str(m.attrs.get("fmu_name", _DASH)), str(m.attrs.get("fmu_guid", _DASH)))] = 1
        if "seed" in m.attrs:
            seeds.append(f"{name}: {m.attrs['seed']}")
    for name, guid in fmus:
        rows.append(["FMU name / GUID", f"{name} / {guid}"])
    if seeds:
        rows.append(["manoeuvre seeds", ", ".join(seeds)])
    for m, ds in _models(ctx.tree).items():
        info = [f"{k}={ds.attrs[k]}" for k in ("structure", "optimizer", "start", "pairs")
                if k in ds.attrs]
        if info:
            rows.append([f"model {m}", "; ".join(map(str, info))])
    # Stamped by sysid.pipeline.study on each stage's group: seconds the stage took when computed.
    timings = [f"{node.path.strip('/')} {float(node.attrs['workflow_elapsed_s']):.1f} s"
               for node in ctx.tree.subtree if "workflow_elapsed_s" in node.attrs]
    if timings:
        rows.append(["workflow stage times", ", ".join(timings)])
    toml = root.get("campaign_toml")
    settings = (f"<h3>Campaign settings</h3><pre>{_esc(toml)}</pre>" if toml
                else _not_available("no campaign_toml attribute on the root group"))
    return _table(["item", "value"], rows, "provenance", table_id="table-provenance") + settings


# --------------------------------------------------------------------------------------------
# Assembly
# --------------------------------------------------------------------------------------------

_CSS = """
body{font-family:-apple-system,"Segoe UI",Helvetica,Arial,sans-serif;margin:0 auto;
max-width:1100px;padding:0 18px 40px;color:#1c1c1c;line-height:1.4}
h1{font-size:1.6em;margin:18px 0 4px}h2{border-bottom:2px solid #4a6fa5;padding-bottom:3px;
margin-top:34px}h3{margin:18px 0 6px}
table{border-collapse:collapse;margin:8px 0 14px;font-size:.86em}
th,td{border:1px solid #c9cfd8;padding:3px 7px;text-align:left;vertical-align:top}
thead th{background:#e8edf4}table.numeric td{font-variant-numeric:tabular-nums}
td.pass{background:#dff3e0}td.fail{background:#f8d9d6}td.na{color:#777}
td.verdict b{font-size:.85em;margin-left:4px}
figure{margin:10px 0 18px}figure img{max-width:100%;height:auto;border:1px solid #e1e4e8}
figcaption{font-size:.85em;color:#444}.file{color:#888}p.na{color:#8a5a00;font-style:italic}
pre{background:#f4f6f8;padding:8px;overflow-x:auto;font-size:.82em}
nav table td{font-size:.95em}.meta{color:#555;font-size:.9em}
"""

#: Inline check used by the headless-browser test: after load, how many images decoded.
_SCRIPT = """
window.addEventListener('load', function () {
  var imgs = document.images, ok = 0;
  for (var i = 0; i < imgs.length; i++) {
    if (imgs[i].complete && imgs[i].naturalWidth > 0) { ok++; }
  }
  var el = document.getElementById('image-check');
  el.setAttribute('data-loaded', String(ok));
  el.setAttribute('data-total', String(imgs.length));
  el.textContent = 'images loaded ' + ok + ' / ' + imgs.length;
});
"""

#: Sections in report order: (anchor, heading, paper items).
_SECTIONS = (
    ("trim", "Trim", "Table 1"),
    ("inputs", "Inputs", "Figure 1"),
    ("conditioning", "Conditioning", "Figures 2-3"),
    ("pairs", "Input/output pairs", "Figures 4-15"),
    ("time", "Time-domain verification", "Figures 16-19"),
    ("derivatives", "Derivatives", "Tables 2-3"),
    ("guidelines", "Cost and guideline summary", ""),
    ("reduction", "Model reduction", ""),
    ("provenance", "Provenance", ""),
)


def _index(ctx: _Context) -> str:
    """Map every paper figure/table number to the report anchors that reproduce it."""
    def link(anchor: str, text: str) -> str:
        return f'<a href="#{anchor}">{_esc(text)}</a>'

    def find(prefix: str) -> list[str]:
        return [a for a in ctx.anchors if a.startswith(prefix)]

    rows = []
    rows.append(["Table 1", "trim at the flight condition",
                 link("table-trim", "table") if "table-trim" in ctx.anchors
                 else "not available"])
    sweeps = find("fig-fig01_inputs_")
    rows.append(["Figure 1", "sweep inputs", " ".join(link(a, a[len("fig-fig01_inputs_"):])
                                                      for a in sweeps) or "not available"])
    for n, a, what in ((2, "fig-fig02_conditioning_magnitude", "magnitude before/after "
                        "conditioning"),
                       (3, "fig-fig03_conditioning_phase", "phase before/after conditioning")):
        rows.append([f"Figure {n}", what, link(a, "figure") if a in ctx.anchors
                     else "not available"])
    pair_rows = []
    for pair, numbers in PAIR_FIGURES.items():
        a = f"pair-{_anchor(pair)}"
        for n in numbers:
            what = ("frequency-domain identification" if n <= 7 else
                    "frequency- vs time-domain model") + f" of {pair}"
            pair_rows.append((n, [f"Figure {n}", what, link(a, pair) if a in ctx.anchors
                                  else "not available"]))
    rows += [r for _, r in sorted(pair_rows, key=lambda nr: nr[0])]
    times = {}
    for a, caption in ctx.anchors.items():
        if a.startswith("time-") and caption.startswith("Figure "):
            times.setdefault(int(caption.split()[1]), []).append(a)
    for axis, n in TIME_FIGURES.items():
        found = times.get(n, [])
        rows.append([f"Figure {n}", f"time responses to {axis} input",
                     " ".join(link(a, a[len("time-"):]) for a in found) or "not available"])
    for tid, label in (("table-derivatives-stability", "Table 2"),
                       ("table-derivatives-control", "Table 3")):
        rows.append([label, ctx.anchors.get(tid, "derivatives").split("— ")[-1],
                     link(tid, "table") if tid in ctx.anchors else "not available"])
    body = "".join(f"<tr><td>{r[0]}</td><td>{_esc(r[1])}</td><td>{r[2]}</td></tr>"
                   for r in rows)
    sections = " · ".join(link(a, h) for a, h, _ in _SECTIONS)
    return (f'<nav id="index"><h2>Index</h2><p>Sections: {sections}</p>'
            f'<table id="table-index"><thead><tr><th>paper item</th><th>content</th>'
            f'<th>in this report</th></tr></thead><tbody>{body}</tbody></table></nav>')


def build_html(tree: xr.DataTree, figure_dir: str | os.PathLike, *, title: str | None = None,
               progress: Progress | None = None, envelope: Envelope = MUAD) -> str:
    """The report's HTML text; figures are written into ``figure_dir`` on the way."""
    progress = progress or Progress(quiet=True)
    renderer = _Renderer(report_processes())
    try:
        ctx = _Context(tree, Path(figure_dir), progress, envelope, renderer)
        text = _page(ctx, title)
        with progress.stage(f"report: rendering {len(ctx.figures)} figures"):
            return ctx.embed_figures(text)
    finally:
        renderer.close()


def _page(ctx: _Context, title: str | None) -> str:
    """The page, with a slot token where each queued figure goes."""
    tree, progress = ctx.tree, ctx.progress
    body: dict[str, str] = {}
    pair_results: dict[str, _PairResult] = {}
    with progress.stage("report: trim (Table 1)"):
        body["trim"] = section_trim(ctx)
    with progress.stage("report: inputs (Figure 1)"):
        body["inputs"] = section_inputs(ctx)
    with progress.stage("report: conditioning (Figures 2-3)"):
        body["conditioning"] = section_conditioning(ctx)
    with progress.stage("report: input/output pairs (Figures 4-15)"):
        body["pairs"] = section_pairs(ctx, pair_results)
    with progress.stage("report: time-domain verification (Figures 16-19)"):
        time = section_time(ctx)
        body["time"] = time["html"]
    with progress.stage("report: derivatives (Tables 2-3)"):
        body["derivatives"] = section_derivatives(ctx)
    with progress.stage("report: guidelines, reduction, provenance"):
        body["guidelines"] = section_guidelines(ctx, pair_results, time)
        body["reduction"] = section_reduction(ctx)
        body["provenance"] = section_provenance(ctx)
    root = tree.to_dataset(inherit=False).attrs
    if title is None:
        name = root.get("campaign", root.get("name", "campaign"))
        cond = root.get("flight_condition")
        title = f"sysid report — {name}" + (f" ({cond})" if cond else "")
    sections = "".join(
        f'<section id="{a}"><h2>{_esc(h)}'
        + (f' <span class="meta">(paper {_esc(items)})</span>' if items else "")
        + f"</h2>{body[a]}</section>" for a, h, items in _SECTIONS)
    return (f'<!DOCTYPE html>\n<html lang="en"><head><meta charset="utf-8">'
            f'<meta name="viewport" content="width=device-width, initial-scale=1">'
            f"<title>{_esc(title)}</title><style>{_CSS}</style></head><body>"
            f"<h1>{_esc(title)}</h1><p class=\"meta\">Rotorcraft system identification report "
            f"generated by sysid {_esc(__version__)}; {len(ctx.figures)} figures "
            f"(also as PNG files in figures/).</p>"
            f'<div id="image-check" hidden data-loaded="" data-total=""></div>'
            f"{_index(ctx)}{sections}<script>{_SCRIPT}</script></body></html>\n")


def write_report(tree: xr.DataTree, out_dir: str | os.PathLike, *, title: str | None = None,
                 quiet: bool = False, envelope: Envelope = MUAD) -> Path:
    """Write ``out_dir/report.html`` and ``out_dir/figures/*.png`` for a campaign DataTree.

    Parameters
    ----------
    tree : xr.DataTree
        A campaign (``docs/data_model.md``); any subset of its groups may be present.
    out_dir : path
        Created if needed. An existing ``report.html`` and ``figures/`` are replaced.
    title : str, optional
        Default: from the root attributes ``campaign`` and ``flight_condition``.
    quiet : bool
        Silence the per-section progress lines.
    envelope : sysid.assess.envelopes.Envelope
        Mismatch envelope of the pair figures (default MUAD).

    Returns
    -------
    Path of ``report.html``.

    Everything is built in a temporary directory inside ``out_dir`` and moved into place
    only when complete: if anything fails, no new ``report.html`` is left behind.
    """
    if not isinstance(tree, xr.DataTree):
        raise InputDataError(f"write_report: expected an xarray.DataTree campaign, got "
                             f"{type(tree).__name__}")
    out_dir = Path(out_dir)
    created = not out_dir.exists()
    out_dir.mkdir(parents=True, exist_ok=True)
    progress = Progress(quiet=quiet)
    tmp = Path(tempfile.mkdtemp(prefix=".report-", dir=out_dir))
    try:
        (tmp / "figures").mkdir()
        text = build_html(tree, tmp / "figures", title=title, progress=progress,
                          envelope=envelope)
        (tmp / "report.html").write_text(text, encoding="utf-8")
        old = out_dir / "figures"
        if old.exists():
            trash = tmp / "old-figures"
            os.replace(old, trash)
        os.replace(tmp / "figures", out_dir / "figures")
        os.replace(tmp / "report.html", out_dir / "report.html")
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        if created:
            shutil.rmtree(out_dir, ignore_errors=True)
        raise
    shutil.rmtree(tmp, ignore_errors=True)
    progress.message(f"[sysid] report written to {out_dir / 'report.html'}")
    return out_dir / "report.html"
