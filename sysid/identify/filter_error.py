"""Time-domain identification with process noise: the filter-error method.

Output error (:mod:`sysid.identify.time_domain`) has no process noise: turbulence that drives
the aircraft lands in its residuals, and under a stabilising feedback loop those residuals
are correlated with the recorded inputs, so its estimates are biased and its bounds (even
corrected for coloured residuals) over-confident. The filter-error method (Maine & Iliff
1986; Jategaonkar 2015 ch. 5) adds process noise ``w ~ N(0, Q)``, ``Q = F F^T`` per sample,
to the model and corrects its states by the steady-state Kalman gain (docs/methods.md,
"Filter error"):

    x^[k+1] = Phi x^[k] + sum_g Gamma_g v_g[k] + K e[k] ,   x^[0] = x0
    y^[k]   = C x^[k] + D u[k] + b ,                          e[k] = z[k] - y^[k]
    P = Phi P Phi^T - Phi P C^T (C P C^T + R)^-1 C P Phi^T + Q     (discrete Riccati)
    K = Phi P C^T (C P C^T + R)^-1

with exactly the discretisation, delay and trim conventions of output error (``Phi, Gamma``
exact zero-order hold, delayed inputs ``v_g`` by linear interpolation; the same
:func:`~sysid.identify.time_domain.prepare_records` and input groups). When the model is
right, ``e`` is the innovation sequence (white, covariance ``Sigma``) and the negative
log-likelihood of the data is

    L = 1/2 sum_k e[k]^T Sigma^-1 e[k] + (N/2) ln det Sigma

(the prediction-error criterion of the innovations form, Ljung 1999 ch. 7). Parameters:
the structure's ``theta``; the process noise in LDL form, ``Q = U D U^T`` with ``D`` the
variances of the state equations that carry noise and ``U`` unit-triangular (its entries the
correlations of a full ``Q``); the measurement-noise variances ``R = diag(R_j)``; a bias per
output and an initial state per record. The variances are bounded at 0 and enter ``Q`` and
``R`` linearly: with standard deviations (``R = r^2``, ``Q = F F^T``) zero is a stationary
point where the Gauss-Newton model sees no decrease, and a fit creeps towards a noise-free
channel for hundreds of evaluations. ``K`` is unchanged when ``Q`` and ``R`` are scaled
together, so ``R_0`` is held at its start value and the common factor is set at the end so
that ``C P C^T + R`` matches ``Sigma``. ``K`` comes from the Riccati equation
(:func:`scipy.linalg.solve_discrete_are`), so the predictor ``Phi - K C`` is stable for
every trial, and ``Q = 0`` is output error. (A free gain matrix is not kept stable: without
process noise its estimate piles up on the stability boundary, the zeros of the noise model
``I + C (qI - Phi + K C)^-1 K`` meeting the unit circle.) Minimised by relaxation: a
trust-region solve on the whitened innovations ``Sigma^-1/2 e`` with ``Sigma`` fixed
(:func:`scipy.optimize.least_squares`), then ``Sigma = 1/N sum e e^T`` (its
maximum-likelihood estimate), until ``L`` changes by less than ``cost_tol``.

Nuisance parameters: the bias ``b`` and initial state ``x^[0]`` of a record enter its
innovations linearly (``e = e_0 + S_c c``, ``S_c`` the same for every record of one sample
interval), so they are eliminated by variable projection (Golub & Pereyra 1973) as in
output error: at every evaluation they are the weighted least-squares solution, and the
solver sees ``theta`` and the noise only, with Kaufman's Jacobian (the sensitivities
projected off the nuisance columns; its Gauss-Newton matrix the Schur complement of the
joint one). Jointly estimated, the near-collinear bias and initial speed of a record made
the solver creep along their valley.

Sensitivities (Jategaonkar 2015 ch. 5): with ``K`` held, ``dx^`` follows the predictor's
own recursion,

    dx^[k+1] = (Phi - K C) dx^[k] + dPhi x^ + dGamma v + Gamma dv + dK e
               - K (dC x^ + dD u + db) ,                  dx^[0] = dx0
    de[k]    = -(C dx^[k] + dC x^[k] + dD u[k] + db)

(``dPhi, dGamma`` Frechet derivatives of the zero-order hold, ``dv`` of a free delay); ``dK``
from the derivative of the Riccati solution, a discrete Lyapunov equation
``dP - Acl dP Acl^T = T + T^T + dQ + K dR K^T``, ``T = (dPhi - K dC) P Acl^T``. The solver
gets the problem compressed to ``n_alpha + 1`` rows from its normal equations, accumulated
record by record (same steps, no tall Jacobian formed); :data:`FINITE_DIFFERENCES` restores
the first version's differences.

Accuracy: Cramer-Rao bounds from the innovations' information matrix
``M = sum_k S[k]^T Sigma^-1 S[k]`` (``S = de/d(theta, U, D, R, b, x0)``, the analytic
sensitivities at the optimum), accumulated record by record as the normal equations are;
the bounds of the structure parameters have ``F``, the biases and initial states
marginalised (Schur complement). They are honest when the innovations are white,
which the result reports as the normalised autocorrelation of each whitened innovation at
lags 1-10 (band ``2/sqrt(N)``).

References
----------
Maine, R. E., Iliff, K. W., "Formulation and Implementation of a Practical Algorithm for
Parameter Estimation with Process and Measurement Noise", SIAM J. Appl. Math. 41(3), 1981;
*Identification of Dynamic Systems: Applications to Aircraft*, AGARD-AG-300 Vol. 3, 1986.
Jategaonkar, R. V., *Flight Vehicle System Identification*, 2nd ed., AIAA, 2015, ch. 5.
Ljung, L., *System Identification: Theory for the User*, 2nd ed., Prentice Hall, 1999,
ch. 4.3 (innovations form), 7 (prediction-error methods), 9 (asymptotic covariance).
Golub, G. H., Pereyra, V., "The differentiation of pseudo-inverses and nonlinear least
squares problems whose variables separate", SIAM J. Numer. Anal. 10(2), 1973; Kaufman, L.,
"A variable projection method for solving separable nonlinear least squares problems",
BIT 15, 1975.
Van Loan, C. F., "Computing integrals involving the matrix exponential", IEEE Trans.
Automat. Contr. 23(3), 1978 (the Frechet derivative as a block of one exponential).
"""

from __future__ import annotations

import concurrent.futures
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
from sysid.core.util import (POOL_FAILURES, fit_settings, forkserver_context,
                             worker_processes)
from sysid.identify.statistics import (ColouredBounds, FitResultParameters, ParameterStatistics,
                                      add_corrected_bounds, coloured_residual_covariance,
                                      information_statistics, parameter_rows)
from sysid.identify.least_squares import (STALL_WINDOW, Settled, SolveStopped,
                                          predicted_decrease, stall_watch)
from sysid.identify.reduction import (GUIDELINES, FitOutcome, ReductionResult,
                                     StoppedAboveCeiling, conditional_start,
                                     refusal_certain, stepwise_reduction)
from sysid.identify.time_domain import (COST_SETTLED, MAX_COST_INCREASE, SOLVE_SETTLED,
                                        OutputErrorModel, _chol_solve, _delayed,
                                        _independent_gram, fit_inputs)
from sysid.models import LinearStructure, discretize, matrix_powers, propagate

__all__ = ["FilterErrorResult", "identify_filter_error", "process_noise_states",
           "WHITENESS_LAGS", "NOISE_STARTS", "SCREEN_PASSES", "MAX_SCREEN_PROCESSES"]

#: Lags (samples) at which the whiteness of the innovations is reported.
WHITENESS_LAGS = 10
#: Innovation sensitivities by finite differences (forward in the solver, central for the
#: bounds) instead of the analytic ones: the first implementation, kept for A/B comparison.
FINITE_DIFFERENCES = False
#: Each relaxation solve at fixed Sigma stops where its Gauss-Newton model predicts less than
#: SOLVE_SETTLED of further decrease of L, as the output-error fit's (False: on the solver's
#: own tolerances; docs/notes/2026-11-26-filter-error-settled-solves.md).
SETTLED_SOLVES = True
#: ... and where its last STALL_WINDOW accepted steps lowered L by less than SOLVE_SETTLED
#: each on average (:func:`sysid.identify.least_squares.stall_watch`): at 80 kt a solve
#: otherwise creeps for a hundred evaluations gaining about 0.15 in L
#: (docs/notes/2026-11-27-filter-error-stall.md).
STALL_SOLVES = True
#: Noise starts of the first fit (factors of the default Q and R start values), the lowest L
#: kept: on the truth FMU's hover campaigns the likelihood has local minima up to 120 apart
#: in L, and no single start finds the lowest on every seed
#: (docs/notes/2026-11-27-filter-error-noise-starts.md).
NOISE_STARTS = ((0.01, 10.0), (0.1, 100.0), (0.01, 1.0), (1.0, 10.0))
#: Relaxation passes after which the noise starts are compared (from the second pass on, a
#: start's L was within 0.4 of where it converged on the campaigns of the note above, bar
#: slow tails that ended at the lowest L anyway).
SCREEN_PASSES = 2
#: Processes that screen the noise starts side by side (``SYSID_FIT_PROCESSES`` overrides;
#: the usable cores up to this, 1 in a Dask worker): each start is a fit of its own, the
#: same bits in any process (docs/notes/2026-11-27-filter-error-parallel-screening.md).
#: The fits after the screening (the lowest start, the reduction's refits) spread their
#: records' sensitivities over as many threads, the same bits in any number.
MAX_SCREEN_PROCESSES = 4
#: The first relaxation pass of a fit from scratch solves at the start's innovation
#: covariance, which the next pass replaces: it stops where less than this (L units, 100
#: COST_SETTLED) of further decrease is predicted instead of SOLVE_SETTLED. On eight hover
#: campaigns the first fit took 36 % less CPU and ended at the same L to 0.04 on five, 0.4
#: and 1.5 higher on two, 5.9 lower on one (docs/notes/2026-11-27-filter-error-first-pass.md).
FIRST_PASS_SETTLED = 1.0
#: A reduction refit stops, refused, at an accepted iterate where its likelihood (the
#: innovation covariance re-estimated there) lies above the likelihood-ratio ceiling by more
#: than REFUSAL_MARGIN times the decrease the pass's Gauss-Newton model still predicts
#: (:func:`~sysid.identify.reduction.refusal_certain`) and by more than this (L units). On
#: 176 refits of 21 fits (hover_6dof, hover_hybrid and hover_hybrid_inflow on six hover
#: campaigns, forward_6dof on three at 80 kt) no accepted one fired it (largest gap over
#: prediction 1.37 where the gap exceeded this; 4.70 for a refit creeping 0.2-0.9 above
#: its ceiling, which this floor covers), and it saved 26-47 % of the refits' evaluations
#: (docs/notes/2026-11-28-filter-error-early-refusal.md).
REFUSAL_MIN_GAP = 1.0
#: Whitened residual returned for every sample of a trial model whose Riccati equation has
#: no stabilising solution (the solver then rejects the step).
_FAILED_RESIDUAL = 1e6


