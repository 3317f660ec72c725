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
from sysid.identify.statistics import ParameterStatistics, format_percent

__all__ = ["FitOutcome", "ReductionStep", "ReductionResult", "stepwise_reduction",
           "GUIDELINES"]


@dataclass
class FitOutcome:
    """What a fit returns to the reduction: its cost measure, statistics and any payload.

    ``statistics.names`` are the free parameters of that fit.
    """

    cost: float
    statistics: ParameterStatistics
    payload: Any = None


@dataclass
class ReductionStep:
    """One attempted removal."""

    parameter: str
    value: float
    cramer_rao_percent: float
    insensitivity_percent: float
    reason: str  #: "insensitivity", "cramer_rao" or "unidentifiable"
    cost_before: float
    cost_after: float
    accepted: bool

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
                         f"{s.cost_after:>12.3f}  {'removed' if s.accepted else 'kept (cost)'}")
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


def stepwise_reduction(fit: Callable[[tuple[str, ...], FitOutcome], FitOutcome],
                       initial: FitOutcome, *, cr_max: float = GUIDELINES["cr_max"],
                       insensitivity_max: float = GUIDELINES["insensitivity_max"],
                       max_cost_increase: float = GUIDELINES["max_cost_increase"],
                       protected: Sequence[str] = (), max_steps: int | None = None,
                       progress=None) -> ReductionResult:
    """Remove poorly determined parameters one at a time, re-converging after each.

    Parameters
    ----------
    fit : callable
        ``fit(removed, previous) -> FitOutcome``: re-converge with the parameters in
        ``removed`` (all removed so far, the newest last) fixed at zero, starting from
        ``previous`` (the last accepted outcome, whose ``payload`` the caller defines).
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
        trial = fit(tuple(removed + [name]), current)
        rise = trial.cost - current.cost
        accepted = bool(np.isfinite(trial.cost) and rise <= max_cost_increase)
        steps.append(ReductionStep(name, float(stats.values[k]),
                                   float(stats.cramer_rao_percent[k]),
                                   float(stats.insensitivity_percent[k]), reason,
                                   float(current.cost), float(trial.cost), accepted))
        if progress is not None:
            progress.message(f"  reduction: {name:<10} CR {format_percent(stats.cramer_rao_percent[k])} % "
                             f"I {format_percent(stats.insensitivity_percent[k])} %  cost "
                             f"{current.cost:.3f} -> {trial.cost:.3f}  "
                             f"{'removed' if accepted else 'kept'}")
        if accepted:
            removed.append(name)
            current = trial
        else:
            needed.append(name)
    return ReductionResult(current, steps, tuple(removed), tuple(needed))
