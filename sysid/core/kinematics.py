"""Rigid-body kinematic and gravity terms of the linearised 6-DoF equations.

A quasi-steady 6-DoF model (paper Eq. 18) is written as

    A = A_aero(derivatives) + A_kin(trim)

where ``A_kin`` holds the terms fixed by the trim condition alone: the gravity components,
the velocity cross-products (``-W0 q``, ``+U0 r``, ...) and the Euler-angle kinematics.
The named stability derivatives (``X_u``, ``M_q``, ...) are the *aerodynamic* part, i.e. the
entry of A minus the entry of ``A_kin``. The truth model's linearisation and the identified
models both use this convention, so their derivative tables compare like with like.

Units are the analysis units: states u v w in ft/s, p q r in deg/s, phi theta psi in deg.
A term coupling a velocity derivative (ft/s^2) to an angle or a rate (deg, deg/s) therefore
carries a factor pi/180.
"""

from __future__ import annotations

import math

import numpy as np
import xarray as xr

from sysid.core.units import FT, G0, STATES_6DOF

_RAD = math.pi / 180.0
_G_FT = G0 / FT  # gravity in ft/s^2


def rigid_body_terms(
    *,
    theta0: float,
    phi0: float,
    u0: float = 0.0,
    v0: float = 0.0,
    w0: float = 0.0,
    states=STATES_6DOF,
) -> xr.DataArray:
    """Kinematic and gravity part of A for straight, steady flight at the given trim.

    Parameters
    ----------
    theta0, phi0 : float
        Trim pitch and roll attitudes, deg.
    u0, v0, w0 : float
        Trim body velocities, ft/s.
    states : sequence of str
        State order; must contain the nine 6-DoF states ``u v w p q r phi theta psi``.

    Returns
    -------
    xr.DataArray
        Dims ``(state_dot, state)``, analysis units (ft/s, deg/s, deg).
    """
    missing = [s for s in STATES_6DOF if s not in states]
    if missing:
        raise ValueError(f"rigid_body_terms needs the 6-DoF states; missing {missing}")
    th, ph = theta0 * _RAD, phi0 * _RAD
    sth, cth, sph, cph = math.sin(th), math.cos(th), math.sin(ph), math.cos(ph)
    g = _G_FT
    terms = {
        # Force equations: u' = -(q W - r V) - g sin(theta) + X/m, etc. (body axes).
        ("u", "q"): -w0 * _RAD,
        ("u", "r"): v0 * _RAD,
        ("u", "theta"): -g * cth * _RAD,
        ("v", "p"): w0 * _RAD,
        ("v", "r"): -u0 * _RAD,
        ("v", "phi"): g * cth * cph * _RAD,
        ("v", "theta"): -g * sth * sph * _RAD,
        ("w", "p"): -v0 * _RAD,
        ("w", "q"): u0 * _RAD,
        ("w", "phi"): -g * cth * sph * _RAD,
        ("w", "theta"): -g * sth * cph * _RAD,
        # Euler kinematics at zero trim rates (deg/s -> deg/s, no unit factor).
        ("phi", "p"): 1.0,
        ("phi", "q"): sph * sth / cth,
        ("phi", "r"): cph * sth / cth,
        ("theta", "q"): cph,
        ("theta", "r"): -sph,
        ("psi", "q"): sph / cth,
        ("psi", "r"): cph / cth,
    }
    states = list(states)
    matrix = np.zeros((len(states), len(states)))
    index = {name: k for k, name in enumerate(states)}
    for (row, col), value in terms.items():
        matrix[index[row], index[col]] = value
    return xr.DataArray(
        matrix,
        dims=("state_dot", "state"),
        coords={"state_dot": states, "state": states},
        attrs={"long_name": "rigid-body kinematic and gravity terms", "theta0_deg": theta0,
               "phi0_deg": phi0, "u0_ft_s": u0, "v0_ft_s": v0, "w0_ft_s": w0},
    )


#: Force/moment letter of each 6-DoF state derivative, for derivative names like ``M_q``.
FORCE_LETTER = {"u": "X", "v": "Y", "w": "Z", "p": "L", "q": "M", "r": "N"}


def derivative_name(state_dot: str, column: str) -> str:
    """Conventional name of an A or B entry: ``derivative_name("q", "u") == "M_u"``."""
    return f"{FORCE_LETTER[state_dot]}_{column}"
