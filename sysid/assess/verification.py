"""Time-domain verification of an identified model on manoeuvres not used to fit it
(CIFER's VERIFY; docs/methods.md, "Time-domain fit and verification"; Tischler & Remple 2012,
ch. 14).

The model is *held*: its derivatives and delays are not touched. It is simulated
(:func:`sysid.models.simulate`, exact zero-order hold with the per-entry delays) with the
recorded inputs of the manoeuvre, as perturbations about the record's ``trim_<channel>``
attributes, from zero initial state. Only two kinds of constants are estimated, by one
linear least-squares problem over all outputs and samples:

- a **bias** ``b_j`` per output ``j``: a constant added to the simulated output (sensor
  offsets, trim mismatch of the measurement);
- a **reference shift** ``s_c`` per input ``c``: a constant added to the recorded input
  before it drives the model (a control trim or rigging offset between the model's reference
  and the record's), i.e. the model sees ``u_c(t) + s_c``.

Because the model is linear, ``y_j(t) = y_j^0(t) + sum_c s_c h_jc(t) + b_j`` with ``y^0`` the
response to the recorded inputs and ``h_jc`` the response of output j to a unit constant on
input c (a step at t = 0, delays included). The constants minimise

    J_rms^2 = 1/(n_t n_o) sum_t sum_j W_j (z_j(t) - y_j(t))^2

so the reported ``J_rms`` is the smallest the held model can reach. Unidentifiable
combinations (e.g. an input without effect) get the minimum-norm solution.

Metrics, per model and manoeuvre: ``J_rms`` (:func:`sysid.assess.metrics.j_rms`, default weights
1 per ft/s, deg/s, deg; guideline :data:`sysid.assess.metrics.J_RMS_GUIDELINE`) and Theil's
inequality coefficient per output (:func:`sysid.assess.metrics.theil_inequality`, guideline
:data:`sysid.assess.metrics.TIC_GUIDELINE`), both on the perturbations about the record's trim (TIC
of absolute values would be dominated by the trim).

Result layout (docs/data_model.md, ``/verification/<maneuver>``): one variable per output
channel with dims ``(source, time)``, absolute values in analysis units, ``source = ["truth",
<method>, ...]`` ("truth" is the recorded data); the recorded controls as ``(time)``
variables; ``tic (source, channel)``, ``j_rms (source)`` (0 for "truth"), ``bias (source,
channel)`` and ``reference_shift (source, input)`` (NaN for "truth").
:func:`merge_verifications` joins the verifications of several models of one manoeuvre.
"""

from __future__ import annotations

import json
from typing import Mapping, Sequence

import numpy as np
import xarray as xr

from sysid.core.errors import IdentificationError, InputDataError
from sysid.models import simulate
from sysid.core.units import CHANNELS, channel_attrs
from sysid.data.campaign import record_trim
from sysid.assess.metrics import J_RMS_GUIDELINE, TIC_GUIDELINE, j_rms, theil_inequality

__all__ = ["ESTIMATES", "verify", "verify_maneuvers", "merge_verifications",
           "verification_table"]

#: What :func:`verify` can estimate.
ESTIMATES = ("bias", "reference_shift")


def _trim(ds: xr.Dataset, channel: str) -> float:
    return record_trim(ds, channel)


def _source_name(model: xr.Dataset, source: str | None) -> str:
    name = source or str(model.attrs.get("method", "") or "model")
    if name == "truth":
        raise InputDataError("verify: a model cannot be called 'truth' (reserved for the data)")
    return name


def verify(model: xr.Dataset, record: xr.Dataset, *,
           estimate: Sequence[str] = ESTIMATES, outputs: Sequence[str] | None = None,
           weights: Mapping[str, float] | None = None, source: str | None = None
           ) -> xr.Dataset:
    """Verify a held model on one manoeuvre: simulate, fit biases / reference shifts, score.

    Parameters
    ----------
    model : xr.Dataset
        Model Dataset (docs/data_model.md), any method.
    record : xr.Dataset
        Time history with the model's inputs (absolute %) and measured outputs (absolute,
        analysis units), ``trim_<channel>`` attributes (else the first-second mean is trim).
    estimate : sequence of {"bias", "reference_shift"}
        Constants to estimate (see the module docstring); ``()`` for a pure simulation.
    outputs : sequence of str, optional
        Compared outputs (default: every model output present in the record).
    weights : mapping, optional
        ``output -> W_j`` for J_rms and for the least squares (default 1).
    source : str, optional
        Name of the model in the result (default: its ``method`` attribute).

    Returns
    -------
    xr.Dataset
        ``/verification/<maneuver>`` layout (module docstring) with source
        ``["truth", source]``.
    """
    bad = set(estimate) - set(ESTIMATES)
    if bad:
        raise InputDataError(f"verify: cannot estimate {sorted(bad)}; choose from {ESTIMATES}")
    name = _source_name(model, source)
    maneuver = str(record.attrs.get("maneuver", "record"))
    inputs = [str(c) for c in model["B"].input.values]
    model_outputs = [str(o) for o in model["C"].output.values]
    if outputs is None:
        outputs = [o for o in model_outputs if o in record.data_vars]
    outputs = list(outputs)
    if not outputs:
        raise InputDataError(f"verify: manoeuvre {maneuver!r} measures none of the model "
                             f"outputs {model_outputs}")
    missing = [c for c in inputs + outputs if c not in record.data_vars]
    if missing:
        raise InputDataError(f"verify: manoeuvre {maneuver!r} lacks channel(s) {missing} "
                             f"(has {sorted(map(str, record.data_vars))})")
    unknown = [o for o in outputs if o not in model_outputs]
    if unknown:
        raise InputDataError(f"verify: {unknown} are not outputs of the model "
                             f"({model_outputs})")
    t = np.asarray(record["time"].values, float)
    trim_in = {c: _trim(record, c) for c in inputs}
    trim_out = {o: _trim(record, o) for o in outputs}
    u = xr.Dataset({c: ("time", np.asarray(record[c].values, float) - trim_in[c])
                    for c in inputs}, coords={"time": t})
    Z = np.stack([np.asarray(record[o].values, float) - trim_out[o] for o in outputs], 1)
    Y0 = _finite_response(model, u, outputs, name, maneuver)
    W = np.array([float((weights or {}).get(o, 1.0)) for o in outputs])
    bias, shift, Y = _estimate(model, name, u, Z, Y0, outputs, inputs, W, estimate)
    return _result(record, maneuver, name, t, outputs, inputs, trim_in, trim_out, Z, Y, W,
                   bias, shift, estimate, model)


