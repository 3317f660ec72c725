"""ADS-33E-PRF bandwidth and phase delay of the attitude responses, with Level boundaries.

For an attitude response ``H(j omega)`` (theta/lon, phi/lat, psi/ped; deg per %), with its phase
``phi(omega)`` unwrapped on the branch below (docs/methods.md, "Handling qualities"):

    omega_180        phi(omega_180) = -180 deg (the first crossing above the reference with
                     the phase falling: neutral stability of a pure-gain loop)
    omega_BW,phase   phi = -135 deg: 45 deg of phase margin (the last falling crossing below
                     omega_180)
    omega_BW,gain    |H| = |H(omega_180)| + 6 dB: 6 dB of gain margin (the last crossing below
                     omega_180)
    tau_p            -(phi(2 omega_180) + 180 deg) / (57.3 * 2 omega_180)     (s)

and the governing bandwidth ADS-33E-PRF 3.3.2.1 (3.3.5.1 for yaw) prescribes: for rate
response types the lesser of ``omega_BW,gain`` and ``omega_BW,phase`` (``omega_BW,phase``
where the gain bandwidth is undefined), for attitude-command/attitude-hold response types
``omega_BW,phase``.

Phase branch: the 360-deg branch whose median phase over the data's coherent band (coherence
>= 0.6, the same band for every source) lies in (-270, 90] deg. Over the band that holds the
bandwidth an attitude response is integrator-like (-90 deg) to lagging (-180 deg and beyond);
below it a low-frequency mode (the hover's unstable pitch-roll oscillation, the outer
velocity hold) can turn the phase positive, so the phase at the band's lowest frequency alone
can pick a branch 360 deg off (it did on noise-free data coherent down to 0.08 rad/s). Only
falling crossings of -180 and -135 deg count: a rising one is no loss of phase margin.

Uncertainty from the composite random error ``eps_r`` (Eq. 13-14): the phase is uncertain by
``(180/pi) eps_r`` deg and the magnitude by ``(20/ln 10) eps_r`` dB, so a crossing of a level
moves by ``sigma_curve / |d curve / d ln omega|`` in ``ln omega``; the gain bandwidth adds the
uncertainty of its level ``|H(omega_180)| + 6 dB`` (from the magnitude and from
``omega_180``), and ``tau_p`` that of ``phi(2 omega_180)`` and of ``omega_180`` (first-order
propagation, errors at different frequencies independent).

Sources (:func:`handling_qualities`): the composite data (the measured attitude, or the rate
integrated, ``H/(j omega)``, where the attitude is not measured), the truth's full
linearisation (``/linearization_full``: rotor, inflow and actuators, the truth), its
quasi-steady reduction (``/linearization``), every identified model (``/models/<method>``) and,
when given, the truth FMU's describing function at the amplitude flown
(:func:`describing_function`: pure control sinusoids with the campaign's holds, first
harmonics, the other holds' linear share taken out), a truth where the linearisation is not
the helicopter flown; on its few frequencies only the phase bandwidth is defined.
The phase of each is unwrapped and put on the branch above, fixed over the data's coherent
band; the crossings are searched from the band's lowest frequency upwards.

Sample and hold: a campaign flown by :func:`sysid.flight_test.campaign.run_campaign` holds each
control sample over the sample interval ``dt`` and records the response at the start of the
hold, so its data carry the zero-order hold ``Z(j omega) = e^{-j omega dt/2} sinc(omega dt / 2)``
(a 5 ms delay at 100 Hz; the exact ZOH equivalent of a continuous model agrees with ``G Z`` to
four digits in bandwidth and phase delay below 20 rad/s) that belongs to the simulated test, not
to the helicopter. The assessment describes the helicopter. Since 2026-11-27 the spectral
stage divides the hold out of the responses itself (records marked ``input_hold``,
:func:`sysid.spectral.response.frequency_response`), so the data and the frequency-domain
models fitted to them are continuous and nothing more is divided here; for responses computed
before (no ``input_hold`` attribute) the known hold is divided out of the data's response
(``sample_hold``) and out of a model fitted to those responses (a frequency-domain fit,
attribute ``J_ave``, whose delays absorbed it). The truth linearisations and time-domain
models (simulated with the hold applied exactly, :func:`sysid.models.simulation.simulate`)
are continuous already. Imported data (no hold known) are left as they are.

Level boundaries (:data:`ADS33_BOUNDARIES`): hover and low speed, target acquisition and
tracking, and all other MTEs, for pitch and roll (ADS-33E-PRF 3.3.2.1) and yaw (3.3.5.1).
A point is Level 1 when it lies right of (below) the Level-1 boundary, Level 2 right of the
Level-2 boundary, else Level 3. Which corner points a public source confirms is recorded in
:data:`ADS33_CONFIRMED`; the others are an unverified transcription (docs/methods.md).

References
----------
* ADS-33E-PRF, *Aeronautical Design Standard, Performance Specification, Handling Qualities
  Requirements for Military Rotorcraft*, US Army AMCOM, 21 March 2000, 3.3.2.1, 3.3.5.1.
* Padfield, G. D., *Helicopter Flight Dynamics*, 2nd ed., Blackwell, 2007, ch. 6 (the
  ADS-33 yaw bandwidth boundaries, Fig. 6.64).
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 15 (bandwidth and phase delay from identified frequency responses).
* docs/methods.md, "Handling qualities and broken-loop margins".
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Mapping, Sequence

import numpy as np
import xarray as xr

from sysid.assess.margins import crossings, interp_log
from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.core.units import CONTROLS
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.flight_test.campaign import Campaign, Maneuver, run_campaign
from sysid.identify.frequency_domain import select_fit_data
from sysid.identify.transfer_function import RATE_OF, TRUTH_SOURCES, pair_response
from sysid.models import frequency_response
from sysid.spectral.response import zero_order_hold

__all__ = ["AXES", "RESPONSE_TYPES", "MTES", "ADS33_BOUNDARIES", "ADS33_SOURCE",
           "bandwidth_phase_delay", "boundary_bandwidth", "ads33_level", "attitude_responses",
           "handling_qualities", "sample_hold_interval", "zero_order_hold",
           "carries_sample_hold", "ADS33_CONFIRMED", "OMEGA_REF_DEFAULT", "MODEL_GRID",
           "describing_function", "describing_grid", "sweep_amplitude", "DF_SETTLE_CYCLES",
           "DF_CYCLES", "DF_SPAN"]

#: Attitude response of each axis: (attitude, control).
AXES = {"pitch": ("theta", "lon"), "roll": ("phi", "lat"), "yaw": ("psi", "ped")}
#: ADS-33E-PRF response types whose governing bandwidth differs (module docstring).
RESPONSE_TYPES = ("rate", "attitude")
#: Mission-task-element classes of the hover and low-speed charts.
MTES = ("tracking", "other")
#: Start (rad/s) of the crossing search and of the band fixing the phase branch when there are
#: no data to take the coherent band from (the band then runs to the top of the grid).
OMEGA_REF_DEFAULT = 1.0
#: Grid of the model responses (rad/s): 2000 log-spaced points over 0.05-100 rad/s.
MODEL_GRID = (0.05, 100.0, 2000)
#: Describing functions (:func:`describing_function`): periods discarded while the closed loop
#: settles after the sine starts, and whole periods analysed.
DF_SETTLE_CYCLES = 2
DF_CYCLES = 3
#: Default describing-function grid (:func:`describing_grid`) around a bandwidth omega_BW:
#: ``n`` log-spaced points from ``lo omega_BW`` to ``hi omega_BW``, ``(lo, hi, n)``.
DF_SPAN = (0.65, 1.65, 7)
#: Degrees per radian as ADS-33E-PRF writes the phase-delay formula.
DEG_PER_RAD = 57.3

#: Where the Level boundaries come from.
ADS33_SOURCE = ("ADS-33E-PRF (21 March 2000), hover and low speed: the bandwidth/phase-delay "
                "figures of 3.3.2.1 (pitch, roll) and 3.3.5.1 (yaw); only the yaw Level 1 "
                "minimum bandwidth for target acquisition and tracking (3.5 rad/s) is "
                "confirmed by a public source (Padfield 2007, Fig. 6.64); every other corner "
                "point is an unverified transcription (docs/methods.md)")

#: Level boundaries of the bandwidth (rad/s) / phase-delay (s) charts, hover and low speed:
#: ``{(axis, mte): {"L1": [(omega_BW, tau_p), ...], "L2": [...]}}``, each boundary from the
#: ``tau_p = 0`` axis upwards; beyond its last corner it continues with its last segment's
#: slope. UNVERIFIED: these corner points were transcribed without a copy of ADS-33E-PRF and
#: could not be checked against the specification's figures (no public copy or table quoting
#: them was found); the one value a public source confirms is listed in
#: :data:`ADS33_CONFIRMED`. Do not base a Level decision on the others (docs/methods.md).
ADS33_BOUNDARIES: dict[tuple[str, str], dict[str, tuple[tuple[float, float], ...]]] = {
    ("pitch", "tracking"): {"L1": ((2.0, 0.0), (2.0, 0.12), (4.0, 0.20)),
                            "L2": ((1.0, 0.0), (1.0, 0.20), (4.0, 0.30))},
    ("roll", "tracking"): {"L1": ((2.5, 0.0), (2.5, 0.12), (4.0, 0.16)),
                           "L2": ((1.5, 0.0), (1.5, 0.20), (4.0, 0.26))},
    ("yaw", "tracking"): {"L1": ((3.5, 0.0), (3.5, 0.06), (6.0, 0.12)),
                          "L2": ((2.0, 0.0), (2.0, 0.20), (6.0, 0.30))},
    ("pitch", "other"): {"L1": ((1.0, 0.0), (1.0, 0.20), (4.0, 0.30)),
                         "L2": ((0.5, 0.0), (0.5, 0.30), (4.0, 0.40))},
    ("roll", "other"): {"L1": ((1.5, 0.0), (1.5, 0.20), (4.0, 0.30)),
                        "L2": ((1.0, 0.0), (1.0, 0.30), (4.0, 0.40))},
    ("yaw", "other"): {"L1": ((2.0, 0.0), (2.0, 0.10), (6.0, 0.20)),
                       "L2": ((1.0, 0.0), (1.0, 0.20), (6.0, 0.30))},
}

#: The corner values a public source confirms: ``{(axis, mte, boundary): (omega_BW rad/s at
#: small tau_p, source)}``. Everything in :data:`ADS33_BOUNDARIES` not listed is unverified.
ADS33_CONFIRMED: dict[tuple[str, str, str], tuple[float, str]] = {
    ("yaw", "tracking", "L1"): (
        3.5, "Padfield, Helicopter Flight Dynamics, 2nd ed., 2007, ch. 6, Fig. 6.64(a) (from "
             "ADS-33): 'Level 1 boundary at 3.5 rad/s' for target acquisition and tracking, "
             "hover/low speed and forward flight"),
}

_QUANTITIES = ("omega_180", "bandwidth_phase", "bandwidth_gain", "bandwidth", "tau_p")


def _slope(omega, y) -> np.ndarray:
    """dy / d ln omega on the grid (central differences)."""
    return np.gradient(np.asarray(y, float), np.log(np.asarray(omega, float)))


def bandwidth_phase_delay(omega, H, *, coherence=None, random_error=None,
                          response_type: str = "rate",
                          omega_ref: float | None = None,
                          branch_band: tuple[float, float] | None = None) -> dict[str, float]:
    """ADS-33E-PRF bandwidth and phase delay of one attitude response (module docstring).

    Parameters
    ----------
    omega : array
        Ascending frequencies, rad/s.
    H : array, complex
        The attitude response on ``omega`` (NaN points are skipped).
    coherence, random_error : array, optional
        Coherence and normalised random error on ``omega`` (data); they give the coherence at
        each point and the ``*_std`` uncertainties (NaN without them).
    response_type : {"rate", "attitude"}
        Which bandwidth governs.
    omega_ref : float, optional
        Start of the crossing search (rad/s); default the lowest frequency.
    branch_band : (float, float), optional
        Band (rad/s) whose median phase fixes the 360-deg branch: it is put in (-270, 90]
        deg (module docstring); default from ``omega_ref`` to the top of ``omega``.

    Returns
    -------
    dict
        ``omega_180``, ``bandwidth_phase``, ``bandwidth_gain``, ``bandwidth`` (rad/s),
        ``tau_p`` (s), ``gain_180_db`` (dB), ``phase_2w180`` (deg), ``coherence_<q>`` at
        ``omega_180``, each bandwidth and ``2 omega_180`` (``coherence_tau_p``),
        ``<q>_std`` (one standard deviation), ``governing`` (``"phase"``/``"gain"``/``""``).
        NaN where a crossing is not on the grid; without a -180 deg crossing the phase
        bandwidth governs and ``omega_180``, the gain bandwidth and ``tau_p`` are NaN.

    Examples
    --------
    >>> w = np.logspace(-1, 2, 3000)
    >>> s = 1j * w
    >>> out = bandwidth_phase_delay(w, 2.0 * np.exp(-0.05 * s) / (s * (0.1 * s + 1)))
    >>> round(out["bandwidth"], 3), round(out["tau_p"], 4)
    """
    if response_type not in RESPONSE_TYPES:
        raise InputDataError(f"response_type {response_type!r}: expected one of "
                             f"{RESPONSE_TYPES}")
    omega = np.asarray(omega, float)
    H = np.asarray(H, complex)
    if omega.shape != H.shape or omega.ndim != 1:
        raise InputDataError(f"bandwidth_phase_delay: omega {omega.shape} and H {H.shape} "
                             "must be 1-D of the same length")
    nan = math.nan
    out: dict[str, float | str] = {k: nan for k in _QUANTITIES}
    out.update({f"{k}_std": nan for k in _QUANTITIES})
    out.update({f"coherence_{k}": nan for k in _QUANTITIES if k != "bandwidth"})
    out.update(gain_180_db=nan, phase_2w180=nan, governing="")
    ok = np.isfinite(H) & (omega > 0) & (np.abs(H) > 0)
    if ok.sum() < 3:
        return out
    w = omega[ok]
    Hk = H[ok]
    g2 = (np.asarray(coherence, float)[ok] if coherence is not None
          else np.full(w.shape, nan))
    eps = (np.asarray(random_error, float)[ok] if random_error is not None
           else np.full(w.shape, nan))
    ref = float(w[0]) if omega_ref is None else float(omega_ref)
    lo, hi = (ref, float(w[-1])) if branch_band is None else map(float, branch_band)
    phase = np.rad2deg(np.unwrap(np.angle(Hk)))
    in_band = (w >= lo) & (w <= hi)
    p_mid = float(np.median(phase[in_band] if in_band.any() else phase))
    phase -= 360.0 * math.ceil((p_mid - 90.0) / 360.0)  # branch: median in (-270, 90]
    gain = 20.0 * np.log10(np.abs(Hk))
    above = lambda xs: xs[xs >= ref]  # noqa: E731
    c180 = above(crossings(w, phase, -180.0, direction="down"))
    # no -180 deg on the grid (a model without rotor lag or delay): omega_180, the gain
    # bandwidth and tau_p are undefined, the phase bandwidth is the last -135 deg crossing
    w180 = float(c180[0]) if c180.size else nan
    g180 = float(interp_log(w, gain, w180))
    out.update(omega_180=w180, gain_180_db=g180)
    top = w180 if c180.size else math.inf
    below = lambda xs: xs[(xs >= ref) & (xs <= top)]  # noqa: E731
    cp = below(crossings(w, phase, -135.0, direction="down"))
    cg = below(crossings(w, gain, g180 + 6.0)) if c180.size else np.empty(0)
    bw_p = float(cp[-1]) if cp.size else nan
    bw_g = float(cg[-1]) if cg.size else nan
    w2 = 2.0 * w180
    phi2 = float(interp_log(w, phase, w2))
    tau_p = -(phi2 + 180.0) / (DEG_PER_RAD * w2)
    if response_type == "attitude" or not math.isfinite(bw_g):
        bw, governing = bw_p, "phase"
    else:
        bw, governing = (bw_g, "gain") if bw_g < bw_p or not math.isfinite(bw_p) else \
            (bw_p, "phase")
    if not math.isfinite(bw):
        governing = ""
    out.update(bandwidth_phase=bw_p, bandwidth_gain=bw_g, bandwidth=bw, tau_p=tau_p,
               phase_2w180=phi2, governing=governing)
    for key, at in (("omega_180", w180), ("bandwidth_phase", bw_p),
                    ("bandwidth_gain", bw_g), ("tau_p", w2)):
        out[f"coherence_{key}"] = float(interp_log(w, g2, at))
    # uncertainties (first order, module docstring)
    s_ph = np.rad2deg(eps)                      # deg
    s_g = (20.0 / math.log(10.0)) * eps         # dB
    dph = _slope(w, phase)
    dg = _slope(w, gain)

    def at(y, x):
        return float(interp_log(w, y, x))

    with np.errstate(divide="ignore", invalid="ignore"):
        s_ln180 = at(s_ph, w180) / abs(at(dph, w180))
        out["omega_180_std"] = w180 * s_ln180
        out["bandwidth_phase_std"] = bw_p * at(s_ph, bw_p) / abs(at(dph, bw_p))
        s_level = math.hypot(at(s_g, w180), at(dg, w180) * s_ln180)
        out["bandwidth_gain_std"] = bw_g * math.hypot(at(s_g, bw_g), s_level) / abs(at(dg, bw_g))
        c = 1.0 / (DEG_PER_RAD * w2)
        out["tau_p_std"] = math.hypot(c * at(s_ph, w2), (c * at(dph, w2) + tau_p) * s_ln180)
    out["bandwidth_std"] = (out["bandwidth_gain_std"] if governing == "gain"
                            else out["bandwidth_phase_std"] if governing == "phase" else nan)
    return out


def boundary_bandwidth(points: Sequence[tuple[float, float]], tau_p) -> np.ndarray:
    """Bandwidth (rad/s) of a Level boundary at phase delay ``tau_p`` (s): the boundary
    polyline interpolated in ``tau_p`` (negative delays count as 0), continued beyond its last
    corner with its last segment's slope."""
    pts = np.asarray(points, float)
    tau = np.maximum(np.asarray(tau_p, float), 0.0)
    w = np.interp(tau, pts[:, 1], pts[:, 0])
    (w0, t0), (w1, t1) = pts[-2], pts[-1]
    slope = (w1 - w0) / (t1 - t0) if t1 != t0 else 0.0
    return np.where(tau > pts[-1, 1], w1 + slope * (tau - t1), w)


