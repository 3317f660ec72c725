"""Accuracy of identified parameters: Cramer-Rao bounds, insensitivities, correlations.

Written from a *weighted residual Jacobian* so that every least-squares fit of the package
(frequency-domain CIFER cost, time-domain output error) shares it. If a fit minimises

    J(theta) = sum_k r_k(theta)^2 ,      r_k = sqrt(w_k) e_k(theta)

with ``e_k`` the raw errors and ``w_k`` the cost's weights, then with ``G = dr/dtheta``
(n_residual x n_parameter) the Gauss-Newton Hessian (information matrix) is

    H = G^T G = sum_k w_k (de_k/dtheta)(de_k/dtheta)^T                  (``scale`` = 1)

and (docs/methods.md, "Frequency-domain fit"; Tischler & Remple 2012)

    CR_i = sqrt( (H^-1)_ii )          Cramer-Rao bound (one standard deviation)
    I_i  = 1 / sqrt( H_ii )           insensitivity (the bound if theta_i alone were free)
    rho_ij = (H^-1)_ij / sqrt((H^-1)_ii (H^-1)_jj)    correlation

both also in percent of ``|theta_i|``. ``scale`` multiplies H: the time-domain output-error
fit passes ``scale = 1/sigma^2`` (residual variance) or whitens its residuals beforehand so
that H is the Fisher information; the frequency-domain fit uses the CIFER convention
``scale = 1`` (see :mod:`sysid.identify.frequency_domain`).

Coloured residuals (time domain). ``H^-1`` is the covariance of the estimate only when the
residuals are white. When they are coloured (unmodelled dynamics, turbulence),
:func:`coloured_residual_covariance` gives the sandwich form of Morelli & Klein (1997), the
correction SIDPAC's ``m_colores`` computes:

    Cov(theta) = M^-1 [ sum_i sum_j S(i)^T R_vv(i - j) S(j) ] M^-1

with ``S(i)`` the (whitened) output sensitivities at sample ``i``, ``M = sum_i S(i)^T S(i)``
and ``R_vv`` the autocorrelation of the (whitened) residuals, its lag sum truncated and
Bartlett-weighted (see the function).

A parameter the data carry no information about (a zero Jacobian column, or a direction of
``theta`` the cost cannot see) is *unidentifiable*: its bound and insensitivity are ``inf`` and
it is flagged, and the other parameters' bounds come from the pseudo-inverse restricted to the
identifiable subspace. Nothing raises on a singular H.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.fft
import xarray as xr

from sysid.core.guidelines import (CR_MAX_PERCENT, INSENSITIVITY_MAX_PERCENT,
                                   UNDETERMINED_PERCENT)

__all__ = ["ParameterStatistics", "parameter_statistics", "information_statistics",
           "correlated_pairs", "undetermined_parameters", "format_undetermined",
           "residual_autocorrelation", "correlation_lag", "coloured_residual_covariance",
           "ColouredBounds", "guideline_mark", "robust_scale", "OUTLYING_SCALES"]

#: Consistency factor of the median absolute deviation: ``1.4826 MAD`` estimates the
#: standard deviation of a normal sample (Rousseeuw & Croux 1993).
MAD_TO_STD = 1.4826
#: A draw further than this many robust scales from the median counts as outlying
#: (:func:`robust_scale`), as in the usual 3-sigma outlier rule.
OUTLYING_SCALES = 3.0
#: Multiple of the white-noise standard error ``1/sqrt(N)`` of a normalised autocorrelation
#: estimate below which the residual autocorrelation counts as decayed
#: (:func:`correlation_lag`): 2 is the usual 95 % whiteness band (Klein & Morelli 2006, 5.5).
WHITENESS_BAND = 2.0
#: The Bartlett window of the lag sum spans this many times the decay lag: the lags inside
#: the decay lag keep at least half their weight.
LAG_WINDOW_FACTOR = 2.0

#: Relative eigenvalue threshold of the normalised Hessian below which a direction is
#: considered not identifiable (rank decision of the pseudo-inverse).
RCOND = 1e-10


@dataclass
class ParameterStatistics:
    """Accuracy of a set of estimated parameters (arrays of shape (n_parameter,)).

    Attributes
    ----------
    names : tuple of str
    values : ndarray
    hessian : ndarray (n, n)
        ``H = scale * G^T G``.
    covariance : ndarray (n, n)
        ``H^-1`` (pseudo-inverse on the identifiable subspace; ``inf`` rows/columns for the
        unidentifiable parameters).
    cramer_rao, insensitivity : ndarray
        Absolute (units of the parameter); ``inf`` when unidentifiable.
    cramer_rao_percent, insensitivity_percent : ndarray
        ``100 * bound / |value|`` (``inf`` for a zero value).
    correlation : ndarray (n, n)
        NaN for unidentifiable parameters.
    identifiable : ndarray of bool
    """

    names: tuple[str, ...]
    values: np.ndarray
    hessian: np.ndarray
    covariance: np.ndarray
    cramer_rao: np.ndarray
    insensitivity: np.ndarray
    cramer_rao_percent: np.ndarray
    insensitivity_percent: np.ndarray
    correlation: np.ndarray
    identifiable: np.ndarray
    attrs: dict = field(default_factory=dict)

    @property
    def unidentifiable(self) -> tuple[str, ...]:
        """Names of the parameters the data say nothing about."""
        return tuple(n for n, ok in zip(self.names, self.identifiable) if not ok)

    def breaks_guidelines(self, *, cr_max: float = CR_MAX_PERCENT,
                          insensitivity_max: float = INSENSITIVITY_MAX_PERCENT) -> np.ndarray:
        """True where ``CR% > cr_max`` or ``I% > insensitivity_max`` (or unidentifiable)."""
        return (~self.identifiable | (self.cramer_rao_percent > cr_max)
                | (self.insensitivity_percent > insensitivity_max))

    def to_dataset(self) -> xr.Dataset:
        """Per-parameter statistics on a ``parameter`` dimension (model Dataset variable names)."""
        names = list(self.names)
        return xr.Dataset(
            {
                "value": ("parameter", self.values),
                "cramer_rao": ("parameter", self.cramer_rao),
                "cramer_rao_percent": ("parameter", self.cramer_rao_percent, {"units": "%"}),
                "insensitivity": ("parameter", self.insensitivity),
                "insensitivity_percent": ("parameter", self.insensitivity_percent,
                                          {"units": "%"}),
                "identifiable": ("parameter", self.identifiable),
                "correlation": (("parameter", "parameter_j"), self.correlation),
            },
            coords={"parameter": names, "parameter_j": names},
            attrs={k: v for k, v in self.attrs.items() if isinstance(v, (int, float, str))},
        )

    def table(self) -> str:
        """Plain-text table: name, value, CR, CR %, insensitivity %."""
        lines = [f"{'parameter':<12}{'value':>14}{'CR':>12}{'CR %':>9}{'I %':>9}"]
        for k, n in enumerate(self.names):
            flag = "" if self.identifiable[k] else "  unidentifiable"
            lines.append(f"{n:<12}{self.values[k]:>14.6g}{self.cramer_rao[k]:>12.4g}"
                         f"{format_percent(self.cramer_rao_percent[k]):>9}"
                         f"{format_percent(self.insensitivity_percent[k]):>9}{flag}")
        return "\n".join(lines)


def format_percent(x: float) -> str:
    """A Cramer-Rao or insensitivity percentage for a table: one decimal, ``inf`` for an
    unidentifiable parameter."""
    return "inf" if not np.isfinite(x) else f"{x:.1f}"


class FitResultParameters:
    """Parameter look-ups shared by the frequency- and time-domain fit results, which carry
    ``model`` (the model Dataset), ``statistics`` and ``full_statistics`` (before reduction)."""

    @property
    def unidentifiable(self) -> tuple[str, ...]:
        """Parameters without influence on the fitted data (final model, or the full model
        before reduction when reduction removed them)."""
        names = set(self.statistics.unidentifiable)
        if self.full_statistics is not None:
            names |= set(self.full_statistics.unidentifiable)
        return tuple(sorted(names))

    def value(self, name: str) -> float:
        """Final value of any parameter (free, fixed or removed)."""
        return float(self.model["value"].sel(parameter=name))


def guideline_mark(cramer_rao_percent: float, insensitivity_percent: float, *,
                   cr_max: float = CR_MAX_PERCENT,
                   insensitivity_max: float = INSENSITIVITY_MAX_PERCENT) -> str:
    """The mark a parameter table puts beside a parameter that breaks an accuracy guideline:
    ``"CR>20%"``, ``"I>10%"``, both (space-separated) or ``""`` (an infinite percentage, i.e.
    unidentifiable or zero, breaks it too)."""
    marks = []
    if not cramer_rao_percent <= cr_max:
        marks.append(f"CR>{cr_max:g}%")
    if not insensitivity_percent <= insensitivity_max:
        marks.append(f"I>{insensitivity_max:g}%")
    return " ".join(marks)


def undetermined_parameters(model) -> list[tuple[str, float]]:
    """Free parameters of a model Dataset whose Cramer-Rao bound (the larger of the plain and
    the corrected one, %) exceeds :data:`UNDETERMINED_PERCENT`: ``(name, percent)``, the
    largest first. The data do not fix their sign, whatever the structure keeps them for."""
    if "cramer_rao_percent" not in model or "free" not in model:
        return []
    pct = model["cramer_rao_percent"].values.astype(float)
    pct = np.where(np.isnan(pct), np.inf, pct)
    if "cramer_rao_percent_corrected" in model:
        corrected = model["cramer_rao_percent_corrected"].values.astype(float)
        pct = np.where(np.isfinite(corrected), np.maximum(pct, corrected), pct)
    free = model["free"].values.astype(bool)
    names = [str(n) for n in model["parameter"].values]
    out = [(names[k], float(pct[k])) for k in np.flatnonzero(free)
           if not pct[k] <= UNDETERMINED_PERCENT]
    return sorted(out, key=lambda item: -item[1])


def format_undetermined(found: Sequence[tuple[str, float]]) -> str:
    """``"L_v 677.1 %, N_v 665.0 %"`` for :func:`undetermined_parameters`' list."""
    return ", ".join(f"{name} {format_percent(pct)} %" for name, pct in found)


