"""Flight-test campaigns: which inputs on which axis, stabilisation, noise, turbulence.

A :class:`Campaign` describes a flight-test programme at one flight condition: manoeuvres per
axis (frequency sweeps, 3211, 2311, doublets, multisines), sample rate, sensor noise,
turbulence, secondary-axis stabilisation and the seed. It reads and writes TOML.
:func:`run_campaign` flies it on the truth FMU in co-simulation, stepping at the sample rate
while low-frequency holds act on the non-excited axes (the paper's set-up; this is what makes
the recorded controls correlated, its Figure 1), and writes one netCDF DataTree with a group
per manoeuvre, each manoeuvre appended atomically as it completes.

Stabilisation (``Stabilisation``)
    Attitude holds on the off-axis cyclic, heading hold on pedal, vertical-speed hold on
    collective, and a weak hold on the excited axis so long-period cycles stay bounded. Gains
    are designed from the truth model's quasi-steady linearisation at the flight condition:
    each loop is ``delta = -(K_x x + K_rate x_dot) / control_derivative`` with the attitude loop
    crossover at ``crossover`` rad/s (default 1.0, the top of the paper's 0.3-1 rad/s range),
    so signs and scaling follow the FMU's control gearing without hand tuning. In
    ``conditional`` mode a loop acts only on the part of its error outside a dead band (the
    paper's "conditional" variant).

What is recorded is what was applied: the pilot command (trim, excitation, off-axis activity)
plus the stabilisation commands, clipped to 0-100 % of travel like the FMU's own saturation.
By default the holds are computed inside the truth FMU (``fmus/helicopter/holds.c``,
parameterised per manoeuvre by :func:`fmu_hold_parameters`), which steps through the whole
pilot command with :meth:`sysid.truth.CoSimulation.run`; ``holds="python"`` computes them here
at every step (:func:`_hold_commands`, the reference: the same bytes, about 5x slower).
"""

from __future__ import annotations

import dataclasses
import fnmatch
import math
import tomllib
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence

import numpy as np
import scipy.signal
import xarray as xr

import sysid
from sysid import truth
from sysid.core.errors import InputDataError, SimulationDiverged
from sysid.core.units import CONTROLS, KT, STATES_6DOF, channel_attrs, convert
from sysid.core.util import Progress
from sysid.data.netcdf import write_campaign
from sysid.signals import inputs

#: A campaign summary: ``f(tree) -> (group, dataset, message)`` or None (see run_campaign).
Summary = Callable[[xr.DataTree], "tuple[str, xr.Dataset, str] | None"]

#: Measured channels recorded for every manoeuvre (analysis units).
MEASUREMENTS = STATES_6DOF + ("ax", "ay", "az")

#: Realistic 1-sigma white sensor noise per channel, analysis units (flight-test grade
#: GPS/INS: about 0.05 m/s on velocities, 0.1 deg/s on rates, 0.05 deg on attitudes; cf.
#: Tischler & Remple 2012, ch. 6). Used by the default campaign.
DEFAULT_NOISE = {
    "u": 0.15, "v": 0.15, "w": 0.15,
    "p": 0.1, "q": 0.1, "r": 0.1,
    "phi": 0.05, "theta": 0.05, "psi": 0.05,
    "ax": 0.1, "ay": 0.1, "az": 0.1,
}

KINDS = ("sweep", "3211", "2311", "doublet", "multisine", "sine")

#: Amplitude factors of the default campaign against airspeed, ``{axis: ((kt, factor), ...)}``,
#: interpolated linearly and held beyond the last point
#: (measurements: docs/notes/2026-11-24-campaign-amplitudes-and-holds.md).
FORWARD_FLIGHT_AMPLITUDE = {"lon": ((0.0, 1.0), (80.0, 0.5), (100.0, 0.25)),
                            "col": ((0.0, 1.0), (80.0, 0.6)),
                            "ped": ((0.0, 1.0), (80.0, 0.6))}

#: Attitude-hold crossover of the default campaign against airspeed (rad/s, same format).
FORWARD_FLIGHT_CROSSOVER = ((0.0, 1.0), (80.0, 1.0), (100.0, 1.5))

#: Closed-loop damping ratio below which :func:`run_campaign` warns before flying.
LIGHT_DAMPING = 0.1

#: Where the stabilisation holds are computed: compiled into the truth FMU (its ``hold_*``
#: parameters, ``fmus/helicopter/holds.c``) or in Python, the reference implementation, about
#: 5x slower (docs/notes/2026-11-24-campaign-holds-in-the-fmu.md). Both give the same bytes.
HOLDS = ("fmu", "python")


def _schedule(points, airspeed_kt: float) -> float:
    """Piecewise-linear schedule ``((kt, value), ...)`` at ``airspeed_kt`` (held at the ends)."""
    kt, value = zip(*points)
    return float(np.interp(airspeed_kt, kt, value))


