"""Composite windowing (paper Eq. 14-17): one response from several window lengths.

Short windows average many segments (low random error) but resolve low frequencies poorly;
long windows reach low frequencies with fewer averages. Compositing combines them frequency by
frequency.

Window lengths (:func:`default_windows`, methods.md)
    longest ``T_max = min(T_record / 2, T_total / 5)`` (``T_record`` the shortest record,
    ``T_total`` all records together), shortest ``T_min = 20 / f_max`` (20 periods of the
    highest frequency of interest, ``f_max = omega_max / 2 pi`` in Hz), ``n_windows`` (default
    5) lengths log-spaced in between. A window is trusted only at ``omega >= 2 pi / T``
    (:func:`trusted`); elsewhere its weight is zero.

Weights (Eq. 14)
    ``W_i = (eps_i / eps_min)^-4`` with ``eps_i`` the window's (conditioned) random error and
    ``eps_min`` the smallest among the trusted windows at that frequency.

Cost (Eq. 16), minimised at every frequency over the composite pair spectra
``Gxx_c, Gyy_c > 0`` and complex ``Gxy_c``::

    J = sum_i W_i [ ((Gxx_c - Gxx_i) / Gxx^)^2 + ((Gyy_c - Gyy_i) / Gyy^)^2
                    + ((Re Gxy_c - Re Gxy_i) / |Gxy^|)^2 + ((Im Gxy_c - Im Gxy_i) / |Gxy^|)^2
                    + 5 ((g2_c - g2_i) / g2^)^2 ],     g2_c = |Gxy_c|^2 / (Gxx_c Gyy_c)

with ``^`` the ``W_i^2``-weighted averages of Eq. 15. The real and imaginary parts are
normalised by ``|Gxy^|`` instead of the paper's ``Re Gxy^`` and ``Im Gxy^``: those pass through
zero wherever the phase crosses a multiple of 90 deg, which makes the paper's terms blow up
(methods.md calls it ill-conditioned); ``|Gxy^|`` has the same scale and never vanishes where
there is a response. Because ``sum_i W_i (x - x_i)^2 = (sum_i W_i)(x - xbar)^2 + const`` with
``xbar`` the ``W``-weighted mean, the cost is a 4-parameter nonlinear least-squares problem per
frequency, solved here by Levenberg-Marquardt vectorised over all frequencies at once (the
Jacobian is the identity plus the rank-one coherence term, so each step is closed-form by
Sherman-Morrison), starting from the ``W``-weighted means. Then ``H_c = Gxy_c / Gxx_c``
(Eq. 17) and the composite coherence is ``g2_c``.

Composite random error
    ``eps_c = sum_i W_i eps_i / sum_i W_i``: the windows use the same data, so their errors are
    strongly correlated and the composite cannot be trusted more than its best windows; this
    weighted mean is close to ``eps_min`` since the Eq. 14 weights fall off as ``eps^-4``.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import xarray as xr

from sysid.errors import InputDataError
from sysid.spectra import MIN_AVERAGES

#: Number of window lengths combined (Tischler & Remple's example uses 5).
DEFAULT_N_WINDOWS = 5
#: Periods of the highest frequency in the shortest window (``T_min = 20 / f_max``).
PERIODS_IN_SHORTEST_WINDOW = 20.0
#: Weight of the coherence term of Eq. 16.
COHERENCE_WEIGHT = 5.0
#: Exponent of Eq. 14.
WEIGHT_EXPONENT = -4.0
#: Levenberg-Marquardt iterations of the Eq. 16 minimisation (converges in a handful).
LM_ITERATIONS = 30


def default_windows(record_durations: Sequence[float], omega_max: float,
                    n_windows: int = DEFAULT_N_WINDOWS, dt: float | None = None) -> np.ndarray:
    """Window lengths (s) for compositing, shortest first.

    Parameters
    ----------
    record_durations : sequence of float
        Duration of each record, s.
    omega_max : float
        Highest frequency of interest, rad/s.
    n_windows : int
        How many lengths, log-spaced between ``T_min = 20 / f_max`` and
        ``T_max = min(T_record / 2, T_total / 5)``.
    dt : float, optional
        Sample interval: lengths are rounded to whole samples (``T_max`` down).
    """
    durations = np.asarray(record_durations, dtype=float)
    if durations.size == 0 or np.any(durations <= 0):
        raise InputDataError(f"record durations must be positive, got {durations}")
    if n_windows < 1:
        raise InputDataError(f"n_windows must be at least 1, got {n_windows}")
    t_max = min(durations.min() / 2.0, durations.sum() / MIN_AVERAGES)
    t_min = PERIODS_IN_SHORTEST_WINDOW * 2.0 * math.pi / omega_max
    if dt is not None:
        t_max = math.floor(t_max / dt + 1e-9) * dt
    if t_min > t_max:
        raise InputDataError(
            f"records too short for omega_max = {omega_max:.4g} rad/s: the shortest window "
            f"(20 periods, {t_min:.4g} s) exceeds the longest allowed window {t_max:.4g} s "
            f"(min(shortest record / 2, total / {MIN_AVERAGES})); use longer records or a "
            "higher omega_max")
    windows = np.geomspace(t_min, t_max, n_windows) if n_windows > 1 else np.array([t_max])
    if dt is not None:
        windows = np.round(windows / dt) * dt
        windows[-1] = t_max
    return np.unique(windows)


def trusted(frequency: xr.DataArray, window: xr.DataArray) -> xr.DataArray:
    """True where window length ``window`` (s) resolves ``frequency`` (rad/s):
    ``omega >= 2 pi / T`` (one period per window)."""
    return frequency >= (2.0 * np.pi / window) * (1.0 - 1e-9)


def weights(random_error: xr.DataArray, usable: xr.DataArray) -> xr.DataArray:
    """Eq. 14, ``W_i = (eps_i / eps_min)^-4`` over dim ``window``; zero where not ``usable``
    or where the error is not finite. All zero where no window is usable."""
    ok = usable & np.isfinite(random_error)
    eps = random_error.where(ok)
    eps_min = eps.min("window")
    with np.errstate(invalid="ignore", divide="ignore"):
        w = (eps / eps_min) ** WEIGHT_EXPONENT
    # eps == 0 everywhere (noise-free data): all error-free windows count equally
    w = xr.where(ok & (eps_min == 0), xr.where(eps == 0, 1.0, 0.0), w)
    return w.where(ok, 0.0).fillna(0.0).assign_attrs(long_name="composite weight (Eq. 14)")


def _lm_core(gxx, gyy, gxy, coh, w, iterations, coherence_weight):
    """Minimise Eq. 16 over the last axis (windows) at every other index.

    Arrays ``(..., n_w)``; ``w >= 0``. Returns composite ``gxx, gyy, gxy`` of shape ``(...)``.
    """
    w = np.where(np.isfinite(gxx) & np.isfinite(gyy) & np.isfinite(gxy) & np.isfinite(coh),
                 w, 0.0)
    gxx, gyy, coh = (np.where(w > 0, a, 0.0) for a in (gxx, gyy, coh))
    gxy = np.where(w > 0, gxy, 0.0)
    w1 = w.sum(-1)
    w2 = (w * w).sum(-1)
    empty = w1 <= 0
    w1s, w2s = np.where(empty, 1.0, w1), np.where(empty, 1.0, w2)
    # Eq. 15: W^2-weighted averages (normalisers); W-weighted means (minimisers of the quadratics)
    hat_xx = (w * w * gxx).sum(-1) / w2s
    hat_yy = (w * w * gyy).sum(-1) / w2s
    hat_xy = (w * w * gxy).sum(-1) / w2s
    hat_coh = (w * w * coh).sum(-1) / w2s
    bar_coh = (w * coh).sum(-1) / w1s
    s_xx = np.where(hat_xx > 0, hat_xx, 1.0)
    s_yy = np.where(hat_yy > 0, hat_yy, 1.0)
    s_xy = np.maximum(np.abs(hat_xy), 1e-9 * np.sqrt(s_xx * s_yy))
    target = np.stack([(w * gxx).sum(-1) / w1s / s_xx, (w * gyy).sum(-1) / w1s / s_yy,
                       (w * gxy.real).sum(-1) / w1s / s_xy, (w * gxy.imag).sum(-1) / w1s / s_xy])
    kappa = s_xy ** 2 / (s_xx * s_yy)
    c_scale = math.sqrt(coherence_weight) / np.maximum(hat_coh, 1e-6)

    def coherence_of(x):
        return kappa * (x[2] ** 2 + x[3] ** 2) / (x[0] * x[1])

    def cost(x):
        return np.sum((x - target) ** 2, axis=0) + (c_scale * (coherence_of(x) - bar_coh)) ** 2

    x = np.where(np.isfinite(target), target, 1.0)
    x[:2] = np.where(x[:2] > 0, x[:2], 1.0)
    lam = np.full(x.shape[1:], 1e-3)
    f = cost(x)
    for _ in range(iterations):
        g2 = coherence_of(x)
        grad = np.stack([-g2 / x[0], -g2 / x[1],
                         2 * kappa * x[2] / (x[0] * x[1]), 2 * kappa * x[3] / (x[0] * x[1])])
        q = c_scale * grad
        r5 = c_scale * (g2 - bar_coh)
        rhs = -(x - target) - q * r5
        # (I (1 + lam) + q q^T) d = rhs, closed form (Sherman-Morrison)
        d = (rhs - q * np.sum(q * rhs, axis=0) / (1 + lam + np.sum(q * q, axis=0))) / (1 + lam)
        trial = x + d
        positive = (trial[0] > 0) & (trial[1] > 0)
        with np.errstate(invalid="ignore", divide="ignore"):
            f_trial = np.where(positive, cost(np.where(positive, trial, x)), np.inf)
        better = f_trial < f
        x = np.where(better, trial, x)
        f = np.where(better, f_trial, f)
        lam = np.where(better, lam / 3.0, lam * 4.0)
    out_xx = x[0] * s_xx
    out_yy = x[1] * s_yy
    out_xy = (x[2] + 1j * x[3]) * s_xy
    nan = np.where(empty, np.nan, 1.0)
    return out_xx * nan, out_yy * nan, out_xy * nan


def composite_spectra(Gxx_pair: xr.DataArray, Gyy_pair: xr.DataArray, Gxy_pair: xr.DataArray,
                      coherence: xr.DataArray, weight: xr.DataArray, *,
                      coherence_weight: float = COHERENCE_WEIGHT,
                      iterations: int = LM_ITERATIONS) -> xr.Dataset:
    """Composite pair spectra minimising Eq. 16 at every frequency.

    All inputs share a ``window`` dim (and any others, e.g. ``output, input, frequency``);
    ``weight`` are the Eq. 14 weights (zero = window not used). Returns ``Gxx_pair``,
    ``Gyy_pair``, ``Gxy_pair`` and ``coherence`` (``|Gxy|^2 / (Gxx Gyy)``) without ``window``;
    NaN where no window has weight.
    """
    gxx, gyy, gxy = xr.apply_ufunc(
        _lm_core, Gxx_pair, Gyy_pair, Gxy_pair, coherence, weight,
        input_core_dims=[["window"]] * 5, output_core_dims=[[], [], []],
        kwargs={"iterations": iterations, "coherence_weight": coherence_weight})
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = (abs(gxy) ** 2 / (gxx * gyy)).clip(0.0, 1.0)
    return xr.Dataset({"Gxx_pair": gxx, "Gyy_pair": gyy, "Gxy_pair": gxy, "coherence": coh})


def composite_response(per_window: xr.Dataset, *, coherence_weight: float = COHERENCE_WEIGHT,
                       iterations: int = LM_ITERATIONS) -> xr.Dataset:
    """Composite frequency responses (Eq. 14-17) from per-window pair results.

    ``per_window`` holds ``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair``, ``partial_coherence`` and
    ``random_error`` (output, input, frequency, window) -- conditioned (MIMO) or ordinary (SISO)
    -- and optionally ``collinear`` (frequency, window). Returns ``H`` (Eq. 17),
    ``partial_coherence`` (composite coherence of the pair spectra), ``random_error``,
    ``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair`` and the weights ``weight`` (with ``window``).
    """
    usable = trusted(per_window["frequency"], per_window["window"])
    if "collinear" in per_window:
        usable = usable & ~per_window["collinear"]
    w = weights(per_window["random_error"], usable)
    ds = composite_spectra(per_window["Gxx_pair"], per_window["Gyy_pair"],
                           per_window["Gxy_pair"], per_window["partial_coherence"], w,
                           coherence_weight=coherence_weight, iterations=iterations)
    ds = ds.rename(coherence="partial_coherence")
    with np.errstate(invalid="ignore", divide="ignore"):
        ds["H"] = ds["Gxy_pair"] / ds["Gxx_pair"]
        wsum = w.sum("window")
        ds["random_error"] = ((w * per_window["random_error"].fillna(0.0)).sum("window")
                              / wsum.where(wsum > 0))
    ds["weight"] = w
    order = ("output", "input", "frequency")
    for name in ("H", "partial_coherence", "random_error", "Gxx_pair", "Gyy_pair", "Gxy_pair"):
        ds[name] = ds[name].transpose(*order, ...)
    return ds


def average_windows(da: xr.DataArray, n_d: xr.DataArray, usable: xr.DataArray) -> xr.DataArray:
    """Average a per-window quantity that belongs to no single input/output pair (the input
    matrix, output autospectra...), with Eq. 14 weights for equal coherence:
    ``eps ~ n_d^-1/2`` gives ``W = (n_d / n_d_max)^2`` over the usable windows."""
    n = n_d.where(usable)
    w = ((n / n.max("window")) ** 2).fillna(0.0)
    wsum = w.sum("window")
    return (da * w).sum("window") / wsum.where(wsum > 0)
