"""Numerical linearisation of the truth helicopter around a trim.

Full model
    Central differences of the model-exchange derivatives ``f(x, u)``:
    ``A[:, j] = (f(x + h_j e_j, u) - f(x - h_j e_j, u)) / (2 h_j)``, with the step
    ``h_j = step * nominal_j``: ``nominal_j`` is the state's nominal value declared by the FMU
    (10 m/s for velocities and induced velocities, 1 rad/s for rates, 1 rad for attitudes,
    0.1 rad for flapping and blade angles) and 1 % for the controls; ``step = 1e-5`` by
    default. The truncation error is O(h^2) and the round-off error ~1e-16 |f| / h, so the
    default step gives ~8 significant digits on the entries that matter. The full state is
    every FMU state except the navigation states ``x_n y_e h``, which are pure integrators
    that feed nothing back.

Quasi-steady 6-DoF reduction
    The rotor (flapping, inflow) and actuator states ``z`` are residualised, i.e. assumed at
    their instantaneous equilibrium ``dz/dt = 0``:
    ``A_r = A11 - A12 A22^-1 A21``, ``B_r = B1 - A12 A22^-1 B2``, over the nine states
    ``u v w p q r phi theta psi``.

Measured outputs
    The FMU's accelerometer outputs ``ax ay az`` (specific force at the CG) are linearised
    the same way, ``C[:, j] = (y(x + h_j e_j) - y(x - h_j e_j)) / (2 h_j)`` and likewise
    ``D`` (the outputs are read after setting the perturbed states and inputs), and appended
    as output rows of the full model.

Reduction to a structure (:func:`truth_for_structure`)
    Any structure's truth: residualise every state the structure does not have (e.g. keep
    ``u ... psi, a1, b1`` of a hybrid model), keep its outputs, then express the states the
    structure does not measure in the structure's own scaling (below), and read each
    parameter as "entry minus the structure's fixed part".

Named derivatives follow :mod:`sysid.core.kinematics`: ``X_u = A_r[u, u] - A_kin[u, u]`` etc.,
the aerodynamic part of the entry once the rigid-body kinematic and gravity terms of the trim
are removed. Everything is returned in analysis units (ft/s, deg/s, deg, %).
"""

from __future__ import annotations

import json
from dataclasses import dataclass

import numpy as np
import xarray as xr

import sysid
from sysid.fmi.runtime import DerivativeFunction, FMUModel
from sysid.truth.fmu import load_fmu
from sysid.truth.trim import NAVIGATION, TrimResult
from sysid.core.kinematics import FORCE_LETTER, derivative_name, rigid_body_terms
from sysid.core.units import (ACCELERATIONS, ANALYSIS_UNIT, CHANNELS, CONTROLS, STATES_6DOF,
                              conversion_factor)
from sysid.models import LinearStructure, residualize_model

#: Default relative finite-difference step (times the state's nominal value).
DEFAULT_STEP = 1e-5


def analysis_unit(model: FMUModel, name: str) -> str:
    """Analysis unit of an FMU variable: the paper's unit for a known channel, else the
    customary imperial/degree counterpart of its declared unit."""
    if name in CHANNELS:
        return CHANNELS[name].unit
    declared = model.unit(name)
    return ANALYSIS_UNIT.get(declared, declared)


def si_to_analysis(model: FMUModel, name: str) -> float:
    """Factor from the FMU's declared unit of ``name`` to its analysis unit."""
    return conversion_factor(model.unit(name), analysis_unit(model, name))


def _jacobians(f: DerivativeFunction, x0, u0, step, nominal) -> tuple[np.ndarray, np.ndarray]:
    n, m = len(x0), len(u0)
    A = np.empty((n, n))
    B = np.empty((n, m))
    for j in range(n):
        h = step * nominal[j]
        e = np.zeros(n)
        e[j] = h
        A[:, j] = (f(x0 + e, u0) - f(x0 - e, u0)) / (2 * h)
    for j in range(m):
        h = step * 1.0
        e = np.zeros(m)
        e[j] = h
        B[:, j] = (f(x0, u0 + e) - f(x0, u0 - e)) / (2 * h)
    return A, B


