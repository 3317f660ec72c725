"""Windowed auto- and cross-spectra of concatenated time histories (paper Eq. 1-6).

Every record is cut into segments of ``N = round(T / dt)`` samples (window length ``T`` in s)
that overlap by ``overlap`` (default 0.8, the paper's value). Segments never span a record
boundary; the segment averages of Eq. 3-6 are pooled over all records (CIFER's concatenation
of repeated manoeuvres). Each segment is tapered by the Hann window, scaled by ``sqrt(8/3)``
so that the taper does not change the signal power (the mean square of the Hann window is
3/8), and transformed with an exact discrete Fourier sum *at the requested frequencies*
(Eq. 1-2)::

    X_k(omega) = dt * sqrt(8/3) * sum_n x[s_k + n] * w[n] * exp(-1j * omega * n * dt),
    w[n] = (1 - cos(2 pi n / N)) / 2,   n = 0 .. N-1.

The sign of the exponent is the engineering one (``exp(-j omega t)``), so that
``Y = H(j omega) X`` and ``H = Gxy / Gxx``; the paper's Eq. 1-2 print the opposite sign and
leave out the factor 1/2 of the Hann window, which the ``sqrt(8/3)`` power correction assumes.

The sums are evaluated for all windows on one common frequency grid (rad/s; log-spaced by
:func:`log_frequencies`), as a real matrix product ``segments @ [cos | sin]`` per record,
which is what a chirp-z / zoom FFT would give on a linear grid but works on any grid.
One-sided spectral densities follow Eq. 3-6 with the factor ``2 / T``::

    Gxx[i, j] = 2 / (T n_seg) * sum_k conj(X_i,k) X_j,k     (input cross-spectral matrix, Eq. 3, 6)
    Gyy[o]    = 2 / (T n_seg) * sum_k |Y_o,k|^2              (Eq. 4)
    Gxy[o, i] = 2 / (T n_seg) * sum_k conj(X_i,k) Y_o,k      (Eq. 5)

(the paper's absolute value bars in Eq. 5-6 are a typesetting slip: cross spectra are complex).
Units: ``unit_x * unit_y / Hz`` (one-sided density per Hz, from the ``2 / T`` of Eq. 3), even
though the frequency coordinate is in rad/s; only ratios of spectra (frequency responses,
coherences) are used downstream.

``n_d`` reported with each window is the number of *independent* averages ``T_r / T`` (total
record time over window length), the count used by the random-error formula Eq. 9 together with
the error constant ``C_eps``, which absorbs the benefit of overlapping (see
:func:`hann_error_constant`). ``n_segments`` is the number of overlapping segments actually
averaged; they cover every record from its first to its last sample (:func:`segment_layout`).

References
----------
* *Comparison of frequency and time domain identification of a helicopter in hover*
  (Eq. 1-6).
* Bendat, J. S. and Piersol, A. G., *Random Data: Analysis and Measurement Procedures*,
  Wiley.
* Welch, P. D., IEEE Trans. Audio Electroacoustics AU-15, 1967 (overlapped segments).
* docs/methods.md, "Spectra" and "Coherence and random error".
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.data.campaign import record_trim

#: Default segment overlap (the paper raises it to 80 % to lower the random error).
DEFAULT_OVERLAP = 0.8
#: A window needs at least this many independent averages ``T_r / T`` (docs/methods.md).
MIN_AVERAGES = 5
#: Shortest accepted segment, samples (below this the Hann taper is meaningless).
MIN_SEGMENT_SAMPLES = 8
#: Power correction of the Hann taper (Eq. 1-2): mean of ``w**2`` is 3/8.
HANN_POWER_CORRECTION = math.sqrt(8.0 / 3.0)
#: Relative tolerance on time steps for "uniform time" and "same sample rate".
TIME_RTOL = 1e-6


# --------------------------------------------------------------------------------------------
# records -> perturbation signals
# --------------------------------------------------------------------------------------------

def _named_records(records) -> list[tuple[str, xr.Dataset]]:
    """``[(name, dataset)]`` from a Dataset, a sequence of Datasets or a ``{name: Dataset}``."""
    if isinstance(records, xr.Dataset):
        records = [records]
    if isinstance(records, Mapping):
        items = [(str(k), v) for k, v in records.items()]
    else:
        items = []
        for k, ds in enumerate(records):
            name = ds.attrs.get("maneuver") if isinstance(ds, xr.Dataset) else None
            items.append((str(name) if name else f"record {k}", ds))
    if not items:
        raise InputDataError("no time-history records given: expected at least one xr.Dataset")
    for name, ds in items:
        if not isinstance(ds, xr.Dataset):
            raise InputDataError(f"record {name!r}: expected an xr.Dataset, "
                                 f"got {type(ds).__name__}")
    return items


def _time_step(name: str, ds: xr.Dataset) -> float:
    """The uniform sample interval of ``ds`` (s), or an InputDataError saying what is wrong."""
    if "time" not in ds.coords or ds["time"].ndim != 1:
        raise InputDataError(f"record {name!r}: expected a 1-D coordinate 'time' in seconds")
    t = np.asarray(ds["time"].values)
    if not np.issubdtype(t.dtype, np.number):
        raise InputDataError(f"record {name!r}: coordinate 'time' must be numeric seconds, "
                             f"got dtype {t.dtype}")
    t = t.astype(float)
    if t.size < 2 or not np.all(np.isfinite(t)):
        raise InputDataError(f"record {name!r}: 'time' needs at least two finite samples")
    steps = np.diff(t)
    dt = float(np.median(steps))
    if dt <= 0 or np.max(np.abs(steps - dt)) > TIME_RTOL * dt:
        k = int(np.argmax(np.abs(steps - dt)))
        raise InputDataError(
            f"record {name!r}: time is not uniformly sampled (step {steps[k]:.6g} s at "
            f"t = {t[k]:.6g} s, median step {dt:.6g} s); expected a uniform 'time' coordinate")
    return dt


def perturbations(records, channels: Sequence[str],
                  inputs: Sequence[str] = ()) -> list[xr.DataArray]:
    """Check time histories and return their perturbation signals.

    Parameters
    ----------
    records : xr.Dataset, sequence of xr.Dataset or mapping name -> xr.Dataset
        Time histories on a uniform ``time`` coordinate (s), channels as data variables in
        analysis units. Names come from the mapping keys, else the ``maneuver`` attribute,
        else ``"record <k>"``.
    channels : sequence of str
        Channels to extract (inputs and outputs).
    inputs : sequence of str
        The subset of ``channels`` that are inputs: an input that does not vary in any record
        is refused (an unexcited input cannot be identified).

    Returns
    -------
    list of xr.DataArray, one per record, dims ``(channel, time)``, float64, with attributes
    ``name`` and ``dt`` (s). Perturbations are taken about the record's ``trim_<channel>``
    attribute when the Dataset has one for that channel, else about the record's mean
    (:func:`sysid.data.campaign.record_trim` with ``missing="record_mean"``).

    Raises
    ------
    InputDataError
        Missing channel, non-numeric or non-uniform time, different sample rates, NaN or
        infinite samples, constant input channel; the message names record and channel.
    """
    items = _named_records(records)
    channels = list(channels)
    if len(set(channels)) != len(channels):
        raise InputDataError(f"channels listed twice: {channels}")
    out = []
    dt0 = None
    name0 = None
    varies = {c: False for c in inputs}
    for name, ds in items:
        dt = _time_step(name, ds)
        if dt0 is None:
            dt0, name0 = dt, name
        elif abs(dt - dt0) > TIME_RTOL * dt0:
            raise InputDataError(
                f"record {name!r} is sampled at {1 / dt:.6g} Hz but record {name0!r} at "
                f"{1 / dt0:.6g} Hz: every record must have the same sample rate (resample first)")
        missing = [c for c in channels if c not in ds.data_vars]
        if missing:
            raise InputDataError(
                f"record {name!r} has no channel(s) {missing}; expected data variables "
                f"{channels} (found {sorted(map(str, ds.data_vars))})")
        rows = []
        for c in channels:
            da = ds[c]
            if da.dims != ("time",):
                raise InputDataError(f"record {name!r}, channel {c!r}: expected dims ('time',), "
                                     f"got {da.dims}")
            if da.dtype.kind not in "biuf":
                raise InputDataError(f"record {name!r}, channel {c!r} holds {da.dtype} values "
                                     "(text?); expected numbers")
            x = np.asarray(da.values, dtype=float)
            bad = ~np.isfinite(x)
            if bad.any():
                k = int(np.argmax(bad))
                raise InputDataError(
                    f"record {name!r}, channel {c!r}: {int(bad.sum())} NaN/infinite sample(s), "
                    f"first at t = {float(ds['time'][k]):.6g} s; expected finite values")
            if c in varies and np.ptp(x) > 1e-12 * max(1.0, float(np.max(np.abs(x)))):
                varies[c] = True
            rows.append(x - record_trim(ds, c, name=name, missing="record_mean"))
        out.append(xr.DataArray(
            np.vstack(rows), dims=("channel", "time"),
            coords={"channel": channels, "time": ds["time"].values},
            attrs={"name": name, "dt": dt}))
    constant = [c for c, v in varies.items() if not v]
    if constant:
        raise InputDataError(
            f"input channel(s) {constant} constant in every record "
            f"({[n for n, _ in items]}): an unexcited input cannot be identified; "
            "expected each input to vary in at least one record (or drop it from the inputs)")
    return out


# --------------------------------------------------------------------------------------------
# grid, taper, windows
# --------------------------------------------------------------------------------------------

def log_frequencies(omega_min: float, omega_max: float, n: int = 200) -> xr.DataArray:
    """``n`` log-spaced frequencies from ``omega_min`` to ``omega_max`` (rad/s), as the
    ``frequency`` coordinate."""
    if not (0 < omega_min < omega_max) or n < 2:
        raise InputDataError(f"frequency grid: expected 0 < omega_min ({omega_min}) < omega_max "
                             f"({omega_max}) rad/s and n >= 2 ({n})")
    w = np.geomspace(omega_min, omega_max, int(n))
    return xr.DataArray(w, dims="frequency", coords={"frequency": w},
                        attrs={"units": "rad/s", "long_name": "frequency"})


def hann_taper(n: int) -> np.ndarray:
    """Periodic Hann window ``(1 - cos(2 pi k / n)) / 2``, ``k = 0 .. n-1`` (Eq. 1-2)."""
    k = np.arange(n)
    return 0.5 * (1.0 - np.cos(2.0 * np.pi * k / n))


def hann_error_constant(overlap: float = DEFAULT_OVERLAP) -> float:
    """Random-error constant ``C_eps`` of Eq. 9 for Hann segments overlapping by ``overlap``.

    With ``n_d = T_r / T`` independent-record averages, overlapping segments (step
    ``(1 - overlap) T``) give ``K = n_d / (1 - overlap)`` averages whose estimates are correlated.
    Welch (1967) gives the variance of the averaged estimate for Gaussian data as
    ``(1 + 2 sum_l c_l^2) / K`` with ``c_l`` the normalised overlap correlation of the squared
    taper at lag ``l`` steps. Hence ``C_eps = sqrt((1 - overlap) (1 + 2 sum_l c_l^2))``:
    0.73 at 50 %, 0.69 at 67-90 % overlap for Hann, the ~0.7 quoted for CIFER-style Hann
    windows with 50-80 % overlap (docs/methods.md). :data:`DEFAULT_C_EPS` rounds it to 0.7.
    """
    if not 0.0 <= overlap < 1.0:
        raise InputDataError(f"overlap must be in [0, 1), got {overlap}")
    n = 4096
    w = hann_taper(n)
    step = max(1, int(round(n * (1.0 - overlap))))
    total = 1.0
    norm = float(np.sum(w * w))
    lag = step
    while lag < n:
        total += 2.0 * (float(np.sum(w[:n - lag] * w[lag:])) / norm) ** 2
        lag += step
    return math.sqrt(step / n * total)


#: Random-error constant of Eq. 9 / 13 for Hann windows with 50-80 % overlap, with ``n_d``
#: the number of independent averages ``T_r / T`` (see :func:`hann_error_constant`).
DEFAULT_C_EPS = 0.7


def segment_layout(n_samples: int, window: float, dt: float,
                   overlap: float) -> tuple[int, np.ndarray]:
    """``(N, starts)`` for one record: samples per segment and the first sample of each.

    The nominal step is ``round(N (1 - overlap))`` samples. When the record is not a whole
    number of steps longer than a segment, the starts are spread evenly from the first to
    the last possible sample (so the actual overlap is slightly above the nominal) rather
    than dropping the record's tail: a sweep spends its last seconds at its highest
    frequencies, which a dropped tail would remove from the longest windows altogether.
    """
    n_win = int(round(window / dt))
    if n_samples < n_win:
        return n_win, np.zeros(0, dtype=int)
    step = max(1, int(round(n_win * (1.0 - overlap))))
    n_seg = -(-(n_samples - n_win) // step) + 1
    return n_win, np.round(np.linspace(0, n_samples - n_win, n_seg)).astype(int)


def check_window(signals: Sequence[xr.DataArray], window: float, overlap: float) -> float:
    """Refuse a window that does not fit the records; return ``n_d = T_r / T``.

    Raises InputDataError naming the window (s) and, when a record is shorter than the
    window, the record.
    """
    if not 0.0 <= overlap < 1.0:
        raise InputDataError(f"overlap must be in [0, 1), got {overlap}")
    dt = signals[0].attrs["dt"]
    n_win = int(round(window / dt))
    if not np.isfinite(window) or n_win < MIN_SEGMENT_SAMPLES:
        raise InputDataError(f"window {window:g} s is shorter than {MIN_SEGMENT_SAMPLES} samples "
                             f"at dt = {dt:g} s")
    total = 0
    for sig in signals:
        n = sig.sizes["time"]
        if n < n_win:
            raise InputDataError(
                f"record {sig.attrs['name']!r} lasts {n * dt:.6g} s, shorter than the "
                f"{window:g} s window: expected every record to be at least one window long "
                "(use shorter windows or drop the record)")
        total += n
    n_d = total / n_win
    if n_d < MIN_AVERAGES - 1e-9:
        raise InputDataError(
            f"window {window:g} s gives only {n_d:.2f} averages over {total * dt:.6g} s of "
            f"data; expected at least {MIN_AVERAGES} (window <= {total * dt / MIN_AVERAGES:.6g} s)")
    return n_d


# --------------------------------------------------------------------------------------------
# spectra
# --------------------------------------------------------------------------------------------

def hann_taper_rate(n: int, dt: float) -> np.ndarray:
    """Time derivative (1/s) of :func:`hann_taper` over a segment of ``n`` samples of ``dt``:
    ``(pi / T) sin(2 pi k / n)``, ``T = n dt``."""
    k = np.arange(n)
    return (np.pi / (n * dt)) * np.sin(2.0 * np.pi * k / n)


def _dft_kernel(n_win: int, dt: float, omega: np.ndarray,
                derivative: bool = False) -> np.ndarray:
    """Real kernel ``(N, 2F)``: tapered ``[cos | -sin]`` of ``omega n dt`` (Eq. 1-2 scaling);
    with ``derivative`` the taper is replaced by its time derivative (same scaling)."""
    n = np.arange(n_win)
    shape = hann_taper_rate(n_win, dt) if derivative else hann_taper(n_win)
    taper = dt * HANN_POWER_CORRECTION * shape
    phase = np.outer(n * dt, omega)
    return np.concatenate([taper[:, None] * np.cos(phase), -taper[:, None] * np.sin(phase)],
                          axis=1)


def _segment_transforms(x: np.ndarray, n_win: int, starts: np.ndarray,
                        kernel: np.ndarray) -> np.ndarray:
    """Fourier coefficients ``(channel, segment, frequency)`` of the segments of ``x``
    ``(channel, time)`` that begin at samples ``starts``."""
    segs = np.lib.stride_tricks.sliding_window_view(x, n_win, axis=-1)[:, starts, :]
    n_ch, n_seg, _ = segs.shape
    prod = segs.reshape(n_ch * n_seg, n_win) @ kernel
    n_f = kernel.shape[1] // 2
    out = prod[:, :n_f] + 1j * prod[:, n_f:]
    return out.reshape(n_ch, n_seg, n_f)


#: Prefix of the transient regressors' input names (see :func:`window_spectra`).
TRANSIENT_PREFIX = "transient_"


def window_spectra(signals: Sequence[xr.DataArray], inputs: Sequence[str],
                   outputs: Sequence[str], window: float, frequency,
                   overlap: float = DEFAULT_OVERLAP,
                   transient: Sequence[str] = ()) -> xr.Dataset:
    """Auto- and cross-spectra of one window length, pooled over records (Eq. 1-6).

    Parameters
    ----------
    signals : list of xr.DataArray ``(channel, time)``
        From :func:`perturbations`.
    inputs, outputs : sequence of str
        Channel names.
    window : float
        Segment length ``T``, s.
    frequency : array-like or xr.DataArray
        Frequencies, rad/s, each below the Nyquist frequency.
    overlap : float
        Fraction of a segment shared with the next one, default 0.8.
    transient : sequence of str
        State channels whose transforms taken with the taper's time derivative are appended
        to the inputs as ``transient_<channel>`` (default none). For a linear system
        ``x' = A x + B u`` integration by parts over a tapered segment gives exactly
        ``(j omega - A) X_w = B U_w + X_w'``: the segment's start and end conditions enter
        through ``X_w'``, the transform of ``x`` weighted by the taper's derivative. Treating
        ``X_w'`` as extra inputs in the conditioning removes that leakage term, which is
        large near lightly damped or unstable modes (an unstable bare airframe flown in
        closed loop) where ``(j omega - A)^-1`` is large.

    Returns
    -------
    xr.Dataset with ``Gxx (input, input_j, frequency)`` complex, ``Gyy (output, frequency)``
    real, ``Gxy (output, input, frequency)`` complex, scalar ``n_d`` (``T_r / T``) and
    ``n_segments``, scalar coordinate ``window`` (s).
    """
    transient = list(transient)
    regressors = list(inputs) + [TRANSIENT_PREFIX + c for c in transient]
    inputs, outputs = list(inputs), list(outputs)
    omega = np.asarray(getattr(frequency, "values", frequency), dtype=float)
    dt = signals[0].attrs["dt"]
    if omega.ndim != 1 or omega.size == 0 or np.any(omega <= 0) or np.any(omega >= np.pi / dt):
        raise InputDataError(f"frequencies must be positive and below the Nyquist frequency "
                             f"{np.pi / dt:.6g} rad/s; got {omega.min():.6g}..{omega.max():.6g}")
    n_d = check_window(signals, window, overlap)
    n_win = int(round(window / dt))
    kernel = _dft_kernel(n_win, dt, omega)
    kernel_rate = _dft_kernel(n_win, dt, omega, derivative=True) if transient else None
    n_in = len(regressors)
    sxx = np.zeros((omega.size, n_in, n_in), complex)
    sxy = np.zeros((omega.size, len(outputs), n_in), complex)
    syy = np.zeros((omega.size, len(outputs)))
    n_seg_total = 0
    for sig in signals:
        x = sig.sel(channel=inputs + outputs).values
        _, starts = segment_layout(x.shape[1], window, dt, overlap)
        with np.errstate(over="ignore", invalid="ignore"):  # overflow is reported below
            coef = _segment_transforms(x, n_win, starts, kernel).transpose(2, 0, 1)
            cx, cy = coef[:, :len(inputs)], coef[:, len(inputs):]   # (F, ch, seg)
            if transient:
                rate = _segment_transforms(sig.sel(channel=transient).values, n_win, starts,
                                           kernel_rate).transpose(2, 0, 1)
                cx = np.concatenate([cx, rate], axis=1)
            sxx += np.conj(cx) @ cx.transpose(0, 2, 1)           # sum_k conj(X_i) X_j
            sxy += cy @ np.conj(cx).transpose(0, 2, 1)           # sum_k conj(X_i) Y_o
            syy += np.sum(cy.real ** 2 + cy.imag ** 2, axis=-1)  # sum_k |Y_o|^2
        n_seg_total += starts.size
    finite = np.concatenate([np.isfinite(np.diagonal(sxx, axis1=1, axis2=2)).all(axis=0),
                             np.isfinite(syy).all(axis=0)])
    if not finite.all() or not np.isfinite(sxx).all() or not np.isfinite(sxy).all():
        channels = inputs + transient + outputs   # the channels behind sxx's and syy's rows
        bad = [c for c, ok in zip(channels, finite) if not ok] or channels
        peak = {c: float(max(np.max(np.abs(s.sel(channel=c).values)) for s in signals))
                for c in bad}
        raise InputDataError(
            f"the spectra of channel(s) {bad} overflow (largest perturbation "
            f"{', '.join(f'{c}: {v:.3g}' for c, v in peak.items())}); expected finite values "
            "of a physical size in analysis units (ft/s, deg/s, deg, %)")
    scale = 2.0 / (n_win * dt) / n_seg_total  # Eq. 3-6: (1/n) sum (2/T) ...
    coords = {"input": regressors, "input_j": regressors, "output": outputs,
              "frequency": omega, "window": float(window)}
    ds = xr.Dataset(
        {
            "Gxx": (("frequency", "input", "input_j"), sxx * scale),
            "Gxy": (("frequency", "output", "input"), sxy * scale),
            "Gyy": (("frequency", "output"), syy * scale),
            "n_d": ((), n_d),
            "n_segments": ((), n_seg_total),
        },
        coords=coords,
    )
    ds["Gxx"] = ds["Gxx"].transpose("input", "input_j", "frequency")
    ds["Gxy"] = ds["Gxy"].transpose("output", "input", "frequency")
    ds["Gyy"] = ds["Gyy"].transpose("output", "frequency")
    return _annotate(ds)


def _annotate(ds: xr.Dataset) -> xr.Dataset:
    ds["Gxx"].attrs.update(long_name="input cross-spectral matrix (Eq. 3, 6)")
    ds["Gyy"].attrs.update(long_name="output autospectrum (Eq. 4)")
    ds["Gxy"].attrs.update(long_name="input-output cross spectrum (Eq. 5)")
    ds["n_d"].attrs.update(long_name="independent averages T_r / T (Eq. 9)")
    ds["n_segments"].attrs.update(long_name="overlapping segments averaged")
    ds["frequency"].attrs.update(units="rad/s", long_name="frequency")
    ds["window"].attrs.update(units="s", long_name="window length")
    return ds


def spectra(signals: Sequence[xr.DataArray], inputs: Sequence[str], outputs: Sequence[str],
            windows: Sequence[float], frequency, overlap: float = DEFAULT_OVERLAP,
            progress=None, transient: Sequence[str] = ()) -> xr.Dataset:
    """:func:`window_spectra` for several window lengths, stacked along a ``window`` dim (s).

    ``progress`` is an optional :class:`sysid.core.util.Progress` for one line per window.
    """
    parts = []
    for T in windows:
        if progress is not None:
            progress.message(f"[sysid] spectra: window {T:g} s")
        parts.append(window_spectra(signals, inputs, outputs, float(T), frequency, overlap,
                                    transient))
    ds = xr.concat(parts, dim="window")
    return _annotate(ds)
