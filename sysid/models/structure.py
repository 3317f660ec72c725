"""Parametrised linear model structures with input time delays (paper Eq. 18-19).

A structure is the state-space model

    x' = A x + B~(s) u ,   y = C x + D u ,   T(s) = C (sI - A)^-1 B~(s) + D        (Eq. 18-19)

in analysis units (ft/s, deg/s, deg, % of travel), where ``B~(s) = B o exp(-s tau)`` delays
each B entry by its own ``tau`` (s); a delay "on an input" is the same value on every entry of
that column. Every matrix is ``fixed part + parameters``: each :class:`Parameter` adds its
value to one entry of A, B, C or D, or sets the delay of one B entry (or input column). In the
built-in 6-DoF structure (:func:`six_dof_structure`) ``A = A_kin(trim) + A_aero(derivatives)``
(:func:`sysid.core.kinematics.rigid_body_terms`). :meth:`LinearStructure.to_dataset` writes the
model Dataset of ``docs/data_model.md``; :func:`model_from_dataset` reads it back.

Output equations. Outputs need not be states: besides the fixed and parametrised ``C, D``, an
output may be a combination of state *derivatives* with the kinematic part removed,

    y = C x + D u + M (x' - K x) = (C + M (A - K)) x + (D + M B) u ,

where ``M`` (n_output x n_state) weights the derivative rows and ``K`` is the rigid-body
kinematic and gravity part of ``A`` (:func:`sysid.core.kinematics.rigid_body_terms`). An
accelerometer at the centre of gravity measures the specific force, i.e. ``ax = u' - K_u x``:
the aerodynamic and control part of the ``u`` force row, so ``X_u ... X_ped`` act on both the
``u`` row of A/B and the ``ax`` row of C/D through the *same* parameter. A sensor ahead of or
beside the CG adds the lever-arm terms ``omega' x r`` (rows ``p q r`` of ``M``; the centripetal
term ``omega x (omega x r)`` is quadratic in the rates and vanishes to first order about the
zero trim rates of steady straight flight). ``M`` may not touch a delayed B entry (the output
would need a delayed feed-through, which the model Dataset cannot hold).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 7 (state-space models with time delays).
* "Comparison of frequency and time domain identification of a helicopter in hover" (the
  reference paper of this project), Eq. 18-19.
"""

from __future__ import annotations

import dataclasses
import json
import math
from dataclasses import dataclass
from typing import Iterable, Mapping, Sequence

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.kinematics import derivative_name, rigid_body_terms
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.models.lti import model_matrices, statespace, transfer_matrix

__all__ = ["Parameter", "LinearStructure", "six_dof_structure", "model_from_dataset",
           "structure_summary", "parse_delay_entry", "entry_name", "DELAY_BOUNDS", "ALL_ROWS",
           "FORCE_STATES"]

#: Physical range of a free delay, s (docs/methods.md, "Delays": 0 to about 0.3 s).
DELAY_BOUNDS = (0.0, 0.3)

_MATRICES = ("A", "B", "C", "D", "delay")
#: ``row`` of a delay parameter that applies to every entry of its input column.
ALL_ROWS = "*"


# --------------------------------------------------------------------------------------------
# Parameters and structures
# --------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Parameter:
    """One named scalar of a structure.

    Attributes
    ----------
    name : str
        Unique name, e.g. ``"M_q"``, ``"L_lon"``, ``"tau_L_lon"`` or ``"A[phi,p]"``.
    matrix : {"A", "B", "C", "D", "delay"}
        Where it acts. An A/B/C/D parameter is *added* to the fixed part of its entry; a delay
        parameter *is* the delay (s) of its B entry, or of every entry of its input column when
        ``row == "*"``.
    row, column : str
        Entry: ``state_dot`` x ``state`` (A), ``state_dot`` x ``input`` (B, delay),
        ``output`` x ``state`` (C), ``output`` x ``input`` (D).
    value : float
        Start value of a free parameter, the value of a fixed one (analysis units).
    free : bool
        Estimated (True) or held at ``value`` (False).
    lower, upper : float
        Bounds of a free parameter (``-inf``/``inf`` for none; delays default to
        :data:`DELAY_BOUNDS`).
    keep : bool
        Never removed by model reduction (:mod:`sysid.identify.reduction`): the structure's
        author knows the effect exists, e.g. an on-axis delay standing for the actuators and
        rotor, whose Cramer-Rao bound sits near the guideline only because it trades off
        against a damping derivative.
    also : tuple of (row, column, scale)
        Further entries of the same matrix (A or B) the parameter sets, each to
        ``scale * value``: a physical constant that appears in several equations is one
        unknown, e.g. one flapping time constant on the a1 and b1 rows, or the tail rotor's
        thrust in the roll and yaw rows (the scale its arms' ratio). Tying such entries
        removes a direction the data cannot separate from the fit. Parts on one entry add:
        a held parameter may give an entry the known part of a free one's tie (e.g. the
        inflow row of ``hover_hybrid_inflow``), two free parameters may not share one.
    """

    name: str
    matrix: str
    row: str
    column: str
    value: float = 0.0
    free: bool = True
    lower: float = -math.inf
    upper: float = math.inf
    keep: bool = False
    also: tuple = ()

    def replace(self, **changes) -> "Parameter":
        return dataclasses.replace(self, **changes)