def _outputs(sim: xr.Dataset, outputs) -> np.ndarray:
    return np.stack([np.asarray(sim[o].values, float) for o in outputs], 1)


def _finite_response(model, u: xr.Dataset, outputs, name: str, maneuver: str) -> np.ndarray:
    """The model's simulated outputs, or a clear error when they are not finite (a fit that
    ran away leaves a model whose response overflows; nothing can be verified with it)."""
    with np.errstate(over="ignore", invalid="ignore"):
        Y = _outputs(simulate(model, u), outputs)
    if not np.all(np.isfinite(Y)):
        worst = ""
        if "value" in model:
            magnitude = np.nan_to_num(np.abs(model["value"].values.astype(float)), nan=np.inf)
            k = int(np.argmax(magnitude))
            worst = (f"; its largest parameter is {model['parameter'].values[k]} = "
                     f"{float(model['value'].values[k]):.3g}")
        raise IdentificationError(
            f"verify: model {name!r} gives non-finite outputs on {maneuver!r}: the identified "
            f"model is unusable (a parameter ran away in the fit{worst})")
    return Y


def _estimate(model, name: str, u: xr.Dataset, Z, Y0, outputs, inputs, W, estimate):
    """Linear least squares for the biases and reference shifts (weighted by W)."""
    n_t, p = Z.shape
    cols, kinds = [], []
    if "bias" in estimate:
        for j in range(p):
            col = np.zeros((n_t, p))
            col[:, j] = 1.0
            cols.append(col)
            kinds.append(("bias", j))
    if "reference_shift" in estimate:
        for k, c in enumerate(inputs):
            step = u.copy()
            for other in inputs:
                step[other] = ("time", np.full(n_t, 1.0 if other == c else 0.0))
            cols.append(_finite_response(model, step, outputs, name,
                                         f"reference-shift step on {c}"))
            kinds.append(("shift", k))
    bias = np.zeros(p)
    shift = np.zeros(len(inputs))
    Y = Y0.copy()
    if cols:
        sw = np.sqrt(W)[None, :]
        X = np.stack([(col * sw).ravel() for col in cols], 1)
        coef = np.linalg.lstsq(X, ((Z - Y0) * sw).ravel(), rcond=None)[0]
        for (kind, k), val, col in zip(kinds, coef, cols):
            Y += val * col
            if kind == "bias":
                bias[k] = val
            else:
                shift[k] = val
    return bias, shift, Y


