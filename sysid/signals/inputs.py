"""Input signals for flight tests: frequency sweeps, multisteps, orthogonal multisines and
Dryden turbulence.

Every generator is a pure function returning an :class:`xarray.Dataset` on a uniform ``time``
grid (s, starting at 0). Control signals hold one data variable per excited control axis
(``lon lat col ped``), in percent of travel *relative to trim* (the simulation adds the trim
value); their attributes record the signal kind, axis, parameters and seed (``-1`` when the
signal involves no randomness) and ``hold``: ``"linear"`` for continuous signals that may be
interpolated between samples, ``"previous"`` for multisteps, whose value holds until the next
sample (with fmpy, repeat the time stamp at every switch or step the FMU yourself).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 5 (automated sweep law, ``C1 = 4``, ``C2 = 0.0187``).
* Morelli, E. A., "Multiple input design for real-time parameter estimation in the frequency
  domain", IFAC SYSID 2003 (orthogonal phase-optimised multisines, relative peak factor).
* Schroeder, M. R., "Synthesis of low-peak-factor signals and binary sequences with low
  autocorrelation", IEEE Trans. Inf. Theory 16, 1970 (Schroeder phases).
* MIL-F-8785C (1980), sec. 3.7 and MIL-HDBK-1797 (1997), app. A: Dryden turbulence forms,
  low-altitude intensities and scale lengths.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg
import scipy.optimize
import scipy.signal
import scipy.special
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.units import CHANNELS, CONTROLS, FT, KT
from sysid.core.util import rng

__all__ = [
    "frequency_sweep",
    "multistep",
    "input_3211",
    "input_2311",
    "doublet",
    "orthogonal_multisines",
    "dryden_turbulence",
    "peak_factor",
]

#: Pulse-width multipliers of the multistep inputs (signs alternate).
MULTISTEP_WIDTHS = {"3211": (3, 2, 1, 1), "2311": (2, 3, 1, 1), "doublet": (1, 1)}

#: Wind speed at 20 ft (kt) for the MIL-F-8785C low-altitude intensities.
W20_KT = {"light": 15.0, "moderate": 30.0, "severe": 45.0}

#: Lowest convection speed (m/s) of the frozen Dryden field; see :func:`dryden_turbulence`.
MIN_GUST_AIRSPEED = 5.0


# --------------------------------------------------------------------------------------------
# helpers


def peak_factor(signal) -> float:
    """Relative peak factor ``(max - min) / (2 sqrt(2) rms)`` (Morelli).

    Equal to 1 for a pure sinusoid; ``signal`` is any array-like or DataArray (all samples).
    """
    x = np.asarray(signal, dtype=float).ravel()
    rms = math.sqrt(float(np.mean(x * x)))
    if rms == 0.0:
        raise InputDataError("peak factor of an all-zero signal is undefined")
    return float((x.max() - x.min()) / (2.0 * math.sqrt(2.0) * rms))


def _check_axis(axis: str) -> str:
    if axis not in CONTROLS:
        raise InputDataError(f"axis {axis!r} is not a control; expected one of {CONTROLS}")
    return axis


def _samples(duration: float, dt: float, what: str) -> int:
    """Number of ``dt`` steps in ``duration``; it must be a whole number of samples."""
    if dt <= 0:
        raise InputDataError(f"dt must be positive, got {dt}")
    if duration < 0:
        raise InputDataError(f"{what} must be non-negative, got {duration} s")
    n = round(duration / dt)
    if abs(n * dt - duration) > 1e-9 * max(1.0, duration):
        raise InputDataError(f"{what} = {duration} s is not a whole number of samples of "
                             f"dt = {dt} s; pulse edges must fall on samples")
    return int(n)


def _control_var(axis: str, values: np.ndarray):
    attrs = {"units": "%", "long_name": f"{CHANNELS[axis].long_name} (perturbation from trim)"}
    return ("time", values, attrs)


def _dataset(data_vars: dict, dt: float, attrs: dict) -> xr.Dataset:
    n = len(next(iter(data_vars.values()))[1])
    time = np.arange(n) * dt
    attrs = {"dt": float(dt), **attrs}
    return xr.Dataset(data_vars,
                      coords={"time": ("time", time, {"units": "s", "long_name": "time"})},
                      attrs=attrs)


# --------------------------------------------------------------------------------------------
# frequency sweep


def sweep_phase(t, *, omega_min: float, omega_max: float, t_dwell: float, t_exp: float,
                C1: float = 4.0, C2: float = 0.0187):
    """Phase (rad) of the automated sweep at times ``t`` (s) measured from its start.

    ``omega = omega_min`` for ``t < t_dwell``; afterwards ``omega = omega_min + K (omega_max -
    omega_min)`` with ``K = C2 (exp(C1 tau / T) - 1)``, ``tau = t - t_dwell``. ``T`` is chosen
    so that ``K = 1`` exactly at ``tau = t_exp``: ``T = C1 t_exp / ln(1 + 1/C2)`` (with the
    standard constants ``T`` is 1.0006 ``t_exp``). The phase is the closed-form integral of
    ``omega``.
    """
    t = np.asarray(t, dtype=float)
    T = C1 * t_exp / math.log1p(1.0 / C2)
    tau = np.clip(t - t_dwell, 0.0, None)
    extra = (omega_max - omega_min) * C2 * (T / C1 * np.expm1(C1 * tau / T) - tau)
    return omega_min * t + extra


def frequency_sweep(axis: str, *, omega_min: float = 0.3, omega_max: float = 20.0,
                    duration: float = 90.0, amplitude: float = 10.0, dt: float = 0.01,
                    lead_in: float = 3.0, lead_out: float = 3.0,
                    long_period_cycles: float = 2.0, C1: float = 4.0, C2: float = 0.0187,
                    perturbation: float = 0.0, seed: int | None = None,
                    low_frequency_fraction: float = 1.0,
                    full_amplitude_omega: float | None = None,
                    amplitude_shape: float = 1.0) -> xr.Dataset:
    """Tischler's automated frequency sweep on one control axis.

    Parameters
    ----------
    axis
        Control excited: ``lon``, ``lat``, ``col`` or ``ped``.
    omega_min, omega_max
        Frequency band (rad/s). Defaults 0.3-20 rad/s: the 0.3 rad/s start gives two
        long-period cycles in 42 s (Tischler & Remple: record at least 2-5 periods of the
        lowest frequency identified, 60-120 s per record); 20 rad/s covers the rotorcraft
        body and coupled-rotor range at 100 Hz sampling.
    duration
        Length of the sweep proper (s): the long-period cycles plus the exponential part;
        the record is ``lead_in + duration + lead_out`` long.
    amplitude
        Sweep amplitude (% of travel), default 10 % (Tischler: about 10-20 %).
    dt
        Sample interval (s); ``omega_max`` must be below half the Nyquist frequency.
    lead_in, lead_out
        Seconds of trim (zeros) before and after the sweep, default 3 s each.
    long_period_cycles
        Cycles at ``omega_min`` before the exponential part (default 2, Tischler).
    C1, C2
        Constants of the sweep law (4.0 and 0.0187, Tischler & Remple).
    perturbation
        RMS of an added band-limited random signal relative to the sweep RMS (0 = none);
        it mimics the irregularity of a piloted sweep. Gaussian noise is band-passed to
        ``[omega_min, omega_max]`` (4th-order zero-phase Butterworth) and tapered to zero at
        both ends of the sweep. Needs ``seed``.
    seed
        Seed of the perturbation.
    low_frequency_fraction, full_amplitude_omega
        Amplitude schedule: the amplitude is ``low_frequency_fraction * amplitude`` at
        ``omega_min`` and grows linearly in log-frequency to ``amplitude`` at
        ``full_amplitude_omega`` (rad/s), constant above. This is what a pilot does on an
        axis whose low-frequency response is large (a hingeless rotor's pitch and roll): keep
        the attitude excursions bounded while the high-frequency response stays measurable.
        Default: constant amplitude.
    amplitude_shape
        Exponent of the schedule's rise: the amplitude fraction is
        ``f + (1 - f) * x**amplitude_shape`` with ``x`` the position in log-frequency from
        ``omega_min`` (0) to ``full_amplitude_omega`` (1). 1 (default) is the linear rise;
        above 1 the amplitude stays low longer and rises steeply just below
        ``full_amplitude_omega``.

    Returns
    -------
    xr.Dataset
        Variable ``<axis>`` (time) in % from trim. The exponential part is shortened by less
        than half a period of its mean frequency so that the total phase is a multiple of
        pi: the sweep starts and ends at zero without a step, and the instantaneous frequency
        reaches ``omega_max`` exactly at its end (attrs ``t_dwell``, ``t_exp``: lengths of
        the long-period and exponential parts, s).
    """
    _check_axis(axis)
    if not 0.0 < omega_min < omega_max:
        raise InputDataError(f"sweep band must satisfy 0 < omega_min < omega_max, got "
                             f"{omega_min} and {omega_max} rad/s")
    nyquist = math.pi / dt
    if omega_max > 0.5 * nyquist:
        raise InputDataError(f"omega_max = {omega_max} rad/s is above half the Nyquist "
                             f"frequency ({0.5 * nyquist:.4g} rad/s) of dt = {dt} s; reduce "
                             "omega_max or dt")
    if C2 <= 0 or C1 <= 0:
        raise InputDataError(f"sweep constants must be positive, got C1={C1}, C2={C2}")
    t_dwell = long_period_cycles * 2.0 * math.pi / omega_min
    t_exp = duration - t_dwell
    if t_exp <= 0.1 * duration:
        raise InputDataError(
            f"{long_period_cycles} cycles at omega_min = {omega_min} rad/s take {t_dwell:.1f} s, "
            f"leaving {max(t_exp, 0):.1f} s of the {duration} s sweep for the exponential part; "
            "raise duration or omega_min, or lower long_period_cycles")
    # Mean frequency of the exponential part: its phase grows as mean_omega * t_exp.
    mean_omega = omega_min + (omega_max - omega_min) * C2 * (1.0 / (C2 * math.log1p(1 / C2))
                                                             - 1.0)
    total = omega_min * t_dwell + mean_omega * t_exp
    t_exp -= (total - math.pi * math.floor(total / math.pi)) / mean_omega
    n_in = _samples(lead_in, dt, "lead_in")
    n_out = _samples(lead_out, dt, "lead_out")
    n_sweep = int(math.floor((t_dwell + t_exp) / dt + 1e-9)) + 1
    n_total = n_in + _samples_ceil(duration, dt) + n_out + 1
    t = np.arange(n_sweep) * dt
    x = np.zeros(n_total)
    phase = sweep_phase(t, omega_min=omega_min, omega_max=omega_max, t_dwell=t_dwell,
                        t_exp=t_exp, C1=C1, C2=C2)
    x[n_in:n_in + n_sweep] = amplitude * np.sin(phase) * _amplitude_schedule(
        np.gradient(phase, dt), omega_min, low_frequency_fraction, full_amplitude_omega,
        amplitude_shape)
    if perturbation:
        g = rng(seed)
        noise = g.standard_normal(n_sweep)
        sos = scipy.signal.butter(2, [omega_min, omega_max], btype="bandpass", fs=2 * math.pi
                                  / dt, output="sos")
        noise = scipy.signal.sosfiltfilt(sos, noise)
        noise *= scipy.signal.windows.tukey(n_sweep, alpha=min(1.0, 2.0 / (n_sweep * dt)))
        noise *= perturbation * (amplitude / math.sqrt(2.0)) / np.sqrt(np.mean(noise ** 2))
        x[n_in:n_in + n_sweep] += noise
    attrs = {
        "kind": "sweep", "axis": axis, "omega_min": omega_min, "omega_max": omega_max,
        "duration": duration, "amplitude": amplitude, "lead_in": lead_in,
        "lead_out": lead_out, "long_period_cycles": long_period_cycles, "C1": C1, "C2": C2,
        "t_dwell": t_dwell, "t_exp": t_exp,
        "low_frequency_fraction": low_frequency_fraction,
        "full_amplitude_omega": full_amplitude_omega or omega_min,
        "amplitude_shape": amplitude_shape,
        "perturbation": perturbation, "seed": -1 if not perturbation else int(seed),
        "hold": "linear",
    }
    return _dataset({axis: _control_var(axis, x)}, dt, attrs)


def _amplitude_schedule(omega: np.ndarray, omega_min: float, fraction: float,
                        omega_full: float | None, shape: float = 1.0) -> np.ndarray:
    """Relative amplitude at instantaneous frequency ``omega`` (see :func:`frequency_sweep`)."""
    if not shape > 0.0:
        raise InputDataError(f"amplitude_shape must be positive, got {shape}")
    if omega_full is None or fraction == 1.0:
        return np.ones_like(omega)
    if not 0.0 < fraction <= 1.0 or omega_full <= omega_min:
        raise InputDataError("amplitude schedule needs 0 < low_frequency_fraction <= 1 and "
                             f"full_amplitude_omega > omega_min, got {fraction} and "
                             f"{omega_full} rad/s")
    position = np.log(np.clip(omega, omega_min, omega_full) / omega_min) / math.log(
        omega_full / omega_min)
    return fraction + (1.0 - fraction) * position ** shape


def _samples_ceil(duration: float, dt: float) -> int:
    return int(math.ceil(duration / dt - 1e-9))


# --------------------------------------------------------------------------------------------
# multisteps


def multistep(kind: str, axis: str, *, base_width: float, amplitude: float, sign: int = 1,
              dt: float = 0.01, lead_in: float = 1.0, lead_out: float = 10.0) -> xr.Dataset:
    """A 3211, 2311 or doublet input: alternating pulses on one control axis.

    Parameters
    ----------
    kind
        ``"3211"`` (widths 3, 2, 1, 1), ``"2311"`` (2, 3, 1, 1) or ``"doublet"`` (1, 1), in
        units of ``base_width``. Signs alternate, starting with ``sign``.
    base_width
        Unit pulse width (s), a whole number of samples; choose it from the mode
        frequencies of interest (a 3211 concentrates energy near ``omega ~ 1.6/base_width``).
    amplitude
        Pulse height (% of travel).
    sign
        +1 or -1: direction of the first pulse.
    lead_in, lead_out
        Trim (zeros) before the first pulse (default 1 s) and after the last pulse (default
        10 s, to record the free response), whole numbers of samples.

    Returns
    -------
    xr.Dataset
        Variable ``<axis>`` (time) in % from trim. Pulse ``i`` covers samples ``t`` with
        ``start_i <= t < end_i`` exactly (edges on samples; attr ``hold = "previous"``).
    """
    _check_axis(axis)
    if kind not in MULTISTEP_WIDTHS:
        raise InputDataError(f"multistep kind {kind!r} unknown; expected one of "
                             f"{sorted(MULTISTEP_WIDTHS)}")
    if sign not in (1, -1):
        raise InputDataError(f"sign must be +1 or -1, got {sign}")
    if base_width <= 0:
        raise InputDataError(f"base_width must be positive, got {base_width} s")
    n_base = _samples(base_width, dt, "base_width")
    n_in = _samples(lead_in, dt, "lead_in")
    n_out = _samples(lead_out, dt, "lead_out")
    widths = MULTISTEP_WIDTHS[kind]
    pulses = [np.full(w * n_base, sign * (-1) ** i * float(amplitude))
              for i, w in enumerate(widths)]
    x = np.concatenate([np.zeros(n_in), *pulses, np.zeros(n_out + 1)])
    attrs = {"kind": kind, "axis": axis, "base_width": base_width, "amplitude": amplitude,
             "sign": int(sign), "widths": list(widths), "lead_in": lead_in,
             "lead_out": lead_out, "seed": -1, "hold": "previous"}
    return _dataset({axis: _control_var(axis, x)}, dt, attrs)


def input_3211(axis: str, **kwargs) -> xr.Dataset:
    """3211 multistep (widths 3, 2, 1, 1 x ``base_width``); see :func:`multistep`."""
    return multistep("3211", axis, **kwargs)


def input_2311(axis: str, **kwargs) -> xr.Dataset:
    """2311 multistep (widths 2, 3, 1, 1 x ``base_width``); see :func:`multistep`."""
    return multistep("2311", axis, **kwargs)


def doublet(axis: str, **kwargs) -> xr.Dataset:
    """Doublet (widths 1, 1 x ``base_width``); see :func:`multistep`."""
    return multistep("doublet", axis, **kwargs)


# --------------------------------------------------------------------------------------------
# orthogonal multisines


def _synthesise(harmonics: np.ndarray, phases: np.ndarray, n: int,
                amplitudes: np.ndarray | float = 1.0) -> np.ndarray:
    """``sum_k a_k cos(2 pi k i / n + phi_k)`` for samples ``i = 0..n-1``."""
    spectrum = np.zeros(n // 2 + 1, dtype=complex)
    spectrum[harmonics] = 0.5 * n * amplitudes * np.exp(1j * phases)
    return np.fft.irfft(spectrum, n)


def _schroeder_phases(count: int) -> np.ndarray:
    """Schroeder (1970) phases for equal power per harmonic: ``-pi k (k-1) / K``."""
    k = np.arange(1, count + 1)
    return -np.pi * k * (k - 1) / count


def _minimise_peak(harmonics, phases, n, ripple_db=0.0,
                   sharpness=(2.0, 8.0, 32.0, 128.0, 512.0), maxiter=200):
    """Phases and amplitudes lowering the peak factor of the multisine.

    The peak factor ``(max - min) / (2 sqrt(2) rms)`` has ``max - min`` replaced by its
    smooth log-sum-exp bound with sharpness ``b`` (in units of the rms), and ``rms =
    sqrt(sum a_k^2 / 2)`` (Parseval). It is minimised by L-BFGS-B with the exact gradient
    (one FFT) for rising ``b``, over the phases and the log-amplitudes ``ln a_k``, the latter
    bounded to ``+-ripple_db / 2`` dB about 1 (``ripple_db = 0``: equal amplitudes, phases
    only). Returns ``(phases, amplitudes)``.
    """
    m = harmonics.size
    bound = 0.5 * ripple_db * math.log(10.0) / 20.0
    z = np.concatenate([phases, np.zeros(m)])
    for b in sharpness:
        def cost(v):
            phi, a = v[:m], np.exp(v[m:])
            rms = math.sqrt(0.5 * np.sum(a * a))
            beta = b / rms
            x = _synthesise(harmonics, phi, n, a)
            span = (scipy.special.logsumexp(beta * x) + scipy.special.logsumexp(-beta * x)) / beta
            weights = scipy.special.softmax(beta * x) - scipy.special.softmax(-beta * x)
            # d x_i / d phi_k = -a_k sin(w_k t_i + phi_k), d x_i / d a_k = cos(w_k t_i + phi_k)
            g = np.exp(1j * phi) * np.conj(np.fft.rfft(weights)[harmonics])
            d_phi = -a * np.imag(g) / rms
            # d (span / rms) / d ln a_k, with d rms / d a_k = a_k / (2 rms)
            d_ln_a = a * (np.real(g) / rms - span * a / (2.0 * rms ** 3))
            return span / rms, np.concatenate([d_phi, d_ln_a])
        z = scipy.optimize.minimize(cost, z, jac=True, method="L-BFGS-B",
                                    bounds=[(None, None)] * m + [(-bound, bound)] * m,
                                    options={"maxiter": maxiter}).x
    return np.mod(z[:m] + np.pi, 2 * np.pi) - np.pi, np.exp(z[m:])


#: Default spread (dB) allowed between the harmonic amplitudes of one multisine axis.
DEFAULT_MULTISINE_RIPPLE_DB = 2.0

#: Ways of dealing the band's harmonics to the axes; see :func:`orthogonal_multisines`.
MULTISINE_DEALS = ("round-robin", "dyadic")


def _deal_harmonics(k_all: np.ndarray, count: int, deal: str) -> list[np.ndarray]:
    """Harmonic numbers of each of ``count`` axes; together they are ``k_all``, each once."""
    if deal == "round-robin":
        return [k_all[j::count] for j in range(count)]
    # dyadic: axis j < count - 1 gets k = 2**j * odd, the last axis the multiples of
    # 2**(count - 1); k & -k is the largest power of two dividing k
    level = np.minimum(np.log2(k_all & -k_all).round().astype(int), count - 1)
    return [k_all[level == j] for j in range(count)]


def orthogonal_multisines(axes, *, omega_min: float, omega_max: float, duration: float,
                          amplitude: float | dict = 10.0, dt: float = 0.01,
                          optimise: bool = True, restarts: int = 0,
                          seed: int | None = None, deal: str = "round-robin",
                          ripple_db: float = DEFAULT_MULTISINE_RIPPLE_DB) -> xr.Dataset:
    """Morelli's orthogonal phase-optimised multisines, one per control axis.

    The record of ``duration`` s has base frequency ``omega_0 = 2 pi / duration``. Every
    harmonic ``k omega_0`` in ``[omega_min, omega_max]`` goes to exactly one axis, so the
    signals are mutually orthogonal over the record (each harmonic completes a whole number
    of cycles on the sample grid). Phases start from Schroeder's (equal amplitudes) and,
    with ``optimise``, phases and amplitudes are refined to lower the peak factor, the
    amplitudes of an axis staying within ``ripple_db`` of each other (smooth minimisation,
    see :func:`_minimise_peak`); with a ``seed``,
    ``restarts`` extra seeded random starting phases are tried and the lowest peak factor
    kept (default 0: random starts end higher than the Schroeder start). Each signal is
    finally shifted circularly (which keeps orthogonality and spectrum) to start at the
    upward zero crossing closest to a sample, and scaled so its peak is ``amplitude``.

    ``deal`` chooses which harmonics each axis gets (``m = len(axes)``):

    ``"round-robin"`` (Morelli's design, the default)
        Axis ``j`` gets band harmonics ``j, j + m, j + 2m, ...``: equal line count and
        spacing ``m omega_0`` on every axis. An axis whose harmonics are ``k = r (mod m)``
        with ``2 r`` not a multiple of ``m`` (with 4 axes, the two axes holding odd ``k``)
        obeys ``x(t + T/m) = Re(exp(2 pi i r/m) z(t))``, ``z`` its analytic signal: the
        signal must stay low in several rotations of ``z`` at once (with ``r/m = 1/4``,
        also its Hilbert transform), and its optimised peak factor stays a few % above 1
        (about 1.05 with 70 lines per axis, falling slowly with the line count), whereas
        the other axes, plain (anti)periodic signals over ``T/m``, reach about 0.98.
        Splitting the odd harmonics any other way between two axes did worse in our trials
        (irregular line spacing: 1.16-1.25). Letting the amplitudes ripple by 2 dB
        (the default ``ripple_db``) brings those axes to about 1.00 and the others to 0.93-0.94.
    ``"dyadic"``
        Axis ``j < m - 1`` gets the harmonics ``k = 2^j x odd``, the last axis the multiples
        of ``2^(m-1)``: with 4 axes, 1/2, 1/4, 1/8 and 1/8 of the lines, spacings 2, 4, 8 and
        8 ``omega_0``. Each axis is then a plain odd-harmonic (or full) multisine over
        ``T / 2^j``, so every axis reaches a peak factor of about 0.98 (1.03 with only 8
        lines), below a sweep of the same band, at the price of unequal line counts: the
        later axes have coarser frequency resolution and their lowest line may sit up to
        ``2^(m-1) omega_0`` above ``omega_min``. Order ``axes`` by the resolution each
        needs. With 1 or 2 axes (and the band starting at an odd harmonic) both deals
        coincide.

    Parameters
    ----------
    axes
        Control axes, e.g. ``("lon", "lat", "col", "ped")``.
    omega_min, omega_max
        Band (rad/s); ``omega_max`` below half the Nyquist frequency.
    duration
        Record length (s), a whole number of samples; sets the frequency resolution.
    amplitude
        Peak (% of travel), one number or ``{axis: peak}``.
    deal
        ``"round-robin"`` or ``"dyadic"``, see above.
    ripple_db
        Largest spread (dB, peak to peak) allowed between the amplitudes of one axis's
        harmonics, default 2 dB (flat within +-1 dB: negligible next to the +-10 dB a sweep's
        autospectrum varies over its band, and harmless to identification, which divides by
        the input spectrum); 0 keeps the amplitudes equal (Morelli's original design).

    Returns
    -------
    xr.Dataset
        One variable per axis (time) in % from trim; attrs ``peak_factor_<axis>`` (relative
        peak factor, :func:`peak_factor`), ``harmonics_<axis>`` (integers ``k``),
        ``harmonic_amplitudes_<axis>`` (% of travel, one per harmonic), ``deal``,
        ``ripple_db``.
    """
    axes = [axes] if isinstance(axes, str) else list(axes)
    for axis in axes:
        _check_axis(axis)
    if len(set(axes)) != len(axes):
        raise InputDataError(f"axes must be distinct, got {axes}")
    n = _samples(duration, dt, "duration")
    if not 0.0 < omega_min < omega_max or omega_max > 0.5 * math.pi / dt:
        raise InputDataError(f"multisine band must satisfy 0 < omega_min < omega_max <= "
                             f"{0.5 * math.pi / dt:.4g} rad/s, got {omega_min}-{omega_max}")
    omega_0 = 2.0 * math.pi / (n * dt)
    k_all = np.arange(math.ceil(omega_min / omega_0 - 1e-9),
                      math.floor(omega_max / omega_0 + 1e-9) + 1)
    k_all = k_all[k_all >= 1]
    if not 0.0 <= ripple_db <= 20.0:
        raise InputDataError(f"ripple_db must be between 0 and 20 dB, got {ripple_db}")
    if deal not in MULTISINE_DEALS:
        raise InputDataError(f"deal must be one of {MULTISINE_DEALS}, got {deal!r}")
    dealt = _deal_harmonics(k_all, len(axes), deal)
    if min(h.size for h in dealt) < 2:
        raise InputDataError(
            f"only {k_all.size} harmonics of {omega_0:.4g} rad/s lie in {omega_min}-{omega_max} "
            f"rad/s, dealt {[int(h.size) for h in dealt]} to {len(axes)} axes ({deal}); "
            "expected at least 2 per axis: lengthen duration or widen the band")
    if restarts and optimise and seed is not None:
        g = rng(seed)
    else:
        g = None
    peaks = amplitude if isinstance(amplitude, dict) else {a: amplitude for a in axes}
    data_vars, attrs = {}, {}
    for axis, harmonics in zip(axes, dealt):
        starts = [_schroeder_phases(harmonics.size)]
        if g is not None:
            starts += [g.uniform(-np.pi, np.pi, harmonics.size) for _ in range(restarts)]
        best = None
        for phases in starts:
            amplitudes = np.ones(harmonics.size)
            if optimise:
                phases, amplitudes = _minimise_peak(harmonics, phases, n, ripple_db)
            x = _synthesise(harmonics, phases, n, amplitudes)
            pf = peak_factor(x)
            if best is None or pf < best[0]:
                best = (pf, x, amplitudes)
        pf, x, amplitudes = best
        # Start at the upward zero crossing passing closest to a sample, so the input leaves
        # trim with the smallest step.
        up = np.flatnonzero((x[:-1] <= 0) & (x[1:] > 0))
        candidates = np.concatenate([up, up + 1])
        x = np.roll(x, -int(candidates[np.argmin(np.abs(x[candidates]))]))
        scale = float(peaks[axis]) / np.abs(x).max()
        x *= scale
        data_vars[axis] = _control_var(axis, x)
        attrs[f"peak_factor_{axis}"] = pf
        attrs[f"harmonics_{axis}"] = harmonics.astype(np.int64)
        attrs[f"harmonic_amplitudes_{axis}"] = scale * amplitudes
    attrs = {"kind": "multisine", "axis": axes[0] if len(axes) == 1 else "",
             "axes": list(axes), "omega_min": omega_min, "omega_max": omega_max,
             "duration": duration, "omega_0": omega_0, "deal": deal,
             "ripple_db": float(ripple_db) if optimise else 0.0,
             "optimise": bool(optimise),
             "restarts": int(restarts) if g is not None else 0,
             "seed": -1 if g is None else int(seed), "hold": "linear", **attrs}
    return _dataset(data_vars, dt, attrs)


# --------------------------------------------------------------------------------------------
# Dryden turbulence


def dryden_parameters(altitude: float, intensity: float | str) -> dict:
    """MIL-F-8785C low-altitude Dryden intensities (m/s) and scale lengths (m).

    With ``h`` the altitude in ft, clamped to 10-1000 ft (the low-altitude model's range):
    ``L_w = h``, ``L_u = L_v = h / (0.177 + 0.000823 h)^1.2``;
    ``sigma_w = 0.1 W20`` with ``W20`` = 15 / 30 / 45 kt for light / moderate / severe, or
    ``sigma_w = intensity`` (m/s) when a number is given;
    ``sigma_u = sigma_v = sigma_w / (0.177 + 0.000823 h)^0.4``.
    """
    h_ft = min(max(altitude / FT, 10.0), 1000.0)
    if isinstance(intensity, str):
        if intensity not in W20_KT:
            raise InputDataError(f"turbulence intensity {intensity!r} unknown; expected a "
                                 f"number (sigma_w, m/s) or one of {sorted(W20_KT)}")
        sigma_w = 0.1 * W20_KT[intensity] * KT
    else:
        sigma_w = float(intensity)
        if not sigma_w >= 0.0:
            raise InputDataError(f"turbulence intensity must be >= 0 m/s, got {intensity}")
    ratio = 0.177 + 0.000823 * h_ft
    return {
        "sigma_u": sigma_w / ratio ** 0.4, "sigma_v": sigma_w / ratio ** 0.4,
        "sigma_w": sigma_w,
        "L_u": h_ft / ratio ** 1.2 * FT, "L_v": h_ft / ratio ** 1.2 * FT, "L_w": h_ft * FT,
        "altitude_used": h_ft * FT,
    }


def _dryden_filter(kind: str, tau: float):
    """State-space ``(A, B, C)`` of the unit-gain Dryden shaping filter with time constant
    ``tau = L / V``: ``1 / (1 + tau s)`` (longitudinal) or ``(1 + sqrt(3) tau s) /
    (1 + tau s)^2`` (lateral and vertical), MIL-F-8785C."""
    if kind == "u":
        return np.array([[-1.0 / tau]]), np.array([[1.0]]), np.array([[1.0 / tau]])
    a = np.array([[0.0, 1.0], [-1.0 / tau ** 2, -2.0 / tau]])
    return a, np.array([[0.0], [1.0]]), np.array([[1.0 / tau ** 2, math.sqrt(3.0) / tau]])


def _simulate_gust(kind, tau, sigma, n, dt, g):
    """Exact discrete samples of the Dryden process with rms ``sigma``.

    The filter driven by unit-intensity white noise is discretised exactly (Van Loan:
    transition matrix and process-noise covariance from one matrix exponential) and started
    from its stationary distribution, so the samples have exactly the continuous process's
    variance and autocorrelation at the sample instants, for any ``dt``.
    """
    a, b, c = _dryden_filter(kind, tau)
    m = a.shape[0]
    big = np.zeros((2 * m, 2 * m))
    big[:m, :m] = -a
    big[:m, m:] = b @ b.T
    big[m:, m:] = a.T
    e = scipy.linalg.expm(big * dt)
    phi = e[m:, m:].T
    q = phi @ e[:m, m:]
    q = 0.5 * (q + q.T)
    p_ss = scipy.linalg.solve_continuous_lyapunov(a, -b @ b.T)
    gain = sigma / math.sqrt(float((c @ p_ss @ c.T)[0, 0]))
    lq = np.linalg.cholesky(q)
    w = g.standard_normal((n, m)) @ lq.T
    x = np.linalg.cholesky(p_ss) @ g.standard_normal(m)
    # x[i+1] = phi x[i] + w[i], vectorised: in the Schur basis (phi = Z T Z^H, T upper
    # triangular) each component is a first-order recursion, filtered last to first.
    t, z_basis = scipy.linalg.schur(phi.astype(complex), output="complex")
    v = w @ z_basis.conj()
    z0 = z_basis.conj().T @ x
    z = np.empty((n, m), dtype=complex)
    for j in reversed(range(m)):
        forcing = v[:-1, j] + z[:-1, j + 1:] @ t[j, j + 1:]
        z[0, j] = z0[j]
        z[1:, j] = scipy.signal.lfilter([1.0], [1.0, -t[j, j]], forcing,
                                        zi=[t[j, j] * z0[j]])[0]
    return gain * (z @ (c[0] @ z_basis)).real


def dryden_turbulence(duration: float, *, dt: float, airspeed: float, altitude: float,
                      intensity: float | str = "light", seed: int,
                      min_airspeed: float = MIN_GUST_AIRSPEED) -> xr.Dataset:
    """Seeded Dryden turbulence velocities along body axes (MIL-F-8785C / MIL-HDBK-1797).

    One-sided spectra (rad/s), with ``V`` the convection speed and ``omega`` the frequency::

        Phi_u = sigma_u^2 (2 L_u / (pi V)) / (1 + (L_u omega / V)^2)
        Phi_v = sigma_v^2 (L_v / (pi V)) (1 + 3 (L_v omega / V)^2) / (1 + (L_v omega / V)^2)^2

    and ``Phi_w`` as ``Phi_v`` with ``L_w, sigma_w``; intensities and scales from
    :func:`dryden_parameters` (low-altitude model). The three components are independent.

    Hover: the model assumes a frozen field convected past the aircraft at ``V``; with no
    airspeed the field is carried by the ambient wind instead, so ``V = max(airspeed,
    min_airspeed)`` with ``min_airspeed`` = 5 m/s (about 10 kt, a light-wind day). The
    value used is in attr ``convection_speed``.

    Parameters
    ----------
    duration : s. dt : sample interval, s. airspeed : m/s. altitude : m above ground.
    intensity : ``sigma_w`` in m/s, or ``"light"``, ``"moderate"``, ``"severe"``.
    seed : required; the same seed gives the same samples.

    Returns
    -------
    xr.Dataset
        ``u_gust``, ``v_gust``, ``w_gust`` (time), m/s (the truth FMU's gust inputs are SI).
    """
    if seed is None:
        raise InputDataError("dryden_turbulence needs a seed: every random process is seeded")
    n = _samples_ceil(duration, dt) + 1
    params = dryden_parameters(altitude, intensity)
    speed = max(float(airspeed), float(min_airspeed))
    if speed <= 0:
        raise InputDataError(f"min_airspeed must be positive, got {min_airspeed} m/s")
    g = rng(seed)
    data_vars = {}
    names = {"u": "longitudinal", "v": "lateral", "w": "vertical"}
    for comp in ("u", "v", "w"):
        sigma, scale = params[f"sigma_{comp}"], params[f"L_{comp}"]
        values = (_simulate_gust(comp, scale / speed, sigma, n, dt, g) if sigma > 0
                  else np.zeros(n))
        data_vars[f"{comp}_gust"] = ("time", values, {
            "units": "m/s", "long_name": f"{names[comp]} turbulence velocity (body axes)"})
    attrs = {"kind": "turbulence", "model": "Dryden, MIL-F-8785C low altitude",
             "airspeed": float(airspeed), "convection_speed": speed,
             "altitude": float(altitude),
             "intensity": intensity if isinstance(intensity, str) else float(intensity),
             "seed": int(seed), "hold": "linear", **params}
    return _dataset(data_vars, dt, attrs)
