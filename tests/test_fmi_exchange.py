"""FMI 3.0 export, exact directional derivatives, the growing delay history and the SSP study,
checked in fmpy and in libcosim (libcosimpy), an importer independent of fmpy.

Independent truths: the FMI 2.0 export (tested against sysid.models.simulate in
test_export.py), the model's own A, B, C, D converted with sysid.core.units, fmpy's and
libcosim's runs of the same FMUs, the truth FMU's co-simulation through sysid.truth.

The "hover models" here are hover_6dof-sized models at the truth's hover linearisation with
identified-like cyclic and pedal delays (the identified models of a study have the same
structure and differ only in numbers; running the study itself takes minutes).
"""

import zipfile

import numpy as np
import pytest
import xarray as xr

from sysid.assess.exported import (directional_jacobian, roundtrip_error, simulate_exported,
                                   verification_inputs)
from sysid.core.units import CHANNELS, conversion_factor
from sysid.fmi.export import export_fmu
from sysid.fmi.signal import export_signal_fmu

try:  # libcosimpy is in the test extras; without it only the libcosim checks are skipped
    import libcosimpy  # noqa: F401
    HAVE_LIBCOSIM = True
except ImportError:  # pragma: no cover
    HAVE_LIBCOSIM = False
needs_libcosim = pytest.mark.skipif(
    not HAVE_LIBCOSIM, reason="libcosimpy not installed (pip install -e '.[test]' installs it)")

#: identified-like delays (s): cyclic and pedal (the hover study finds 71-96 ms and 45 ms)
DELAYS = {"frequency_domain": {"lon": 0.0713, "lat": 0.0962, "ped": 0.045},
          "time_domain": {"lon": 0.08, "lat": 0.0871, "ped": 0.05}}


def _with_delays(model: xr.Dataset, delays: dict, method: str) -> xr.Dataset:
    out = model.copy(deep=True)
    tau = xr.zeros_like(out["B"])
    for inp, value in delays.items():
        tau.loc[{"input": inp}] = xr.where(out["B"].sel(input=inp) != 0, value, 0.0)
    out["delay"] = tau
    out.attrs["method"] = method
    return out


@pytest.fixture(scope="module")
def hover_models(truth_fmu, hover_trim):
    from sysid.truth import linearize

    lin = linearize(hover_trim).quasi_steady
    return {m: _with_delays(lin, d, m) for m, d in DELAYS.items()}


@pytest.fixture(scope="module")
def exported(hover_models, tmp_path_factory):
    folder = tmp_path_factory.mktemp("fmi3")
    return {(m, v): export_fmu(ds, folder / f"{m}_fmi{v}.fmu", fmi_version=v)
            for m, ds in hover_models.items() for v in (2, 3)}


def _si(name: str) -> float:
    """FMU (SI) unit per analysis unit of a channel."""
    return conversion_factor(CHANNELS[name].unit, CHANNELS[name].si_unit) if name in CHANNELS \
        else 1.0


# ------------------------------------------------------------------------------------------
# FMI 3.0 export


@pytest.mark.fmu
def test_fmi3_export_validates_and_carries_its_own_build_description(exported):
    from fmpy.validation import validate_fmu

    for (method, version), fmu in exported.items():
        assert validate_fmu(str(fmu)) == [], (method, version)
        with zipfile.ZipFile(fmu) as zf:
            names = zf.namelist()
            md = zf.read("modelDescription.xml").decode()
            build = zf.read("sources/buildDescription.xml").decode() if version == 3 else None
        assert f'fmiVersion="{version}.0"' in md
        assert "<ModelExchange" in md and "<CoSimulation" in md
        if version == 3:
            assert 'fmiBuildDescription fmiVersion="3.0"' in build
            for f in ("fmu_core.c", "fmi3_functions.c", "model.c"):
                assert f'<SourceFile name="{f}"/>' in build and f"sources/{f}" in names
            assert any(n.startswith("binaries/x86_64-") or n.startswith("binaries/aarch64-")
                       or "-" in n.split("/")[1] for n in names if n.startswith("binaries/"))
        else:
            assert "sources/buildDescription.xml" not in names


@pytest.mark.fmu
@pytest.mark.parametrize("maneuver", ["3211_lon", "2311_lon", "2311_lat"])
def test_fmi3_runs_match_the_fmi2_export(hover_models, exported, maneuver):
    # Same C model behind both versions: co-simulation to 1e-9 and model exchange to 1e-6
    # of the peak response (CVode runs both, tolerance 1e-10); measured 0 and ~1e-13.
    inputs = verification_inputs()[maneuver]
    for method in hover_models:
        for mode, tol in (("cs", 1e-9), ("me", 1e-6)):
            a = simulate_exported(exported[(method, 2)], inputs, mode=mode)
            b = simulate_exported(exported[(method, 3)], inputs, mode=mode)
            for name in ("u", "w", "p", "q", "r", "phi", "theta"):
                trim = float(a[name].values[0])
                peak = np.max(np.abs(a[name].values - trim))
                assert np.max(np.abs(a[name].values - b[name].values)) <= tol * peak, \
                    (method, mode, name)


