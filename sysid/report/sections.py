"""The report's sections, one function each, in the order of the paper's figures and tables.

Each ``section_*`` takes the report :class:`~sysid.report.figures.Context` and returns HTML
(figures as slot tokens filled in later); :func:`index` maps paper items to anchors.
Pairs are ``"output/input"`` (``"q/lon"``); magnitudes in dB, phases in deg, frequency in rad/s.

References
----------
* "Comparison of frequency and time domain identification of a helicopter in hover" (the
  reference paper of this project): Table 1, Figures 1-19, Tables 2-3.
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012 (cost and accuracy guidelines).
"""

from __future__ import annotations

import datetime as _dt
import importlib.metadata
import platform
from collections.abc import Mapping
from dataclasses import dataclass

import numpy as np
import xarray as xr

import sysid.report.plots as plots
import sysid.report.read as read
from sysid import __version__
from sysid.assess.envelopes import check_envelope, mismatch
from sysid.core.guidelines import BIAS_BOUNDS_MAX, GUIDELINES, UNDETERMINED_PERCENT
from sysid.assess.comparison import (BIAS_MEANING, DOMINANT, dominant_equivalents,
                                     fidelity_scoreboard, truth_for_model)
from sysid.identify.statistics import (format_undetermined, guideline_mark,
                                      undetermined_parameters)
from sysid.spectral.response import NO_TRANSIENT_GROUP
from sysid.core.units import CHANNELS, CONTROLS, STATES_6DOF
from sysid.models import parse_tied_entries
from sysid.report.figures import Context
from sysid.report.page import DASH, esc, html_table, not_available, num, slug, verdict_cell

__all__ = ["PAPER_PAIRS", "CONDITIONING_PAIRS", "PAIR_FIGURES", "TIME_FIGURES", "SECTIONS",
           "PairResult", "index", "section_trim", "section_inputs", "section_conditioning",
           "section_pairs", "section_time", "section_derivatives", "section_guidelines",
           "section_reduction", "section_provenance", "section_fidelity", "ON_AXIS_PAIRS",
           "tied_parameters_note"]


#: The paper's input/output pairs, in its order (section "Mathematical model structure").
PAPER_PAIRS = ("q/lon", "p/lon", "u/lon", "p/lat", "q/lat", "v/lat", "r/lat", "w/col", "r/col",
               "p/col", "q/col", "r/ped", "v/ped")


#: The on-axis pairs, shown with and without leakage conditioning.
ON_AXIS_PAIRS = ("q/lon", "p/lat", "w/col", "r/ped")
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


def _pairs_present(fr: xr.Dataset, models: Mapping[str, xr.Dataset] | None = None
                   ) -> list[str]:
    """Paper pairs, then the other pairs some model was fitted to (e.g. ``ax/lon`` where an
    accelerometer stands for an unmeasured ``u``), whose output and input are in the
    frequency response and carry data."""
    out = []
    H = read.as_complex(fr["H"])
    fitted = [p for m in (models or {}).values() for p in read.pair_costs(m)]
    for pair in dict.fromkeys([*PAPER_PAIRS, *fitted]):
        o, i = pair.split("/")
        if o in H.output.values and i in H.input.values:
            if np.any(np.isfinite(H.sel(output=o, input=i).values)):
                out.append(pair)
    return out


def _sources(ctx: Context) -> dict[str, xr.Dataset]:
    """All models to overlay: the truth linearisation first, then ``/models/*``."""
    out = {}
    lin = read.linearization(ctx.tree)
    if lin is not None:
        out[_TRUTH] = lin
    out.update(read.models(ctx.tree))
    return out


# -- Table 1 ---------------------------------------------------------------------------------


def section_trim(ctx: Context) -> str:
    """Trim table like the paper's Table 1."""
    found = read.trim_values(ctx.tree)
    if found is None:
        return ""  # no trim: the section is omitted
    values, attrs, source = found
    ctx.anchors["table-trim"] = "Table 1 — trim"
    left = [(f"{_SYMBOL.get(k, k)}₀", f"{num(values[k], '.2f')} {CHANNELS[k].unit}")
            for k in STATES_6DOF if k in values]
    right = [(f"δ_{k}₀", f"{num(values[k], '.2f')} %") for k in CONTROLS if k in values]
    if "mass_kg" in attrs:
        right.append(("total mass", f"{num(attrs['mass_kg'], '.1f')} kg"))
    if "airspeed_kt" in attrs:
        right.append(("airspeed", f"{num(attrs['airspeed_kt'], '.1f')} kt"))
    if "residual" in attrs:
        right.append(("trim residual", num(attrs["residual"], ".2e")))
    n = max(len(left), len(right))
    rows = []
    for k in range(n):
        a = left[k] if k < len(left) else ("", "")
        b = right[k] if k < len(right) else ("", "")
        rows.append([*a, *b])
    return (f'<p>Source: {esc(source)}.</p>'
            + html_table(["Parameter", "Value", "Parameter", "Value"], rows, "numeric",
                         table_id="table-trim"))