@dataclass
class Maneuver:
    """One manoeuvre. ``axis`` is a control name (``lon lat col ped``).

    Amplitudes are % of travel; frequencies rad/s; times s. Sweep fields apply to sweeps and
    multisines, ``base_width``/``sign`` to multisteps; a ``sine`` is ``amplitude sin(omega_min
    t)`` for ``duration`` s (describing functions).
    """

    name: str
    kind: str
    axis: str
    amplitude: float = 10.0
    duration: float = 90.0
    omega_min: float = 0.1
    omega_max: float = 20.0
    long_period_cycles: float = 2.0
    low_frequency_fraction: float = 1.0
    full_amplitude_omega: float = 0.0  #: rad/s; 0 = constant amplitude
    amplitude_shape: float = 1.0  #: exponent of the schedule's rise (1 = linear in log-omega)
    base_width: float = 1.0
    sign: int = 1
    lead_in: float = 3.0
    lead_out: float = 5.0
    #: Dryden rms gust intensity of this manoeuvre, m/s; None: the campaign's (air changes
    #: over a test day: sweeps are flown in the calm, docs/methods.md, "Hybrid structures").
    turbulence: float | None = None

    def validate(self) -> None:
        if self.kind not in KINDS:
            raise InputDataError(f"manoeuvre {self.name!r}: kind {self.kind!r} not in {KINDS}")
        if self.axis not in CONTROLS:
            raise InputDataError(
                f"manoeuvre {self.name!r}: axis {self.axis!r} is not a control {CONTROLS}")
        if not (self.amplitude > 0 and self.duration > 0):
            raise InputDataError(f"manoeuvre {self.name!r}: amplitude and duration must be > 0")
        if self.kind in ("sweep", "multisine") and not 0 < self.omega_min < self.omega_max:
            raise InputDataError(
                f"manoeuvre {self.name!r}: need 0 < omega_min < omega_max (rad/s)")
        if self.kind == "sine" and not self.omega_min > 0:
            raise InputDataError(f"manoeuvre {self.name!r}: a sine needs omega_min > 0 (rad/s)")
        if self.turbulence is not None and not self.turbulence >= 0:
            raise InputDataError(f"manoeuvre {self.name!r}: turbulence must be >= 0 m/s (or "
                                 f"left out for the campaign's), got {self.turbulence!r}")


@dataclass
class Stabilisation:
    """Low-frequency secondary-axis holds (see module docstring)."""

    enabled: bool = True
    #: Attitude/heading loop crossover, rad/s: the top of the paper's 0.3-1 range (lower
    #: leaves the hover pitch-roll oscillation unstable; docs/notes, "campaign amplitudes").
    crossover: float = 1.0
    #: Heading-hold crossover, rad/s: low, so pedal does not track the torque reaction of
    #: collective sweeps (col and ped would become collinear).
    heading_crossover: float = 0.3
    vertical_speed_bandwidth: float = 0.3  #: rad/s
    #: Crossover of the weaker hold on the excited axis, relative to ``crossover`` (weaker
    #: holds let sweeps drift out of the hover regime).
    primary_fraction: float = 0.8
    #: Outer u/v -> attitude reference gain (the reference moves ``velocity_hold/2`` deg per
    #: ft/s against the drift; 0 disables it).
    velocity_hold: float = 0.6
    conditional: bool = False
    dead_band: dict = field(default_factory=lambda: {"attitude": 3.0, "rate": 3.0,
                                                     "vertical_speed": 2.0})
    #: Seeded band-limited off-axis pilot activity, % rms, added to secondary axes so that
    #: every control moves (as in the paper's Figure 1). 0 disables it.
    secondary_perturbation: float = 0.5


@dataclass
class Campaign:
    """A flight-test campaign at one flight condition."""

    name: str = "hover"
    airspeed_kt: float = 0.0
    sample_rate: float = 100.0  #: Hz
    seed: int = 20261121
    maneuvers: list[Maneuver] = field(default_factory=list)
    noise: dict = field(default_factory=dict)  #: channel -> 1-sigma, analysis units
    turbulence: float = 0.0  #: Dryden rms gust intensity, m/s (0: calm)
    stabilisation: Stabilisation = field(default_factory=Stabilisation)
    max_attitude_excursion: float = 60.0  #: deg from trim before a run counts as diverged
    max_velocity_excursion: float = 100.0  #: ft/s from trim before a run counts as diverged

    @property
    def flight_condition(self) -> str:
        return "hover" if self.airspeed_kt == 0 else f"{self.airspeed_kt:g} kt"

    def validate(self) -> None:
        if self.sample_rate <= 0:
            raise InputDataError(f"campaign {self.name!r}: sample_rate must be > 0 Hz")
        if not self.maneuvers:
            raise InputDataError(f"campaign {self.name!r}: no manoeuvres")
        names = [m.name for m in self.maneuvers]
        duplicated = sorted({n for n in names if names.count(n) > 1})
        if duplicated:
            raise InputDataError(f"campaign {self.name!r}: duplicated manoeuvre names {duplicated}")
        for m in self.maneuvers:
            m.validate()
        unknown = sorted(set(self.noise) - set(MEASUREMENTS))
        if unknown:
            raise InputDataError(f"campaign {self.name!r}: noise given for unknown channels "
                                 f"{unknown}; measured channels are {list(MEASUREMENTS)}")

    def select(self, pattern: str) -> "Campaign":
        """A copy with only the manoeuvres whose name matches the glob ``pattern``."""
        chosen = [m for m in self.maneuvers if fnmatch.fnmatchcase(m.name, pattern)]
        return dataclasses.replace(self, maneuvers=chosen)

    # -- TOML ---------------------------------------------------------------------------
    @classmethod
    def from_toml(cls, path: str | Path) -> "Campaign":
        path = Path(path)
        try:
            spec = tomllib.loads(path.read_text())
        except (OSError, tomllib.TOMLDecodeError) as exc:
            raise InputDataError(f"cannot read campaign file {path}: {exc}") from None
        return cls.from_dict(spec, where=str(path))

    @classmethod
    def from_dict(cls, spec: dict, where: str = "campaign") -> "Campaign":
        spec = dict(spec)
        try:
            maneuvers = [Maneuver(**m) for m in spec.pop("maneuvers", [])]
            stab = Stabilisation(**spec.pop("stabilisation", {}))
            campaign = cls(**spec, maneuvers=maneuvers, stabilisation=stab)
        except TypeError as exc:
            raise InputDataError(f"{where}: {exc}") from None
        campaign.validate()
        return campaign

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)

    def to_toml(self) -> str:
        """TOML text that :meth:`from_toml` reads back to an equal campaign."""
        d = self.to_dict()
        lines = [f"{k} = {_toml_value(v)}" for k, v in d.items()
                 if not isinstance(v, (dict, list))]
        lines.append(f"noise = {_toml_value(d['noise'])}")
        lines.append("\n[stabilisation]")
        lines += [f"{k} = {_toml_value(v)}" for k, v in d["stabilisation"].items()]
        for m in d["maneuvers"]:
            lines.append("\n[[maneuvers]]")
            lines += [f"{k} = {_toml_value(v)}" for k, v in m.items() if v is not None]
        return "\n".join(lines) + "\n"


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, dict):
        return "{ " + ", ".join(f"{k} = {_toml_value(v)}" for k, v in value.items()) + " }"
    if isinstance(value, float):
        return repr(value)
    return str(value)


