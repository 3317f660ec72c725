"""Benchmark: time-domain output-error identification of a hover 3211 set (4 manoeuvres,
15 s each at 100 Hz) of the known system, with model reduction, from a perturbed start
(target < 20 s on one core); for comparison the frequency-domain identification of the same
structure on analytic responses, and the cost of one analytic sensitivity Jacobian against
one finite-difference Jacobian (one simulation per parameter), and the relaxation with its
early weighted solves capped against converging every one (ratio). Runs once as a plain test
under --benchmark-disable. Stable timings need one BLAS thread (OPENBLAS_NUM_THREADS=1):
on a loaded 2-core machine multi-threaded OpenBLAS slows the many small products by up to 10x.
"""

from __future__ import annotations

import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))
from known_systems import add_noise, multistep_records  # noqa: E402
from test_identify_frequency import (SPURIOUS, analytic_response,  # noqa: E402
                                     truth_structure, truth_values)

from sysid.identify import identify_frequency_domain, identify_time_domain  # noqa: E402
from sysid.identify.time_domain import (OutputErrorModel, fitted_outputs,  # noqa: E402
                                        prepare_records)


def _jacobian_timings(records, st) -> dict:
    outs = fitted_outputs(records, st)
    model = OutputErrorModel(st, prepare_records(records, st, outs), outs)
    theta = st.theta0 * 1.02
    model.jacobian(theta)  # warm-up
    t0 = time.perf_counter()
    for _ in range(3):
        model._cache = None
        model.jacobian(theta)
    analytic = (time.perf_counter() - t0) / 3
    t0 = time.perf_counter()
    r0 = model.residuals(theta)
    for j in range(len(theta)):  # forward differences: one full simulation per parameter
        tp = theta.copy()
        tp[j] += 1e-6 * max(1.0, abs(theta[j]))
        model.residuals(tp) - r0
    finite = time.perf_counter() - t0
    return {"jacobian_analytic_s": analytic, "jacobian_finite_difference_s": finite,
            "n_parameters": len(theta)}


def _relaxation_timings(records, st, start) -> dict:
    """The same fit (no reduction) with the early weighted solves capped (the default) and
    converged every time (the baseline, as before the cap)."""
    import sysid.identify.time_domain as td

    out = {}
    default = td.EARLY_NFEV
    try:
        for label, cap in (("uncapped", 10**9), ("capped", default)):
            td.EARLY_NFEV = cap
            t0 = time.perf_counter()
            result = identify_time_domain(records, st, start=start, reduce=False)
            out[f"relaxation_{label}_s"] = time.perf_counter() - t0
            out[f"relaxation_{label}_cost_evaluations"] = result.n_cost_evaluations
    finally:
        td.EARLY_NFEV = default
    out["relaxation_speedup_ratio"] = out["relaxation_uncapped_s"] / out["relaxation_capped_s"]
    return out


def test_bench_identify_time_domain(benchmark):
    st = truth_structure(extra_free=SPURIOUS)
    records = add_noise(multistep_records(noise=0.0, dt=0.01, duration=15.0), 1.0, seed=3)
    rng = np.random.default_rng(5)
    start = st.theta0 * (1.0 + rng.uniform(-0.5, 0.5, st.theta0.size))
    start[[st.free_names.index(n) for n in SPURIOUS]] = 0.0

    def run():
        t0 = time.perf_counter()
        result = identify_time_domain(records, st, start=start, reduce=True)
        return result, time.perf_counter() - t0

    result, elapsed = benchmark.pedantic(run, rounds=1, iterations=1)
    fr = analytic_response(st, noise=0.05, seed=3)
    t0 = time.perf_counter()
    freq = identify_frequency_domain(fr, st, start=start, reduce=True)
    elapsed_freq = time.perf_counter() - t0
    info = benchmark.extra_info
    info["time_domain_s"] = elapsed
    info["frequency_domain_s"] = elapsed_freq
    info["samples"] = int(sum(r.sizes["time"] for r in records))
    info["time_domain_jacobian_evaluations"] = result.n_jacobian_evaluations
    info["time_domain_cost_evaluations"] = result.n_cost_evaluations
    info["time_domain_outer_iterations"] = result.n_outer_iterations
    info["reduction_steps"] = len(result.reduction.steps)
    info.update(_jacobian_timings(records, truth_structure()))
    info.update(_relaxation_timings(records, truth_structure(), truth_structure().theta0 * 0.7))
    print(f"\ntime domain {elapsed:.2f} s, frequency domain {elapsed_freq:.2f} s, {info}")
    assert set(result.reduction.removed) == set(SPURIOUS)
    assert set(result.structure.free_names) == set(truth_values())
    assert set(freq.structure.free_names) == set(truth_values())
    # Target < 20 s on one core (measured ~10 s with one BLAS thread); reported in
    # extra_info beside the frequency-domain time, not asserted.