def parameter_rows(model, *, absolute_cr: bool = False) -> list[str]:
    """Table lines (header first) of the free parameters of a model Dataset: value,
    optionally the absolute Cramer-Rao bound, CR %, the bound corrected for coloured residuals
    (``CRc``, ``CRc %``; time-domain models that carry ``cramer_rao_corrected``; in the
    frequency domain the bound scaled by the fit residuals) and
    insensitivity %, then a mark where a parameter breaks the 20 % CR guideline (on the larger
    of its bounds) or the 10 % insensitivity guideline (:func:`guideline_mark`), and an
    ``unidentifiable`` flag; followed by a line saying what the marks mean and which
    parameters the data leave undetermined (:data:`UNDETERMINED_PERCENT`), and one listing
    the free delays in ms."""
    corrected = ("cramer_rao_corrected" in model
                 and bool(np.isfinite(model["cramer_rao_corrected"].values).any()))
    head = f"{'parameter':<12}{'value':>14}" + (f"{'CR':>12}" if absolute_cr else "")
    head += f"{'CR %':>9}"
    if corrected:
        head += (f"{'CRc':>12}" if absolute_cr else "") + f"{'CRc %':>9}"
    lines = [head + f"{'I %':>9}  guidelines"]
    free = model["free"].values.astype(bool)
    names = [str(n) for n in model["parameter"].values]
    marked = 0
    for k, name in enumerate(names):
        if not free[k]:
            continue
        cr_pct = float(model["cramer_rao_percent"][k])
        in_pct = float(model["insensitivity_percent"][k])
        row = f"{name:<12}{float(model['value'][k]):>14.5g}"
        row += f"{float(model['cramer_rao'][k]):>12.4g}" if absolute_cr else ""
        row += f"{format_percent(cr_pct):>9}"
        worst = cr_pct
        if corrected:
            c_pct = float(model["cramer_rao_percent_corrected"][k])
            row += (f"{float(model['cramer_rao_corrected'][k]):>12.4g}" if absolute_cr else "")
            row += f"{format_percent(c_pct):>9}"
            worst = max(cr_pct, c_pct) if np.isfinite(c_pct) else cr_pct
        mark = guideline_mark(worst, in_pct)
        marked += bool(mark)
        flag = "" if bool(model["identifiable"].values[k]) else " unidentifiable"
        lines.append(row + f"{format_percent(in_pct):>9}  {mark}{flag}".rstrip())
    note = (f"guidelines: CR % <= {CR_MAX_PERCENT:g}"
            + (" (the larger of CR % and CRc %)" if corrected else "")
            + f", I % <= {INSENSITIVITY_MAX_PERCENT:g}; {marked} parameter(s) marked")
    undetermined = undetermined_parameters(model)
    if undetermined:
        note += (f"; undetermined by the data (bound above {UNDETERMINED_PERCENT:g} % of the "
                 f"value): {format_undetermined(undetermined)}")
    if corrected and "residual_window_lag_points" in model.attrs:
        note += ("; CRc: scaled by the fit residuals, correlated over "
                 f"{int(model.attrs['residual_window_lag_points'])} frequency points")
    elif corrected:
        note += ("; CRc: corrected for coloured residuals (Morelli & Klein 1997), "
                 f"lag window {model.attrs.get('residual_window_lag_s', float('nan')):.2f} s")
    lines.append(note)
    delays = [(n, float(model["value"][k])) for k, n in enumerate(names)
              if str(model["matrix"].values[k]) == "delay" and free[k]]
    if delays:
        lines.append("delays: " + ", ".join(f"{n} = {v * 1000:.1f} ms" for n, v in delays))
    return lines


