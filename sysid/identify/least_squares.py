"""The nonlinear least-squares problem handed to the trust-region solver, compressed.

For residuals ``r`` (m) and Jacobian ``J`` (m x n, m >> n) with the thin factorisation
``J = Q R_J``, the problem with ``n + 1`` rows

    f = [Q^T r, |r - Q Q^T r|],      J_f = [R_J; 0]

has the same cost ``|f|^2 = |r|^2``, gradient ``J_f^T f = J^T r``, column norms and every
Gauss-Newton model ``|f + J_f p| = |r + J p|``, so a trust-region solver takes the same
steps to rounding without factorising the tall Jacobian at every iteration. Both fits use it
(docs/notes/2026-11-24-time-domain-speed.md measures the saving).

A solve may also end from inside the solver's Jacobian callback, at an accepted iterate
where the Gauss-Newton model ``1/2 g^T (J^T J)^-1 g`` predicts too little further decrease
(:func:`predicted_decrease`, :class:`Settled`): the time-domain fits stop their solves so.
Or where its last accepted steps together gained too little (:func:`stall_watch`,
:class:`Stalled`): the frequency-domain and filter-error fits stop a creep along an
ill-conditioned valley so.

References
----------
* Golub, G. H. and Van Loan, C. F., *Matrix Computations*, 4th ed., Johns Hopkins, 2013,
  sec. 5.3 (least squares by QR; the residual norm from the discarded part).
"""

from __future__ import annotations

import math

import numpy as np
import scipy.linalg

__all__ = ["compress", "triangle", "SolveStopped", "Settled", "Stalled", "predicted_decrease",
           "stall_watch", "STALL_WINDOW"]

#: Accepted steps over which a solve's progress is judged (:func:`stall_watch`;
#: :func:`sysid.identify.reduction.pace_insufficient`).
STALL_WINDOW = 10


def triangle(J: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """``(R_J, Q^T r)`` of the thin factorisation ``J = Q R_J`` (J: m x n, m >> n).

    From the Cholesky factor of the column-scaled Gram matrix ``J^T J`` (one BLAS-3 product
    instead of a QR of the tall matrix), ``Q^T r = R_J^-T J^T r``; when the
    scaled Gram matrix is too ill-conditioned for that (reciprocal condition below 1e-10,
    i.e. J's above 1e5), the QR of J itself.
    """
    d = np.sqrt(np.einsum("ij,ij->j", J, J))
    d = np.where(d > 0, d, 1.0)
    Js = J / d
    Gram = Js.T @ Js
    try:
        U = scipy.linalg.cholesky(Gram, lower=False)
        diag = np.diag(U)
        if np.min(diag) ** 2 < 1e-10 * np.max(diag) ** 2:
            raise np.linalg.LinAlgError("ill-conditioned")
    except np.linalg.LinAlgError:
        Q, R = scipy.linalg.qr(J, mode="economic")
        return R, Q.T @ r
    qr = scipy.linalg.solve_triangular(U, Js.T @ r, trans="T", lower=False)
    return U * d, qr


def compress(r: np.ndarray, J: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The compressed problem ``(f, J_f)``: ``n + 1`` residuals and their ``(n + 1) x n``
    Jacobian (module docstring). Non-finite residuals (a diverged trial model) give an
    infinite cost, so the solver steps back."""
    n = J.shape[1]
    if not np.all(np.isfinite(r)) or not np.all(np.isfinite(J)):
        return np.full(n + 1, np.inf), np.zeros((n + 1, n))
    RJ, qr = triangle(J, r)
    rest = math.sqrt(max(float(r @ r) - float(qr @ qr), 0.0))
    return np.append(qr, rest), np.vstack([RJ, np.zeros((1, n))])


class SolveStopped(Exception):
    """Ends a solve at ``theta`` from inside the solver's callbacks (raised through it)."""

    def __init__(self, theta):
        super().__init__(type(self).__name__)
        self.theta = np.array(theta, float)


class Settled(SolveStopped):
    """A solve has converged at ``theta`` (an accepted iterate): its Gauss-Newton model
    predicts less further decrease than the fit asks for (:func:`predicted_decrease`)."""


class Stalled(SolveStopped):
    """A solve has stopped progressing at ``theta`` (an accepted iterate): its last accepted
    steps together lowered the cost by less than the fit asks for (:func:`stall_watch`)."""


def stall_watch(jacobian, cost, *, decrease: float, window: int = STALL_WINDOW):
    """The Jacobian callable ``jacobian`` for :func:`scipy.optimize.least_squares`, raising
    :class:`Stalled` at an accepted iterate whose ``cost(theta)`` is less than ``decrease``
    below the cost ``window`` accepted iterates earlier.

    The trust-region solver asks for the Jacobian at its start and after every accepted step,
    so the test runs once per iterate. Why: along a long, ill-conditioned valley the solver
    can creep for thousands of evaluations, each gaining a few millionths of the cost, before
    its own relative tolerances end it; the Gauss-Newton model there predicts more than the
    steps deliver, so :func:`predicted_decrease` does not see it.

    Examples
    --------
    >>> import numpy as np
    >>> jac = stall_watch(lambda th: np.eye(1), lambda th: float(th[0]), window=2,
    ...                   decrease=0.5)
    >>> for c in (10.0, 5.0, 4.8):
    ...     _ = jac(np.array([c]))
    >>> try:
    ...     jac(np.array([4.7]))
    ... except Stalled as stop:
    ...     print(stop.theta)
    [4.7]
    """
    history: list[float] = []

    def watched(theta):
        c = float(cost(theta))
        history.append(c)
        if len(history) > window and history[-1 - window] - c < decrease:
            raise Stalled(theta)
        return jacobian(theta)
    return watched


def predicted_decrease(bounds: tuple[np.ndarray, np.ndarray], theta: np.ndarray,
                       g: np.ndarray, M: np.ndarray, unconstrained: float) -> float:
    """Decrease ``1/2 g^T M^-1 g`` of a Gauss-Newton model (gradient ``g``, matrix ``M``)
    over the parameters not held at a bound of ``bounds = (lower, upper)`` (within 1e-3 of
    its range, the gradient pushing outward); ``unconstrained`` where none is held."""
    lo, hi = bounds
    near = 1e-3 * np.where(np.isfinite(hi - lo), hi - lo, 1.0)
    free = ~(((theta - lo < near) & (g > 0)) | ((hi - theta < near) & (g < 0)))
    if free.all():
        return unconstrained
    if not free.any():
        return 0.0
    Mf, gf = M[np.ix_(free, free)], g[free]
    try:
        return 0.5 * float(gf @ np.linalg.solve(Mf, gf))
    except np.linalg.LinAlgError:  # a direction without curvature (e.g. collinear nuisances)
        return 0.5 * float(gf @ np.linalg.lstsq(Mf, gf, rcond=None)[0])
