"""Frequency-response stage: time histories -> conditioned, composite frequency responses.

The CIFER chain FRESPID (windowed spectra, :mod:`sysid.spectral.spectra`) -> MISOSA (MIMO conditioning,
:mod:`sysid.spectral.conditioning`) -> COMPOSITE (:mod:`sysid.spectral.composite`) in one call::

    ds = frequency_response(records, inputs=["lon", "lat", "col", "ped"],
                            outputs=["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"])

Perturbations: a record's channel is taken about the Dataset attribute ``trim_<channel>`` when
present (time histories written by :mod:`sysid.flight_test.campaign` carry them), else about the record's
mean over its whole length (imported data). Several records are concatenated CIFER-style: each
is segmented separately and the segment averages are pooled.

The returned Dataset (``docs/data_model.md``) has dims ``output``, ``input``, ``input_j``,
``frequency`` (rad/s) and ``window`` (s, only in the per-window result):

``H`` (output, input, frequency), complex
    composite conditioned response (Eq. 17), output units per input unit; the unconditioned
    single-input estimate when ``conditioned=False``.
``coherence`` (output, input, frequency)
    composite ordinary coherence (Eq. 7; Eq. 16 applied to the unconditioned pair spectra).
``partial_coherence`` (output, input, frequency)
    composite coherence of the conditioned pair spectra (Eq. 11; equals ``coherence`` when
    unconditioned). This is the coherence to use for the conditioned ``H``.
``random_error`` (output, input, frequency)
    composite normalised random error (Eq. 13 per window, combined with the Eq. 14 weights).
``multiple_coherence`` (output, frequency)
    Eq. 12 from the window-averaged spectra.
``Gxx`` (input, input_j, frequency), ``Gyy`` (output, frequency), ``Gxy`` (output, input,
frequency), ``cross_coherence`` (input, input_j, frequency), ``input_coherence`` (input,
frequency)
    unconditioned spectra averaged over the usable windows (weights ``(n_d/n_d_max)^2``, i.e.
    Eq. 14 at equal coherence), cross-control coherence Eq. 8, and each input's multiple
    coherence on the other inputs.
``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair`` (output, input, frequency)
    the composite (conditioned) pair spectra of the sampled data, ``H = Gxy_pair /
    Gxx_pair / Z`` (``Z`` the input hold's transfer, 1 without one; below).
``collinear`` (frequency), bool
    no window is usable there (nearly collinear inputs in every window trusted at that
    frequency); ``H`` is NaN.
``window_length``, ``n_d`` (window_length)
    the window lengths (s) and their independent averages ``T_r / T``.

Attributes: ``overlap``, ``C_eps``, ``windows`` (s), ``records``, ``inputs``, ``outputs``,
``conditioned``, ``collinear_threshold``, ``conditioning_method``, ``transient_states`` (the
states whose segment start/end leakage was conditioned out; empty when off) and
``transient_choice`` (``"auto"``, ``"given"`` or ``"off"``: how they were chosen).

Leakage-free by default: with ``transient_states="auto"`` (the default) every measured state
among :data:`LEAKAGE_STATES` joins the conditioning through its taper-derivative transform
(docs/methods.md, "Leakage-free conditioning").

Held inputs: records whose ``input_hold`` attribute is ``"zero_order"`` (a simulation
stepped with each input sample held over its interval, as the truth FMU is flown) relate
their samples through the zero-order hold, ``Z(j w) = (1 - e^{-j w T}) / (j w T)``: a delay
of half a sample (5 ms at 100 Hz, 4 deg at 15 rad/s) that is the sampling's, not the
aircraft's. ``H`` is divided by it, so it is the continuous system's response that the
models describe (the time-domain fits discretise with the same hold); attribute
``input_hold`` says what was divided out (docs/methods.md, "Spectra").
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from sysid import __version__
from sysid.spectral import composite as _composite
from sysid.spectral import conditioning as _conditioning
from sysid.spectral import spectra as _spectra
from sysid.core.errors import InputDataError
from sysid.core.units import CHANNELS
from sysid.core.util import Progress

#: Default number of log-spaced frequency points.
DEFAULT_N_FREQUENCIES = 200
#: Default highest frequency as a fraction of the sample rate: ``omega_max = 2 pi fs / 10``
#: (ten samples per period of the highest frequency; 62.8 rad/s at 100 Hz).
SAMPLES_PER_PERIOD_AT_OMEGA_MAX = 10.0


#: The states whose segment start/end leakage ``transient_states="auto"`` conditions out when
#: they are measured: the rigid-body states of the quasi-steady 6-DoF model that feed back into
#: its dynamics (velocities, rates, and the bank and pitch attitudes through gravity). The
#: heading ``psi`` is left out: no force or moment depends on it, so its transient leaks into
#: no other channel, and every regressor costs a degree of freedom per segment.
LEAKAGE_STATES = ("u", "v", "w", "p", "q", "r", "phi", "theta")
#: Values of ``transient_states`` that choose :data:`LEAKAGE_STATES` automatically.
AUTO = "auto"
#: Values of a record's ``input_hold`` attribute: ``"zero_order"``, every input sample held
#: over its sample interval (a simulation stepped with it); absent for measured data, whose
#: inputs are sampled like the outputs.
INPUT_HOLDS = ("zero_order",)
#: The campaign group where a study keeps the conditioned responses without leakage
#: conditioning beside the default ones (docs/data_model.md; the report's before/after figure).
NO_TRANSIENT_GROUP = "frequency_response_no_transient"


def resolve_transient_states(records, transient_states, *, inputs: Sequence[str] = (),
                             conditioned: bool = True) -> tuple[list[str], str]:
    """The transient states a frequency response will use, and how they were chosen.

    ``transient_states`` is ``"auto"`` (every channel of :data:`LEAKAGE_STATES` present in all
    records and not an input; none for an unconditioned estimate), an explicit sequence or
    comma-separated string (used as given and checked later), or empty / None (off).
    Returns ``(states, choice)`` with ``choice`` one of ``"auto"``, ``"given"``, ``"off"``.
    """
    if isinstance(transient_states, str):
        transient_states = transient_states.strip()
    if transient_states is None or len(transient_states) == 0:
        return [], "off"
    if isinstance(transient_states, str) and transient_states.lower() == AUTO:
        if not conditioned:
            return [], "off"
        items = _spectra._named_records(records)
        present = [c for c in LEAKAGE_STATES
                   if c not in inputs and all(c in ds.data_vars for _, ds in items)]
        return present, (AUTO if present else "off")
    states = _channel_list(transient_states, "transient state")
    return states, ("given" if states else "off")


def _progress(progress) -> Progress:
    if isinstance(progress, Progress):
        return progress
    return Progress(quiet=not progress)


def _channel_list(names, what: str) -> list[str]:
    if isinstance(names, str):
        names = [n.strip() for n in names.split(",") if n.strip()]
    names = list(names)
    if not names:
        raise InputDataError(f"no {what} channels given")
    if len(set(names)) != len(names):
        raise InputDataError(f"{what} channels listed twice: {names}")
    return names


def _frequency_grid(frequencies, omega_min, omega_max, n_frequencies, windows, dt):
    nyquist = math.pi / dt
    if frequencies is not None:
        w = np.sort(np.asarray(getattr(frequencies, "values", frequencies), dtype=float))
        grid = xr.DataArray(w, dims="frequency", coords={"frequency": w},
                            attrs={"units": "rad/s", "long_name": "frequency"})
    else:
        lo = omega_min if omega_min is not None else 2.0 * math.pi / max(windows)
        hi = omega_max if omega_max is not None else (
            2.0 * math.pi / (SAMPLES_PER_PERIOD_AT_OMEGA_MAX * dt))
        grid = _spectra.log_frequencies(lo, hi, n_frequencies)
    if grid.size == 0 or float(grid.max()) >= nyquist or float(grid.min()) <= 0:
        raise InputDataError(
            f"frequencies {float(grid.min()):.6g}..{float(grid.max()):.6g} rad/s: expected "
            f"positive values below the Nyquist frequency {nyquist:.6g} rad/s")
    return grid


def zero_order_hold(omega, dt: float) -> np.ndarray:
    """Transfer of a zero-order hold of interval ``dt`` (s) at ``omega`` (rad/s):
    ``Z(j w) = (1 - e^{-j w dt}) / (j w dt) = e^{-j w dt / 2} sinc(w dt / 2)``, a delay of
    half a sample and a gain droop (1 at 0).

    Examples
    --------
    >>> np.angle(zero_order_hold([10.0], 0.01), deg=True)   # half a sample: -0.05 rad
    array([-2.86478898])
    """
    x = np.asarray(omega, dtype=float) * float(dt) / 2.0
    return np.exp(-1j * x) * np.sinc(x / np.pi)


def records_input_hold(records) -> str | None:
    """The ``input_hold`` shared by every record (``None``: not held, measured data).
    Raises InputDataError for an unknown value or records that disagree."""
    holds = {name: ds.attrs.get("input_hold") for name, ds in _spectra._named_records(records)}
    values = set(holds.values())
    unknown = sorted(str(v) for v in values - {None, *INPUT_HOLDS})
    if unknown:
        raise InputDataError(f"records have input_hold {unknown}; expected one of "
                             f"{list(INPUT_HOLDS)} or none (measured data)")
    if len(values) > 1:
        raise InputDataError(f"records disagree on how their inputs were held between samples "
                             f"(attribute input_hold): {holds}; compute their responses "
                             f"separately")
    return next(iter(values)) if values else None


def frequency_response(records, inputs: Sequence[str], outputs: Sequence[str], *,
                       n_windows: int = _composite.DEFAULT_N_WINDOWS,
                       windows: Sequence[float] | None = None,
                       overlap: float = _spectra.DEFAULT_OVERLAP,
                       frequencies=None, n_frequencies: int = DEFAULT_N_FREQUENCIES,
                       omega_min: float | None = None, omega_max: float | None = None,
                       C_eps: float = _spectra.DEFAULT_C_EPS, conditioned: bool = True,
                       collinear_threshold: float = _conditioning.DEFAULT_COLLINEAR_THRESHOLD,
                       method: str = "matrix",
                       coherence_weight: float = _composite.COHERENCE_WEIGHT,
                       keep_windows: bool = False, progress=None,
                       transient_states: Sequence[str] | str | None = AUTO):
    """Composite (conditioned) frequency responses of every input/output pair.

    Parameters
    ----------
    records : xr.Dataset, sequence of xr.Dataset or mapping name -> xr.Dataset
        Time histories, uniform ``time`` (s), channels as data variables in analysis units.
    inputs, outputs : sequence of str (or comma-separated str)
        Channel names, e.g. ``["lon", "lat", "col", "ped"]`` and ``["p", "q"]``.
    n_windows : int
        Window lengths for compositing when ``windows`` is not given (default 5; lengths
        from :func:`sysid.spectral.composite.default_windows`).
    windows : sequence of float, optional
        Explicit window lengths, s.
    overlap : float
        Segment overlap, default 0.8.
    frequencies : array-like, optional
        Frequency grid, rad/s. Default: ``n_frequencies`` (200) log-spaced points from
        ``omega_min`` (default ``2 pi / T_max``, the lowest frequency the longest window
        resolves) to ``omega_max`` (default ``2 pi fs / 10``).
    C_eps : float
        Random-error constant of Eq. 9/13 (default 0.7 for Hann, 50-80 % overlap, with
        ``n_d = T_r / T``; see :func:`sysid.spectral.spectra.hann_error_constant`).
    conditioned : bool
        MIMO conditioning of each pair on the other inputs (default). ``False`` gives the
        unconditioned single-input estimates (:func:`siso_frequency_response`).
    collinear_threshold : float
        Frequencies where an input's multiple coherence on the other inputs exceeds this
        (default 0.99) are flagged ``collinear`` in each window and not used.
    method : {"matrix", "recursion"}
        Conditioning by the normal equations or the paper's Eq. 10 recursion (same result).
    coherence_weight : float
        Weight of the coherence term of the composite cost Eq. 16 (default 5.0, the
        paper's). Where the windows disagree this term brings the composite coherence to the
        windows' weighted mean coherence; with the spectral terms scaled by the windows'
        spread (:mod:`sysid.spectral.composite`) the change goes mostly into the spectrum the windows
        disagree on (typically ``Gyy``), not into ``H``. ``0`` reduces compositing to the
        Eq. 14-weighted average of the window spectra.
    keep_windows : bool
        Also return the per-window results (dim ``window``, s).
    progress : sysid.core.util.Progress or bool, optional
        Per-stage progress lines; silent by default.
    transient_states : "auto", sequence of str (or comma-separated str), or empty
        Measured state channels whose taper-derivative transforms join the conditioning as
        extra inputs (:func:`sysid.spectral.spectra.window_spectra`), removing the leakage of
        each segment's start and end conditions (docs/methods.md, "Leakage-free
        conditioning"). Default ``"auto"``: the channels of :data:`LEAKAGE_STATES`
        (``u v w p q r phi theta``: the states that drive the 6-DoF dynamics; not ``psi``,
        on which nothing depends) that every record carries, none for an unconditioned
        estimate. ``()`` or ``""`` turns it off (the paper's method). It matters near lightly
        damped or unstable modes flown in closed loop, where ``(j omega - A)^-1`` is large.
        The correction is exact for a linear system whose states are all measured; with
        some missing it removes their part of the leakage only. Each regressor costs a
        degree of freedom of each window's averages, which the partial coherence and the
        random error are charged for, as are the other inputs (:func:`charge_regressors`).

    Returns
    -------
    xr.Dataset, or ``(composite, per_window)`` when ``keep_windows``. See the module docstring
    for the variables.

    Examples
    --------
    >>> from sysid.data.netcdf import read_campaign
    >>> from sysid.data.campaign import maneuvers
    >>> tree = read_campaign("campaign.nc")
    >>> fr = frequency_response(maneuvers(tree, "sweep_*"), inputs=["lon", "lat", "col", "ped"],
    ...                         outputs=["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"])
    >>> fr["H"].sel(output="q", input="lon")        # complex, deg/s per %, on fr.frequency
    """
    inputs = _channel_list(inputs, "input")
    outputs = _channel_list(outputs, "output")
    both = set(inputs) & set(outputs)
    if both:
        raise InputDataError(f"channels {sorted(both)} are both inputs and outputs")
    if not isinstance(records, (xr.Dataset, Mapping)):
        records = list(records)   # read twice below (channels, then signals)
    transient, transient_choice = resolve_transient_states(
        records, transient_states, inputs=inputs, conditioned=conditioned)
    if transient and not conditioned:
        raise InputDataError("transient_states need the conditioned (MIMO) estimate: the "
                             "transient terms are extra inputs of the conditioning")
    if set(transient) & set(inputs):
        raise InputDataError(f"channels {sorted(set(transient) & set(inputs))} are both "
                             "inputs and transient states")
    prog = _progress(progress)
    with prog.stage("frequency response: checking records"):
        extra = [c for c in transient if c not in outputs]
        signals = _spectra.perturbations(records, inputs + outputs + extra, inputs)
        hold = records_input_hold(records)
    dt = signals[0].attrs["dt"]
    durations = [s.sizes["time"] * dt for s in signals]
    if windows is None:
        hi = omega_max
        if hi is None and frequencies is not None:
            hi = float(np.max(frequencies))
        if hi is None:
            hi = 2.0 * math.pi / (SAMPLES_PER_PERIOD_AT_OMEGA_MAX * dt)
        windows = _composite.default_windows(durations, hi, n_windows, dt=dt)
    windows = sorted(round(round(T / dt) * dt, 9) for T in windows)
    if len(set(windows)) != len(windows):
        raise InputDataError(f"window lengths coincide after rounding to samples: {windows}")
    for T in windows:
        _spectra.check_window(signals, T, overlap)
    grid = _frequency_grid(frequencies, omega_min, omega_max, n_frequencies, windows, dt)

    with prog.stage(f"frequency response: spectra of {len(windows)} windows "
                    f"({', '.join(f'{T:g}' for T in windows)} s), {grid.size} frequencies"):
        spec = _spectra.spectra(signals, inputs, outputs, windows, grid, overlap,
                                transient=transient)
    with prog.stage("frequency response: conditioning" if conditioned
                    else "frequency response: single-input estimates"):
        controls = {"input": inputs, "input_j": inputs}
        siso = _conditioning.siso_response(spec.sel(controls), C_eps=C_eps)
        if conditioned:
            per_window = _conditioning.conditioned_response(
                spec, C_eps=C_eps, collinear_threshold=collinear_threshold, method=method,
                collinear_inputs=inputs)
            # the transient regressors are conditioned on, not reported
            per_window = per_window.sel({d: inputs for d in controls if d in per_window.dims})
            if transient:
                # Every regressor beside the primary input costs a degree of freedom: the
                # transient terms and the m - 1 other inputs (Bendat & Piersol: n_d - q for
                # q conditioning inputs; docs/methods.md).
                per_window = charge_regressors(per_window, len(transient) + len(inputs) - 1,
                                               C_eps=C_eps)
        else:
            per_window = siso
    with prog.stage("frequency response: composite windowing"):
        result, weight = _assemble(per_window, siso, conditioned, coherence_weight)
    if hold == "zero_order":  # the sampling's half-sample delay is not the system's
        Z = xr.DataArray(zero_order_hold(result["frequency"].values, dt), dims="frequency",
                         coords={"frequency": result["frequency"]})
        for ds in (result, per_window):
            ds["H"] = (ds["H"] / Z).assign_attrs(ds["H"].attrs)
    collinear_note = _collinear_note(result, per_window, collinear_threshold)
    if collinear_note and bool(result["collinear"].all()):
        raise InputDataError(f"{collinear_note}: no conditioned response exists at any "
                             "frequency; excite the inputs independently or leave one of "
                             "them out of the inputs")
    if collinear_note:
        prog.message(f"[sysid] warning: {collinear_note}; H is NaN there")
    attrs = {
        "overlap": overlap, "C_eps": C_eps, "windows": np.asarray(windows),
        "records": [s.attrs["name"] for s in signals], "inputs": inputs, "outputs": outputs,
        "conditioned": bool(conditioned), "collinear_threshold": collinear_threshold,
        "conditioning_method": method if conditioned else "", "sysid_version": __version__,
        "coherence_weight": coherence_weight,
        "sample_interval": dt, "transient_states": list(transient),
        "transient_choice": transient_choice,
        "input_hold": hold or "none",
    }
    result.attrs = dict(attrs)
    result.attrs["collinear_note"] = collinear_note
    _units(result, inputs, outputs)
    if not keep_windows:
        return result
    usable = _composite.trusted(per_window["frequency"], per_window["window"])
    per_window = per_window.assign(trusted=usable, weight=weight).transpose(
        "output", "input", "input_j", "frequency", "window")
    per_window.attrs = dict(attrs)
    _units(per_window, inputs, outputs)
    return result, per_window


def charge_regressors(per_window: xr.Dataset, n_extra: int, *,
                      C_eps: float = _spectra.DEFAULT_C_EPS) -> xr.Dataset:
    """Charge the conditioned pair spectra for ``n_extra`` regressors beside the primary
    input (the other inputs and the transient terms): each costs a degree of freedom of the
    window's averages.

    Conditioning on ``n_extra`` regressors fits away a share of the output's residual that
    grows with ``n_extra / n_d`` even where they explain nothing, so the residual spectrum,
    and with it the partial coherence, would look better than it is (most in the longest
    window, with the fewest averages). As a least-squares residual
    variance is divided by its degrees of freedom, the residual part of ``Gyy_pair`` is scaled
    by ``n_d / (n_d - n_extra)`` (``n_d = T_r / T``):

        Gyy' = |Gxy|^2 / Gxx + (Gyy - |Gxy|^2 / Gxx) n_d / (n_d - n_extra)

    and the partial coherence (Eq. 11) and random error (Eq. 13, with ``n_d - n_extra``
    averages) follow from it; ``H`` is unchanged. A window left with fewer than
    :data:`sysid.spectral.spectra.MIN_AVERAGES` averages gets an infinite random error, so
    compositing does not use it (docs/methods.md, "Leakage-free conditioning").
    """
    n_d = per_window["n_d"]
    n_eff = n_d - n_extra
    factor = (n_d / n_eff).where(n_eff >= _spectra.MIN_AVERAGES)
    with np.errstate(invalid="ignore", divide="ignore"):
        explained = abs(per_window["Gxy_pair"]) ** 2 / per_window["Gxx_pair"]
        gyy = explained + (per_window["Gyy_pair"] - explained).clip(min=0.0) * factor
        g2 = (explained / gyy).clip(0.0, 1.0)
    eps = _conditioning.random_error(g2, n_eff.where(n_eff >= _spectra.MIN_AVERAGES), C_eps)
    out = per_window.copy()
    out["Gyy_pair"] = gyy.where(np.isfinite(gyy), per_window["Gyy_pair"]).assign_attrs(
        per_window["Gyy_pair"].attrs)
    out["partial_coherence"] = g2.fillna(0.0).assign_attrs(per_window["partial_coherence"].attrs)
    out["random_error"] = eps.fillna(np.inf).assign_attrs(per_window["random_error"].attrs)
    return out


def _assemble(per_window: xr.Dataset, siso: xr.Dataset, conditioned: bool,
              coherence_weight: float):
    """Composite results from the per-window ones (see module docstring), and the Eq. 14
    weights (output, input, frequency, window)."""
    main = _composite.composite_response(per_window, coherence_weight=coherence_weight)
    out = xr.Dataset({name: main[name] for name in
                      ("H", "partial_coherence", "random_error",
                       "Gxx_pair", "Gyy_pair", "Gxy_pair")})
    if conditioned:
        ordinary = _composite.composite_response(siso, coherence_weight=coherence_weight)
        out["coherence"] = ordinary["partial_coherence"]
    else:
        out["coherence"] = main["partial_coherence"]
    usable = _composite.trusted(per_window["frequency"], per_window["window"])
    for name in ("Gxx", "Gyy", "Gxy"):
        out[name] = _composite.average_windows(per_window[name], per_window["n_d"], usable)
    out["cross_coherence"] = _conditioning.cross_coherence(out["Gxx"])
    out["input_coherence"] = _conditioning.input_coherence(out["Gxx"])
    out["multiple_coherence"] = _conditioning.conditioned_pair_spectra(
        out["Gxx"], out["Gyy"], out["Gxy"])["multiple_coherence"]
    out["collinear"] = (main["weight"].sum("window") == 0).all(("output", "input"))
    out["H"] = out["H"].where(~out["collinear"])
    out["n_d"] = per_window["n_d"].rename(window="window_length")
    for name in ("Gxx", "Gyy", "Gxy", "cross_coherence", "input_coherence",
                 "multiple_coherence"):
        out[name].attrs.update(per_window[name].attrs)
    out["H"].attrs.update(per_window["H"].attrs)
    out["coherence"].attrs.update(long_name="composite ordinary coherence (Eq. 7, 16)",
                                  units="1")
    out["partial_coherence"].attrs.update(
        long_name=("composite partial coherence (Eq. 11, 16)" if conditioned
                   else "composite ordinary coherence (Eq. 7, 16)"), units="1")
    out["random_error"].attrs.update(long_name="composite normalised random error (Eq. 13, 14)",
                                     units="1")
    out["collinear"].attrs.update(long_name="no usable window: inputs nearly collinear")
    return out, main["weight"]


def _collinear_note(result: xr.Dataset, per_window: xr.Dataset, threshold: float) -> str:
    """Which inputs are collinear and where (``""`` when no frequency is flagged): those
    that make up the near-null direction of the normalised input spectral matrix (weight of
    at least 0.2 in its last singular vector, on average over the flagged frequencies and
    the windows), e.g. ``lon, lat`` for ``lat = 2 lon``."""
    flag = np.asarray(result["collinear"].values, bool)
    if not flag.any() or "Gxx" not in per_window:
        return ""
    gxx = per_window["Gxx"].isel(frequency=np.flatnonzero(flag)).transpose(
        ..., "input", "input_j").values
    d = np.sqrt(np.abs(np.real(np.diagonal(gxx, axis1=-2, axis2=-1))))
    with np.errstate(invalid="ignore", divide="ignore"):
        gn = gxx / (d[..., :, None] * d[..., None, :])
    gn = gn[np.all(np.isfinite(gn), axis=(-2, -1))]
    inputs = [str(i) for i in per_window["input"].values]
    involved = inputs
    if gn.size:
        null = np.abs(np.linalg.svd(gn)[2][..., -1, :]).mean(axis=0)
        involved = [i for i, v in zip(inputs, null) if v >= 0.2] or inputs
    w = np.asarray(result["frequency"].values)[flag]
    return (f"inputs {', '.join(involved)} are collinear (an input's multiple coherence on "
            f"the others >= {threshold:g}) at {flag.sum()} of {flag.size} frequencies, "
            f"{w.min():.3g} .. {w.max():.3g} rad/s")


def _units(ds: xr.Dataset, inputs, outputs) -> None:
    """``units`` strings for the response and the channel coordinates (analysis units)."""
    unit = {c: CHANNELS[c].unit if c in CHANNELS else "" for c in list(inputs) + list(outputs)}
    ds["output"].attrs.update(units_per_channel=[unit[o] for o in outputs])
    ds["input"].attrs.update(units_per_channel=[unit[i] for i in inputs])
    ds["frequency"].attrs.update(units="rad/s", long_name="frequency")
    ds["H"].attrs["units"] = "output unit per input unit (see output/input units_per_channel)"


def siso_frequency_response(records, inputs: Sequence[str], outputs: Sequence[str], **kwargs):
    """Unconditioned single-input composite estimates ``H = Gxy / Gxx_ii`` of every pair,
    ignoring the other inputs (for comparison with the conditioned result); same parameters
    as :func:`frequency_response` except ``conditioned``."""
    kwargs.pop("conditioned", None)
    kwargs.pop("transient_states", None)
    return frequency_response(records, inputs, outputs, conditioned=False,
                              transient_states=(), **kwargs)