def entry_name(matrix: str, row: str, column: str) -> str:
    return f"{matrix}[{row},{column}]"


class LinearStructure:
    """A parametrised state-space structure ``(A, B, C, D, delays)`` (paper Eq. 18-19).

    Parameters
    ----------
    states, inputs, outputs : sequence of str
        Names; ``outputs`` defaults to ``states`` (``C = I``).
    A0, B0, C0, D0 : array_like, optional
        Fixed parts, shapes (n_state, n_state), (n_state, n_input), (n_output, n_state),
        (n_output, n_input). Defaults: zeros, zeros, identity selection of the outputs that
        are states, zeros.
    parameters : sequence of Parameter
        Free and fixed parameters; each A/B/C/D entry and each B delay is set by at most one.
    trim_input, trim_output : mapping, optional
        Absolute trim values (analysis units); default 0.
    name, description : str
    attrs : mapping, optional
        Extra metadata (e.g. the trim attitudes used for the kinematic terms).
    output_equation : array_like, optional
        ``M``, shape (n_output, n_state): weights of the state-derivative rows in each output
        (``y += M (x' - K x)``; module docstring). Default zeros.
    kinematic : array_like, optional
        ``K``, shape (n_state, n_state): the kinematic/gravity part of A that an output
        equation removes (specific force excludes gravity). Default zeros.
    """

    def __init__(self, *, states: Sequence[str], inputs: Sequence[str],
                 outputs: Sequence[str] | None = None, A0=None, B0=None, C0=None, D0=None,
                 parameters: Iterable[Parameter] = (), trim_input: Mapping | None = None,
                 trim_output: Mapping | None = None, name: str = "user",
                 description: str = "", attrs: Mapping | None = None,
                 output_equation=None, kinematic=None):
        self.states = tuple(states)
        self.inputs = tuple(inputs)
        self.outputs = tuple(outputs) if outputs is not None else self.states
        for label, names in (("states", self.states), ("inputs", self.inputs),
                             ("outputs", self.outputs)):
            if len(set(names)) != len(names) or not names:
                raise InputDataError(f"structure {name!r}: {label} must be a non-empty list of "
                                     f"unique names, got {list(names)}")
        n, m, p = len(self.states), len(self.inputs), len(self.outputs)
        self.A0 = _matrix(A0, (n, n), "A0", name)
        self.B0 = _matrix(B0, (n, m), "B0", name)
        if C0 is None:
            C0 = np.zeros((p, n))
            for i, out in enumerate(self.outputs):
                if out in self.states:
                    C0[i, self.states.index(out)] = 1.0
        self.C0 = _matrix(C0, (p, n), "C0", name)
        self.D0 = _matrix(D0, (p, m), "D0", name)
        self.M = _matrix(output_equation, (p, n), "output_equation", name)
        self.K = _matrix(kinematic, (n, n), "kinematic", name)
        self.parameters = tuple(parameters)
        self.name = name
        self.description = description
        self.attrs = dict(attrs or {})
        self.trim_input = {k: float((trim_input or {}).get(k, 0.0)) for k in self.inputs}
        self.trim_output = {k: float((trim_output or {}).get(k, 0.0)) for k in self.outputs}
        self._index()

    # -- bookkeeping ---------------------------------------------------------------------

    def _index(self) -> None:
        names = [p.name for p in self.parameters]
        dup = {x for x in names if names.count(x) > 1}
        if dup:
            raise InputDataError(f"structure {self.name!r}: duplicate parameter names {sorted(dup)}")
        axes = {"A": (self.states, self.states), "B": (self.states, self.inputs),
                "C": (self.outputs, self.states), "D": (self.outputs, self.inputs),
                "delay": (self.states, self.inputs)}
        self._entries = {k: ([], [], []) for k in "ABCD"}  # parameter index, row, column
        self._scales = {k: [] for k in "ABCD"}  # the entry's multiple of the value (ties)
        self._delay_entries: list[tuple[int, np.ndarray, int]] = []  # (param, rows, column)
        seen: dict[tuple, list] = {}  # entry -> [(parameter, free)]
        delayed = np.zeros((len(self.states), len(self.inputs)), dtype=bool)
        for k, par in enumerate(self.parameters):
            if par.matrix not in _MATRICES:
                raise InputDataError(f"parameter {par.name!r}: matrix must be one of "
                                     f"{_MATRICES}, got {par.matrix!r}")
            rows, cols = axes[par.matrix]
            if par.column not in cols:
                raise InputDataError(f"parameter {par.name!r}: column {par.column!r} is not one "
                                     f"of the structure's {list(cols)}")
            if par.matrix == "delay" and par.row == ALL_ROWS:
                r = np.arange(len(rows))
            elif par.row in rows:
                r = np.array([rows.index(par.row)])
            else:
                raise InputDataError(f"parameter {par.name!r}: row {par.row!r} is not one of "
                                     f"the structure's {list(rows)}")
            c = cols.index(par.column)
            if not (par.lower <= par.value <= par.upper):
                raise InputDataError(f"parameter {par.name!r}: value {par.value} outside its "
                                     f"bounds [{par.lower}, {par.upper}]")
            if par.matrix == "delay":
                if np.any(delayed[r, c]):
                    raise InputDataError(f"parameter {par.name!r}: B entry of input "
                                         f"{par.column!r} already has a delay parameter")
                delayed[r, c] = True
                self._delay_entries.append((k, r, c))
            else:
                if par.also and par.matrix not in ("A", "B"):
                    raise InputDataError(f"parameter {par.name!r}: only A and B parameters "
                                         f"may set further entries ('also'), this one is in "
                                         f"{par.matrix}")
                for i, j, scale in [(int(r[0]), c, 1.0), *self._tied(par)]:
                    # an entry adds its parameters' parts; at most one of them free (a
                    # known part plus an unknown one), no parameter twice
                    key = (par.matrix, i, j)
                    clash = [other for other, free in seen.get(key, [])
                             if other == par.name or (free and par.free)]
                    if clash:
                        raise InputDataError(
                            f"parameters {clash[0]!r} and {par.name!r} both set "
                            f"{entry_name(par.matrix, rows[i], cols[j])} (an entry may add "
                            f"held parameters to at most one free one)")
                    seen.setdefault(key, []).append((par.name, par.free))
                    self._entries[par.matrix][0].append(k)
                    self._entries[par.matrix][1].append(i)
                    self._entries[par.matrix][2].append(j)
                    self._scales[par.matrix].append(scale)
        self._entries = {k: tuple(np.asarray(v, dtype=int) for v in t)
                         for k, t in self._entries.items()}
        self._scales = {k: np.asarray(v, dtype=float) for k, v in self._scales.items()}
        self.free_mask = np.array([p.free for p in self.parameters], dtype=bool)
        self.free_index = np.flatnonzero(self.free_mask)
        self._check_output_delays()

    def _tied(self, par: Parameter) -> list[tuple[int, int, float]]:
        """``(row index, column index, scale)`` of the further A or B entries of ``par``
        (rows are states; columns states for A, inputs for B)."""
        cols = self.states if par.matrix == "A" else self.inputs
        out = []
        for item in par.also:
            try:
                row, col, scale = item
                i, j = self.states.index(row), cols.index(col)
            except (TypeError, ValueError):
                raise InputDataError(f"parameter {par.name!r}: further entry {item!r} must be "
                                     f"(row, column, scale) with the row among the states "
                                     f"{list(self.states)} and the column among the "
                                     f"{'states' if par.matrix == 'A' else 'inputs'} "
                                     f"{list(cols)}") from None
            if not (isinstance(scale, (int, float)) and math.isfinite(scale) and scale != 0):
                raise InputDataError(f"parameter {par.name!r}: entry ({row},{col}) has scale "
                                     f"{scale!r}; expected a finite non-zero number")
            out.append((i, j, float(scale)))
        return out

    def entries_of(self, k: int) -> list[tuple[int, int, float]]:
        """Every entry parameter ``k`` sets: ``(row index, column index, scale)``, the
        primary entry first (scale 1); empty for a delay."""
        par = self.parameters[k]
        if par.matrix == "delay":
            return []
        kk, r, c = self._entries[par.matrix]
        hit = np.flatnonzero(kk == k)
        return [(int(r[h]), int(c[h]), float(self._scales[par.matrix][h])) for h in hit]

    def entry_shared(self, matrix: str, row: int, column: int) -> int:
        """How many parameters add to entry ``(row, column)`` of ``matrix`` (A-D): 0 for
        a fixed entry, more than 1 where ties add onto another parameter's entry."""
        kk, r, c = self._entries[matrix]
        return int(np.count_nonzero((r == row) & (c == column)))

    def _check_output_delays(self) -> None:
        """An output equation may not read a delayed B entry (module docstring)."""
        used = np.any(self.M != 0, axis=0)  # state rows some output equation reads
        if not used.any():
            return
        k, r, c = self._entries["B"]
        has_b = self.B0 != 0
        has_b[r, c] = True
        for kk, rows, col in self._delay_entries:
            bad = [self.states[i] for i in rows if used[i] and has_b[i, col]]
            if bad:
                outs = [self.outputs[o] for o in np.flatnonzero(self.M[:, self.states.index(
                    bad[0])])]
                raise InputDataError(
                    f"structure {self.name!r}: delay {self.parameters[kk].name!r} acts on "
                    f"B[{bad[0]},{self.inputs[col]}], which output(s) {outs} read through their "
                    f"output equation; a delayed feed-through cannot be represented: delay "
                    f"only the rows no output equation reads (e.g. the flapping or moment "
                    f"rows), or use a per-entry delay")

    @property
    def has_output_equations(self) -> bool:
        """True when some output reads state derivatives (``M != 0``)."""
        return bool(np.any(self.M != 0))

    @property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(p.name for p in self.parameters)

    @property
    def free_names(self) -> tuple[str, ...]:
        """Names of the free parameters, in the order of ``theta``."""
        return tuple(self.parameters[k].name for k in self.free_index)

    @property
    def kept_names(self) -> tuple[str, ...]:
        """Free parameters that model reduction must not remove (``keep = true``)."""
        return tuple(self.parameters[k].name for k in self.free_index
                     if self.parameters[k].keep)

    @property
    def theta0(self) -> np.ndarray:
        """Start values of the free parameters, shape (n_free,)."""
        return np.array([self.parameters[k].value for k in self.free_index], dtype=float)

    @property
    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        """Lower and upper bounds of the free parameters."""
        free = [self.parameters[k] for k in self.free_index]
        return (np.array([p.lower for p in free], float), np.array([p.upper for p in free], float))

    def parameter(self, name: str) -> Parameter:
        for p in self.parameters:
            if p.name == name:
                return p
        raise KeyError(f"structure {self.name!r} has no parameter {name!r}; "
                       f"parameters: {list(self.parameter_names)}")

    def values(self, theta=None) -> np.ndarray:
        """All parameter values (free ones from ``theta``), shape (n_parameter,)."""
        vals = np.array([p.value for p in self.parameters], dtype=float)
        if theta is not None:
            theta = np.asarray(theta, dtype=float)
            if theta.shape != (len(self.free_index),):
                raise InputDataError(f"structure {self.name!r}: theta has shape {theta.shape}, "
                                     f"expected ({len(self.free_index)},) for free parameters "
                                     f"{list(self.free_names)}")
            vals[self.free_index] = theta
        return vals

    def replace_parameters(self, changes: Mapping[str, Mapping]) -> "LinearStructure":
        """A copy with some parameters changed, e.g. ``{"M_u": {"free": False, "value": 0}}``."""
        unknown = set(changes) - set(self.parameter_names)
        if unknown:
            raise KeyError(f"structure {self.name!r} has no parameters {sorted(unknown)}")
        params = [p.replace(**changes[p.name]) if p.name in changes else p
                  for p in self.parameters]
        return self._copy(parameters=params)

    def with_values(self, theta) -> "LinearStructure":
        """A copy whose free parameters start at ``theta``."""
        vals = self.values(theta)
        params = [p.replace(value=float(np.clip(v, p.lower, p.upper)))
                  for p, v in zip(self.parameters, vals)]
        return self._copy(parameters=params)

    def fix(self, names: Iterable[str], value: float | None = 0.0) -> "LinearStructure":
        """A copy with ``names`` fixed (at ``value``; ``None`` keeps their current value).

        Fixing a derivative at 0 removes it from the model (model reduction).
        """
        change = {"free": False} if value is None else {"free": False, "value": float(value)}
        return self.replace_parameters({n: change for n in names})

    def free(self, names: Iterable[str]) -> "LinearStructure":
        """A copy with ``names`` free."""
        return self.replace_parameters({n: {"free": True} for n in names})

    def values_from_model(self, model: xr.Dataset) -> np.ndarray:
        """Free-parameter values read from another model Dataset's matrices.

        For start values from e.g. the truth model's quasi-steady linearisation: an A/B/C/D
        parameter takes the Dataset's entry minus this structure's fixed part (so a named
        derivative is ``A_entry - A_kin``; a tied parameter the mean over its entries, each
        divided by its scale), a delay parameter the Dataset's delay of its entry
        (the largest over the column for a whole-input delay), clipped to its bounds. Entries
        the Dataset does not have keep this structure's start values.
        """
        theta = self.theta0.copy()
        fixed = {"A": self.A0, "B": self.B0, "C": self.C0, "D": self.D0}
        dims = {"A": ("state_dot", "state"), "B": ("state_dot", "input"),
                "C": ("output", "state"), "D": ("output", "input"),
                "delay": ("state_dot", "input")}
        axes = {"A": (self.states, self.states), "B": (self.states, self.inputs),
                "C": (self.outputs, self.states), "D": (self.outputs, self.inputs),
                "delay": (self.states, self.inputs)}
        for j, k in enumerate(self.free_index):
            par = self.parameters[k]
            if par.matrix not in model:
                continue
            da = model[par.matrix]
            rdim, cdim = dims[par.matrix]
            if rdim not in da.dims or cdim not in da.dims or par.column not in da[cdim].values:
                continue
            if par.matrix == "delay":
                rows = (list(self.states) if par.row == ALL_ROWS else [par.row])
                rows = [r for r in rows if r in da[rdim].values]
                if not rows:
                    continue
                val = float(da.sel({rdim: rows, cdim: par.column}).max())
            else:
                if par.row not in da[rdim].values:
                    continue
                rows, cols = axes[par.matrix]
                # a tied parameter: the mean over its entries (each over its scale) that no
                # other parameter adds to (all of them if every one is shared)
                entries = self.entries_of(k)
                own = [e for e in entries if self.entry_shared(par.matrix, e[0], e[1]) == 1]
                got = [(float(da.sel({rdim: rows[i], cdim: cols[j]})) - fixed[par.matrix][i, j])
                       / scale for i, j, scale in (own or entries)
                       if rows[i] in da[rdim].values and cols[j] in da[cdim].values]
                val = float(np.mean(got))
            if np.isfinite(val):
                theta[j] = float(np.clip(val, par.lower, par.upper))
        return theta

    def _copy(self, **changes) -> "LinearStructure":
        kw = dict(states=self.states, inputs=self.inputs, outputs=self.outputs, A0=self.A0,
                  B0=self.B0, C0=self.C0, D0=self.D0, parameters=self.parameters,
                  trim_input=self.trim_input, trim_output=self.trim_output, name=self.name,
                  description=self.description, attrs=self.attrs, output_equation=self.M,
                  kinematic=self.K)
        kw.update(changes)
        return LinearStructure(**kw)

    # -- evaluation ----------------------------------------------------------------------

    def matrices(self, theta=None) -> tuple[np.ndarray, ...]:
        """``(A, B, C, D, tau)`` as arrays for the free values ``theta`` (default: start).

        ``C`` and ``D`` include the output equations: ``C + M (A - K)``, ``D + M B``.
        """
        vals = self.values(theta)
        mats = {"A": self.A0.copy(), "B": self.B0.copy(), "C": self.C0.copy(),
                "D": self.D0.copy()}
        for key, (k, r, c) in self._entries.items():
            if len(k):
                np.add.at(mats[key], (r, c), vals[k] * self._scales[key])
        tau = np.zeros_like(self.B0)
        for k, r, c in self._delay_entries:
            tau[r, c] = vals[k]
        if self.has_output_equations:
            mats["C"] += self.M @ (mats["A"] - self.K)
            mats["D"] += self.M @ mats["B"]
        return mats["A"], mats["B"], mats["C"], mats["D"], tau

    def frequency_response(self, omega, theta=None) -> xr.DataArray:
        """Frequency response T(j omega) (Eq. 19 with delays), all frequencies at once.

        Parameters
        ----------
        omega : array_like, shape (n_frequency,)
            Frequencies, rad/s.
        theta : array_like, optional
            Free parameter values (default: start values).

        Returns
        -------
        xr.DataArray
            Complex, dims ``(output, input, frequency)``, analysis units per %.
        """
        omega = np.atleast_1d(np.asarray(omega, dtype=float))
        T = transfer_matrix(*self.matrices(theta), 1j * omega)
        return xr.DataArray(T, dims=("output", "input", "frequency"),
                            coords={"output": list(self.outputs), "input": list(self.inputs),
                                    "frequency": omega},
                            attrs={"long_name": "model frequency response"})

    def pair_response(self, theta, s, out_idx, in_idx, *, jacobian: bool = False):
        """Response of selected output/input pairs at individual points, with its derivative.

        Vectorised over points: point ``k`` is output ``out_idx[k]`` / input ``in_idx[k]`` at
        Laplace variable ``s[k]``. The derivatives are the closed forms of Eq. 19:

        - ``dT/dA_ij = [C R]_oi [R B~]_jk`` with ``R = (sI - A)^-1``,
        - ``dT/dB_ik = [C R]_oi exp(-s tau_ik)``,
        - ``dT/dtau = -s sum_i [C R]_oi B~_ik`` over the B entries the delay acts on,
        - ``dT/dC_oj = [R B~]_jk``, ``dT/dD_ok = 1``;
        - an output equation ``M`` adds ``M_oi [R B~]_jk`` to ``dT/dA_ij`` and ``M_oi`` to
          ``dT/dB_ik`` (``C + M (A - K)`` and ``D + M B`` depend on them).

        Returns
        -------
        T : ndarray, complex, shape (n_point,)
        dT : ndarray, complex, shape (n_point, n_free) (only when ``jacobian``)
        """
        A, B, C, D, tau = self.matrices(theta)
        s = np.asarray(s, dtype=complex)
        n = A.shape[0]
        R = np.linalg.inv(s[:, None, None] * np.eye(n) - A)  # (n_pt, n, n)
        E = np.exp(-s[:, None, None] * tau[None])  # (n_pt, n, m)
        Bd = B[None] * E
        bcol = Bd[np.arange(len(s)), :, in_idx]  # (n_pt, n): B~[:, k]
        X = np.einsum("pij,pj->pi", R, bcol)  # R B~ e_k
        CR = np.einsum("pi,pij->pj", C[out_idx], R)  # e_o^T C R
        T = np.einsum("pi,pi->p", C[out_idx], X) + D[out_idx, in_idx]
        if not jacobian:
            return T
        dT = np.zeros((len(s), len(self.parameters)), dtype=complex)
        Mo = self.M[out_idx]  # (n_pt, n): output-equation weights of each point's output
        k, r, c = self._entries["A"]
        if len(k):  # a tied parameter sums over its entries
            np.add.at(dT, (slice(None), k), (CR[:, r] + Mo[:, r]) * X[:, c]
                      * self._scales["A"])
        k, r, c = self._entries["B"]
        if len(k):  # a tied parameter sums over its entries
            np.add.at(dT, (slice(None), k), (CR[:, r] * E[:, r, c] + Mo[:, r])
                      * (in_idx[:, None] == c[None, :]) * self._scales["B"])
        k, r, c = self._entries["C"]
        if len(k):
            dT[:, k] = X[:, c] * (out_idx[:, None] == r[None, :])
        k, r, c = self._entries["D"]
        if len(k):
            dT[:, k] = ((out_idx[:, None] == r[None, :]) & (in_idx[:, None] == c[None, :]))
        for kk, rows, col in self._delay_entries:
            contrib = -s * np.einsum("pi,pi->p", CR[:, rows], Bd[:, rows, col])
            dT[:, kk] = np.where(in_idx == col, contrib, 0.0)
        return T, dT[:, self.free_index]

    # -- conversion ----------------------------------------------------------------------

    def to_statespace(self, theta=None, *, pade_order: int | None = None):
        """The model as a :class:`control.StateSpace` (see :func:`statespace`)."""
        return statespace(self.to_dataset(theta), pade_order=pade_order)

    def to_dataset(self, theta=None, statistics=None, *, attrs: Mapping | None = None
                   ) -> xr.Dataset:
        """The model Dataset of ``docs/data_model.md``.

        Parameters
        ----------
        theta : array_like, optional
            Free parameter values (default: start values).
        statistics : sysid.identify.statistics.ParameterStatistics, optional
            Accuracy of the free parameters (Cramer-Rao bounds, insensitivities, correlation);
            NaN where absent and for fixed parameters.
        attrs : mapping, optional
            Extra attributes (method, cost totals, data used ...).
        """
        A, B, C, D, tau = self.matrices(theta)
        vals = self.values(theta)
        st, inp, out = list(self.states), list(self.inputs), list(self.outputs)
        names = list(self.parameter_names)
        npar = len(names)
        stats = {k: np.full(npar, np.nan) for k in
                 ("cramer_rao", "cramer_rao_percent", "insensitivity", "insensitivity_percent")}
        corr = np.full((npar, npar), np.nan)
        identifiable = np.ones(npar, dtype=bool)
        if statistics is not None:
            pos = {n: i for i, n in enumerate(names)}
            idx = np.array([pos[n] for n in statistics.names], dtype=int)
            for key in stats:
                stats[key][idx] = getattr(statistics, key)
            corr[np.ix_(idx, idx)] = statistics.correlation
            identifiable[idx] = statistics.identifiable
        par_attrs = {
            "value": {"long_name": "parameter value", "units": "analysis units"},
            "cramer_rao": {"long_name": "Cramer-Rao bound (one standard deviation)"},
            "cramer_rao_percent": {"long_name": "Cramer-Rao bound in percent of |value|",
                                   "units": "%"},
            "insensitivity": {"long_name": "insensitivity 1/sqrt(H_ii)"},
            "insensitivity_percent": {"long_name": "insensitivity in percent of |value|",
                                      "units": "%"},
        }
        ds = xr.Dataset(
            {
                "A": (("state_dot", "state"), A, {"long_name": "state matrix"}),
                "B": (("state_dot", "input"), B, {"long_name": "control matrix"}),
                "C": (("output", "state"), C, {"long_name": "output matrix"}),
                "D": (("output", "input"), D, {"long_name": "feed-through matrix"}),
                "delay": (("state_dot", "input"), tau,
                          {"long_name": "time delay of each B entry", "units": "s"}),
                "trim_input": (("input",), [self.trim_input[k] for k in inp],
                               {"long_name": "absolute trim inputs", "units": "%"}),
                "trim_output": (("output",), [self.trim_output[k] for k in out],
                                {"long_name": "absolute trim outputs"}),
                "value": (("parameter",), vals, par_attrs["value"]),
                **{k: (("parameter",), v, par_attrs[k]) for k, v in stats.items()},
                "free": (("parameter",), self.free_mask.copy()),
                "identifiable": (("parameter",), identifiable,
                                 {"long_name": "False where the data carry no information"}),
                "matrix": (("parameter",), np.array([p.matrix for p in self.parameters],
                                                    dtype=object)),
                "row": (("parameter",), np.array([p.row for p in self.parameters], dtype=object)),
                "column": (("parameter",), np.array([p.column for p in self.parameters],
                                                    dtype=object)),
                "lower": (("parameter",), [p.lower for p in self.parameters]),
                "upper": (("parameter",), [p.upper for p in self.parameters]),
                "correlation": (("parameter", "parameter_j"), corr,
                                {"long_name": "parameter correlation coefficients"}),
            },
            coords={"state": st, "state_dot": st, "input": inp, "output": out,
                    "parameter": names, "parameter_j": names},
        )
        if any(p.also for p in self.parameters):
            ds["also"] = (("parameter",), np.array([_also_text(p.also)
                                                    for p in self.parameters], dtype=object),
                          {"long_name": "further A or B entries a tied parameter sets, "
                                        "'row,column*scale' separated by ';'"})
        if self.has_output_equations:
            ds["output_equation"] = (("output", "state_dot"), self.M.copy(), {
                "long_name": "weights of the state-derivative rows in each output: "
                             "C = C_fixed + M (A - K), D = D_fixed + M B"})
            ds["kinematic"] = (("state_dot", "state"), self.K.copy(), {
                "long_name": "kinematic and gravity part K of A removed by the output "
                             "equations (specific force excludes gravity)"})
        base_attrs = {"structure": self.name, "structure_description": self.description,
                      "method": "structure"}
        base_attrs.update({k: v for k, v in self.attrs.items()
                           if isinstance(v, (str, int, float))})
        base_attrs.update(dict(attrs or {}))
        ds.attrs.update(base_attrs)
        return ds


