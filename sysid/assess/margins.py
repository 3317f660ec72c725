"""Broken-loop utilities: crossover, gain and phase margins of a loop transfer function.

A loop ``L(j omega)`` (negative feedback: the closed loop is ``L / (1 + L)``) has

    gain crossover  omega_c :  |L(j omega_c)| = 1,       phase margin  PM = 180 + angle L(j omega_c)
    phase crossover omega_p :  angle L(j omega_p) = -180, gain margin   GM = 1 / |L(j omega_p)|

(deg; GM also in dB, ``-20 log10 |L(j omega_p)|``). The crossings are interpolated linearly
in log omega on the frequency data (:func:`crossings`; the phase unwrapped, every crossing of
-180 deg + k 360 deg a phase crossover), which carry any delay exactly, where a state-space
form would need a Pade approximant. (:func:`control.stability_margins` on the same data gives
the same numbers but spends about 0.7 s per loop evaluating its spline point by point.)

The campaign's stabilisation loops (:mod:`sysid.flight_test.campaign`: attitude holds on the
cyclic and pedal, a vertical-speed hold on the collective, designed on the quasi-steady
linearisation) are broken one at a time at their control, with the other holds closed, on the
truth's full linearisation (rotor, inflow and actuator states):

    L_c(s) = -K_c (sI - A - B_o K_o)^-1 B_c

with ``delta = K x`` the hold law linearised about trim (:func:`sysid.flight_test.campaign.hold_gains`,
which differentiates the very law flown), ``K_c`` its row for control ``c`` and ``B_o K_o`` the
other loops. One configuration per excited axis, as the campaign flies them (the excited
axis keeps a weaker hold).

The same closed loop replays a campaign (:func:`linear_replay`): each manoeuvre's pilot
command ``u_p = u - K (y - y_trim)`` (recorded control minus the linearised hold law on the
recorded outputs) drives the linear model with the holds closed, sampled as the campaign was
flown (zero-order hold, response recorded at the start of each hold, exact discretisation):

    x[k+1] = Phi x[k] + Gamma (u_p[k] + K x[k]),   y[k] = C x[k] + D u[k]

Data that are exactly linear, with the campaign's inputs, holds and sampling, tell an error of
the spectral and handling-qualities methods from the truth's departure from its linearisation.

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 15 (broken-loop response, crossover frequency and stability margins).
* docs/methods.md, "Handling qualities and broken-loop margins".
"""

from __future__ import annotations

import math
import tomllib

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.data.campaign import CampaignData
from sysid.flight_test.campaign import MEASUREMENTS, Campaign, design_loops, hold_gains
from sysid.models import model_matrices
from sysid.models.simulation import discretize

__all__ = ["crossings", "interp_log", "loop_margins", "broken_loop_response", "hold_margins",
           "flown_campaign", "linear_replay", "MARGIN_GRID"]

#: Frequency grid (rad/s) of the hold loops' broken-loop responses: 4000 log-spaced points
#: from 0.01 to 200 rad/s (the holds cross over at 0.3-1 rad/s; the rotor modes end below
#: 200 rad/s). Dense enough that interpolated crossings are exact to well under 0.1 %.
MARGIN_GRID = (0.01, 200.0, 4000)