def ads33_level(bandwidth, tau_p, *, axis: str, mte: str) -> np.ndarray:
    """ADS-33E-PRF Level (1, 2 or 3) of bandwidth/phase-delay points; 0 where either is NaN.

    ``axis`` in :data:`AXES`, ``mte`` in :data:`MTES` (hover and low speed)."""
    key = (axis, mte)
    if key not in ADS33_BOUNDARIES:
        raise InputDataError(f"no ADS-33E-PRF boundary for axis {axis!r} and MTE {mte!r} "
                             f"(axes {list(AXES)}, MTEs {list(MTES)})")
    bw = np.asarray(bandwidth, float)
    tau = np.asarray(tau_p, float)
    bounds = ADS33_BOUNDARIES[key]
    level = np.where(bw >= boundary_bandwidth(bounds["L1"], tau), 1,
                     np.where(bw >= boundary_bandwidth(bounds["L2"], tau), 2, 3))
    return np.where(np.isfinite(bw) & np.isfinite(tau), level, 0)


# --------------------------------------------------------------------------------------------
# a campaign


def carries_sample_hold(model: xr.Dataset) -> bool:
    """Whether an identified model was fitted to a campaign's frequency responses (a
    frequency-domain fit, attribute ``J_ave``), so that its delays absorbed the campaign's
    zero-order hold; a time-domain model is simulated with the hold applied exactly and is
    continuous."""
    return "J_ave" in model.attrs


