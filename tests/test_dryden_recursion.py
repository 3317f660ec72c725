"""The vectorised Dryden recursion (sysid.signals.inputs._simulate_gust, filtered in the Schur
basis) against the plain step-by-step state recursion it replaced, same seed.

The first-order (u) filter repeats the recursion's floating-point operations: equal bytes.
The second-order (v, w) filters change basis: rounding differences only, bounded here at
1e-12 of the rms (measured 1e-14 to 8e-14 on seeds 1-3, docs/notes/2026-11-24-campaign-holds-in-the-fmu.md).
"""

import math

import numpy as np
import pytest
import scipy.linalg

from sysid.signals import inputs


def _step_by_step(kind, tau, sigma, n, dt, g):
    a, b, c = inputs._dryden_filter(kind, tau)
    m = a.shape[0]
    big = np.zeros((2 * m, 2 * m))
    big[:m, :m], big[:m, m:], big[m:, m:] = -a, b @ b.T, a.T
    e = scipy.linalg.expm(big * dt)
    phi = e[m:, m:].T
    q = phi @ e[:m, m:]
    q = 0.5 * (q + q.T)
    p_ss = scipy.linalg.solve_continuous_lyapunov(a, -b @ b.T)
    gain = sigma / math.sqrt(float((c @ p_ss @ c.T)[0, 0]))
    w = g.standard_normal((n, m)) @ np.linalg.cholesky(q).T
    x = np.linalg.cholesky(p_ss) @ g.standard_normal(m)
    out = np.empty(n)
    for i in range(n):
        out[i] = c[0] @ x
        x = phi @ x + w[i]
    return gain * out


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("kind", ["u", "v", "w"])
def test_vectorised_dryden_matches_the_recursion(kind, seed):
    for tau in (6.0, 0.5):  # hover convection (L = 30 m at 5 m/s) and a fast one
        args = (kind, tau, 0.7, 4000, 0.01)
        old = _step_by_step(*args, np.random.default_rng(seed))
        new = inputs._simulate_gust(*args, np.random.default_rng(seed))
        if kind == "u":
            assert new.tobytes() == old.tobytes()
        else:
            assert np.abs(new - old).max() <= 1e-12 * old.std()
