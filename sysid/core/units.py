"""Units and channel metadata.

The FMUs work in SI and declare their units in ``modelDescription.xml``. Analysis is done in
the paper's units (ft/s, deg/s, deg, ft/s^2, percent of control travel, rad/s for frequency).
Conversion happens once, at the FMU boundary, with :func:`convert` from the unit the FMU
declares to the analysis unit listed in :data:`CHANNELS`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

FT = 0.3048  #: metres per foot (exact, international foot)
DEG = math.pi / 180.0  #: radians per degree
KT = 1852.0 / 3600.0  #: metres per second per knot (exact)
G0 = 9.80665  #: standard gravity, m/s^2

#: SI base units in the order of the attributes of FMI 2.0's ``<BaseUnit>``.
BASE_UNITS = ("kg", "m", "s", "A", "K", "mol", "cd", "rad")


@dataclass(frozen=True)
class Unit:
    """A unit as SI base-unit exponents and a factor: SI value = ``factor`` * value.

    This is FMI 2.0's ``<BaseUnit>`` (exponents per :data:`BASE_UNITS`, ``factor``), so the
    one table :data:`UNITS` both converts values and writes the FMUs' unit definitions.
    """

    name: str
    exponents: tuple[tuple[str, int], ...] = ()  #: (base unit, exponent), non-zero, in order
    factor: float = 1.0

    @classmethod
    def of(cls, name: str, factor: float = 1.0, **exponents: int) -> "Unit":
        return cls(name, tuple((b, int(exponents[b])) for b in BASE_UNITS
                               if exponents.get(b)), float(factor))


_U = Unit.of
#: Every unit of this project. Percent of control travel is the dimensionless ratio 1/100
#: (SI Brochure; FMI 2.0 <BaseUnit factor="0.01"/>), as both FMU tables already declared it:
#: converting % to % is 1 and % to 1 is 0.01, not a dimension of its own.
UNITS: dict[str, Unit] = {u.name: u for u in (
    _U("1"), _U("%", 0.01), _U("percent", 0.01),
    _U("s", s=1),
    _U("m", m=1), _U("ft", FT, m=1), _U("m2", m=2), _U("m3", m=3),
    _U("m/s", m=1, s=-1), _U("ft/s", FT, m=1, s=-1), _U("kt", KT, m=1, s=-1),
    _U("m/s2", m=1, s=-2), _U("m/s^2", m=1, s=-2), _U("ft/s2", FT, m=1, s=-2),
    _U("ft/s^2", FT, m=1, s=-2),
    _U("rad", rad=1), _U("deg", DEG, rad=1), _U("1/rad", rad=-1),
    _U("rad/s", rad=1, s=-1), _U("deg/s", DEG, rad=1, s=-1),
    _U("rad/s2", rad=1, s=-2), _U("deg/s2", DEG, rad=1, s=-2),
    _U("kg", kg=1), _U("kg.m2", kg=1, m=2), _U("kg/m3", kg=1, m=-3),
    _U("N", kg=1, m=1, s=-2), _U("N.m", kg=1, m=2, s=-2),
    _U("N.m/rad", kg=1, m=2, s=-2, rad=-1), _U("W", kg=1, m=2, s=-3),
)}
del _U

#: Display units the FMUs declare for an SI unit (FMI ``<DisplayUnit>``), first one preferred.
DISPLAY_UNITS = {"m": ("ft",), "m/s": ("ft/s", "kt"), "m/s2": ("ft/s2",), "rad": ("deg",),
                 "rad/s": ("deg/s",), "rad/s2": ("deg/s2",)}
#: SI unit of the time derivative of a state in the given SI unit.
DERIVATIVE_UNIT = {"m": "m/s", "m/s": "m/s2", "rad": "rad/s", "rad/s": "rad/s2"}
#: Analysis (the paper's) unit of an FMU's SI unit, for variables outside :data:`CHANNELS`.
ANALYSIS_UNIT = {"m/s": "ft/s", "rad/s": "deg/s", "rad": "deg", "m/s2": "ft/s^2", "m": "ft",
                 "%": "%"}


def conversion_factor(from_unit: str, to_unit: str) -> float:
    """Factor ``k`` such that ``value_in_to_unit = k * value_in_from_unit``.

    Raises ``ValueError`` naming both units when they are unknown or of different dimension.
    """
    for unit in (from_unit, to_unit):
        if unit not in UNITS:
            raise ValueError(f"unknown unit {unit!r}; known units: {sorted(UNITS)}")
    a, b = UNITS[from_unit], UNITS[to_unit]
    if a.exponents != b.exponents:
        raise ValueError(f"cannot convert {from_unit!r} to {to_unit!r}: different dimensions")
    return a.factor / b.factor


def convert(value, from_unit: str, to_unit: str):
    """Convert ``value`` (scalar, array or xarray object) between two units."""
    return value * conversion_factor(from_unit, to_unit)


def display_units(unit: str) -> tuple[tuple[str, float], ...]:
    """FMI display units of ``unit``: ``(name, factor)`` with display value = factor * value."""
    return tuple((d, conversion_factor(unit, d)) for d in DISPLAY_UNITS.get(unit, ()))


@dataclass(frozen=True)
class Channel:
    """One measured or commanded quantity: its name, meaning and units."""

    name: str
    long_name: str
    unit: str  #: analysis unit (the paper's)
    si_unit: str  #: unit declared by the truth FMU


#: Controls (inputs), percent of travel, in the paper's order.
CONTROLS = ("lon", "lat", "col", "ped")
#: The 6-DoF quasi-steady states, in the paper's order.
STATES_6DOF = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi")
#: Accelerations at the centre of gravity (body axes).
ACCELERATIONS = ("ax", "ay", "az")

CHANNELS: dict[str, Channel] = {
    c.name: c
    for c in (
        Channel("lon", "longitudinal cyclic stick", "%", "%"),
        Channel("lat", "lateral cyclic stick", "%", "%"),
        Channel("col", "collective lever", "%", "%"),
        Channel("ped", "pedals", "%", "%"),
        Channel("u", "body longitudinal velocity", "ft/s", "m/s"),
        Channel("v", "body lateral velocity", "ft/s", "m/s"),
        Channel("w", "body vertical velocity", "ft/s", "m/s"),
        Channel("p", "roll rate", "deg/s", "rad/s"),
        Channel("q", "pitch rate", "deg/s", "rad/s"),
        Channel("r", "yaw rate", "deg/s", "rad/s"),
        Channel("phi", "roll attitude", "deg", "rad"),
        Channel("theta", "pitch attitude", "deg", "rad"),
        Channel("psi", "heading", "deg", "rad"),
        Channel("ax", "longitudinal acceleration at the CG", "ft/s^2", "m/s2"),
        Channel("ay", "lateral acceleration at the CG", "ft/s^2", "m/s2"),
        Channel("az", "vertical acceleration at the CG", "ft/s^2", "m/s2"),
    )
}


#: Values no rotorcraft channel can take, in analysis units: ``channel -> (lowest, highest)``.
#: Not flight-envelope limits but bounds of the physically possible, so that a corrupted
#: sample (e.g. 1e300 from a broken logger) is refused where it enters instead of
#: derailing a fit: control travel one full travel beyond either stop; body velocities
#: about 590 kt; angular rates ten revolutions per second; bank and pitch one turn either
#: way (unwrapped records); heading 100 turns (unwrapped yaw of a long record);
#: accelerations 100 g (G0 = 32.17 ft/s^2).
PHYSICAL_RANGE: dict[str, tuple[float, float]] = {
    **{c: (-100.0, 200.0) for c in ("lon", "lat", "col", "ped")},
    **{c: (-1000.0, 1000.0) for c in ("u", "v", "w")},
    **{c: (-3600.0, 3600.0) for c in ("p", "q", "r")},
    "phi": (-360.0, 360.0), "theta": (-360.0, 360.0), "psi": (-36000.0, 36000.0),
    **{c: (-100 * G0 / FT, 100 * G0 / FT) for c in ("ax", "ay", "az")},
}


def physical_range(channel: str, unit: str | None = None) -> tuple[float, float] | None:
    """:data:`PHYSICAL_RANGE` of ``channel`` in ``unit`` (default its analysis unit); None
    for a channel outside the table or a unit that does not convert to the analysis unit."""
    if channel not in PHYSICAL_RANGE:
        return None
    lo, hi = PHYSICAL_RANGE[channel]
    if unit and unit != CHANNELS[channel].unit:
        try:
            k = conversion_factor(CHANNELS[channel].unit, unit)
        except ValueError:
            return None
        lo, hi = sorted((lo * k, hi * k))
    return lo, hi


def channel_attrs(name: str) -> dict:
    """``units`` and ``long_name`` attributes for a channel in analysis units."""
    ch = CHANNELS[name]
    return {"units": ch.unit, "long_name": ch.long_name}


def db(x):
    """Magnitude in decibels, ``20 log10 |x|``."""
    return 20.0 * np.log10(np.abs(x))