def _result(record, maneuver, name, t, outputs, inputs, trim_in, trim_out, Z, Y, W, bias,
            shift, estimate, model) -> xr.Dataset:
    coords = {"time": ("time", t, {"units": "s", "long_name": "time"}),
              "source": ["truth", name], "channel": list(outputs), "input": list(inputs)}
    measured = xr.Dataset({o: ("time", Z[:, j]) for j, o in enumerate(outputs)},
                          coords={"time": t})
    simulated = xr.Dataset({o: ("time", Y[:, j]) for j, o in enumerate(outputs)},
                           coords={"time": t})
    wmap = dict(zip(outputs, W.tolist()))
    jr = j_rms(measured, simulated, weights=wmap)
    tic = [float(theil_inequality(measured[o], simulated[o])) for o in outputs]
    data = {}
    for j, o in enumerate(outputs):
        attrs = channel_attrs(o) if o in CHANNELS else {}
        attrs = dict(attrs, trim=trim_out[o])
        data[o] = (("source", "time"), np.stack([Z[:, j], Y[:, j]]) + trim_out[o], attrs)
    for c in inputs:
        if c in record.data_vars:
            attrs = channel_attrs(c) if c in CHANNELS else {}
            data[c] = ("time", np.asarray(record[c].values, float), dict(attrs, trim=trim_in[c]))
    data["tic"] = (("source", "channel"), np.array([np.zeros(len(outputs)), tic]),
                   {"long_name": "Theil inequality coefficient (perturbations)",
                    "guideline": TIC_GUIDELINE})
    data["j_rms"] = (("source",), np.array([0.0, jr]),
                     {"long_name": "weighted rms output error", "guideline": J_RMS_GUIDELINE})
    data["bias"] = (("source", "channel"), np.array([np.full(len(outputs), np.nan), bias]),
                    {"long_name": "estimated output bias"})
    data["reference_shift"] = (("source", "input"),
                               np.array([np.full(len(inputs), np.nan), shift]),
                               {"long_name": "estimated input reference shift", "units": "%"})
    attrs = {"maneuver": maneuver, "kind": str(record.attrs.get("kind", "")),
             "axis": str(record.attrs.get("axis", "")),
             f"estimated_{name}": ",".join(estimate) or "none",
             f"weights_{name}": json.dumps(wmap),
             "metrics_on": "perturbations about the record's trim_<channel>",
             "J_rms_guideline": J_RMS_GUIDELINE, "TIC_guideline": TIC_GUIDELINE,
             f"structure_{name}": str(model.attrs.get("structure", ""))}
    return xr.Dataset(data, coords=coords, attrs=attrs)


def verify_maneuvers(model: xr.Dataset, records: Sequence[xr.Dataset], **kwargs
                     ) -> dict[str, xr.Dataset]:
    """:func:`verify` on each record: ``{maneuver: verification Dataset}``."""
    out = {}
    for rec in records:
        ds = verify(model, rec, **kwargs)
        out[ds.attrs["maneuver"]] = ds
    return out


def merge_verifications(datasets: Sequence[xr.Dataset]) -> xr.Dataset:
    """Join verifications of one manoeuvre by several models into one Dataset.

    ``source`` becomes ``["truth", <each model>...]`` (a model verified twice keeps its last
    verification); channels are the union (NaN where a model lacks one). The recorded data
    must be the same (same manoeuvre name and time grid).
    """
    datasets = [d for d in datasets if d is not None]
    if not datasets:
        raise InputDataError("merge_verifications: nothing to merge")
    first = datasets[0]
    for d in datasets[1:]:
        if d.attrs.get("maneuver") != first.attrs.get("maneuver"):
            raise InputDataError(f"merge_verifications: manoeuvres differ "
                                 f"({first.attrs.get('maneuver')!r} vs "
                                 f"{d.attrs.get('maneuver')!r})")
        if d.sizes["time"] != first.sizes["time"] or not np.allclose(d["time"], first["time"]):
            raise InputDataError(f"merge_verifications: manoeuvre "
                                 f"{first.attrs.get('maneuver')!r} has different time grids")
    models: dict[str, xr.Dataset] = {}
    for d in datasets:
        for s in d["source"].values:
            if str(s) != "truth":
                models[str(s)] = d.sel(source=[s])
    truth = [d.sel(source=["truth"]) for d in datasets if "truth" in d["source"].values]
    timed = {k: v for d in datasets for k, v in d.data_vars.items()
             if v.dims == ("time",)}
    parts = [p.drop_vars(list(timed), errors="ignore") for p in truth[:1] + list(models.values())]
    merged = xr.concat(parts, dim="source", join="outer", data_vars="all",
                       coords="minimal", compat="override", combine_attrs="drop_conflicts")
    for k, v in timed.items():
        merged[k] = v
    # tic/j_rms of the truth row are 0 by definition (outer join filled channels with NaN)
    if "tic" in merged:
        merged["tic"].loc[dict(source="truth")] = 0.0
    attrs = {}
    for d in datasets:
        attrs.update(d.attrs)
    merged.attrs = attrs
    return merged


def verification_table(ds: xr.Dataset, *, j_rms_max: float = J_RMS_GUIDELINE,
                       tic_max: float = TIC_GUIDELINE) -> str:
    """Plain-text table of J_rms and TIC per output with PASS/FAIL against the guidelines."""
    channels = [str(c) for c in ds["channel"].values]
    head = f"{'model':<18}{'J_rms':>9}      " + "".join(f"{'TIC ' + c:>12}" for c in channels)
    lines = [f"verification of {ds.attrs.get('maneuver', '?')} (guidelines J_rms <= "
             f"{j_rms_max:g}, TIC <= {tic_max:g})", head]
    for s in ds["source"].values:
        if str(s) == "truth":
            continue
        jr = float(ds["j_rms"].sel(source=s))
        row = f"{str(s):<18}{jr:>9.3f} {'PASS' if jr <= j_rms_max else 'FAIL':<5}"
        for c in channels:
            v = float(ds["tic"].sel(source=s, channel=c))
            verdict = "" if not np.isfinite(v) else ("PASS" if v <= tic_max else "FAIL")
            row += f"{v:>7.3f} {verdict:<4}"
        lines.append(row + f"  (estimated: {ds.attrs.get(f'estimated_{s}', '?')})")
    return "\n".join(lines)