def _also_text(also) -> str:
    return ";".join(f"{r},{c}*{float(s):g}" for r, c, s in also)


def parse_tied_entries(text: str) -> tuple:
    """``"q,col*-0.4;r,col*1"`` (a model Dataset's ``also``) -> ``(("q", "col", -0.4),
    ("r", "col", 1.0))``: the further entries a tied parameter sets, with their scales."""
    out = []
    for part in filter(None, str(text).split(";")):
        entry, scale = part.rsplit("*", 1)
        row, col = entry.split(",")
        out.append((row, col, float(scale)))
    return tuple(out)


def _matrix(value, shape, label, name) -> np.ndarray:
    if value is None:
        return np.zeros(shape)
    arr = np.array(value, dtype=float)
    if arr.shape != shape:
        raise InputDataError(f"structure {name!r}: {label} has shape {arr.shape}, expected {shape}")
    return arr


# --------------------------------------------------------------------------------------------
# The built-in 6-DoF quasi-steady structure
# --------------------------------------------------------------------------------------------

#: The named derivative rows of the 6-DoF structure (force and moment equations).
FORCE_STATES = ("u", "v", "w", "p", "q", "r")


def six_dof_structure(*, theta0: float, phi0: float, u0: float = 0.0, v0: float = 0.0,
                      w0: float = 0.0, free: Iterable[str] | str = "all",
                      values: Mapping[str, float] | None = None,
                      bounds: Mapping[str, tuple[float, float]] | None = None,
                      delays: Mapping[str, str] | None = None,
                      trim_input: Mapping[str, float] | None = None,
                      trim_output: Mapping[str, float] | None = None,
                      kinematics: bool = True, name: str = "six_dof") -> LinearStructure:
    """The 6-DoF quasi-steady structure of the paper (Eq. 18): 9 states, 4 inputs, C = I, D = 0.

    States ``u v w p q r phi theta psi`` (ft/s, deg/s, deg), inputs ``lon lat col ped`` (%).
    ``A = A_kin(trim) + A_aero``: the fixed part holds the gravity, velocity cross-product and
    Euler-kinematic terms of :func:`sysid.core.kinematics.rigid_body_terms` at the trim; the 60
    named derivatives ``X_u ... N_r`` (36, rows u..r, columns u..r) and ``X_lon ... N_ped``
    (24) are parameters, each free or fixed.

    Parameters
    ----------
    theta0, phi0 : float
        Trim attitudes, deg. ``u0, v0, w0``: trim body velocities, ft/s.
    free : "all" or iterable of str
        Derivatives estimated; the others are fixed (at ``values`` or 0, i.e. absent).
    values : mapping, optional
        Start values (free) or values (fixed) of derivatives and delays.
    bounds : mapping, optional
        ``name -> (lower, upper)``.
    delays : mapping, optional
        ``delay name -> entry``: an entry ``"p,lon"`` delays one B entry (the paper's
        ``{"tau_L_lon": "p,lon", "tau_M_lat": "q,lat"}``), an entry ``"lon"`` the whole input.
        Delays are free, bounded to :data:`DELAY_BOUNDS`, start at ``values`` or 0.05 s.
    kinematics : bool
        Include the fixed rigid-body terms (default True).
    """
    values = dict(values or {})
    bounds = dict(bounds or {})
    names = [derivative_name(r, c) for r in FORCE_STATES for c in FORCE_STATES]
    names += [derivative_name(r, c) for r in FORCE_STATES for c in CONTROLS]
    free_set = set(names) if free == "all" else set(free)
    delays = dict(delays or {})
    unknown = free_set - set(names) - set(delays)
    unknown |= set(values) - set(names) - set(delays)
    if unknown:
        raise InputDataError(f"six_dof_structure: unknown derivatives {sorted(unknown)}; "
                             f"known: X_u ... N_r and X_lon ... N_ped")
    params = []
    for r in FORCE_STATES:
        for c in FORCE_STATES + CONTROLS:
            nm = derivative_name(r, c)
            lo, hi = bounds.get(nm, (-math.inf, math.inf))
            params.append(Parameter(nm, "A" if c in FORCE_STATES else "B", r, c,
                                    float(values.get(nm, 0.0)), nm in free_set, lo, hi))
    for nm, entry in delays.items():
        row, col = parse_delay_entry(entry, nm)
        lo, hi = bounds.get(nm, DELAY_BOUNDS)
        params.append(Parameter(nm, "delay", row, col, float(values.get(nm, 0.05)), True, lo, hi))
    A0 = (rigid_body_terms(theta0=theta0, phi0=phi0, u0=u0, v0=v0, w0=w0).values
          if kinematics else np.zeros((9, 9)))
    return LinearStructure(states=STATES_6DOF, inputs=CONTROLS, A0=A0, parameters=params,
                           trim_input=trim_input, trim_output=trim_output, name=name,
                           description="6-DoF quasi-steady model, A = A_kin(trim) + derivatives",
                           attrs={"theta0_deg": float(theta0), "phi0_deg": float(phi0),
                                  "u0_ft_s": float(u0), "v0_ft_s": float(v0),
                                  "w0_ft_s": float(w0), "kinematics": int(bool(kinematics))})


