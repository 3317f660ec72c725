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

A parameter the data carry no information about (a zero Jacobian column, or a direction of
``theta`` the cost cannot see) is *unidentifiable*: its bound and insensitivity are ``inf`` and
it is flagged, and the other parameters' bounds come from the pseudo-inverse restricted to the
identifiable subspace. Nothing raises on a singular H.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import xarray as xr

from sysid.core.guidelines import CR_MAX_PERCENT, INSENSITIVITY_MAX_PERCENT

__all__ = ["ParameterStatistics", "parameter_statistics", "correlated_pairs"]

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


def parameter_rows(model, *, absolute_cr: bool = False) -> list[str]:
    """Table lines (header first) of the free parameters of a model Dataset: value,
    optionally the absolute Cramer-Rao bound, CR % and insensitivity %, and an
    ``unidentifiable`` flag; followed by one line listing the free delays in ms."""
    head = f"{'parameter':<12}{'value':>14}" + (f"{'CR':>12}" if absolute_cr else "")
    lines = [head + f"{'CR %':>9}{'I %':>9}"]
    free = model["free"].values.astype(bool)
    names = [str(n) for n in model["parameter"].values]
    for k, name in enumerate(names):
        if not free[k]:
            continue
        flag = "" if bool(model["identifiable"].values[k]) else "  unidentifiable"
        cr = f"{float(model['cramer_rao'][k]):>12.4g}" if absolute_cr else ""
        lines.append(f"{name:<12}{float(model['value'][k]):>14.5g}{cr}"
                     f"{format_percent(float(model['cramer_rao_percent'][k])):>9}"
                     f"{format_percent(float(model['insensitivity_percent'][k])):>9}{flag}")
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
    values = np.asarray(values, dtype=float)
    n = G.shape[1] if G.ndim == 2 else 0
    if values.shape != (n,) or len(names) != n:
        raise ValueError(f"parameter_statistics: jacobian has {n} columns but {values.shape} "
                         f"values and {len(names)} names")
    H = scale * (G.T @ G)
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
    with np.errstate(divide="ignore", invalid="ignore"):
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