@pytest.mark.fmu
def test_fmi3_export_matches_the_reference_simulation(hover_models, exported):
    # against sysid.models.simulate directly (as test_export.py does for FMI 2.0)
    inputs = verification_inputs()["2311_lat"]
    for method, ds in hover_models.items():
        assert roundtrip_error(ds, exported[(method, 3)], inputs, mode="cs"
                               ).attrs["max_relative_error"] < 1e-9
        assert roundtrip_error(ds, exported[(method, 3)], inputs, mode="me"
                               ).attrs["max_relative_error"] < 1e-5


@pytest.mark.fmu
def test_truth_fmu_builds_as_fmi3_and_runs_like_fmi2(truth_fmu, hover_trim):
    from fmpy import simulate_fmu
    from fmpy.validation import validate_fmu
    from sysid.truth import build_fmu

    fmu3 = build_fmu(fmi_version=3)
    assert validate_fmu(str(fmu3)) == []
    start = {**hover_trim.parameters, **hover_trim.start_values()}
    start["lon"] += 1.0  # a step on the longitudinal cyclic from trim
    runs = [simulate_fmu(str(f), fmi_type="CoSimulation", stop_time=2.0, output_interval=0.01,
                         start_values=start, output=["p", "q", "theta", "u"])
            for f in (truth_fmu, fmu3)]
    for name in ("p", "q", "theta", "u"):
        assert np.array_equal(runs[0][name], runs[1][name])
    assert np.max(np.abs(runs[0]["q"])) > 1e-3  # it moved


# ------------------------------------------------------------------------------------------
# directional derivatives


@pytest.mark.fmu
def test_directional_derivatives_equal_the_model_matrices(hover_models, exported):
    # A, B, C, D of the model (analysis units) converted to the FMU's SI units by the unit
    # table: A_si = S_x A S_x^-1, B_si = S_x B (inputs stay %), C_si = S_y C S_x^-1,
    # D_si = S_y D. Delayed B entries are zero: der(x)(t) depends on u(t - tau), not on the
    # current input (fmus/linear/README.md).
    for (method, version), fmu in exported.items():
        ds = hover_models[method]
        J = directional_jacobian(fmu)
        states = [str(s) for s in ds.state.values]
        inputs = [str(i) for i in ds.input.values]
        outputs = [str(o) for o in ds.output.values]
        sx = np.array([_si(s) for s in states])
        sy = np.array([_si(o) for o in outputs])
        A = ds.A.sel(state_dot=states, state=states).values
        B = ds.B.sel(state_dot=states, input=inputs).values
        B = np.where(ds.delay.sel(state_dot=states, input=inputs).values > 0, 0.0, B)
        C = ds.C.sel(output=outputs, state=states).values
        D = ds.D.sel(output=outputs, input=inputs).values
        xs = [f"x_{s}" for s in states]
        expected = {"A": sx[:, None] * A / sx[None, :], "B": sx[:, None] * B,
                    "C": sy[:, None] * C / sx[None, :], "D": sy[:, None] * D}
        got = {"A": J.A.sel(state_dot=xs, state=xs).values,
               "B": J.B.sel(state_dot=xs, input=inputs).values,
               "C": J.C.sel(output=outputs, state=xs).values,
               "D": J.D.sel(output=outputs, input=inputs).values}
        for key in expected:
            scale = max(1.0, np.max(np.abs(expected[key])))
            assert np.max(np.abs(got[key] - expected[key])) <= 1e-12 * scale, \
                (method, version, key)
        assert np.count_nonzero(expected["B"]) > 0


@pytest.mark.fmu
def test_model_description_declares_directional_derivatives(exported, truth_fmu):
    for (_, version), fmu in exported.items():
        md = zipfile.ZipFile(fmu).read("modelDescription.xml").decode()
        flag = "providesDirectionalDerivative" + ("s" if version == 3 else "")
        assert f'{flag}="true"' in md
    # the truth FMU has no exact derivatives of its physics (fmus/helicopter/README.md)
    md = zipfile.ZipFile(truth_fmu).read("modelDescription.xml").decode()
    assert 'providesDirectionalDerivative="false"' in md


# ------------------------------------------------------------------------------------------
# delay history: 1e-4 s steps over 10 s with 0.2 s delays


