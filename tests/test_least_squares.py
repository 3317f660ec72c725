"""The solver helpers of sysid.identify.least_squares on a problem whose trust-region solve
is known to creep: two hyperbolic constraints and a weak pull along their valley, whose exact
minimum (cost 0 at theta = (30, 1/30, 30)) the solver approaches a few thousandths per step."""

import numpy as np
import scipy.optimize

from sysid.identify.least_squares import Stalled, compress, stall_watch
from sysid.identify.reduction import StoppedAboveCeiling, ceiling_watch, pace_insufficient


def _residuals(t):
    return np.array([1e3 * (t[0] * t[1] - 1), 1e3 * (t[1] * t[2] - 1), 1e-2 * (t[0] - 30.0)])


def _jacobian(t):
    return np.array([[1e3 * t[1], 1e3 * t[0], 0], [0, 1e3 * t[2], 1e3 * t[1]], [1e-2, 0, 0]])


def _cost(t):
    r = _residuals(np.asarray(t, float))
    return float(r @ r)


def _solve(jac, residuals=_residuals):
    return scipy.optimize.least_squares(residuals, [1.0, 1.0, 1.0], jac=jac, method="trf",
                                        x_scale="jac", ftol=1e-10, xtol=1e-10, gtol=1e-10)


def test_the_problem_creeps_to_the_solvers_cap():
    plain = _solve(_jacobian)
    assert plain.status == 0 and plain.nfev == 300  # max_nfev = 100 n
    assert 2 * plain.cost > 1e-2                     # far from the exact minimum 0


def test_stall_watch_ends_the_creep_at_an_accepted_iterate():
    plain = _solve(_jacobian)
    costs: list = []

    def cost(t):
        costs.append(_cost(t))
        return costs[-1]

    window, decrease = 10, 1e-3
    try:
        _solve(stall_watch(_jacobian, cost, window=window, decrease=decrease))
    except Stalled as stop:
        theta = stop.theta
    else:
        raise AssertionError("the creep was not stopped")
    # the stop is the last accepted iterate, its window gained less than asked, the ones
    # before did not stop it, and it is no worse than the plain solve by more than the rule
    # allows per window times the windows the plain solve went on for
    assert _cost(theta) == costs[-1]
    assert costs[-1 - window] - costs[-1] < decrease
    assert all(costs[k - window] - costs[k] >= decrease for k in range(window, len(costs) - 1))
    assert len(costs) < plain.nfev / 3
    assert _cost(theta) - 2 * plain.cost < decrease * plain.nfev / window


def test_stall_watch_leaves_a_converging_solve_alone():
    """A linear least-squares problem (exact minimum by lstsq) is solved to the same point."""
    rng = np.random.default_rng(3)
    X, y = rng.standard_normal((50, 3)), rng.standard_normal(50)
    exact = np.linalg.lstsq(X, y, rcond=None)[0]
    res = scipy.optimize.least_squares(
        lambda t: X @ t - y, np.full(3, 25.0), method="trf", x_scale="jac", ftol=1e-12,
        xtol=1e-12, gtol=1e-12,
        jac=stall_watch(lambda t: X, lambda t: float(np.sum((X @ t - y) ** 2)), window=10,
                        decrease=1e-6))
    np.testing.assert_allclose(res.x, exact, rtol=1e-8, atol=1e-10)


def test_a_trial_that_cannot_reach_its_ceiling_at_its_pace_is_stopped():
    """A reduction trial creeping above its ceiling: the Gauss-Newton model (square Jacobian:
    no residual outside its range) predicts the whole cost can go, so only the pace rule
    can stop it; the plain solve confirms it would have ended above the ceiling."""
    plain = _solve(_jacobian)
    ceiling = 1e-3
    assert 2 * plain.cost > ceiling

    def compressed(t):
        t = np.asarray(t, float)
        return compress(_residuals(t), _jacobian(t))

    for budget, stops in ((None, False), (300, True)):
        watch = ceiling_watch(compressed, ceiling, budget=budget)
        try:
            res = _solve(watch, lambda t: compressed(t)[0])
        except StoppedAboveCeiling as stop:
            assert stops and stop.cost > ceiling
            assert np.linalg.norm(stop.theta - plain.x) < 10  # on the same valley
        else:
            assert not stops and res.status == 0


def test_pace_rule():
    # 0.05 per step for 2679 more steps cannot close 306; 2 per step can close 0; a cost
    # under the ceiling or too short a history is never refused
    assert pace_insufficient([1222.7] + [338.2 - 0.05 * k for k in range(20)], 32.0, 2700)
    assert not pace_insufficient([60.0 - 2.0 * k for k in range(15)], 32.0, 2700)
    assert not pace_insufficient([30.0] * 20, 32.0, 2700)
    assert not pace_insufficient([100.0] * 5, 32.0, 2700)
    assert pace_insufficient([100.0] * 12, 32.0, 2700)  # no progress at all