def crossings(omega, y, level: float, *, direction: str = "any") -> np.ndarray:
    """Frequencies (rad/s) where ``y`` crosses ``level``, interpolated linearly in log omega.

    ``omega`` ascending and positive, ``y`` the same shape (NaN points break the curve).
    ``direction``: ``"any"``, ``"down"`` (``y`` falling through the level with rising
    frequency) or ``"up"``. Returns the crossings in ascending order (empty when none); a
    sample exactly on the level counts once.
    """
    if direction not in ("any", "down", "up"):
        raise InputDataError(f"crossings: direction {direction!r}: expected 'any', 'down' "
                             "or 'up'")
    w = np.asarray(omega, float)
    d = np.asarray(y, float) - level
    a, b = d[:-1], d[1:]
    ok = np.isfinite(a) & np.isfinite(b)
    up = ((a < 0) & (b >= 0)) | ((a == 0) & (b > 0))
    down = ((a > 0) & (b <= 0)) | ((a == 0) & (b < 0))
    hit = ok & {"any": up | down, "down": down, "up": up}[direction]
    k = np.flatnonzero(hit)
    with np.errstate(invalid="ignore", divide="ignore"):
        t = np.where(b[k] != a[k], -a[k] / (b[k] - a[k]), 0.0)
    lw = np.log(w)
    return np.exp(lw[k] + t * (lw[k + 1] - lw[k]))


def interp_log(omega, y, at) -> np.ndarray:
    """``y`` interpolated linearly in log omega at ``at`` (rad/s); NaN outside the grid."""
    w = np.asarray(omega, float)
    at = np.asarray(at, float)
    out = np.interp(np.log(np.clip(at, 1e-300, None)), np.log(w), np.asarray(y, float),
                    left=np.nan, right=np.nan)
    return np.where(np.isfinite(at), out, np.nan)


def loop_margins(L, omega=None) -> dict[str, float]:
    """Crossover and margins of a loop's frequency response (negative feedback).

    With several crossings (a loop around an unstable airframe is conditionally stable) the
    crossover is the *highest* gain crossover (the loop's bandwidth) and the phase margin is
    taken there; the gain margin is the smallest gain increase to instability (phase
    crossovers above the crossover) and ``gain_margin_low_db`` the smallest gain *reduction*
    (phase crossovers below it, negative dB).

    Parameters
    ----------
    L : array or xr.DataArray, complex
        ``L(j omega)`` on an ascending grid; a DataArray brings its ``frequency`` coordinate.
    omega : array, optional
        rad/s (required for a plain array).

    Returns
    -------
    dict
        ``gain_crossover`` (rad/s), ``phase_margin`` (deg), ``phase_crossover`` (rad/s, of the
        upper gain margin), ``gain_margin`` (ratio) and ``gain_margin_db``,
        ``gain_margin_low_db`` and ``phase_crossover_low`` (rad/s), ``stability_margin`` (the
        smallest distance of the Nyquist curve from -1). NaN (gain margins: inf) where the
        curve has no such crossing on the grid.

    Examples
    --------
    >>> w = np.logspace(-2, 3, 2000)
    >>> s = 1j * w
    >>> m = loop_margins(2.0 * np.exp(-0.05 * s) / (s * (0.2 * s + 1)), w)
    >>> round(m["phase_margin"], 1), round(m["gain_margin_db"], 1)
    (64.1, 20.3)
    """
    if isinstance(L, xr.DataArray):
        if omega is None:
            omega = L["frequency"].values
        L = L.values
    if omega is None:
        raise InputDataError("loop_margins: give omega (rad/s) with a plain array")
    L = np.asarray(L, complex)
    omega = np.asarray(omega, float)
    if L.shape != omega.shape or L.ndim != 1:
        raise InputDataError(f"loop_margins: L has shape {L.shape}, omega {omega.shape}; "
                             "expected two 1-D arrays of the same length")
    ok = np.isfinite(L) & (omega > 0) & (np.abs(L) > 0)
    if ok.sum() < 2:
        raise InputDataError("loop_margins: fewer than 2 finite points of the loop response")
    w, L = omega[ok], L[ok]
    phase = np.rad2deg(np.unwrap(np.angle(L)))
    gain_db = 20.0 * np.log10(np.abs(L))
    # gain crossovers |L| = 1 and the phase margin there, wrapped to [-180, 180)
    wgc = crossings(w, gain_db, 0.0)
    pm = np.mod(interp_log(w, phase, wgc) + 360.0, 360.0) - 180.0
    # phase crossovers: every crossing of -180 deg + k 360 deg, the gain margin 1/|L| there
    turns = (phase + 180.0) / 360.0
    levels = range(math.floor(np.nanmin(turns)), math.ceil(np.nanmax(turns)) + 1)
    wpc = np.sort(np.concatenate([crossings(w, phase, -180.0 + 360.0 * k) for k in levels]))
    gm_db = -interp_log(w, gain_db, wpc)
    out = {"gain_crossover": math.nan, "phase_margin": math.nan,
           "phase_crossover": math.nan, "gain_margin": math.inf, "gain_margin_db": math.inf,
           "phase_crossover_low": math.nan, "gain_margin_low_db": -math.inf,
           "stability_margin": float(np.min(np.abs(1.0 + L)))}
    if wgc.size:
        k = int(np.argmax(wgc))
        out["gain_crossover"], out["phase_margin"] = float(wgc[k]), float(pm[k])
    wc = out["gain_crossover"] if math.isfinite(out["gain_crossover"]) else 0.0
    upper = np.flatnonzero(wpc > wc)
    lower = np.flatnonzero(wpc <= wc)
    if upper.size:
        k = upper[np.argmin(gm_db[upper])]
        out.update(phase_crossover=float(wpc[k]), gain_margin=float(10.0 ** (gm_db[k] / 20.0)),
                   gain_margin_db=float(gm_db[k]))
    if lower.size:
        k = lower[np.argmax(gm_db[lower])]
        out.update(phase_crossover_low=float(wpc[k]), gain_margin_low_db=float(gm_db[k]))
    return out