@dataclass
class FilterErrorResult(FitResultParameters):
    """Outcome of :func:`identify_filter_error`.

    Attributes
    ----------
    model : xr.Dataset
        Model Dataset (docs/data_model.md), ``method = "filter_error"``: the structure's
        parameters with Cramer-Rao bounds from the innovations (process noise, biases and
        initial states marginalised), plus ``gain``, ``process_noise``,
        ``measurement_noise``, ``innovation_covariance`` and ``innovation_autocorrelation``.
    structure : LinearStructure
    theta : ndarray
        Free structure parameters.
    statistics : ParameterStatistics
        Accuracy of ``theta`` (nuisance and process noise marginalised).
    joint_statistics : ParameterStatistics
        Joint statistics of ``theta``, the process noise ``U[<state>,<state>]`` and
        ``Q[<state>]`` (``Q = U D U^T``), the measurement-noise variances ``R[<output>]``
        (before the common scaling), biases ``bias_<output>[<record>]`` and initial states
        ``x0_<state>[<record>]``.
    gain : xr.DataArray
        Steady-state Kalman gain ``K`` (state, output) of the first record's sample interval.
    process_noise : xr.DataArray
        ``Q = F F^T`` (state, state_), per sample, analysis units squared.
    process_noise_distribution : xr.DataArray
        ``F = U D^1/2`` (state, state_), ``Q = F F^T``.
    measurement_noise : xr.DataArray
        ``R`` (output), diagonal: ``diag(Sigma - C P C^T)`` with the scaled process noise.
    innovation_covariance : xr.DataArray
        ``Sigma`` (output, output_).
    coloured : ColouredBounds or None
        Bounds of ``theta`` corrected for coloured innovations (Morelli & Klein, as for
        output error), also in ``model`` as ``cramer_rao_corrected``.
    whiteness : xr.DataArray
        Normalised autocorrelation of the whitened innovations (output, lag), lags
        1..:data:`WHITENESS_LAGS`, pooled over records; ``attrs["band"] = 2/sqrt(N)``.
    cost : float
        ``L`` at the optimum (``N/2 ln det Sigma + N p / 2``).
    records, outputs : tuple of str
    passes : int
        Relaxation passes (LM solve, ``Sigma`` update).
    n_cost_evaluations : int
    cpu_time : float
        CPU seconds of the fit (``time.process_time``), the reduction's refits and the noise
        starts screened in other processes included.
    reduction : ReductionResult or None
        The model reduction's steps (``reduce=True``).
    noise_and_nuisance : ndarray
        The solver's end values of the process-noise entries, measurement-noise stds and
        per-record biases and initial states (the warm start of a reduction refit).
    """

    model: xr.Dataset
    structure: LinearStructure
    theta: np.ndarray
    statistics: ParameterStatistics
    joint_statistics: ParameterStatistics
    gain: xr.DataArray
    process_noise: xr.DataArray
    process_noise_distribution: xr.DataArray
    measurement_noise: xr.DataArray
    innovation_covariance: xr.DataArray
    whiteness: xr.DataArray
    cost: float
    records: tuple
    outputs: tuple
    passes: int
    n_cost_evaluations: int
    cpu_time: float
    full_statistics: ParameterStatistics | None = None
    coloured: ColouredBounds | None = None
    reduction: ReductionResult | None = None
    noise_and_nuisance: np.ndarray | None = None
    #: CPU (s) of the noise starts screened in other processes (in ``cpu_time`` too)
    cpu_elsewhere: float = 0.0
    #: What the corrected bounds need when a fit left them for later (:func:`_add_coloured`):
    #: a callable giving the marginal sensitivities per record, the whitened innovations per
    #: record, and dt.
    coloured_pending: tuple | None = field(default=None, repr=False)

    @property
    def J(self) -> float:
        """The cost (negative log-likelihood), named like the other fit results."""
        return self.cost

    def table(self) -> str:
        """Derivative table with the innovations' Cramer-Rao bounds and the bounds corrected
        for their colour, the process and measurement noise, the innovations' whiteness."""
        m = self.model
        states = [str(s) for s in self.process_noise.state.values]
        q = np.sqrt(np.diag(self.process_noise.values))
        white = float(np.max(np.abs(self.whiteness.values)))
        band = float(self.whiteness.attrs["band"])
        lines = [f"Filter-error identification ({self.structure.name}) on "
                 f"{len(self.records)} record(s): {', '.join(self.records)}",
                 *parameter_rows(m, absolute_cr=True),
                 "process noise std per step (sqrt diag Q): " + ", ".join(
                     f"{s} {v:.3g}" for s, v in zip(states, q) if v > 0),
                 "measurement noise std: " + ", ".join(
                     f"{o} {math.sqrt(v):.4g}" for o, v in
                     zip(self.outputs, self.measurement_noise.values)),
                 f"innovations: largest |autocorrelation| at lags 1-{WHITENESS_LAGS} "
                 f"{white:.3f} (white within {band:.3f})" + ("" if white <= band else
                 ": not white, judge the parameters by CRc"),
                 f"cost (neg. log-likelihood) = {self.cost:.3f}, {self.passes} passes, "
                 f"{self.cpu_time:.1f} s CPU"]
        if self.reduction is not None and self.reduction.steps:
            lines += ["model reduction:", self.reduction.table()]
        return "\n".join(lines)