@pytest.fixture(scope="module")
def long_delay(hover_models, tmp_path_factory):
    ds = _with_delays(hover_models["frequency_domain"], {"lon": 0.2, "lat": 0.2, "ped": 0.2},
                      "frequency_domain")
    return ds, export_fmu(ds, tmp_path_factory.mktemp("delay") / "delay02.fmu")


def _fine_cs_run(fmu, lon_of_t, h=1e-4, stop=10.0):
    """fmpy FMU2Slave stepped at h with lon set before each step; q after each step."""
    import shutil
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    unzip = extract(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip, instanceName="fine",
                      modelIdentifier=md.coSimulation.modelIdentifier)
    n = int(round(stop / h))
    q = np.empty(n)
    try:
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        for k in range(n):
            slave.setReal([vr["lon"]], [lon_of_t(k * h)])
            slave.doStep(k * h, h)
            q[k] = slave.getReal([vr["q"]])[0]
        slave.terminate()
    finally:
        slave.freeInstance()
        shutil.rmtree(unzip, ignore_errors=True)
    return q


def _lon_step(ds):
    trim = float(ds.trim_input.sel(input="lon"))
    return lambda t: trim + (1.0 if t >= 1.0 - 1e-9 else 0.0)


@pytest.fixture(scope="module")
def fine_fmpy_run(long_delay):
    ds, fmu = long_delay
    return _fine_cs_run(fmu, _lon_step(ds))


@pytest.mark.fmu
def test_fine_steps_with_long_delays_run_through_in_fmpy(fine_fmpy_run):
    # 100000 steps of 1e-4 s: the history holds 2000 samples inside the delay (the FMU
    # used to stop after 256). A lon step at 1 s reaches q at 1.2 s, not before.
    q = fine_fmpy_run
    t = (np.arange(q.size) + 1) * 1e-4
    q0 = q[0]
    assert np.all(q[t <= 1.2 - 1e-9] == q0)
    assert abs(q[-1] - q0) > 1e-3


@pytest.mark.fmu
def test_fine_model_exchange_input_updates_with_long_delays_in_fmpy(long_delay):
    # model exchange: an input update every 1e-4 s for 2 s (20000 samples in the history)
    ds, fmu = long_delay
    t = np.arange(0, 20001) * 1e-4
    inputs = xr.Dataset({"lon": ("time", np.where(t >= 0.5, 1.0, 0.0))}, coords={"time": t})
    got = simulate_exported(fmu, inputs, mode="me", rtol=1e-8)
    q = got["q"].values
    assert np.allclose(q[t < 0.7 - 1e-6], q[0], atol=1e-12, rtol=0)
    assert abs(q[-1] - q[0]) > 1e-3


@pytest.mark.fmu
@needs_libcosim
def test_fine_steps_with_long_delays_run_through_in_libcosim(long_delay, fine_fmpy_run,
                                                             tmp_path):
    # libcosim steps the FMU 100000 times at 1e-4 s, fed by a signal FMU (a lon step at 1 s
    # sampled at 0.01 s); it agrees with fmpy's run of the same FMU to rounding
    from libcosim_runner import run_ssp
    from sysid.fmi.ssp import SspComponent, write_ssp

    ds, fmu = long_delay
    trim = float(ds.trim_input.sel(input="lon"))
    ts = np.arange(0, 1001) * 0.01
    signal = xr.Dataset({"lon": ("time", trim + np.where(ts >= 1.0 - 1e-9, 1.0, 0.0))},
                        coords={"time": ts})
    sig = export_signal_fmu(signal, tmp_path / "step.fmu", model_name="step")
    ssp = write_ssp(tmp_path / "fine.ssp", name="fine",
                    components=[SspComponent("signal", sig, outputs=("lon",)),
                                SspComponent("model", fmu, inputs=("lon",))],
                    connections=[("signal", "lon", "model", "lon")], stop_time=10.0,
                    step_size=1e-4)
    res = run_ssp(ssp, {"model": ["q"]}, 10.0, 1e-4)
    t, q = res[("model", "q")]
    assert t[-1] >= 10.0 - 1e-4 - 1e-9  # the whole run was stepped and recorded
    ref = fine_fmpy_run  # the same lon step at 1 s; ref[k - 1] is q after the step to k h
    k = np.rint(t / 1e-4).astype(int)
    later = k >= 1
    assert later.sum() >= 99990
    assert np.max(np.abs(q[later] - ref[k[later] - 1])) <= 1e-12 * np.max(np.abs(ref - ref[0]))