def perturbed_start(theta, structure, seed: int, fraction: float) -> np.ndarray:
    """``theta`` moved by up to ``+-fraction`` (relative; 1e-3 absolute for zeros), seeded,
    and clipped to the structure's bounds: the restart that confirms a minimum."""
    rng = np.random.default_rng(seed)
    lo, hi = structure.bounds
    scale = np.where(np.abs(theta) > 0, np.abs(theta), 1e-3)
    return np.clip(theta + fraction * scale * rng.uniform(-1.0, 1.0, np.shape(theta)), lo, hi)


def parameter_statistics(jacobian, values, names: Sequence[str], *, scale: float = 1.0,
                         rcond: float = RCOND) -> ParameterStatistics:
    """Cramer-Rao bounds, insensitivities and correlations from a weighted residual Jacobian.

    Parameters
    ----------
    jacobian : array_like, shape (n_residual, n_parameter)
        ``G = d r / d theta`` of the weighted residuals (``J = sum r^2``).
    values : array_like, shape (n_parameter,)
        Parameter estimates (for the percentages).
    names : sequence of str
    scale : float
        Multiplies ``G^T G`` (e.g. ``1/sigma^2``); 1 for the CIFER convention.
    rcond : float
        Relative eigenvalue threshold of the normalised Hessian (diagonal scaled to 1)
        below which a direction is unidentifiable.

    Returns
    -------
    ParameterStatistics
    """
    G = np.asarray(jacobian, dtype=float)
    n = G.shape[1] if G.ndim == 2 else 0
    if np.shape(values) != (n,) or len(names) != n:
        raise ValueError(f"parameter_statistics: jacobian has {n} columns but "
                         f"{np.shape(values)} values and {len(names)} names")
    return information_statistics(G.T @ G, values, names, scale=scale, rcond=rcond)