class _Predictor:
    """Innovations of every record for a full parameter vector
    ``beta = [theta, F entries, r_1..r_(p-1), per record (biases, initial state)]`` and
    their analytic sensitivities ``de/dbeta`` (:meth:`jacobian`)."""

    def __init__(self, structure, records, outputs, noise_mask, biases, initial_state):
        self.structure = structure
        self.records = records
        self.oe = OutputErrorModel(structure, records, outputs, biases=False,
                                   initial_state=False)  # for its input groups and ZOH
        self.out_idx = self.oe.out_idx
        # Q = U D U^T: D the variances of the masked diagonal, U = I + the masked
        # off-diagonal entries (the LDL form: every parameter's derivative of Q is finite,
        # a variance can sit at its bound 0)
        self.f_rows, self.f_cols = np.nonzero(noise_mask)
        self.u_rows, self.u_cols = np.nonzero(noise_mask & ~np.eye(len(noise_mask), dtype=bool))
        self.d_idx = np.flatnonzero(np.diag(noise_mask))
        self.biases, self.initial_state = biases, initial_state
        self.n_theta = len(structure.free_index)
        self.n, self.p = len(structure.states), len(outputs)
        self.n_f = len(self.u_rows) + len(self.d_idx)
        self.n_g = self.n_f + self.p - 1  # U entries, D entries and R_1 .. R_(p-1)
        self.n_rec = (self.p if biases else 0) + (self.n if initial_state else 0)
        self.n_alpha = self.n_theta + self.n_g  #: what the solver sees (nuisance projected)
        self.n_beta = self.n_alpha + len(records) * self.n_rec
        self.whitener = np.eye(self.p)
        self.r0 = 1.0  #: the measurement-noise std of the first output, held (scale of Q, R)
        self.n_eval = 0
        self.n_jac = 0
        self._disc = (None, None)  #: (theta, discrete model) of the last evaluation
        self._state = (None, None)  #: (beta, predictor states) of the last evaluation
        self._comp = (None, None)  #: (beta, compressed problem) of the last evaluation
        self.settle = None  #: (lower, upper) of beta: a solve stops at SOLVE_SETTLED
        self.settle_tol = SOLVE_SETTLED  #: ... of further predicted decrease of L
        self._dmat = self._matrix_derivatives()
        self.threads = 1  #: threads over the records in :meth:`_sensitivities`

    def names(self, outputs) -> list[str]:
        st = self.structure
        out = list(st.free_names)
        out += [f"U[{st.states[i]},{st.states[j]}]" for i, j in zip(self.u_rows, self.u_cols)]
        out += [f"Q[{st.states[i]}]" for i in self.d_idx]
        out += [f"R[{o}]" for o in outputs[1:]]
        for rec in self.records:
            if self.biases:
                out += [f"bias_{o}[{rec.name}]" for o in outputs]
            if self.initial_state:
                out += [f"x0_{s}[{rec.name}]" for s in st.states]
        return out

    def split(self, beta):
        """``(theta, F, R, b, x0)`` of a full ``beta``; of ``alpha = beta[:n_alpha]`` (no
        nuisance values) ``b`` and ``x0`` are ``None``."""
        t = self.n_theta
        theta = beta[:t]
        U, d = self.noise(beta)
        F = U * np.sqrt(np.maximum(d, 0.0))  # Q = F F^T = U D U^T
        R = np.concatenate([[self.r0 ** 2], beta[t + self.n_f:t + self.n_g]])
        if len(beta) == self.n_alpha:
            return theta, F, R, None, None
        rest = beta[t + self.n_g:].reshape(len(self.records), self.n_rec)
        nb = self.p if self.biases else 0
        b = rest[:, :nb] if self.biases else np.zeros((len(self.records), self.p))
        x0 = rest[:, nb:] if self.initial_state else np.zeros((len(self.records), self.n))
        return theta, F, R, b, x0

    def noise(self, beta) -> tuple[np.ndarray, np.ndarray]:
        """``(U, d)`` of ``Q = U diag(d) U^T`` from ``beta``."""
        t, nu = self.n_theta, len(self.u_rows)
        U = np.eye(self.n)
        U[self.u_rows, self.u_cols] = beta[t:t + nu]
        d = np.zeros(self.n)
        d[self.d_idx] = beta[t + nu:t + self.n_f]
        return U, d

    def _matrix_derivatives(self):
        """``(dA, dB, dC, dD)`` of the fitted model per free structure parameter (``None``
        for a delay): constant, the matrices being affine in the other parameters
        (``C + M (A - K)``, ``D + M B`` with output equations)."""
        st = self.structure
        n, m, q = len(st.states), len(st.inputs), len(st.outputs)
        out = []
        for k in st.free_index:
            par = st.parameters[int(k)]
            if par.matrix == "delay":
                out.append(None)
                continue
            d = {"A": np.zeros((n, n)), "B": np.zeros((n, m)), "C": np.zeros((q, n)),
                 "D": np.zeros((q, m))}
            for i, c, scale in st.entries_of(int(k)):
                d[par.matrix][i, c] += scale
            dC, dD = d["C"] + st.M @ d["A"], d["D"] + st.M @ d["B"]
            out.append((d["A"], d["B"], dC[self.out_idx], dD[self.out_idx]))
        return out

    def discrete(self, theta):
        """``(groups, C, D, {dt: (Phi, Gamma)})`` at ``theta`` (the last one cached: the
        difference steps in the other parameters keep theta)."""
        if self._disc[0] is not None and np.array_equal(self._disc[0], theta):
            return self._disc[1]
        A, B, C, D, tau = self.structure.matrices(theta)
        groups = self.oe.groups(tau)
        Bg = np.stack([B[:, g.column] * g.rows for g in groups], axis=1)
        disc = {}
        for rec in self.records:
            if rec.dt not in disc:
                d = self.oe._discretise(A, Bg, rec.dt, False)
                disc[rec.dt] = (d["Phi"], d["Gam"])
        out = (groups, C[self.out_idx], D[self.out_idx], disc)
        self._disc = (np.array(theta, float), out)
        return out

    def kalman(self, Phi, C, F, R):
        """``(K, P)`` of the steady-state predictor; raises ``LinAlgError``/``ValueError``
        when the Riccati equation has no stabilising solution."""
        Q = F @ F.T + 1e-12 * np.eye(self.n)
        if not (np.all(np.isfinite(Phi)) and np.all(np.isfinite(Q))
                and np.all(np.isfinite(R))):  # a trial step past overflow
            raise np.linalg.LinAlgError("non-finite model or noise")
        P = scipy.linalg.solve_discrete_are(Phi.T, C.T, Q, np.diag(R))
        K = Phi @ P @ C.T @ np.linalg.inv(C @ P @ C.T + np.diag(R))
        if not np.max(np.abs(np.linalg.eigvals(Phi - K @ C))) < 1.0:  # NaN too
            raise np.linalg.LinAlgError("unstable predictor")
        return K, P

    def set_whitener(self, whitener: np.ndarray) -> None:
        """``Sigma^-1/2`` of the residuals (the metric of the nuisance's least squares, so
        the cached evaluations are dropped)."""
        self.whitener = np.asarray(whitener, float)
        self._state = (None, None)
        self._comp = (None, None)

    def _run(self, beta) -> dict:
        """The predictor at ``beta``: per record inputs ``V``, their delay derivatives
        ``dV`` (N, G), states ``X`` (N, n) and innovations ``E`` (N, p); ``(K, P)`` per dt;
        ``nuisance`` (records, n_rec). A full ``beta`` gives the nuisance values; ``alpha``
        (``n_alpha`` entries) has them solved for (module docstring, variable projection).
        Raises ``LinAlgError``/``ValueError`` when the Riccati equation fails. The last one
        is cached (the solver asks for the Jacobian where it evaluated the residuals)."""
        beta = np.asarray(beta, float)
        if self._state[0] is not None and np.array_equal(self._state[0], beta):
            return self._state[1]
        self.n_eval += 1
        theta, F, R, b, x0 = self.split(beta)
        groups, C, D, disc = self.discrete(theta)
        gains = {dt: self.kalman(Phi, C, F, R) for dt, (Phi, _) in disc.items()}
        own = {}
        for dt, (Phi, _) in disc.items():
            longest = max(len(rec.time) for rec in self.records if rec.dt == dt)
            own[dt] = self._own_sensitivities(Phi - gains[dt][0] @ C, gains[dt][0], C,
                                              longest)
        run = {"gains": gains, "own": own, "V": [], "dV": [], "X": [], "E": [],
               "nuisance": np.zeros((len(self.records), self.n_rec))}
        for r, rec in enumerate(self.records):
            Phi, Gam = disc[rec.dt]
            K = gains[rec.dt][0]
            VV = [_delayed(rec.U[:, g.column], g.delay / rec.dt) for g in groups]
            V = np.stack([v for v, _ in VV], axis=1)
            N = len(V)
            # x^[k+1] = (Phi - K C) x^[k] + Gamma v[k] + K (z[k] - D u[k]), x^[0] = 0 ...
            ZD = rec.Z - rec.U @ D.T
            X = propagate(Phi - K @ C, V @ Gam.T + ZD @ K.T)
            E = ZD - X @ C.T
            # ... plus the bias and initial state, which enter linearly
            Pw, Sw, _ = (a[:N] for a in own[rec.dt])
            if b is None:
                c = self._nuisance(run, r, E)
            else:
                c = np.concatenate([b[r] if self.biases else [], x0[r] if self.initial_state
                                    else []])
            if self.n_rec:  # x^ += Acl^k x0 - sum_(i<k) Acl^i K b, e = z - D u - C x^ - b
                nb = self.p if self.biases else 0
                if self.biases:
                    X = X - (Sw.reshape(-1, self.n) @ (K @ c[:nb])).reshape(N, self.n)
                    ZD = ZD - c[:nb]
                if self.initial_state:
                    X = X + (Pw.reshape(-1, self.n) @ c[nb:]).reshape(N, self.n)
                E = ZD - X @ C.T
            run["nuisance"][r] = c
            run["V"].append(V)
            run["dV"].append(np.stack([d for _, d in VV], axis=1))
            run["X"].append(X)
            run["E"].append(E)
        self._state = (beta.copy(), run)
        return run

    def _own_sensitivities(self, Acl, K, C, N) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """``(P, S, De)`` of a record's bias and initial state ``c`` over ``N`` samples:
        ``P[k] = Acl^k`` and ``S[k] = sum_(i<k) Acl^i`` (N, n, n), so that ``dx^[k]/dx0 =
        P[k]`` and ``dx^[k]/db = -S[k] K`` (the initial state decays, a bias enters as
        ``-K b``), and the whitened ``Sigma^-1/2 de/dc`` (N, p, n_rec), ``de/dc = -C dx^/dc``
        less ``b``. From the powers (:func:`~sysid.models.matrix_powers`), those of ``C``
        whitened first; the same for every record of one sample interval."""
        n, p, W = self.n, self.p, self.whitener
        P = matrix_powers(Acl, N)
        S = np.zeros((N, n, n))
        np.cumsum(P[:-1], axis=0, out=S[1:])
        De = np.empty((N, p, self.n_rec))
        CP = matrix_powers(Acl, N, start=W @ C)  # Sigma^-1/2 C Acl^k
        if self.biases:
            CS = np.zeros((N, p, n))
            np.cumsum(CP[:-1], axis=0, out=CS[1:])
            De[:, :, :p] = (CS.reshape(N * p, n) @ K).reshape(N, p, p) - W
        if self.initial_state:
            De[:, :, p if self.biases else 0:] = -CP
        return P, S, De

    def _own_factor(self, run, r):
        """``(B_c, keep, L)`` of record ``r``: its whitened bias and initial-state
        sensitivities (N p, n_rec), the columns independent of earlier ones and the Cholesky
        factor of their Gram matrix (cached in ``run``: the solve and the normal equations
        share it; the whitened sensitivities are computed once per sample interval, a
        record's the first N samples)."""
        cache = run.setdefault("own_factor", {})
        if r not in cache:
            rec = self.records[r]
            Bc = run["own"][rec.dt][2][:len(rec.time)].reshape(-1, self.n_rec)
            cache[r] = (Bc, *_independent_gram(Bc.T @ Bc))
        return cache[r]

    def _nuisance(self, run, r, E) -> np.ndarray:
        """Bias and initial state of record ``r`` minimising its whitened innovations
        ``|Sigma^-1/2 (E + De c)|`` (weighted linear least squares; a column dependent on
        earlier ones, e.g. the initial heading beside the heading bias, is held at 0)."""
        c = np.zeros(self.n_rec)
        if not self.n_rec:
            return c
        Bc, keep, L = self._own_factor(run, r)
        c[keep] = -_chol_solve(L, (Bc.T @ (E @ self.whitener.T).ravel())[keep])
        return c

    def innovations(self, beta) -> list[np.ndarray]:
        """``e = z - y^`` per record (N, p); raises ``LinAlgError``/``ValueError`` when the
        Riccati equation fails."""
        return self._run(beta)["E"]

    def residuals(self, beta) -> np.ndarray:
        """Whitened innovations ``Sigma^-1/2 e`` (N p), at the nuisance of a full ``beta``,
        projected (nuisance solved for) for ``alpha``."""
        try:
            E = self.innovations(beta)
        except (np.linalg.LinAlgError, ValueError):
            size = sum(len(rec.time) for rec in self.records) * self.p
            return np.full(size, _FAILED_RESIDUAL)
        return np.concatenate([e @ self.whitener.T for e in E]).ravel()

    def compressed_residuals(self, alpha) -> np.ndarray:
        """``f`` (n_alpha + 1) of the projected problem compressed by the thin
        factorisation of its Jacobian (:func:`_compress`): ``|f| = |Sigma^-1/2 e|``,
        same gradient and Gauss-Newton models, so the solver's steps are the full problem's
        without factorising the (N p x n_alpha) Jacobian at every iteration."""
        return self._compressed(alpha)[0]

    def compressed_jacobian(self, alpha, *_) -> np.ndarray:
        """``[R_J; 0]`` (n_alpha + 1, n_alpha) of :meth:`compressed_residuals`. The solver
        asks for it at each accepted iterate; with ``self.settle = (lower, upper)`` it raises
        ``Settled`` there when the Gauss-Newton model predicts less than
        ``settle_tol`` (:data:`~sysid.identify.time_domain.SOLVE_SETTLED`, in a first pass
        :data:`FIRST_PASS_SETTLED`) of further decrease of ``L`` (at
        fixed ``Sigma`` half the squared whitened innovations)."""
        f, Jf = self._compressed(alpha)
        if self.settle is not None and np.all(np.isfinite(f)):
            RJ, q = Jf[:-1], f[:-1]
            if predicted_decrease(self.settle, np.asarray(alpha, float), RJ.T @ q, RJ.T @ RJ,
                                  0.5 * float(q @ q)) < self.settle_tol:
                raise Settled(alpha)
        return Jf

    def _compressed(self, alpha):
        alpha = np.asarray(alpha, float)
        if self._comp[0] is not None and np.array_equal(self._comp[0], alpha):
            return self._comp[1]
        try:
            self._run(alpha)
        except (np.linalg.LinAlgError, ValueError):
            size = sum(len(rec.time) for rec in self.records) * self.p
            f = np.zeros(self.n_alpha + 1)
            f[-1] = _FAILED_RESIDUAL * math.sqrt(size)  # the cost of the failed residuals
            out = (f, np.zeros((self.n_alpha + 1, self.n_alpha)))
        else:
            out = _compress(*self.normal_equations(alpha))
        self._comp = (alpha.copy(), out)
        return out

    # -- analytic sensitivities ----------------------------------------------------------------

    def _discrete_derivatives(self, theta, dt, groups):
        """``dPhi`` (P, n, n) and ``dGamma`` (P, n, G) per non-delay free structure parameter
        (zeros for a delay) at sample interval ``dt``: Frechet derivative of the exponential
        of ``M = [[A, Bg], [0, 0]] dt`` for the A parameters, the upper right block of the
        exponential of ``[[M, dM], [0, M]]`` (Van Loan 1978; one batched exponential for all
        of them), ``Psi dBg`` (``Psi = int_0^dt e^As ds``) for the others."""
        A, B, _, _, _ = self.structure.matrices(theta)
        Bg = np.stack([B[:, g.column] * g.rows for g in groups], axis=1)
        n, G = Bg.shape
        m = n + G
        Psi = discretize(A, np.eye(n), dt)[1]  # int_0^dt e^(As) ds
        dPhi = np.zeros((self.n_theta, n, n))
        dGam = np.zeros((self.n_theta, n, G))
        in_a = []
        for j, dm in enumerate(self._dmat):
            if dm is None:
                continue
            dBg = np.stack([dm[1][:, g.column] * g.rows for g in groups], axis=1)
            if np.any(dm[0]):
                in_a.append((j, dm[0], dBg))
            else:
                dGam[j] = Psi @ dBg
        if in_a:
            Z = np.zeros((len(in_a), 2 * m, 2 * m))
            Z[:, :n, :n] = Z[:, m:m + n, m:m + n] = A * dt
            Z[:, :n, n:m] = Z[:, m:m + n, m + n:] = Bg * dt
            for i, (_, dA, dBg) in enumerate(in_a):
                Z[i, :n, m:m + n], Z[i, :n, m + n:] = dA * dt, dBg * dt
            dE = scipy.linalg.expm(Z)[:, :n, m:]
            idx = [j for j, _, _ in in_a]
            dPhi[idx], dGam[idx] = dE[:, :, :n], dE[:, :, n:]
        return dPhi, dGam

    def _gain_derivatives(self, Phi, C, K, P, noise, R, dPhi, dC):
        """``dK`` (n_theta + n_g, n, p) for the structure parameters, the noise entries
        (``noise = (U, d)``) and ``R_1..R_(p-1)``: the Riccati solution's derivative from the discrete Lyapunov equation
        ``dP - Acl dP Acl^T = T + T^T + dQ + K dR K^T``, ``T = (dPhi - K dC) P Acl^T``,
        ``Acl = Phi - K C`` (the gain's own variation drops out: K is optimal), then
        ``dK = (dPhi P C^T + Phi dP C^T + Phi P dC^T - K dS) S^-1``,
        ``S = C P C^T + R``, ``dS = dC P C^T + C dP C^T + C P dC^T + dR``."""
        n, p, nt = self.n, self.p, self.n_theta
        Acl = Phi - K @ C
        S = C @ P @ C.T + np.diag(R)
        m = nt + self.n_g
        dPhi_all = np.zeros((m, n, n))
        dC_all = np.zeros((m, p, n))
        dQ = np.zeros((m, n, n))
        dR = np.zeros((m, p, p))
        dPhi_all[:nt], dC_all[:nt] = dPhi, dC
        U, d = noise
        for a, (i, j) in enumerate(zip(self.u_rows, self.u_cols)):  # Q = U D U^T
            half = np.zeros((n, n))
            half[i] = d[j] * U[:, j]
            dQ[nt + a] = half + half.T
        for a, j in enumerate(self.d_idx):
            dQ[nt + len(self.u_rows) + a] = np.outer(U[:, j], U[:, j])
        for a in range(1, p):
            dR[nt + self.n_f + a - 1, a, a] = 1.0
        active = np.flatnonzero([np.any(a) or np.any(b) or np.any(c) or np.any(d)
                                 for a, b, c, d in zip(dPhi_all, dC_all, dQ, dR)])
        dK = np.zeros((m, n, p))
        if not len(active):
            return dK
        T = (dPhi_all[active] - K @ dC_all[active]) @ P @ Acl.T
        rhs = T + T.transpose(0, 2, 1) + dQ[active] + K @ dR[active] @ K.T
        # (I - Acl (x) Acl) vec(dP) = vec(rhs), row-major vec: one LU for every right side
        lyap = np.eye(n * n) - np.kron(Acl, Acl)
        dP = np.linalg.solve(lyap, rhs.reshape(len(active), n * n).T).T.reshape(-1, n, n)
        dP = 0.5 * (dP + dP.transpose(0, 2, 1))
        dCa = dC_all[active]
        dS = dCa @ P @ C.T + C @ dP @ C.T + C @ P @ dCa.transpose(0, 2, 1) + dR[active]
        num = (dPhi_all[active] @ P @ C.T + Phi @ dP @ C.T + Phi @ P @ dCa.transpose(0, 2, 1)
               - K @ dS)
        dK[active] = num @ np.linalg.inv(S)
        return dK

    def _sensitivities(self, beta, each=None):
        """Per record ``(r, B)``, ``B`` (N, p, n_alpha) the whitened innovation sensitivities
        ``Sigma^-1/2 de/dalpha`` to the structure and noise parameters (a record's own bias
        and initial-state columns are :meth:`_own_factor`'s): the sensitivities
        ``dx^`` follow the predictor's recursion with ``K`` held,
        ``dx^[k+1] = (Phi - K C) dx^[k] + dPhi x^ + dGamma v + Gamma dv + dK e
        - K (dC x^ + dD u + db)``, ``dx^[0] = dx0``, and ``de = -(C dx^ + dC x^ + dD u + db)``.
        With ``each``, ``(r, each(r, B))`` instead. The records run in :attr:`threads`
        threads, in order (their products and the compiled recursion release the
        interpreter). Raises ``LinAlgError``/``ValueError`` where the Riccati equation
        fails."""
        run = self._run(np.asarray(beta, float))
        self.n_jac += 1
        theta, F, R, _, _ = self.split(beta)
        groups, C, D, disc = self.discrete(theta)
        n, p, nt, ng = self.n, self.p, self.n_theta, self.n_g
        dC = np.zeros((nt, p, n))
        dD = np.zeros((nt, p, len(self.structure.inputs)))
        for j, d in enumerate(self._dmat):
            if d is not None:
                dC[j], dD[j] = d[2], d[3]
        per_dt = {}
        for dt, (Phi, Gam) in disc.items():
            K, P = run["gains"][dt]
            dPhi, dGam = self._discrete_derivatives(theta, dt, groups)
            dK = self._gain_derivatives(Phi, C, K, P, self.noise(beta), R, dPhi, dC)
            per_dt[dt] = (Phi, Gam, K, dPhi, dGam, dK)
        out_cols = np.flatnonzero(np.any(dC != 0, axis=(1, 2)) | np.any(dD != 0, axis=(1, 2)))
        delays = [(j, next(g for g, gr in enumerate(groups) if gr.free_delay == j))
                  for j, d in enumerate(self._dmat) if d is None]
        WC = self.whitener @ C
        shared = nt + ng

        def one(r):
            rec = self.records[r]
            Phi, Gam, K, dPhi, dGam, dK = per_dt[rec.dt]
            X, E, V, dV = run["X"][r], run["E"][r], run["V"][r], run["dV"][r]
            N = len(X)
            # dPhi x^ + dGamma v (structure parameters) and dK e (structure parameters
            # through Phi and C, F entries, r): one product, laid out (N, n, shared)
            M = np.zeros((n + V.shape[1] + p, n, shared))
            if nt:
                M[:n + V.shape[1], :, :nt] = np.concatenate([dPhi, dGam], axis=2).transpose(
                    2, 1, 0)
            M[n + V.shape[1]:] = dK.transpose(2, 1, 0)
            W = (np.hstack([X, V, E]) @ M.reshape(len(M), -1)).reshape(N, n, shared)
            O = None
            if len(out_cols):  # dC x^ + dD u, fed back through K
                dCD = np.concatenate([dC[out_cols], dD[out_cols]], axis=2)
                O = (np.hstack([X, rec.U]) @ dCD.reshape(len(out_cols) * p, -1).T).reshape(
                    N, len(out_cols), p).transpose(0, 2, 1)
                W[:, :, out_cols] -= np.matmul(K, O)
            for j, g in delays:
                W[:, :, j] = np.outer(dV[:, g] / rec.dt, Gam[:, g])
            B = np.matmul(-WC, propagate(Phi - K @ C, W))  # de = -(C dx^ + ...), whitened
            if O is not None:  # the direct terms dC x^ + dD u
                B[:, :, out_cols] -= np.matmul(self.whitener, O)
            return r, (B if each is None else each(r, B))

        records = range(len(self.records))
        if self.threads > 1 and len(records) > 1:
            with concurrent.futures.ThreadPoolExecutor(self.threads) as pool:
                yield from pool.map(one, records)
        else:
            for r in records:
                yield one(r)

    def jacobian(self, beta) -> np.ndarray:
        """``d(Sigma^-1/2 e)/dbeta`` (N p, n_beta), rows as :meth:`residuals`, from
        :meth:`_sensitivities`: the tall form of :meth:`information`'s blocks (the fit
        itself uses the blocks; the tests check both). Zeros where the Riccati equation
        fails."""
        size = sum(len(rec.time) for rec in self.records) * self.p
        J = np.zeros((size, self.n_beta))
        try:
            blocks = list(self._sensitivities(beta))
        except (np.linalg.LinAlgError, ValueError):
            return J
        run = self._run(np.asarray(beta, float))
        shared, nr, rows = self.n_alpha, self.n_rec, 0
        for r, B in blocks:
            block = B.reshape(-1, shared)
            J[rows:rows + len(block), :shared] = block
            if nr:
                c0 = shared + r * nr
                J[rows:rows + len(block), c0:c0 + nr] = self._own_factor(run, r)[0]
            rows += len(block)
        return J

    def information(self, beta) -> np.ndarray:
        """``M = J^T J`` (n_beta, n_beta) of :meth:`jacobian` at a full ``beta``, from each
        record's blocks (its sensitivities to ``alpha`` and its own bias and initial-state
        columns; the other records' are 0 in its rows) without forming ``J``. Zeros where
        the Riccati equation fails."""
        na, nr = self.n_alpha, self.n_rec
        M = np.zeros((self.n_beta, self.n_beta))
        beta = np.asarray(beta, float)
        try:
            run = self._run(beta)

            def share(r, B):  # in the record's thread
                Ba = B.reshape(-1, na)
                Bc = self._own_factor(run, r)[0] if nr else np.zeros((len(Ba), 0))
                return Ba.T @ Ba, Bc.T @ Ba, Bc.T @ Bc

            shares = list(self._sensitivities(beta, each=share))
        except (np.linalg.LinAlgError, ValueError):
            return M
        for r, (Gaa, Gca, Gcc) in shares:  # in record order
            M[:na, :na] += Gaa
            c = slice(na + r * nr, na + (r + 1) * nr)
            M[c, :na] = Gca
            M[:na, c] = Gca.T
            M[c, c] = Gcc
        return M

    def marginal_rows(self, beta, A: np.ndarray) -> list[np.ndarray]:
        """Per record the marginal sensitivities ``G_t - G_n A`` (N, p, n_theta) of the
        structure parameters at a full ``beta``, ``A`` (n_beta - n_theta, n_theta) from
        :func:`_marginal`: :meth:`jacobian`'s rows less their fit by the noise and nuisance
        columns, record by record."""
        beta = np.asarray(beta, float)
        run = self._run(beta)
        nt, na, nr = self.n_theta, self.n_alpha, self.n_rec
        An, Ac = A[:na - nt], A[na - nt:].reshape(len(self.records), nr, nt)

        def rows(r, B):
            Ba = B.reshape(-1, na)
            G = Ba[:, :nt] - Ba[:, nt:] @ An
            if nr:
                G -= self._own_factor(run, r)[0] @ Ac[r]
            return G.reshape(len(B), self.p, nt)

        return [G for _, G in self._sensitivities(beta, each=rows)]

    def normal_equations(self, alpha) -> tuple[np.ndarray, np.ndarray, float]:
        """``(J^T J, J^T r, r^T r)`` of the projected problem (nuisance solved for, module
        docstring): ``r`` the whitened innovations, ``J`` Kaufman's Jacobian, the
        sensitivities to ``alpha`` projected off the nuisance columns, record by record
        without forming it: ``J^T J`` is the Schur complement
        ``G_aa - G_ac G_cc^-1 G_ca`` of each record's joint Gram matrix, and
        ``J^T r = S_a^T r`` (the nuisance's normal equations ``S_c^T r = 0``)."""
        run = self._run(np.asarray(alpha, float))
        E = run["E"]
        na = self.n_alpha

        def gram(r, B):  # a record's share, in its thread
            Ba = B.reshape(-1, na)
            v = (E[r] @ self.whitener.T).ravel()
            Gr = Ba.T @ Ba
            if self.n_rec:
                Bc, keep, L = self._own_factor(run, r)
                T = scipy.linalg.solve_triangular(L, (Bc.T @ Ba)[keep], lower=True,
                                                  check_finite=False)
                Gr -= T.T @ T
            return Gr, Ba.T @ v, float(v @ v)

        G = np.zeros((na, na))
        g = np.zeros(na)
        rr = 0.0
        for _, (Gr, gr, vv) in self._sensitivities(alpha, each=gram):  # in record order
            G += Gr
            g += gr
            rr += vv
        return G, g, rr


