"""Running FMUs and SSP packages in libcosim (libcosimpy), an FMI 2.0 co-simulation importer
independent of fmpy. Times in libcosim are integer nanoseconds."""

from __future__ import annotations

import numpy as np

NS = 1_000_000_000


def _quiet():
    from libcosimpy.CosimLogging import CosimLogLevel, log_output_level

    log_output_level(CosimLogLevel.ERROR)


def _record(execution, observer, names: dict[str, list[str]]):
    from libcosimpy.CosimEnums import CosimVariableType

    index = {s.name.decode(): s.index for s in execution.slave_infos()}
    refs = {}
    for slave, outputs in names.items():
        variables = {v.name.decode(): v.reference for v in
                     execution.slave_variables(index[slave])}
        for name in outputs:
            refs[(slave, name)] = (index[slave], variables[name])
            observer.start_time_series(index[slave], variables[name], CosimVariableType.REAL)
    return refs


def _samples(observer, refs, n: int) -> dict:
    out = {}
    for key, (slave, ref) in refs.items():
        times, _, values = observer.time_series_real_samples(slave, ref, from_step=0,
                                                             sample_count=n)
        out[key] = (np.asarray(times, dtype=float) / NS, np.asarray(values, dtype=float))
    return out


def run_ssp(path, names: dict[str, list[str]], stop_time: float, step: float) -> dict:
    """Run an SSP package to ``stop_time``; ``{(component, variable): (time, values)}``."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimObserver import CosimObserver

    _quiet()
    execution = CosimExecution.from_ssp_file(str(path))
    observer = CosimObserver.create_time_series(buffer_size=int(stop_time / step) + 10)
    execution.add_observer(observer)
    refs = _record(execution, observer, names)
    assert execution.simulate_until(int(round(stop_time * NS))), "libcosim run failed"
    return _samples(observer, refs, int(round(stop_time / step)) + 10)


def run_fmu(path, outputs: list[str], inputs: dict[str, float], stop_time: float,
            step: float) -> tuple[bool, dict]:
    """One FMU alone with constant inputs; (completed, {name: (time, values)})."""
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimManipulator import CosimManipulator
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave

    _quiet()
    execution = CosimExecution.from_step_size(int(round(step * NS)))
    slave = CosimLocalSlave(fmu_path=str(path), instance_name="model")
    index = execution.add_local_slave(slave)
    variables = {v.name.decode(): v.reference for v in execution.slave_variables(index)}
    for name, value in inputs.items():
        execution.real_initial_value(index, variables[name], value)
    observer = CosimObserver.create_time_series(buffer_size=int(stop_time / step) + 10)
    execution.add_observer(observer)
    refs = _record(execution, observer, {"model": outputs})
    ok = execution.simulate_until(int(round(stop_time * NS)))
    samples = _samples(observer, refs, int(round(stop_time / step)) + 10)
    return ok, {name: samples[("model", name)] for name in outputs}
