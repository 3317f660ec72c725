"""Export speed and the exported FMU's co-simulation speed (one core).

- export and build: model Dataset -> compiled, packaged FMU (code generation + C compiler);
- real-time factor of the exported 6-DoF model with two delays in co-simulation, stepped at
  100 Hz from Python (fmpy's FMU2Slave: setReal + doStep + getReal per step) and in one long
  step (exact zero-order hold: one matrix exponential, then one update).

The tests run once as plain tests by default (--benchmark-disable); with benchmarks enabled
pytest-benchmark times them and the numbers are in ``benchmark.extra_info``.
"""

import shutil
import time

import pytest

from sysid.fmi.export import export_fmu
from sysid.models import six_dof_structure

SIM_SECONDS = 20.0


def _model():
    values = {"X_u": -0.02, "M_q": -1.2, "L_p": -3.0, "Z_w": -0.3, "N_r": -0.5, "Y_v": -0.05,
              "M_lon": -0.9, "L_lat": 1.5, "L_lon": 0.3, "M_lat": 0.2, "Z_col": -0.8,
              "N_ped": 0.7, "tau_L_lon": 0.07, "tau_M_lat": 0.11}
    s = six_dof_structure(theta0=3.0, phi0=-2.0, values=values,
                          delays={"tau_L_lon": "p,lon", "tau_M_lat": "q,lat"})
    return s.to_dataset(attrs={"method": "frequency_domain"})


@pytest.fixture(scope="module")
def slave(tmp_path_factory):
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    fmu = export_fmu(_model(), tmp_path_factory.mktemp("bench") / "model.fmu")
    md = read_model_description(str(fmu))
    unzip = extract(str(fmu))
    s = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                  modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    s.instantiate()
    vr = {v.name: v.valueReference for v in md.modelVariables}
    yield s, [vr[c] for c in ("lon", "lat", "col", "ped")], [vr[c] for c in ("p", "q", "r")]
    s.freeInstance()
    shutil.rmtree(unzip, ignore_errors=True)


def _start(s):
    s.reset()
    s.setupExperiment(startTime=0.0)
    s.enterInitializationMode()
    s.exitInitializationMode()


def _stepped(s, vr_in, vr_out):
    _start(s)
    start = time.perf_counter()
    t = 0.0
    for k in range(int(SIM_SECONDS * 100)):
        s.setReal(vr_in, [50.0 + (k % 50 == 0), 50.0, 50.0, 50.0])
        s.doStep(t, 0.01)
        s.getReal(vr_out)
        t += 0.01
    return SIM_SECONDS / (time.perf_counter() - start)


def _one_step(s, vr_in, vr_out):
    _start(s)
    start = time.perf_counter()
    s.setReal(vr_in, [51.0, 50.0, 50.0, 50.0])
    s.doStep(0.0, SIM_SECONDS)
    s.getReal(vr_out)
    return SIM_SECONDS / (time.perf_counter() - start)


def test_export_and_build_time(benchmark, tmp_path):
    ds = _model()
    times = []

    def run():
        start = time.perf_counter()
        export_fmu(ds, tmp_path / "m.fmu")
        times.append(time.perf_counter() - start)

    benchmark.pedantic(run, rounds=3, iterations=1)
    benchmark.extra_info["export_and_build_s"] = min(times)
    print(f"\nexport + build of a 9-state model with 2 delays: {min(times):.2f} s")


def test_real_time_factor_stepped_at_100hz(benchmark, slave):
    factors = []
    benchmark.pedantic(lambda: factors.append(_stepped(*slave)), rounds=3, iterations=1)
    rtf = max(factors)
    benchmark.extra_info["real_time_factor"] = rtf
    print(f"\nexported FMU stepped at 100 Hz from Python: {rtf:.0f}x real time")


def test_real_time_factor_one_step(benchmark, slave):
    factors = []
    benchmark.pedantic(lambda: factors.append(_one_step(*slave)), rounds=3, iterations=1)
    rtf = max(factors)
    benchmark.extra_info["real_time_factor"] = rtf
    print(f"\nexported FMU in one {SIM_SECONDS:g} s step: {rtf:.0f}x real time")