def process_noise_states(process_noise, structure: LinearStructure):
    """``process_noise`` with ``"auto"`` resolved: the states the structure declares
    (TOML ``process_noise``, where its disturbances enter), else ``"measured"``."""
    if isinstance(process_noise, str) and process_noise == "auto":
        declared = structure.attrs.get("process_noise", "")
        return declared.split(",") if declared else "measured"
    return process_noise


def _noise_mask(process_noise, states: Sequence[str],
                outputs: Sequence[str] = ()) -> np.ndarray:
    n = len(states)
    if isinstance(process_noise, str):
        if process_noise == "full":
            return np.tril(np.ones((n, n), bool))
        if process_noise == "diagonal":
            return np.eye(n, dtype=bool)
        if process_noise == "measured":
            return np.diag([s in set(outputs) for s in states])
        raise InputDataError(f"process_noise must be 'full', 'diagonal', 'measured', 'auto', "
                             f"state names or a boolean (state, state) mask of Q, not "
                             f"{process_noise!r}")
    if len(process_noise) and all(isinstance(x, str) for x in process_noise):
        unknown = sorted(set(process_noise) - set(states))
        if unknown:
            raise InputDataError(f"process_noise: unknown state(s) {unknown}; the "
                                 f"structure's states are {list(states)}")
        return np.diag([s in set(process_noise) for s in states])
    mask = np.asarray(process_noise, bool)
    if mask.shape != (n, n):
        raise InputDataError(f"process_noise mask has shape {mask.shape}; expected "
                             f"(states, states) = {(n, n)}")
    return mask


