"""Benchmark: frequency-domain identification of the hover-like known system, with model
reduction (target < 10 s on one core). Runs once as a plain test under --benchmark-disable."""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from test_identify_frequency import (SPURIOUS, analytic_response,  # noqa: E402
                                     truth_structure, truth_values)

from sysid.identify import identify_frequency_domain  # noqa: E402


def test_bench_identify_with_reduction(benchmark):
    st = truth_structure(extra_free=SPURIOUS)
    fr = analytic_response(st, noise=0.05, seed=3)
    rng = np.random.default_rng(5)
    start = st.theta0 * (1.0 + rng.uniform(-0.5, 0.5, st.theta0.size))

    def run():
        t0 = time.perf_counter()
        result = identify_frequency_domain(fr, st, start=start, reduce=True)
        return result, time.perf_counter() - t0

    result, elapsed = benchmark.pedantic(run, rounds=1, iterations=1)
    benchmark.extra_info["elapsed_s"] = elapsed
    benchmark.extra_info["cost_evaluations"] = result.n_cost_evaluations
    benchmark.extra_info["jacobian_evaluations"] = result.n_jacobian_evaluations
    benchmark.extra_info["cost_evaluations_per_s"] = result.n_cost_evaluations / elapsed
    benchmark.extra_info["reduction_steps"] = len(result.reduction.steps)
    assert set(result.reduction.removed) == set(SPURIOUS)
    assert set(result.structure.free_names) == set(truth_values())
    # Target: < 10 s on one core (measured ~0.3 s with one BLAS thread); reported in
    # extra_info, not asserted: timings on a shared machine are not a test of correctness.