#: Lateral sweep amplitude schedules (fraction at 0.1 rad/s, rad/s from which the amplitude is
#: full, exponent of the rise in log-frequency): cubic in hover at full amplitude, linear
#: otherwise (see :func:`default_campaign`).
HOVER_LATERAL_RISE = (0.15, 1.2, 3.0)
LINEAR_LATERAL_RISE = (0.15, 1.5, 1.0)


def default_campaign(airspeed_kt: float = 0.0, *, noise: bool = True, seed: int = 20261121,
                     sweep_duration: float = 150.0) -> Campaign:
    """The paper's campaign: two sweep records per axis, plus a 3211 and a 2311 per axis.

    Sweeps run 0.1-20 rad/s (covering the flapping/inflow modes near 14-16 rad/s). One
    long-period cycle at 0.1 rad/s already takes 63 s, so records are 150 s with a single
    long-period cycle, leaving 87 s for the exponential part (docs/methods.md: 60-120 s of sweep
    and at least 2-5 periods of the lowest frequency over the concatenated records); multistep
    base widths target the 1-3 rad/s band of the rigid-body modes. With ``noise`` the default
    sensor noise levels and light turbulence (0.3 m/s rms) are on.
    """
    amplitude = {"lon": 5.0, "lat": 8.0, "col": 10.0, "ped": 8.0}
    # Amplitudes, schedules and holds: docs/notes/2026-11-24-campaign-amplitudes-and-holds.md.
    for axis, points in FORWARD_FLIGHT_AMPLITUDE.items():
        amplitude[axis] *= _schedule(points, max(airspeed_kt, 0.0))
    # Schedule: fraction of the amplitude at 0.1 rad/s, rad/s from which it is full, exponent
    # of the rise in log-frequency (1 = linear); cubic lateral rise in hover only.
    lateral = HOVER_LATERAL_RISE if airspeed_kt == 0 else LINEAR_LATERAL_RISE
    schedule = {"lon": (0.1, 1.5, 1.0), "lat": lateral, "col": (0.3, 1.5, 1.0),
                "ped": (0.2, 1.5, 1.0)}
    base_width = {"lon": 0.5, "lat": 0.4, "col": 0.8, "ped": 0.8}
    maneuvers = []
    for axis in CONTROLS:
        for k in (1, 2):
            maneuvers.append(Maneuver(
                f"sweep_{axis}_{k}", "sweep", axis, amplitude[axis], duration=sweep_duration,
                long_period_cycles=1.0, low_frequency_fraction=schedule[axis][0],
                full_amplitude_omega=schedule[axis][1], amplitude_shape=schedule[axis][2]))
    for kind in ("3211", "2311"):
        for axis in CONTROLS:
            maneuvers.append(Maneuver(f"{kind}_{axis}", kind, axis, amplitude[axis] * 0.7,
                                      duration=7 * base_width[axis], base_width=base_width[axis],
                                      lead_in=2.0, lead_out=6.0))
    name = "hover" if airspeed_kt == 0 else f"forward_{airspeed_kt:g}kt"
    # Above hover: no outer u/v loop (it lowers the pitch-heave damping) and a crossover that
    # rises with speed (FORWARD_FLIGHT_CROSSOVER).
    crossover = _schedule(FORWARD_FLIGHT_CROSSOVER, max(airspeed_kt, 0.0))
    stabilisation = (Stabilisation() if airspeed_kt == 0
                     else Stabilisation(velocity_hold=0.0, crossover=crossover))
    return Campaign(name=name, airspeed_kt=airspeed_kt, seed=seed, maneuvers=maneuvers,
                    noise=dict(DEFAULT_NOISE) if noise else {},
                    turbulence=0.3 if noise else 0.0, stabilisation=stabilisation)


def flown_turbulence(maneuver: Maneuver, campaign: Campaign) -> float:
    """The Dryden rms gust intensity (m/s) ``maneuver`` is flown in: its own, else the
    campaign's."""
    return float(campaign.turbulence if maneuver.turbulence is None else maneuver.turbulence)


def with_calm_sweeps(campaign: Campaign) -> Campaign:
    """A copy of ``campaign`` whose sweeps are flown in calm air (turbulence 0; the other
    manoeuvres keep theirs). Why: in the default campaign's light turbulence v/ped has no
    coherent range, so a hybrid's lateral speed terms go undetermined in the frequency
    domain (docs/methods.md, "Hybrid structures"); flight-test practice flies sweeps in
    calm air."""
    return dataclasses.replace(campaign, maneuvers=[
        dataclasses.replace(m, turbulence=0.0) if m.kind == "sweep" else m
        for m in campaign.maneuvers])


#: Amplitude factors of :func:`linear_regime_campaign` on the default sweeps, per axis.
LINEAR_REGIME_SCALE = {"lon": 0.5, "lat": 0.5, "col": 1.0, "ped": 0.5}