def jacobians_si(trim: TrimResult, *, step: float = DEFAULT_STEP, fmu=None
                 ) -> tuple[xr.DataArray, xr.DataArray]:
    """A and B of every FMU state (SI, FMU names), central differences with relative ``step``.

    Returns
    -------
    A : xr.DataArray, dims (state_dot, state)
    B : xr.DataArray, dims (state_dot, input)
    """
    model = _model(trim, fmu)
    f = DerivativeFunction(model, trim.parameters)
    try:
        names = model.state_names
        x0 = np.array([trim.states[s] for s in names])
        u0 = np.array([trim.controls[c] for c in CONTROLS])
        nominal = np.array([model.variable(s).nominal or 1.0 for s in names], dtype=float)
        A, B = _jacobians(f, x0, u0, step, nominal)
    finally:
        f.close()
    coords = {"state_dot": list(names), "state": list(names)}
    return (xr.DataArray(A, dims=("state_dot", "state"), coords=coords,
                         attrs={"units": "SI", "step": step}),
            xr.DataArray(B, dims=("state_dot", "input"),
                         coords={"state_dot": list(names), "input": list(CONTROLS)},
                         attrs={"units": "SI per %", "step": step}))


def output_jacobians_si(trim: TrimResult, names, *, step: float = DEFAULT_STEP, fmu=None
                        ) -> tuple[xr.DataArray, xr.DataArray]:
    """C and D of the FMU outputs ``names`` (SI) by central differences, like
    :func:`jacobians_si`: dims ``(output, state)`` and ``(output, input)``."""
    model = _model(trim, fmu)
    f = DerivativeFunction(model, trim.parameters)
    names = list(names)
    try:
        states = model.state_names
        x0 = np.array([trim.states[s] for s in states])
        u0 = np.array([trim.controls[c] for c in CONTROLS])
        nominal = np.array([model.variable(s).nominal or 1.0 for s in states], dtype=float)

        def y(x, u):
            vals = f.outputs(x, u, names)
            return np.array([vals[k] for k in names], dtype=float)

        C = np.empty((len(names), len(states)))
        D = np.empty((len(names), len(CONTROLS)))
        for j in range(len(states)):
            e = np.zeros(len(states))
            e[j] = step * nominal[j]
            C[:, j] = (y(x0 + e, u0) - y(x0 - e, u0)) / (2 * e[j])
        for j in range(len(CONTROLS)):
            e = np.zeros(len(CONTROLS))
            e[j] = step
            D[:, j] = (y(x0, u0 + e) - y(x0, u0 - e)) / (2 * step)
    finally:
        f.close()
    return (xr.DataArray(C, dims=("output", "state"),
                         coords={"output": names, "state": list(states)}),
            xr.DataArray(D, dims=("output", "input"),
                         coords={"output": names, "input": list(CONTROLS)}))


def _model(trim: TrimResult, fmu) -> FMUModel:
    if isinstance(fmu, FMUModel):
        return fmu
    return load_fmu(fmu if fmu is not None else trim.fmu_path)


def _to_analysis(model, A: np.ndarray, B: np.ndarray, states) -> tuple[np.ndarray, np.ndarray]:
    k = np.array([si_to_analysis(model, s) for s in states])
    return A * k[:, None] / k[None, :], B * k[:, None]


def residualize(A: np.ndarray, B: np.ndarray, slow: list[int], fast: list[int]):
    """Quasi-steady reduction: ``A11 - A12 A22^-1 A21`` and ``B1 - A12 A22^-1 B2``."""
    A12 = A[np.ix_(slow, fast)]
    A22 = A[np.ix_(fast, fast)]
    solve_A = np.linalg.solve(A22, A[np.ix_(fast, slow)])
    solve_B = np.linalg.solve(A22, B[fast])
    return A[np.ix_(slow, slow)] - A12 @ solve_A, B[slow] - A12 @ solve_B


def _common_attrs(trim: TrimResult, step: float) -> dict:
    return {"method": "linearization", "flight_condition": trim.flight_condition,
            "airspeed_kt": float(trim.airspeed_kt), "fmu_name": trim.fmu_name,
            "fmu_guid": trim.fmu_guid, "sysid_version": sysid.__version__,
            "finite_difference_step": step,
            "finite_difference": "central differences of the ME derivatives, "
                                 "h_j = step * nominal_j (controls: step * 1 %)"}