def _model_grid() -> np.ndarray:
    lo, hi, n = MODEL_GRID
    return np.logspace(math.log10(lo), math.log10(hi), int(n))


def attitude_responses(data: CampaignData, *, sources: Sequence[str] | None = None,
                       coherence_min: float = COHERENCE_MIN,
                       sample_hold: float | None = None) -> dict:
    """The attitude responses of every source, per axis.

    Returns ``{axis: {"pair", "origin", "omega_ref", "omega_band", "responses": {source:
    (omega, H, coherence or None, random_error or None)}, "hold_removed": [source, ...]}}``.
    ``origin`` says whether the data's attitude was measured or integrated from the rate;
    ``omega_band`` is the data's coherent band (rad/s; None without data) and ``omega_ref`` its
    lowest frequency (:data:`OMEGA_REF_DEFAULT` without data). Sources: ``data``,
    ``linearization_full``, ``linearization`` and the ``/models`` methods, those present (or
    the ones named in ``sources``). ``sample_hold`` (s): the campaign's zero-order hold,
    divided out of the data and of the models fitted to them (:func:`carries_sample_hold`;
    module docstring); None: none.
    """
    fr = data.frequency_response()
    models: dict[str, xr.Dataset] = {}
    for name in ("linearization_full", "linearization"):
        ds = data.group(name)
        if ds is not None and "A" in ds and "B" in ds:
            models[name] = ds
    models.update({m: ds for m, ds in data.models().items() if "A" in ds and "B" in ds})
    wanted = list(sources) if sources is not None else (["data"] if fr is not None else []) \
        + list(models)
    unknown = [s for s in wanted if s != "data" and s not in models]
    if unknown or ("data" in wanted and fr is None):
        raise InputDataError(f"campaign {data.source}: sources {unknown or ['data']} not "
                             f"found (available: {(['data'] if fr is not None else []) + list(models)})")
    grid = _model_grid()
    out = {}
    for axis, (attitude, control) in AXES.items():
        entry = {"pair": f"{attitude}/{control}", "origin": "", "omega_ref": OMEGA_REF_DEFAULT,
                 "omega_band": None, "responses": {}, "hold_removed": []}
        if fr is not None:
            ds, origin = pair_response(fr, attitude, control)
            entry["origin"] = origin
            pair = (attitude, control)
            try:
                sel = select_fit_data(ds, [pair], coherence_min=coherence_min, n_points=2)
                band = sel.ranges[f"{attitude}/{control}"]
                entry["omega_ref"] = float(band[0])
                entry["omega_band"] = (float(band[0]), float(band[-1]))
            except Exception:  # noqa: BLE001 - no coherent band: keep the default reference
                pass
            if "data" in wanted:
                cvar = "partial_coherence" if "partial_coherence" in ds else "coherence"
                one = ds.sel(output=attitude, input=control)
                w = ds["frequency"].values
                H = one["H"].values
                if sample_hold:
                    H = H / zero_order_hold(w, sample_hold)
                    entry["hold_removed"].append("data")
                entry["responses"]["data"] = (
                    w, H, one[cvar].values,
                    one["random_error"].values if "random_error" in ds else None)
        for name, model in models.items():
            if name not in wanted:
                continue
            T = frequency_response(model, grid)
            outs = [str(x) for x in T["output"].values]
            if control not in [str(x) for x in T["input"].values]:
                continue
            if attitude in outs:
                H = T.sel(output=attitude, input=control).values
            elif RATE_OF[attitude] in outs:
                H = T.sel(output=RATE_OF[attitude], input=control).values / (1j * grid)
            else:
                continue
            if sample_hold and name not in TRUTH_SOURCES and carries_sample_hold(model):
                H = H / zero_order_hold(grid, sample_hold)
                entry["hold_removed"].append(name)
            entry["responses"][name] = (grid, H, None, None)
        out[axis] = entry
    return out