def information_statistics(information, values, names: Sequence[str], *, scale: float = 1.0,
                           rcond: float = RCOND) -> ParameterStatistics:
    """:func:`parameter_statistics` from the information matrix ``M = G^T G`` (n_parameter,
    n_parameter) itself: for fits that accumulate it record by record without forming
    the tall Jacobian ``G``."""
    M = np.asarray(information, dtype=float)
    values = np.asarray(values, dtype=float)
    n = M.shape[0] if M.ndim == 2 else 0
    if M.shape != (n, n) or values.shape != (n,) or len(names) != n:
        raise ValueError(f"information_statistics: information has shape {M.shape} but "
                         f"{values.shape} values and {len(names)} names")
    H = scale * M
    diag = np.diag(H).copy()
    # A zero (or non-finite) column: the cost does not depend on the parameter at all.
    col_ok = np.isfinite(diag) & (diag > 0)
    if np.any(col_ok):  # columns at rounding level of the largest one count as zero
        col_ok &= diag > 1e-16 * np.max(diag[col_ok])
    identifiable = col_ok.copy()
    cov = np.full((n, n), np.inf)
    idx = np.flatnonzero(col_ok)
    if len(idx):
        d = np.sqrt(diag[idx])
        Hn = H[np.ix_(idx, idx)] / np.outer(d, d)  # unit diagonal: correlation-like
        lam, V = np.linalg.eigh(Hn)
        keep = lam > rcond * max(lam.max(), 1.0)
        # A parameter with a sizeable component along a null direction is unidentifiable.
        null_weight = np.sum(V[:, ~keep] ** 2, axis=1)
        ok_sub = null_weight < 1e-6
        Cn = (V[:, keep] / lam[keep]) @ V[:, keep].T
        Csub = Cn / np.outer(d, d)
        identifiable[idx] = ok_sub
        cov[np.ix_(idx, idx)] = np.where(np.outer(ok_sub, ok_sub), Csub, np.inf)
    var = np.diag(cov).copy()
    cramer_rao = np.where(identifiable, np.sqrt(np.abs(var)), np.inf)
    with np.errstate(divide="ignore"):
        insensitivity = np.where(col_ok, 1.0 / np.sqrt(np.where(col_ok, diag, 1.0)), np.inf)
    absval = np.abs(values)
    # tiny |value| overflows the percentage to inf, which is what it is
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        cr_pct = np.where(absval > 0, 100.0 * cramer_rao / absval, np.inf)
        in_pct = np.where(absval > 0, 100.0 * insensitivity / absval, np.inf)
        sd = np.sqrt(np.where(identifiable, var, np.nan))
        corr = cov / np.outer(sd, sd)
    corr[~identifiable, :] = np.nan
    corr[:, ~identifiable] = np.nan
    corr[np.diag_indices(n)] = np.where(identifiable, 1.0, np.nan)
    return ParameterStatistics(tuple(names), values.copy(), H, cov, cramer_rao, insensitivity,
                               cr_pct, in_pct, corr, identifiable,
                               attrs={"scale": float(scale), "rcond": float(rcond)})