def linear_regime_campaign(airspeed_kt: float = 0.0, *, seed: int = 20261121,
                           noise: bool = True) -> Campaign:
    """The default campaign's sweeps flown to check frequency responses against the
    linearisation: cyclic and pedal sweeps at half amplitude (the lateral one with the linear
    rise), calm air (sensor noise kept).

    Why (measured in hover on the truth FMU): near the unstable pitch-roll oscillation
    (0.3-0.8 rad/s) the default sweeps take the truth model out of its linear range (pitch
    14 deg, speed 13 ft/s); noise-free and calm, with the linear lateral rise, the
    conditioned q/lon sits 5.4 dB above the linearisation at 0.3-0.5 rad/s, and 1.8 dB at a
    quarter of the amplitude (8.2 and 3.6 dB with `yaw_rate_flapping = 1`). Turbulence
    fed back by the holds biases the closed-loop estimate too (+2.4 dB at half amplitude),
    one reason to fly sweeps in calm air. The collective keeps its amplitude: w/col is inside
    MUAD at it, and at half amplitude sensor noise takes w/col's coherence down to 0.76 near
    1 rad/s. With this campaign q/lon, p/lat, w/col and r/ped lie inside MUAD wherever their
    coherence is >= 0.6, with coherence >= 0.88 over 1-10 rad/s, on seed 20261121 and on
    seeds 1-7 (tests/test_hover_study.py: seed 3 in the default run, all with
    SYSID_EXHAUSTIVE=1); with every sweep at 0.75 of the default
    amplitude q/lon already leaves the bound at 0.43-0.49 rad/s.
    """
    base = default_campaign(airspeed_kt, noise=noise, seed=seed).select("sweep_*")
    # Half amplitude needs no cubic lateral rise (docs/notes, "campaign amplitudes").
    fraction, full_omega, shape = LINEAR_LATERAL_RISE
    sweeps = [dataclasses.replace(m, amplitude=m.amplitude * LINEAR_REGIME_SCALE[m.axis])
              for m in base.maneuvers]
    sweeps = [dataclasses.replace(m, low_frequency_fraction=fraction,
                                  full_amplitude_omega=full_omega, amplitude_shape=shape)
              if m.axis == "lat" else m for m in sweeps]
    return dataclasses.replace(base, name=f"{base.name}_linear_regime", maneuvers=sweeps,
                               turbulence=0.0)


#: Pedal sweeps of :func:`handling_qualities_campaign`: repeats, record length (s) and amplitude
#: relative to the default campaign's.
HQ_PEDAL_SWEEPS = {"repeats": 4, "duration": 300.0, "scale": 1.0}


def handling_qualities_campaign(airspeed_kt: float = 0.0, *, seed: int = 20261121,
                                noise: bool = True) -> Campaign:
    """The default campaign's sweeps flown for the handling-qualities figures: calm air
    (sensor noise kept) and the pedal sweeps as :data:`HQ_PEDAL_SWEEPS` (four 300-s records).

    Why (measured in hover on the truth FMU, docs/notes/2026-11-25-hq-yaw-pedal-sweeps.md):
    the heading bandwidth (about 0.3 rad/s) lies in the pedal sweep's low-frequency part,
    which a 150-s record passes in half a cycle (11 s between 0.2 and 0.5 rad/s); there the
    conditioned psi/ped of the nonlinear truth came out 9-14 % above the linearisation's
    bandwidth in calm air, where its describing function at the amplitude flown is 2 % above.
    Four 300-s records (1.6 cycles each) bring the data to within 4 % of the linearisation
    and 2 % of the describing function on seeds 1-3 and 20261121. Turbulence fed back by the
    heading hold spreads the default campaign's yaw bandwidth over -3 to +14 %.
    """
    base = default_campaign(airspeed_kt, noise=noise, seed=seed).select("sweep_*")
    pedal = next(m for m in base.maneuvers if m.axis == "ped")
    spec = HQ_PEDAL_SWEEPS
    pedals = [dataclasses.replace(pedal, name=f"sweep_ped_{k + 1}", duration=spec["duration"],
                                  amplitude=pedal.amplitude * spec["scale"])
              for k in range(int(spec["repeats"]))]
    sweeps = [m for m in base.maneuvers if m.axis != "ped"] + pedals
    return dataclasses.replace(base, name=f"{base.name}_handling_qualities", maneuvers=sweeps,
                               turbulence=0.0)


# ---------------------------------------------------------------------------------------
# Excitation signals
# ---------------------------------------------------------------------------------------
def excitation(maneuver: Maneuver, dt: float, seed: int) -> np.ndarray:
    """The designed excitation of one manoeuvre on its axis (% from trim), sampled at ``dt``."""
    m = maneuver
    if m.kind == "sweep":
        ds = inputs.frequency_sweep(m.axis, omega_min=m.omega_min, omega_max=m.omega_max,
                                    duration=m.duration, amplitude=m.amplitude, dt=dt,
                                    lead_in=m.lead_in, lead_out=m.lead_out,
                                    long_period_cycles=m.long_period_cycles,
                                    low_frequency_fraction=m.low_frequency_fraction,
                                    full_amplitude_omega=m.full_amplitude_omega or None,
                                    amplitude_shape=m.amplitude_shape)
    elif m.kind == "sine":  # starts from trim at zero phase, back to trim after ``duration``
        n_in, n_on, n_out = (int(round(x / dt)) for x in (m.lead_in, m.duration, m.lead_out))
        out = np.zeros(n_in + n_on + n_out + 1)
        out[n_in:n_in + n_on] = m.amplitude * np.sin(m.omega_min * dt * np.arange(n_on))
        return out
    elif m.kind in ("3211", "2311", "doublet"):
        ds = inputs.multistep(m.kind, m.axis, base_width=m.base_width, amplitude=m.amplitude,
                              sign=m.sign, dt=dt, lead_in=m.lead_in, lead_out=m.lead_out)
    else:
        ds = inputs.orthogonal_multisines([m.axis], omega_min=m.omega_min,
                                          omega_max=m.omega_max, duration=m.duration,
                                          amplitude=m.amplitude, dt=dt, seed=seed)
    return np.asarray(ds[m.axis].values, dtype=float)


