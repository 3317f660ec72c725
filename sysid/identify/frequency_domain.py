"""Frequency-domain output-error identification (CIFER DERIVID style).

Cost (docs/methods.md, "Frequency-domain fit"; Tischler & Remple 2012). For each selected
output/input pair ``l``, over ``n_omega`` (default 20) log-spaced frequencies of the pair's
coherent range,

    J_l = (20 / n_omega) sum_omega W_gamma [ W_g (|T_c|_dB - |T|_dB)^2
                                           + W_p (angle T_c - angle T)^2 ]

with the measured (composite) response ``T_c``, the model response ``T`` of Eq. 19 (with the
per-entry delays), the phase difference in degrees wrapped to +-180, ``W_g = 1``,
``W_p = 0.01745`` and ``W_gamma = [1.58 (1 - exp(-gamma^2))]^2`` (``gamma^2`` is the coherence
itself, not squared again). ``J = sum_l J_l`` and ``J_ave = J / n_pairs``.

Coherence used: the ``partial_coherence`` of the composite Dataset when present (it measures
the linear dependence of the output on the *conditioned* input, i.e. the quality of the
conditioned MIMO response ``H`` that is fitted, paper Eq. 11), else the ordinary
``coherence`` (Eq. 7). Its range ``>= coherence_min`` (default 0.6, the paper's guideline)
selects the fitted band: the longest run of consecutive frequencies meeting it that spans at
least the frequency resolution ``2 pi / T_max`` of the longest window (a narrower run holds
less than two independent spectral estimates; :func:`frequency_resolution`).

Minimisation: :func:`scipy.optimize.least_squares` on the residual vector
``r = sqrt((20/n) W_gamma) [ W_g^1/2 (dB error), W_p^1/2 (phase error, deg) ]`` (so
``sum r^2 = J``), with the analytic Jacobian of Eq. 19 (see
:meth:`sysid.models.LinearStructure.pair_response`). Default method ``"trf"``: a trust-region
Levenberg-Marquardt-type algorithm that, unlike MINPACK's ``"lm"``, honours bounds, which
keeps free delays in their physical range 0..0.3 s (docs/methods.md, "Delays"). ``"lm"`` is accepted when no
parameter is bounded. The fit is restarted once from the solution perturbed by a seeded
+-20 % to confirm the minimum; the better of the two is kept and both costs are reported.
A solve also ends where its last accepted steps stopped gaining (:data:`STALL_DECREASE`).

Accuracy (CIFER convention): ``H = G^T G`` with ``G`` the Jacobian of the weighted residuals
above, i.e. ``H = sum_l (20/n) sum_omega W_gamma [W_g g_dB g_dB^T + W_p g_phase g_phase^T]``
(half the Gauss-Newton Hessian of J). ``CR_i = sqrt((H^-1)_ii)``, ``I_i = 1/sqrt(H_ii)``. No
residual-variance rescaling: CIFER's cost weights are chosen so that J behaves like a
likelihood with unit-variance residuals (one unit of cost ~ 1 dB magnitude error or 7.6 deg
phase error at unit coherence weight), so the bound is comparable across pairs and data sets
and the 20 % / 10 % guidelines and the model reduction apply to it unchanged (Tischler &
Remple 2012). It is a standard deviation of the estimate only when the weighted residuals
are independent with unit variance, i.e. ``J_ave`` near ``2 n_omega`` (40); a closer fit
scatters proportionally less than the bound says.

Residual-scaled bound (``cramer_rao_corrected``, :func:`residual_scaled_bounds`): the
sandwich ``H^-1 B H^-1`` of :func:`sysid.identify.statistics.coloured_residual_covariance`
with each pair's fitted points, in frequency order, as one record of two outputs (weighted
magnitude and phase residuals): ``B = sum_pairs sum_i sum_j g_i^T R(i - j) g_j`` with ``R``
the residual correlation over neighbouring points pooled over the pairs, Bartlett-weighted.
It takes the residual level from the fit and counts neighbouring points (interpolated from
overlapping windows) as correlated. A structure's misfit repeats from one noise seed to the
next, so where it dominates the residuals this bound measures the misfit, not the scatter.

Noise bound (``cramer_rao_noise``, :func:`random_error_bounds`): the same sandwich with the
residual covariance taken from the spectral random error of the measured response instead of
the residuals, so it carries the measurement noise only, not the model's misfit; the bound
the fidelity scoreboard and the Monte Carlo calibration judge the errors on (docs/methods.md,
"Accuracy": calibrated on known systems, optimistic on the truth FMU).

Selection bound (``cramer_rao_selection``, :func:`selection_bounds`): the scatter of the
estimate over refits on points re-selected from draws of the coherence within its own random
error (a parametric bootstrap of the threshold choice). Under a structure's misfit the
estimate depends on which points are fitted, and the hard coherence threshold moves them
from one data set to the next; the random-error bound cannot see that. ``cramer_rao_total``
(both in quadrature) is the bound the fidelity scoreboard judges on (docs/methods.md,
"Accuracy").

Start values (paper: results depend on them; here they must not): from a start model
Dataset (e.g. the truth model's quasi-steady linearisation) when given, otherwise from a
frequency-domain equation-error fit (:func:`equation_error_start`).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012 (CIFER's DERIVID cost, accuracy metrics).
* *Comparison of frequency and time domain identification of a helicopter in hover*
  (Eq. 18-19).
* docs/methods.md, "Frequency-domain fit", "Accuracy", "Delays".
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Mapping, NamedTuple, Sequence

import numpy as np
import scipy.optimize
import xarray as xr

from sysid.core.errors import IdentificationError, InputDataError
from sysid.core.guidelines import COHERENCE_MIN, FIT_TIME_LIMIT_S, UNDETERMINED_PERCENT
from sysid.identify.least_squares import STALL_WINDOW, Stalled, compress, stall_watch
from sysid.identify.reduction import (GUIDELINES, FitOutcome, ReductionResult,
                                      STOPPED_ABOVE_CEILING, StoppedAboveCeiling,
                                      ceiling_watch, conditional_start,
                                      stepwise_reduction)
from sysid.identify.statistics import (ColouredBounds, FitResultParameters,
                                      ParameterStatistics, coloured_residual_covariance,
                                      on_parameters, parameter_rows, parameter_statistics,
                                      perturbed_start, robust_scale, OUTLYING_SCALES)
from sysid.models import LinearStructure
from sysid.spectral.composite import trusted as composite_trusted
from sysid.core.util import Deadline, Progress, fit_settings

__all__ = [
    "DEFAULT_PAIRS",
    "W_G",
    "W_P",
    "frequency_resolution",
    "coherence_weight",
    "parse_pairs",
    "FitData",
    "select_fit_data",
    "cifer_cost",
    "response_errors",
    "response_residuals",
    "response_jacobian",
    "equation_error_start",
    "residual_scaled_bounds",
    "random_error_bounds",
    "coherence_random_error",
    "coherence_correlation_width",
    "perturbed_coherence",
    "selection_bounds",
    "SelectionScatter",
    "FrequencyFitResult",
    "identify_frequency_domain",
]

#: The paper's input/output pairs (model structure section): on-axis q/lon, p/lat, w/col,
#: r/ped; coupling p/lon, q/lat, r/col, v/ped; high-coherence u/lon, v/lat, r/lat, p/col, q/col.
DEFAULT_PAIRS = (("q", "lon"), ("p", "lon"), ("u", "lon"), ("p", "lat"), ("q", "lat"),
                 ("v", "lat"), ("r", "lat"), ("w", "col"), ("r", "col"), ("p", "col"),
                 ("q", "col"), ("r", "ped"), ("v", "ped"))
W_G = 1.0  #: magnitude weight (per dB^2), docs/methods.md
W_P = 0.01745  #: phase weight (per deg^2), docs/methods.md
N_POINTS = 20  #: frequency points per pair (docs/methods.md)
#: Draws of the point-selection bootstrap (:func:`selection_bounds`): its standard deviation
#: is then known to about 1 / sqrt(2 (draws - 1)), i.e. 16 %, like a 20-seed Monte Carlo, and
#: a jump of the estimate that one re-selection in ten causes is seen with probability 0.88.
SELECTION_DRAWS = 20
#: Reduction refits start at the conditional minimum of the last fit's quadratic model
#: (:func:`sysid.identify.reduction.conditional_start`; False: at the other estimates
#: unchanged, as before).
CONDITIONAL_START = True
#: A free parameter has "run away" when the fit ends with it this many times larger than its
#: start value (and than 1 in analysis units) and its Cramer-Rao bound is unbounded or above
#: :data:`RUNAWAY_CR_PERCENT`: the optimiser slid along a valley in which only ratios are
#: determined. Example: a roll-subsidence pole above the fitted band leaves only
#: ``L_x / L_p`` in p/lat, and the whole roll row grows together (quick 100-kt campaign:
#: 27x the linearisation, CR 235-250 %, on to 1e15 in the model reduction).
RUNAWAY_FACTOR = 10.0
RUNAWAY_CR_PERCENT = UNDETERMINED_PERCENT
#: ... or when it ends this many times larger than its start value (and than 1) whatever its
#: bound: far along such a valley the relative bound shrinks with the value (full 100-kt
#: campaign: the roll row at 1e8-1e9, L_p at 6e8 with a bound under 100 %, no anchor, 1e20
#: in the reduction and a model whose 2311 response overflowed).
RUNAWAY_FAR_FACTOR = 1000.0
#: Runaway damping derivatives are held at their start values (the a priori model), which
#: fixes the scale of their row while the ratios of the others to them stay identified.
#: Other runaway parameters are left to the model reduction.
DAMPING_DERIVATIVES = ("L_p", "M_q", "N_r", "Z_w", "Y_v", "X_u")
#: A solve ends where its last STALL_WINDOW accepted steps together lowered J_ave by less than
#: STALL_DECREASE (:func:`sysid.identify.least_squares.stall_watch`): 1/5000 of the model
#: reduction's 2-J_ave acceptance threshold, like the time-domain fits' settle test.
STALL_DECREASE = 4e-4
#: ``status`` of a solve ended by the stall test (scipy uses -1 to 4, the reduction -2).
STALLED = -3
_DB = 20.0 / math.log(10.0)
_DEG = 180.0 / math.pi


def coherence_weight(gamma2):
    """CIFER coherence weight ``W_gamma = [1.58 (1 - exp(-gamma^2))]^2``.

    ``gamma2`` is the coherence (already a squared quantity, 0..1); it is not squared again.
    """
    g2 = np.clip(np.nan_to_num(np.asarray(gamma2, dtype=float), nan=0.0), 0.0, 1.0)
    return (1.58 * (1.0 - np.exp(-g2))) ** 2


def parse_pairs(pairs) -> tuple[tuple[str, str], ...]:
    """``"q/lon,p/lat"`` or ``["q/lon", ("p", "lat")]`` -> ``(("q", "lon"), ("p", "lat"))``."""
    if pairs is None:
        return DEFAULT_PAIRS
    if isinstance(pairs, str):
        pairs = [p for p in pairs.split(",") if p.strip()]
    out = []
    for p in pairs:
        if isinstance(p, str):
            parts = [x.strip() for x in p.split("/")]
            if len(parts) != 2 or not all(parts):
                raise InputDataError(f"pair {p!r}: expected 'output/input', e.g. 'q/lon'")
            out.append((parts[0], parts[1]))
        else:
            o, i = p
            out.append((str(o), str(i)))
    if not out:
        raise InputDataError("no input/output pairs given")
    return tuple(out)


def _pair_name(pair) -> str:
    return f"{pair[0]}/{pair[1]}"


@dataclass
class FitData:
    """The points fitted: per point its pair, frequency and measured response.

    Arrays have shape (n_point,); pair ``l`` owns the points with ``pair_index == l``.

    Attributes
    ----------
    pairs : tuple of (output, input)
        Pairs with a coherent range (fitted).
    skipped : dict
        ``"out/in" -> reason`` for the pairs left out.
    omega : ndarray
        rad/s.
    mag_db, phase_deg : ndarray
        Measured magnitude (dB) and phase (deg, unwrapped along the pair's range).
    coherence : ndarray
        gamma^2 at the point; ``weight`` = ``(20/n) W_gamma``.
    ranges : dict
        ``"out/in" -> (omega_min, omega_max)``.
    coherence_variable : str
        ``"partial_coherence"`` or ``"coherence"``.
    weak : dict
        Pairs admitted at the fallback coherence threshold (see :func:`select_fit_data`).
    """

    pairs: tuple
    skipped: dict
    pair_index: np.ndarray
    omega: np.ndarray
    mag_db: np.ndarray
    phase_deg: np.ndarray
    coherence: np.ndarray
    random_error: np.ndarray
    weight: np.ndarray
    ranges: dict
    n_points: int
    coherence_min: float
    coherence_variable: str
    weak: dict = field(default_factory=dict)  #: ``"out/in" -> fallback threshold used``

    @property
    def H(self) -> np.ndarray:
        """Measured complex response at the points."""
        return 10.0 ** (self.mag_db / 20.0) * np.exp(1j * np.deg2rad(self.phase_deg))


def _longest_run(mask: np.ndarray, omega: np.ndarray | None = None,
                 min_width: float = 0.0) -> tuple[int, int] | None:
    """Longest run of consecutive ``True`` (``(start, stop)`` indices) among the runs that
    span at least ``min_width`` rad/s of ``omega``."""
    best, start, best_len = None, None, 0
    for k, ok in enumerate(list(mask) + [False]):
        if ok and start is None:
            start = k
        elif not ok and start is not None:
            wide = omega is None or omega[k - 1] - omega[start] >= min_width
            if wide and k - start > best_len:
                best, best_len = (start, k), k - start
            start = None
    return best


def frequency_resolution(fr: xr.Dataset) -> float:
    """Spacing of independent spectral estimates of the longest window, ``2 pi / T_max``
    (rad/s); 0 when the Dataset does not record its windows (attribute ``windows``, s).

    A coherent run narrower than this holds less than two independent estimates (one Hann
    main lobe): its interpolated points are not independent data, so it is not fitted.
    """
    windows = np.atleast_1d(np.asarray(fr.attrs.get("windows", []), dtype=float))
    windows = windows[np.isfinite(windows) & (windows > 0)]
    return 2.0 * math.pi / float(windows.max()) if windows.size else 0.0


def select_fit_data(fr: xr.Dataset, pairs=None, *, coherence_min: float = COHERENCE_MIN,
                    n_points: int = N_POINTS,
                    ranges: Mapping[str, tuple[float, float]] | None = None,
                    frequency_range: tuple[float, float] | None = None,
                    fallback_coherence_min: float | None = None) -> FitData:
    """Choose the fitted points of each pair from a composite frequency-response Dataset.

    Parameters
    ----------
    fr : xr.Dataset
        Dims ``output, input, frequency`` (rad/s); ``H`` complex; ``partial_coherence`` or
        ``coherence``; optionally ``random_error`` (docs/data_model.md).
    pairs : str or sequence, optional
        ``"q/lon,p/lat"`` etc.; default :data:`DEFAULT_PAIRS`.
    coherence_min : float
        Pairs are fitted over the longest run of consecutive frequencies with
        ``gamma^2 >= coherence_min`` (default 0.6) that spans at least
        :func:`frequency_resolution` of ``fr``.
    n_points : int
        Log-spaced points per pair over that range (default 20); the measured magnitude (dB),
        unwrapped phase and coherence are interpolated linearly in log frequency.
    ranges : mapping, optional
        ``"q/lon" -> (omega_min, omega_max)`` limiting a pair's range (rad/s).
    frequency_range : (float, float), optional
        Global limit for every pair (rad/s).
    fallback_coherence_min : float, optional
        A pair with no coherent range at ``coherence_min`` is retried at this lower
        threshold (and reported in ``FitData.weak``) instead of being skipped. Meant for weak
        off-axis responses that still constrain a derivative; the coherence weight
        ``W_gamma`` keeps them from dominating. Default: no fallback.

    Returns
    -------
    FitData
        Pairs without a coherent range (or absent from ``fr``) are listed in ``skipped``.
    """
    pairs = parse_pairs(pairs)
    if "H" not in fr:
        raise InputDataError("frequency-response Dataset has no variable 'H'")
    if "window" in fr["H"].dims:
        raise InputDataError("frequency-response Dataset still has a 'window' dimension; "
                             "identification needs the composite responses")
    for dim in ("output", "input", "frequency"):
        if dim not in fr["H"].dims:
            raise InputDataError(f"frequency-response 'H' lacks dimension {dim!r} "
                                 f"(has {fr['H'].dims})")
    cvar = "partial_coherence" if "partial_coherence" in fr else "coherence"
    if cvar not in fr:
        raise InputDataError("frequency-response Dataset has neither 'partial_coherence' nor "
                             "'coherence'")
    omega_all = np.asarray(fr["frequency"].values, dtype=float)
    order = np.argsort(omega_all)
    omega_all = omega_all[order]
    resolution = frequency_resolution(fr)
    ranges = dict(ranges or {})
    outputs = [str(x) for x in fr["output"].values]
    inputs = [str(x) for x in fr["input"].values]
    kept, skipped, weak = [], {}, {}
    cols = {k: [] for k in ("pair", "omega", "mag", "phase", "g2", "eps")}
    used_ranges = {}
    for pair in pairs:
        name = _pair_name(pair)
        if pair[0] not in outputs or pair[1] not in inputs:
            skipped[name] = "not in the frequency-response Dataset"
            continue
        H = np.asarray(fr["H"].sel(output=pair[0], input=pair[1]).values)[order]
        g2 = np.asarray(fr[cvar].sel(output=pair[0], input=pair[1]).values, float)[order]
        eps = (np.asarray(fr["random_error"].sel(output=pair[0], input=pair[1]).values,
                          float)[order] if "random_error" in fr else np.full(len(H), np.nan))
        valid = np.isfinite(H) & np.isfinite(g2) & (np.abs(H) > 0) & (omega_all > 0)
        for lim in (frequency_range, ranges.get(name)):
            if lim is not None:
                valid &= (omega_all >= lim[0]) & (omega_all <= lim[1])
        run = _longest_run(valid & (g2 >= coherence_min), omega_all, resolution)
        if (run is None or run[1] - run[0] < 2) and fallback_coherence_min is not None:
            run = _longest_run(valid & (g2 >= fallback_coherence_min), omega_all, resolution)
            if run is not None and run[1] - run[0] >= 2:
                weak[name] = float(fallback_coherence_min)
        if run is None or run[1] - run[0] < 2:
            skipped[name] = (f"no coherent range (coherence {cvar} >= {coherence_min} at fewer "
                             f"than 2 consecutive frequencies, or over less than the "
                             f"resolution {resolution:.3g} rad/s of the longest window)")
            continue
        sl = slice(*run)
        w = omega_all[sl]
        lw = np.log(w)
        pts = np.exp(np.linspace(lw[0], lw[-1], n_points))
        lp = np.log(pts)
        mag = 20.0 * np.log10(np.abs(H[sl]))
        ph = np.unwrap(np.angle(H[sl]))
        cols["pair"].append(np.full(n_points, len(kept)))
        cols["omega"].append(pts)
        cols["mag"].append(np.interp(lp, lw, mag))
        cols["phase"].append(np.rad2deg(np.interp(lp, lw, ph)))
        cols["g2"].append(np.interp(lp, lw, g2[sl]))
        cols["eps"].append(np.interp(lp, lw, eps[sl]))
        used_ranges[name] = (float(w[0]), float(w[-1]))
        kept.append(pair)
    if not kept:
        collinear = (fr.attrs.get("collinear_note") or (
            "inputs are collinear at some frequencies (the response's 'collinear' flag)"
            if "collinear" in fr and bool(fr["collinear"].any()) else ""))
        raise IdentificationError(
            "no input/output pair has a coherent frequency range (coherence >= "
            f"{coherence_min})" + (f"; {collinear}: their responses cannot be separated"
                                   if collinear else "") + ": "
            + "; ".join(f"{k}: {v}" for k, v in skipped.items()))
    cat = {k: np.concatenate(v) for k, v in cols.items()}
    weight = (20.0 / n_points) * coherence_weight(cat["g2"])
    return FitData(tuple(kept), skipped, cat["pair"].astype(int), cat["omega"], cat["mag"],
                   cat["phase"], cat["g2"], cat["eps"], weight, used_ranges, int(n_points),
                   float(coherence_min), cvar, weak)


def _wrap180(x):
    return (np.asarray(x) + 180.0) % 360.0 - 180.0


def response_errors(T, data: FitData) -> tuple[np.ndarray, np.ndarray]:
    """Raw CIFER errors of a model response ``T`` at the points of ``data``: magnitude (dB)
    and phase (deg, wrapped to +-180), model minus measured. A response of exactly zero gets
    a large but finite magnitude error (400 dB)."""
    T = np.asarray(T)
    with np.errstate(divide="ignore"):
        mag = _DB * np.log(np.abs(T))
    e_mag = mag - data.mag_db
    e_ph = _wrap180(np.angle(T, deg=True) - data.phase_deg)
    bad = ~np.isfinite(e_mag)
    if np.any(bad):
        e_mag = np.where(bad, 400.0, e_mag)
    return e_mag, e_ph


def response_residuals(T, data: FitData) -> np.ndarray:
    """Weighted residuals ``sqrt(weight) [W_g^1/2 e_dB, W_p^1/2 e_deg]`` of a model response
    ``T`` at the points of ``data`` (module docstring); their sum of squares is the CIFER
    cost ``J``."""
    e_mag, e_ph = response_errors(T, data)
    sqrt_w = np.sqrt(data.weight)
    return np.concatenate([sqrt_w * math.sqrt(W_G) * e_mag, sqrt_w * math.sqrt(W_P) * e_ph])


def response_jacobian(T, dT, data: FitData) -> np.ndarray:
    """Jacobian of :func:`response_residuals` from the response ``T`` (n_point,) and its
    derivatives ``dT`` (n_point, n_parameter): ``d dB = (20/ln 10) Re(dT/T)``,
    ``d deg = (180/pi) Im(dT/T)``."""
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        rel = np.asarray(dT) / np.asarray(T)[:, None]
        sqrt_w = np.sqrt(data.weight)
        J = np.vstack([(sqrt_w * math.sqrt(W_G))[:, None] * _DB * rel.real,
                       (sqrt_w * math.sqrt(W_P))[:, None] * _DEG * rel.imag])
    # Where the response vanishes or overflows, response_errors clamps the residual to a
    # constant: no slope (an inf here would stop the solver with a NaN/inf error).
    return np.where(np.isfinite(J), J, 0.0)


class _Problem:
    """Residuals and analytic Jacobian of the CIFER cost for one structure and data set."""

    def __init__(self, structure: LinearStructure, data: FitData):
        self.structure = structure
        self.data = data
        missing = [_pair_name(p) for p in data.pairs
                   if p[0] not in structure.outputs or p[1] not in structure.inputs]
        if missing:
            raise IdentificationError(f"structure {structure.name!r} has no output/input for "
                                      f"pairs {missing} (outputs {list(structure.outputs)}, "
                                      f"inputs {list(structure.inputs)})")
        outs = np.array([structure.outputs.index(p[0]) for p in data.pairs])
        ins = np.array([structure.inputs.index(p[1]) for p in data.pairs])
        self.out_idx = outs[data.pair_index]
        self.in_idx = ins[data.pair_index]
        self.s = 1j * data.omega
        self.n_cost = 0
        self.n_jac = 0
        self._cache_key = None
        self._cache = None
        self._compressed_key = None
        self._compressed_value = None

    def _eval(self, theta, jacobian):
        key = (theta.tobytes(), jacobian)
        if self._cache_key == key or (not jacobian and self._cache_key == (theta.tobytes(), True)):
            return self._cache
        out = self.structure.pair_response(theta, self.s, self.out_idx, self.in_idx,
                                           jacobian=jacobian)
        self._cache_key, self._cache = key, out
        return out

    def errors(self, theta):
        """Raw errors: magnitude (dB) and wrapped phase (deg), model minus measured."""
        out = self._eval(np.asarray(theta, float), False)
        return response_errors(out[0] if isinstance(out, tuple) else out, self.data)

    def residuals(self, theta):
        self.n_cost += 1
        out = self._eval(np.asarray(theta, float), False)
        return response_residuals(out[0] if isinstance(out, tuple) else out, self.data)

    def jacobian(self, theta):
        self.n_jac += 1
        T, dT = self._eval(np.asarray(theta, float), True)
        return response_jacobian(T, dT, self.data)

    def compressed_residuals(self, theta):
        """The problem in ``n + 1`` rows (:func:`sysid.identify.least_squares.compress`): the
        same steps as the full one without an SVD of the tall Jacobian per iteration."""
        self.n_cost += 1
        return self._compressed(np.asarray(theta, float))[0]

    def compressed_jacobian(self, theta):
        self.n_jac += 1
        return self._compressed(np.asarray(theta, float))[1]

    def _compressed(self, theta):
        key = theta.tobytes()
        if self._compressed_key != key:
            T, dT = self._eval(theta, True)
            self._compressed_value = compress(response_residuals(T, self.data),
                                              response_jacobian(T, dT, self.data))
            self._compressed_key = key
        return self._compressed_value

    def pair_costs(self, theta) -> np.ndarray:
        r = self.residuals(theta)
        n = len(self.data.omega)
        per_point = r[:n] ** 2 + r[n:] ** 2
        return np.bincount(self.data.pair_index, weights=per_point,
                           minlength=len(self.data.pairs))


def cifer_cost(structure: LinearStructure, data: FitData, theta=None) -> dict[str, float]:
    """CIFER cost per pair (``"q/lon" -> J_l``) of a structure at ``theta`` (default start),
    with ``"J"`` (total) and ``"J_ave"`` (total / number of pairs)."""
    prob = _Problem(structure, data)
    theta = structure.theta0 if theta is None else np.asarray(theta, float)
    costs = prob.pair_costs(theta)
    out = {_pair_name(p): float(c) for p, c in zip(data.pairs, costs)}
    out["J"] = float(costs.sum())
    out["J_ave"] = float(costs.mean())
    return out


# --------------------------------------------------------------------------------------------
# Start values: frequency-domain equation error
# --------------------------------------------------------------------------------------------


def with_derived_states(fr: xr.Dataset, structure: LinearStructure) -> xr.Dataset:
    """``fr`` (``H`` and the coherences) plus the responses of the states it lacks that an
    output equation measures as a pure derivative: an output ``y = x_i' - K_i x`` (an
    accelerometer at the CG, ``ax = u' - K_u x``) gives ``H_x_i = (H_y + K_i H_x) / s``
    when every state ``K_i`` reads is in ``fr``; its coherence is the output's. Used for
    equation-error start values of data without ``u v w`` (Tischler & Remple 2012, ch. 11).
    """
    st = structure
    outs = [str(x) for x in fr["output"].values]
    names, rows = [], {}
    for i, state in enumerate(st.states):
        if state in outs:
            continue
        for o, out in enumerate(st.outputs):
            m = st.M[o]
            reads = [st.states[j] for j in np.flatnonzero(st.K[i])]
            if (out in outs and m[i] == 1.0 and np.count_nonzero(m) == 1
                    and not st.C0[o].any() and not st.D0[o].any()
                    and all(r in outs for r in reads)):
                names.append(state)
                rows[state] = (out, {r: float(st.K[i, st.states.index(r)]) for r in reads})
                break
    if not names:
        return fr
    s = 1j * xr.DataArray(np.asarray(fr["frequency"].values, float), dims="frequency",
                          coords={"frequency": fr["frequency"]})
    H, cohs = [], {v: [] for v in ("coherence", "partial_coherence") if v in fr}
    for state in names:
        out, reads = rows[state]
        h = fr["H"].sel(output=out) + sum(k * fr["H"].sel(output=r) for r, k in reads.items())
        H.append((h / s.where(s != 0)).assign_coords(output=state))
        for v in cohs:
            cohs[v].append(fr[v].sel(output=out).assign_coords(output=state))
    new = xr.Dataset({"H": xr.concat([fr["H"], *H], dim="output"),
                      **{v: xr.concat([fr[v], *c], dim="output") for v, c in cohs.items()}},
                     attrs=fr.attrs)
    return new


def equation_error_start(fr: xr.Dataset, structure: LinearStructure, data: FitData | None = None,
                         *, coherence_min: float = COHERENCE_MIN) -> np.ndarray:
    """Start values of the free parameters from a frequency-domain equation-error fit.

    With every state measured (C = I), the state equation holds for the response of all
    states to each input ``k``: ``s H_ik = sum_j A_ij H_jk + B~_ik`` (unit input k). Each row
    ``i`` of A and B is a linear least-squares problem in its free entries, over the measured
    frequencies of each input where ``gamma^2_ik >= coherence_min`` (restricted to the fitted
    ranges of that input's pairs when ``data`` is given). Every equation is normalised by
    ``|s H_ik|`` (relative equation error, so all frequencies count alike) and weighted by
    ``sqrt(W_gamma)``.

    States without a response of their own whose derivative an output measures (``u v w``
    from ``ax ay az``) are derived first (:func:`with_derived_states`).

    Free delays enter through the first-order expansion ``B_ik e^{-s tau} ~ B_ik - s c_ik``
    with ``c_ik = B_ik tau`` as an extra unknown, so ``tau = c/B`` (least squares over the
    delay's entries, clipped to its bounds). Parameters that no equation determines (rows
    without coherent data, C/D parameters) keep the structure's start values.
    """
    st = structure
    theta = st.theta0.copy()
    states = list(st.states)
    fr = with_derived_states(fr, st)
    fr_out = [str(x) for x in fr["output"].values]
    fr_in = [str(x) for x in fr["input"].values]
    if not all(s in fr_out for s in states):
        return theta  # equation error needs every state's response
    cvar = "partial_coherence" if "partial_coherence" in fr else "coherence"
    omega = np.asarray(fr["frequency"].values, float)
    Hall = fr["H"].sel(output=states).transpose("output", "input", "frequency").values
    G2 = np.nan_to_num(fr[cvar].sel(output=states).transpose("output", "input", "frequency")
                       .values.astype(float))
    free_pos = {int(k): j for j, k in enumerate(st.free_index)}
    # Known part: fixed matrices plus fixed parameters (free ones set to zero).
    Afix, Bfix, _, _, tau_fix = st.matrices(np.zeros(len(st.free_index)))
    band = {}
    if data is not None:
        for pair, (lo, hi) in data.ranges.items():
            inp = pair.split("/")[1]
            a, b = band.get(inp, (np.inf, -np.inf))
            band[inp] = (min(a, lo), max(b, hi))
    free_delay = {}  # (row, column) -> delay parameter index, for free delays
    for k, rows, col in st._delay_entries:
        if st.free_mask[k]:
            for r in rows:
                free_delay[(int(r), int(col))] = int(k)
    c_est: dict[tuple[int, int], float] = {}
    b_est: dict[tuple[int, int], float] = {}
    # each entry's regressor with its scale (a tied parameter's start: its entry on the
    # last row that has one, divided by that entry's scale)
    entries = [(key, int(k), int(r), int(c), float(w)) for key in ("A", "B")
               for k, r, c, w in zip(*st._entries[key], st._scales[key]) if st.free_mask[k]]
    for i in range(len(states)):
        regs = [(key, k, c, w) for key, k, r, c, w in entries if r == i]
        if not regs:
            continue
        regs += [("c", k, c, 1.0) for (r, c), k in free_delay.items() if r == i]
        rows_X, rows_y = [], []
        for m, inp in enumerate(st.inputs):
            if inp not in fr_in:
                continue
            ki = fr_in.index(inp)
            H = Hall[:, ki, :]  # (n_state, n_frequency)
            g2 = G2[i, ki, :]
            ok = (g2 >= coherence_min) & np.all(np.isfinite(H), axis=0) & (omega > 0)
            if inp in band:
                ok &= (omega >= band[inp][0]) & (omega <= band[inp][1])
            if ok.sum() < 2:
                continue
            s = 1j * omega[ok]
            Hk = H[:, ok]
            delayed = (i, m) in free_delay
            lhs = s * Hk[i] - Afix[i] @ Hk
            lhs = lhs - Bfix[i, m] * (1.0 if delayed else np.exp(-s * tau_fix[i, m]))
            X = np.zeros((ok.sum(), len(regs)), dtype=complex)
            for col, (kind, k, c, _) in enumerate(regs):
                if kind == "A":
                    X[:, col] = Hk[c]
                elif kind == "B" and c == m:
                    X[:, col] = 1.0 if delayed else np.exp(-s * tau_fix[i, m])
                elif kind == "c" and c == m:
                    X[:, col] = -s  # B e^{-s tau} ~ B - s (B tau)
            scale = np.sqrt(coherence_weight(g2[ok])) / np.maximum(np.abs(s * Hk[i]), 1e-12)
            rows_X.append(X * scale[:, None])
            rows_y.append(lhs * scale)
        if not rows_X:
            continue
        X = np.vstack(rows_X)
        y = np.concatenate(rows_y)
        Xr = np.vstack([X.real, X.imag])
        yr = np.concatenate([y.real, y.imag])
        used = np.any(Xr != 0, axis=0)
        if not np.any(used):
            continue
        sol = np.zeros(len(regs))
        sol[used] = np.linalg.lstsq(Xr[:, used], yr, rcond=None)[0]
        for col, (kind, k, c, w) in enumerate(regs):
            if not used[col]:
                continue
            if kind == "c":
                c_est[(i, c)] = sol[col]
                continue
            par = st.parameters[k]
            theta[free_pos[k]] = float(np.clip(sol[col] / w, par.lower, par.upper))
            if kind == "B":
                b_est[(i, c)] = sol[col]
    # Delays from c = B tau, least squares over the delay's entries.
    for k, rows, col in st._delay_entries:
        if not st.free_mask[k]:
            continue
        num = den = 0.0
        for r in rows:
            key = (int(r), int(col))
            if key in c_est:
                b = b_est.get(key, Bfix[key])
                num += c_est[key] * b
                den += b * b
        if den > 0:
            par = st.parameters[k]
            theta[free_pos[k]] = float(np.clip(num / den, par.lower, par.upper))
    return theta


def residual_scaled_bounds(structure: LinearStructure, data: FitData, theta,
                           information_inverse) -> ColouredBounds | None:
    """Bounds of the free parameters scaled by the fit's own residuals (module docstring).

    Each pair's points (frequency order) are one record with two outputs, the weighted
    magnitude and phase residuals ``r`` of :func:`response_residuals`, and the rows of the
    residual Jacobian ``G`` its sensitivities; ``information_inverse`` is ``(G^T G)^-1`` (the
    CIFER covariance). Then ``Cov = H^-1 [sum_pairs sum_i sum_j g_i^T K(i - j) g_j] H^-1`` with
    ``K`` the pooled residual correlation over neighbouring points under a Bartlett window
    (:func:`sysid.identify.statistics.coloured_residual_covariance`): independent residuals
    of variance ``s^2`` give ``s^2 H^-1``, the least-squares covariance. None without free
    parameters.

    References
    ----------
    E. A. Morelli and V. Klein, J. Guidance, Control, and Dynamics 20(1), 1997 (the sandwich
    form, here over frequency points instead of time samples).
    """
    theta = np.asarray(theta, float)
    if theta.size == 0:
        return None
    problem = _Problem(structure, data)
    r = problem.residuals(theta)
    G = problem.jacobian(theta)
    n = len(data.omega)
    sensitivities, residuals = [], []
    for pair in range(len(data.pairs)):
        idx = np.flatnonzero(data.pair_index == pair)
        sensitivities.append(np.stack([G[idx], G[n + idx]], axis=1))    # (points, 2, n_par)
        residuals.append(np.stack([r[idx], r[n + idx]], axis=1))        # (points, 2)
    return coloured_residual_covariance(sensitivities=sensitivities, residuals=residuals,
                                        information_inverse=information_inverse)


def random_error_bounds(structure: LinearStructure, data: FitData, theta,
                        information_inverse) -> np.ndarray:
    """Bounds of the free parameters from the spectral random error of the fitted points
    (shape (n_parameter,); NaN where the random error is unknown or a parameter
    unidentifiable).

    ``Cov = H^-1 G^T Sigma G H^-1`` with ``Sigma`` diagonal: each weighted residual's
    variance ``weight W_g (20 / ln 10 eps)^2`` (magnitude, dB) or ``weight W_p (180 / pi
    eps)^2`` (phase, deg), ``eps`` the normalised random error of the response at the point
    (docs/methods.md, Eq. 9; composite: the windows' weighted mean). Unlike
    :func:`residual_scaled_bounds` it sees the noise only, not the structure's misfit.
    """
    theta = np.asarray(theta, float)
    Minv = np.asarray(information_inverse, dtype=float)
    out = np.full(theta.size, np.nan)
    ok = np.isfinite(np.diag(Minv)) if theta.size else np.zeros(0, bool)
    if not np.any(ok) or not np.all(np.isfinite(data.random_error)):
        return out
    G = _Problem(structure, data).jacobian(theta)[:, ok]
    var = np.concatenate([data.weight * W_G * (_DB * data.random_error) ** 2,
                          data.weight * W_P * (_DEG * data.random_error) ** 2])
    Hi = Minv[np.ix_(ok, ok)]
    out[ok] = np.sqrt(np.abs(np.diag(Hi @ (G.T * var) @ G @ Hi)))
    return out


def coherence_random_error(fr: xr.Dataset) -> xr.DataArray:
    """Standard deviation of the composite coherence estimate (output, input, frequency).

    ``sigma(g2) = 2 g2 sqrt(1 - g2) eps_r``: Bendat & Piersol's ``sqrt(2) (1 - g2) / (|g|
    sqrt(n_d))`` relative error of ``g2`` with the number of averages ``n_d`` the one the
    response's random error ``eps_r`` implies through Eq. 9 (so the taper and overlap constant
    and the composite's weighting carry over). Zero where ``eps_r`` is not finite.
    """
    cvar = "partial_coherence" if "partial_coherence" in fr else "coherence"
    g2 = fr[cvar].clip(0.0, 1.0)
    eps = fr["random_error"].where(np.isfinite(fr["random_error"]), 0.0)
    return (2.0 * g2 * np.sqrt(1.0 - g2) * eps).rename("coherence_random_error")


def coherence_correlation_width(fr: xr.Dataset) -> np.ndarray:
    """Frequency span (rad/s) over which the composite coherence's errors are correlated, per
    frequency of ``fr`` (shape (frequency,)): the resolution ``2 pi / T`` of the shortest
    window trusted there (:func:`sysid.spectral.composite.trusted`), the one
    with the most averages, which the Eq. 14 weights favour; the grid spacing when the
    Dataset does not record its windows (attribute ``windows``, s)."""
    omega = np.asarray(fr["frequency"].values, float)
    windows = np.atleast_1d(np.asarray(fr.attrs.get("windows", []), dtype=float))
    windows = np.sort(windows[np.isfinite(windows) & (windows > 0)])
    if not windows.size:
        return np.gradient(omega) if omega.size > 1 else np.ones_like(omega)
    trusted = composite_trusted(xr.DataArray(omega, dims="frequency"),
                                xr.DataArray(windows, dims="window")).transpose(
        "frequency", "window").values
    shortest = np.where(trusted.any(axis=1), windows[np.argmax(trusted, axis=1)], windows[-1])
    return 2.0 * math.pi / shortest


def _smooth_normal(omega: np.ndarray, width: np.ndarray, shape: tuple, rng) -> np.ndarray:
    """Unit-variance Gaussian field over ``omega`` (rad/s, last axis, increasing) whose values
    are correlated over about ``width`` rad/s (per frequency): independent draws at unit
    spacing of the warped axis ``s = int d omega / width``, smoothed by a unit Gaussian
    kernel."""
    s = np.concatenate([[0.0], np.cumsum(np.diff(omega) / (0.5 * (width[1:] + width[:-1])))])
    knots = np.arange(-2.0, s[-1] + 2.0 + 1e-9, 1.0)
    kernel = np.exp(-0.5 * (s[:, None] - knots[None, :]) ** 2)
    kernel /= np.sqrt((kernel ** 2).sum(axis=1, keepdims=True))
    return rng.standard_normal((*shape, knots.size)) @ kernel.T


def perturbed_coherence(fr: xr.Dataset, *, seed: int) -> xr.Dataset:
    """``fr`` with its fitted coherence replaced by one draw consistent with the coherence's
    own random error (:func:`coherence_random_error`), correlated over
    :func:`coherence_correlation_width`. ``H`` and its random error are unchanged."""
    cvar = "partial_coherence" if "partial_coherence" in fr else "coherence"
    ordered = fr.sortby("frequency")
    da = ordered[cvar].transpose("output", "input", "frequency")
    omega = np.asarray(da["frequency"].values, float)
    z = _smooth_normal(omega, coherence_correlation_width(ordered), da.shape[:2],
                       np.random.default_rng(seed))
    sigma = coherence_random_error(ordered).transpose(*da.dims).values
    out = ordered.copy()
    out[cvar] = da.copy(data=np.clip(da.values + sigma * z, 0.0, 1.0))
    return out


class SelectionScatter(NamedTuple):
    """What :func:`selection_bounds` returns: ``bound`` (n_parameter,), the robust standard
    deviation over the draws; ``fitted``, the number of draws counted; ``outlying``
    (n_parameter,), the fraction of them more than
    :data:`sysid.identify.statistics.OUTLYING_SCALES` bounds from the median."""

    bound: np.ndarray
    fitted: int
    outlying: np.ndarray


def selection_bounds(fr: xr.Dataset, structure: LinearStructure, theta, *, draws: int,
                     seed: int, selection: Mapping, fit: Mapping) -> SelectionScatter:
    """Scatter of the estimate caused by the choice of the fitted points (shape
    (n_parameter,), one standard deviation), the number of draws that fitted and the
    fraction of them outlying.

    The fitted ranges follow a threshold on the measured coherence, which is itself an
    estimate; under a structure's misfit the estimate depends on the points, so another
    realisation of the coherence moves it. Each of ``draws`` draws re-selects the points
    (``selection``: the keywords of :func:`select_fit_data`) on
    :func:`perturbed_coherence` and refits ``structure`` from ``theta`` (``fit``: the
    keywords of the fit); the robust standard deviation over the draws
    (:func:`sysid.identify.statistics.robust_scale`) is the bound. Robust because a draw
    starts from coherence that already carries its own error, so it carries it twice: the
    coherent run splits more often than between real data sets, and such refits jump
    (docs/notes/2026-11-26-robust-selection-bound.md); the fraction of outlying draws is
    reported beside the bound. A draw whose fit runs away (:func:`runaway_parameters`; the
    fit would anchor it, i.e. change the structure) or fails (including past the fit's time
    limit) is not counted. Added in quadrature to the random-error bound it is the bound the
    scoreboard judges on (docs/methods.md, "Accuracy").

    References
    ----------
    J. S. Bendat and A. G. Piersol, *Random Data*, 4th ed., Wiley, 2010 (random error of the
    coherence). B. Efron and R. J. Tibshirani, *An Introduction to the Bootstrap*, Chapman &
    Hall, 1993 (parametric bootstrap).
    """
    theta = np.asarray(theta, float)
    estimates = []
    for k in range(int(draws)):
        try:
            data = select_fit_data(perturbed_coherence(fr, seed=seed + k), **selection)
            c = _converge(structure, data, theta, **fit)
        except IdentificationError:
            continue
        if not runaway_parameters(structure.free_names, c.theta, theta, c.statistics):
            estimates.append(c.theta)
    if len(estimates) < 2:
        missing = np.full(theta.size, np.nan)
        return SelectionScatter(missing, len(estimates), missing)
    bound, outlying = robust_scale(np.asarray(estimates), axis=0)
    return SelectionScatter(bound, len(estimates), outlying)


# --------------------------------------------------------------------------------------------
# The fit
# --------------------------------------------------------------------------------------------


@dataclass
class _Converged:
    structure: LinearStructure
    theta: np.ndarray
    pair_cost: np.ndarray
    J: float
    J_ave: float
    statistics: ParameterStatistics
    nfev: int
    status: int
    message: str


def _solve(problem: _Problem, theta0, *, method: str, tol: float, max_nfev: int | None,
           deadline: Deadline | None = None, ceiling: float | None = None
           ) -> scipy.optimize.OptimizeResult:
    lo, hi = problem.structure.bounds
    theta0 = np.clip(np.asarray(theta0, float), lo, hi)
    bounded = np.any(np.isfinite(lo)) or np.any(np.isfinite(hi))
    if method == "lm":
        residuals = problem.residuals if deadline is None else deadline.wrap(problem.residuals)
        if bounded:
            raise IdentificationError("method 'lm' (MINPACK) cannot honour parameter bounds "
                                      "(e.g. delays in 0..0.3 s); use method='trf'")
        return scipy.optimize.least_squares(residuals, theta0, jac=problem.jacobian,
                                            method="lm", x_scale="jac", ftol=tol, xtol=tol,
                                            gtol=tol, max_nfev=max_nfev)
    # keep strictly inside the bounds (trf requirement)
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    theta0 = np.clip(theta0, lo + 1e-9 * span, hi - 1e-9 * span)
    residuals = problem.compressed_residuals
    if deadline is not None:
        residuals = deadline.wrap(residuals)
    scale = 1.0 / len(problem.data.pairs)

    def j_ave(th):
        f = problem._compressed(np.asarray(th, float))[0]
        return scale * float(f @ f)

    jacobian = watched = stall_watch(problem.compressed_jacobian, j_ave,
                                     decrease=STALL_DECREASE)
    if ceiling is not None:  # a reduction trial: stop once J_ave cannot come under ceiling
        budget = max_nfev if max_nfev is not None else 100 * len(theta0)  # scipy's trf cap
        jacobian = ceiling_watch(lambda th: (problem._compressed(np.asarray(th, float))[0],
                                             watched(th)), ceiling, scale=scale, budget=budget)
    return scipy.optimize.least_squares(residuals, theta0, jac=jacobian,
                                        bounds=(lo, hi), method=method, x_scale="jac",
                                        ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)


def _converge(structure: LinearStructure, data: FitData, theta0, *, method: str, tol: float,
              max_nfev: int | None, counter: dict, deadline: Deadline | None = None,
              ceiling: float | None = None) -> _Converged:
    prob = _Problem(structure, data)
    if len(structure.free_index) == 0:
        theta = np.zeros(0)
        res_nfev, status, msg = 0, 0, "no free parameters"
    else:
        try:
            res = _solve(prob, theta0, method=method, tol=tol, max_nfev=max_nfev,
                         deadline=deadline, ceiling=ceiling)
            theta, res_nfev, status, msg = res.x, res.nfev, res.status, res.message
        except StoppedAboveCeiling as stop:
            theta, res_nfev, msg = stop.theta, prob.n_cost, str(stop)
            status = STOPPED_ABOVE_CEILING
        except Stalled as stop:
            theta, res_nfev, status = stop.theta, prob.n_cost, STALLED
            msg = (f"stalled: {STALL_WINDOW} accepted steps lowered J_ave by less than "
                   f"{STALL_DECREASE:g}")
    costs = prob.pair_costs(theta)
    stats = parameter_statistics(prob.jacobian(theta) if len(theta) else np.zeros((1, 0)),
                                 theta, structure.free_names)
    counter["cost"] += prob.n_cost
    counter["jacobian"] += prob.n_jac
    return _Converged(structure, theta, costs, float(costs.sum()), float(costs.mean()), stats,
                      int(res_nfev), int(status), str(msg))


def runaway_parameters(names: Sequence[str], theta, start, statistics: ParameterStatistics
                       ) -> list[str]:
    """Free parameters that ran away from their start values (see :data:`RUNAWAY_FACTOR`
    and :data:`RUNAWAY_FAR_FACTOR`)."""
    theta, start = np.asarray(theta, float), np.asarray(start, float)
    scale = np.maximum(np.abs(start), 1.0)
    large = np.abs(theta) > RUNAWAY_FACTOR * scale
    far = np.abs(theta) > RUNAWAY_FAR_FACTOR * scale
    with np.errstate(invalid="ignore"):
        undetermined = (~statistics.identifiable
                        | ~(statistics.cramer_rao_percent <= RUNAWAY_CR_PERCENT))
    return [n for n, a, b, c in zip(names, large, undetermined, far) if (a and b) or c]


def _anchor_runaways(structure: LinearStructure, data: FitData, theta0, full: _Converged,
                     kw: dict, progress: Progress, max_anchors: int = 3):
    """Hold runaway parameters at their start values, one at a time, and refit.

    Returns ``(structure, theta0, full, anchored)``: the structure with the anchored
    parameters fixed, the start vector of its free parameters, the refitted result and
    ``{name: value}`` of the anchors (in the order they were fixed).
    """
    anchored: dict[str, float] = {}
    for _ in range(max_anchors):
        # A parameter without any influence on the fitted pairs drifts too; removing it is
        # the model reduction's job (it fixes it at zero), so only influential ones count.
        columns = np.linalg.norm(_Problem(structure, data).jacobian(theta0), axis=0)
        influential = set(np.asarray(structure.free_names)[columns > 1e-12 * columns.max()])
        runaway = [n for n in runaway_parameters(structure.free_names, full.theta, theta0,
                                                 full.statistics) if n in influential]
        anchor = next((n for n in DAMPING_DERIVATIVES if n in runaway), None)
        if anchor is None:
            break
        start = dict(zip(structure.free_names, np.asarray(theta0, float)))
        anchored[anchor] = float(start[anchor])
        progress.message(f"[sysid] identify: {', '.join(runaway)} ran away together "
                         f"(Cramer-Rao bound over {RUNAWAY_CR_PERCENT:g} %, values over "
                         f"{RUNAWAY_FACTOR:g}x their start values): "
                         f"{anchor} held at its start value {start[anchor]:.5g} and refitted")
        structure = structure.fix([anchor], start[anchor])
        theta0 = np.array([start[n] for n in structure.free_names])
        full = _converge(structure, data, theta0, **kw)
    return structure, theta0, full, anchored


@dataclass
class FrequencyFitResult(FitResultParameters):
    """Outcome of :func:`identify_frequency_domain`.

    Attributes
    ----------
    model : xr.Dataset
        Model Dataset (docs/data_model.md), ``method = "frequency_domain"``.
    structure : LinearStructure
        The final (reduced) structure; ``theta`` its free values.
    statistics : ParameterStatistics
        Accuracy of the free parameters of the final model.
    pair_cost : dict
        ``"q/lon" -> J_l``; ``J`` and ``J_ave`` totals.
    data : FitData
        Fitted points; ``data.skipped`` the pairs left out and why.
    reduction : ReductionResult or None
    start : str
        ``"model"``, ``"equation_error"`` or ``"structure"``.
    restart : dict
        ``J_ave`` of the first convergence and of the restart from the perturbed solution;
        ``abandoned`` where the restart stopped once it could not come under the first.
    n_cost_evaluations, n_jacobian_evaluations : int
    elapsed : float
        Wall time, s.
    scaled : ColouredBounds or None
        Bounds of the free parameters scaled by the residuals (:func:`residual_scaled_bounds`),
        also in ``model`` as ``cramer_rao_corrected`` and ``cramer_rao_percent_corrected``.
    """

    model: xr.Dataset
    structure: LinearStructure
    theta: np.ndarray
    statistics: ParameterStatistics
    pair_cost: dict
    J: float
    J_ave: float
    data: FitData
    reduction: ReductionResult | None
    start: str
    restart: dict
    n_cost_evaluations: int
    n_jacobian_evaluations: int
    elapsed: float
    full_statistics: ParameterStatistics | None = None
    initial_structure: LinearStructure | None = None
    scaled: ColouredBounds | None = None

    @property
    def skipped_pairs(self) -> dict:
        return dict(self.data.skipped)

    def table(self) -> str:
        """Derivative table like the paper's Tables 2-3, delays, cost per pair and J_ave."""
        m = self.model
        lines = [f"Frequency-domain identification ({self.structure.name}), start: {self.start}",
                 *parameter_rows(m)]
        lines.append("cost per pair: " + ", ".join(
            f"{k} {v:.2f}" for k, v in self.pair_cost.items() if k not in ("J", "J_ave")))
        lines.append(f"J_ave = {self.J_ave:.3f} over {len(self.data.pairs)} pairs")
        anchored = json.loads(m.attrs.get("anchored_parameters", "{}"))
        if anchored:
            lines.append("held at their start values (their row ran away): " + ", ".join(
                f"{k} = {v:.5g}" for k, v in anchored.items()))
        if self.data.skipped:
            lines.append("skipped pairs: " + "; ".join(f"{k} ({v})"
                                                       for k, v in self.data.skipped.items()))
        if self.reduction is not None and self.reduction.steps:
            lines.append("model reduction:")
            lines.append(self.reduction.table())
        return "\n".join(lines)


@fit_settings
def identify_frequency_domain(fr: xr.Dataset, structure: LinearStructure, *, pairs=None,
                              start: xr.Dataset | np.ndarray | None = None,
                              coherence_min: float | None = None, n_points: int = N_POINTS,
                              ranges: Mapping[str, tuple[float, float]] | None = None,
                              frequency_range: tuple[float, float] | None = None,
                              fallback_coherence_min: float | None = None,
                              reduce: bool = True, cr_max: float = GUIDELINES["cr_max"],
                              insensitivity_max: float = GUIDELINES["insensitivity_max"],
                              max_cost_increase: float = GUIDELINES["max_cost_increase"],
                              protected: Sequence[str] = (), method: str = "trf",
                              tol: float = 1e-10, max_nfev: int | None = None,
                              time_limit: float | None = FIT_TIME_LIMIT_S,
                              restart_fraction: float = 0.2, seed: int = 0,
                              anchor_runaways: bool = True,
                              selection_draws: int = SELECTION_DRAWS,
                              quiet: bool = True, progress: Progress | None = None
                              ) -> FrequencyFitResult:
    """Identify a structure from composite frequency responses (CIFER-style output error).

    Parameters
    ----------
    fr : xr.Dataset
        Composite frequency responses: dims ``output, input, frequency``; ``H`` complex,
        ``partial_coherence`` (preferred) or ``coherence``, ``random_error``.
    structure : LinearStructure
        Model structure; its free parameters are estimated.
    pairs : str or sequence, optional
        Fitted pairs, e.g. ``"q/lon,p/lat"``; default the structure's (``pairs`` in its
        TOML file), else :data:`DEFAULT_PAIRS` (the paper's 13).
    start : xr.Dataset or array, optional
        Start values: a model Dataset (e.g. the truth model's quasi-steady linearisation) or
        the free-parameter vector. Default: frequency-domain equation error when every state
        is measured, else the structure's values.
    coherence_min, n_points, ranges, frequency_range, fallback_coherence_min
        Point selection, see :func:`select_fit_data` (defaults: the structure's
        ``coherence_min``, else 0.6, and 20, no fallback). Without
        ``frequency_range`` the structure's own validity band (``frequency_range`` in its TOML
        file, e.g. below the rotor modes for a quasi-steady model) limits every pair.
    reduce : bool
        Run the stepwise model reduction (:mod:`sysid.identify.reduction`) with
        ``cr_max`` (20 %), ``insensitivity_max`` (10 %), ``max_cost_increase`` (2 J_ave)
        and never removing ``protected`` or the structure's ``keep`` parameters.
    method : {"trf", "lm", "dogbox"}
        :func:`scipy.optimize.least_squares` method (default "trf", honours delay bounds).
    tol : float
        ``ftol = xtol = gtol`` of the optimiser.
    max_nfev, time_limit
        Cost evaluations per solve (default scipy's, 100 per parameter) and the wall-clock
        bound (s) of the whole identification (default
        :data:`sysid.core.guidelines.FIT_TIME_LIMIT_S`, None: unbounded); past it,
        :class:`~sysid.core.errors.IdentificationError`.
    restart_fraction, seed : float, int
        The final fit is restarted from its solution perturbed by ``+-restart_fraction``
        (relative, seeded) to confirm the minimum.
    anchor_runaways : bool
        After the first fit, hold a damping derivative that ran away along an
        unidentifiable valley (:func:`runaway_parameters`) at its start value and refit
        (repeated for up to three); recorded in the model's ``anchored_parameters``
        attribute (JSON ``{name: value}``). Default True.
    selection_draws : int
        Draws of the point-selection bootstrap (:func:`selection_bounds`, seeded from
        ``seed``) behind ``cramer_rao_selection`` and ``cramer_rao_total``; 0 leaves them
        NaN (default :data:`SELECTION_DRAWS`).
    quiet, progress
        Per-stage lines on stderr unless quiet.

    Returns
    -------
    FrequencyFitResult

    Examples
    --------
    >>> from sysid.data.netcdf import read_campaign
    >>> from sysid.data.campaign import maneuvers, trim_from_attrs
    >>> from sysid.models import load_structure
    >>> tree = read_campaign("campaign.nc")
    >>> fr = tree["frequency_response"].to_dataset()
    >>> structure = load_structure("hover_6dof", trim=trim_from_attrs(maneuvers(tree, "sweep_*")))
    >>> result = identify_frequency_domain(fr, structure,
    ...                                    start=tree["linearization"].to_dataset())
    >>> print(result.table())                      # derivatives, CR %, cost per pair, J_ave
    """
    t_start = time.perf_counter()
    progress = progress or Progress(quiet=quiet)
    if frequency_range is None and "fit_omega_max" in structure.attrs:
        frequency_range = (structure.attrs["fit_omega_min"], structure.attrs["fit_omega_max"])
    if pairs is None:
        pairs = structure.attrs.get("fit_pairs")  # the structure's own, else the paper's
    if coherence_min is None:
        coherence_min = float(structure.attrs.get("fit_coherence_min", COHERENCE_MIN))
    selection = dict(pairs=pairs, coherence_min=coherence_min, n_points=n_points,
                     ranges=ranges, frequency_range=frequency_range,
                     fallback_coherence_min=fallback_coherence_min)
    data = select_fit_data(fr, **selection)
    for name, reason in data.skipped.items():
        progress.message(f"[sysid] identify: pair {name} skipped: {reason}")
    for name, threshold in data.weak.items():
        progress.message(f"[sysid] identify: pair {name} admitted at coherence >= {threshold}"
                         f" (no range at {coherence_min})")
    if len(structure.free_index) == 0:
        raise IdentificationError(f"structure {structure.name!r} has no free parameters")
    counter = {"cost": 0, "jacobian": 0}
    if start is None:
        theta0 = equation_error_start(fr, structure, data, coherence_min=coherence_min)
        start_kind = "equation_error"
        if np.array_equal(theta0, structure.theta0):
            start_kind = "structure"
    elif isinstance(start, xr.Dataset):
        theta0, start_kind = structure.values_from_model(start), "model"
    else:
        theta0, start_kind = np.asarray(start, float), "values"
        if theta0.shape != structure.theta0.shape:
            raise InputDataError(f"start has {theta0.size} values; structure "
                                 f"{structure.name!r} has {structure.theta0.size} free "
                                 f"parameters {list(structure.free_names)}")
    kw = dict(method=method, tol=tol, max_nfev=max_nfev, counter=counter,
              deadline=Deadline(time_limit, "frequency-domain fit"))
    with progress.stage(f"frequency-domain fit of {len(structure.free_index)} parameters on "
                        f"{len(data.pairs)} pairs"):
        full = _converge(structure, data, theta0, **kw)
        anchored: dict[str, float] = {}
        if anchor_runaways:
            structure, theta0, full, anchored = _anchor_runaways(structure, data, theta0,
                                                                 full, kw, progress)
        progress.message(f"[sysid]   converged: J_ave = {full.J_ave:.3f} ({full.nfev} cost "
                         f"evaluations)")
    reduction = None
    final = full
    if reduce:
        def refit(removed, previous, ceiling):
            prev: _Converged = previous.payload
            st = structure.fix(removed, 0.0)
            if CONDITIONAL_START:
                th0 = conditional_start(prev.statistics, removed[-1], st.free_names)
            else:
                start_vals = dict(zip(prev.structure.free_names, prev.theta))
                th0 = np.array([start_vals[n] for n in st.free_names])
            c = _converge(st, data, th0, ceiling=ceiling, **kw)
            return FitOutcome(c.J_ave, c.statistics, c,
                              converged=c.status != STOPPED_ABOVE_CEILING)

        with progress.stage("model reduction"):
            reduction = stepwise_reduction(
                refit, FitOutcome(full.J_ave, full.statistics, full), cr_max=cr_max,
                insensitivity_max=insensitivity_max, max_cost_increase=max_cost_increase,
                protected=(*protected, *structure.kept_names), progress=progress)
        final = reduction.final.payload
    # Restart from the perturbed solution to confirm the minimum; abandoned once it can no
    # longer come under the first one (it could only confirm it then, not improve on it).
    theta_r = perturbed_start(final.theta, final.structure, seed, restart_fraction)
    again = _converge(final.structure, data, theta_r, ceiling=final.J_ave, **kw)
    restart = {"J_ave_first": final.J_ave, "J_ave_restart": again.J_ave,
               "fraction": restart_fraction, "seed": seed,
               "abandoned": again.status == STOPPED_ABOVE_CEILING}
    if again.J < final.J:
        final = again
    restart["same_minimum"] = bool(abs(restart["J_ave_first"] - restart["J_ave_restart"])
                                   <= 1e-3 * max(final.J_ave, 1e-6) + 1e-8)
    progress.message(f"[sysid]   restart: J_ave {restart['J_ave_first']:.4f} -> "
                     f"{restart['J_ave_restart']:.4f}"
                     + (" (abandoned above the first minimum)" if restart["abandoned"] else ""))
    pair_cost = {_pair_name(p): float(c) for p, c in zip(data.pairs, final.pair_cost)}
    pair_cost["J"] = final.J
    pair_cost["J_ave"] = final.J_ave
    scaled = residual_scaled_bounds(final.structure, data, final.theta,
                                    final.statistics.covariance)
    noise = random_error_bounds(final.structure, data, final.theta,
                                final.statistics.covariance)
    chosen = None
    if selection_draws > 0 and final.theta.size:
        with progress.stage(f"point-selection bootstrap ({selection_draws} refits)"):
            chosen = selection_bounds(fr, final.structure, final.theta, draws=selection_draws,
                                      seed=seed + 1, selection=selection, fit=kw)
    elapsed = time.perf_counter() - t_start
    model = _model_dataset(final, data, reduction, start_kind, restart, counter, fr, elapsed,
                           method, scaled, noise, chosen)
    model.attrs["anchored_parameters"] = json.dumps(anchored)
    return FrequencyFitResult(model, final.structure, final.theta, final.statistics, pair_cost,
                              final.J, final.J_ave, data, reduction, start_kind, restart,
                              counter["cost"], counter["jacobian"], elapsed,
                              full_statistics=full.statistics, initial_structure=structure,
                              scaled=scaled)


def _model_dataset(final: _Converged, data: FitData, reduction, start_kind, restart, counter,
                   fr, elapsed, method, scaled: ColouredBounds | None = None,
                   noise: np.ndarray | None = None,
                   chosen: SelectionScatter | None = None) -> xr.Dataset:
    st = final.structure
    attrs = {
        "method": "frequency_domain",
        "cost": final.J,
        "J_ave": final.J_ave,
        "pairs": ",".join(_pair_name(p) for p in data.pairs),
        "skipped_pairs": json.dumps(data.skipped),
        "coherence_variable": data.coherence_variable,
        "coherence_min": data.coherence_min,
        "n_points_per_pair": data.n_points,
        "W_g": W_G,
        "W_p": W_P,
        "cramer_rao_convention": "CIFER: H = G^T G of the weighted residuals, CR = sqrt(diag H^-1)",
        "start": start_kind,
        "optimizer": f"scipy.optimize.least_squares({method})",
        "restart": json.dumps(restart),
        "n_cost_evaluations": int(counter["cost"]),
        "n_jacobian_evaluations": int(counter["jacobian"]),
        "elapsed_s": float(elapsed),
        "reduction": int(reduction is not None),
        "reduction_steps": json.dumps([s.as_dict() for s in reduction.steps]
                                      if reduction is not None else []),
        "removed_parameters": ",".join(reduction.removed) if reduction is not None else "",
    }
    for key in ("campaign", "flight_condition", "name"):
        if key in fr.attrs and isinstance(fr.attrs[key], (str, int, float)):
            attrs[f"data_{key}"] = fr.attrs[key]
    ds = st.to_dataset(final.theta, final.statistics, attrs=attrs)
    cost = np.full((len(st.outputs), len(st.inputs)), np.nan)
    wmin = np.full_like(cost, np.nan)
    wmax = np.full_like(cost, np.nan)
    for (o, i), c in zip(data.pairs, final.pair_cost):
        r, k = st.outputs.index(o), st.inputs.index(i)
        cost[r, k] = c
        wmin[r, k], wmax[r, k] = data.ranges[_pair_name((o, i))]
    ds["cost"] = (("output", "input"), cost, {"long_name": "CIFER cost per input/output pair"})
    ds["omega_min"] = (("output", "input"), wmin,
                       {"long_name": "lowest fitted frequency", "units": "rad/s"})
    ds["omega_max"] = (("output", "input"), wmax,
                       {"long_name": "highest fitted frequency", "units": "rad/s"})
    cr_c = on_parameters(ds.parameter.values, st.free_names,
                         None if scaled is None else scaled.cramer_rao)
    cr_cp = on_parameters(ds.parameter.values, st.free_names,
                          None if scaled is None else scaled.percent(final.theta))
    if scaled is not None:
        ds.attrs.update(residual_decay_lag_points=int(scaled.decay_lag),
                        residual_window_lag_points=int(scaled.window_lag))
    ds.attrs["cramer_rao_corrected_convention"] = (
        "H^-1 [sum_pairs sum_i sum_j g_i^T R_rr(i-j) g_j] H^-1 over each pair's fitted points "
        "(H = G^T G), R_rr the weighted residual correlation pooled over the pairs, Bartlett "
        "lag window: the CIFER bound scaled by the residuals")
    ds["cramer_rao_corrected"] = ("parameter", cr_c, {
        "long_name": "Cramer-Rao bound scaled by the fit residuals (one standard deviation)"})
    ds["cramer_rao_percent_corrected"] = ("parameter", cr_cp, {
        "long_name": "residual-scaled Cramer-Rao bound in percent of |value|", "units": "%"})
    cr_n = on_parameters(ds.parameter.values, st.free_names, noise)
    ds["cramer_rao_noise"] = ("parameter", cr_n, {
        "long_name": "bound from the spectral random error of the fitted points (one standard "
                     "deviation; measurement noise only)"})
    selected, fitted, outlying = (None, 0, None) if chosen is None else chosen
    cr_s = on_parameters(ds.parameter.values, st.free_names, selected)
    ds["cramer_rao_selection"] = ("parameter", cr_s, {
        "long_name": "robust scatter of the estimate over re-selections of the fitted points "
                     "from the coherence's random error (one standard deviation)"})
    ds["selection_outlying"] = ("parameter", on_parameters(ds.parameter.values, st.free_names,
                                                           outlying), {
        "long_name": f"fraction of the point re-selections whose estimate lies more than "
                     f"{OUTLYING_SCALES:g} selection bounds from their median", "units": "1"})
    ds["cramer_rao_total"] = ("parameter", np.hypot(cr_n, cr_s), {
        "long_name": "random-error and point-selection bounds in quadrature (one standard "
                     "deviation; the bound the fidelity scoreboard judges on)"})
    ds.attrs["selection_draws_fitted"] = int(fitted)
    return ds