def _whiteness(E: list[np.ndarray], whitener: np.ndarray, lags: int) -> np.ndarray:
    """Normalised autocorrelation (p, lags) of the whitened innovations, biased estimate,
    pooled over records (no product spans two records)."""
    p = E[0].shape[1]
    num = np.zeros((p, lags))
    den = np.zeros(p)
    for e in E:
        w = e @ whitener.T
        w = w - w.mean(axis=0)
        den += np.einsum("kj,kj->j", w, w)
        for lag in range(1, lags + 1):
            if lag < len(w):
                num[:, lag - 1] += np.einsum("kj,kj->j", w[lag:], w[:-lag])
    return num / den[:, None]


@fit_settings
def identify_filter_error(records, structure: LinearStructure, *,
                          start: xr.Dataset | np.ndarray | None = None,
                          outputs: Sequence[str] | None = None, process_noise="full",
                          biases: bool = True, initial_state: bool = True,
                          tol: float = 1e-8, max_passes: int = 30,
                          cost_tol: float = COST_SETTLED,
                          max_nfev: int | None = None, reduce: bool = False,
                          cr_max: float = GUIDELINES["cr_max"],
                          insensitivity_max: float = GUIDELINES["insensitivity_max"],
                          max_cost_increase: float = MAX_COST_INCREASE,
                          protected: Sequence[str] = (),
                          noise_starts: Sequence[tuple[float, float]] = NOISE_STARTS,
                          progress=None) -> FilterErrorResult:
    """Identify a structure from time histories flown in turbulence by the filter-error
    method (maximum likelihood with process and measurement noise; module docstring).

    Minimises ``L = 1/2 sum_k e[k]^T Sigma^-1 e[k] + N/2 ln det Sigma`` over the structure's
    free parameters ``theta``, the process and measurement noise and the nuisance
    parameters, ``e`` the innovations of the steady-state Kalman predictor
    ``x^[k+1] = Phi x^[k] + Gamma v[k] + K e[k]``, ``K`` from the discrete Riccati equation.

    Parameters
    ----------
    records : xr.Dataset or sequence of xr.Dataset
        Time histories as for :func:`~sysid.identify.time_domain.identify_time_domain`.
    structure : LinearStructure
    start : xr.Dataset or array, optional
        Start values of ``theta`` (model Dataset or free-parameter vector); default the
        structure's.
    outputs : sequence of str, optional
        Fitted outputs (default: every structure output present in all records).
    process_noise : {"full", "diagonal", "measured", "auto"}, state names or bool array
        Estimated entries of ``Q = U D U^T`` (``D`` on the diagonal, ``U`` off it): lower
        triangle (any ``Q``), diagonal (independent noise per state equation), diagonal on
        the states that are fitted outputs, the structure's declared states
        (:func:`process_noise_states`), diagonal on the named states only, or a mask.
    biases, initial_state : bool
        Estimate a bias per output and an initial predictor state per record.
    tol : float
        ``ftol = xtol = gtol`` of each trust-region solve.
    max_passes, cost_tol
        Relaxation: at most ``max_passes`` (solve, ``Sigma`` update) cycles; stop when a
        pass changes ``L`` by less than ``cost_tol`` (absolute; default the output-error
        fit's ``COST_SETTLED``, 0.01).
    max_nfev : int, optional
        Cost evaluations per solve (default scipy's).
    reduce, cr_max, insensitivity_max, max_cost_increase, protected
        Stepwise model reduction as the output-error fit's (the same guidelines and
        likelihood-ratio threshold), judged on the innovations' bounds; each refit starts
        at the conditional minimum of the last fit's quadratic model with the last fit's
        process noise, measurement noise, biases and initial states (one likelihood
        basin: from scratch a refit can land in another, tens of units of ``L`` away) and
        stops, refused, once it can no longer come under the likelihood-ratio ceiling
        (:data:`REFUSAL_MIN_GAP`).
    noise_starts : sequence of (q, r)
        Noise start values of the first fit, as factors of the default ones (``Q`` and ``R``);
        each is relaxed for :data:`SCREEN_PASSES` passes and the one with the lowest ``L``
        converged (the likelihood has local minima that differ in how the noise is split
        between process and measurement; :data:`NOISE_STARTS`), side by side in up to
        :data:`MAX_SCREEN_PROCESSES` processes (``SYSID_FIT_PROCESSES``).
    progress : Progress, optional
        A line per start and per reduction step.

    Returns
    -------
    FilterErrorResult

    Raises
    ------
    InputDataError
        Records not usable (see :func:`~sysid.identify.time_domain.prepare_records`), a bad
        ``process_noise``/``start``, or fewer than ten residuals per estimated parameter.
    IdentificationError
        No free parameters; no stabilising Kalman predictor at the start or the optimum
        (``(Phi, C)`` not detectable); a singular innovation covariance.

    References
    ----------
    Maine & Iliff 1981, 1986; Jategaonkar 2015, ch. 5; Ljung 1999, ch. 7.

    Examples
    --------
    >>> result = identify_filter_error(records, structure, start=linearisation)
    >>> result.model["value"].sel(parameter="N_r"), result.statistics.cramer_rao
    >>> float(abs(result.whiteness).max()) <= 2 * result.whiteness.attrs["band"]
    """
    kw = dict(outputs=outputs, process_noise=process_noise, biases=biases,
              initial_state=initial_state, tol=tol, max_passes=max_passes, cost_tol=cost_tol,
              max_nfev=max_nfev)
    cpu0 = time.process_time()
    full = _best_start(records, structure, start=start, noise_starts=noise_starts,
                       progress=progress, **kw)
    if not reduce:
        _add_coloured(full)
        full.cpu_time = time.process_time() - cpu0 + full.cpu_elsewhere
        full.model.attrs["cpu_time_s"] = full.cpu_time
        return full

    def refit(removed, previous, ceiling):
        prev: FilterErrorResult = previous.payload
        st = structure.fix(removed, 0.0)
        theta0 = conditional_start(prev.statistics, removed[-1], st.free_names)
        # statistics only for a refit the reduction keeps, corrected bounds only for
        # the one it ends with (the same decisions and result, a tenth less CPU)
        r = _fit(records, st, start=theta0, warm=prev.noise_and_nuisance,
                 ceiling=ceiling, corrected=False, **kw)
        return FitOutcome(r.cost, getattr(r, "statistics", None), r,
                          converged=getattr(r, "converged", True))

    reduction = stepwise_reduction(
        refit, FitOutcome(full.cost, full.statistics, full), cr_max=cr_max,
        insensitivity_max=insensitivity_max, max_cost_increase=max_cost_increase,
        protected=(*protected, *structure.kept_names), progress=progress)
    _add_coloured(reduction.final.payload)
    final: FilterErrorResult = reduction.final.payload
    final.reduction = reduction
    final.full_statistics = full.statistics
    final.cpu_time = time.process_time() - cpu0 + full.cpu_elsewhere
    final.model.attrs.update({
        "reduction": 1, "cpu_time_s": final.cpu_time,
        "reduction_steps": json.dumps([step.as_dict() for step in reduction.steps]),
        "removed_parameters": ",".join(reduction.removed)})
    if "noise_starts" in full.model.attrs:
        final.model.attrs["noise_starts"] = full.model.attrs["noise_starts"]
    return final