def _eigen(A: np.ndarray) -> xr.DataArray:
    ev = np.linalg.eigvals(A)
    ev = ev[np.lexsort((ev.imag, -np.abs(ev)))]
    return xr.DataArray(ev, dims="mode", coords={"mode": np.arange(len(ev))},
                        attrs={"units": "1/s", "long_name": "eigenvalues of A"})


@dataclass(frozen=True)
class Linearization:
    """Linearisation of the truth helicopter at one trim.

    Attributes
    ----------
    full : xr.Dataset
        ``A (state_dot, state)``, ``B (state_dot, input)`` over every FMU state except
        navigation, analysis units, with ``C = I`` and ``D = 0`` (every state an output);
        ``eigenvalue (mode)``.
    quasi_steady : xr.Dataset
        The 6-DoF quasi-steady model per ``docs/data_model.md`` (method ``linearization``):
        ``A B C D delay trim_input trim_output``, named derivatives on the ``parameter``
        dimension, ``eigenvalue (mode)``.
    trim : TrimResult
    """

    full: xr.Dataset
    quasi_steady: xr.Dataset
    trim: TrimResult

    @property
    def eigenvalues_full(self) -> np.ndarray:
        return self.full["eigenvalue"].values

    @property
    def eigenvalues_reduced(self) -> np.ndarray:
        return self.quasi_steady["eigenvalue"].values

    def derivatives(self) -> xr.DataArray:
        """Named derivatives (``X_u`` ... ``N_ped``) as a DataArray on ``parameter``."""
        return self.quasi_steady["value"]


def linearize(trim: TrimResult, *, step: float = DEFAULT_STEP, fmu=None) -> Linearization:
    """Linearise the helicopter at ``trim``: full model and quasi-steady 6-DoF model.

    Parameters
    ----------
    trim : TrimResult
        From :func:`sysid.truth.trim`.
    step : float
        Relative central-difference step (see module docstring).
    fmu : path or FMUModel, optional
        Defaults to the FMU the trim was computed with.
    """
    model = _model(trim, fmu)
    A_si, B_si = jacobians_si(trim, step=step, fmu=model)
    names = [s for s in model.state_names if s not in NAVIGATION]
    A = A_si.sel(state_dot=names, state=names).values
    B = B_si.sel(state_dot=names).values
    A_an, B_an = _to_analysis(model, A, B, names)
    attrs = _common_attrs(trim, step)

    # Every state is an output (C = I, D = 0), and so are the accelerometers the FMU has, so
    # the full model is a complete model Dataset: sysid.models.frequency_response evaluates it
    # like any identified model.
    n = len(names)
    acc = [a for a in ACCELERATIONS if a in model.output_names]
    C_an, D_an = np.eye(n), np.zeros((n, len(CONTROLS)))
    if acc:
        Cy, Dy = output_jacobians_si(trim, acc, step=step, fmu=model)
        ky = np.array([si_to_analysis(model, a) for a in acc])
        kx = np.array([si_to_analysis(model, s) for s in names])
        C_an = np.vstack([C_an, Cy.sel(state=names).values * ky[:, None] / kx[None, :]])
        D_an = np.vstack([D_an, Dy.values * ky[:, None]])
    full = xr.Dataset(
        {"A": (("state_dot", "state"), A_an), "B": (("state_dot", "input"), B_an),
         "C": (("output", "state"), C_an),
         "D": (("output", "input"), D_an),
         "eigenvalue": _eigen(A_an)},
        coords={"state_dot": names, "state": names, "output": names + acc,
                "input": list(CONTROLS),
                "unit": ("state", [analysis_unit(model, s) for s in names])},
        attrs={**attrs, "structure": "full"})

    slow = [names.index(s) for s in STATES_6DOF]
    fast = [k for k, s in enumerate(names) if s not in STATES_6DOF]
    Ar, Br = residualize(A_an, B_an, slow, fast)
    quasi = _quasi_steady_dataset(Ar, Br, trim, attrs)
    return Linearization(full=full, quasi_steady=quasi, trim=trim)


