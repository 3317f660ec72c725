"""Trim of the truth helicopter: steady, level, zero-sideslip flight at a given airspeed.

The trim solves, on the model-exchange derivatives of the FMU, for the four controls (%),
the pitch and roll attitudes and every internal state (rotor flapping, inflow, actuators)
such that the six body accelerations and the internal state derivatives all vanish:

    unknowns  lon lat col ped, theta, phi, a1 b1 vi_mr vi_tr theta_0 theta_1s theta_1c theta_tr
    equations du dv dw dp dq dr = 0, d(internal states) = 0

with the body velocity fixed by the flight condition: airspeed ``V`` along a level flight path
with zero sideslip (``v = 0``, ``w = u tan(theta) / cos(phi)``, ``u^2 + w^2 = V^2``), zero
body rates, no wind, and the heading ``psi`` chosen so that the ground track points along
the earth x axis (north). The actuator states are unknowns rather than computed from the
gearing, so the trim never duplicates the FMU's control laws.

Forward-flight trims are reached by continuation from hover in steps of at most 20 kt.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr
from scipy.optimize import root

from sysid.core.errors import FMUError, InputDataError
from sysid.fmi.runtime import DerivativeFunction, FMUModel
from sysid.core.units import CHANNELS, CONTROLS, KT, STATES_6DOF, channel_attrs, convert
from sysid.truth.fmu import load_fmu

#: Rigid-body and navigation states: prescribed by the flight condition, not solved for.
RIGID_BODY = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
NAVIGATION = ("x_n", "y_e", "h")
#: Trim residual: the six body accelerations (m/s^2, rad/s^2).
BODY_ACCELERATIONS = ("u", "v", "w", "p", "q", "r")
#: Largest airspeed accepted by :func:`trim`, kt.
MAX_AIRSPEED_KT = 160.0
#: Residual accepted as converged (SI, largest absolute state derivative).
TOLERANCE = 1e-9


def internal_states(model: FMUModel) -> tuple[str, ...]:
    """States besides the rigid body and navigation: rotor, inflow and actuator states."""
    return tuple(s for s in model.state_names if s not in RIGID_BODY + NAVIGATION)


def level_flight_velocity(airspeed: float, theta: float, phi: float) -> tuple[float, float, float]:
    """Body velocity (u, v, w) in m/s of level, zero-sideslip flight at ``airspeed`` (m/s).

    Level flight: the earth-vertical velocity ``-u sin(theta) + w cos(phi) cos(theta)``
    vanishes; zero sideslip: ``v = 0``.
    """
    ratio = math.tan(theta) / math.cos(phi)
    u = airspeed / math.sqrt(1.0 + ratio * ratio)
    return u, 0.0, u * ratio


def track_heading(u: float, w: float, theta: float, phi: float) -> float:
    """Heading (rad) that points the ground track of body velocity (u, 0, w) north."""
    north = u * math.cos(theta) + w * math.cos(phi) * math.sin(theta)
    east = -w * math.sin(phi)
    return -math.atan2(east, north)


@dataclass(frozen=True)
class TrimResult:
    """A trimmed flight condition of the truth helicopter.

    Attributes
    ----------
    airspeed_kt : float
        True airspeed, kt.
    controls : dict
        ``lon lat col ped``, % of travel.
    states : dict
        Every FMU state at trim, SI (FMU names and units).
    outputs : dict
        Every FMU output at trim, SI (FMU names and units).
    residual : dict
        State derivatives at the solution (SI); the six body accelerations are the trim
        residual.
    parameters : dict
        Parameter overrides (SI) the trim was computed with; simulations reuse them.
    fmu_path, fmu_name, fmu_guid
        The FMU the trim belongs to.
    """

    airspeed_kt: float
    controls: dict
    states: dict
    outputs: dict
    residual: dict
    parameters: dict = field(default_factory=dict)
    fmu_path: Path | None = None
    fmu_name: str = ""
    fmu_guid: str = ""

    @property
    def theta_deg(self) -> float:
        """Pitch attitude, deg."""
        return math.degrees(self.states["theta"])

    @property
    def phi_deg(self) -> float:
        """Roll attitude, deg."""
        return math.degrees(self.states["phi"])

    @property
    def psi_deg(self) -> float:
        """Heading, deg."""
        return math.degrees(self.states["psi"])

    @property
    def max_residual(self) -> float:
        """Largest absolute body acceleration at trim (m/s^2 or rad/s^2)."""
        return max(abs(self.residual[s]) for s in BODY_ACCELERATIONS)

    @property
    def flight_condition(self) -> str:
        """``"hover"`` or ``"<airspeed> kt"``."""
        return "hover" if self.airspeed_kt == 0 else f"{self.airspeed_kt:g} kt"

    def start_values(self) -> dict:
        """FMU start values (SI) that initialise an ME or CS instance exactly at this trim:
        every state, the four controls and zero gusts."""
        values = dict(self.states)
        values.update(self.controls)
        values.update({"u_gust": 0.0, "v_gust": 0.0, "w_gust": 0.0})
        return values

    def channel_values(self) -> dict:
        """Trim value of every channel of :data:`sysid.core.units.CHANNELS`, analysis units."""
        values = {}
        for name, channel in CHANNELS.items():
            if name in self.controls:
                values[name] = float(self.controls[name])
            else:
                si = self.states[name] if name in self.states else self.outputs[name]
                values[name] = float(convert(si, channel.si_unit, channel.unit))
        return values

    def attrs(self) -> dict:
        """``trim_<channel>`` attributes (analysis units) for time-history datasets."""
        attrs = {f"trim_{k}": v for k, v in self.channel_values().items()}
        attrs.update(flight_condition=self.flight_condition, airspeed_kt=float(self.airspeed_kt))
        return attrs

    def to_dataset(self) -> xr.Dataset:
        """The trim as a Dataset: one scalar variable per channel (analysis units), plus the
        internal states (SI) and the trim residual."""
        data = {name: xr.DataArray(value, attrs=channel_attrs(name))
                for name, value in self.channel_values().items()}
        for name, value in self.states.items():
            if name not in data:
                data[name] = xr.DataArray(value, attrs={"units": "SI (FMU unit)"})
        data["residual"] = xr.DataArray(
            [self.residual[s] for s in BODY_ACCELERATIONS], dims="state_dot",
            coords={"state_dot": list(BODY_ACCELERATIONS)},
            attrs={"long_name": "body accelerations at trim", "units": "m/s2 or rad/s2"})
        return xr.Dataset(data, attrs={"flight_condition": self.flight_condition,
                                       "airspeed_kt": float(self.airspeed_kt),
                                       "fmu_name": self.fmu_name, "fmu_guid": self.fmu_guid,
                                       "mass_kg": float(self.mass)})

    @property
    def mass(self) -> float:
        """Aircraft mass, kg."""
        return float(self.parameters["mass"])

    def table(self) -> str:
        """The trim as a text table in the layout of the paper's Table 1."""
        v = self.channel_values()
        rows = [
            ("u_0", f"{v['u']:.2f} ft/s", "delta_lon_0", f"{v['lon']:.2f} %"),
            ("v_0", f"{v['v']:.2f} ft/s", "delta_lat_0", f"{v['lat']:.2f} %"),
            ("w_0", f"{v['w']:.2f} ft/s", "delta_col_0", f"{v['col']:.2f} %"),
            ("phi_0", f"{v['phi']:.2f} deg", "delta_ped_0", f"{v['ped']:.2f} %"),
            ("theta_0", f"{v['theta']:.2f} deg", "Total mass", f"{self.mass:.1f} kg"),
        ]
        title = f"Trimmed state values, {self.flight_condition}"
        lines = [title, "-" * len(title),
                 f"{'Parameter':<12}{'Value':>14}   {'Parameter':<14}{'Value':>10}"]
        lines += [f"{a:<12}{b:>14}   {c:<14}{d:>10}" for a, b, c, d in rows]
        lines.append(f"(heading {v['psi']:.2f} deg; residual {self.max_residual:.1e})")
        return "\n".join(lines)