def _best_start(records, structure, *, start, noise_starts, progress, **kw):
    """The first fit: each noise start relaxed for :data:`SCREEN_PASSES` passes, the one
    with the lowest ``L`` then converged (its model records every start's screened ``L`` in
    ``noise_starts``; its corrected bounds are left to :func:`_add_coloured`, which a
    reduction needs only for the model it ends with)."""
    if not len(noise_starts):
        raise InputDataError("identify_filter_error: noise_starts is empty; give at least "
                             "one (q, r) pair, e.g. (1, 1)")
    if len(noise_starts) == 1:
        best = _fit(records, structure, start=start, noise_start=tuple(noise_starts[0]),
                    corrected=False, **kw)
        best.model.attrs["noise_starts"] = json.dumps([[*map(float, noise_starts[0]),
                                                        float(best.cost)]])
        return best
    screen = {**kw, "max_passes": min(SCREEN_PASSES, kw["max_passes"]), "screen": True}
    fits, errors = [], []
    screened, elsewhere = _screened(records, structure, start, noise_starts, screen,
                                    progress)
    for (q, r), got in zip(noise_starts, screened):
        if isinstance(got, IdentificationError):  # no stabilising predictor from this start
            errors.append(got)
            fits.append(None)
            continue
        fits.append(got)
        if progress is not None:
            progress.message(f"[sysid] filter error: noise start Q x {q:g}, R x {r:g}: "
                             f"L = {got.cost:.3f} after {got.passes} passes "
                             f"({got.cpu_time:.1f} s)")
    done = [f for f in fits if f is not None]
    if not done:
        raise errors[0]
    chosen = min(done, key=lambda f: f.cost)
    best = _fit(records, structure, start=chosen.theta, warm=chosen.noise_and_nuisance,
                corrected=False, **kw)
    best.cpu_elsewhere = elsewhere
    best.model.attrs["noise_starts"] = json.dumps(
        [[float(q), float(r), None if f is None else float(f.cost)]
         for (q, r), f in zip(noise_starts, fits)])
    return best


@fit_settings
def _screen_one(records, structure, start, noise_start, screen):
    """One noise start's screening passes, or the IdentificationError that ended them."""
    try:
        return _fit(records, structure, start=start, noise_start=tuple(noise_start), **screen)
    except IdentificationError as exc:
        return exc


