"""Co-simulation speed of the truth helicopter, as real-time factors (one core).

Targets: >= 200x real time stepped from Python at 100 Hz, >= 2000x in one long step. The
tests run once as plain tests by default (--benchmark-disable); with benchmarks enabled
pytest-benchmark times them and the factors are in ``benchmark.extra_info``.
"""

import time

import pytest

pytestmark = pytest.mark.fmu

SIM_SECONDS = 20.0


@pytest.fixture(scope="module")
def sim(truth_fmu):
    from sysid.truth import CoSimulation

    with CoSimulation(truth_fmu) as s:
        yield s


def _stepped(sim, trim):
    sim.reset(trim)
    controls = sim.trim_controls.copy()
    start = time.perf_counter()
    for _ in range(int(SIM_SECONDS * 100)):
        sim.step(controls, dt=0.01)
    return SIM_SECONDS / (time.perf_counter() - start)


def _one_step(sim, trim):
    sim.reset(trim)
    start = time.perf_counter()
    sim.step(sim.trim_controls, dt=SIM_SECONDS)
    return SIM_SECONDS / (time.perf_counter() - start)


def test_real_time_factor_stepped_at_100hz(benchmark, sim, hover_trim):
    factors = []
    benchmark.pedantic(lambda: factors.append(_stepped(sim, hover_trim)), rounds=3,
                       iterations=1)
    rtf = max(factors)
    benchmark.extra_info["real_time_factor"] = rtf
    print(f"\nco-simulation stepped at 100 Hz from Python: {rtf:.0f}x real time (target 200x)")


def test_real_time_factor_one_step(benchmark, sim, hover_trim):
    factors = []
    benchmark.pedantic(lambda: factors.append(_one_step(sim, hover_trim)), rounds=3,
                       iterations=1)
    rtf = max(factors)
    benchmark.extra_info["real_time_factor"] = rtf
    print(f"\nco-simulation in one {SIM_SECONDS:g} s step: {rtf:.0f}x real time (target 2000x)")