class _TrimProblem:
    """Residual function of the trim for one airspeed."""

    def __init__(self, f: DerivativeFunction, airspeed: float):
        self.f = f
        self.airspeed = airspeed
        names = f.state_names
        self.index = {n: k for k, n in enumerate(names)}
        self.internal = [s for s in names if s not in RIGID_BODY + NAVIGATION]
        self.rows = [self.index[s] for s in (*BODY_ACCELERATIONS, *self.internal)]

    def unpack(self, z: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """States (SI) and controls (%) from the unknowns
        ``[lon lat col ped]/100, theta, phi, internal states``."""
        controls = np.asarray(z[:4]) * 100.0
        theta, phi = float(z[4]), float(z[5])
        x = np.zeros(len(self.index))
        u, v, w = level_flight_velocity(self.airspeed, theta, phi)
        x[self.index["u"]], x[self.index["v"]], x[self.index["w"]] = u, v, w
        x[self.index["theta"]], x[self.index["phi"]] = theta, phi
        for k, name in enumerate(self.internal):
            x[self.index[name]] = z[6 + k]
        return x, controls

    def __call__(self, z: np.ndarray) -> np.ndarray:
        x, controls = self.unpack(z)
        return self.f(x, controls)[self.rows]


def _initial_guess(model: FMUModel, internal) -> np.ndarray:
    """Hover-like start: mid controls, small nose-up attitude, FMU start values elsewhere."""
    return np.array([0.5, 0.5, 0.5, 0.5, math.radians(3.0), math.radians(-2.0),
                     *[model.start(s) for s in internal]])


def _solve(problem: _TrimProblem, z0: np.ndarray) -> np.ndarray:
    sol = root(problem, z0, method="hybr", options={"xtol": 1e-14, "maxfev": 4000})
    z = sol.x
    # Newton polish with a central-difference Jacobian: drives the residual to round-off.
    for _ in range(3):
        r = problem(z)
        if np.max(np.abs(r)) < 1e-12:
            break
        n = len(z)
        jac = np.empty((len(r), n))
        for j in range(n):
            dz = np.zeros(n)
            dz[j] = 1e-7 * max(1.0, abs(z[j]))
            jac[:, j] = (problem(z + dz) - problem(z - dz)) / (2 * dz[j])
        try:
            z = z - np.linalg.solve(jac, r)
        except np.linalg.LinAlgError:
            break
    return z


def trim(airspeed_kt: float = 0.0, *, fmu=None, parameters: dict | None = None) -> TrimResult:
    """Trim the helicopter in steady, level, zero-sideslip flight.

    Parameters
    ----------
    airspeed_kt : float
        True airspeed, kt (0 = hover), between 0 and :data:`MAX_AIRSPEED_KT`.
    fmu : path or FMUModel, optional
        The FMU (default: the truth helicopter, built on first use).
    parameters : dict, optional
        FMU parameter overrides, SI (e.g. ``{"mass": 2600.0}``).

    Returns
    -------
    TrimResult
        Controls in %, attitudes, every state and output (SI), the residual.

    Raises
    ------
    InputDataError
        Airspeed outside the supported range or not finite.
    FMUError
        The trim did not converge (residual above ``1e-9``).
    """
    if not (isinstance(airspeed_kt, (int, float)) and math.isfinite(airspeed_kt)) \
            or not 0.0 <= airspeed_kt <= MAX_AIRSPEED_KT:
        raise InputDataError(f"trim airspeed must be between 0 and {MAX_AIRSPEED_KT:g} kt, "
                             f"got {airspeed_kt!r}")
    model = fmu if isinstance(fmu, FMUModel) else load_fmu(fmu)
    model.require((*CONTROLS, *RIGID_BODY, "mass"), "to trim the helicopter")
    missing = [s for s in RIGID_BODY if s not in model.state_names]
    if missing:
        raise FMUError(f"{model.path} cannot be used to trim the helicopter: {missing} are "
                       f"not continuous states (states: {list(model.state_names)})")
    parameters = dict(parameters or {})
    f = DerivativeFunction(model, parameters)
    try:
        internal = internal_states(model)
        z = _initial_guess(model, internal)
        n_steps = max(1, math.ceil(airspeed_kt / 20.0))
        for speed in np.linspace(0.0, airspeed_kt, n_steps + 1)[1 if airspeed_kt else 0:]:
            problem = _TrimProblem(f, float(speed) * KT)
            z = _solve(problem, z)
        problem = _TrimProblem(f, airspeed_kt * KT)
        x, controls = problem.unpack(z)
        index = problem.index
        x[index["psi"]] = track_heading(x[index["u"]], x[index["w"]], x[index["theta"]],
                                        x[index["phi"]])
        dx = f(x, controls)
        residual = dict(zip(model.state_names, dx.tolist()))
        worst = max(abs(residual[s]) for s in (*BODY_ACCELERATIONS, *internal))
        if not worst < TOLERANCE or np.any(controls < 0) or np.any(controls > 100):
            raise FMUError(f"trim at {airspeed_kt:g} kt did not converge: residual {worst:.2e}, "
                           f"controls {np.round(controls, 2).tolist()} %")
        outputs = f.outputs(x, controls, [*model.output_names, "mass"])
    finally:
        f.close()
    states = dict(zip(model.state_names, x.tolist()))
    mass = outputs.pop("mass")
    out = {k: v for k, v in outputs.items() if k not in states}
    parameters.setdefault("mass", mass)
    return TrimResult(airspeed_kt=float(airspeed_kt),
                      controls=dict(zip(CONTROLS, controls.tolist())), states=states,
                      outputs=out, residual=residual, parameters=parameters,
                      fmu_path=model.path, fmu_name=model.name, fmu_guid=model.guid)


__all__ = ["TrimResult", "trim", "level_flight_velocity", "internal_states", "STATES_6DOF"]
