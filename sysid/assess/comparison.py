"""The domain comparison: identified derivative sets beside the truth linearisation.

The paper's Tables 2-3 list, per derivative, the frequency-domain and the time-domain
estimates with their normalised Cramer-Rao bounds. :func:`derivative_table` builds that table
for any set of model Datasets (``docs/data_model.md``) plus the truth model's quasi-steady
linearisation, and :func:`sign_agreement` checks the paper's conclusion 8 (consistent signs
of the dominant derivatives). :func:`fidelity_scoreboard` puts each estimate's error against
the truth in units of its own bound and flags the errors beyond
:data:`~sysid.core.guidelines.BIAS_BOUNDS_MAX` bounds: a bias the noise cannot explain, i.e. a
structure or data problem. :func:`compare_models` builds a campaign's ``/comparison`` group
(the table and the scoreboard) from its ``/models`` and ``/linearization``.

Against a reduced-order structure the truth's own parameters are ambiguous: the linearisation
reduced to the structure's states is exact at low frequency, but a fit over a band weighs the
whole band. :func:`truth_in_band` fits the structure to the truth's exact responses in the
frequency-domain estimate's own band, points and weights, so that an error splits into the
structure's part (``truth_in_band - truth``) and the data's (``estimate - truth_in_band``).
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import IdentificationError, InputDataError
from sysid.core.guidelines import BIAS_BOUNDS_MAX, COHERENCE_MIN
from sysid.core.util import atomic_path
from sysid.data.campaign import CampaignData
from sysid.identify.frequency_domain import N_POINTS, identify_frequency_domain
from sysid.models import (frequency_response, model_from_dataset, parameter_values,
                          residualize_model)
from sysid.truth.linearize import truth_for_structure

#: The derivatives that dominate the hover dynamics (damping and on-axis control power).
DOMINANT = ("Z_w", "M_q", "L_p", "N_r", "M_lon", "L_lat", "Z_col", "N_ped")


def _free_entries(models: Mapping[str, xr.Dataset], names: Sequence[str]):
    """``(row, column, model, index)`` of every free parameter ``names[row]`` of the
    ``column``-th model (``index`` into its ``parameter`` dimension)."""
    for j, model in enumerate(models.values()):
        present = {str(p): k for k, p in enumerate(model.parameter.values)}
        for i, name in enumerate(names):
            k = present.get(name)
            if k is not None and bool(model["free"].values[k]):
                yield i, j, model, k


def derivative_table(models: Mapping[str, xr.Dataset], truth: xr.Dataset | None = None
                     ) -> xr.Dataset:
    """Value and CR % of every parameter free in any model, per method, plus the truth.

    Returns a Dataset over ``parameter`` and ``model`` (the method name) with ``value``, ``cramer_rao_percent``
    and ``free`` (False where a model fixed or dropped the parameter: its value is then
    NaN), and ``truth`` (parameter) from the linearisation (NaN for delays, which the
    quasi-steady truth does not have).
    """
    names: list[str] = []
    for model in models.values():
        for name, free in zip(model.parameter.values, model["free"].values):
            if bool(free) and str(name) not in names:
                names.append(str(name))
    methods = list(models)
    value = np.full((len(names), len(methods)), np.nan)
    cr = np.full_like(value, np.nan)
    free = np.zeros_like(value, dtype=bool)
    for i, j, model, k in _free_entries(models, names):
        free[i, j] = True
        value[i, j] = float(model["value"].values[k])
        cr[i, j] = float(model["cramer_rao_percent"].values[k])
    truth_values = parameter_values(truth, names)
    coords = {"parameter": names, "model": methods}
    return xr.Dataset(
        {
            "value": (("parameter", "model"), value),
            "cramer_rao_percent": (("parameter", "model"), cr, {"units": "%"}),
            "free": (("parameter", "model"), free),
            "truth": (("parameter",), truth_values,
                      {"long_name": "truth model's quasi-steady linearisation"}),
        },
        coords=coords,
        attrs={"long_name": "identified derivatives per method (paper Tables 2-3)"},
    )


#: What a scoreboard flag means (shown beside it in the report and by ``sysid compare``).
BIAS_MEANING = "bias beyond noise: a structure or data problem, not noise"

#: Why a flagged estimate is biased, per kind of bound it was judged on (``bias_reason``).
#: The frequency-domain ``selection`` and ``random_error`` flags are refined by the
#: residual-scaled bound (:data:`MISFIT_REASON` when the fit's own residuals cover the error,
#: else :data:`BEYOND_MISFIT_REASON`).
BIAS_REASONS = {
    "selection": ("bias beyond the random error and the point selection's scatter: structure "
                  "misfit"),
    "random_error": "bias beyond the random error: structure misfit",
    "corrected": ("bias beyond the coloured-residual bound: structure misfit, or coloured "
                  "residuals under feedback (the bound under-covers when the loop feeds the "
                  "disturbance into the inputs)"),
    "scaled": BIAS_MEANING,
    "cifer": BIAS_MEANING,
    "white": BIAS_MEANING,
}
#: Frequency domain, flagged on the noise bound (``selection`` or ``random_error``, the
#: scoreboard's ``bound_kind``) but within the residual-scaled bound.
MISFIT_REASON = ("bias beyond the noise bound, within the fit residuals: structure misfit "
                 "(repeatable, not noise)")
#: Frequency domain, flagged on the noise bound and beyond the residual-scaled bound too.
BEYOND_MISFIT_REASON = ("bias beyond the noise bound and the fit residuals: a data, start "
                        "or structure problem")
#: Flagged, and the structure fitted to the truth's exact responses in the same band, points
#: and weights (:func:`truth_in_band`) lands within the threshold of the estimate.
STRUCTURE_REASON = ("bias the truth's own responses share when fitted in the same band: the "
                    "structure's error, not the data's")
#: Flagged, and beyond the threshold of :func:`truth_in_band` too.
DATA_REASON = ("bias beyond the noise bound also against the truth fitted in the same band: "
               "the data (nonlinearity, turbulence, spectral estimates) or the start")


#: The bound each method's errors are judged on where the model carries it (docs/methods.md,
#: "Accuracy"): frequency domain the spectral random error and the point selection's scatter
#: in quadrature (neither counts the structure's repeatable misfit as noise; the random error
#: alone is calibrated on known systems but optimistic on the truth FMU, where the fitted
#: points move with the data), time domain corrected for coloured residuals.
CALIBRATED_BOUND = {"frequency_domain": "cramer_rao_total",
                    "time_domain": "cramer_rao_corrected"}


def _finite_positive(model: xr.Dataset, variable: str, k: int) -> float | None:
    if variable not in model:
        return None
    value = float(model[variable].values[k])
    return value if np.isfinite(value) and value > 0 else None


def _bound(model: xr.Dataset, k: int) -> tuple[float, float, str]:
    """``(plain bound, bound used, kind)`` of parameter ``k``: the bound calibrated against the
    seed-to-seed scatter where the model carries a finite one (frequency domain: random error
    and point selection, ``selection``; time domain: corrected for coloured residuals,
    ``corrected``), else the frequency-domain random-error bound alone (``random_error``),
    else its residual-scaled bound (``scaled``), else the plain Cramer-Rao bound (``cifer``
    or ``white``)."""
    plain = float(model["cramer_rao"].values[k])
    frequency = str(model.attrs.get("method", "")) == "frequency_domain"
    order = (((CALIBRATED_BOUND["frequency_domain"], "selection"),
              ("cramer_rao_noise", "random_error"), ("cramer_rao_corrected", "scaled"))
             if frequency else ((CALIBRATED_BOUND["time_domain"], "corrected"),))
    for variable, kind in order:
        used = _finite_positive(model, variable, k)
        if used is not None:
            return plain, used, kind
    return plain, plain, ("cifer" if frequency else "white")


def _reason(model: xr.Dataset, k: int, kind: str, error: float, threshold: float) -> str:
    """Why a flagged estimate (parameter ``k``) is biased (:data:`BIAS_REASONS`)."""
    if kind in ("selection", "random_error"):
        scaled = _finite_positive(model, "cramer_rao_corrected", k)
        if scaled is not None:
            return MISFIT_REASON if abs(error) <= threshold * scaled else BEYOND_MISFIT_REASON
    return BIAS_REASONS[kind]


def fidelity_scoreboard(models: Mapping[str, xr.Dataset], truth: xr.Dataset | None = None, *,
                        threshold: float = BIAS_BOUNDS_MAX,
                        in_band: xr.DataArray | None = None) -> xr.Dataset:
    """Each identified parameter's error against the truth in units of its own bound.

    For every parameter free in any model and every model (method): the estimate, its bound
    ``sigma`` (one standard deviation, :data:`CALIBRATED_BOUND`: frequency domain
    ``cramer_rao_total``, the spectral random error and the point selection's scatter; time
    domain
    ``cramer_rao_corrected``, corrected for coloured residuals; else the frequency-domain
    residual-scaled bound, else the plain Cramer-Rao bound; docs/methods.md, "Accuracy"),
    the truth's quasi-steady value, the error ``value - truth`` and

        z = |value - truth| / sigma,     flag = z > threshold (default 3)

    A flagged estimate is biased beyond what the noise explains (:data:`BIAS_MEANING`);
    ``bias_reason`` says why (:data:`BIAS_REASONS`). NaN where a model does not estimate the
    parameter or the truth has no value (delays). ``in_band`` (parameter, model), the values
    of :func:`truth_in_band` where known, gives ``band_error_in_bounds`` =
    ``|value - in_band| / sigma`` and decides a flag's reason: :data:`STRUCTURE_REASON`
    within the threshold, else :data:`DATA_REASON`.

    Returns a Dataset over ``parameter`` and ``model`` with ``value``, ``bound``,
    ``cramer_rao`` (the plain bound: CIFER convention or white noise, the one of the
    guidelines' CR % marks), ``bound_kind`` (``"selection"``, ``"random_error"``,
    ``"scaled"``, ``"cifer"``, ``"corrected"`` or ``"white"``), ``error``,
    ``error_in_bounds``, ``bias_flag``,
    ``bias_reason`` (empty where not flagged), ``truth`` (parameter), ``truth_in_band`` and
    ``band_error_in_bounds`` (NaN without ``in_band``); attribute ``bias_bounds_max`` (the
    threshold).

    Examples
    --------
    >>> board = fidelity_scoreboard(data.models(), data.quasi_steady())    # doctest: +SKIP
    >>> board["bias_reason"].sel(model="frequency_domain")                # doctest: +SKIP
    """
    table = derivative_table(models, truth)
    names = [str(n) for n in table.parameter.values]
    methods = list(models)
    shape = (len(names), len(methods))
    bound = np.full(shape, np.nan)
    plain = np.full(shape, np.nan)
    kind = np.full(shape, "", dtype=object)
    reason = np.full(shape, "", dtype=object)
    error = table["value"] - table["truth"]
    entries = list(_free_entries(models, names))
    for i, j, model, k in entries:
        plain[i, j], bound[i, j], kind[i, j] = _bound(model, k)
    with np.errstate(divide="ignore", invalid="ignore"):
        z = np.where(bound > 0, np.abs(error.values) / bound, np.nan)   # no bound: no score
    flag = np.isfinite(z) & (z > threshold)
    band = (np.full(shape, np.nan) if in_band is None else
            in_band.reindex(parameter=names, model=methods).transpose("parameter", "model")
            .values.astype(float))
    with np.errstate(divide="ignore", invalid="ignore"):
        band_z = np.where(bound > 0, np.abs(table["value"].values - band) / bound, np.nan)
    for i, j, model, k in entries:
        if flag[i, j]:
            reason[i, j] = (_reason(model, k, kind[i, j], float(error.values[i, j]), threshold)
                            if not np.isfinite(band_z[i, j]) else
                            STRUCTURE_REASON if band_z[i, j] <= threshold else DATA_REASON)
    dims = ("parameter", "model")
    return xr.Dataset(
        {
            "value": table["value"],
            "bound": (dims, bound, {"long_name": "bound used (one standard deviation)"}),
            "cramer_rao": (dims, plain, {"long_name": "plain Cramer-Rao bound"}),
            "bound_kind": (dims, kind.astype(str),
                           {"long_name": "selection (frequency domain, spectral random "
                                         "error and point selection), random_error "
                                         "(frequency domain, spectral random error), "
                                         "scaled (frequency domain, fit residuals), "
                                         "cifer (frequency domain, CIFER convention), "
                                         "corrected (time domain, coloured residuals) or "
                                         "white (time domain, white noise)"}),
            "error": error.assign_attrs(long_name="estimate minus truth"),
            "error_in_bounds": (dims, z, {"long_name": "|estimate - truth| / bound"}),
            "bias_flag": (dims, flag,
                          {"long_name": f"error beyond {threshold:g} bounds: {BIAS_MEANING}"}),
            "bias_reason": (dims, reason.astype(str),
                            {"long_name": "why a flagged estimate is biased (empty: no flag)"}),
            "truth": table["truth"],
            "truth_in_band": (dims, band, {"long_name": "the structure fitted to the truth's "
                                                        "exact responses in the estimate's "
                                                        "band, points and weights"}),
            "band_error_in_bounds": (dims, band_z,
                                     {"long_name": "|estimate - truth_in_band| / bound"}),
        },
        coords={"parameter": names, "model": methods},
        attrs={"long_name": "fidelity scoreboard: error against the truth in bounds",
               "bias_bounds_max": float(threshold), "bias_meaning": BIAS_MEANING},
    )


def truth_for_model(tree: xr.DataTree, model: xr.Dataset) -> xr.Dataset | None:
    """The truth a model's parameters are compared with: the quasi-steady linearisation
    ``/linearization``, or, for a model with states it lacks (e.g. flapping), the full one
    ``/linearization_full`` reduced to the model's structure
    (:func:`sysid.truth.linearize.truth_for_structure`), whose speed derivatives differ from
    the quasi-steady ones by the residualised rotor (hover_hybrid: L_v -0.39 against -6.69).
    None without a linearisation."""
    lin = (tree["linearization"].to_dataset(inherit=False)
           if "linearization" in tree.children else None)
    if lin is None or "A" not in lin:
        return None
    if ("linearization_full" not in tree.children or "A" not in model
            or set(map(str, model["A"].state.values)) <= set(map(str, lin["A"].state.values))):
        return lin
    try:
        return truth_for_structure(tree["linearization_full"].to_dataset(),
                                   model_from_dataset(model)[0])
    except (ValueError, KeyError, InputDataError):  # e.g. outputs the FMU does not have
        return lin


def truth_in_band(data: CampaignData, model: xr.Dataset) -> xr.Dataset | None:
    """A frequency-domain model's structure fitted to the truth's exact responses in the
    estimate's own band: the campaign's composite responses with ``H`` replaced by the truth
    linearisation's (the full one where the campaign has it), so the same coherence and
    random error select and weigh the same points; the estimate's pairs, coherence limit,
    band and points per pair; started at the estimate, the parameters it removed held, no
    reduction and no point-selection bootstrap (its bounds would be the noise-free data's).
    ``model - truth_in_band`` is the data's part of an error (noise, turbulence,
    nonlinearity, spectral estimates), ``truth_in_band - truth`` the structure's.

    None for a model of another method, or without composite responses or a linearisation
    with the responses' outputs and inputs (flight data).
    """
    if str(model.attrs.get("method", "")) != "frequency_domain" or "parameter" not in model.dims:
        return None
    fr = data.frequency_response()
    tree = data.tree
    name = ("linearization_full" if "linearization_full" in tree.children else
            "linearization" if "linearization" in tree.children else None)
    if fr is None or name is None:
        return None
    lin = tree[name].to_dataset(inherit=False)
    outputs, inputs = list(map(str, fr.output.values)), list(map(str, fr.input.values))
    if ("C" not in lin or not set(outputs) <= set(map(str, lin["C"].output.values))
            or not set(inputs) <= set(map(str, lin["B"].input.values))):
        return None
    exact = frequency_response(lin, fr.frequency.values).sel(output=outputs, input=inputs)
    responses = fr.assign(H=exact.transpose(*fr["H"].dims))
    attrs = model.attrs
    pairs = [tuple(p.split("/")) for p in str(attrs.get("pairs", "")).split(",") if p]
    band = (float(attrs["fit_omega_min"]), float(attrs["fit_omega_max"])) if (
        "fit_omega_min" in attrs and "fit_omega_max" in attrs) else None
    structure = model_from_dataset(model)[0]
    fit = identify_frequency_domain(
        responses, structure, pairs=pairs or None, start=model, frequency_range=band,
        coherence_min=float(attrs.get("coherence_min", COHERENCE_MIN)),
        n_points=int(attrs.get("n_points_per_pair", N_POINTS)), reduce=False,
        selection_draws=0)
    return fit.model.assign_attrs(method="truth_in_band", linearization=f"/{name}")


#: The bounds :func:`quasi_steady_equivalents` carries over (those a model has).
EQUIVALENT_BOUNDS = ("cramer_rao", "cramer_rao_corrected", "cramer_rao_noise",
                     "cramer_rao_total")


def quasi_steady_equivalents(model: xr.Dataset, quasi_steady: xr.Dataset,
                             names: Sequence[str] | None = None) -> xr.Dataset:
    """The quasi-steady derivatives a higher-order model implies, with propagated bounds.

    The model's extra states (e.g. flapping ``a1, b1``) are residualised
    (:func:`sysid.models.residualize_model`, ``z' = 0``) onto the states of ``quasi_steady``
    (a model Dataset, e.g. the truth's ``/linearization``), and each of its parameters is read
    as that structure reads it (the residualised entry minus the structure's fixed part,
    e.g. the kinematics). With ``f(theta)`` that map and ``G = df/dtheta`` (central
    differences), each bound ``sigma`` of :data:`EQUIVALENT_BOUNDS` the model has is carried
    over as

        sigma_eq = sqrt(diag(G D R D G^T)),     D = diag(sigma),  R = correlation

    (first-order propagation; the correlation is the plain Cramer-Rao one, the calibrated
    bounds rescale its variances). Why: a hybrid model's L_p, M_q, L_lat, M_lon are not its
    parameters, yet they are what a 6-DoF model, the paper's table and a Monte Carlo
    calibration compare.

    Parameters
    ----------
    model : xr.Dataset
        Identified model (``value``, ``free``, ``correlation`` and its bounds) with states
        ``quasi_steady``'s and more.
    quasi_steady : xr.Dataset
        Model Dataset whose parameters name the equivalents.
    names : sequence of str, optional
        The equivalents wanted (default every A/B parameter of ``quasi_steady``).

    Returns
    -------
    xr.Dataset
        Over ``parameter``: ``value`` and the bounds (absolute); attribute ``residualized``.

    Examples
    --------
    >>> eq = quasi_steady_equivalents(data.models()["time_domain"], data.quasi_steady(),
    ...                               names=DOMINANT)                   # doctest: +SKIP
    """
    target, _ = model_from_dataset(quasi_steady)
    states = list(target.states)
    wanted = [k for k in target.free_index
              if target.parameters[k].matrix in ("A", "B")
              and (names is None or target.parameters[k].name in names)]
    out_names = [target.parameters[k].name for k in wanted]
    at = {k: j for j, k in enumerate(target.free_index)}
    structure, theta = model_from_dataset(model)

    def f(th):
        reduced = residualize_model(structure.to_dataset(th), states)
        return target.values_from_model(reduced)[[at[k] for k in wanted]]

    value = f(theta)
    data = {"value": ("parameter", value)}
    free = list(structure.free_index)
    have = [b for b in EQUIVALENT_BOUNDS if b in model]
    if free and have and "correlation" in model:
        G = np.zeros((len(wanted), len(free)))
        for j, k in enumerate(free):
            h = 1e-6 * max(1.0, abs(theta[j]))
            up, down = theta.copy(), theta.copy()
            up[j] += h
            down[j] -= h
            G[:, j] = (f(up) - f(down)) / (2 * h)
        idx = [int(np.flatnonzero(model["parameter"].values == structure.parameters[k].name)[0])
               for k in free]
        R = np.nan_to_num(model["correlation"].values[np.ix_(idx, idx)])
        np.fill_diagonal(R, 1.0)
        for b in have:
            sigma = model[b].values[idx].astype(float)
            S = np.where(np.isfinite(sigma), sigma, 0.0)
            cov = G @ (S[:, None] * R * S[None, :]) @ G.T
            bound = np.sqrt(np.maximum(np.diag(cov), 0.0))
            bound[np.any((G != 0) & ~np.isfinite(sigma)[None, :], axis=1)] = np.nan
            data[b] = ("parameter", bound)
    return xr.Dataset(data, coords={"parameter": out_names},
                      attrs={"residualized": ",".join(s for s in structure.states
                                                      if s not in states)})


def dominant_equivalents(tree: xr.DataTree, models: Mapping[str, xr.Dataset], *,
                         every: bool = False) -> dict[str, xr.Dataset]:
    """Per model with states the quasi-steady ``/linearization`` lacks (flapping, inflow),
    the :func:`quasi_steady_equivalents` of the :data:`DOMINANT` derivatives it does not
    have as parameters (``every``: of all of them; e.g. an inflow model's Z_w is the
    thrust's, about three times the quasi-steady one); empty for quasi-steady models or
    without a linearisation."""
    if "linearization" not in tree.children:
        return {}
    lin = tree["linearization"].to_dataset(inherit=False)
    if "A" not in lin:
        return {}
    rigid = set(map(str, lin["A"].state.values))
    out = {}
    for method, model in models.items():
        if ("A" not in model or "parameter" not in model.dims
                or set(map(str, model["A"].state.values)) <= rigid):
            continue
        missing = [n for n in DOMINANT if every or n not in model.parameter.values]
        if missing:
            out[method] = quasi_steady_equivalents(model, lin, names=missing)
    return out


def compare_models(data: CampaignData) -> xr.Dataset:
    """The ``/comparison`` Dataset of a campaign: :func:`derivative_table` of every
    ``/models/<method>`` beside the truth linearisation ``/linearization`` (when present),
    with the :func:`fidelity_scoreboard` variables ``bound``, ``bound_kind``,
    ``error_in_bounds``, ``bias_flag``, ``bias_reason`` and, for a frequency-domain model,
    ``truth_in_band`` (:func:`truth_in_band`) and ``band_error_in_bounds``."""
    models = data.models()
    if not models:
        raise InputDataError(f"{data.source} has no identified models (/models/<method>); "
                             "run 'sysid identify' and/or 'sysid identify-time' first")
    truth = truth_for_model(data.tree, next(iter(models.values())))
    table = derivative_table(models, truth)
    in_band, failed = None, {}
    if truth is not None:
        fitted = {}
        for m, ds in models.items():
            try:
                fitted[m] = truth_in_band(data, ds)
            except (IdentificationError, InputDataError) as exc:  # a diagnostic: the table
                failed[m] = f"{type(exc).__name__}: {exc}"      # stands without it
        fitted = {m: ds for m, ds in fitted.items() if ds is not None}
        if fitted:
            names = [str(p) for p in table.parameter.values]
            in_band = xr.DataArray(
                np.array([parameter_values(fitted[m], names) if m in fitted
                          else np.full(len(names), np.nan) for m in models]).T,
                dims=("parameter", "model"), coords={"parameter": names, "model": list(models)})
    board = fidelity_scoreboard(models, truth, in_band=in_band)
    for name in ("bound", "bound_kind", "error_in_bounds", "bias_flag", "bias_reason",
                 "truth_in_band", "band_error_in_bounds"):
        table[name] = board[name]
    table.attrs.update(bias_bounds_max=board.attrs["bias_bounds_max"],
                       bias_meaning=BIAS_MEANING)
    if failed:
        table.attrs["truth_in_band_failed"] = json.dumps(failed)
    return table


def write_table_csv(table: xr.Dataset, path: str | Path) -> Path:
    """Write a :func:`derivative_table` as CSV (one row per parameter and model), atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        table.to_dataframe().reset_index().to_csv(tmp, index=False)
    return path


def relative_error(table: xr.Dataset) -> xr.DataArray:
    """``(value - truth) / |truth|`` per parameter and model."""
    return (table["value"] - table["truth"]) / abs(table["truth"])


def sign_agreement(table: xr.Dataset, parameters=DOMINANT) -> xr.DataArray:
    """True per parameter where every method that estimated it has the same sign."""
    present = [p for p in parameters if p in table.parameter.values]
    signs = np.sign(table["value"].sel(parameter=present))
    agree = (signs.max("model", skipna=True) == signs.min("model", skipna=True))
    return agree.assign_attrs(long_name="all methods agree on the sign")


def format_sign_agreement(table: xr.Dataset) -> str:
    """One line: the dominant derivatives whose sign differs between methods, if any."""
    agree = sign_agreement(table)
    differing = [str(p) for p, ok in zip(agree.parameter.values, agree.values) if not ok]
    return ("dominant derivatives with the same sign in every method: "
            + ("all" if not differing else f"all but {', '.join(differing)}"))


def format_table(table: xr.Dataset) -> str:
    """A text table like the paper's Tables 2-3 (value and CR % per method, truth)."""
    methods = [str(m) for m in table.model.values]
    head = f"{'parameter':<11}" + "".join(f"{m:>28}" for m in methods) + f"{'truth':>12}"
    sub = f"{'':<11}" + "".join(f"{'value':>16}{'CR %':>12}" for _ in methods)
    lines = [head, sub]
    for name in table.parameter.values:
        row = f"{str(name):<11}"
        for m in methods:
            cell = table.sel(parameter=name, model=m)
            if bool(cell["free"]):
                row += f"{float(cell['value']):>16.5g}{float(cell['cramer_rao_percent']):>12.1f}"
            else:
                row += f"{'dropped':>16}{'':>12}"
        truth = float(table["truth"].sel(parameter=name))
        row += f"{truth:>12.5g}" if np.isfinite(truth) else f"{'-':>12}"
        lines.append(row)
    return "\n".join(lines)


def format_scoreboard(board: xr.Dataset) -> str:
    """The fidelity scoreboard as text: per parameter and method the estimate, the plain
    Cramer-Rao bound (guidelines), the bound the error is judged on and its kind, the truth,
    the error in bounds and a flag beyond the threshold, then the flagged parameters grouped
    by reason (:func:`fidelity_scoreboard` or a ``/comparison`` Dataset that carries its
    variables)."""
    threshold = float(board.attrs.get("bias_bounds_max", BIAS_BOUNDS_MAX))
    methods = [str(m) for m in board.model.values]
    lines = [f"fidelity scoreboard: error against the truth in bounds (flag '!' beyond "
             f"{threshold:g}: {BIAS_MEANING})",
             f"{'parameter':<11}{'truth':>11}" + "".join(
                 f"{m[:22]:>53}" for m in methods),
             f"{'':<11}{'':>11}" + "".join(
                 f"{'value':>11}{'CR':>10}{'bound':>10}{'kind':>13}{'err/bd':>8}{'':>1}"
                 for _ in methods)]
    flagged: dict[str, dict[str, list[str]]] = {m: {} for m in methods}
    has_plain = "cramer_rao" in board
    has_reason = "bias_reason" in board
    for name in board.parameter.values:
        truth = float(board["truth"].sel(parameter=name))
        row = f"{str(name):<11}" + (f"{truth:>11.4g}" if np.isfinite(truth) else f"{'-':>11}")
        for m in methods:
            cell = board.sel(parameter=name, model=m)
            value, bound = float(cell["value"]), float(cell["bound"])
            if not np.isfinite(value):
                row += f"{'-':>11}{'':>10}{'':>10}{'':>13}{'':>8} "
                continue
            plain = float(cell["cramer_rao"]) if has_plain else np.nan
            z = float(cell["error_in_bounds"])
            flag = bool(cell["bias_flag"])
            if flag:
                why = str(cell["bias_reason"].values) if has_reason else BIAS_MEANING
                flagged[m].setdefault(why or BIAS_MEANING, []).append(str(name))
            row += (f"{value:>11.4g}" + (f"{plain:>10.3g}" if np.isfinite(plain) else f"{'-':>10}")
                    + f"{bound:>10.3g}{str(cell['bound_kind'].values):>13}"
                    + (f"{z:>8.1f}" if np.isfinite(z) else f"{'-':>8}") + ("!" if flag else " "))
        lines.append(row)
    lines.append("flagged: " + ", ".join(f"{m} {sum(map(len, r.values()))}"
                                         for m, r in flagged.items()))
    for m, reasons in flagged.items():
        for why, names in reasons.items():
            lines.append(f"  {m}: {', '.join(names)}: {why}")
    return "\n".join(lines)
