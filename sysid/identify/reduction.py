"""Stepwise model reduction (docs/methods.md, "Model reduction"; Tischler & Remple 2012).

Generic over the fit: the caller passes a function that re-converges the model with a given
set of parameters removed, so the frequency-domain fit and the time-domain output-error fit
share the same rule:

1. Among the free parameters that break a guideline (``CR% > cr_max`` or
   ``I% > insensitivity_max``; unidentifiable parameters break both), pick the one with the
   largest insensitivity among those breaking the insensitivity guideline, or, if none does,
   the one with the largest Cramer-Rao bound among those breaking the CR guideline.
2. Remove it (the fit callable fixes it at zero) and re-converge.
3. If the cost rose by more than ``max_cost_increase`` (in units of the cost measure the fit
   reports, J_ave for the frequency-domain fit: default 2, "a couple of units of J_ave"),
   the removal is undone, the parameter is kept as *needed* and the next candidate is tried.
4. Stop when no remaining free parameter breaks a guideline (or every one that does has been
   found needed).

Every step, accepted or undone, is recorded.

Each trial refit is told the ceiling ``cost before + max_cost_increase`` above which its
removal is undone. A fit may stop a trial early once its cost can no longer come under the
ceiling (:func:`refusal_certain`) or cannot reach it at its pace before its evaluation
budget runs out (:func:`pace_insufficient`); its outcome then says ``converged=False``, its
cost is where it stopped (at or above what it would have converged to) and the decision is
the one the converged trial gives. Accepted removals are always converged fully.

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012.
* docs/methods.md, "Model reduction".
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Sequence

import numpy as np

from sysid.core.guidelines import REDUCTION_GUIDELINES as GUIDELINES
from sysid.identify.least_squares import STALL_WINDOW
from sysid.identify.statistics import ParameterStatistics, format_percent

__all__ = ["FitOutcome", "ReductionStep", "ReductionResult", "stepwise_reduction",
           "refusal_certain", "pace_insufficient", "ceiling_watch", "StoppedAboveCeiling",
           "REFUSAL_MARGIN", "STOPPED_ABOVE_CEILING", "GUIDELINES", "conditional_start"]

#: Early refusal of a trial refit (:func:`refusal_certain`): the cost must lie above the
#: ceiling by more than this many times the whole decrease the fit's Gauss-Newton model still
#: predicts. Measured on the hover study and three 80-kt quick seeds (103 frequency-domain
#: fits): no accepted refit ever came within 1/7 of firing it (largest ratio 1.39); the
#: total later decrease exceeded the predicted one by at most 10.1x, in a trial hundreds of
#: units above its ceiling (docs/notes/2026-11-25-reduction-early-refusal.md).
REFUSAL_MARGIN = 10.0


@dataclass
class FitOutcome:
    """What a fit returns to the reduction: its cost measure, statistics and any payload.

    ``statistics.names`` are the free parameters of that fit.
    """

    cost: float
    statistics: ParameterStatistics | None  #: None only for a refit above its ceiling
    payload: Any = None
    #: False when the fit stopped early because its cost could no longer come under the
    #: ceiling it was given (``cost`` is then where it stopped).
    converged: bool = True


@dataclass
class ReductionStep:
    """One attempted removal."""

    parameter: str
    value: float
    cramer_rao_percent: float
    insensitivity_percent: float
    reason: str  #: "insensitivity", "cramer_rao" or "unidentifiable"
    cost_before: float
    cost_after: float  #: of the refit; where it stopped when ``converged`` is False
    accepted: bool
    converged: bool = True  #: False: refused early, the refit stopped above the ceiling

    def as_dict(self) -> dict:
        return {k: (float(v) if isinstance(v, (float, np.floating)) else v)
                for k, v in self.__dict__.items()}


@dataclass
class ReductionResult:
    """Outcome of :func:`stepwise_reduction`."""

    final: FitOutcome
    steps: list[ReductionStep] = field(default_factory=list)
    removed: tuple[str, ...] = ()
    needed: tuple[str, ...] = ()  #: break a guideline but their removal raised the cost

    def table(self) -> str:
        lines = [f"{'step':>4}  {'parameter':<12}{'CR %':>9}{'I %':>9}{'cost before':>13}"
                 f"{'cost after':>12}  result"]
        for k, s in enumerate(self.steps, 1):
            lines.append(f"{k:>4}  {s.parameter:<12}{format_percent(s.cramer_rao_percent):>9}"
                         f"{format_percent(s.insensitivity_percent):>9}{s.cost_before:>13.3f}"
                         f"{s.cost_after:>12.3f}  {'removed' if s.accepted else 'kept (cost)'}"
                         f"{'' if s.converged else ', refit stopped early'}")
        return "\n".join(lines)


def _candidate(stats: ParameterStatistics, exclude: set[str], cr_max: float,
               insensitivity_max: float) -> tuple[int, str] | None:
    names = stats.names
    ok = np.array([n not in exclude for n in names], dtype=bool)
    unident = ok & ~stats.identifiable
    if np.any(unident):
        k = int(np.flatnonzero(unident)[np.argmax(stats.insensitivity_percent[unident])])
        return k, "unidentifiable"
    ins = np.where(ok, stats.insensitivity_percent, -np.inf)
    breaks_i = ins > insensitivity_max
    if np.any(breaks_i):
        return int(np.argmax(np.where(breaks_i, ins, -np.inf))), "insensitivity"
    crp = np.where(ok, stats.cramer_rao_percent, -np.inf)
    breaks_c = crp > cr_max
    if np.any(breaks_c):
        return int(np.argmax(np.where(breaks_c, crp, -np.inf))), "cramer_rao"
    return None


def refusal_certain(cost: float, model_minimum: float, ceiling: float, *,
                    margin: float | None = None, min_gap: float = 0.0) -> bool:
    """Whether a least-squares refit at ``cost`` will end above ``ceiling``.

    ``model_minimum`` is the minimum over all steps of the Gauss-Newton model at the current
    point, ``|r + J p|^2`` minimised over ``p`` (same units as ``cost``); ``cost -
    model_minimum`` is the decrease the linearised problem still offers. The rule

        cost - ceiling > margin * (cost - model_minimum)

    stops only when even ``margin`` (default :data:`REFUSAL_MARGIN`; inf: never) times
    that decrease would leave the cost above the ceiling (and, with ``min_gap``, the cost
    lies more than that above it). The argument: the solver's accepted steps never raise
    the cost, so a trial ends under the ceiling only if it still falls by
    ``cost - ceiling``. Near a minimum the Gauss-Newton model predicts the
    remaining fall to within a small factor (the neglected second-order term is small
    there; measured 1.5-2.5 on converging refits), and it ignores the parameter bounds,
    which can only raise the real minimum. Far from a minimum the prediction can be wrong
    by more (10x measured, in a trial crawling hundreds of units above its ceiling), but the
    margin is then also measured against accepted trials (:data:`REFUSAL_MARGIN`). It is an
    argued rule, not a proof for every problem: a fit that must not rest on it passes no
    ceiling.

    Examples
    --------
    >>> refusal_certain(440.0, 435.0, 12.4), refusal_certain(30.85, 30.26, 30.02)
    (True, False)
    >>> refusal_certain(30.85, 30.84, 30.02), refusal_certain(30.85, 30.84, 30.02, min_gap=1.0)
    (True, False)
    """
    margin = REFUSAL_MARGIN if margin is None else margin  # read here: a benchmark sets inf
    if not (np.isfinite(cost) and np.isfinite(model_minimum) and np.isfinite(ceiling)
            and np.isfinite(margin)):
        return False
    return bool(cost - ceiling > max(margin * max(cost - model_minimum, 0.0), min_gap))


#: ``status`` a fit reports for a trial refit stopped by :func:`ceiling_watch` (scipy's
#: least_squares uses -1 to 4).
STOPPED_ABOVE_CEILING = -2


class StoppedAboveCeiling(Exception):
    """Raised by :func:`ceiling_watch` inside the solver; ``theta`` is where it stopped."""

    def __init__(self, theta: np.ndarray, cost: float, ceiling: float):
        super().__init__(f"cost {cost:.6g} can no longer come under the ceiling {ceiling:.6g}")
        self.theta = np.array(theta, dtype=float)
        self.cost = cost


def ceiling_watch(compressed: Callable[[np.ndarray], tuple[np.ndarray, np.ndarray]],
                  ceiling: float, *, scale: float = 1.0, budget: int | None = None,
                  window: int = STALL_WINDOW) -> Callable[[np.ndarray], np.ndarray]:
    """The Jacobian callable for :func:`scipy.optimize.least_squares` on a compressed problem
    (``compressed(theta) -> (f, J_f)``, :func:`sysid.identify.least_squares.compress`) that
    raises :class:`StoppedAboveCeiling` once :func:`refusal_certain` holds, or, with a
    ``budget`` of solver evaluations, once :func:`pace_insufficient` does.

    The solver asks for the Jacobian at its start and after every accepted step, so the test
    runs at each iterate. In the compressed problem the cost is ``|f|^2`` and the
    Gauss-Newton model's minimum ``f[-1]^2`` (the residual outside the Jacobian's range);
    ``scale`` converts both to the units of ``ceiling`` (1 / pairs for J_ave).
    """
    history: list[float] = []

    def jacobian(theta):
        f, J = compressed(theta)
        cost, floor = scale * float(f @ f), scale * float(f[-1] ** 2)
        history.append(cost)
        if refusal_certain(cost, floor, ceiling) or (
                budget is not None and pace_insufficient(history, ceiling, budget, window)):
            raise StoppedAboveCeiling(theta, cost, ceiling)
        return J
    return jacobian


def pace_insufficient(costs: Sequence[float], ceiling: float, budget: int,
                      window: int = STALL_WINDOW) -> bool:
    """Whether a refit whose accepted iterates had ``costs`` cannot reach ``ceiling`` before
    its solver's evaluation ``budget`` runs out, at the pace of its last ``window`` steps.

    With ``k = len(costs)`` accepted iterates (each took at least one evaluation) and the
    pace ``d = (costs[-1 - window] - costs[-1]) / window``, the rule is

        costs[-1] - ceiling > d * (budget - k)

    Why: a trial crawling along a valley far above its ceiling (J_ave 325 -> 318 over 2700
    evaluations against a ceiling of 32) ends at the solver's cap and is undone; this stops
    it where that is already clear. A creep's pace falls as it goes, so its linear
    extrapolation overstates the decrease still to come.

    Examples
    --------
    >>> pace_insufficient([1222.7] + [338.2 - 0.05 * k for k in range(20)], 32.0, 2700)
    True
    >>> pace_insufficient([60.0 - 2.0 * k for k in range(15)], 32.0, 2700)
    False
    """
    k = len(costs)
    if k <= window or not (np.isfinite(costs[-1]) and np.isfinite(ceiling)):
        return False
    pace = max(costs[-1 - window] - costs[-1], 0.0) / window
    return bool(costs[-1] - ceiling > pace * max(budget - k, 0))


def conditional_start(statistics: ParameterStatistics, removed: str,
                      names: Sequence[str]) -> np.ndarray:
    """Start of the refit without ``removed``: the other estimates moved to where the last
    fit's quadratic model has its minimum with ``removed`` held at zero.

    ``theta_r - Sigma_rj / Sigma_jj * theta_j`` (the conditional mean of a Gaussian with
    covariance ``Sigma = H^-1``; equivalently ``theta_r - H_rr^-1 H_rj theta_j``). A plain
    start (the others unchanged) begins the refit as far from its optimum as the removed
    parameter's correlations reach. Any scale of ``Sigma`` cancels. Falls back to the plain
    start where ``Sigma`` is not finite.

    Parameters
    ----------
    statistics : ParameterStatistics
        Of the last accepted fit (``names``, ``values``, ``covariance``).
    removed : str
        The parameter now fixed at zero.
    names : sequence of str
        Free parameters of the refit, in its order.

    Returns
    -------
    ndarray (len(names),)
    """
    index = {n: i for i, n in enumerate(statistics.names)}
    keep = np.array([index[n] for n in names], dtype=int)
    theta = np.asarray(statistics.values, float)
    j = index[removed]
    S = np.asarray(statistics.covariance, float)
    start = theta[keep].copy()
    column = S[keep, j]
    if np.isfinite(S[j, j]) and S[j, j] > 0 and np.all(np.isfinite(column)):
        start -= column / S[j, j] * theta[j]
    return start


def stepwise_reduction(fit: Callable[..., FitOutcome],
                       initial: FitOutcome, *, cr_max: float = GUIDELINES["cr_max"],
                       insensitivity_max: float = GUIDELINES["insensitivity_max"],
                       max_cost_increase: float = GUIDELINES["max_cost_increase"],
                       protected: Sequence[str] = (), max_steps: int | None = None,
                       progress=None) -> ReductionResult:
    """Remove poorly determined parameters one at a time, re-converging after each.

    Parameters
    ----------
    fit : callable
        ``fit(removed, previous, ceiling) -> FitOutcome``: re-converge with the parameters
        in ``removed`` (all removed so far, the newest last) fixed at zero, starting from
        ``previous`` (the last accepted outcome, whose ``payload`` the caller defines).
        ``ceiling`` is the cost above which the removal is undone; the fit may stop once its
        cost can no longer come under it (``FitOutcome.converged`` False) or ignore it, and
        may leave ``statistics`` None when it ends above it.
    initial : FitOutcome
        The converged full model.
    cr_max, insensitivity_max : float
        Guidelines in percent of the parameter value (defaults 20 and 10, docs/methods.md).
    max_cost_increase : float
        Largest accepted rise of ``FitOutcome.cost`` per removal (default 2 units of J_ave).
    protected : sequence of str
        Parameters never removed.
    max_steps : int, optional
        Limit on attempted removals (default: number of free parameters).
    progress : sysid.core.util.Progress, optional
        Receives one line per step.

    Returns
    -------
    ReductionResult
    """
    current = initial
    removed: list[str] = []
    needed: list[str] = []
    steps: list[ReductionStep] = []
    limit = max_steps if max_steps is not None else len(initial.statistics.names)
    while len(steps) < limit:
        stats = current.statistics
        pick = _candidate(stats, set(protected) | set(needed), cr_max, insensitivity_max)
        if pick is None:
            break
        k, reason = pick
        name = stats.names[k]
        ceiling = current.cost + max_cost_increase
        trial = fit(tuple(removed + [name]), current, ceiling)
        accepted = bool(np.isfinite(trial.cost) and trial.cost <= ceiling)
        if accepted and (not trial.converged or trial.statistics is None):
            raise ValueError(f"stepwise_reduction: the refit without {name} "
                             f"{'stopped early' if not trial.converged else 'has no statistics'}"
                             f" at cost {trial.cost:.6g}, under its ceiling {ceiling:.6g}; a "
                             f"fit may stop early or leave out its statistics only above the "
                             f"ceiling")
        steps.append(ReductionStep(name, float(stats.values[k]),
                                   float(stats.cramer_rao_percent[k]),
                                   float(stats.insensitivity_percent[k]), reason,
                                   float(current.cost), float(trial.cost), accepted,
                                   bool(trial.converged)))
        if progress is not None:
            progress.message(f"  reduction: {name:<10} CR {format_percent(stats.cramer_rao_percent[k])} % "
                             f"I {format_percent(stats.insensitivity_percent[k])} %  cost "
                             f"{current.cost:.3f} -> {trial.cost:.3f}  "
                             f"{'removed' if accepted else 'kept'}"
                             f"{'' if trial.converged else ' (refit stopped early)'}")
        if accepted:
            removed.append(name)
            current = trial
        else:
            needed.append(name)
    return ReductionResult(current, steps, tuple(removed), tuple(needed))
