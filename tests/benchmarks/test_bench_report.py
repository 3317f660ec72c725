"""Benchmark: the HTML report of a synthetic hover campaign against drawing its figures.

The campaign is tests/test_report.py's (13 pairs, 4 sweeps, 2 verification manoeuvres, 3
models). Baseline, measured in the same run: one two-panel Bode figure of 200 points drawn
and encoded as PNG at the report's resolution. The figure of merit is the report's time over
(number of figures x one baseline figure): about 1 when the report costs what its figures
cost drawn one after the other, below 1 with figure worker processes, above 1 for overhead
(sections, tables, HTML). Printed and stored in ``benchmark.extra_info``; timing is not
asserted (the tests run once as plain tests by default, --benchmark-disable).
"""

import sys
import time
from pathlib import Path

import numpy as np
from matplotlib.backends.backend_agg import FigureCanvasAgg
from matplotlib.figure import Figure

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
from test_report import synthetic_campaign  # noqa: E402

from sysid.report import write_report  # noqa: E402
from sysid.report.plots import DPI, png_bytes  # noqa: E402


def _one_bode_figure() -> float:
    """Seconds to draw and encode one two-panel Bode figure (the baseline)."""
    omega = np.logspace(-1, 1.5, 200)
    h = 1.0 / (1j * omega * (1j * omega / 4.0 + 1.0))
    start = time.perf_counter()
    fig = Figure(figsize=(6.4, 4.8), dpi=DPI)
    FigureCanvasAgg(fig)
    mag, phase = fig.subplots(2, 1, sharex=True)
    mag.semilogx(omega, 20 * np.log10(np.abs(h)))
    phase.semilogx(omega, np.degrees(np.angle(h)))
    mag.set_ylabel("dB")
    phase.set_ylabel("deg")
    phase.set_xlabel("rad/s")
    png_bytes(fig)
    return time.perf_counter() - start


def test_bench_report_against_its_figures(benchmark, tmp_path):
    tree = synthetic_campaign()["tree"]
    baseline = min(_one_bode_figure() for _ in range(3))
    runs = iter(range(10))

    def render():
        return write_report(tree, tmp_path / f"out{next(runs)}", quiet=True)

    start = time.perf_counter()
    path = benchmark.pedantic(render, rounds=1, iterations=1)
    elapsed = time.perf_counter() - start
    n_figures = len(list((path.parent / "figures").iterdir()))
    assert path.is_file() and n_figures > 0
    ratio = elapsed / (n_figures * baseline)
    benchmark.extra_info.update({"report_s": elapsed, "figures": n_figures,
                                 "one_figure_s": baseline, "report_over_figures": ratio})
    print(f"\nreport {elapsed:.2f} s, {n_figures} figures, one Bode figure {baseline:.3f} s: "
          f"{ratio:.2f}x the figures drawn one after the other")
