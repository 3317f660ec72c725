"""Peak memory of a batch's driver does not grow with the number of conditions.

The driver (the process calling run_batch) keeps per condition only a record and a small
summary; the studies run in the worker processes. Each batch runs in a fresh interpreter
(peak RSS only ever rises within a process), once with 1 and once with 8 conditions of the
smallest kind the batch accepts: a quick condition whose task fails at once (injected
SimulationDiverged), so the test measures the driver's own bookkeeping (futures, records,
combine, calibration, plots, netCDF) and not the studies. The bound is relative: the growth
of the peak over the interpreter's RSS before the batch may rise by at most 5 % of the
1-condition growth per further condition (measured: 46.3 MiB with 1 and with 8, against
the bound's 1.35; holding each condition's campaign in the driver would multiply it by
about 8). The peak is the kernel's VmHWM of the driver's own memory:
``getrusage``'s ``ru_maxrss`` of a process started by ``subprocess`` also counts the RSS
of the process that started it (Linux keeps it across the exec), here the pytest worker's,
which can hide the batch's growth entirely.
"""

import json
import subprocess
import sys
import textwrap

import pytest

DRIVER = textwrap.dedent("""
    import json, sys
    import distributed  # imported before the baseline: its import is not the batch's memory
    from sysid.pipeline.batch import Condition, run_batch

    def status_kib(field):  # VmRSS now, VmHWM the peak of this process's own memory
        with open("/proc/self/status") as f:
            return next(int(line.split()[1]) for line in f if line.startswith(field + ":"))

    n, out = int(sys.argv[1]), sys.argv[2]
    conditions = [Condition(20.0, seed=s, quick=True) for s in range(1, n + 1)]
    before = status_kib("VmRSS")
    result = run_batch(conditions, out, n_workers=1, quiet=True,
                       inject_failure={c.name: "SimulationDiverged" for c in conditions})
    peak = status_kib("VmHWM")
    print(json.dumps({"before_kib": before, "peak_kib": peak, "after_kib": status_kib("VmRSS"),
                      "failed": len(result.failures)}))
""")


def _driver(n, folder):
    proc = subprocess.run([sys.executable, "-c", DRIVER, str(n), str(folder)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.fmu
def test_driver_peak_memory_does_not_grow_with_conditions(tmp_path, truth_fmu):
    one = _driver(1, tmp_path / "one")
    eight = _driver(8, tmp_path / "eight")
    assert one["failed"] == 1 and eight["failed"] == 8  # every task ran and reported back
    growth_one = one["peak_kib"] - one["before_kib"]
    growth_eight = eight["peak_kib"] - eight["before_kib"]
    print(f"\ndriver peak RSS growth: 1 condition {growth_one / 1024:.1f} MiB, "
          f"8 conditions {growth_eight / 1024:.1f} MiB")
    assert growth_one > 0
    per_condition = 0.05  # of the first condition's growth
    assert growth_eight <= (1 + 7 * per_condition) * growth_one, (growth_one, growth_eight)