def _screened(records, structure, start, noise_starts, screen, progress=None
              ) -> tuple[list, float]:
    """:func:`_screen_one` of every start, in order, and the CPU (s) they took in other
    processes: side by side in up to :data:`MAX_SCREEN_PROCESSES` processes
    (:func:`~sysid.core.util.forkserver_context`), in turn with one, or when the processes
    cannot be started or die (the same results, later)."""
    processes = min(worker_processes("SYSID_FIT_PROCESSES", MAX_SCREEN_PROCESSES),
                    len(noise_starts))
    if processes > 1:
        try:
            with concurrent.futures.ProcessPoolExecutor(
                    processes, mp_context=forkserver_context()) as pool:
                futures = [pool.submit(_screen_one, records, structure, start, qr, screen)
                           for qr in noise_starts]
                got = [f.result() for f in futures]
            return got, sum(g.cpu_time for g in got if isinstance(g, _Screened))
        except POOL_FAILURES as exc:
            if progress is not None:
                progress.message(f"[sysid] filter error: the screening processes failed "
                                 f"({type(exc).__name__}: {exc}); screening in this process")
    return [_screen_one(records, structure, start, qr, screen) for qr in noise_starts], 0.0


@dataclass
class _Screened:
    """Where a fit's relaxation ended, without statistics: a noise start's screening passes
    (only the lowest start is converged and reported) or a reduction refit above its
    ceiling (refused)."""

    theta: np.ndarray
    cost: float
    passes: int
    cpu_time: float
    noise_and_nuisance: np.ndarray
    #: False for a refit stopped once it could no longer come under its ceiling
    converged: bool = True


def _refusal_watch(jacobian, pred: _Predictor, ceiling: float, likelihood):
    """The Jacobian callable ``jacobian`` of a reduction refit's solve, raising
    :class:`~sysid.identify.reduction.StoppedAboveCeiling` at an accepted iterate whose
    likelihood ``likelihood(alpha)`` cannot come under ``ceiling`` (:data:`REFUSAL_MIN_GAP`):
    the Gauss-Newton model's further decrease is ``|q|^2 / 2`` of the compressed residuals
    ``f = [q, f_N]``."""

    def watched(alpha):
        f, _ = pred._compressed(alpha)
        cost = likelihood(alpha)
        if refusal_certain(cost, cost - 0.5 * float(f[:-1] @ f[:-1]), ceiling,
                           min_gap=REFUSAL_MIN_GAP):
            raise StoppedAboveCeiling(alpha, cost, ceiling)
        return jacobian(alpha)

    return watched


def _add_coloured(result: FilterErrorResult) -> None:
    """The corrected bounds a reduction refit left for later (``coloured_pending``), put on
    its model; nothing when they are there."""
    if result.coloured_pending is None:
        return
    rows, residuals, dt = result.coloured_pending
    result.coloured = coloured_residual_covariance(
        sensitivities=rows(), residuals=residuals,
        information_inverse=result.statistics.covariance)
    add_corrected_bounds(result.model, result.structure.free_names, result.theta,
                         result.coloured, dt)
    result.coloured_pending = None


def _fit(records, structure, *, start, outputs, process_noise, biases, initial_state, tol,
         max_passes, cost_tol, max_nfev, warm: np.ndarray | None = None,
         noise_start: tuple[float, float] = (1.0, 1.0), screen: bool = False,
         ceiling: float | None = None, corrected: bool = True
         ) -> FilterErrorResult | _Screened:
    """One fit by relaxation. Without statistics (a :class:`_Screened`): a screening start
    (``screen``), or a fit that ends above ``ceiling`` (a reduction refit its likelihood-ratio
    rule refuses). ``corrected=False`` leaves the corrected bounds to :func:`_add_coloured`."""
    cpu0 = time.process_time()
    records, outs, recs = fit_inputs(records, structure, outputs,
                                     what="identify_filter_error")
    if start is None:
        theta0 = structure.theta0
    elif isinstance(start, xr.Dataset):
        theta0 = structure.values_from_model(start)
    else:
        theta0 = np.asarray(start, float)
        if theta0.shape != structure.theta0.shape:
            raise InputDataError(f"start has {theta0.size} values; structure "
                                 f"{structure.name!r} has {structure.theta0.size} free "
                                 f"parameters {list(structure.free_names)}")
    n = len(structure.states)
    mask = _noise_mask(process_noise_states(process_noise, structure), structure.states,
                       outs)
    pred = _Predictor(structure, recs, outs, mask, biases, initial_state)
    # a screened start shares the cores with the others; any other fit has them to itself
    pred.threads = 1 if screen else worker_processes("SYSID_FIT_PROCESSES",
                                                     MAX_SCREEN_PROCESSES)
    n_samples = sum(len(r.time) for r in recs)
    p = len(outs)
    if n_samples * p < 10 * pred.n_beta:
        raise InputDataError(
            f"identify_filter_error: {n_samples} samples x {p} outputs is fewer than ten "
            f"residuals per estimated parameter ({pred.n_beta}: {pred.n_theta} structure, "
            f"{pred.n_f} process noise, {pred.n_rec} per record)")
    # Start: R from the first differences of the measurements (white noise doubles in a
    # difference); Q diagonal, the variance of a tenth of the difference std of each measured
    # state (Q = 0 is not a start: no gain, no gradient towards one); both scaled by
    # noise_start. K depends on (Q, R) only up to a common factor: the first output's R is
    # held at its start value.
    dz = np.vstack([np.diff(r.Z, axis=0) for r in recs])
    r_start = np.sqrt(np.maximum(0.5 * dz.var(axis=0), 1e-24))
    pred.r0 = float(r_start[0])
    q0 = np.zeros(n)
    for j, o in enumerate(outs):
        if o in structure.states:
            q0[structure.states.index(o)] = (0.1 * dz[:, j].std()) ** 2
    q0 = np.where(q0 > 0, q0, max(1e-6, float(np.max(q0))))
    alpha = np.concatenate([theta0, np.zeros(len(pred.u_rows)),
                            noise_start[0] * q0[pred.d_idx], noise_start[1] * r_start[1:] ** 2])
    if warm is not None:  # a refit: the last fit's noise values (the nuisance is solved for)
        if len(warm) != pred.n_beta - pred.n_theta:
            raise InputDataError(f"identify_filter_error: warm start has {len(warm)} noise "
                                 f"and nuisance values, expected {pred.n_beta - pred.n_theta}")
        alpha[pred.n_theta:] = warm[:pred.n_g]
    lo, hi = structure.bounds
    lower = np.concatenate([lo, np.full(pred.n_beta - len(lo), -np.inf)])
    upper = np.concatenate([hi, np.full(pred.n_beta - len(hi), np.inf)])
    lower[pred.n_theta + len(pred.u_rows):pred.n_alpha] = 0.0  # variances
    na = pred.n_alpha
    alpha = np.clip(alpha, lower[:na], upper[:na])

    def innovations(a, where):
        try:
            E = pred.innovations(a)
        except (np.linalg.LinAlgError, ValueError) as exc:
            raise IdentificationError(
                f"filter error: no stabilising steady-state Kalman predictor {where} "
                f"(discrete Riccati equation: {exc}); is (Phi, C) detectable with the fitted "
                f"outputs {list(outs)}?") from exc
        Eall = np.vstack(E)
        Sigma = Eall.T @ Eall / len(Eall)
        sign, logdet = np.linalg.slogdet(Sigma)
        if sign <= 0 or not np.isfinite(logdet):
            raise IdentificationError(
                f"filter error: innovation covariance singular {where} (outputs "
                f"{list(outs)} linearly dependent or noise-free)")
        return E, Sigma, 0.5 * n_samples * (logdet + p)

    # the bounded trust-region reflective solver (variances at least 0, free delays in their
    # range); MINPACK's Levenberg-Marquardt when nothing is bounded
    bounded = bool(np.any(np.isfinite(lower[:na])) or np.any(np.isfinite(upper[:na])))
    method, bounds = (("trf", (lower[:na], upper[:na])) if bounded
                      else ("lm", (-np.inf, np.inf)))
    E, Sigma, cost = innovations(alpha, "at the start")
    cost_prev, passes, refused = math.inf, 0, False
    fun, jac = ((pred.residuals, "2-point") if FINITE_DIFFERENCES else
                (pred.compressed_residuals, pred.compressed_jacobian))
    pred.settle = ((lower[:na], upper[:na]) if SETTLED_SOLVES and not FINITE_DIFFERENCES
                   else None)
    for passes in range(1, max_passes + 1):
        pred.set_whitener(np.linalg.inv(np.linalg.cholesky(Sigma)))
        pred.settle_tol = (FIRST_PASS_SETTLED if passes == 1 and warm is None
                           else SOLVE_SETTLED)
        watched = jac
        if pred.settle is not None and STALL_SOLVES:
            watched = stall_watch(jac, lambda a: 0.5 * float(np.sum(fun(a) ** 2)),
                                  decrease=STALL_WINDOW * SOLVE_SETTLED)
        if ceiling is not None and not FINITE_DIFFERENCES:
            watched = _refusal_watch(watched, pred, ceiling,
                                     lambda a: innovations(a, "in a reduction refit")[2])
        try:
            # a variance at its bound 0 leaves the correlations it scales without effect:
            # zero Jacobian columns, which the trust-region step handles but divides by
            with np.errstate(divide="ignore", invalid="ignore"):
                alpha = scipy.optimize.least_squares(
                    fun, alpha, method=method, jac=watched, bounds=bounds, x_scale="jac",
                    ftol=tol, xtol=tol, gtol=tol, max_nfev=max_nfev).x
        except SolveStopped as stopped:  # Settled or Stalled, at an accepted iterate
            alpha = stopped.theta
        except StoppedAboveCeiling as stopped:  # a refit the reduction will refuse
            alpha, refused = stopped.theta, True
        E, Sigma, cost = innovations(alpha, "at the end of a solve")
        nuisance = pred._run(alpha)["nuisance"]  # in the metric of this pass
        if refused or abs(cost_prev - cost) < cost_tol:
            break
        cost_prev = cost
    beta = np.concatenate([alpha, nuisance.ravel()])  # the E that gave Sigma
    if screen or (ceiling is not None and cost > ceiling):
        return _Screened(alpha[:pred.n_theta].copy(), float(cost), int(passes),
                         time.process_time() - cpu0, beta[pred.n_theta:].copy(),
                         converged=not refused)
    pred.set_whitener(np.linalg.inv(np.linalg.cholesky(Sigma)))
    names = pred.names(outs)
    nt = pred.n_theta
    if FINITE_DIFFERENCES:
        J = _central_jacobian(pred.residuals, beta, lower, upper)
        M = J.T @ J
    else:
        M = pred.information(beta)
    joint = information_statistics(M, beta, names)
    Mt, coef = _marginal(M, nt)
    stats = information_statistics(Mt, beta[:nt], list(structure.free_names))
    pending = None
    if nt:  # the innovations' colour (structure error the process noise did not absorb)
        if FINITE_DIFFERENCES:
            ends = np.cumsum([0] + [len(e) * p for e in E])
            Gt = J[:, :nt] - J[:, nt:] @ coef

            def rows():
                return [Gt[a:b].reshape(-1, p, nt) for a, b in zip(ends[:-1], ends[1:])]
        else:
            pred.set_whitener(pred.whitener)  # its caches go: rows() runs again if asked

            def rows():
                return pred.marginal_rows(beta, coef)
        pending = (rows, [e @ pred.whitener.T for e in E], recs[0].dt)
    theta, F, R, _, _ = pred.split(beta)
    _, C, _, disc = pred.discrete(theta)
    K, P = pred.kalman(disc[recs[0].dt][0], C, F, R)
    # (Q, R) are known up to a common factor: the one that matches the model's innovation
    # variances C P C^T + R to the measured ones on average; R reported as what the scaled
    # process noise leaves of Sigma (without process noise the shape of R is not identifiable)
    scale = float(np.mean(np.diag(Sigma) / np.diag(C @ P @ C.T + np.diag(R))))
    F = F * math.sqrt(scale)
    R = np.maximum(np.diag(Sigma) - scale * np.diag(C @ P @ C.T), 0.0)
    white = _whiteness(E, pred.whitener, WHITENESS_LAGS)
    states = list(structure.states)
    sc = {"state": states, "state_": states}
    gain_da = xr.DataArray(K, dims=("state", "output"),
                           coords={"state": states, "output": list(outs)}, name="gain",
                           attrs={"dt": recs[0].dt})
    q_da = xr.DataArray(F @ F.T, dims=("state", "state_"), coords=sc, name="process_noise")
    f_da = xr.DataArray(F, dims=("state", "state_"), coords=sc,
                        name="process_noise_distribution")
    r_da = xr.DataArray(R, dims=("output",), coords={"output": list(outs)},
                        name="measurement_noise")
    sig_da = xr.DataArray(Sigma, dims=("output", "output_"),
                          coords={"output": list(outs), "output_": list(outs)},
                          name="innovation_covariance")
    band = 2.0 / math.sqrt(n_samples)
    white_da = xr.DataArray(white, dims=("output", "lag"),
                            coords={"output": list(outs),
                                    "lag": np.arange(1, WHITENESS_LAGS + 1)},
                            name="innovation_autocorrelation", attrs={"band": band})
    cpu = time.process_time() - cpu0
    attrs = {
        "method": "filter_error",
        "estimator": "filter error (steady-state Kalman predictor, process noise Q = U D U^T, "
                     "R = diag(R_j), variances >= 0, Riccati gain; bias and initial state by "
                     "variable projection), relaxation: trust-region solve with Sigma fixed, "
                     "then Sigma = mean e e^T",
        "cost": float(cost),
        "cost_definition": "negative log-likelihood 1/2 sum e^T Sigma^-1 e + N/2 ln det Sigma",
        "records": ",".join(r.name for r in recs),
        "fitted_outputs": ",".join(outs),
        "n_samples": int(n_samples),
        "process_noise_entries": json.dumps([[states[i], states[j]] for i, j in
                                             zip(pred.f_rows, pred.f_cols)]),
        "cramer_rao_convention": "M = sum S^T Sigma^-1 S of the innovations (process noise "
                                 "and nuisance marginalised), CR = sqrt(diag M^-1)",
        "sensitivities": ("forward differences (solver), central differences (bounds)"
                          if FINITE_DIFFERENCES else "analytic (predictor sensitivity "
                          "equations, Riccati derivative from a Lyapunov equation)"),
        "passes": int(passes),
        "n_cost_evaluations": int(pred.n_eval),
        "n_jacobian_evaluations": int(pred.n_jac),
        "cpu_time_s": float(cpu),
        "whiteness_band": band,
        "max_abs_autocorrelation": float(np.max(np.abs(white))),
    }
    model = structure.to_dataset(theta, stats, attrs=attrs)
    add_corrected_bounds(model, structure.free_names, theta, None, recs[0].dt)
    for da in (gain_da, q_da, r_da, sig_da, white_da):
        model[da.name] = da
    result = FilterErrorResult(model, structure, theta, stats, joint, gain_da, q_da, f_da,
                               r_da, sig_da, white_da, float(cost),
                               tuple(r.name for r in recs), outs, int(passes),
                               int(pred.n_eval), float(cpu), full_statistics=stats,
                               noise_and_nuisance=beta[nt:].copy(), coloured_pending=pending)
    if corrected:
        _add_coloured(result)
    return result


