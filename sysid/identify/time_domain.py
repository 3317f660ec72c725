"""Time-domain output-error identification (maximum likelihood, Levenberg-Marquardt).

The paper's time-domain reference method (docs/methods.md, "Time-domain fit and verification";
Jategaonkar, *Flight Vehicle System Identification*, 2nd ed., AIAA 2015, ch. 4; Klein & Morelli,
*Aircraft System Identification*, AIAA 2006, ch. 6). The linear model of a structure
(paper Eq. 18, per-B-entry delays)

    x[k+1] = Phi x[k] + sum_g Gamma_g v_g[k] ,      y[k] = C x[k] + D u[k] + b ,   x[0] = x0

is simulated with the measured inputs of one or more manoeuvres, with exactly the conventions
of :func:`sysid.models.simulate`: exact zero-order-hold discretisation ``(Phi, Gamma)`` by
one matrix exponential (:func:`sysid.models.discretize`); the B entries are grouped by
(input, delay), group ``g`` fed with ``v_g[k] = u(t_k - tau_g)`` by linear interpolation
between samples (held at the first sample before the record starts).

Data: every record is a time-history Dataset (docs/data_model.md); inputs and measurements are
perturbations about the record's ``trim_<channel>`` attributes (or the mean of the first
second when a channel has none).

Cost and estimator (maximum-likelihood output error, Jategaonkar 2015 sec. 4.3, Klein &
Morelli 2006 sec. 6.2). With residuals ``e = z - y`` and the diagonal measurement-noise
covariance ``R = diag(sigma_j^2)``,

    L(theta, R) = 1/2 sum_records sum_k e[k]^T R^-1 e[k] + (N/2) sum_j ln R_jj

(``N`` = samples over all records; the ``2 pi`` constant dropped). It is minimised by
relaxation, and with :data:`PROFILE` (off by default) in two phases. First relaxation: (1) with R fixed, a few steps of a Levenberg-Marquardt-type solve
of the weighted least-squares problem (:func:`scipy.optimize.least_squares`, ``"trf"``, which
honours the 0..0.3 s bounds of free delays); (2) ``R_jj = mean_k e_j[k]^2`` (its ML
estimate); until R changes by less than :data:`PROFILE_R_CHANGE` between passes. Then the
profile likelihood ``L_p(theta) = min over R (and the nuisance) of L = N/2 sum_j ln R_jj(theta)
+ N p / 2`` is minimised by one trust-region solve (``"trf"``) with R re-estimated at every
evaluation: gradient ``J^T R^-1 e`` (the weighted problem's), model matrix the Gauss-Newton
matrix of ``L_p`` (``J^T R^-1 J`` less the coupling of theta and R; the relaxation ignores
it and converges linearly) plus a structured secant estimate of the residuals'
second-order terms (Dennis, Gay & Welsch 1981), until the model predicts less than
:data:`SOLVE_SETTLED` of further decrease. The same maximum-likelihood point in about a
third of the evaluations on the hover study, but not on every data set
(docs/notes/2026-11-26-profile-likelihood.md). ``PROFILE = False`` (the default) keeps the
relaxation to the end: repeated until the relative changes of every ``R_jj`` and
of ``L`` are below ``r_tol``/``cost_tol``, every third R extrapolated by Aitken's
delta-squared step once its solves converge fully; a solve at fixed R ends where its
Gauss-Newton model predicts less than :data:`SOLVE_SETTLED` of further decrease. A
reduction refit starts at the conditional minimum of the last fit's quadratic model
(:func:`sysid.identify.reduction.conditional_start`). The solver is given each problem
compressed to ``n_theta + 1`` rows (``J = Q R_J``; residual ``[Q^T r, |r - Q Q^T r|]``,
Jacobian ``[R_J; 0]``; for the profile, ``R_B^T R_B`` the model matrix): the same cost,
gradient and quadratic models, without factorising the tall Jacobian at every iteration.

Nuisance parameters (docs/methods.md, "Time-domain fit and verification"): a bias per output and an initial state per record. Both
enter the outputs *linearly* for a given ``theta`` (``y = y_u(theta) + O(theta) x0 + b`` with
``O[k] = C Phi^k``), so they are eliminated by variable projection (Golub & Pereyra 1973):
at every evaluation they are the weighted linear least-squares solution for that ``theta``,
and the optimiser only sees the structure's parameters. This is the same minimum as
estimating them jointly in the Levenberg-Marquardt loop, at a fraction of the cost. The
Jacobian used is Kaufman's (1975): the output sensitivities at fixed nuisance, projected
onto the orthogonal complement of the nuisance columns -- whose Gauss-Newton matrix is
exactly the Schur complement of the joint information matrix, i.e. the information about
``theta`` with the nuisance parameters marginalised. An initial-state column that is
linearly dependent on the bias columns (e.g. heading ``psi``, which no state equation feeds
back, so ``x0_psi`` and the ``psi`` bias act identically) is not estimated (set to 0) and
reported as such.

Output sensitivities (analytic, not finite differences). ``s = dx/dtheta`` obeys the same
discrete dynamics, ``s[k+1] = Phi s[k] + dPhi x[k] + dGamma v[k] + Gamma dv[k]``, with
``s[0] = 0``:

- A entry: ``[dPhi, dGamma]`` is the Frechet derivative of the matrix exponential of the
  augmented matrix ``[[A, B_g], [0, 0]] dt`` in the direction of the entry
  (:func:`scipy.linalg.expm_frechet`), exact for the zero-order hold;
- B entry ``(i, g)``: ``dGamma = Psi e_i e_g^T`` with ``Psi = int_0^dt e^{A s} ds``;
- delay of group g: ``dv_g[k] = (u[k-m-1] - u[k-m]) / dt`` (the derivative of the linear
  interpolation, right-sided at whole samples);
- C and D entries act on the output equation directly.

All parameters are propagated together as one forcing array by :func:`sysid.models.propagate`
(block-Toeplitz, vectorised), i.e. one "simulation" with ``n_theta`` right-hand sides instead
of ``n_theta`` finite-difference simulations. ``TimeFitResult.n_jacobian_evaluations`` and
``elapsed`` report the cost; the benchmark compares with finite differences.

Accuracy: the information matrix ``M = sum_k S[k]^T R^-1 S[k]`` (S: output sensitivities,
nuisance marginalised as above) is formed from the whitened Jacobian (rows divided by
``sigma_j``) by :func:`sysid.identify.statistics.parameter_statistics`:
``CR_i = sqrt((M^-1)_ii)``, insensitivity ``1/sqrt(M_ii)``, correlations. Biases and initial
states get their bounds from the joint information matrix (structure parameters plus
nuisance). These are the Cramer-Rao bounds for white measurement noise. Beside them, the
final model carries bounds corrected for coloured residuals (unmodelled dynamics,
turbulence): the Morelli & Klein (1997) sandwich ``M^-1 [sum_i sum_j S(i)^T R_vv(i-j) S(j)]
M^-1`` of :func:`sysid.identify.statistics.coloured_residual_covariance`, from the same
projected whitened sensitivities and the whitened residuals of each record (model variables
``cramer_rao_corrected``, ``cramer_rao_percent_corrected``). The model reduction still
decides on the white-noise bounds.

Model reduction: the same :func:`sysid.identify.reduction.stepwise_reduction` as the
frequency-domain fit, with the cost measure ``L`` above (after re-estimating R): removing a
parameter that is truly zero raises ``L`` by ``chi^2_1 / 2`` (likelihood ratio), so the
default ``max_cost_increase`` is ``chi^2_1(0.999) / 2 = 5.41``: a removal is undone when the
likelihood-ratio test finds the parameter significant at the 0.1 % level.
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import dataclass, field
from typing import Sequence

import numpy as np
import scipy.linalg
import scipy.optimize
import xarray as xr

from sysid.core.errors import IdentificationError, InputDataError
from sysid.core.guidelines import FIT_TIME_LIMIT_S
from sysid.core.util import Deadline, Progress, fit_settings
from sysid.data.campaign import record_trim
from sysid.data.importers import validate_time_history
from sysid.identify.least_squares import (Settled, SolveStopped, compress, predicted_decrease,
                                          triangle)
from sysid.identify.reduction import (GUIDELINES, FitOutcome, ReductionResult,
                                     conditional_start, stepwise_reduction)
from sysid.identify.statistics import (ColouredBounds, FitResultParameters,
                                      ParameterStatistics, add_corrected_bounds,
                                      coloured_residual_covariance,
                                      parameter_rows, parameter_statistics,
                                      perturbed_start)
from sysid.models import LinearStructure, discretize, propagate

__all__ = [
    "MAX_COST_INCREASE",
    "TimeRecord",
    "prepare_records",
    "OutputErrorModel",
    "TimeFitResult",
    "identify_time_domain",
]

#: Default largest accepted rise of the negative log-likelihood per removed parameter in the
#: model reduction: half the 99.9 % quantile of chi^2 with one degree of freedom.
MAX_COST_INCREASE = 0.5 * 10.827566170662733
#: Relative floor of the noise variances (times the variance of the measured perturbation):
#: keeps the weights finite on noise-free data.
R_FLOOR = 1e-14
#: Relaxation: cost evaluations allowed per weighted solve while R still changes by more than
#: EARLY_R_CHANGE (relative) between outer iterations (see ``_converge``).
EARLY_NFEV = 3
EARLY_R_CHANGE = 0.02
#: Relaxation: a change of the negative log-likelihood this small (absolute) counts as
#: settled whatever ``cost_tol`` says. Weakly determined parameters let successive converged
#: solves differ by about 1e-3 in L (measured on the 100-kt campaign, where a relative
#: 1e-7 kept the loop going for ten outer iterations); 0.01 is 1/500 of the reduction's
#: acceptance threshold MAX_COST_INCREASE, so no decision downstream can see it.
COST_SETTLED = 0.01
#: Solver and relaxation accelerations (on by default; the benchmark switches them off for
#: its baseline): the least-squares problem handed to the solver compressed to n_theta + 1
#: rows (``OutputErrorModel.compressed_residuals``), and Aitken extrapolation of R.
COMPRESSED = True
AITKEN = True
#: Estimator: after the relaxation's first passes, a trust-region solve of the profile
#: likelihood ``L_p(theta) = min over R and the nuisance of L`` (R re-estimated at every
#: evaluation; Gauss-Newton plus secant model, ``OutputErrorModel._profile_model``). False:
#: the relaxation (LM at fixed R, then the R update) to the end, which converges linearly.
#: Off by default: 2.4x fewer evaluations on the hover study, but 4.6x more on an 80-kt
#: quick campaign (seed 3) ending 0.115 higher in L, and on turbulent closed-loop records
#: it stepped into unstable models (now guarded); docs/notes/2026-11-26-profile-likelihood.md.
PROFILE = False
#: Fixed point of R and the nuisance parameters at one theta (``_consistent_variance``):
#: largest relative change of R accepted, and the iterations allowed.
CONSISTENT_R_CHANGE = 1e-9
CONSISTENT_MAX_ITER = 50
#: The relaxation's capped passes run until R changes by less than this (relative) between
#: passes; the profile solve takes over from there (at once in a refit whose start's
#: residuals are that close to the previous fit's R).
PROFILE_R_CHANGE = 0.1
#: A solve (the relaxation's at fixed R, or the profile solve) stops at an iterate where its
#: Gauss-Newton model predicts a decrease of the negative log-likelihood below this
#: (``1/2 g^T H^-1 g``): 1/10 of COST_SETTLED, i.e. about 0.045 Cramer-Rao bounds from the
#: solve's minimum.
SOLVE_SETTLED = 1e-3
#: The relaxation's solves stop at SOLVE_SETTLED (False: on the solver's own tolerances
#: ``tol``, as before; the benchmark's baseline).
RELAXATION_SETTLES = True
#: A reduction refit starts from the last fit's quadratic model with the removed parameter
#: at zero (:func:`sysid.identify.reduction.conditional_start`), not from its other
#: estimates unchanged.
CONDITIONAL_START = True
#: Simulated (whitened) values beyond this count as a diverged trial model.
_HUGE = 1e100


# --------------------------------------------------------------------------------------------
# Data
# --------------------------------------------------------------------------------------------


@dataclass
class TimeRecord:
    """One manoeuvre prepared for the fit (perturbations about trim, analysis units).

    Attributes
    ----------
    name : str
    time : ndarray (N,)
        s, uniform.
    dt : float
        Sample interval, s.
    U : ndarray (N, n_input)
        Inputs in the structure's input order, % from trim.
    Z : ndarray (N, n_output)
        Measured outputs (the fitted ones, in fit order), from trim.
    trim_input, trim_output : ndarray
        The trims subtracted (absolute, analysis units).
    """

    name: str
    time: np.ndarray
    dt: float
    U: np.ndarray
    Z: np.ndarray
    trim_input: np.ndarray
    trim_output: np.ndarray


def _trim_of(ds: xr.Dataset, channel: str) -> float:
    """``trim_<channel>`` attribute, else the mean of the first :data:`TRIM_WINDOW` s
    (the data model's one rule, :func:`sysid.data.campaign.record_trim`)."""
    return record_trim(ds, channel)


def fitted_outputs(records: Sequence[xr.Dataset], structure: LinearStructure,
                   outputs: Sequence[str] | None = None) -> tuple[str, ...]:
    """The outputs to fit: ``outputs``, or every structure output present in all records."""
    if outputs is None:
        outs = [o for o in structure.outputs if all(o in r.data_vars for r in records)]
        if not outs:
            raise InputDataError(f"no output of structure {structure.name!r} "
                                 f"({list(structure.outputs)}) is measured in every record")
        return tuple(outs)
    outs = tuple(str(o) for o in outputs)
    unknown = [o for o in outs if o not in structure.outputs]
    if unknown:
        raise InputDataError(f"outputs {unknown} are not outputs of structure "
                             f"{structure.name!r} ({list(structure.outputs)})")
    return outs


def fit_inputs(records, structure: LinearStructure, outputs, *, what: str
               ) -> tuple[list[xr.Dataset], list[str], list[TimeRecord]]:
    """``(records, outputs, prepared records)`` of a time-domain fit (one Dataset or a
    sequence); refuses no records and a structure without free parameters, naming ``what``."""
    records = [records] if isinstance(records, xr.Dataset) else list(records)
    if not records:
        raise InputDataError(f"{what}: no records given")
    outs = fitted_outputs(records, structure, outputs)
    recs = prepare_records(records, structure, outs)
    if len(structure.free_index) == 0:
        raise IdentificationError(f"structure {structure.name!r} has no free parameters")
    return records, outs, recs


def prepare_records(records: Sequence[xr.Dataset], structure: LinearStructure,
                    outputs: Sequence[str]) -> list[TimeRecord]:
    """Check the time histories and turn them into perturbation arrays.

    Raises :class:`~sysid.core.errors.InputDataError` naming the manoeuvre and channel when an
    input or output is missing, not finite, or the time grid is not uniform.
    """
    if isinstance(records, xr.Dataset):
        records = [records]
    if not len(records):
        raise InputDataError("identify_time_domain: no records given")
    out = []
    for i, ds in enumerate(records):
        name = str(ds.attrs.get("maneuver", f"record_{i}"))
        dt = validate_time_history(ds, list(structure.inputs) + list(outputs), name=name)
        t = np.asarray(ds["time"].values, float)
        if len(t) < 3:
            raise InputDataError(f"manoeuvre {name!r}: needs at least 3 samples")
        tin = np.array([_trim_of(ds, c) for c in structure.inputs])
        tout = np.array([_trim_of(ds, o) for o in outputs])
        U = np.stack([np.asarray(ds[c].values, float) for c in structure.inputs], 1) - tin
        Z = np.stack([np.asarray(ds[o].values, float) for o in outputs], 1) - tout
        out.append(TimeRecord(name, t, float(dt), U, Z, tin, tout))
    names = [r.name for r in out]
    if len(set(names)) != len(names):
        raise InputDataError(f"records have duplicate manoeuvre names {names}")
    return out


# --------------------------------------------------------------------------------------------
# The output-error model: simulation, nuisance elimination, analytic sensitivities
# --------------------------------------------------------------------------------------------


def _delay_split(delay_samples: float) -> tuple[int, float]:
    m = int(math.floor(delay_samples + 1e-12))
    return m, max(delay_samples - m, 0.0)


def _delayed(u: np.ndarray, delay_samples: float) -> tuple[np.ndarray, np.ndarray]:
    """``u(t_n - d)`` by linear interpolation (the convention of :func:`sysid.models.simulate`)
    and its derivative with respect to ``d`` in samples (right-sided at whole samples).

    Returns ``(v, dv_dd)``, shapes (N,).
    """
    N = len(u)
    m, f = _delay_split(delay_samples)
    idx = np.arange(N) - m
    a = u[np.clip(idx, 0, N - 1)]
    b = u[np.clip(idx - 1, 0, N - 1)]
    return (1.0 - f) * a + f * b, b - a


@dataclass
class _Group:
    """B entries of one input fed with the same delayed signal."""

    column: int  #: input index
    rows: np.ndarray  #: bool (n_state,)
    delay: float  #: s
    free_delay: int  #: position in theta of the free delay parameter, -1 if none


@dataclass
class _Evaluation:
    """Everything computed for one ``theta`` (arrays per record where listed)."""

    theta: np.ndarray
    residual: np.ndarray  #: weighted, projected, all records concatenated
    errors: list  #: (N, p) unweighted residuals z - y
    bias: list  #: (p,) per record (0 where not estimated)
    x0: list  #: (n,) per record (NaN where not estimated)
    jacobian: np.ndarray | None = None  #: projected, weighted (n_residual, n_theta)
    sens: list = field(default_factory=list)  #: weighted sensitivities (N p, n_theta)
    nuisance: list = field(default_factory=list)  #: weighted nuisance columns (N p, k)
    kept: list = field(default_factory=list)  #: names of the estimated nuisance columns
    factor: list = field(default_factory=list)  #: lower Cholesky factors of K^T K per record
    compressed: tuple | None = None  #: (f, J) of the compressed problem (n_theta + 1 rows)
    sigma: np.ndarray | None = None  #: noise std devs that whitened this evaluation
    R: np.ndarray | None = None  #: mean squared errors per output (floored), re-estimated
    cost: float = math.inf  #: L(theta, R) at that R, the profile likelihood
    gradient: np.ndarray | None = None  #: J^T r, the gradient of the profile likelihood
    secant: np.ndarray | None = None  #: the structured secant matrix S at this theta
    decrease: float = math.inf  #: 1/2 g^T H^-1 g, the Gauss-Newton model's predicted fall


class OutputErrorModel:
    """Residuals and analytic Jacobian of the output-error problem for one structure.

    Parameters
    ----------
    structure : LinearStructure
    records : list of TimeRecord
    outputs : sequence of str
        Fitted outputs (a subset of the structure's, in the records' ``Z`` column order).
    biases, initial_state : bool
        Estimate a bias per output / an initial state per record (variable projection).
    """

    def __init__(self, structure: LinearStructure, records: list[TimeRecord],
                 outputs: Sequence[str], *, biases: bool = True, initial_state: bool = True):
        self.structure = structure
        self.records = records
        self.outputs = tuple(outputs)
        self.out_idx = np.array([structure.outputs.index(o) for o in self.outputs])
        self.biases = bool(biases)
        self.initial_state = bool(initial_state)
        self.sigma = np.ones(len(self.outputs))
        #: profile likelihood: R re-estimated at every evaluation (see ``_consistent_variance``)
        self.profile = False
        self.floor = np.zeros(len(self.outputs))  #: floor of the noise variances
        self.anchor = None  #: cost offset of the profile problem handed to the solver
        self.secant = None  #: (theta, gradient, S) at the profile solve's last accepted iterate
        self.settle = False  #: the relaxation's solve stops at SOLVE_SETTLED
        self.n_cost = 0
        self.n_jac = 0
        self._cache: _Evaluation | None = None
        self._classify()

    # -- parameters --------------------------------------------------------------------------

    def _classify(self) -> None:
        st = self.structure
        self.kind = []  # per free parameter: ("A", i, j) / ("B", i, c) / ("C", o, j) / ...
        delay_of = {int(k): j for j, k in enumerate(st.free_index)}
        for j, k in enumerate(st.free_index):
            par = st.parameters[k]
            if par.matrix == "A":
                # every entry the parameter sets (several when tied), with its scale
                self.kind.append(("A", st.states.index(par.row), st.states.index(par.column),
                                  st.entries_of(int(k))))
            elif par.matrix == "B":
                self.kind.append(("B", st.states.index(par.row), st.inputs.index(par.column),
                                  st.entries_of(int(k))))
            elif par.matrix == "C":
                self.kind.append(("C", st.outputs.index(par.row), st.states.index(par.column)))
            elif par.matrix == "D":
                self.kind.append(("D", st.outputs.index(par.row), st.inputs.index(par.column)))
            else:
                self.kind.append(("delay", delay_of[int(k)], st.inputs.index(par.column)))

    def groups(self, tau: np.ndarray) -> list[_Group]:
        """Input groups: one per free delay parameter (its entries), the other B entries of
        each input grouped by their (fixed) delay value."""
        st = self.structure
        n, m = tau.shape
        covered = np.zeros((n, m), dtype=bool)
        out = []
        pos = {int(k): j for j, k in enumerate(st.free_index)}
        for k, rows, c in st._delay_entries:
            if st.free_mask[k]:
                mask = np.zeros(n, dtype=bool)
                mask[rows] = True
                covered[rows, c] = True
                out.append(_Group(int(c), mask, float(tau[rows[0], c]), pos[int(k)]))
        for c in range(m):
            rest = ~covered[:, c]
            for d in np.unique(tau[rest, c]):
                out.append(_Group(c, rest & (tau[:, c] == d), float(d), -1))
        return out

    # -- discretisation ----------------------------------------------------------------------

    def _discretise(self, A, Bg, dt, jacobian):
        """``Phi, Gamma`` (exact ZOH) and, with ``jacobian``, ``Psi = int e^{As} ds`` and the
        Frechet derivatives ``[dPhi, dGamma]`` (n, n+G) for every free A entry."""
        n, G = Bg.shape
        M = np.zeros((n + G, n + G))
        M[:n, :n] = A * dt
        M[:n, n:] = Bg * dt
        E = scipy.linalg.expm(M)
        out = {"Phi": E[:n, :n], "Gam": E[:n, n:]}
        if jacobian:
            out["Psi"] = discretize(A, np.eye(n), dt)[1]  # int_0^dt e^(As) ds
            dA = []
            for kind in self.kind:
                if kind[0] == "A":
                    dM = np.zeros_like(M)
                    for i, c, scale in kind[3]:
                        dM[i, c] = dt * scale
                    dA.append(scipy.linalg.expm_frechet(M, dM, compute_expm=False)[:n])
            out["dA"] = np.array(dA).reshape(len(dA), n, n + G)
        return out

    # -- evaluation --------------------------------------------------------------------------

    def nuisance_names(self, record: TimeRecord) -> list[str]:
        names = []
        if self.biases:
            names += [f"bias_{o}[{record.name}]" for o in self.outputs]
        if self.initial_state:
            names += [f"x0_{s}[{record.name}]" for s in self.structure.states]
        return names

    def evaluate(self, theta, jacobian: bool = False) -> _Evaluation:
        """Simulate every record at ``theta``, eliminate the nuisance parameters, and (with
        ``jacobian``) propagate the output sensitivities."""
        theta = np.asarray(theta, dtype=float)
        c = self._cache
        if c is not None and np.array_equal(c.theta, theta) and (c.jacobian is not None
                                                                 or not jacobian):
            return c
        st = self.structure
        A, B, C, D, tau = st.matrices(theta)
        groups = self.groups(tau)
        Bg = np.stack([B[:, g.column] * g.rows for g in groups], axis=1)
        Cf, Df = C[self.out_idx], D[self.out_idx]
        disc = {}
        ev = _Evaluation(theta.copy(), np.zeros(0), [], [], [])
        res_parts, jac_parts = [], []
        # A trial step may produce a violently unstable model: overflow is detected in
        # _record (infinite residual), not warned about.
        with np.errstate(over="ignore", invalid="ignore"):
            sims = []
            for rec in self.records:
                if rec.dt not in disc:
                    disc[rec.dt] = self._discretise(A, Bg, rec.dt, jacobian)
                sims.append(self._simulate(rec, disc[rec.dt], groups, Cf, Df))
            if self.profile:
                self.sigma = np.sqrt(self._consistent_variance(sims))
            for rec, sim in zip(self.records, sims):
                out = self._record(rec, sim, disc[rec.dt], groups, Cf, Df, jacobian, ev)
                res_parts.append(out[0])
                if jacobian:
                    jac_parts.append(out[1])
        ev.residual = np.concatenate(res_parts)
        ev.sigma = self.sigma.copy()
        if np.all(np.isfinite(ev.residual)):
            ev.R = _noise_variance(ev.errors, self.floor)
            ev.cost = _likelihood(ev.errors, ev.R)
        if jacobian:
            ev.jacobian = np.vstack(jac_parts)
            self.n_jac += 1
        self._cache = ev
        return ev

    def _simulate(self, rec: TimeRecord, disc, groups, Cf, Df) -> dict:
        """Unweighted simulation of one record: delayed inputs ``V``, ``dV`` (N, G), forced
        states ``Xu`` (N, n) and outputs ``Yu`` (N, p), and with initial states ``Phi^k``
        ``Xo`` (N, n, n) and its outputs ``Yo`` (N, p, n)."""
        N, n = len(rec.time), self.structure.A0.shape[0]
        Phi, Gam = disc["Phi"], disc["Gam"]
        VV = [_delayed(rec.U[:, g.column], g.delay / rec.dt) for g in groups]
        V = np.stack([v for v, _ in VV], axis=1)  # (N, G)
        Xu = propagate(Phi, V @ Gam.T)
        sim = {"V": V, "dV": np.stack([d for _, d in VV], 1), "Xu": Xu,
               "Yu": Xu @ Cf.T + rec.U @ Df.T, "Xo": None, "Yo": None}
        if self.initial_state:
            if len(disc.get("powers", ())) < N:  # Phi^k, shared by the records of this dt
                disc["powers"] = propagate(Phi, np.zeros((N, n, n)), np.eye(n))
            sim["Xo"] = disc["powers"][:N]
            sim["Yo"] = np.matmul(Cf, sim["Xo"])
        return sim

    def _consistent_variance(self, sims: list) -> np.ndarray:
        """Noise variances ``R_jj = mean_k e_j[k]^2`` (floored) with the nuisance parameters
        estimated at the weights ``R^-1`` themselves: the fixed point at this ``theta``, so
        that the cost is the profile likelihood ``min over nuisance and R`` of ``L``.

        Iterated from ``self.sigma**2`` on per-output Gram matrices of the unweighted nuisance
        columns ``K_j`` (k x k) and targets ``t_j`` (``|e_j|^2 = |t_j|^2 - 2 c^T K_j^T t_j +
        c^T K_j^T K_j c``), so an iteration costs no pass over the samples. Biases alone
        do not depend on the weights (one iteration); initial states couple the outputs.
        """
        p, n = len(self.outputs), self.structure.A0.shape[0]
        nb = p if self.biases else 0
        k = nb + (n if self.initial_state else 0)
        parts, n_samples = [], 0
        for rec, sim in zip(self.records, sims):
            t = rec.Z - sim["Yu"]  # (N, p)
            n_samples += len(t)
            G, b = np.zeros((p, k, k)), np.zeros((p, k))
            if self.biases:  # bias j is a column of ones on output j
                G[np.arange(p), np.arange(p), np.arange(p)] = len(t)
                b[np.arange(p), np.arange(p)] = t.sum(axis=0)
            if self.initial_state:
                Yt = sim["Yo"].transpose(1, 2, 0)  # (p, n, N)
                G[:, nb:, nb:] = Yt @ Yt.transpose(0, 2, 1)
                b[:, nb:] = (Yt @ t.T[:, :, None])[..., 0]
                if self.biases:
                    cross = Yt.sum(axis=2)  # (p, n)
                    G[np.arange(p), np.arange(p), nb:] = cross
                    G[np.arange(p), nb:, np.arange(p)] = cross
            parts.append((G if k else None, b, np.einsum("kj,kj->j", t, t)))
        R = self.sigma ** 2
        if not all(np.all(np.isfinite(a)) for part in parts for a in part if a is not None):
            return R  # a diverged trial model: _record reports it
        keeps = [None] * len(parts)  # the independent columns, chosen at the first weights
        for _ in range(CONSISTENT_MAX_ITER):
            w = 1.0 / R
            sse = np.zeros(p)
            for i, (G, b, tt) in enumerate(parts):
                sse += tt
                if G is None:
                    continue
                A = np.tensordot(w, G, 1)
                if keeps[i] is None:
                    keeps[i] = _independent_gram(A)[0]
                keep = keeps[i]
                c = np.zeros(len(keep))
                c[keep] = scipy.linalg.cho_solve(
                    scipy.linalg.cho_factor(A[np.ix_(keep, keep)]), (w @ b)[keep])
                sse += np.einsum("k,jkl,l->j", c, G, c) - 2.0 * (b @ c)
            R_new = np.maximum(sse / n_samples, self.floor)
            done = np.max(np.abs(R_new / R - 1.0)) < CONSISTENT_R_CHANGE
            R = R_new
            if done:
                break
        return R

    def _record(self, rec: TimeRecord, sim: dict, disc, groups, Cf, Df, jacobian,
                ev: _Evaluation):
        """Residuals (and projected Jacobian) of one simulated record, whitened by
        ``self.sigma``; appends its errors, nuisance estimates and sensitivities to ``ev``."""
        N, p, n = len(rec.time), len(self.outputs), self.structure.A0.shape[0]
        sig = self.sigma
        V, Xu, Xo = sim["V"], sim["Xu"], sim["Xo"]
        target = ((rec.Z - sim["Yu"]) / sig).ravel()
        # Nuisance columns (whitened): biases first, then initial states.
        cols, names = [], self.nuisance_names(rec)
        if self.biases:
            Bc = np.zeros((N, p, p))
            Bc[:, np.arange(p), np.arange(p)] = 1.0 / sig
            cols.append(Bc.reshape(N * p, p))
        if self.initial_state:
            cols.append((sim["Yo"] / sig[None, :, None]).reshape(N * p, n))
        bias = np.zeros(p)
        x0 = np.full(n, np.nan)
        x = Xu
        if not all(np.all(np.abs(a) < _HUGE) for a in [target, *cols]):
            # The trial model diverged (overflow): an infinite residual makes the trust-region
            # solver shrink its step (scipy's trf treats non-finite residuals that way).
            ev.errors.append(np.full((N, p), np.inf))
            ev.bias.append(np.full(p, np.nan))
            ev.x0.append(x0)
            return np.full(N * p, np.inf), (np.zeros((N * p, len(self.kind)))
                                            if jacobian else None)
        if cols:
            Nm = np.hstack(cols)
            keep, L = _independent_columns(Nm)
            K = Nm[:, keep]
            coef = _chol_solve(L, K.T @ target)
            resid = target - K @ coef
            full = np.zeros(Nm.shape[1])
            full[keep] = coef
            if self.biases:
                bias = full[:p]
            if self.initial_state:
                x0 = np.where(keep[-n:], full[-n:], np.nan)
                x = Xu + Xo @ np.nan_to_num(x0)
        else:
            K, L, keep = np.zeros((N * p, 0)), np.zeros((0, 0)), np.zeros(0, bool)
            Nm = K
            resid = target
        e = rec.Z - (x @ Cf.T + rec.U @ Df.T + bias)
        ev.errors.append(e)
        ev.bias.append(bias)
        ev.x0.append(x0)
        if not jacobian:
            return resid, None
        S = self._sensitivities(rec, disc, groups, V, sim["dV"], x, Cf) / sig[None, :, None]
        S = S.reshape(N * p, -1)
        ev.sens.append(S)
        ev.nuisance.append(K)
        ev.factor.append(L)
        ev.kept.append([nm for nm, k in zip(names, keep) if k])
        # Kaufman's variable-projection Jacobian of r = (z - y)/sigma (projected).
        G = -(S - K @ _chol_solve(L, K.T @ S)) if K.shape[1] else -S
        return resid, G

    def _sensitivities(self, rec, disc, groups, V, dV, x, Cf):
        """Output sensitivities ``dy/dtheta`` at fixed nuisance, shape (N, p, n_theta)."""
        N, n = x.shape
        P = len(self.kind)
        W = np.zeros((N, n, P))
        XV = np.hstack([x, V])
        a_pos = [j for j, k in enumerate(self.kind) if k[0] == "A"]
        if a_pos:
            # dA[p] [x; v] for every sample and A entry: one (N, n+G) x (n+G, P_A n) product
            dA = disc["dA"]
            at = (slice(a_pos[0], a_pos[-1] + 1) if a_pos[-1] - a_pos[0] + 1 == len(a_pos)
                  else a_pos)  # a slice writes twice as fast as a list of columns
            W[:, :, at] = (XV @ dA.reshape(-1, dA.shape[2]).T).reshape(
                N, len(a_pos), n).transpose(0, 2, 1)
        extra = []  # C / D parameters act on the output equation
        for j, kind in enumerate(self.kind):
            if kind[0] == "B":  # every entry of a tied parameter, with its scale
                for i, c, scale in kind[3]:
                    g = _group_of(groups, i, c)
                    W[:, :, j] += scale * np.outer(V[:, g], disc["Psi"][:, i])
            elif kind[0] == "delay":
                g = next(k for k, gr in enumerate(groups) if gr.free_delay == kind[1])
                W[:, :, j] = np.outer(dV[:, g] / rec.dt, disc["Gam"][:, g])
            elif kind[0] in "CD":
                extra.append((j, kind))
        Sx = propagate(disc["Phi"], W, block=8) if P else np.zeros((N, n, 0))
        # C-contiguous (N, p, P), so that the caller's (N p, P) view is not a copy
        S = np.matmul(Cf, Sx)
        for j, (kind, o, c) in extra:
            hit = np.flatnonzero(self.out_idx == o)
            if len(hit):
                S[:, hit[0], j] += x[:, c] if kind == "C" else rec.U[:, c]
        Mf = self.structure.M[self.out_idx]  # output equations: C + M (A - K), D + M B
        if np.any(Mf):
            for j, kind in enumerate(self.kind):
                if kind[0] not in "AB":
                    continue
                for i, c, scale in kind[3]:
                    if np.any(Mf[:, i]):
                        drive = x[:, c] if kind[0] == "A" else rec.U[:, c]
                        S[:, :, j] += scale * np.outer(drive, Mf[:, i])
        return S

    # -- interface for least_squares ---------------------------------------------------------

    def residuals(self, theta):
        self.n_cost += 1
        return self.evaluate(theta).residual

    def jacobian(self, theta):
        return self.evaluate(theta, jacobian=True).jacobian

    # -- the same problem compressed to n_theta + 1 rows (what the solver is given) ----------

    def compressed_residuals(self, theta):
        """``[Q^T r, |r - Q Q^T r|]`` with ``J = Q R_J`` (thin): the residual in a basis
        where the Jacobian is the small triangle ``R_J`` (:meth:`compressed_jacobian`).

        ``|f|``, ``J^T f``, the column norms of the Jacobian and every Gauss-Newton model
        ``|f + J p|`` are those of the full problem, so the trust-region solver takes the
        same steps to rounding, without factorising the tall (samples x outputs) Jacobian
        at every iteration (docs/notes/2026-11-24-time-domain-speed.md).
        Every evaluation therefore computes the sensitivities too.
        """
        self.n_cost += 1
        return self._compressed(theta)[0]

    def compressed_jacobian(self, theta):
        """``[R_J; 0]`` (:meth:`compressed_residuals`). The solver asks for it at each
        accepted iterate; with ``self.settle`` it raises ``Settled`` there when the
        Gauss-Newton model predicts less than :data:`SOLVE_SETTLED` of further decrease."""
        ev = self.evaluate(theta, jacobian=True)
        f, J = self._compressed(theta)
        if self.settle and np.all(np.isfinite(f)):
            RJ = J[:-1]
            ev.decrease = predicted_decrease(self.structure.bounds, ev.theta, RJ.T @ f[:-1],
                                              RJ.T @ RJ, 0.5 * float(f[:-1] @ f[:-1]))
            if ev.decrease < SOLVE_SETTLED:
                raise Settled(ev.theta)
        return J

    def _compressed(self, theta):
        ev = self.evaluate(theta, jacobian=True)
        if ev.compressed is None:
            ev.compressed = compress(ev.residual, ev.jacobian)
        return ev.compressed

    # -- the profile likelihood, compressed the same way ------------------------------------

    def profile_residuals(self, theta):
        """``f`` (n_theta + 1) with ``1/2 |f|^2 = L_p(theta) - anchor``, ``J_f^T f`` the
        gradient of ``L_p`` and ``J_f^T J_f`` the model matrix ``B`` (``J_f`` from
        :meth:`profile_jacobian`; ``_profile_model``): ``f = [R_B^-T g, rest]``. Raises
        ``_Reanchor`` when ``L_p`` has fallen so far below the anchor that no such ``f``
        exists."""
        self.n_cost += 1
        ev = self.evaluate(theta, jacobian=True)
        if ev.compressed is None:
            ev.compressed = self._profile_model(ev)
        q, RJ = ev.compressed
        if not np.all(np.isfinite(q)):
            return np.full(len(q) + 1, np.inf)
        if self.anchor is None:  # a solve's start: N p / 2 below its cost and model minimum
            self.anchor = ev.cost - 0.5 * float(q @ q) - 0.5 * ev.residual.size
        rest2 = 2.0 * (ev.cost - self.anchor) - float(q @ q)
        if rest2 < 0.0:
            raise _Reanchor(ev.theta)
        return np.append(q, math.sqrt(rest2))

    def profile_jacobian(self, theta):
        """``[R_B; 0]`` (:meth:`profile_residuals`). The solver asks for it at each accepted
        iterate, which becomes the secant update's reference; raises ``Settled`` there when
        the Gauss-Newton model's predicted decrease (``_profile_model``) is below
        :data:`SOLVE_SETTLED`."""
        ev = self.evaluate(theta, jacobian=True)
        if ev.compressed is None:
            ev.compressed = self._profile_model(ev)
        q, RJ = ev.compressed
        if np.all(np.isfinite(q)):
            self.secant = (ev.theta, ev.gradient, ev.secant if ev.secant is not None
                           else np.zeros_like(RJ))
        if ev.decrease < SOLVE_SETTLED:
            raise Settled(ev.theta)
        return np.vstack([RJ, np.zeros((1, RJ.shape[1]))])

    def _profile_model(self, ev: _Evaluation) -> tuple[np.ndarray, np.ndarray]:
        """``(q, R_B)``: ``R_B`` upper triangular with ``R_B^T R_B = B = H + S`` and
        ``q = R_B^-T g`` (g the gradient ``J^T r`` of the profile likelihood).

        ``L_p = N/2 sum_j ln R_jj(theta) + const`` has the Gauss-Newton matrix
        ``H = J^T J - (2/N) U^T W U``: ``U_j = J_j^T r_j`` (the gradient of output j alone, J
        the projected whitened Jacobian) and ``W = (I - (2/N) V^T (K^T K)^-1 V)^-1`` with
        ``V_j = K_j^T r_j`` (the nuisance's share, their Schur complement; W = I with
        biases alone); floored outputs drop out. The relaxation's solver sees ``J^T J``
        alone. ``S`` is the structured secant estimate of what ``H`` misses (the residuals'
        second-order terms; Dennis, Gay & Welsch 1981), updated from the last accepted
        iterate (``_secant_update``). Where ``B`` is not safely positive definite, ``H``,
        then ``J^T J``. Sets ``ev.decrease``, the decrease ``1/2 g^T H^-1 g`` the
        Gauss-Newton model alone predicts (the stopping measure: a secant term grown large
        far from the optimum can make ``B``'s prediction small while the gradient is not),
        over the parameters not held at a bound (within 1e-3 of its range, the gradient
        pushing outward).
        """
        r, J = ev.residual, ev.jacobian
        n = J.shape[1]
        if not (np.all(np.isfinite(r)) and np.all(np.isfinite(J))):
            return np.full(n, np.inf), np.zeros((n, n))
        RJ, q = triangle(J, r)
        ev.gradient = RJ.T @ q
        down = self._profile_downdate(ev)
        P = RJ.T @ RJ
        H = P - down.T @ down if down is not None else P
        ev.secant = _secant_update(self.secant, ev.theta, ev.gradient, H)
        d = np.sqrt(np.diag(P))
        d = np.where(d > 0, d, 1.0)

        def factor(B):  # (q, R_B), or None where B is not safely positive definite
            if not np.all(np.isfinite(B)):
                return None
            try:
                U = scipy.linalg.cholesky(B / np.outer(d, d), lower=False)
            except np.linalg.LinAlgError:
                return None
            diag = np.diag(U)
            if np.min(diag) ** 2 < 1e-10 * np.max(diag) ** 2:
                return None
            RB = U * d
            return scipy.linalg.solve_triangular(RB, ev.gradient, trans="T", lower=False), RB

        gauss_newton = factor(H) if down is not None else None
        gauss_newton = gauss_newton or (q, RJ)
        ev.decrease = predicted_decrease(
            self.structure.bounds, ev.theta, ev.gradient, gauss_newton[1].T @ gauss_newton[1],
            0.5 * float(gauss_newton[0] @ gauss_newton[0]))
        secant = factor(H + ev.secant) if ev.secant is not None else None
        return secant or gauss_newton

    def _profile_downdate(self, ev: _Evaluation) -> np.ndarray | None:
        """Rows ``D`` (k x n) with ``D^T D = (2/N) U^T W U`` (``_profile_model``); None when
        ``I - (2/N) V^T (K^T K)^-1 V`` is not positive definite."""
        p, n = len(self.outputs), ev.jacobian.shape[1]
        U, M = np.zeros((p, n)), np.zeros((p, p))
        start, n_samples = 0, 0
        for k, E in enumerate(ev.errors):
            m, n_samples = E.size, n_samples + len(E)
            rr = ev.residual[start:start + m].reshape(-1, p)
            U += np.einsum("kjn,kj->jn", ev.jacobian[start:start + m].reshape(-1, p, n), rr)
            K = ev.nuisance[k]
            if K.shape[1]:
                V = np.einsum("kjl,kj->jl", K.reshape(-1, p, K.shape[1]), rr)  # (p, k)
                Y = scipy.linalg.solve_triangular(ev.factor[k], V.T, lower=True)
                M += Y.T @ Y
            start += m
        free = ev.R > self.floor
        scale = 2.0 / n_samples
        try:
            Lw = scipy.linalg.cholesky(np.eye(int(free.sum())) - scale * M[np.ix_(free, free)],
                                       lower=True)
        except (np.linalg.LinAlgError, ValueError):  # not positive definite, or not finite
            return None
        return math.sqrt(scale) * scipy.linalg.solve_triangular(Lw, U[free], lower=True)

    def set_sigma(self, sigma) -> None:
        self.sigma = np.asarray(sigma, dtype=float)
        self._cache = None


def _secant_update(state, theta: np.ndarray, gradient: np.ndarray,
                   H: np.ndarray) -> np.ndarray | None:
    """The structured secant matrix ``S`` at ``theta`` from ``state = (theta_a, g_a, S_a)``
    of the last accepted iterate: ``(H + S) s = y`` (``s = theta - theta_a``, ``y`` the
    change of the gradient) by the symmetric rank-2 update of NL2SOL (Dennis, Gay & Welsch
    1981, with its sizing of ``S_a``); ``S_a`` itself when ``y^T s <= 0`` or the update is not
    finite (a step into a violently unstable model); None without a state."""
    if state is None:
        return None
    theta_a, g_a, S_a = state
    s, y = theta - theta_a, gradient - g_a
    with np.errstate(over="ignore", invalid="ignore"):
        ys = np.float64(y @ s)
        if not np.any(s) or not ys > 0.0 or not np.isfinite(ys):
            return S_a
        y_sharp = y - H @ s
        sSs = np.float64(s @ S_a @ s)
        S = S_a * min(1.0, abs(s @ y_sharp) / abs(sSs)) if sSs != 0.0 else S_a
        v = y_sharp - S @ s
        S = S + (np.outer(v, y) + np.outer(y, v)) / ys - (v @ s) * np.outer(y, y) / ys ** 2
    return S if np.all(np.isfinite(S)) else S_a


class _Reanchor(SolveStopped):
    """The profile likelihood fell below what the solver's cost offset allows (at ``theta``,
    the lowest point so far): restart the solve there with a new offset."""


def _group_of(groups: list[_Group], row: int, column: int) -> int:
    for k, g in enumerate(groups):
        if g.column == column and g.rows[row]:
            return k
    raise IdentificationError(f"no input group holds B entry ({row}, {column})")


def _independent_columns(Nm: np.ndarray, rtol: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """Columns of ``Nm`` (N x k) not numerically in the span of the columns before them, and
    the Cholesky factor of the Gram matrix of the kept columns.

    Ordered (unpivoted) Cholesky of the column-normalised Gram matrix ``Nm^T Nm``: column j
    is dependent when its residual after projection on the kept earlier ones is below
    ``rtol`` of its norm. Biases come first, so an initial state acting like a bias is the one
    dropped. The small k x k Gram matrix replaces a QR of the tall N x k matrix (a BLAS-3
    product, many times faster); the nuisance columns are well scaled, so the squared
    condition number costs no accuracy that matters here.

    Returns
    -------
    keep : ndarray of bool (k,)
    L : ndarray (k_kept, k_kept)
        Lower Cholesky factor of ``Nm[:, keep]^T Nm[:, keep]``.
    """
    return _independent_gram(Nm.T @ Nm, rtol)


def _independent_gram(Gram: np.ndarray, rtol: float = 1e-7) -> tuple[np.ndarray, np.ndarray]:
    """:func:`_independent_columns` from the Gram matrix ``Nm^T Nm`` (k x k) itself: one
    LAPACK Cholesky of the kept columns' normalised Gram matrix, repeated without the first
    column whose pivot (its squared residual after the kept ones before it) is below
    ``rtol^2``, until none is (the columns before it are unaffected, so this keeps what
    a column-by-column factorisation keeps)."""
    d = np.sqrt(np.maximum(np.diag(Gram), 0.0))
    keep = d > 0.0
    while True:
        idx = np.flatnonzero(keep)
        if not len(idx):
            return keep, np.zeros((0, 0))
        Gn = Gram[np.ix_(idx, idx)] / np.outer(d[idx], d[idx])
        Ln, info = scipy.linalg.lapack.dpotrf(Gn, lower=1, clean=1)
        valid = len(idx) if info == 0 else info - 1  # info > 0: a pivot <= 0 there
        small = np.flatnonzero(np.diag(Ln)[:valid] ** 2 <= rtol ** 2)
        bad = small[0] if len(small) else (valid if info > 0 else None)
        if bad is None:
            return keep, Ln * d[idx][:, None]
        keep[idx[bad]] = False


def _chol_solve(L: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Solve ``(L L^T) x = b``."""
    return scipy.linalg.cho_solve((L, True), b)


# --------------------------------------------------------------------------------------------
# Maximum-likelihood relaxation: LM with R fixed, then the R update
# --------------------------------------------------------------------------------------------


@dataclass
class _Converged:
    structure: LinearStructure
    theta: np.ndarray
    R: np.ndarray  #: noise variances of the fitted outputs
    cost: float  #: negative log-likelihood L
    statistics: ParameterStatistics
    evaluation: _Evaluation
    outer_iterations: int
    nfev: int
    history: list  #: (cost, max relative R change) per outer iteration
    outputs: tuple = ()  #: fitted outputs


def _noise_variance(errors: list, floor: np.ndarray) -> np.ndarray:
    """ML estimate ``R_jj = mean over all samples of e_j^2``, floored."""
    E = np.vstack(errors)
    return np.maximum(np.mean(E ** 2, axis=0), floor)


def _likelihood(errors: list, R: np.ndarray) -> float:
    """``L = 1/2 sum e^T R^-1 e + N/2 sum ln R_jj`` (no 2 pi constant)."""
    E = np.vstack(errors)
    return float(0.5 * np.sum(E ** 2 / R) + 0.5 * len(E) * np.sum(np.log(R)))


def _solve(model: OutputErrorModel, theta0, *, tol: float, max_nfev: int | None,
           deadline: Deadline | None = None):
    lo, hi = model.structure.bounds
    span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    theta0 = np.clip(np.asarray(theta0, float), lo + 1e-9 * span, hi - 1e-9 * span)
    fun, jac = ((model.profile_residuals, model.profile_jacobian) if model.profile
                else (model.compressed_residuals, model.compressed_jacobian) if COMPRESSED
                else (model.residuals, model.jacobian))
    residuals = fun if deadline is None else deadline.wrap(fun)
    return scipy.optimize.least_squares(residuals, theta0, jac=jac,
                                        bounds=(lo, hi), method="trf", x_scale="jac",
                                        ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev)


def _converge(structure: LinearStructure, records: list[TimeRecord], outputs, theta0, *,
              R0: np.ndarray | None, biases: bool, initial_state: bool, tol: float,
              max_nfev: int | None, max_outer: int, r_tol: float, cost_tol: float,
              counter: dict, deadline: Deadline | None = None,
              profile: bool | None = None) -> _Converged:
    """Relaxation (Jategaonkar 2015 sec. 4.6): LM on theta with R fixed, then R from the
    residuals, until R and the cost settle; with ``profile`` (default :data:`PROFILE`),
    until R changes by less than :data:`PROFILE_R_CHANGE`, then :func:`_converge_profile`
    (at once when the start's residuals fit a given ``R0`` that well: most of the
    reduction's refits). A profile solve that ends above the likelihood it started from (it
    wandered into unstable models) is discarded and the relaxation goes on from there."""
    profile = PROFILE if profile is None else profile
    kw = dict(biases=biases, initial_state=initial_state, tol=tol, max_nfev=max_nfev,
              r_tol=r_tol, cost_tol=cost_tol, counter=counter, deadline=deadline)

    def handed_over(theta, R, cost, **solve):
        conv = _converge_profile(model, theta, R0=R, tol=tol, max_nfev=max_nfev,
                                 counter=counter, deadline=deadline, **solve)
        if np.isfinite(conv.cost) and conv.cost <= cost + COST_SETTLED:
            return conv
        return _converge(structure, records, outputs, theta, R0=R,
                         max_outer=solve["max_outer"], profile=False, **kw)

    model = OutputErrorModel(structure, records, outputs, biases=biases,
                             initial_state=initial_state)
    floor = R_FLOOR * np.maximum(np.var(np.vstack([r.Z for r in records]), axis=0), 1e-12)
    model.floor = floor
    theta = np.asarray(theta0, float).copy()
    if profile and R0 is not None:
        # a refit: straight to the profile solve when its start's residuals still fit R0
        model.set_sigma(np.sqrt(R0))
        errors = model.evaluate(theta).errors
        R_start = _noise_variance(errors, floor)
        if np.max(np.abs(R_start / R0 - 1.0)) < PROFILE_R_CHANGE:
            return handed_over(theta, R0, _likelihood(errors, R_start), max_outer=max_outer,
                               history=[], outer=0)
    if R0 is None:  # start weights: the residuals of the start model (unit weights first)
        R0 = _noise_variance(model.evaluate(theta).errors, floor)
    R = np.asarray(R0, float).copy()
    history, nfev, cost, outer = [], 0, math.inf, 0
    # While R is still far from its fixed point, solving each weighted problem to full
    # accuracy is wasted: the next R moves the optimum again. Those early solves stop after
    # a few Gauss-Newton steps; once R has settled to EARLY_R_CHANGE, every solve converges
    # fully, so the end point is the relaxation's usual fixed point.
    early = True
    # log R of successive plain fixed-point steps whose solves converged fully; three of them
    # give an Aitken extrapolation of R (the relaxation converges linearly: each step shrinks
    # the change of R by a near-constant factor of ~0.6 on the hover study).
    chain: list = []
    for outer in range(1, max_outer + 1):
        R_in = R
        model.set_sigma(np.sqrt(R))
        if len(theta):
            limit = max_nfev
            if early and outer < max_outer:
                limit = EARLY_NFEV if max_nfev is None else min(max_nfev, EARLY_NFEV)
            before = model.n_cost
            model.settle = RELAXATION_SETTLES
            try:
                theta = _solve(model, theta, tol=tol, max_nfev=limit, deadline=deadline).x
            except Settled as settled:
                theta = settled.theta
            finally:
                model.settle = False
            nfev += model.n_cost - before
        ev = model.evaluate(theta)
        R_new = _noise_variance(ev.errors, floor)
        change = float(np.max(np.abs(R_new / R - 1.0)))
        new_cost = _likelihood(ev.errors, R_new)
        history.append((new_cost, change))
        settled = abs(new_cost - cost) <= max(cost_tol * abs(new_cost), COST_SETTLED)
        done = not early and change < r_tol and settled
        full_solve = not early
        early = early and change >= EARLY_R_CHANGE
        R, cost = R_new, new_cost
        if done:
            break
        if profile and change < PROFILE_R_CHANGE and outer < max_outer:
            return handed_over(theta, R, cost, max_outer=max_outer - outer, history=history,
                               outer=outer)
        chain = (chain or [np.log(R_in)]) + [np.log(R_new)] if full_solve else []
        if len(chain) == 3 and outer < max_outer and AITKEN:
            R, chain = np.exp(_aitken(*chain)), []
    model.set_sigma(np.sqrt(R))
    ev = model.evaluate(theta, jacobian=True)
    stats = _end_statistics(model, theta, ev, counter, outer)
    return _Converged(structure, theta, R, cost, stats, ev, outer, nfev, history,
                      tuple(outputs))


def _end_statistics(model: OutputErrorModel, theta: np.ndarray, ev: _Evaluation,
                    counter: dict, outer: int) -> ParameterStatistics:
    """Cramer-Rao statistics at a fit's end point ``ev``; adds the model's evaluations and
    the solves (``outer``) to ``counter``."""
    if len(theta):
        stats = parameter_statistics(ev.jacobian, theta, model.structure.free_names)
    else:
        stats = parameter_statistics(np.zeros((1, 0)), theta, ())
    counter["cost"] += model.n_cost
    counter["jacobian"] += model.n_jac
    counter["outer"] += outer
    return stats


def _converge_profile(model: OutputErrorModel, theta: np.ndarray, *, R0: np.ndarray | None,
                      tol: float, max_nfev: int | None, max_outer: int, counter: dict,
                      deadline: Deadline | None, history: list, outer: int) -> _Converged:
    """Trust-region solve (``trf``) of the profile likelihood ``L_p(theta)`` from ``theta``:
    R and the nuisance parameters consistent at every evaluation, model matrix Gauss-Newton
    plus structured secant (``OutputErrorModel._profile_model``), so one solve reaches the
    maximum-likelihood point the relaxation approaches linearly. It stops where the
    Gauss-Newton model predicts less than :data:`SOLVE_SETTLED` of further decrease; where
    ``trf``'s own tolerances ``tol`` or ``max_nfev`` end it before that, it starts again
    there (secant reset). The solver's cost is ``L_p - anchor``, the anchor ``N p / 2`` (the
    whitened cost at a fixed R's optimum: the relaxation's scale for ``tol``) below the
    start's model minimum; a fall past it restarts the solve there (at most ``max_outer``
    solves)."""
    model.profile, model.secant = True, None
    if R0 is not None:  # the inner fixed point's first guess
        model.set_sigma(np.sqrt(R0))
    for outer in range(outer + 1, outer + max_outer + 1):
        model.anchor = None  # set by the solve's first evaluation
        if not len(theta):
            break
        try:
            theta = _solve(model, theta, tol=tol, max_nfev=max_nfev, deadline=deadline).x
        except Settled as settled:
            theta = settled.theta
        except _Reanchor as low:
            theta = low.theta
            history.append((model.evaluate(theta).cost, 0.0))
            continue
        ev = model.evaluate(theta, jacobian=True)
        if ev.compressed is None:
            ev.compressed = model._profile_model(ev)
        stalled = bool(history) and history[-1][0] - ev.cost < SOLVE_SETTLED
        history.append((ev.cost, 0.0))
        if ev.decrease < SOLVE_SETTLED or not np.isfinite(ev.decrease) or stalled:
            break
        model.secant = None  # trf stopped on its own tolerances short of settling: again
    ev = model.evaluate(theta, jacobian=True)
    stats = _end_statistics(model, theta, ev, counter, outer)
    return _Converged(model.structure, theta, ev.R, ev.cost, stats, ev, outer, model.n_cost,
                      history, tuple(model.outputs))


def _aitken(x0: np.ndarray, x1: np.ndarray, x2: np.ndarray) -> np.ndarray:
    """Aitken's delta-squared extrapolation of three successive fixed-point iterates, per
    component, where they converge monotonically (ratio of successive changes in (0, 0.9));
    the last iterate elsewhere."""
    d1, d2 = x1 - x0, x2 - x1
    with np.errstate(divide="ignore", invalid="ignore"):
        q = np.where(d1 != 0, d2 / d1, 0.0)
    use = (q > 0) & (q < 0.9)
    return np.where(use, x2 + d2 * np.where(use, q / (1 - q), 0.0), x2)


def _joint_statistics(conv: _Converged) -> ParameterStatistics:
    """Statistics of structure parameters and nuisance parameters together, from the joint
    (block) Jacobian of all records (for the bounds of biases and initial states)."""
    ev = conv.evaluation
    widths = [nm.shape[1] for nm in ev.nuisance]
    blocks = []
    for k, (S, Nm) in enumerate(zip(ev.sens, ev.nuisance)):
        row = [S]
        for j, w in enumerate(widths):
            row.append(Nm if j == k else np.zeros((len(S), w)))
        blocks.append(np.hstack(row))
    G = np.vstack(blocks)
    names = list(conv.structure.free_names) + [n for kept in ev.kept for n in kept]
    values = np.concatenate([conv.theta] + [_nuisance_values(conv, k)
                                            for k in range(len(ev.kept))])
    return parameter_statistics(G, values, names)


def _nuisance_values(conv: _Converged, k: int) -> np.ndarray:
    ev = conv.evaluation
    out = []
    for name in ev.kept[k]:
        kind, rest = name.split("_", 1)
        channel = rest.split("[", 1)[0]
        if kind == "bias":
            out.append(ev.bias[k][list(conv.outputs).index(channel)])
        else:
            out.append(ev.x0[k][list(conv.structure.states).index(channel)])
    return np.array(out, float)


# --------------------------------------------------------------------------------------------
# Result
# --------------------------------------------------------------------------------------------


@dataclass
class TimeFitResult(FitResultParameters):
    """Outcome of :func:`identify_time_domain` (fields mirror
    :class:`sysid.identify.frequency_domain.FrequencyFitResult`).

    Attributes
    ----------
    model : xr.Dataset
        Model Dataset (docs/data_model.md), ``method = "time_domain"``; extra variables
        ``noise_variance`` (output), ``output_rms_error`` (output), ``bias`` and
        ``bias_cramer_rao`` (record, output), ``initial_state`` and
        ``initial_state_cramer_rao`` (record, state; NaN where not estimated).
    structure : LinearStructure
        Final (reduced) structure; ``theta`` its free values.
    statistics : ParameterStatistics
        Accuracy of the free parameters (nuisance parameters marginalised).
    nuisance_statistics : ParameterStatistics
        Joint statistics of structure and nuisance parameters (names ``bias_<out>[<record>]``,
        ``x0_<state>[<record>]``).
    cost : float
        Negative log-likelihood ``L`` at the optimum (R re-estimated).
    J_rms : float
        ``sqrt(mean of e^2 over samples and outputs)`` with unit weights (ft/s, deg/s, deg).
    noise_variance : dict
        ``output -> R_jj`` (analysis units squared).
    output_rms_error : dict
        ``output -> rms residual``.
    biases : xr.DataArray
        (record, output), analysis units.
    records, outputs : tuple of str
        Manoeuvres used, outputs fitted.
    reduction : ReductionResult or None
    start : str
        ``"model"``, ``"values"`` or ``"structure"``.
    restart : dict
        Cost of the first convergence and of the restart from the perturbed solution (empty
        when ``restart_fraction == 0``).
    n_cost_evaluations, n_jacobian_evaluations, n_outer_iterations : int
    elapsed : float
        Wall time, s.
    coloured : ColouredBounds or None
        Bounds of the free parameters corrected for coloured residuals (Morelli & Klein;
        :func:`sysid.identify.statistics.coloured_residual_covariance`), also in ``model`` as
        ``cramer_rao_corrected`` and ``cramer_rao_percent_corrected``.
    """

    model: xr.Dataset
    structure: LinearStructure
    theta: np.ndarray
    statistics: ParameterStatistics
    nuisance_statistics: ParameterStatistics
    cost: float
    J_rms: float
    noise_variance: dict
    output_rms_error: dict
    biases: xr.DataArray
    records: tuple
    outputs: tuple
    reduction: ReductionResult | None
    start: str
    restart: dict
    n_cost_evaluations: int
    n_jacobian_evaluations: int
    n_outer_iterations: int
    elapsed: float
    full_statistics: ParameterStatistics | None = None
    initial_structure: LinearStructure | None = None
    coloured: ColouredBounds | None = None

    @property
    def J(self) -> float:
        """The cost (negative log-likelihood), named like the frequency-domain result."""
        return self.cost

    def bias(self, record: str, output: str) -> tuple[float, float]:
        """``(bias, Cramer-Rao bound)`` of one output in one record."""
        m = self.model
        return (float(m["bias"].sel(record=record, output=output)),
                float(m["bias_cramer_rao"].sel(record=record, output=output)))

    def table(self) -> str:
        """Derivative table with Cramer-Rao bounds (paper Tables 2-3), delays, noise, biases."""
        m = self.model
        lines = [f"Time-domain identification ({self.structure.name}), output error on "
                 f"{len(self.records)} record(s): {', '.join(self.records)}; start: {self.start}",
                 *parameter_rows(m, absolute_cr=True)]
        lines.append("noise std (from residuals): " + ", ".join(
            f"{o} {math.sqrt(v):.4g}" for o, v in self.noise_variance.items()))
        lines.append("output biases (Cramer-Rao bound):")
        for rec in self.records:
            lines.append(f"  {rec}: " + ", ".join(
                f"{o} {self.bias(rec, o)[0]:.4g} ({self.bias(rec, o)[1]:.2g})"
                for o in self.outputs))
        lines.append(f"cost (neg. log-likelihood) = {self.cost:.3f}, J_rms = {self.J_rms:.4f}")
        if self.reduction is not None and self.reduction.steps:
            lines.append("model reduction:")
            lines.append(self.reduction.table())
        return "\n".join(lines)


# --------------------------------------------------------------------------------------------
# Entry point
# --------------------------------------------------------------------------------------------


@fit_settings
def identify_time_domain(records, structure: LinearStructure, *,
                         start: xr.Dataset | np.ndarray | None = None,
                         outputs: Sequence[str] | None = None, biases: bool = True,
                         initial_state: bool = True, reduce: bool = True,
                         cr_max: float = GUIDELINES["cr_max"],
                         insensitivity_max: float = GUIDELINES["insensitivity_max"],
                         max_cost_increase: float = MAX_COST_INCREASE,
                         protected: Sequence[str] = (), tol: float = 1e-8,
                         max_nfev: int | None = None, max_outer: int = 20,
                         time_limit: float | None = FIT_TIME_LIMIT_S,
                         r_tol: float = 1e-3, cost_tol: float = 1e-7,
                         restart_fraction: float = 0.0, seed: int = 0, quiet: bool = True,
                         progress=None) -> TimeFitResult:
    """Identify a structure from time histories by maximum-likelihood output error.

    Parameters
    ----------
    records : xr.Dataset or sequence of xr.Dataset
        Time histories (docs/data_model.md): controls ``lon lat col ped`` (%), measurements
        in analysis units, absolute, with ``trim_<channel>`` attributes; all are fitted at
        once (one set of structure parameters, nuisance parameters per record).
    structure : LinearStructure
        Model structure; its free parameters are estimated.
    start : xr.Dataset or array, optional
        Start values: a model Dataset (e.g. the frequency-domain result or the truth model's
        linearisation) or the free-parameter vector; default the structure's values.
    outputs : sequence of str, optional
        Fitted outputs (default: every structure output present in all records).
    biases, initial_state : bool
        Estimate a bias per output and an initial state per record (nuisance parameters,
        eliminated by variable projection; see the module docstring).
    reduce : bool
        Stepwise model reduction (:func:`sysid.identify.reduction.stepwise_reduction`) with
        ``cr_max`` (20 %), ``insensitivity_max`` (10 %) and ``max_cost_increase``
        (:data:`MAX_COST_INCREASE`, in units of the negative log-likelihood), never removing
        ``protected`` or the structure's ``keep`` parameters.
    tol : float
        ``ftol = xtol = gtol`` of :func:`scipy.optimize.least_squares` (``"trf"``).
    max_nfev : int, optional
        Limit on cost evaluations per LM solve (default scipy's, 100 per parameter).
    time_limit : float or None
        Wall-clock bound (s) of the whole identification (default
        :data:`sysid.core.guidelines.FIT_TIME_LIMIT_S`); past it,
        :class:`~sysid.core.errors.IdentificationError`. None: unbounded.
    max_outer, r_tol, cost_tol
        Relaxation: at most ``max_outer`` (LM solve, R update) cycles and profile solves
        together; with ``PROFILE = False``, stop when every ``R_jj`` changes by less than
        ``r_tol`` (relative) and the cost by less than ``cost_tol`` (relative) or
        :data:`COST_SETTLED` (absolute).
    restart_fraction, seed
        When > 0, the final fit is restarted from its solution perturbed by
        ``+-restart_fraction`` (relative, seeded) and the better minimum kept.
    quiet, progress
        Per-stage lines on stderr unless quiet.

    Returns
    -------
    TimeFitResult

    Examples
    --------
    >>> from sysid.data.netcdf import read_campaign
    >>> from sysid.data.campaign import maneuvers, trim_from_attrs
    >>> from sysid.models import load_structure
    >>> tree = read_campaign("campaign.nc")
    >>> records = maneuvers(tree, "3211_*")
    >>> structure = load_structure("hover_6dof", trim=trim_from_attrs(records))
    >>> result = identify_time_domain(records, structure,
    ...                               start=tree["linearization"].to_dataset())
    >>> result.model["value"].sel(parameter="M_q"), result.model.attrs["J_rms"]
    """
    t_start = time.perf_counter()
    progress = progress or Progress(quiet=quiet)
    records, outs, recs = fit_inputs(records, structure, outputs,
                                     what="identify_time_domain")
    if start is None:
        theta0, start_kind = structure.theta0, "structure"
    elif isinstance(start, xr.Dataset):
        theta0, start_kind = structure.values_from_model(start), "model"
    else:
        theta0, start_kind = np.asarray(start, float), "values"
        if theta0.shape != structure.theta0.shape:
            raise InputDataError(f"start has {theta0.size} values; structure "
                                 f"{structure.name!r} has {structure.theta0.size} free "
                                 f"parameters {list(structure.free_names)}")
    counter = {"cost": 0, "jacobian": 0, "outer": 0}
    kw = dict(biases=biases, initial_state=initial_state, tol=tol, max_nfev=max_nfev,
              max_outer=max_outer, r_tol=r_tol, cost_tol=cost_tol, counter=counter,
              deadline=Deadline(time_limit, "time-domain fit"))

    def converge(st, th0, R0):
        return _converge(st, recs, outs, th0, R0=R0, **kw)

    n_samples = sum(len(r.time) for r in recs)
    with progress.stage(f"time-domain output error: {len(structure.free_index)} parameters, "
                        f"{len(recs)} record(s), {n_samples} samples x {len(outs)} outputs"):
        full = converge(structure, theta0, None)
        progress.message(f"[sysid]   converged: cost {full.cost:.3f} after "
                         f"{full.outer_iterations} R updates ({full.nfev} LM evaluations)")
    reduction, final = None, full
    if reduce:
        def refit(removed, previous, ceiling):
            # the ceiling is not used: the relaxation's likelihood has no lower bound from
            # one solve's Gauss-Newton model (a later R update can lower it further)
            prev: _Converged = previous.payload
            st = structure.fix(removed, 0.0)
            if CONDITIONAL_START:
                th0 = conditional_start(prev.statistics, removed[-1], st.free_names)
            else:
                vals = dict(zip(prev.structure.free_names, prev.theta))
                th0 = np.array([vals[n] for n in st.free_names])
            c = converge(st, th0, prev.R)
            return FitOutcome(c.cost, c.statistics, c)

        with progress.stage("model reduction"):
            reduction = stepwise_reduction(
                refit, FitOutcome(full.cost, full.statistics, full), cr_max=cr_max,
                insensitivity_max=insensitivity_max, max_cost_increase=max_cost_increase,
                protected=(*protected, *structure.kept_names), progress=progress)
        final = reduction.final.payload
    restart = {}
    if restart_fraction > 0:
        again = converge(final.structure, perturbed_start(final.theta, final.structure, seed,
                                                   restart_fraction), final.R)
        restart = {"cost_first": final.cost, "cost_restart": again.cost,
                   "fraction": restart_fraction, "seed": seed}
        if again.cost < final.cost:
            final = again
        restart["same_minimum"] = bool(abs(restart["cost_first"] - restart["cost_restart"])
                                       <= 1e-6 * max(abs(final.cost), 1.0))
    joint = _joint_statistics(final)
    coloured = _coloured_bounds(final)
    E = np.vstack(final.evaluation.errors)
    J_rms = float(np.sqrt(np.mean(E ** 2)))
    elapsed = time.perf_counter() - t_start
    model = _model_dataset(final, joint, recs, outs, reduction, start_kind, restart, counter,
                           elapsed, records, J_rms, coloured)
    rms = np.sqrt(np.mean(E ** 2, axis=0))
    return TimeFitResult(
        model, final.structure, final.theta, final.statistics, joint, final.cost, J_rms,
        dict(zip(outs, final.R.tolist())), dict(zip(outs, rms.tolist())), model["bias"],
        tuple(r.name for r in recs), outs, reduction, start_kind, restart, counter["cost"],
        counter["jacobian"], counter["outer"], elapsed, full_statistics=full.statistics,
        initial_structure=structure, coloured=coloured)


def _coloured_bounds(conv: _Converged) -> ColouredBounds | None:
    """Bounds of the free parameters corrected for coloured residuals, from the final
    evaluation's projected whitened Jacobian and whitened residuals, record by record."""
    ev = conv.evaluation
    n, p = len(conv.theta), len(conv.outputs)
    if n == 0 or ev.jacobian is None:
        return None
    ends = np.cumsum([0] + [len(e) * p for e in ev.errors])
    S = [ev.jacobian[a:b].reshape(-1, p, n) for a, b in zip(ends[:-1], ends[1:])]
    v = [ev.residual[a:b].reshape(-1, p) for a, b in zip(ends[:-1], ends[1:])]
    return coloured_residual_covariance(sensitivities=S, residuals=v,
                                        information_inverse=conv.statistics.covariance)


def _model_dataset(final: _Converged, joint: ParameterStatistics, recs, outs, reduction,
                   start_kind, restart, counter, elapsed, datasets, J_rms,
                   coloured: ColouredBounds | None = None) -> xr.Dataset:
    st = final.structure
    ev = final.evaluation
    attrs = {
        "method": "time_domain",
        "cost": final.cost,
        "cost_definition": "negative log-likelihood 1/2 sum e^T R^-1 e + N/2 sum ln R_jj",
        "J_rms": float(J_rms),
        "records": ",".join(r.name for r in recs),
        "n_records": len(recs),
        "n_samples": int(sum(len(r.time) for r in recs)),
        "fitted_outputs": ",".join(outs),
        "noise_variance": json.dumps(dict(zip(outs, final.R.tolist()))),
        "estimator": ("maximum-likelihood output error (relaxation: LM with R fixed, R "
                      "update; then Gauss-Newton on the profile likelihood)" if PROFILE else
                      "maximum-likelihood output error (relaxation: LM with R fixed, R update)"),
        "nuisance": "bias per output and initial state per record (variable projection)",
        "sensitivities": "analytic (ZOH sensitivity equations, expm Frechet derivatives)",
        "cramer_rao_convention": "H = sum S^T R^-1 S (nuisance marginalised), "
                                 "CR = sqrt(diag H^-1)",
        "start": start_kind,
        "optimizer": "scipy.optimize.least_squares(trf)",
        "restart": json.dumps(restart),
        "outer_iterations": int(final.outer_iterations),
        "n_cost_evaluations": int(counter["cost"]),
        "n_jacobian_evaluations": int(counter["jacobian"]),
        "elapsed_s": float(elapsed),
        "reduction": int(reduction is not None),
        "reduction_steps": json.dumps([s.as_dict() for s in reduction.steps]
                                      if reduction is not None else []),
        "removed_parameters": ",".join(reduction.removed) if reduction is not None else "",
    }
    for key in ("flight_condition", "campaign"):
        if key in datasets[0].attrs and isinstance(datasets[0].attrs[key], (str, int, float)):
            attrs[f"data_{key}"] = datasets[0].attrs[key]
    ds = st.to_dataset(final.theta, final.statistics, attrs=attrs)
    # Trim reference: the first record's (the perturbations were taken about it).
    tin = dict(zip(st.inputs, recs[0].trim_input))
    ds["trim_input"].values = np.array([tin[c] for c in st.inputs])
    tout = dict(zip(outs, recs[0].trim_output))
    ds["trim_output"].values = np.array([tout.get(o, float(v)) for o, v in
                                         zip(st.outputs, ds["trim_output"].values)])
    names = [r.name for r in recs]
    cr = dict(zip(joint.names, joint.cramer_rao))
    b_cr = np.array([[cr.get(f"bias_{o}[{r}]", np.nan) for o in outs] for r in names])
    x0_cr = np.array([[cr.get(f"x0_{s}[{r}]", np.nan) for s in st.states] for r in names])
    full_out = list(st.outputs)

    def pad(rows):  # (k, n_fitted) -> (k, n_structure_outputs), NaN where not fitted
        return np.array([[row[outs.index(o)] if o in outs else np.nan for o in full_out]
                         for row in rows])

    E = np.vstack(ev.errors)
    ds = ds.assign_coords(record=names)
    ds["noise_variance"] = ("output", pad([final.R])[0],
                            {"long_name": "measurement-noise variance R (from residuals)"})
    ds["output_rms_error"] = ("output", pad([np.sqrt(np.mean(E ** 2, axis=0))])[0],
                              {"long_name": "rms output residual"})
    ds["bias"] = (("record", "output"), pad(np.array(ev.bias)),
                  {"long_name": "output bias (nuisance)"})
    ds["bias_cramer_rao"] = (("record", "output"), pad(b_cr),
                             {"long_name": "Cramer-Rao bound of the output bias"})
    ds["initial_state"] = (("record", "state"), np.array(ev.x0),
                           {"long_name": "initial state perturbation (nuisance); NaN: not "
                                         "estimated"})
    ds["initial_state_cramer_rao"] = (("record", "state"), x0_cr,
                                      {"long_name": "Cramer-Rao bound of the initial state"})
    return add_corrected_bounds(ds, st.free_names, final.theta, coloured, recs[0].dt)