# ---------------------------------------------------------------------------------------
# Stabilisation
# ---------------------------------------------------------------------------------------
@dataclass(frozen=True)
class _Loop:
    """``delta_control = -(k_error * error + k_rate * rate) / derivative`` (analysis units)."""

    control: str
    error: str  # 'phi', 'theta', 'psi' or 'hdot'
    rate: str | None
    k_error: float
    k_rate: float
    derivative: float


def design_loops(linearization: xr.Dataset, stab: Stabilisation) -> dict[str, _Loop]:
    """Hold loops per control designed on the quasi-steady linearisation (module docstring).

    ``linearization`` is a model Dataset (docs/data_model.md) with A, B in analysis units.
    For an attitude loop on ``x'' = D x' + B u`` the open loop ``K/(s(s + a))`` with
    ``a = k_rate - D`` crosses over at ``crossover`` when ``K = w_c sqrt(w_c^2 + a^2)``; the rate
    gain adds damping only when the bare airframe has less than ``1.4 w_c``.
    """
    A, B = linearization["A"], linearization["B"]
    loops = {}
    for control, angle, rate in (("lat", "phi", "p"), ("lon", "theta", "q"), ("ped", "psi", "r")):
        damping = float(A.sel(state_dot=rate, state=rate))
        wc = stab.heading_crossover if control == "ped" else stab.crossover
        k_rate = max(0.0, 1.4 * wc + damping)
        a = k_rate - damping
        k_error = wc * math.sqrt(wc**2 + a**2)
        loops[control] = _Loop(control, angle, rate, k_error, k_rate,
                               float(B.sel(state_dot=rate, input=control)))
    # Vertical speed: hdot'' ~ -Z_col delta at hover, so delta = k hdot / Z_col gives a
    # first-order loop of bandwidth k.
    loops["col"] = _Loop("col", "hdot", None, stab.vertical_speed_bandwidth, 0.0,
                         float(B.sel(state_dot="w", input="col")))
    for loop in loops.values():
        if abs(loop.derivative) < 1e-9:
            raise InputDataError(f"cannot design the {loop.control} hold: its control "
                                 "derivative in the linearisation is zero")
    return loops


def hold_gains(loops: dict[str, _Loop], stab: Stabilisation, trim_y: dict,
               excited_axis: str | None = None) -> xr.DataArray:
    """The hold law linearised about trim: ``delta = K x`` (%, per analysis unit of state).

    Central differences of the very law flown (:func:`_hold_commands`, dead bands off), so the
    analysis cannot drift from the implementation. ``excited_axis`` gets the weaker hold
    (``primary_fraction``). Returns K with dims ``(input, state)`` over CONTROLS and the
    rigid-body states.
    """
    linear = dataclasses.replace(stab, conditional=False)
    fractions = {c: (stab.primary_fraction if c == excited_axis else 1.0) for c in CONTROLS}
    names = list(MEASUREMENTS)
    col = {c: k for k, c in enumerate(names)}
    y0 = np.array([trim_y[c] for c in names], dtype=float)
    K = np.empty((len(CONTROLS), len(STATES_6DOF)))
    for j, state in enumerate(STATES_6DOF):
        h = 1e-3  # analysis units (ft/s, deg/s, deg); the law is smooth (sin/cos in hdot)
        up, down = y0.copy(), y0.copy()
        up[col[state]] += h
        down[col[state]] -= h
        K[:, j] = (_hold_commands(up, col, trim_y, loops, fractions, linear)
                   - _hold_commands(down, col, trim_y, loops, fractions, linear)) / (2 * h)
    return xr.DataArray(K, dims=("input", "state"),
                        coords={"input": list(CONTROLS), "state": list(STATES_6DOF)})


def closed_loop_modes(model: xr.Dataset, loops: dict[str, _Loop], stab: Stabilisation,
                      trim_y: dict, slowest: float = 5.0) -> xr.Dataset:
    """Closed-loop modes of a linear model with the holds, one configuration per excited axis.

    ``model`` has A (state_dot, state) and B (state_dot, input) in analysis units and contains
    the rigid-body states (the quasi-steady model, or the full one with rotor, inflow and
    actuator states, which is what the holds really see). Returns, per ``excited`` axis,
    ``max_real`` (1/s, > 0 is unstable) and ``min_damping`` (smallest damping ratio of the
    oscillatory modes slower than ``slowest`` rad/s, the ones sweeps excite).
    """
    A = model["A"].transpose("state_dot", "state").values
    B = model["B"].sel(input=list(CONTROLS)).transpose("state_dot", "input").values
    states = list(model["state"].values)
    missing = [s for s in STATES_6DOF if s not in states]
    if missing:
        raise InputDataError(f"closed-loop check: the model lacks states {missing}")
    columns = [states.index(s) for s in STATES_6DOF]
    max_real, min_damping = [], []
    for axis in CONTROLS:
        K = np.zeros((len(CONTROLS), len(states)))
        K[:, columns] = hold_gains(loops, stab, trim_y, axis).values
        eig = np.linalg.eigvals(A + B @ K)
        max_real.append(float(eig.real.max()))
        oscillatory = eig[(np.abs(eig.imag) > 1e-6) & (np.abs(eig) < slowest)]
        min_damping.append(float(np.min(-oscillatory.real / np.abs(oscillatory)))
                           if oscillatory.size else 1.0)
    return xr.Dataset({"max_real": ("excited", max_real, {"units": "1/s"}),
                       "min_damping": ("excited", min_damping, {"units": "1"})},
                      coords={"excited": list(CONTROLS)})