def broken_loop_response(A, B, K, control: int, omega) -> np.ndarray:
    """``L_c(j omega) = -K_c (j omega I - A - B_o K_o)^-1 B_c``: loop ``control`` broken at
    its input, the others closed (``u = K x``; module docstring). Shapes ``A (n, n)``,
    ``B (n, m)``, ``K (m, n)``; returns ``(n_omega,)`` complex."""
    A, B, K = (np.asarray(x, float) for x in (A, B, K))
    others = [j for j in range(B.shape[1]) if j != control]
    A_o = A + B[:, others] @ K[others]
    s = 1j * np.asarray(omega, float)
    M = s[:, None, None] * np.eye(A.shape[0]) - A_o
    X = np.linalg.solve(M, np.broadcast_to(B[:, control], (s.size, A.shape[0]))[..., None])
    return -(X[..., 0] @ K[control])


def flown_campaign(data: CampaignData) -> Campaign:
    """The :class:`Campaign` a campaign file was flown with (root attribute ``campaign_toml``);
    imported data (none) are refused."""
    text = data.tree.attrs.get("campaign_toml")
    if not text:
        raise InputDataError(f"campaign {data.source}: no 'campaign_toml' root attribute, so "
                             "the holds that were flown are unknown (imported data has none)")
    return Campaign.from_dict(tomllib.loads(str(text)), where=f"{data.source}: campaign_toml")


def _loop_parts(data: CampaignData, model: str):
    """``/linearization`` (the holds' design model), the plant ``/<model>``, ``/trim``, the
    plant's ``(A, B, C, D, tau)`` with the inputs in :data:`CONTROLS` order, and the columns
    of the 6-DoF states among its states; errors name the group or channel missing."""
    lin, plant, trim = data.quasi_steady(), data.group(model), data.group("trim")
    for name, ds in (("linearization", lin), (model, plant), ("trim", trim)):
        if ds is None:
            raise InputDataError(f"campaign {data.source}: no /{name} group (written by the "
                                 "flight-test stage)")
    A, B, C, D, tau = model_matrices(plant)
    states = [str(s) for s in plant["A"].state.values]
    inputs = [str(s) for s in plant["B"].input.values]
    absent = [s for s in STATES_6DOF if s not in states] + [c for c in CONTROLS
                                                            if c not in inputs]
    if absent:
        raise InputDataError(f"campaign {data.source}: /{model} lacks {absent}")
    order = [inputs.index(c) for c in CONTROLS]
    return (lin, plant, trim, (A, B[:, order], C, D[:, order], tau),
            [states.index(s) for s in STATES_6DOF])