def _hold_removed(data: CampaignData, hold: float | None, names: Sequence[str],
                  responses: dict) -> dict:
    """``sample_hold_removed_s`` and ``sample_hold_removed_from`` of the assessment: the hold
    divided out here, or by the spectral stage (then out of the data and so out of the
    frequency-domain models fitted to them)."""
    fr = data.frequency_response()
    if not hold and fr is not None and fr.attrs.get("input_hold") == "zero_order":
        models = data.models()
        upstream = [n for n in names if n == "data"
                    or (n in models and carries_sample_hold(models[n]))]
        return {"sample_hold_removed_s": float(fr.attrs["sample_interval"]),
                "sample_hold_removed_from": ",".join(upstream)}
    return {"sample_hold_removed_s": float(hold) if hold else 0.0,
            "sample_hold_removed_from": ",".join(
                n for n in names if any(n in e["hold_removed"] for e in responses.values()))}


def sample_hold_interval(data: CampaignData) -> float | None:
    """The zero-order hold (s) still in a campaign's frequency responses: their
    ``sample_interval`` when the campaign was flown by sysid (root ``campaign_toml``) and the
    responses were computed before the spectral stage divided the hold out itself (no
    ``input_hold`` attribute: :func:`sysid.spectral.response.frequency_response`), else None
    (divided out already; imported data: unknown)."""
    fr = data.frequency_response()
    if (fr is None or not data.tree.attrs.get("campaign_toml")
            or fr.attrs.get("input_hold") == "zero_order"):
        return None
    dt = fr.attrs.get("sample_interval")
    return float(dt) if dt is not None and float(dt) > 0 else None


