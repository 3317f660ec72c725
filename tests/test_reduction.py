"""Stepwise reduction with early refusal of trial refits, on a linear least-squares problem
whose nested-model costs are known in closed form (the independent truth)."""

import numpy as np
import scipy.optimize

from sysid.identify.least_squares import compress
from sysid.identify.reduction import (STOPPED_ABOVE_CEILING, FitOutcome, StoppedAboveCeiling,
                                      ceiling_watch, conditional_start, refusal_certain,
                                      stepwise_reduction)
from sysid.identify.statistics import parameter_statistics


def _problem(seed):
    """y = X beta + e: two well-determined parameters, a small one (true value about four
    bounds: it breaks the 20 % Cramer-Rao guideline but removing it raises the cost by
    ~16 > 4) and two spurious ones."""
    rng = np.random.default_rng(seed)
    X = rng.standard_normal((400, 5))
    beta = np.array([1.0, -0.6, 0.09, 0.0, 0.0])
    y = X @ beta + 0.5 * rng.standard_normal(400)
    names = ("a", "b", "c", "d", "e")
    return X, y, names


def _fit(X, y, names, removed, ceiling, use_ceiling, counts):
    keep = [k for k, n in enumerate(names) if n not in removed]
    Xk = X[:, keep]

    def compressed(theta):
        counts.append(1)
        return compress((Xk @ theta - y) / 0.5, Xk / 0.5)

    # a far start, so the solver needs several steps (a linear problem converges in one
    # Gauss-Newton step; the trust region makes it take more)
    theta0 = np.full(len(keep), 25.0)
    jac = (ceiling_watch(compressed, ceiling) if use_ceiling
           else (lambda th: compressed(th)[1]))
    try:
        res = scipy.optimize.least_squares(lambda th: compressed(th)[0], theta0, jac=jac,
                                           method="trf", x_scale="jac", ftol=1e-12,
                                           xtol=1e-12, gtol=1e-12)
        theta, status = res.x, int(res.status)
    except StoppedAboveCeiling as stop:
        theta, status = stop.theta, STOPPED_ABOVE_CEILING
    r = (Xk @ theta - y) / 0.5
    stats = parameter_statistics(Xk / 0.5, theta, tuple(names[k] for k in keep))
    return FitOutcome(float(r @ r), stats, None, converged=status != STOPPED_ABOVE_CEILING)


def _exact_cost(X, y, names, removed):
    keep = [k for k, n in enumerate(names) if n not in removed]
    beta, *_ = np.linalg.lstsq(X[:, keep], y, rcond=None)
    r = (X[:, keep] @ beta - y) / 0.5
    return float(r @ r)


def test_refusal_rule_on_the_gauss_newton_minimum():
    # far above the ceiling with little decrease left: certain; a large predicted decrease or
    # a cost under the ceiling: not certain
    assert refusal_certain(440.0, 435.0, 12.4)
    assert not refusal_certain(30.85, 30.26, 30.02)
    assert not refusal_certain(11.0, 11.0, 12.4)
    assert not refusal_certain(440.0, 435.0, 12.4, margin=np.inf)
    assert not refusal_certain(np.nan, 1.0, 2.0)


def test_early_refusal_keeps_the_decisions_and_saves_evaluations():
    refused: list = []
    for seed in (1, 2, 3):
        X, y, names = _problem(seed)
        results, evaluations = {}, {}
        for use in (False, True):
            counts: list = []

            def fit(removed, previous, ceiling):
                return _fit(X, y, names, removed, ceiling, use, counts)

            results[use] = stepwise_reduction(fit, fit((), None, np.inf), cr_max=20.0,
                                              insensitivity_max=10.0, max_cost_increase=4.0)
            evaluations[use] = len(counts)
        plain, early = results[False], results[True]
        # the decisions are those of the closed-form nested costs
        removed: list = []
        for step in early.steps:
            before = _exact_cost(X, y, names, removed)
            after = _exact_cost(X, y, names, removed + [step.parameter])
            assert step.accepted == (after - before <= 4.0), (seed, step)
            if step.accepted:
                removed.append(step.parameter)
                assert step.converged
                np.testing.assert_allclose(step.cost_after, after, rtol=1e-9)
            else:  # stopped above the ceiling: at or above the converged trial cost
                assert step.cost_after >= after * (1 - 1e-12)
        assert set(early.removed) == {"d", "e"}
        refused += [s for s in early.steps if not s.accepted]
        # ... and those of the fit without early refusal; the same final model
        assert [(s.parameter, s.accepted) for s in plain.steps] == \
            [(s.parameter, s.accepted) for s in early.steps]
        np.testing.assert_array_equal(plain.final.statistics.values,
                                      early.final.statistics.values)
        assert not any(s.converged for s in early.steps if not s.accepted)
        assert evaluations[True] < evaluations[False]
    assert refused  # the small parameter's removal was tried and undone


def test_conditional_start_is_the_refit_minimum_of_a_linear_problem():
    """For a linear least-squares problem the conditional start is the refit's minimum
    itself: the least-squares solution with the removed column deleted (closed form, from
    numpy's lstsq, not from the statistics)."""
    for seed in range(5):
        X, y, names = _problem(seed)
        X = X + 0.6 * X[:, [2]]  # correlate every column with "c"
        X[:, 2] /= 1.6
        full = np.linalg.lstsq(X, y, rcond=None)[0]
        stats = parameter_statistics(X / 0.5, full, names)
        for j, name in enumerate(names):
            rest = [n for n in names if n != name]
            keep = [k for k in range(len(names)) if k != j]
            truth = np.linalg.lstsq(X[:, keep], y, rcond=None)[0]
            start = conditional_start(stats, name, rest)
            plain = full[keep]
            np.testing.assert_allclose(start, truth, rtol=1e-9, atol=1e-12)
            # and the plain start is measurably elsewhere wherever the columns correlate
            assert np.max(np.abs(plain - truth)) > 1e-3 * np.max(np.abs(truth))


def test_conditional_start_keeps_the_estimates_where_the_covariance_is_not_finite():
    X, y, names = _problem(0)
    full = np.linalg.lstsq(X, y, rcond=None)[0]
    stats = parameter_statistics(X, full, names)
    stats.covariance[:, 1] = np.inf
    start = conditional_start(stats, "b", ("a", "c", "d", "e"))
    np.testing.assert_array_equal(start, full[[0, 2, 3, 4]])