def hold_margins(data: CampaignData, *, model: str = "linearization_full",
                 grid: tuple[float, float, int] = MARGIN_GRID) -> xr.Dataset:
    """Crossover and margins of each stabilisation hold of a flown campaign.

    The holds are rebuilt from the campaign that was flown (root attribute ``campaign_toml``)
    and the quasi-steady ``/linearization`` as :func:`sysid.flight_test.campaign.run_campaign`
    designs them; each is broken at its control on ``/<model>`` (default the full
    linearisation) with the others closed (module docstring).

    Returns
    -------
    xr.Dataset
        dims ``excited`` (the sweep axis of the configuration, CONTROLS) and ``hold`` (the
        broken loop's control); the :func:`loop_margins` quantities ``gain_crossover``,
        ``phase_margin`` (deg), ``phase_crossover``, ``gain_margin_db`` (dB),
        ``phase_crossover_low``, ``gain_margin_low_db``, ``stability_margin``; attributes
        ``model``, ``design_crossover`` (rad/s), ``heading_crossover``,
        ``vertical_speed_bandwidth``.
    """
    spec = flown_campaign(data)
    stab = spec.stabilisation
    if not stab.enabled:
        raise InputDataError(f"campaign {data.source}: stabilisation is off; no holds to "
                             "analyse")
    lin, plant, trim, (A, B, _, _, _), cols = _loop_parts(data, model)
    missing = [c for c in MEASUREMENTS if c not in trim]
    if missing:
        raise InputDataError(f"campaign {data.source}: /trim lacks {missing}")
    trim_y = {c: float(trim[c]) for c in MEASUREMENTS}
    loops = design_loops(lin, stab)
    omega = np.logspace(math.log10(grid[0]), math.log10(grid[1]), int(grid[2]))
    keys = ("gain_crossover", "phase_margin", "phase_crossover", "gain_margin_db",
            "phase_crossover_low", "gain_margin_low_db", "stability_margin")
    out = {k: np.full((len(CONTROLS), len(CONTROLS)), np.nan) for k in keys}
    for e, excited in enumerate(CONTROLS):
        K = np.zeros((len(CONTROLS), A.shape[0]))
        K[:, cols] = hold_gains(loops, stab, trim_y, excited).sel(input=list(CONTROLS)).values
        for h in range(len(CONTROLS)):
            m = loop_margins(broken_loop_response(A, B, K, h, omega), omega)
            for k in keys:
                out[k][e, h] = m[k]
    units = {"gain_crossover": "rad/s", "phase_crossover": "rad/s", "phase_margin": "deg",
             "gain_margin_db": "dB", "phase_crossover_low": "rad/s",
             "gain_margin_low_db": "dB", "stability_margin": "1"}
    names = {"gain_crossover": "highest gain crossover frequency (|L| = 1)",
             "phase_margin": "phase margin at the gain crossover",
             "phase_crossover": "phase crossover above the gain crossover (angle L = -180)",
             "gain_margin_db": "gain margin: smallest gain increase to instability",
             "phase_crossover_low": "phase crossover below the gain crossover",
             "gain_margin_low_db": "lower gain margin: smallest gain reduction to instability "
                                   "(conditionally stable loop)",
             "stability_margin": "smallest distance of L(j omega) from -1"}
    return xr.Dataset({k: (("excited", "hold"), v, {"units": units[k], "long_name": names[k]})
                       for k, v in out.items()},
                      coords={"excited": list(CONTROLS), "hold": list(CONTROLS)},
                      attrs={"model": model, "design_crossover": float(stab.crossover),
                             "heading_crossover": float(stab.heading_crossover),
                             "vertical_speed_bandwidth": float(stab.vertical_speed_bandwidth),
                             "loop": "L_c = -K_c (sI - A - B_o K_o)^-1 B_c, other holds closed"})