def correlated_pairs(stats: ParameterStatistics, threshold: float = 0.9
                     ) -> list[tuple[str, str, float]]:
    """Parameter pairs with ``|correlation| > threshold``, strongest first."""
    out = []
    C = stats.correlation
    for i in range(len(stats.names)):
        for j in range(i + 1, len(stats.names)):
            if np.isfinite(C[i, j]) and abs(C[i, j]) > threshold:
                out.append((stats.names[i], stats.names[j], float(C[i, j])))
    return sorted(out, key=lambda x: -abs(x[2]))


# --------------------------------------------------------------------------------------------
# Coloured residuals: the Morelli-Klein correction of the time-domain bounds
# --------------------------------------------------------------------------------------------


def residual_autocorrelation(residuals: Sequence[np.ndarray], max_lag: int) -> np.ndarray:
    """Biased residual auto/cross-correlation, pooled over records, by FFT.

    ``C[k, a, b] = (1/N) sum_records sum_t v[t + k, a] v[t, b]`` for ``k = 0..max_lag``
    (``N`` the samples of all records; no product spans two records). The biased (1/N)
    estimate keeps the lag sequence positive semi-definite.

    Parameters
    ----------
    residuals : sequence of ndarray (N_r, p)
        Residuals of each record (whitened in the time-domain fit).
    max_lag : int
        Largest lag, samples.

    Returns
    -------
    ndarray (max_lag + 1, p, p)
    """
    residuals = [np.asarray(v, dtype=float) for v in residuals]
    if not residuals or any(v.ndim != 2 for v in residuals):
        raise ValueError("residual_autocorrelation: residuals must be a non-empty list of "
                         "(samples, outputs) arrays")
    p = residuals[0].shape[1]
    if any(v.shape[1] != p for v in residuals):
        raise ValueError(f"residual_autocorrelation: records have different output counts "
                         f"{[v.shape[1] for v in residuals]}")
    max_lag = int(max_lag)
    total = np.zeros((max_lag + 1, p, p))
    n_total = 0
    for v in residuals:
        N = len(v)
        n_total += N
        nfft = scipy.fft.next_fast_len(N + max_lag + 1, real=True)
        V = scipy.fft.rfft(v, n=nfft, axis=0)  # (F, p)
        c = scipy.fft.irfft(V[:, :, None] * np.conj(V[:, None, :]), n=nfft, axis=0)
        kmax = min(max_lag, N - 1)
        total[:kmax + 1] += c[:kmax + 1]
    return total / max(n_total, 1)