# --------------------------------------------------------------------------------------------
# the truth at the flown amplitude


def sweep_amplitude(maneuver: Maneuver, omega) -> np.ndarray:
    """Pilot amplitude (% of travel) of a sweep manoeuvre at instantaneous frequency ``omega``
    (rad/s): the schedule of :func:`sysid.signals.inputs.frequency_sweep`,
    ``A (f + (1 - f) x^shape)`` with ``x`` the position of ``omega`` in log frequency from
    ``omega_min`` (0) to ``full_amplitude_omega`` (1), clipped to [0, 1]."""
    m = maneuver
    w = np.asarray(omega, float)
    f, w_full = float(m.low_frequency_fraction), float(m.full_amplitude_omega)
    if w_full <= m.omega_min or f == 1.0:
        return np.full(w.shape, float(m.amplitude))
    x = np.log(np.clip(w, m.omega_min, w_full) / m.omega_min) / math.log(w_full / m.omega_min)
    return m.amplitude * (f + (1.0 - f) * x ** m.amplitude_shape)


def describing_grid(bandwidth: float) -> np.ndarray:
    """Describing-function frequencies (rad/s) around a bandwidth (rad/s): :data:`DF_SPAN`.
    The phase between them is interpolated linearly in log omega (error 0.1 % of bandwidth on
    the hover's heading response)."""
    if not (math.isfinite(bandwidth) and bandwidth > 0):
        raise InputDataError(f"describing_grid: bandwidth {bandwidth!r} rad/s: expected > 0")
    lo, hi, n = DF_SPAN
    return np.geomspace(lo * bandwidth, hi * bandwidth, int(n))