def parse_delay_entry(entry: str, name: str) -> tuple[str, str]:
    parts = [x.strip() for x in str(entry).split(",")]
    if len(parts) == 1:
        return ALL_ROWS, parts[0]
    if len(parts) == 2:
        return parts[0], parts[1]
    raise InputDataError(f"delay {name!r}: entry must be 'row,input' or 'input', got {entry!r}")


def model_from_dataset(model: xr.Dataset) -> tuple[LinearStructure, np.ndarray]:
    """Rebuild ``(structure, theta)`` from a model Dataset written by :meth:`to_dataset`.

    The fixed parts are the matrices minus the parameters' contributions, so
    ``structure.matrices(theta)`` reproduces ``A B C D delay`` exactly. A Dataset without the
    ``parameter`` dimension (e.g. a linearisation) gives a structure with no parameters.
    """
    A, B, C, D, tau = model_matrices(model)
    states = [str(s) for s in model["A"].state.values]
    inputs = [str(s) for s in model["B"].input.values]
    outputs = [str(s) for s in model["C"].output.values]
    params = []
    if "parameter" in model.dims and "matrix" in model:
        lower = model["lower"].values if "lower" in model else None
        upper = model["upper"].values if "upper" in model else None
        for k, nm in enumerate(model["parameter"].values):
            matrix = str(model["matrix"].values[k])
            params.append(Parameter(
                str(nm), matrix, str(model["row"].values[k]), str(model["column"].values[k]),
                float(model["value"].values[k]), bool(model["free"].values[k]),
                float(lower[k]) if lower is not None else -math.inf,
                float(upper[k]) if upper is not None else math.inf,
                also=parse_tied_entries(model["also"].values[k]) if "also" in model else ()))
    M = K = None
    if "output_equation" in model:
        M = model["output_equation"].sel(output=outputs, state_dot=states).values.astype(float)
        K = model["kinematic"].sel(state_dot=states, state=states).values.astype(float)
    probe = LinearStructure(states=states, inputs=inputs, outputs=outputs, parameters=params)
    vals = probe.values()
    base = {"A": A.copy(), "B": B.copy(), "C": C.copy(), "D": D.copy()}
    if M is not None:  # the output equations' share of C and D comes back from A and B
        base["C"] -= M @ (A - K)
        base["D"] -= M @ B
    for key, (k, r, c) in probe._entries.items():
        if len(k):
            np.subtract.at(base[key], (r, c), vals[k] * probe._scales[key])
    if np.any((tau != 0) & ~_delay_covered(probe)):
        raise InputDataError("model Dataset has delays on B entries that no delay parameter "
                             "covers; cannot rebuild its structure")
    trim_in = dict(zip(inputs, model["trim_input"].sel(input=inputs).values.tolist())) \
        if "trim_input" in model else None
    trim_out = dict(zip(outputs, model["trim_output"].sel(output=outputs).values.tolist())) \
        if "trim_output" in model else None
    attrs = {k: v for k, v in model.attrs.items()
             if k in ("theta0_deg", "phi0_deg", "u0_ft_s", "v0_ft_s", "w0_ft_s", "kinematics")}
    structure = LinearStructure(states=states, inputs=inputs, outputs=outputs, A0=base["A"],
                                B0=base["B"], C0=base["C"], D0=base["D"], parameters=params,
                                trim_input=trim_in, trim_output=trim_out,
                                name=str(model.attrs.get("structure", "from_dataset")),
                                description=str(model.attrs.get("structure_description", "")),
                                attrs=attrs, output_equation=M, kinematic=K)
    return structure, vals[structure.free_index]


def _delay_covered(structure: LinearStructure) -> np.ndarray:
    covered = np.zeros((len(structure.states), len(structure.inputs)), dtype=bool)
    for _, rows, col in structure._delay_entries:
        covered[rows, col] = True
    return covered


def structure_summary(structure: LinearStructure) -> str:
    """One JSON line describing a structure (for attributes and logs)."""
    return json.dumps({"name": structure.name, "states": list(structure.states),
                       "inputs": list(structure.inputs), "outputs": list(structure.outputs),
                       "free": list(structure.free_names)})
