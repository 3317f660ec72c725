"""Peak resident memory of the whole hover study (`sysid run hover`), against the interpreter
with the package imported, measured in the same run (a ratio, not an absolute number).

The study runs in a fresh interpreter through the CLI's own entry point; that process
reports its own peak (the kernel's VmHWM: ``getrusage``'s ``ru_maxrss`` of a process
started by ``subprocess`` also counts the RSS of the process that started it, which Linux
keeps across the exec, and reported the pytest process's 642 MiB for both the study and
the baseline) and the largest of its child processes (the report's figure workers,
RUSAGE_CHILDREN: an upper bound, for the same reason). Reported in
``benchmark.extra_info``, not asserted (tests/test_batch_memory.py asserts that a batch's driver does not grow with the
number of conditions). The study takes minutes: it runs only with --benchmark-enable.
"""

import json
import subprocess
import sys
import textwrap
import time

import pytest

PEAK = textwrap.dedent("""
    import json, resource, sys
    {body}
    with open("/proc/self/status") as f:  # VmHWM: the peak of this process's own memory
        hwm = next(int(line.split()[1]) for line in f if line.startswith("VmHWM:"))
    print(json.dumps({{"self_kib": hwm,
                      "children_kib": resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss,
                      "status": status}}))
""")
BASELINE = "import sysid.cli, sysid.pipeline.study\nstatus = 0"
STUDY = "from sysid.cli import main\nstatus = main(['run', 'hover', '-o', sys.argv[1]])"


def _peak(body: str, *args) -> dict:
    proc = subprocess.run([sys.executable, "-c", PEAK.format(body=body), *args],
                          capture_output=True, text=True, timeout=3600)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])


@pytest.mark.fmu
def test_peak_memory_of_the_hover_study(benchmark, tmp_path, truth_fmu):
    if benchmark.disabled:
        pytest.skip("the whole hover study takes minutes: only with --benchmark-enable")
    baseline = _peak(BASELINE)
    timing = {}

    def study():
        start = time.perf_counter()
        result = _peak(STUDY, str(tmp_path / "hover"))
        timing["wall_s"] = time.perf_counter() - start
        return result

    peak = benchmark.pedantic(study, rounds=1, iterations=1)
    assert peak["status"] == 0
    mib = 1024.0
    benchmark.extra_info.update(
        peak_rss_MiB=round(peak["self_kib"] / mib, 1),
        peak_rss_children_MiB=round(peak["children_kib"] / mib, 1),
        baseline_rss_MiB=round(baseline["self_kib"] / mib, 1),
        peak_over_baseline=round(peak["self_kib"] / baseline["self_kib"], 2),
        wall_s=round(timing["wall_s"], 1))
    print(f"\nsysid run hover: peak RSS {peak['self_kib'] / mib:.0f} MiB "
          f"({peak['self_kib'] / baseline['self_kib']:.1f}x the {baseline['self_kib'] / mib:.0f}"
          f" MiB of the interpreter with sysid imported); largest child "
          f"{peak['children_kib'] / mib:.0f} MiB; {timing['wall_s']:.0f} s")