def describing_function(campaign: Campaign, *, omega, axis: str = "yaw", amplitude=None,
                        settle_cycles: int = DF_SETTLE_CYCLES, cycles: int = DF_CYCLES,
                        fmu=None, quiet: bool = True) -> xr.Dataset:
    """Describing function of the truth FMU's attitude response on one axis: its first-harmonic
    response to pure control sinusoids at the amplitude the campaign's sweep flies.

    A quasi-linear truth where the linearisation is not the helicopter flown (the hover's
    quadratic fin forces make the yaw damping grow with the yaw rate; docs/methods.md). For
    each ``omega`` the FMU flies ``A(omega) sin(omega t)`` on the axis's control with the
    campaign's holds (the excited axis's weaker hold, the same gains), in calm air, without
    sensor noise or off-axis pilot activity. After ``settle_cycles`` periods, over ``cycles``
    whole periods, ``y(t) = a + b t + c cos(omega t) + d sin(omega t)`` is fitted by least
    squares to the attitude and to every applied control (the trend takes the heading's
    drift), first harmonics ``Y = c_y - j d_y`` and ``U_c``, and

        H(omega) = (Y / Z(j omega) - sum_{c != u} G_c(j omega) U_c) / U_u     (deg per %)

    with the campaign's zero-order hold ``Z`` (:func:`zero_order_hold`) divided out, as from
    the data, and the share of the other holds' controls taken out through the full
    linearisation's ``G_c`` (they move at omega too, 9-19 % of the heading's harmonic in
    hover; the data's conditioning on every control does the same). At small amplitude it
    is the linearisation's response (tests/test_handling_qualities.py).

    Parameters
    ----------
    campaign : Campaign
        Flight condition, sample rate, holds and the sweep whose amplitude is flown.
    omega : array
        Frequencies, rad/s (ascending).
    axis : str
        One of :data:`AXES`.
    amplitude : float or array, optional
        Pilot amplitude (% of travel) per frequency; default the campaign's first sweep on
        the axis's control at ``omega`` (:func:`sweep_amplitude`).
    settle_cycles, cycles : int
        Periods discarded while the closed loop settles, periods analysed.

    Returns
    -------
    xr.Dataset
        On ``frequency`` (rad/s): ``H`` (complex, deg/%), ``pilot_amplitude``,
        ``control_amplitude`` (%), ``attitude_amplitude`` (deg), ``rate_amplitude`` (deg/s,
        first harmonic of the body rate), ``distortion`` (rms residual of the attitude fit
        over its first-harmonic amplitude) and ``off_axis_share`` (``|sum G_c U_c|`` over
        ``|Y / Z|``). Attributes ``axis``, ``pair``, ``sample_hold_removed_s``, ``campaign``,
        ``settle_cycles``, ``cycles``.

    Examples
    --------
    >>> df = describing_function(default_campaign(0.0), omega=np.geomspace(0.2, 0.5, 7))
    >>> hq = handling_qualities(data, describing=[df])   # source "describing_function"
    """
    if axis not in AXES:
        raise InputDataError(f"describing_function: axis {axis!r}: expected one of {list(AXES)}")
    attitude, control = AXES[axis]
    w = np.atleast_1d(np.asarray(omega, float))
    if w.ndim != 1 or not np.all(w > 0) or np.any(np.diff(w) <= 0):
        raise InputDataError(f"describing_function: omega must be ascending and > 0 rad/s, got "
                             f"{w}")
    if int(settle_cycles) < 0 or int(cycles) < 1:
        raise InputDataError(f"describing_function: need settle_cycles >= 0 and cycles >= 1, "
                             f"got {settle_cycles} and {cycles}")
    if amplitude is None:
        sweeps = [m for m in campaign.maneuvers if m.kind == "sweep" and m.axis == control]
        if not sweeps:
            raise InputDataError(f"describing_function: campaign {campaign.name!r} has no "
                                 f"sweep on {control!r} to take the amplitude from; pass "
                                 "amplitude=")
        pilot = sweep_amplitude(sweeps[0], w)
    else:
        pilot = np.broadcast_to(np.asarray(amplitude, float), w.shape).copy()
    if not np.all(pilot > 0):
        raise InputDataError(f"describing_function: amplitudes must be > 0 %, got {pilot}")
    periods = 2.0 * math.pi / w
    lead_in = 1.0
    flown = dataclasses.replace(
        campaign, noise={}, turbulence=0.0,
        stabilisation=dataclasses.replace(campaign.stabilisation, secondary_perturbation=0.0),
        maneuvers=[Maneuver(f"sine_{control}_{k}", "sine", control, amplitude=float(a),
                            omega_min=float(x), omega_max=float(x) * 1.001,
                            duration=(int(settle_cycles) + int(cycles)) * float(T),
                            lead_in=lead_in, lead_out=0.5)
                   for k, (x, a, T) in enumerate(zip(w, pilot, periods))])
    tree = run_campaign(flown, fmu=fmu, quiet=quiet)
    dt = 1.0 / flown.sample_rate
    rate = RATE_OF[attitude]
    linear = tree["linearization_full"].to_dataset()
    out = {k: np.full(w.shape, np.nan) for k in ("control_amplitude", "attitude_amplitude",
                                                  "rate_amplitude", "distortion",
                                                  "off_axis_share")}
    H = np.full(w.shape, np.nan + 0j)
    G = frequency_response(linear, w)  # the full linearisation, for the other holds' share
    for k, (x, T, m) in enumerate(zip(w, periods, flown.maneuvers)):
        ds = tree[f"maneuvers/{m.name}"].to_dataset()
        t = ds["time"].values - lead_in
        keep = (t >= settle_cycles * T - 1e-9) & (t < (settle_cycles + cycles) * T - 1e-9)
        tk = t[keep]
        basis = np.column_stack([np.ones_like(tk), tk - tk.mean(), np.cos(x * tk),
                                 np.sin(x * tk)])
        first = {}
        for name in (attitude, rate) + CONTROLS:
            y = ds[name].values[keep]
            coef, *_ = np.linalg.lstsq(basis, y, rcond=None)
            first[name] = complex(coef[2], -coef[3])
            if name == attitude:
                resid = y - basis @ coef
                out["distortion"][k] = np.sqrt(np.mean(resid**2)) / abs(first[name])
        # the other holds move the other controls at omega too: their linear share of the
        # attitude is taken out (the data's conditioning on every control does the same)
        others = sum(complex(G.sel(output=attitude, input=c).values[k]) * first[c]
                     for c in CONTROLS if c != control)
        out["off_axis_share"][k] = abs(others) / abs(first[attitude] / zero_order_hold(x, dt))
        H[k] = (first[attitude] / zero_order_hold(x, dt) - others) / first[control]
        out["control_amplitude"][k] = abs(first[control])
        out["attitude_amplitude"][k] = abs(first[attitude])
        out["rate_amplitude"][k] = abs(first[rate])
    units = {"control_amplitude": "%", "attitude_amplitude": "deg", "rate_amplitude": "deg/s",
             "distortion": "1", "off_axis_share": "1"}
    result = xr.Dataset(
        {"H": ("frequency", H, {"units": "deg/%", "long_name": f"describing function "
                                                              f"{attitude}/{control}"}),
         "pilot_amplitude": ("frequency", pilot, {"units": "%"}),
         **{k: ("frequency", v, {"units": units[k]}) for k, v in out.items()}},
        coords={"frequency": ("frequency", w, {"units": "rad/s"})},
        attrs={"axis": axis, "pair": f"{attitude}/{control}",
               "sample_hold_removed_s": float(dt), "campaign": flown.name,
               "settle_cycles": int(settle_cycles), "cycles": int(cycles)})
    return result