def correlation_lag(autocorrelation: np.ndarray, n_samples: int, *,
                    band: float = WHITENESS_BAND) -> int:
    """Lag (samples) by which every output's normalised residual autocorrelation
    ``rho_a(k) = C[k, a, a] / C[0, a, a]`` has first fallen inside the whiteness band
    ``|rho_a| < band / sqrt(n_samples)``; the largest lag given when one never does. 0 for
    white residuals. (Inside in magnitude: a Kalman filter's innovations can be negatively
    correlated at lag 1 and positively beyond.)"""
    C = np.asarray(autocorrelation, dtype=float)
    var = np.einsum("kaa->ka", C)
    lag = 0
    limit = band / np.sqrt(max(int(n_samples), 1))
    for a in range(C.shape[1]):
        if not var[0, a] > 0:
            continue
        inside = np.flatnonzero(np.abs(var[1:, a] / var[0, a]) < limit)
        lag = max(lag, int(inside[0]) if len(inside) else len(C) - 1)
    return lag


@dataclass
class ColouredBounds:
    """Parameter covariance corrected for coloured residuals (:func:`coloured_residual_covariance`).

    Attributes
    ----------
    covariance : ndarray (n, n)
        ``M^-1 B M^-1``; ``inf`` rows/columns where ``M^-1`` has them (unidentifiable).
    cramer_rao : ndarray (n,)
        ``sqrt(diag(covariance))``, units of the parameters.
    decay_lag : int
        Samples by which the residual autocorrelation has decayed (:func:`correlation_lag`).
    window_lag : int
        Half-width of the Bartlett window of the lag sum, samples (0: white).
    """

    covariance: np.ndarray
    cramer_rao: np.ndarray
    decay_lag: int
    window_lag: int

    def percent(self, values) -> np.ndarray:
        """``100 * bound / |value|`` (``inf`` for a zero value)."""
        absval = np.abs(np.asarray(values, dtype=float))
        with np.errstate(divide="ignore", invalid="ignore"):
            return np.where(absval > 0, 100.0 * self.cramer_rao / absval, np.inf)


def on_parameters(parameters, free_names: Sequence[str], values) -> np.ndarray:
    """``values`` of the free parameters ``free_names`` placed on the model's whole
    ``parameter`` axis (fixed ones NaN); ``values=None`` gives all NaN."""
    out = np.full(len(parameters), np.nan)
    if values is not None and len(free_names):
        pos = {str(p): k for k, p in enumerate(np.asarray(parameters))}
        out[[pos[name] for name in free_names]] = values
    return out


def add_corrected_bounds(ds: xr.Dataset, free_names: Sequence[str], theta,
                         coloured: ColouredBounds | None, dt: float) -> xr.Dataset:
    """Put the bounds corrected for coloured residuals on a model Dataset's ``parameter``
    axis (``cramer_rao_corrected``, ``cramer_rao_percent_corrected``; NaN where fixed or
    without a correction) with the lags in s (``residual_decay_lag_s``,
    ``residual_window_lag_s``) and the convention in the attributes. Returns ``ds``."""
    cr_c = on_parameters(ds.parameter.values, free_names,
                         None if coloured is None else coloured.cramer_rao)
    cr_cp = on_parameters(ds.parameter.values, free_names,
                          None if coloured is None else coloured.percent(theta))
    if coloured is not None:
        ds.attrs.update(residual_decay_lag_s=float(coloured.decay_lag * dt),
                        residual_window_lag_s=float(coloured.window_lag * dt))
    ds.attrs["cramer_rao_corrected_convention"] = (
        "M^-1 [sum_i sum_j S(i)^T R_vv(i-j) S(j)] M^-1 (Morelli & Klein 1997), R_vv the "
        "whitened residual autocorrelation, Bartlett lag window")
    ds["cramer_rao_corrected"] = ("parameter", cr_c, {
        "long_name": "Cramer-Rao bound corrected for coloured residuals (one standard "
                     "deviation)"})
    ds["cramer_rao_percent_corrected"] = ("parameter", cr_cp, {
        "long_name": "corrected Cramer-Rao bound in percent of |value|", "units": "%"})
    return ds