def preflight_check(model: xr.Dataset, loops: dict[str, _Loop], campaign: Campaign,
                    trim_y: dict) -> xr.Dataset | None:
    """Refuse to fly holds that leave the linearised closed loop unstable; warn if lightly
    damped (a sweep through such a mode grows until the nonlinear aircraft departs)."""
    stab = campaign.stabilisation
    if not stab.enabled:
        return None
    modes = closed_loop_modes(model, loops, stab, trim_y)
    excited = {m.axis for m in campaign.maneuvers}
    for axis in CONTROLS:
        if axis not in excited:
            continue
        mode = modes.sel(excited=axis)
        # a neutral mode (eigenvalue 0 to round-off, e.g. an unheld velocity) is not unstable
        if float(mode.max_real) > 1e-6:
            raise InputDataError(
                f"campaign {campaign.name!r} at {campaign.flight_condition}: with {axis} "
                f"excited the holds leave the linearised closed loop unstable (eigenvalue real "
                f"part {float(mode.max_real):+.3f} /s); change the [stabilisation] crossover "
                "or vertical_speed_bandwidth")
        if float(mode.min_damping) < LIGHT_DAMPING:
            warnings.warn(
                f"campaign {campaign.name!r} at {campaign.flight_condition}: with {axis} "
                f"excited the closed loop has a mode at damping ratio "
                f"{float(mode.min_damping):.2f} (< {LIGHT_DAMPING}); sweeps through it may "
                "diverge: consider a higher [stabilisation] crossover", stacklevel=3)
    return modes


def _dead_band(value: float, width: float) -> float:
    return math.copysign(max(abs(value) - width, 0.0), value)


# ---------------------------------------------------------------------------------------
# Execution
# ---------------------------------------------------------------------------------------
def run_campaign(campaign: Campaign, output: str | Path | None = None, *, quiet: bool = False,
                 fmu=None, summaries: Sequence[Summary] = (), holds: str = "fmu"
                 ) -> xr.DataTree:
    """Fly every manoeuvre of ``campaign`` on the truth FMU; return (and write) the DataTree.

    With ``output`` the campaign is written to that netCDF file atomically, once, when every
    manoeuvre has been flown; if one fails (e.g. :class:`SimulationDiverged`, naming the
    manoeuvre and time) the ones completed before it are written before the error is
    raised. (Appending each manoeuvre as it completed rewrote the whole file every time:
    about 40 % of a quick campaign's run time.)

    ``summaries`` run on the completed campaign before it is written; each returns
    ``(group, dataset, message)`` (stored at ``/<group>``, message printed) or None. They come
    from higher layers, e.g. the cross-control coherence of
    :func:`sysid.spectral.cross_control.campaign_summary`.

    ``holds`` (:data:`HOLDS`): where the stabilisation is computed, inside the truth FMU
    (default) or in Python (the reference; same bytes, about 5x slower).

    Examples
    --------
    >>> campaign = default_campaign(0.0, seed=1).select("sweep_lon_*")
    >>> tree = run_campaign(campaign, "sweeps_lon.nc")
    >>> tree["maneuvers/sweep_lon_1"]["q"]               # deg/s, absolute, on ``time`` (s)
    """
    campaign.validate()
    if holds not in HOLDS:
        raise InputDataError(f"holds must be one of {HOLDS}, got {holds!r}")
    progress = Progress(quiet=quiet)
    model = truth.load_fmu(fmu)
    with progress.stage(f"trim and linearise at {campaign.flight_condition}"):
        trim = truth.trim(campaign.airspeed_kt, fmu=model)
        linearization = truth.linearize(trim, fmu=model)
    loops = design_loops(linearization.quasi_steady, campaign.stabilisation)
    modes = preflight_check(linearization.full, loops, campaign, trim.channel_values())
    tree = xr.DataTree(xr.Dataset(attrs=_campaign_attrs(campaign)))
    tree["trim"] = xr.DataTree(trim.to_dataset())
    tree["linearization"] = xr.DataTree(linearization.quasi_steady)
    tree["linearization_full"] = xr.DataTree(linearization.full)
    if modes is not None:
        tree["closed_loop"] = xr.DataTree(modes)
    if output is not None:
        output = Path(output)
        if output.exists():
            output.unlink()
    sim = truth.CoSimulation(model, outputs=MEASUREMENTS)
    try:
        for m in campaign.maneuvers:
            ds = fly(sim, trim, loops, m, campaign, progress=progress, holds=holds)
            tree[f"maneuvers/{m.name}"] = xr.DataTree(ds)
    except BaseException:
        if output is not None:
            write_campaign(tree, output)  # what was completed
        raise
    finally:
        sim.close()
    for summarise in summaries:
        result = summarise(tree)
        if result is not None:
            group, dataset, message = result
            tree[group] = xr.DataTree(dataset)
            progress.message(message)
    if output is not None:
        write_campaign(tree, output)
    return tree


def _campaign_attrs(campaign: Campaign) -> dict:
    return {
        "campaign": campaign.name,
        "flight_condition": campaign.flight_condition,
        "airspeed_kt": float(campaign.airspeed_kt),
        "seed": int(campaign.seed),
        "sysid_version": sysid.__version__,
        "campaign_toml": campaign.to_toml(),
    }