def handling_qualities(data: CampaignData, *, response_type: str | Mapping[str, str] = "rate",
                       sources: Sequence[str] | None = None,
                       sample_hold: float | str | None = "auto",
                       coherence_min: float = COHERENCE_MIN,
                       describing: Sequence[xr.Dataset] = (), quiet: bool = True,
                       progress: Progress | None = None) -> xr.Dataset:
    """ADS-33E-PRF bandwidth, phase delay and Level of the pitch, roll and yaw attitude
    responses of a campaign's data, truth linearisations and identified models.

    Parameters
    ----------
    data : CampaignData
        A campaign with ``/frequency_response`` and/or ``/linearization_full``,
        ``/linearization``, ``/models/<method>``.
    response_type : str or mapping
        ``"rate"`` (default: the bare airframe) or ``"attitude"`` (ACAH), or per axis
        (``{"pitch": "attitude", ...}``).
    sources : sequence of str, optional
        Restrict to these sources (``data``, ``linearization_full``, ``linearization``,
        model methods).
    coherence_min : float
        Coherence of the data's band, which fixes the phase branch and whose lowest
        frequency starts the crossing search (default 0.6).
    sample_hold : float, "auto" or None
        The campaign's zero-order hold (s), divided out of the data and of the models fitted
        to them so that every source describes the continuous helicopter (module
        docstring); "auto": :func:`sample_hold_interval`; None: none.
    describing : sequence of xr.Dataset
        Describing functions of the truth (:func:`describing_function`, one axis each),
        assessed as the source ``describing_function``: the truth at the amplitude flown.

    Returns
    -------
    xr.Dataset
        dims ``axis`` (pitch, roll, yaw; coordinate ``pair``) and ``source``; variables
        ``omega_180``, ``bandwidth_phase``, ``bandwidth_gain``, ``bandwidth`` (rad/s),
        ``tau_p`` (s), each with ``<name>_std``; ``coherence_omega_180``,
        ``coherence_bandwidth_phase``, ``coherence_bandwidth_gain``, ``coherence_tau_p`` (the
        coherence at ``2 omega_180``; NaN for models), ``gain_180_db``, ``phase_2w180``,
        ``governing`` (str), ``level_tracking``, ``level_other`` (1-3; 0 undefined),
        ``response_type`` and ``origin`` (axis) and ``omega_ref`` (axis, rad/s). Attributes
        ``boundaries`` (:data:`ADS33_SOURCE`), ``coherence_min``, ``sample_hold_removed_s``
        (the hold divided out of the data and the frequency-domain models; 0: none) and
        ``sample_hold_removed_from`` (comma-separated sources).

    Examples
    --------
    >>> hq = handling_qualities(CampaignData.read("campaign.nc"))
    >>> hq["bandwidth"].sel(source=["data", "linearization_full"]).to_pandas()
    """
    progress = progress or Progress(quiet=quiet)
    types = ({a: response_type for a in AXES} if isinstance(response_type, str)
             else {a: response_type.get(a, "rate") for a in AXES})
    bad = {a: t for a, t in types.items() if t not in RESPONSE_TYPES}
    if bad:
        raise InputDataError(f"response types {bad}: expected one of {RESPONSE_TYPES}")
    hold = sample_hold_interval(data) if sample_hold == "auto" else sample_hold
    responses = attitude_responses(data, sources=sources, coherence_min=coherence_min,
                                   sample_hold=hold)
    for df in describing:
        axis = df.attrs.get("axis")
        if axis not in AXES or "H" not in df:
            raise InputDataError(f"describing function for axis {axis!r}: expected a "
                                 f"describing_function() result on one of {list(AXES)}")
        responses[axis]["responses"]["describing_function"] = (
            df["frequency"].values, df["H"].values, None, None)
        responses[axis]["hold_removed"].append("describing_function")
    names: list[str] = []
    for entry in responses.values():
        names += [n for n in entry["responses"] if n not in names]
    if not names:
        raise InputDataError(f"campaign {data.source}: no frequency response, linearisation "
                             "or model to assess")
    axes = list(AXES)
    numeric = None
    strings = {"governing": np.full((len(axes), len(names)), "", dtype=object)}
    for a, axis in enumerate(axes):
        entry = responses[axis]
        for k, name in enumerate(names):
            if name not in entry["responses"]:
                continue
            w, H, g2, eps = entry["responses"][name]
            res = bandwidth_phase_delay(w, H, coherence=g2, random_error=eps,
                                        response_type=types[axis], omega_ref=entry["omega_ref"],
                                        branch_band=entry["omega_band"])
            if numeric is None:
                numeric = {key: np.full((len(axes), len(names)), np.nan)
                           for key, v in res.items() if not isinstance(v, str)}
            for key in numeric:
                numeric[key][a, k] = res[key]
            strings["governing"][a, k] = res["governing"]
            progress.message(f"[sysid] handling qualities: {axis} ({entry['pair']}) {name}: "
                             f"omega_BW {res['bandwidth']:.3g} rad/s, tau_p "
                             f"{res['tau_p']:.3g} s")
    if numeric is None:
        raise InputDataError(f"campaign {data.source}: no attitude response for any axis")
    units = {"tau_p": "s", "tau_p_std": "s", "gain_180_db": "dB", "phase_2w180": "deg"}
    ds = xr.Dataset(coords={"axis": axes, "source": names,
                            "pair": ("axis", [responses[a]["pair"] for a in axes])})
    for key, v in numeric.items():
        unit = units.get(key, "1" if key.startswith("coherence") else "rad/s")
        ds[key] = (("axis", "source"), v, {"units": unit})
    ds["governing"] = (("axis", "source"), strings["governing"].astype(str))
    for mte in MTES:
        ds[f"level_{mte}"] = (("axis", "source"), np.stack(
            [ads33_level(ds["bandwidth"].values[a], ds["tau_p"].values[a], axis=axis, mte=mte)
             for a, axis in enumerate(axes)]).astype(int),
            {"long_name": f"ADS-33E-PRF Level, hover and low speed, "
                          f"{'target acquisition and tracking' if mte == 'tracking' else 'all other MTEs'}"
                          " (0: undefined)"})
    ds["response_type"] = ("axis", [types[a] for a in axes])
    ds["origin"] = ("axis", [responses[a]["origin"] for a in axes])
    ds["omega_ref"] = ("axis", [responses[a]["omega_ref"] for a in axes], {"units": "rad/s"})
    ds.attrs = {"boundaries": ADS33_SOURCE, "coherence_min": float(coherence_min),
                "phase_delay": "tau_p = -(phase(2 omega_180) + 180 deg) / "
                               "(57.3 * 2 omega_180)",
                "uncertainty": "one standard deviation from the composite random error",
                **_hold_removed(data, hold, names, responses)}
    return ds