def truth_for_structure(full: xr.Dataset, structure: LinearStructure) -> xr.Dataset:
    """The truth linearisation as a model of ``structure``: its states, outputs, parameters.

    ``full`` is :attr:`Linearization.full` (or ``/linearization_full`` of a campaign). Steps:

    1. residualise every state the structure lacks (:func:`sysid.models.residualize_model`),
       keeping the structure's outputs (the accelerometer rows come from the FMU's outputs);
    2. unmeasured states (no output reads them directly) are defined only up to a change of
       coordinates ``z' = T z``; the structure fixes it through the A entries it holds fixed
       in their rows, e.g. ``A[a1,q] = A[b1,p] = -1`` of a hybrid model (an entry with a free
       part, e.g. an inflow row tied to Z_w, fixes nothing: that state keeps the truth's
       scale). ``T`` solves
       ``T A_truth[z, Q] = A_structure[z, Q]`` (least squares) over the measured columns
       ``Q`` where every z-row entry is fixed and some is non-zero; then ``A' = S A S^-1``,
       ``B' = S B``, ``C' = C S^-1`` with ``S = diag(I, T)``. Without such columns ``T = I``.
       For the hybrid models this maps the truth's tip-path-plane angles (``a1`` aft,
       ``b1`` to starboard, deg) onto the structure's normalised flapping states;
    3. each parameter is the entry minus the structure's fixed part
       (:meth:`LinearStructure.values_from_model`), with the output equations removed from
       C and D; delays are 0 (the truth's actuator lags are residualised states).

    Returns the model Dataset of ``structure`` at those values (``value`` per parameter,
    matrices of the structure), with attributes ``method = "linearization"`` and
    ``normalisation`` (T, row-major) -- the parameters' truth values.
    """
    states, outputs = list(structure.states), list(structure.outputs)
    avail = [str(o) for o in full["C"].output.values]
    missing = [o for o in outputs if o not in avail]
    if missing:
        raise ValueError(f"truth_for_structure: the linearisation has no outputs {missing} "
                         f"(has {avail})")
    red = residualize_model(full, states, outputs)
    A, B, C, D = (red[k].values.copy() for k in ("A", "B", "C", "D"))
    measured = np.any(structure.C0 != 0, axis=0) | np.any(structure.M != 0, axis=0)
    z = [i for i, s in enumerate(states) if not measured[i] and s not in STATES_6DOF]
    # states with no fixed entry on a measured column (e.g. actuators with the truth's names
    # and known gearing) keep the truth's scale
    free = np.zeros_like(structure.A0, dtype=bool)
    fixedA = structure.A0.copy()
    vals = structure.values()
    for k in (k for k, p in enumerate(structure.parameters) if p.matrix == "A"):
        for r, c, scale in structure.entries_of(k):  # every entry of a tied parameter
            if structure.parameters[k].free:
                free[r, c] = True
            else:
                fixedA[r, c] += scale * vals[k]
    # ... and that entry has no free part (a held entry a free tie adds to, e.g. an inflow
    # row tied to the heave damping, does not fix the state's scale)
    z = [i for i in z if np.any((fixedA[i] != 0) & measured & ~free[i])]
    T = np.eye(len(z))
    if z:
        Q = [j for j in range(len(states)) if j not in z and not free[z, j].any()
             and np.any(fixedA[z, j] != 0)]
        if len(Q) >= len(z):
            T = np.linalg.lstsq(A[np.ix_(z, Q)].T, fixedA[np.ix_(z, Q)].T, rcond=None)[0].T
            S = np.eye(len(states))
            S[np.ix_(z, z)] = T
            Si = np.linalg.inv(S)
            A, B, C = S @ A @ Si, S @ B, C @ Si
    model = structure.to_dataset()
    model["A"].values, model["B"].values = A, B
    model["C"].values, model["D"].values = C, D
    # C and D carry the output equations; strip them so values_from_model reads C/D params
    model_plain = model.copy()
    if structure.has_output_equations:
        model_plain["C"].values = C - structure.M @ (A - structure.K)
        model_plain["D"].values = D - structure.M @ B
    theta = structure.values_from_model(model_plain)
    delay_free = [j for j, k in enumerate(structure.free_index)
                  if structure.parameters[k].matrix == "delay"]
    theta[delay_free] = 0.0
    values = structure.values(theta)
    for k, p in enumerate(structure.parameters):  # fixed parameters read from the truth too
        if not p.free and p.matrix in "AB":
            src = A if p.matrix == "A" else B
            cols = states if p.matrix == "A" else list(structure.inputs)
            fixed0 = structure.A0 if p.matrix == "A" else structure.B0
            r, c = states.index(p.row), cols.index(p.column)
            others = sum(scale * values[m] for m in range(len(values)) if m != k
                         and structure.parameters[m].matrix == p.matrix
                         for i, j, scale in structure.entries_of(m) if (i, j) == (r, c))
            values[k] = src[r, c] - fixed0[r, c] - others
    model["value"].values = values
    model.attrs.update(full.attrs)
    model.attrs.update({"method": "linearization", "structure": structure.name,
                        "normalisation": json.dumps(np.round(T, 12).tolist()),
                        "reduction": "residualised: " + red.attrs.get("residualized", "")})
    return model


