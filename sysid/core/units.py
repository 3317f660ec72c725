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

# Multiplicative factors from a unit to its SI base. Only units that occur in this project.
_TO_SI = {
    "1": 1.0,
    "%": 1.0,
    "percent": 1.0,
    "s": 1.0,
    "m": 1.0,
    "ft": FT,
    "m/s": 1.0,
    "ft/s": FT,
    "kt": KT,
    "m/s2": 1.0,
    "m/s^2": 1.0,
    "ft/s2": FT,
    "ft/s^2": FT,
    "rad": 1.0,
    "deg": DEG,
    "rad/s": 1.0,
    "deg/s": DEG,
    "rad/s2": 1.0,
    "deg/s2": DEG,
    "N": 1.0,
    "N.m": 1.0,
    "W": 1.0,
    "kg": 1.0,
    "kg.m2": 1.0,
}

# Units that may be converted into each other (same physical dimension).
_DIMENSION = {
    "1": "1", "%": "%", "percent": "%", "s": "s",
    "m": "L", "ft": "L",
    "m/s": "L/T", "ft/s": "L/T", "kt": "L/T",
    "m/s2": "L/T2", "m/s^2": "L/T2", "ft/s2": "L/T2", "ft/s^2": "L/T2",
    "rad": "A", "deg": "A",
    "rad/s": "A/T", "deg/s": "A/T",
    "rad/s2": "A/T2", "deg/s2": "A/T2",
    "N": "F", "N.m": "M", "W": "P", "kg": "kg", "kg.m2": "I",
}


def conversion_factor(from_unit: str, to_unit: str) -> float:
    """Factor ``k`` such that ``value_in_to_unit = k * value_in_from_unit``.

    Raises ``ValueError`` naming both units when they are unknown or of different dimension.
    """
    for unit in (from_unit, to_unit):
        if unit not in _TO_SI:
            raise ValueError(f"unknown unit {unit!r}; known units: {sorted(_TO_SI)}")
    if _DIMENSION[from_unit] != _DIMENSION[to_unit]:
        raise ValueError(f"cannot convert {from_unit!r} to {to_unit!r}: different dimensions")
    return _TO_SI[from_unit] / _TO_SI[to_unit]


def convert(value, from_unit: str, to_unit: str):
    """Convert ``value`` (scalar, array or xarray object) between two units."""
    return value * conversion_factor(from_unit, to_unit)


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


def channel_attrs(name: str) -> dict:
    """``units`` and ``long_name`` attributes for a channel in analysis units."""
    ch = CHANNELS[name]
    return {"units": ch.unit, "long_name": ch.long_name}


def db(x):
    """Magnitude in decibels, ``20 log10 |x|``."""
    return 20.0 * np.log10(np.abs(x))
