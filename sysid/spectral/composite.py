"""Composite windowing (paper Eq. 14-17): one response from several window lengths.

Short windows average many segments (low random error) but resolve low frequencies poorly;
long windows reach low frequencies with fewer averages. Compositing combines them frequency by
frequency.

Window lengths (:func:`default_windows`; docs/methods.md, "Composite windowing")
    longest ``T_max = min(T_record / 2, T_total / 5)`` (``T_record`` the shortest record,
    ``T_total`` all records together), shortest ``T_min = 20 / f_max`` (20 periods of the
    highest frequency of interest, ``f_max = omega_max / 2 pi`` in Hz), ``n_windows`` (default
    5) lengths log-spaced in between. A window is trusted only at ``omega >= 2 pi / T``
    (:func:`trusted`, one period per window; a stricter rule changed nothing measurable,
    docs/notes/2026-11-21-composite-trusted-band.md); elsewhere its weight is zero. Windows
    with fewer than 5 independent averages are refused before this stage
    (:func:`sysid.spectral.spectra.check_window`); ``n_d = T_r / T`` does not vary with frequency.

Weights (Eq. 14)
    ``W_i = (eps_i / eps_min)^-4`` with ``eps_i`` the window's random error -- Eq. 13 from the
    pair's conditioned partial coherence and the window's ``n_d`` (Eq. 9 for the ordinary
    spectra) -- and ``eps_min`` the smallest among the trusted windows at that frequency.

Cost (Eq. 16), minimised at every frequency over the composite pair spectra
``Gxx_c, Gyy_c > 0`` and complex ``Gxy_c``::

    J = sum_i W_i [ ((Gxx_c - Gxx_i) / s_xx)^2 + ((Gyy_c - Gyy_i) / s_yy)^2
                    + ((Re Gxy_c - Re Gxy_i) / s_xy)^2 + ((Im Gxy_c - Im Gxy_i) / s_xy)^2
                    + 5 ((g2_c - g2_i) / g2^)^2 ],     g2_c = |Gxy_c|^2 / (Gxx_c Gyy_c)

with ``g2_i`` the windows' partial coherences and ``g2^`` their ``W^2``-weighted average as
in Eq. 15; the coherence term keeps the paper's weight 5. Then ``H_c = Gxy_c / Gxx_c``
(Eq. 17) and the composite coherence is ``g2_c``.

Scales ``s`` (where this differs from the printed Eq. 16): the spread of the windows' values of
that spectrum about their ``W``-weighted mean ``xbar``, ``s_x^2 = sum_i W_i |x_i - xbar|^2 /
sum_i W_i`` (floored at ``DISPERSION_FLOOR |xbar|``), one complex spread for both parts of
``Gxy``. Why: with the Eq. 15 averages (or ``Re``/``Im`` of ``Gxy^``, which cross zero) the
coherence correction lands in ``H``; with the spread it lands on the spectrum the windows
disagree on (docs/notes/2026-11-21-composite-normalisation.md). ``scale="average"`` gives the
Eq. 15 scaling (``|Gxy^|`` for both cross-spectrum terms) for comparison.

Solution: since ``sum_i W_i (x - x_i)^2 = (sum_i W_i)(x - xbar)^2 + const``, the cost is a
4-parameter nonlinear least-squares problem per frequency, solved by Levenberg-Marquardt
vectorised over all frequencies (in the variables ``x / s`` the Jacobian is the identity plus
the rank-one coherence term, so each step is closed-form by Sherman-Morrison), starting from
the ``W``-weighted means.

Composite random error
    ``eps_c = sum_i W_i eps_i / sum_i W_i``: the windows use the same data, so their errors are
    strongly correlated and the composite cannot be trusted more than its best windows; this
    weighted mean is close to ``eps_min`` since the Eq. 14 weights fall off as ``eps^-4``.

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012 (CIFER's COMPOSITE).
* *Comparison of frequency and time domain identification of a helicopter in hover*
  (Eq. 14-17).
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.spectral.spectra import MIN_AVERAGES

#: Number of window lengths combined (Tischler & Remple's example uses 5).
DEFAULT_N_WINDOWS = 5
#: Periods of the highest frequency in the shortest window (``T_min = 20 / f_max``).
PERIODS_IN_SHORTEST_WINDOW = 20.0
#: Weight of the coherence term of Eq. 16.
COHERENCE_WEIGHT = 5.0
#: Exponent of Eq. 14.
WEIGHT_EXPONENT = -4.0
#: Levenberg-Marquardt iterations of the Eq. 16 minimisation. On the reference MIMO system the
#: responses of all pairs with a path agree with a 300-iteration solution to 1e-9 after 20 and
#: to 1e-13 after 30 (pairs without a path, pure noise, can need ~20 before the damping
#: settles); 40 leaves a margin at a cost of a few ms.
LM_ITERATIONS = 40
#: Scale of the spectral terms of Eq. 16: ``"dispersion"`` (the windows' spread, default) or
#: ``"average"`` (the Eq. 15 weighted averages).
DEFAULT_SCALE = "dispersion"
#: Smallest spread scale relative to the weighted mean (windows that agree exactly). Any value
#: from 1e-6 to 5e-2 gives the same composite responses to 3 digits on the test systems.
DISPERSION_FLOOR = 1e-3
_SCALES = ("dispersion", "average")


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


def _scales(gxx, gyy, gxy, w, w1s, w2s, scale):
    """Scales ``s_xx, s_yy, s_xy`` of the spectral terms of Eq. 16 (see the module docstring)
    and the ``W``-weighted means ``xbar`` (minimisers of the quadratic terms)."""
    bar_xx = (w * gxx).sum(-1) / w1s
    bar_yy = (w * gyy).sum(-1) / w1s
    bar_xy = (w * gxy).sum(-1) / w1s
    if scale == "average":
        # Eq. 15: W^2-weighted averages
        s_xx = (w * w * gxx).sum(-1) / w2s
        s_yy = (w * w * gyy).sum(-1) / w2s
        s_xy = np.abs((w * w * gxy).sum(-1) / w2s)
    else:
        # the windows' spread about the weighted mean, floored for windows that agree exactly
        floor = DISPERSION_FLOOR ** 2
        s_xx = np.sqrt((w * (gxx - bar_xx[..., None]) ** 2).sum(-1) / w1s + floor * bar_xx ** 2)
        s_yy = np.sqrt((w * (gyy - bar_yy[..., None]) ** 2).sum(-1) / w1s + floor * bar_yy ** 2)
        s_xy = np.sqrt((w * np.abs(gxy - bar_xy[..., None]) ** 2).sum(-1) / w1s
                       + floor * np.abs(bar_xy) ** 2)
    s_xx = np.where(s_xx > 0, s_xx, 1.0)
    s_yy = np.where(s_yy > 0, s_yy, 1.0)
    s_xy = np.maximum(s_xy, 1e-9 * DISPERSION_FLOOR * np.sqrt(s_xx * s_yy))
    return (bar_xx, bar_yy, bar_xy), (s_xx, s_yy, s_xy)


def _lm_core(gxx, gyy, gxy, coh, w, iterations, coherence_weight, scale=DEFAULT_SCALE):
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
    (bar_xx, bar_yy, bar_xy), (s_xx, s_yy, s_xy) = _scales(gxx, gyy, gxy, w, w1s, w2s, scale)
    # Eq. 15: W^2-weighted average coherence (normaliser); W-weighted mean (minimiser)
    hat_coh = (w * w * coh).sum(-1) / w2s
    bar_coh = (w * coh).sum(-1) / w1s
    # variables x = (Gxx_c / s_xx, Gyy_c / s_yy, Re Gxy_c / s_xy, Im Gxy_c / s_xy): the four
    # quadratic terms are then |x - target|^2 (times sum W, which divides out)
    target = np.stack([bar_xx / s_xx, bar_yy / s_yy, bar_xy.real / s_xy, bar_xy.imag / s_xy])
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


def _check_scale(scale: str) -> None:
    if scale not in _SCALES:
        raise InputDataError(f"composite scale must be one of {_SCALES}, got {scale!r}")


def composite_spectra(Gxx_pair: xr.DataArray, Gyy_pair: xr.DataArray, Gxy_pair: xr.DataArray,
                      coherence: xr.DataArray, weight: xr.DataArray, *,
                      coherence_weight: float = COHERENCE_WEIGHT,
                      iterations: int = LM_ITERATIONS,
                      scale: str = DEFAULT_SCALE) -> xr.Dataset:
    """Composite pair spectra minimising Eq. 16 at every frequency.

    All inputs share a ``window`` dim (and any others, e.g. ``output, input, frequency``);
    ``weight`` are the Eq. 14 weights (zero = window not used). ``scale`` selects the
    normalisation of the spectral terms: ``"dispersion"`` (default, the windows' spread) or
    ``"average"`` (Eq. 15); see the module docstring. Returns ``Gxx_pair``, ``Gyy_pair``,
    ``Gxy_pair`` and ``coherence`` (``|Gxy|^2 / (Gxx Gyy)``) without ``window``; NaN where no
    window has weight.
    """
    _check_scale(scale)
    gxx, gyy, gxy = xr.apply_ufunc(
        _lm_core, Gxx_pair, Gyy_pair, Gxy_pair, coherence, weight,
        input_core_dims=[["window"]] * 5, output_core_dims=[[], [], []],
        kwargs={"iterations": iterations, "coherence_weight": coherence_weight,
                "scale": scale})
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = (abs(gxy) ** 2 / (gxx * gyy)).clip(0.0, 1.0)
    return xr.Dataset({"Gxx_pair": gxx, "Gyy_pair": gyy, "Gxy_pair": gxy, "coherence": coh})


def composite_response(per_window: xr.Dataset, *, coherence_weight: float = COHERENCE_WEIGHT,
                       iterations: int = LM_ITERATIONS,
                       scale: str = DEFAULT_SCALE) -> xr.Dataset:
    """Composite frequency responses (Eq. 14-17) from per-window pair results.

    ``per_window`` holds ``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair``, ``partial_coherence`` and
    ``random_error`` (output, input, frequency, window) -- conditioned (MIMO) or ordinary (SISO)
    -- and optionally ``collinear`` (frequency, window). Returns ``H`` (Eq. 17),
    ``partial_coherence`` (composite coherence of the pair spectra), ``random_error``,
    ``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair`` and the weights ``weight`` (with ``window``).
    ``scale`` as in :func:`composite_spectra`.
    """
    _check_scale(scale)
    usable = trusted(per_window["frequency"], per_window["window"])
    if "collinear" in per_window:
        usable = usable & ~per_window["collinear"]
    w = weights(per_window["random_error"], usable)
    ds = composite_spectra(per_window["Gxx_pair"], per_window["Gyy_pair"],
                           per_window["Gxy_pair"], per_window["partial_coherence"], w,
                           coherence_weight=coherence_weight, iterations=iterations,
                           scale=scale)
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