# -- Figure 1 --------------------------------------------------------------------------------


def section_inputs(ctx: Context) -> str:
    """The four controls of each sweep manoeuvre (paper Figure 1)."""
    sweeps = {n: m for n, m in read.maneuvers(ctx.tree).items()
              if m.attrs.get("kind") == "sweep" or n.startswith("sweep")}
    if not sweeps:
        return ""
    parts = []
    for name, m in sweeps.items():
        controls = {k: m[k].values for k in CONTROLS if k in m}
        if not controls or "time" not in m.coords:
            parts.append(not_available(f"/maneuvers/{name} has no controls on a time axis"))
            continue
        axis = m.attrs.get("axis", "")
        title = f"{name}: frequency sweep" + (f" on {axis}" if axis else "")
        parts.append(ctx.figure(f"fig01_inputs_{name}", f"Figure 1 — {title}",
                                plots.inputs_figure, m["time"].values, controls, title))
    return "".join(parts)


# -- Figures 2-3 and cross-control coherence ------------------------------------------------


def section_conditioning(ctx: Context) -> str:
    """Conditioned vs unconditioned responses (paper Figures 2-3), partial vs ordinary
    coherence, and the cross-control coherence (Eq. 8)."""
    fr = read.dataset(ctx.tree, "frequency_response")
    siso = read.dataset(ctx.tree, "frequency_response_siso")
    if fr is None or "H" not in fr:
        return ""
    parts = []
    omega = fr["frequency"].values
    pairs = [p for p in CONDITIONING_PAIRS if p in _pairs_present(fr)]
    lin = read.linearization(ctx.tree)
    H = read.as_complex(fr["H"])
    if siso is not None and "H" in siso and pairs:
        Hs = read.as_complex(siso["H"]).interp(frequency=omega) if not np.array_equal(
            siso["frequency"].values, omega) else read.as_complex(siso["H"])
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
        parts.append(not_available("no /frequency_response_siso group: the unconditioned "
                                   "responses of Figures 2-3 cannot be shown"))
    parts.append(_leakage(ctx, fr, lin))
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


def _leakage(ctx: Context, fr: xr.Dataset, lin: xr.Dataset | None) -> str:
    """The on-axis composite responses with (the default) and without leakage conditioning
    (``/frequency_response_no_transient``), one figure, with the truth linearisation."""
    states = [str(c) for c in np.atleast_1d(fr.attrs.get("transient_states", []))]
    plain = read.dataset(ctx.tree, NO_TRANSIENT_GROUP)
    if not states:
        return not_available("leakage conditioning was off for /frequency_response (the "
                             "paper's plain conditioned estimate); no before/after figure")
    if plain is None or "H" not in plain:
        return not_available(f"no /{NO_TRANSIENT_GROUP} group: the responses without leakage "
                             "conditioning were not kept")
    omega = fr["frequency"].values
    pairs = [p for p in ON_AXIS_PAIRS if p in _pairs_present(fr) and p in _pairs_present(plain)]
    if not pairs:
        return not_available("no on-axis pair in both response groups")
    H = read.as_complex(fr["H"])
    Hp = read.as_complex(plain["H"])
    if not np.array_equal(plain["frequency"].values, omega):
        Hp = Hp.interp(frequency=omega)
    Hl = ctx.model_response(_TRUTH, lin, omega) if lin is not None else None
    panels, coherence = {}, {}
    for pair in pairs:
        o, i = pair.split("/")
        panels[pair] = {"leakage_free": H.sel(output=o, input=i).values,
                        "plain": Hp.sel(output=o, input=i).values}
        if Hl is not None and o in Hl.output.values and i in Hl.input.values:
            panels[pair]["linearization"] = Hl.sel(output=o, input=i).values
        coherence[pair] = fr["partial_coherence"].sel(output=o, input=i).values
    text = (f"<p>Leakage-free conditioning (the default; docs/methods.md, \"Leakage-free "
            f"conditioning\"): the taper-derivative transforms of the measured states "
            f"{esc(', '.join(states))} join each segment's conditioning, removing the leakage "
            f"of its start and end conditions. Below, the on-axis composite responses with it "
            f"and without it (/{NO_TRANSIENT_GROUP}), where the default estimate's partial "
            f"coherence is at least {GUIDELINES['coherence']:g}.</p>")
    return text + ctx.figure("fig03a_leakage_before_after",
                             "Composite on-axis responses with and without leakage "
                             "conditioning", plots.leakage_figure, panels, omega, coherence)