def fly(sim, trim, loops: dict[str, _Loop], maneuver: Maneuver, campaign: Campaign,
        progress: Progress | None = None, *, holds: str = "fmu") -> xr.Dataset:
    """Fly one manoeuvre from trim with the holds closed; return its time history.

    ``holds`` (:data:`HOLDS`): ``"fmu"`` steps the truth FMU through the whole pilot command
    with the holds computed inside it (:meth:`sysid.truth.CoSimulation.run`); ``"python"``
    computes them here at every step (:func:`_hold_commands`), the reference the FMU's law
    mirrors operation for operation.
    """
    if holds not in HOLDS:
        raise InputDataError(f"holds must be one of {HOLDS}, got {holds!r}")
    progress = progress or Progress(quiet=True)
    dt = 1.0 / campaign.sample_rate
    index = campaign.maneuvers.index(maneuver) if maneuver in campaign.maneuvers else 0
    seed = campaign.seed + 1000 * index  # each manoeuvre its own reproducible stream
    design = excitation(maneuver, dt, seed)
    n = design.size
    stab = campaign.stabilisation
    random = np.random.default_rng(seed)
    trim_u = np.array([trim.controls[c] for c in CONTROLS])
    axis = CONTROLS.index(maneuver.axis)
    # The pilot command: trim, the excitation on its axis and, with the holds on, seeded
    # band-limited (first-order, 2 rad/s) off-axis activity on the other axes.
    pilot = np.tile(trim_u, (n, 1))
    pilot[:, axis] += design
    if stab.enabled and stab.secondary_perturbation > 0:
        alpha = math.exp(-2.0 * dt)
        white = random.standard_normal((n, len(CONTROLS))) * math.sqrt(1 - alpha**2)
        white[0] = 0.0  # the activity starts from trim
        off_axis = stab.secondary_perturbation * scipy.signal.lfilter([1.0], [1.0, -alpha],
                                                                      white, axis=0)
        off_axis[:, axis] = 0.0
        pilot += off_axis
    gusts = None
    intensity = flown_turbulence(maneuver, campaign)
    if intensity > 0:
        g = inputs.dryden_turbulence(n * dt, dt=dt, airspeed=campaign.airspeed_kt * KT,
                                     altitude=30.0, intensity=intensity, seed=seed + 1)
        gusts = np.stack([g[c].values[:n] for c in ("u_gust", "v_gust", "w_gust")], axis=1)
        gusts = convert(gusts, "m/s", "ft/s")  # the stepping API takes gusts in ft/s

    trim_y = trim.channel_values()
    sim.name = maneuver.name
    col = {c: list(sim.output_names).index(c) for c in MEASUREMENTS}

    def report(fraction):
        if not progress.quiet:
            progress.stream.write(f"\r  {maneuver.name:<16} {100 * fraction:5.1f} %")
            progress.stream.flush()

    if holds == "fmu":
        sim.reset(trim, parameters=fmu_hold_parameters(loops, stab, trim_y, maneuver.axis))
        flight = sim.run(pilot, gusts, dt=dt, progress=None if progress.quiet else report)
        # What the step loop checks before each step, on the same samples and in its order.
        _check_excursions(flight.outputs[:n], col, trim_y, campaign, maneuver, dt)
        if flight.failure is not None:
            k = flight.steps
            raise SimulationDiverged(
                f"manoeuvre {maneuver.name!r} diverged at t = {k * dt:.2f} s: {flight.failure}",
                maneuver=maneuver.name, time=k * dt)
        applied = flight.applied
        measured = flight.outputs[:n][:, [col[c] for c in MEASUREMENTS]]
    else:
        y = sim.reset(trim)
        applied = np.empty((n, len(CONTROLS)))
        measured = np.empty((n, len(MEASUREMENTS)))
        fractions = {c: (stab.primary_fraction if c == maneuver.axis else 1.0)
                     for c in CONTROLS}
        for k in range(n):
            command = pilot[k]
            if stab.enabled:
                command = command + _hold_commands(y, col, trim_y, loops, fractions, stab)
            command = np.clip(command, 0.0, 100.0)
            applied[k] = command
            measured[k] = [y[col[c]] for c in MEASUREMENTS]
            _check_envelope(y, col, trim_y, campaign, maneuver, k * dt)
            try:
                y = sim.step(command, None if gusts is None else gusts[k], dt)
            except SimulationDiverged as exc:
                raise SimulationDiverged(
                    f"manoeuvre {maneuver.name!r} diverged at t = {k * dt:.2f} s: {exc}",
                    maneuver=maneuver.name, time=k * dt) from None
            if k % max(n // 30, 1) == 0:
                report(k / n)
    if not progress.quiet:
        progress.stream.write(f"\r  {maneuver.name:<16} 100.0 %\n")
    for j, c in enumerate(MEASUREMENTS):
        sigma = campaign.noise.get(c, 0.0)
        if sigma > 0:
            measured[:, j] += sigma * random.standard_normal(n)
    return _time_history(applied, measured, dt, maneuver, campaign, trim, sim, seed)


def fmu_hold_parameters(loops: dict[str, _Loop], stab: Stabilisation, trim_y: dict,
                        excited_axis: str) -> dict[str, float]:
    """The hold law of :func:`_hold_commands` as parameters of the truth FMU (``hold_*``).

    Gains already carry the weaker hold of ``excited_axis`` (``primary_fraction``), computed
    here exactly as :func:`_hold_commands` computes them, so the FMU's law
    (``fmus/helicopter/holds.c``) repeats the same floating-point operations. Trim
    references and dead bands are in analysis units. Holds off: ``hold_enabled = 0``.
    """
    if not stab.enabled:
        return {"hold_enabled": 0.0}
    expected = {"lon": ("theta", "q"), "lat": ("phi", "p"), "col": ("hdot", None),
                "ped": ("psi", "r")}
    parameters = {"hold_enabled": 1.0, "hold_velocity": float(stab.velocity_hold)}
    for control in CONTROLS:
        loop = loops[control]
        if (loop.error, loop.rate) != expected[control]:
            raise InputDataError(
                f"the FMU's {control} hold acts on {expected[control]}, the loop given acts on "
                f"{(loop.error, loop.rate)}: fly it with holds='python'")
        scale = stab.primary_fraction if control == excited_axis else 1.0
        if loop.error == "hdot":
            parameters[f"hold_k_error_{control}"] = scale * loop.k_error
        else:
            parameters[f"hold_k_error_{control}"] = loop.k_error * scale**2
            parameters[f"hold_k_rate_{control}"] = scale * loop.k_rate
        parameters[f"hold_derivative_{control}"] = loop.derivative
    parameters.update({f"hold_trim_{c}": float(trim_y[c]) for c in STATES_6DOF})
    band = stab.dead_band if stab.conditional else {}
    parameters.update({f"hold_dead_band_{k}": float(band.get(k, 0.0))
                       for k in ("attitude", "rate", "vertical_speed")})
    return parameters


def _hold_commands(y, col, trim_y, loops, fractions, stab) -> np.ndarray:
    """Stabilisation commands (% from trim) for every control, in CONTROLS order."""
    out = np.zeros(len(CONTROLS))
    band = stab.dead_band if stab.conditional else {"attitude": 0, "rate": 0,
                                                     "vertical_speed": 0}
    d = {c: y[col[c]] - trim_y[c] for c in MEASUREMENTS}
    # Weak outer velocity loops add to the attitude references (hover drift).
    theta_ref = stab.velocity_hold * d["u"] * 0.5 if stab.velocity_hold else 0.0
    phi_ref = -stab.velocity_hold * d["v"] * 0.5 if stab.velocity_hold else 0.0
    refs = {"phi": phi_ref, "theta": theta_ref, "psi": 0.0}
    for j, control in enumerate(CONTROLS):
        loop = loops[control]
        scale = fractions[control]
        if loop.error == "hdot":
            th, ph = math.radians(y[col["theta"]]), math.radians(y[col["phi"]])
            hdot = (y[col["u"]] * math.sin(th) - y[col["v"]] * math.sin(ph) * math.cos(th)
                    - y[col["w"]] * math.cos(ph) * math.cos(th))
            th0, ph0 = math.radians(trim_y["theta"]), math.radians(trim_y["phi"])
            hdot0 = (trim_y["u"] * math.sin(th0) - trim_y["v"] * math.sin(ph0) * math.cos(th0)
                     - trim_y["w"] * math.cos(ph0) * math.cos(th0))
            err = _dead_band(hdot - hdot0, band["vertical_speed"])
            out[j] = scale * loop.k_error * err / loop.derivative
            continue
        err = d[loop.error] - refs[loop.error]
        if loop.error == "psi":
            err = (err + 180.0) % 360.0 - 180.0
        err = _dead_band(err, band["attitude"])
        rate = _dead_band(d[loop.rate], band["rate"])
        k_error = loop.k_error * scale**2  # crossover scaled by `scale`
        out[j] = -(k_error * err + scale * loop.k_rate * rate) / loop.derivative
    return out


#: Excursion checks in the order the step loop makes them: (channel, limit attribute, unit).
_EXCURSIONS = (("phi", "max_attitude_excursion", "deg"), ("theta", "max_attitude_excursion", "deg"),
               ("u", "max_velocity_excursion", "ft/s"), ("v", "max_velocity_excursion", "ft/s"),
               ("w", "max_velocity_excursion", "ft/s"))


def _excursion(campaign, maneuver, t, check: int) -> SimulationDiverged:
    """The error of check 0 (non-finite outputs) or ``_EXCURSIONS[check - 1]`` at ``t``."""
    if check == 0:
        what = "non-finite outputs"
    else:
        c, limit, unit = _EXCURSIONS[check - 1]
        what = f"{c} left trim by more than {getattr(campaign, limit):g} {unit}"
    return SimulationDiverged(f"manoeuvre {maneuver.name!r} diverged at t = {t:.2f} s: {what}",
                              maneuver=maneuver.name, time=t)


def _check_envelope(y, col, trim_y, campaign, maneuver, t) -> None:
    """Raise SimulationDiverged if the outputs ``y`` of one step left trim too far."""
    if not np.all(np.isfinite(y)):
        raise _excursion(campaign, maneuver, t, 0)
    for check, (c, limit, _) in enumerate(_EXCURSIONS, start=1):
        if abs(y[col[c]] - trim_y[c]) > getattr(campaign, limit):
            raise _excursion(campaign, maneuver, t, check)


def _check_excursions(y, col, trim_y, campaign, maneuver, dt) -> None:
    """:func:`_check_envelope` on every row of ``y`` (one per step, ``dt`` apart from 0),
    vectorised: raises at the first row and check that fails."""
    bad = [~np.isfinite(y).all(axis=1)]
    bad += [np.abs(y[:, col[c]] - trim_y[c]) > getattr(campaign, limit)
            for c, limit, _ in _EXCURSIONS]
    bad = np.stack(bad, axis=1)
    rows = np.flatnonzero(bad.any(axis=1))
    if rows.size:
        k = int(rows[0])
        raise _excursion(campaign, maneuver, k * dt, int(np.argmax(bad[k])))


def _time_history(applied, measured, dt, maneuver, campaign, trim, sim, seed) -> xr.Dataset:
    n = applied.shape[0]
    time = np.arange(n) * dt
    data = {c: ("time", applied[:, j], channel_attrs(c)) for j, c in enumerate(CONTROLS)}
    data.update({c: ("time", measured[:, j], channel_attrs(c))
                 for j, c in enumerate(MEASUREMENTS)})
    attrs = {
        "maneuver": maneuver.name,
        "kind": maneuver.kind,
        "axis": maneuver.axis,
        "flight_condition": campaign.flight_condition,
        "airspeed_kt": float(campaign.airspeed_kt),
        "fmu_name": sim.fmu_name,
        "fmu_guid": sim.fmu_guid,
        "seed": int(seed),
        "sysid_version": sysid.__version__,
        "amplitude": float(maneuver.amplitude),
        "stabilisation": "on" + (" (conditional)" if campaign.stabilisation.conditional else "")
        if campaign.stabilisation.enabled else "off",
    }
    attrs["turbulence_m_s"] = flown_turbulence(maneuver, campaign)
    # the FMU is stepped with each command held over the step: the recorded samples relate
    # through a zero-order hold, which the frequency responses divide out
    attrs["input_hold"] = "zero_order"
    attrs.update({f"trim_{c}": float(v) for c, v in trim.channel_values().items()})
    return xr.Dataset(data, coords={"time": ("time", time, {"units": "s"})}, attrs=attrs)