def _marginal(M: np.ndarray, nt: int) -> tuple[np.ndarray, np.ndarray]:
    """``(M_t, A)``: the information ``M_t = M_tt - M_tn M_nn^-1 M_nt`` (nt, nt) of the first
    ``nt`` parameters with the others marginalised (the Schur complement of the joint
    information ``M``, n x n), and ``A = M_nn^-1 M_nt`` (n - nt, nt), the least-squares
    fit of their sensitivities by the others' (``G_t - G_n A`` are the marginal
    sensitivities, ``M_t`` their Gram matrix). A column of ``G_n`` dependent on earlier ones
    is left out (:func:`_independent_gram`; its row of ``A`` is 0)."""
    Mtt, Mnt = M[:nt, :nt], M[nt:, :nt]
    A = np.zeros(Mnt.shape)
    if not len(Mnt):
        return Mtt.copy(), A
    keep, L = _independent_gram(M[nt:, nt:])
    if not keep.any():
        return Mtt.copy(), A
    A[keep] = _chol_solve(L, Mnt[keep])
    T = scipy.linalg.solve_triangular(L, Mnt[keep], lower=True, check_finite=False)
    return Mtt - T.T @ T, A


def _compress(G: np.ndarray, g: np.ndarray, rr: float) -> tuple[np.ndarray, np.ndarray]:
    """``(f, J_f)``, ``n + 1`` residuals and their ``(n + 1) x n`` Jacobian with
    ``|f|^2 = rr = |r|^2``, ``J_f^T f = g = J^T r`` and ``J_f^T J_f = G = J^T J`` (so every
    Gauss-Newton model and column norm is the full problem's; as
    :func:`sysid.identify.least_squares.compress`), from the eigen-decomposition
    ``V diag(lam) V^T`` of the column-scaled Gram matrix: ``J_f = diag(sqrt(lam)) V^T D``,
    ``f = diag(lam)^-1/2 V^T D^-1 g``. Unlike a Cholesky factor it allows a rank-deficient
    ``J``: the bias and the initial state of a state that no other state reads (the heading)
    are exactly collinear. Directions with ``lam < 1e-12 max(lam)`` are dropped (no curvature
    and, to rounding, no gradient)."""
    n = G.shape[1]
    d = np.sqrt(np.diag(G))
    d = np.where(d > 0, d, 1.0)
    lam, V = np.linalg.eigh(G / np.outer(d, d))
    keep = lam > 1e-12 * lam[-1]
    s = np.sqrt(lam[keep])
    Vk = V[:, keep]
    q = (Vk.T @ (g / d)) / s
    f = np.zeros(n + 1)
    f[:len(q)] = q
    f[-1] = math.sqrt(max(float(rr) - float(q @ q), 0.0))
    Jf = np.zeros((n + 1, n))
    Jf[:len(q)] = (Vk * s).T * d
    return f, Jf


def _central_jacobian(fun, x, lower, upper) -> np.ndarray:
    """Central-difference Jacobian (one-sided at a bound), relative step ``eps^(1/3)``."""
    f0 = fun(x)
    J = np.empty((f0.size, x.size))
    h = np.finfo(float).eps ** (1 / 3) * np.maximum(1.0, np.abs(x))
    for i in range(x.size):
        xp, xm = x.copy(), x.copy()
        xp[i] = min(x[i] + h[i], upper[i])
        xm[i] = max(x[i] - h[i], lower[i])
        J[:, i] = (fun(xp) - fun(xm)) / (xp[i] - xm[i])
    return J