def _cross_coherence(ctx: Context, ds: xr.Dataset | None) -> str:
    if ds is None or "cross_coherence" not in ds:
        return not_available("no cross_coherence variable in /frequency_response")
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
            rows.append([name, num(mean, ".3f"), num(np.nanmax(v), ".3f"),
                         num(100 * frac, ".0f"),
                         verdict_cell(num(mean, ".3f"), None if np.isnan(mean)
                                      else mean <= limit, pair=name)])
    return (ctx.figure("fig03c_cross_control_coherence",
                       "Cross-control coherence of the inputs (Eq. 8)",
                       plots.cross_coherence_figure, omega, curves, limit)
            + html_table(["inputs", "mean", "max", f"% of frequencies > {limit:g}",
                          f"mean ≤ {limit:g}"], rows, "numeric", raw=True,
                         table_id="table-cross-coherence"))


# -- Figures 4-15 ----------------------------------------------------------------------------


@dataclass
class PairResult:
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


def section_pairs(ctx: Context, results: dict[str, PairResult]) -> str:
    """Per pair: Bode plot of data and models, coherence, and the MUAD mismatch
    (paper Figures 4-15). Fills ``results`` for the guideline summary."""
    fr = read.dataset(ctx.tree, "frequency_response")
    if fr is None or "H" not in fr:
        return ""
    models = read.models(ctx.tree)
    pairs = _pairs_present(fr, models)
    if not pairs:
        return ""
    omega = fr["frequency"].values
    H = read.as_complex(fr["H"])
    coh = read.coherence(fr)
    sources = _sources(ctx)
    bounds_ds = ctx.envelope.bounds(omega)
    bounds = {k: bounds_ds[k].values for k in bounds_ds.data_vars}
    responses = {n: ctx.model_response(n, m, omega) for n, m in sources.items()}
    min_coh = GUIDELINES["coherence"]
    parts = [f"<p>Mismatch (Eq. 20) of each model against the composite data, judged against "
             f"the {esc(ctx.envelope.name)} bounds ({esc(ctx.envelope.citation)}) at the "
             f"frequencies where the {esc(coh.name.replace('_', ' '))} is ≥ {min_coh:g}. "
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
            results.setdefault(pair, PairResult({}, np.nan, np.nan, None))
            results[pair].fraction_inside[name] = frac
            cost = read.pair_costs(sources[name]).get(pair)
            rows.append([plots.source_label(name), num(cost, ".2f"),
                         num(100 * frac, ".0f"),
                         num(float(check["worst_magnitude_excess"]), ".2f"),
                         num(float(check["worst_phase_excess"]), ".1f")])
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
        res = results.setdefault(pair, PairResult({}, np.nan, np.nan, None))
        res.coherence_min = float(g.min()) if g.size else np.nan
        res.coherence_fraction = float(np.mean(g >= min_coh)) if g.size else np.nan
        res.fit_range = rng
        anchor = f"pair-{slug(pair)}"
        ctx.anchors[anchor] = caption
        parts.append(f'<section class="pair" id="{anchor}"><h3>{esc(o)}/δ_{esc(i)}</h3>'
                     + ctx.figure(f"pair_{o}_{i}", caption, plots.pair_figure, pair, omega,
                                  data.values, coherence_curves, curves, errs, bounds, counted)
                     + html_table(["model", "pair cost J",
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


def section_time(ctx: Context) -> dict:
    """Time-domain overlays of each verification manoeuvre (paper Figures 16-19).

    Returns ``{"html": ..., "j_rms": {source: [values]}, "tic": {source: [values]}}`` for
    the guideline summary.
    """
    nodes = read.children(ctx.tree, "verification")
    out = {"html": "", "j_rms": {}, "tic": {}}
    if not nodes:
        return out
    maneuvers = read.maneuvers(ctx.tree)
    parts = []
    for name in sorted(nodes, key=read.natural):
        ds = nodes[name].to_dataset(inherit=False)
        channels = [v for v in ds.data_vars if set(ds[v].dims) == {"source", "time"}]
        if not channels or "time" not in ds.coords:
            parts.append(not_available(f"/verification/{name} has no (source, time) channels"))
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
        anchor = f"time-{slug(name)}"
        ctx.anchors[anchor] = caption
        rows = []
        models_here = [s for s in sources if s != "truth"]
        for s in models_here:
            jr = float(ds["j_rms"].sel(source=s)) if "j_rms" in ds else np.nan
            if np.isfinite(jr):
                out["j_rms"].setdefault(s, []).append(jr)
            row = [plots.source_label(s),
                   verdict_cell(num(jr, ".3f"), None if np.isnan(jr)
                                else jr <= GUIDELINES["j_rms"], source=s, metric="j_rms")]
            for ch in channels:
                v = tic.get(s, {}).get(ch, np.nan)
                if np.isfinite(v):
                    out["tic"].setdefault(s, []).append(v)
                row.append(verdict_cell(num(v, ".3f"), None if np.isnan(v)
                                        else v <= GUIDELINES["tic"], source=s, channel=ch))
            rows.append(row)
        table = html_table(["model", f"J_rms (≤ {GUIDELINES['j_rms']:g})"]
                           + [f"TIC {ch} (≤ {GUIDELINES['tic']:g})" for ch in channels],
                           rows, "numeric", raw=True)
        parts.append(f'<section class="time" id="{anchor}"><h3>{esc(name)}</h3>'
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


def _derivative_rows(ctx: Context, models: dict[str, xr.Dataset], kinds: tuple[str, ...]
                     ) -> tuple[list[str], list[list[str]]]:
    """Rows of a derivative table for the parameters of matrices ``kinds``."""
    lin = read.linearization(ctx.tree)
    truth = {m: truth_for_model(ctx.tree, ds) for m, ds in models.items()}
    dropped = {m: read.dropped(ctx.tree, m, ds) for m, ds in models.items()}
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
    corrected = {m: "cramer_rao_percent_corrected" in ds for m, ds in models.items()}
    header = ["parameter"] + (["truth"] if lin is not None else [])
    for m in models:
        header += [f"{m}: value", f"{m}: CR %"]
        header += [f"{m}: CRc %"] if corrected[m] else []
        header += [f"{m}: I %", f"{m}: guidelines"]
    rows = []
    for nm in names:
        row = [nm] + ([num(_truth_value(truth[owner[nm]], nm, models[owner[nm]]))]
                      if lin is not None else [])
        for m, ds in models.items():
            width = 5 if corrected[m] else 4
            if "parameter" not in ds.dims or nm not in ds["parameter"].values:
                row += [DASH] * width
                continue
            p = ds.sel(parameter=nm)
            free = bool(p["free"]) if "free" in ds else True
            value = float(p["value"])
            if nm in dropped[m]:
                row += ["dropped"] + [DASH] * (width - 1)
            elif not free:
                row += [num(value) if value != 0.0 else DASH] + ["fixed"] * (width - 2) + [""]
            else:
                cr = float(p["cramer_rao_percent"]) if "cramer_rao_percent" in ds else np.nan
                ins = (float(p["insensitivity_percent"]) if "insensitivity_percent" in ds
                       else np.nan)
                row += [num(value), num(cr, ".1f")]
                worst = cr
                if corrected[m]:
                    crc = float(p["cramer_rao_percent_corrected"])
                    row += [num(crc, ".1f")]
                    worst = max(cr, crc) if np.isfinite(crc) else cr
                mark = guideline_mark(worst, ins) if np.isfinite(cr) or np.isfinite(ins) else ""
                row += [num(ins, ".1f"), f'<td class="fail">&#9888; {esc(mark)}</td>'
                        if mark else ""]
        rows.append(row)
    return header, rows


def section_derivatives(ctx: Context) -> str:
    """Stability (Table 2) and control derivatives with delays (Table 3) of every model, with
    Cramer-Rao bounds and insensitivities in percent, and the truth linearisation's value."""
    models = read.models(ctx.tree)
    if not any("parameter" in m.dims for m in models.values()):
        return ""
    parts = ['<p>Values in analysis units (ft/s, deg/s, deg, % of travel; delays in s). '
             'CR %: Cramer-Rao bound, I %: insensitivity, both in percent of |value| '
             '(frequency domain: CIFER convention, docs/methods.md, "Accuracy"); CRc %: the '
             'bound corrected for the residuals (time domain: coloured residuals; frequency '
             'domain: the CIFER bound scaled by the fit residuals); '
             '"dropped": removed by model reduction; "fixed": held at the value shown; '
             f'"{DASH}": not in that model. &#9888; marks a parameter above the '
             f'{GUIDELINES["cramer_rao_percent"]:g} % Cramer-Rao guideline (on the larger '
             f'of CR % and CRc %) or the {GUIDELINES["insensitivity_percent"]:g} % '
             'insensitivity guideline: poorly determined, whatever its value.</p>']
    for table_id, title, kinds in (
            ("table-derivatives-stability", "Table 2 — stability derivatives", ("A",)),
            ("table-derivatives-control", "Table 3 — control derivatives and time delays",
             ("B", "C", "D", "delay"))):
        header, rows = _derivative_rows(ctx, models, kinds)
        anchor = table_id
        ctx.anchors[anchor] = title
        parts.append(f'<h3 id="{anchor}-title">{esc(title)}</h3>')
        parts.append(html_table(header, rows, "numeric derivatives", raw=True,
                                table_id=anchor) if rows
                     else not_available(f"no parameters for {title}"))
    parts.append(tied_parameters_note(models))
    parts.append(_equivalents_table(ctx, models))
    return "".join(parts)


def tied_parameters_note(models: Mapping[str, xr.Dataset]) -> str:
    """A paragraph naming each tied parameter (``also``: one value on several entries) and
    the further entries it sets with their scales; empty when no model has one."""
    tied = {}
    for ds in models.values():
        if "also" not in ds or "parameter" not in ds.dims:
            continue
        for k, name in enumerate(map(str, ds["parameter"].values)):
            entries = parse_tied_entries(ds["also"].values[k] or "")
            if entries:
                matrix = str(ds["matrix"].values[k])
                tied[name] = ", ".join(f"{matrix}[{r},{c}] (x {scale:g})"
                                       for r, c, scale in entries)
    if not tied:
        return ""
    items = "; ".join(f"{esc(name)} also sets {esc(text)}" for name, text in tied.items())
    return (f"<p>Tied parameters (one value on several entries, each times its scale; "
            f"the tables show the first entry): {items}.</p>")


def _equivalents_table(ctx: Context, models: dict[str, xr.Dataset]) -> str:
    """Every dominant derivative a higher-order model implies (its extra states
    residualised), beside the truth's quasi-steady values; empty for quasi-steady models
    (:func:`sysid.assess.comparison.dominant_equivalents`)."""
    equivalents = dominant_equivalents(ctx.tree, models, every=True)
    if not equivalents:
        return ""
    lin = read.linearization(ctx.tree)
    names = [n for n in DOMINANT if any(n in eq.parameter.values for eq in equivalents.values())]
    header = ["derivative", "truth"]
    for m, eq in equivalents.items():
        header += [f"{m}: value", f"{m}: CR %"] + (
            [f"{m}: CRc %"] if "cramer_rao_corrected" in eq else [])
    rows = []
    for nm in names:
        row = [nm, num(_truth_value(lin, nm, lin))]
        for eq in equivalents.values():
            cells = [DASH, DASH] + ([DASH] if "cramer_rao_corrected" in eq else [])
            if nm in eq.parameter.values:
                v = float(eq["value"].sel(parameter=nm))
                cells = [num(v)] + [num(100 * float(eq[b].sel(parameter=nm)) / abs(v), ".3g")
                                    for b in ("cramer_rao", "cramer_rao_corrected")
                                    if b in eq]
            row += cells
        rows.append(row)
    anchor = "table-derivatives-equivalent"
    residualized = ", ".join(sorted({s for eq in equivalents.values()
                                     for s in eq.attrs["residualized"].split(",") if s}))
    ctx.anchors[anchor] = "Quasi-steady equivalents"
    return (f'<h3 id="{anchor}-title">Quasi-steady equivalents</h3>'
            f"<p>The dominant derivatives the model implies with its extra states "
            f"({esc(residualized)}) residualised, as a 6-DoF model would report them "
            f"(docs/methods.md, \"Model structure\"); bounds propagated to first order "
            f"from the parameters' bounds and correlations. Truth: its quasi-steady "
            f"linearisation.</p>"
            + html_table(header, rows, "numeric derivatives", raw=True, table_id=anchor))


# -- Fidelity scoreboard ---------------------------------------------------------------------


#: How the scoreboard labels the kind of bound an error is judged on (plain bounds: none).
_BOUND_LABEL = {"selection": " (random error + selection)", "random_error": " (random error)",
                "scaled": " (residual-scaled)",
                "corrected": " (corrected)"}


def section_fidelity(ctx: Context) -> str:
    """Each identified derivative's error against the truth's quasi-steady linearisation in
    units of its own calibrated bound (frequency domain: from the spectral random error; time
    domain: corrected for coloured residuals; the plain Cramer-Rao bound beside it), flagged
    with the reason beyond :data:`~sysid.core.guidelines.BIAS_BOUNDS_MAX` bounds
    (:func:`sysid.assess.comparison.fidelity_scoreboard`)."""
    models = {m: ds for m, ds in read.models(ctx.tree).items()
              if "parameter" in ds.dims and "cramer_rao" in ds}
    if not models:
        return ""
    # a higher-order structure (e.g. flapping): the truth reduced to its states
    truth = truth_for_model(ctx.tree, next(iter(models.values())))
    if truth is None:  # no truth to measure the errors against: omitted
        return ""
    reduced = set(map(str, truth["A"].state.values)) != set(
        map(str, read.linearization(ctx.tree)["A"].state.values))
    comparison = (ctx.tree["comparison"].to_dataset(inherit=False)
                  if "comparison" in ctx.tree.children else xr.Dataset())
    board = fidelity_scoreboard(models, truth, in_band=comparison.get("truth_in_band"))
    names = [str(n) for n in board.parameter.values
             if np.isfinite(float(board["truth"].sel(parameter=n)))]
    banded = {m for m in models
              if np.isfinite(board["truth_in_band"].sel(model=m).values).any()}
    header = ["parameter", "truth"]
    for m in models:
        header += [f"{m}: value", f"{m}: CR", f"{m}: bound", f"{m}: error / bound"]
        header += [f"{m}: truth in band", f"{m}: error / bound in band"] if m in banded else []
        header += [f"{m}: flag"]
    rows, flagged = [], {m: [] for m in models}
    for nm in names:
        row = [nm, num(float(board["truth"].sel(parameter=nm)))]
        for m in models:
            cell = board.sel(parameter=nm, model=m)
            if not np.isfinite(float(cell["value"])):
                row += [DASH] * (6 if m in banded else 4) + [""]
                continue
            kind = str(cell["bound_kind"].values)
            flag = bool(cell["bias_flag"])
            if flag:
                flagged[m].append(nm)
            why = str(cell["bias_reason"].values) or BIAS_MEANING
            row += [num(float(cell["value"])), num(float(cell["cramer_rao"]), ".3g"),
                    num(float(cell["bound"]), ".3g") + _BOUND_LABEL.get(kind, ""),
                    num(float(cell["error_in_bounds"]), ".1f")]
            if m in banded:
                row += [num(float(cell["truth_in_band"])),
                        num(float(cell["band_error_in_bounds"]), ".1f")]
            row += [f'<td class="fail">&#9888; {esc(why)}</td>' if flag else ""]
        rows.append(row)
    ctx.anchors["table-fidelity"] = "Fidelity scoreboard"
    summary = "; ".join(f"{esc(m)}: {len(v)} of "
                        f"{int(np.isfinite(board['error_in_bounds'].sel(model=m)).sum())} "
                        f"flagged" + (f" ({esc(', '.join(v))})" if v else "")
                        for m, v in flagged.items())
    against = ("linearisation reduced to the model's states" if reduced else
               "quasi-steady linearisation")
    text = (f"<p>Each identified derivative against the truth model's {against}, "
            f"the error in units of the estimate's own one-sigma bound, the one "
            f"that does not count a repeatable misfit as noise (frequency domain: from the "
            f"spectral random error; time domain: corrected for coloured residuals; else the "
            f"plain bound; their Monte Carlo calibration: docs/methods.md, \"Accuracy\"). "
            f"CR is the plain Cramer-Rao bound (frequency domain: CIFER "
            f"convention) on which the guidelines' marks are judged. &#9888; where the error "
            f"exceeds {BIAS_BOUNDS_MAX:g} bounds: the noise cannot explain it, so the model "
            f"structure or the data are the cause; the flag says which where the fit shows "
            f"it (frequency domain: within the fit's own residuals, a structure misfit). "
            + (f"'Truth in band' is the structure fitted to the truth's exact responses at the "
               f"frequency-domain estimate's own points and weights: an estimate within "
               f"{BIAS_BOUNDS_MAX:g} bounds of it but not of the truth is off by the structure's "
               f"error, not the data's. " if banded else "")
            + f"{summary}.</p>")
    return text + html_table(header, rows, "numeric fidelity", raw=True,
                             table_id="table-fidelity")


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


def section_guidelines(ctx: Context, pair_results: dict[str, PairResult], time: dict) -> str:
    """Cost, accuracy and verification guidelines per model, and the coherence of the data,
    as PASS/FAIL tables."""
    models = read.models(ctx.tree)
    columns = list(models) + [s for s in time["j_rms"] if s not in models]
    if not columns and not pair_results:
        return ""
    g = GUIDELINES
    rows = []

    def row(key: str, label: str, cells: list[str]):
        rows.append(f'<tr data-guideline="{esc(key)}"><th>{esc(label)}</th>'
                    + "".join(cells) + "</tr>")

    def cell(value: float | None, ok: bool | None, model: str, text: str | None = None):
        shown = text if text is not None else num(value, ".3g")
        return verdict_cell(shown, None if value is None or np.isnan(value) else ok,
                            model=model)

    cells = []
    for m in columns:
        ja = read.j_ave(models[m]) if m in models else None
        cells.append(cell(ja, ja is not None and ja <= g["J_ave"], m))
    row("J_ave", f"J_ave ≤ {g['J_ave']:g}", cells)
    cells = []
    for m in columns:
        costs = read.pair_costs(models[m]) if m in models else {}
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
            cells.append(cell(v, v <= g[key], m, f"max {num(v, '.3g')} % ({name})"
                              if name else None))
        row(key, f"{label} ≤ {g[key]:g} % (free parameters)", cells)
    cells = []
    for m in columns:
        if m not in models:
            cells.append(cell(None, None, m))
            continue
        found = undetermined_parameters(models[m])
        text = format_undetermined(found) if found else "none"
        cells.append(cell(float(len(found)), None, m, text))
    row("undetermined", f"undetermined by the data: CR > {UNDETERMINED_PERCENT:g} % "
        "(information)", cells)
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
    head = "".join(f"<th>{esc(plots.source_label(m))}</th>" for m in columns)
    model_table = (f'<table class="numeric guidelines" id="table-guidelines"><thead><tr>'
                   f'<th>guideline</th>{head}</tr></thead><tbody>{"".join(rows)}</tbody></table>')
    data_rows = []
    for pair, r in pair_results.items():
        rng = (f"{r.fit_range[0]:.3g}–{r.fit_range[1]:.3g}" if r.fit_range
               else "whole data range")
        data_rows.append([pair, rng, num(r.coherence_min, ".3f"),
                          num(100 * r.coherence_fraction, ".0f"),
                          verdict_cell(num(r.coherence_min, ".3f"),
                                       None if np.isnan(r.coherence_min)
                                       else r.coherence_min >= g["coherence"], pair=pair)])
    data_table = (html_table(["pair", "fit range [rad/s]", "min γ²", f"% ≥ {g['coherence']:g}",
                              f"min γ² ≥ {g['coherence']:g}"], data_rows, "numeric", raw=True,
                             table_id="table-coherence") if data_rows else "")
    return ("<p>Thresholds from the rotorcraft system-identification guidelines "
            "(Tischler &amp; Remple 2012; sysid's docs/methods.md, Guidelines). "
            "n/a: the quantity is not in the campaign.</p>"
            + (model_table if columns else "")
            + (f"<h3>Composite coherence over the fitted range (γ² ≥ {g['coherence']:g})</h3>"
               + data_table if data_rows else ""))


# -- Model reduction -------------------------------------------------------------------------


def section_reduction(ctx: Context) -> str:
    """Model reduction steps of each model, one row per step."""
    models = read.models(ctx.tree)
    parts = []
    for m, ds in models.items():
        steps = read.reduction(ctx.tree, m, ds)
        if not steps:
            continue
        keys = []
        for s in steps:
            keys += [k for k in s if k not in keys]
        rows = [[str(k + 1)] + [_format_cell(s.get(key)) for key in keys]
                for k, s in enumerate(steps)]
        parts.append(f"<h3>{esc(m)}</h3>" + html_table(["step"] + keys, rows, "numeric"))
    return "".join(parts)


def _format_cell(value) -> str:
    if value is None:
        return DASH
    if isinstance(value, bool):
        return "yes" if value else "no"
    if isinstance(value, (int, float)):
        return num(value, ".4g")
    return str(value)


# -- Provenance ------------------------------------------------------------------------------


def section_provenance(ctx: Context) -> str:
    """Versions, seeds, FMU identity, campaign settings and creation time."""
    root = ctx.tree.to_dataset(inherit=False).attrs
    rows = [["report created", _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds")],
            ["sysid version (report)", __version__],
            ["sysid version (campaign)", str(root.get("sysid_version", DASH))],
            ["campaign", str(root.get("campaign", root.get("name", DASH)))],
            ["flight condition", str(root.get("flight_condition", DASH))],
            ["campaign seed", str(root.get("seed", DASH))],
            ["python", platform.python_version()], ["numpy", np.__version__],
            ["xarray", xr.__version__], ["matplotlib", importlib.metadata.version("matplotlib")]]
    fmus = {}
    seeds = []
    for name, m in read.maneuvers(ctx.tree).items():
        if "fmu_name" in m.attrs or "fmu_guid" in m.attrs:
            fmus[(str(m.attrs.get("fmu_name", DASH)), str(m.attrs.get("fmu_guid", DASH)))] = 1
        if "seed" in m.attrs:
            seeds.append(f"{name}: {m.attrs['seed']}")
    for name, guid in fmus:
        rows.append(["FMU name / GUID", f"{name} / {guid}"])
    if seeds:
        rows.append(["manoeuvre seeds", ", ".join(seeds)])
    for m, ds in read.models(ctx.tree).items():
        info = [f"{k}={ds.attrs[k]}" for k in ("method", "estimator", "structure",
                                                "optimizer", "start", "pairs")
                if k in ds.attrs]
        if info:
            rows.append([f"model {m}", "; ".join(map(str, info))])
    # Stamped by sysid.pipeline.study on each stage's group: seconds the stage took when computed.
    timings = [f"{node.path.strip('/')} {float(node.attrs['workflow_elapsed_s']):.1f} s"
               for node in ctx.tree.subtree if "workflow_elapsed_s" in node.attrs]
    if timings:
        rows.append(["workflow stage times", ", ".join(timings)])
    toml = root.get("campaign_toml")
    settings = f"<h3>Campaign settings</h3><pre>{esc(toml)}</pre>" if toml else ""
    return (html_table(["item", "value"], rows, "provenance", table_id="table-provenance")
            + settings)


#: Sections in report order: (anchor, heading, paper items).
SECTIONS = (
    ("trim", "Trim", "Table 1"),
    ("inputs", "Inputs", "Figure 1"),
    ("conditioning", "Conditioning", "Figures 2-3"),
    ("pairs", "Input/output pairs", "Figures 4-15"),
    ("time", "Time-domain verification", "Figures 16-19"),
    ("derivatives", "Derivatives", "Tables 2-3"),
    ("fidelity", "Fidelity scoreboard", ""),
    ("guidelines", "Cost and guideline summary", ""),
    ("reduction", "Model reduction", ""),
    ("handling_qualities", "Handling qualities (ADS-33E-PRF) and hold margins", ""),
    ("provenance", "Provenance", ""),
)


def index(ctx: Context, sections=SECTIONS) -> str:
    """Map every paper figure/table number to the report anchors that reproduce it;
    ``sections`` are the ones on the page (default all)."""
    def link(anchor: str, text: str) -> str:
        return f'<a href="#{anchor}">{esc(text)}</a>'

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
        a = f"pair-{slug(pair)}"
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
    body = "".join(f"<tr><td>{r[0]}</td><td>{esc(r[1])}</td><td>{r[2]}</td></tr>"
                   for r in rows)
    sections = " · ".join(link(a, h) for a, h, _ in sections)
    return (f'<nav id="index"><h2>Index</h2><p>Sections: {sections}</p>'
            f'<table id="table-index"><thead><tr><th>paper item</th><th>content</th>'
            f'<th>in this report</th></tr></thead><tbody>{body}</tbody></table></nav>')
