"""Resampling of imported records onto a uniform time grid (clock jitter, missing samples).

:func:`resample_record` takes strictly increasing sample times and the channels sampled at
them and returns one or more uniform pieces:

1. The typical step ``dt`` is the recorder's: the median step finds the gaps, a line
   fitted through the sample times against their nominal indices gives ``dt``. A step longer than
   :data:`sysid.core.guidelines.GAP_MIN_STEPS` typical steps is a *gap*; a gap of up to
   :data:`~sysid.core.guidelines.GAP_MAX_STEPS` steps (its length rounded to whole steps)
   is bridged, a longer one splits the record (pieces ``a``, ``b``, ...).
2. Each piece is interpolated by a cubic spline (``scipy.interpolate.CubicSpline``,
   not-a-knot) through the recorded samples: on the new grid directly when the new step is
   not longer than ``dt``; otherwise first onto a uniform grid at ``dt``, then low-pass
   filtered, then onto the new grid.
3. The anti-aliasing filter is a linear-phase FIR designed by the window method (Hamming
   window, ``scipy.signal.firwin``) with its -6 dB cutoff at
   :data:`ANTIALIAS_CUTOFF` of the new Nyquist frequency and a transition band of about a
   fifth of it (``N = 33 dt_new / dt`` taps: the Hamming window's transition width is
   ``3.3 / (N dt)`` [OS]), applied centred (zero phase: no added delay, so time-domain fits
   and delay estimates see none) on a record extended by odd reflection at each end. A
   Hamming FIR keeps the pass band flat to 0.02 dB and the stop band 53 dB down [OS]; the
   identification band (up to about a tenth of the sample rate) sits well inside the pass
   band, and the same filter on inputs and outputs cancels in a frequency response anyway.

References
----------
.. [OS] A. V. Oppenheim and R. W. Schafer, *Discrete-Time Signal Processing*, 3rd ed.,
   Pearson, 2010, Sec. 7.5 (FIR design by windowing; Hamming window: peak approximation
   error -53 dB, transition width 3.3 / N of the sample rate).
.. [B78] C. de Boor, *A Practical Guide to Splines*, Springer, 1978 (cubic spline
   interpolation; error O(h^4)).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from sysid.core.errors import InputDataError
from sysid.core.guidelines import GAP_MAX_STEPS, GAP_MIN_STEPS

__all__ = ["ANTIALIAS_CUTOFF", "Piece", "ordered_steps", "resample_record", "piece_suffix"]

#: -6 dB cutoff of the anti-aliasing FIR as a fraction of the new Nyquist frequency.
ANTIALIAS_CUTOFF = 0.8
#: A new rate within this fraction below the data rate counts as the same rate (no filter):
#: covers "auto"'s rounding to 4 significant digits; what lies in the top 0.1 % of the band
#: folds back into the top 0.1 %.
_SAME_RATE = 1e-3


@dataclass
class Piece:
    """One uniform piece of a resampled record: ``time`` (s, on the input's clock),
    ``values`` (time, channel) and what was done (``attrs``, netCDF-storable)."""

    time: np.ndarray
    values: np.ndarray
    attrs: dict = field(default_factory=dict)


def piece_suffix(k: int) -> str:
    """``a``, ``b``, ..., ``z``, ``aa``, ``ab``, ... for piece ``k`` (0-based)."""
    letters = ""
    k += 1
    while k:
        k, r = divmod(k - 1, 26)
        letters = chr(ord("a") + r) + letters
    return letters


def _spline(t: np.ndarray, values: np.ndarray, grid: np.ndarray) -> np.ndarray:
    from scipy.interpolate import CubicSpline  # deferred with scipy.signal below

    if t.size < 4:  # a cubic needs four samples; two or three: a straight line
        return np.column_stack([np.interp(grid, t, values[:, j])
                                for j in range(values.shape[1])])
    return CubicSpline(t, values, axis=0, bc_type="not-a-knot")(grid)


def _lowpass(values: np.ndarray, dt: float, dt_new: float) -> tuple[np.ndarray, str]:
    """Zero-phase Hamming FIR low-pass of uniform ``values`` (time, channel) at step ``dt``
    for a new step ``dt_new`` > ``dt``; returns the filtered values and a description."""
    from scipy.signal import firwin  # deferred: scipy.signal is slow to import

    ratio = dt_new / dt
    half = int(np.ceil(16.5 * ratio))
    taps = firwin(2 * half + 1, ANTIALIAS_CUTOFF * 0.5 / dt_new, window="hamming",
                  fs=1.0 / dt)
    n = values.shape[0]
    pad = min(half, n - 1)
    # Odd reflection about the end samples keeps level and slope at the ends.
    head = 2 * values[:1] - values[pad:0:-1]
    tail = 2 * values[-1:] - values[-2:-pad - 2:-1]
    extended = np.concatenate([head, values, tail])
    out = np.empty_like(values)
    for j in range(values.shape[1]):
        full = np.convolve(extended[:, j], taps, mode="same")
        out[:, j] = full[pad:pad + n]
    text = (f"zero-phase Hamming FIR, {taps.size} taps, cutoff "
            f"{ANTIALIAS_CUTOFF * 0.5 / dt_new:.4g} Hz (-6 dB), before interpolation")
    return out, text


def _clock_step(t: np.ndarray, median: float) -> float:
    """The recorder's step: the slope of a least-squares line through the sample times
    against their nominal indices (each step counted as ``round(step / median)`` nominal
    steps, so a missing sample counts two). Unbiased under jitter, where the median step of
    a jittered record is off by a fraction of the jitter."""
    index = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(np.diff(t) / median), 1))])
    if index[-1] < 2:
        return float(median)
    slope = np.polyfit(index, t, 1)[0]
    return float(slope) if np.isfinite(slope) and slope > 0 else float(median)


def _jitter(t: np.ndarray, dt: float) -> float:
    """Largest distance of a sample time from the uniform grid of step ``dt`` fitted to the
    record (least squares), as a fraction of ``dt``."""
    index = np.concatenate([[0.0], np.cumsum(np.maximum(np.round(np.diff(t) / dt), 1))])
    if t.size < 3:
        return 0.0
    offset = np.mean(t - dt * index)
    return float(np.max(np.abs(t - dt * index - offset)) / dt)


def ordered_steps(t: np.ndarray, where: str, label=None) -> np.ndarray:
    """Steps ``diff(t)`` (s) of a one-dimensional, finite, strictly increasing time vector
    of at least 2 samples; :class:`InputDataError` naming the first offending sample
    (``label(i)``, e.g. a CSV line) otherwise."""
    label = label or (lambda i: f"sample {i}")
    if t.ndim != 1:
        raise InputDataError(f"{where}: time must be one-dimensional, got shape {t.shape}")
    if t.size < 2:
        raise InputDataError(f"{where}: time has {t.size} sample(s); expected at least 2")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputDataError(f"{where}: time is not finite at {label(bad[0])} ({t[bad[0]]})")
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.diff(t)
        span = t[-1] - t[0]
    if not np.isfinite(span):
        raise InputDataError(f"{where}: time span {float(t[0])!r} .. {float(t[-1])!r} "
                             "overflows; expected times in seconds of a manoeuvre")
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = int(back[0]) + 1
        raise InputDataError(f"{where}: time is not strictly increasing at {label(i)}: "
                             f"t = {float(t[i])!r} after {float(t[i - 1])!r}")
    return steps


def resample_record(t, values, *, rate, where: str = "record",
                    label=None) -> list[Piece]:
    """Put a record on a uniform grid: cubic-spline interpolation, a zero-phase anti-aliasing
    FIR when the new rate is below the data rate, gaps bridged or split (module docstring).

    Parameters
    ----------
    t : (n,) array
        Sample times, s, finite and strictly increasing (checked).
    values : (n, k) array
        Channels at those times (finite).
    rate : float or "auto"
        New sample rate, Hz; ``"auto"``: the recorder's rate, ``1 / dt`` to 4 significant
        digits (so records of one logger share it), with ``dt`` the slope of a
        least-squares line through the sample times against their nominal indices (the
        median step finds the gaps; under jitter it is itself off by a fraction of the
        jitter, the fitted slope is not).
    where, label
        How errors name the record and sample ``i`` (``label(i)``).

    Returns
    -------
    list of Piece
        One per stretch between gaps longer than ``GAP_MAX_STEPS`` typical steps, in time
        order; each ``time`` starts at the stretch's first sample and steps by
        ``1 / rate``. ``attrs``: ``resample_rate_hz``, ``resample_source_step_s`` (the
        recorder's step ``dt``), ``resample_max_jitter`` (largest distance of a sample
        time from the fitted uniform grid, as a fraction of ``dt``), ``resample_gaps_filled`` and ``resample_gaps_split`` (``[[start, length],
        ...]``, s from the record's first sample), ``resample_filter``, ``resample_pieces``
        and, when split, ``resample_piece`` (``a``, ``b``, ...) and ``resample_piece_start_s``.

    Examples
    --------
    >>> t = np.arange(200) * 0.01 + np.random.default_rng(0).uniform(-2e-3, 2e-3, 200)
    >>> [p.time.size for p in resample_record(np.sort(t), np.sin(t)[:, None], rate="auto")]
    [199]
    """
    label = label or (lambda i: f"sample {i}")
    t = np.asarray(t, dtype=float)
    values = np.asarray(values, dtype=float)
    if values.ndim == 1:
        values = values[:, None]
    if t.ndim == 1 and values.shape[0] != t.size:
        raise InputDataError(f"{where}: time {t.shape} and values {values.shape} disagree")
    steps = ordered_steps(t, where, label)
    dt = _clock_step(t, float(np.median(steps)))
    if isinstance(rate, str):
        if rate != "auto":
            raise InputDataError(f"resample {rate!r}: expected a rate in Hz or 'auto'")
        # To 4 significant digits: records of one logger get one rate (the spectra need it)
        # and a 100 Hz logger gives 100 Hz, not 99.99989 Hz; the time scale moves by at most
        # 5e-4 relative, far below what identification resolves.
        dt_new = 1.0 / float(f"{1.0 / dt:.4g}")
    else:
        rate = float(rate)
        if not np.isfinite(rate) or rate <= 0:
            raise InputDataError(f"resample rate {rate!r} Hz: expected a positive number")
        dt_new = 1.0 / rate
    gap = steps > GAP_MIN_STEPS * dt
    # A gap's length in whole nominal steps: 4 steps recorded as 0.04000000000000001 s (or
    # 4.3 steps under jitter) is a gap of 4.
    split = gap & (np.round(steps / dt) > GAP_MAX_STEPS)
    jitter = _jitter(t, dt)
    t0 = t[0]
    filled = [[float(t[i] - t0), float(steps[i])] for i in np.flatnonzero(gap & ~split)]
    splits = [[float(t[i] - t0), float(steps[i])] for i in np.flatnonzero(split)]
    bounds = np.concatenate([[0], np.flatnonzero(split) + 1, [t.size]])
    common = {
        "resample_rate_hz": 1.0 / dt_new,
        "resample_source_step_s": dt,
        "resample_max_jitter": jitter,
        "resample_gaps_filled": filled,
        "resample_gaps_split": splits,
        "resample_pieces": len(bounds) - 1,
    }
    pieces = []
    for k, (a, b) in enumerate(zip(bounds[:-1], bounds[1:])):
        tp, vp = t[a:b], values[a:b]
        n_new = int(np.floor((tp[-1] - tp[0]) / dt_new * (1 + 1e-12))) + 1
        if tp.size < 2 or n_new < 2:
            raise InputDataError(
                f"{where}: the stretch from {label(int(a))} to {label(int(b) - 1)} between "
                f"gaps longer than {GAP_MAX_STEPS:g} steps is too short to resample "
                f"({tp.size} sample(s)); expected at least two steps of the new grid")
        grid = tp[0] + np.arange(n_new) * dt_new
        if dt_new > dt * (1 + _SAME_RATE):
            n_fine = int(np.floor((tp[-1] - tp[0]) / dt * (1 + 1e-12))) + 1
            fine_t = tp[0] + np.arange(n_fine) * dt
            fine, text = _lowpass(_spline(tp, vp, fine_t), dt, dt_new)
            out = _spline(fine_t, fine, grid)
        else:
            out = _spline(tp, vp, grid)
            text = "none (the new rate is not below the data rate)"
        attrs = {**common, "resample_filter": text}
        if len(bounds) > 2:
            attrs["resample_piece"] = piece_suffix(k)
            attrs["resample_piece_start_s"] = float(tp[0] - t0)
        pieces.append(Piece(time=grid, values=out, attrs=attrs))
    return pieces