@pytest.mark.fmu
def test_terminate_is_accepted_after_an_error(long_delay):
    # a refused call puts the FMU in its error state; terminate must still be accepted
    import shutil
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import (FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE,
                           fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE, calloc,
                           free)

    _, fmu = long_delay
    md = read_model_description(str(fmu))
    unzip = extract(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip, instanceName="err",
                      modelIdentifier=md.coSimulation.modelIdentifier)
    # Own callbacks, kept alive here: fmpy's shared default logger goes through a native
    # proxy that crashed this process once on CI when the FMU logged its error.
    messages = []
    callbacks = fmi2CallbackFunctions()
    callbacks.logger = fmi2CallbackLoggerTYPE(
        lambda env, name, status, category, message: messages.append(message))
    callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
    callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
    try:
        slave.instantiate(callbacks=callbacks)
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        with pytest.raises(Exception, match="status 3"):
            slave.doStep(5.0, 0.01)  # wrong communication point: error state
        assert slave.fmi2Terminate(slave.component) == 0  # fmi2OK
        assert any(b"communication point" in m for m in messages), messages
    finally:
        slave.freeInstance()
        shutil.rmtree(unzip, ignore_errors=True)


# ------------------------------------------------------------------------------------------
# the SSP study


@pytest.fixture(scope="module")
def study_ssp(hover_models, truth_fmu, tmp_path_factory):
    from sysid.data.netcdf import write_campaign
    from sysid.assess.exchange import export_study_ssp

    folder = tmp_path_factory.mktemp("ssp")
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"airspeed_kt": 0.0}),
                                  **{f"/models/{m}": ds for m, ds in hover_models.items()}})
    write_campaign(tree, folder / "campaign.nc")
    return export_study_ssp(folder / "campaign.nc", folder / "study.ssp",
                            truth_fmu=truth_fmu), folder


@pytest.mark.fmu
def test_ssp_package_layout(study_ssp):
    path, _ = study_ssp
    with zipfile.ZipFile(path) as zf:
        names = set(zf.namelist())
        ssd = zf.read("SystemStructure.ssd").decode()
    assert "SystemStructure.ssd" in names
    assert {"resources/input_2311.fmu", "resources/frequency_domain.fmu",
            "resources/time_domain.fmu"} <= names
    assert any(n.startswith("resources/helicopter") for n in names)
    assert 'version="1.0"' in ssd and ssd.count("<ssd:Connection ") == 12


@pytest.mark.fmu
@needs_libcosim
def test_ssp_runs_in_libcosim_like_the_fmpy_runs(study_ssp, hover_trim):
    # libcosim loads the package and runs it; every output equals sysid's own fmpy
    # co-simulation of the same FMUs with the same 2311 (truth from trim) to 1e-12.
    from libcosim_runner import run_ssp
    from sysid.assess.exchange import study_signal
    from sysid.truth import simulate as simulate_truth

    path, folder = study_ssp
    with zipfile.ZipFile(path) as zf:
        zf.extractall(folder / "unzipped")
    res_dir = folder / "unzipped" / "resources"
    signal = study_signal(hover_trim)
    t = signal["time"].values
    stop, dt = float(t[-1]), float(t[1] - t[0])
    channels = ["u", "w", "p", "q", "r", "theta", "phi"]
    names = {"truth": channels, "frequency_domain": channels, "time_domain": channels,
             "input_2311": ["lon", "lat"]}
    res = run_ssp(path, names, stop, dt)
    n = len(t)
    truth_fmu = next(res_dir.glob("helicopter*.fmu"))
    ref = {"truth": simulate_truth(signal, hover_trim, mode="cs", fmu=truth_fmu)}
    for m in ("frequency_domain", "time_domain"):
        ref[m] = simulate_exported(res_dir / f"{m}.fmu", signal, mode="cs", absolute=True)
    for (comp, name), (times, values) in res.items():
        k = np.rint(times / dt).astype(int)
        assert np.allclose(times, k * dt, atol=1e-9) and k.size >= n - 1
        if comp == "input_2311":
            assert np.array_equal(values, signal[name].values[k])
            continue
        y = ref[comp][name].values[k] * _si(name)  # analysis -> SI
        y_lc = values
        peak = np.max(np.abs(y - y[0]))
        assert peak > 0, (comp, name)
        assert np.max(np.abs(y_lc - y)) <= 1e-12 * max(peak, np.max(np.abs(y))), (comp, name)


@pytest.mark.fmu
def test_cli_export_ssp(study_ssp, capsys):
    from sysid.cli import main

    _, folder = study_ssp
    out = folder / "cli.ssp"
    assert main(["export-ssp", str(folder / "campaign.nc"), "-o", str(out), "--quiet"]) == 0
    assert out.is_file() and str(out) in capsys.readouterr().out
    assert main(["export-ssp", str(folder / "campaign.nc"), "-o", str(folder / "x.zip"),
                 "--quiet"]) == 1
    assert ".ssp" in capsys.readouterr().err