def linear_replay(data: CampaignData, *, model: str = "linearization_full",
                  pattern: str = "*") -> xr.DataTree:
    """A campaign's manoeuvres flown again by a linear model in closed loop with the holds.

    Each manoeuvre matching ``pattern`` is replayed through ``/<model>`` (no delays) with the
    pilot command ``u - K (y - y_trim)`` recovered from the recording and the holds closed
    (module docstring). Exact for a noise-free recording within the hold law's linear range
    (no clipping); with sensor noise the recovered pilot command carries ``K`` times the noise.

    Returns
    -------
    xr.DataTree
        A copy of the campaign tree without ``/frequency_response`` whose manoeuvres hold the
        replayed controls (%) and the outputs the model has (noise-free, analysis units,
        absolute); recorded channels the model lacks are dropped. Root attribute
        ``linear_replay`` names the model.

    Examples
    --------
    >>> replay = linear_replay(CampaignData.read("campaign.nc"), pattern="sweep_*")
    """
    spec = flown_campaign(data)
    stab = spec.stabilisation
    lin, plant, trim, (A, B, C, D, tau), cols = _loop_parts(data, model)
    if np.any(tau != 0):
        raise InputDataError(f"campaign {data.source}: /{model} has delays; the replay needs "
                             "a delay-free model (the truth's linearisations are)")
    outputs = [str(s) for s in plant["C"].output.values]
    trim_y = {c: float(trim[c]) for c in MEASUREMENTS if c in trim}
    loops = design_loops(lin, stab)
    recorded = data.maneuvers(pattern)  # raises when none matches
    tree = data.tree.copy()
    if "frequency_response" in tree.children:
        del tree["frequency_response"]
    maneuvers = tree["maneuvers"]
    for name, ds in recorded.items():
        missing = [c for c in CONTROLS + STATES_6DOF if c not in ds]
        if missing:
            raise InputDataError(f"campaign {data.source}: manoeuvre {name} lacks {missing}")
        time = ds["time"].values
        dt = float(np.median(np.diff(time)))
        Phi, Gamma = discretize(A, B, dt)
        K6 = (hold_gains(loops, stab, trim_y, str(ds.attrs.get("axis")))
              .sel(input=list(CONTROLS), state=list(STATES_6DOF)).values)
        K = np.zeros((len(CONTROLS), A.shape[0]))
        K[:, cols] = K6
        u_trim = np.array([float(ds.attrs[f"trim_{c}"]) for c in CONTROLS])
        y_trim = np.array([float(ds.attrs[f"trim_{c}"]) for c in STATES_6DOF])
        U = np.stack([ds[c].values for c in CONTROLS], axis=1) - u_trim
        Y = np.stack([ds[c].values for c in STATES_6DOF], axis=1) - y_trim
        pilot = U - Y @ K6.T
        x = np.zeros(A.shape[0])
        X = np.empty((len(time), A.shape[0]))
        Uc = np.empty_like(pilot)
        for k in range(len(time)):
            X[k] = x
            Uc[k] = pilot[k] + K @ x
            x = Phi @ x + Gamma @ Uc[k]
        Yl = X @ C.T + Uc @ D.T
        new = xr.Dataset(coords={"time": ds["time"]}, attrs=dict(ds.attrs))
        for j, c in enumerate(CONTROLS):
            new[c] = ("time", Uc[:, j] + u_trim[j], ds[c].attrs)
        for c in MEASUREMENTS:
            if c in outputs and c in ds and f"trim_{c}" in ds.attrs:
                new[c] = ("time", Yl[:, outputs.index(c)] + float(ds.attrs[f"trim_{c}"]),
                          ds[c].attrs)
        maneuvers[name] = xr.DataTree(new)
    tree.attrs = dict(tree.attrs, linear_replay=model)
    return tree