def coloured_residual_covariance(*, sensitivities: Sequence[np.ndarray],
                                 residuals: Sequence[np.ndarray], information_inverse,
                                 window_lag: int | None = None) -> ColouredBounds:
    """Cramer-Rao bounds corrected for coloured residuals (Morelli & Klein 1997).

    With whitened sensitivities ``S(i)`` (p x n per sample, rows divided by the noise
    standard deviations, i.e. ``R^-1/2 dy/dtheta``) and whitened residuals ``v(i)``::

        Cov = M^-1 B M^-1 ,   B = sum_records sum_i sum_j S(i)^T K(i - j) S(j)
        K(k) = w_k C(k) ,   K(-k) = K(k)^T ,   w_k = 1 - |k| / (L + 1)  (|k| <= L, else 0)

    ``C`` is :func:`residual_autocorrelation`; ``M^-1`` the white-noise covariance. Morelli
    and Klein sum all lags of the unbiased estimate; at the optimum the full biased lag sum
    collapses (``sum_i S(i)^T v(i) = 0``), and the far lags only add estimation noise, so the
    sum is truncated at ``L = LAG_WINDOW_FACTOR x`` :func:`correlation_lag` with Bartlett
    weights, which keep ``B`` positive semi-definite (the Newey-West form). White residuals
    give ``L = 0`` and ``B = M``: the white-noise bound. The inner sum over ``j`` is a
    convolution, a product per frequency after an FFT of each record (``O(N log N p n)``),
    and the outer sum one ``(F p) x n`` matrix product by Parseval's theorem.

    Parameters
    ----------
    sensitivities : sequence of ndarray (N_r, p, n)
        Whitened output sensitivities per record (nuisance-projected in the output-error fit).
    residuals : sequence of ndarray (N_r, p)
        Whitened residuals per record.
    information_inverse : array_like (n, n)
        ``M^-1`` (``inf`` rows/columns for unidentifiable parameters, as
        :attr:`ParameterStatistics.covariance`).
    window_lag : int, optional
        ``L`` in samples (default: automatic, as above).

    Returns
    -------
    ColouredBounds

    References
    ----------
    E. A. Morelli and V. Klein, "Accuracy of aircraft dynamic parameter estimates from
    flight test data", J. Guidance, Control, and Dynamics 20(1), 1997, pp. 74-80.
    V. Klein and E. A. Morelli, *Aircraft System Identification*, AIAA 2006, sec. 6.4.
    W. K. Newey and K. D. West, "A simple, positive semi-definite, heteroskedasticity and
    autocorrelation consistent covariance matrix", Econometrica 55(3), 1987.
    """
    S_list = [np.asarray(S, dtype=float) for S in sensitivities]
    v_list = [np.asarray(v, dtype=float) for v in residuals]
    Minv = np.asarray(information_inverse, dtype=float)
    n = Minv.shape[0]
    if len(S_list) != len(v_list) or not S_list:
        raise ValueError(f"coloured_residual_covariance: {len(S_list)} sensitivity and "
                         f"{len(v_list)} residual records; expected the same, at least one")
    for k, (S, v) in enumerate(zip(S_list, v_list)):
        if S.ndim != 3 or S.shape[:2] != v.shape or S.shape[2] != n:
            raise ValueError(f"coloured_residual_covariance: record {k}: sensitivities "
                             f"{S.shape} do not match residuals {v.shape} and {n} parameters")
    n_samples = sum(len(v) for v in v_list)
    shortest = min(len(v) for v in v_list)
    if window_lag is None:
        probe = residual_autocorrelation(v_list, shortest // 2)
        decay = correlation_lag(probe, n_samples)
        window = int(min(np.ceil(LAG_WINDOW_FACTOR * decay), shortest - 1))
    else:
        decay = window = int(min(max(window_lag, 0), shortest - 1))
    C = residual_autocorrelation(v_list, window)
    weights = 1.0 - np.arange(window + 1) / (window + 1.0)
    K_pos = weights[:, None, None] * C  # K(k), k = 0..L
    p = v_list[0].shape[1]
    B = np.zeros((n, n))
    for S in S_list:
        N = len(S)
        nfft = scipy.fft.next_fast_len(N + window, real=True)
        kernel = np.zeros((nfft, p, p))  # circular layout: K(k) at k, K(-k) at nfft - k
        kernel[:window + 1] = K_pos
        if window:
            kernel[nfft - window:] = np.transpose(K_pos[1:], (0, 2, 1))[::-1]
        Kf = scipy.fft.rfft(kernel, axis=0)  # (F, p, p)
        Sf = scipy.fft.rfft(S, n=nfft, axis=0)  # (F, p, n)
        # T(i) = sum_k K(k) S(i - k) is a product per frequency (p small: a sum over p
        # broadcast products is faster than F tiny matrix products) ...
        Tf = Kf[:, :, 0, None] * Sf[:, None, 0, :]
        for b in range(1, p):
            Tf += Kf[:, :, b, None] * Sf[:, None, b, :]
        # ... and sum_i S(i)^T T(i) is, by Parseval, one (F p) x n complex matrix product
        # (one-sided spectrum: the bins between 0 and Nyquist count twice).
        weight = np.full(len(Sf), 2.0)
        weight[0] = 1.0
        if nfft % 2 == 0:
            weight[-1] = 1.0
        Sw = np.conj(Sf) * (weight / nfft)[:, None, None]
        B += np.real(Sw.reshape(-1, n).T @ Tf.reshape(-1, n))
    B = 0.5 * (B + B.T)
    ok = np.isfinite(np.diag(Minv))
    cov = np.full((n, n), np.inf)
    if np.any(ok):
        Mi = Minv[np.ix_(ok, ok)]
        cov[np.ix_(ok, ok)] = Mi @ B[np.ix_(ok, ok)] @ Mi
    cr = np.where(ok, np.sqrt(np.abs(np.diag(cov))), np.inf)
    return ColouredBounds(cov, cr, int(decay), int(window))


def robust_scale(samples, axis: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """Robust standard deviation of ``samples`` along ``axis`` and the fraction of samples
    outlying from it.

    ``s = 1.4826 median |x - median x|`` (the normalised median absolute deviation): the
    standard deviation for normal samples, but unmoved by a minority of samples far from
    the rest; the fraction is that of samples more than :data:`OUTLYING_SCALES` ``s`` from
    the median (0 where ``s = 0``). Shapes: ``samples`` (..., n, ...) -> two arrays without
    ``axis``. Its efficiency at the normal is 37 %, so from 20 samples ``s`` is known to about
    27 % (the plain standard deviation to 16 %).

    References
    ----------
    P. J. Rousseeuw and C. Croux, "Alternatives to the median absolute deviation",
    *J. Amer. Statist. Assoc.* 88 (1993) 1273-1283.

    Examples
    --------
    >>> s, out = robust_scale(np.array([-1.0, 0.0, 1.0, 0.5, -0.5, 40.0]))
    >>> round(float(s), 3), round(float(out), 3)
    (1.112, 0.167)
    """
    x = np.asarray(samples, float)
    centre = np.median(x, axis=axis, keepdims=True)
    scale = MAD_TO_STD * np.median(np.abs(x - centre), axis=axis, keepdims=True)
    outlying = (scale > 0) & (np.abs(x - centre) > OUTLYING_SCALES * scale)
    return np.squeeze(scale, axis=axis), outlying.mean(axis=axis)
