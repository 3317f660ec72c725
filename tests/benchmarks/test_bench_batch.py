"""Batch speed-up: the same conditions on a 1-worker and a 2-worker LocalCluster.

Four reduced (``quick``) 80-kt conditions (seeds 1-4; the issue's goal 3 is stated for four)
run from an empty folder each time, alternating 1, 2, 1, 2 workers in one process so that
both see the same machine load; ``benchmark.extra_info`` reports every wall time, the
workers' CPU time (the cluster's processes are children of this one), the load average
before each run and the ratio of the mean wall times (goal >= 1.8 on 2 cores). With
SYSID_EXHAUSTIVE=1 the issue's six full-size conditions run instead. Timing is reported,
not asserted (the machine may be shared); the estimates of the two runs are compared.
"""

import os
import resource
import time

import numpy as np
import pytest

from sysid.pipeline.batch import Condition, conditions, run_batch


def _conditions():
    if os.environ.get("SYSID_EXHAUSTIVE") == "1":
        return conditions([0, 20, 40, 60, 80, 100])
    # Four equal-sized conditions (same airspeed, four seeds): with two workers the ideal
    # speed-up is 2.0 and no single condition sets the wall time; also a Monte Carlo summary.
    return [Condition(80.0, seed=s, quick=True) for s in (1, 2, 3, 4)]


def _children_cpu_s() -> float:
    usage = resource.getrusage(resource.RUSAGE_CHILDREN)
    return usage.ru_utime + usage.ru_stime


@pytest.mark.fmu
def test_batch_speedup_two_workers(benchmark, tmp_path, truth_fmu):
    if benchmark.disabled:
        # Four studies on one worker and on two, twice, take many minutes; the default run
        # covers the batch itself in tests/test_batch.py (reduced cluster run, failing tasks).
        pytest.skip("timing comparison only with --benchmark-enable")
    cs = _conditions()
    runs = []

    def run(workers):
        load = os.getloadavg()[0]
        cpu, start = _children_cpu_s(), time.perf_counter()
        result = run_batch(cs, tmp_path / f"run{len(runs)}_w{workers}", n_workers=workers,
                           quiet=True)
        runs.append({"workers": workers, "wall_s": round(time.perf_counter() - start, 1),
                     "workers_cpu_s": round(_children_cpu_s() - cpu, 1),
                     "load_before": round(load, 1), "result": result})
        return result

    run(1)
    benchmark.pedantic(run, args=(2,), rounds=1, iterations=1)
    run(1)
    run(2)
    wall = {w: float(np.mean([r["wall_s"] for r in runs if r["workers"] == w])) for w in (1, 2)}
    benchmark.extra_info.update(
        conditions=[c.name for c in cs],
        runs=[{k: v for k, v in r.items() if k != "result"} for r in runs],
        speedup=round(wall[1] / wall[2], 2),
        failed=[[f["name"] for f in r["result"].failures] for r in runs])
    print(benchmark.extra_info)
    # Same work in every run: the same conditions succeed with the same estimates.
    first = runs[0]["result"].dataset
    for r in runs[1:]:
        ds = r["result"].dataset
        assert list(ds.status.values) == list(first.status.values)
        np.testing.assert_allclose(ds["value"].values, first["value"].values, rtol=1e-9)