def _quasi_steady_dataset(Ar, Br, trim: TrimResult, attrs: dict) -> xr.Dataset:
    states = list(STATES_6DOF)
    values = trim.channel_values()
    kin = rigid_body_terms(theta0=values["theta"], phi0=values["phi"], u0=values["u"],
                           v0=values["v"], w0=values["w"], states=states).values
    rows = [s for s in states if s in FORCE_LETTER]
    names, value, matrix, row, column = [], [], [], [], []
    for i, rname in enumerate(states):
        if rname not in FORCE_LETTER:
            continue
        for j, cname in enumerate(states):
            if cname in FORCE_LETTER:
                names.append(derivative_name(rname, cname))
                value.append(Ar[i, j] - kin[i, j])
                matrix.append("A")
                row.append(rname)
                column.append(cname)
    for i, rname in enumerate(states):
        if rname not in rows:
            continue
        for j, cname in enumerate(CONTROLS):
            names.append(derivative_name(rname, cname))
            value.append(Br[i, j])
            matrix.append("B")
            row.append(rname)
            column.append(cname)
    n_par = len(names)
    nan = np.full(n_par, np.nan)
    ds = xr.Dataset(
        {
            "A": (("state_dot", "state"), Ar),
            "B": (("state_dot", "input"), Br),
            "C": (("output", "state"), np.eye(len(states))),
            "D": (("output", "input"), np.zeros((len(states), len(CONTROLS)))),
            "delay": (("state_dot", "input"), np.zeros((len(states), len(CONTROLS)))),
            "trim_input": ("input", [values[c] for c in CONTROLS]),
            "trim_output": ("output", [values[s] for s in states]),
            "value": ("parameter", np.array(value)),
            "cramer_rao": ("parameter", nan),
            "cramer_rao_percent": ("parameter", nan),
            "insensitivity": ("parameter", nan),
            "insensitivity_percent": ("parameter", nan),
            "free": ("parameter", np.ones(n_par, dtype=bool)),
            "matrix": ("parameter", np.array(matrix)),
            "row": ("parameter", np.array(row)),
            "column": ("parameter", np.array(column)),
            "eigenvalue": _eigen(Ar),
        },
        coords={"state_dot": states, "state": states, "input": list(CONTROLS),
                "output": states, "parameter": names},
        attrs={**attrs, "structure": "quasi_steady_6dof",
               "derivative_convention": "named derivative = A_r entry minus "
                                        "sysid.core.kinematics.rigid_body_terms(trim)",
               "units": "ft/s, deg/s, deg, %"},
    )
    ds["A"].attrs["long_name"] = "quasi-steady state matrix (rotor/inflow/actuators residualised)"
    ds["B"].attrs["long_name"] = "quasi-steady control matrix"
    ds["delay"].attrs["units"] = "s"
    ds["value"].attrs["long_name"] = "named stability and control derivatives"
    for name in ("trim_input", "trim_output"):
        ds[name].attrs["long_name"] = "absolute trim value, analysis units"
    return ds
