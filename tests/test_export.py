"""FMU export of identified models (sysid.fmi.export) and its validation (sysid.assess.exported).

Independent truths: sysid.models.simulate (exact zero-order hold in Python with scipy's expm),
the Pade-augmented model of sysid.models.statespace (python-control's Pade), a step-by-step
scipy discretisation, analytic envelopes, and the truth helicopter FMU.
"""

import contextlib
import shutil
import zipfile
import xml.etree.ElementTree as ET

import numpy as np
import pytest
import scipy.linalg
import xarray as xr

from sysid.core.errors import FMUError, InputDataError
from sysid.fmi.export import export_fmu
from sysid.assess.exported import (compare_with_truth, envelope_check, roundtrip_error,
                                  simulate_exported)
from sysid.signals.inputs import multistep
from sysid.models import (LinearStructure, Parameter, six_dof_structure, simulate, statespace,
                          structure_from_dict)
from sysid.core.units import DEG, FT

TRIM_IN = {"lon": 50.0, "lat": 48.0, "col": 55.0, "ped": 45.0}
TRIM_OUT = {"u": 0.5, "theta": 3.0, "phi": -2.0, "psi": 10.0}
VALUES = {"X_u": -0.02, "M_q": -1.2, "L_p": -3.0, "M_u": 0.01, "L_v": -0.02, "Z_w": -0.3,
          "N_r": -0.5, "Y_v": -0.05, "X_lon": 0.3, "M_lon": -0.9, "L_lat": 1.5, "M_lat": 0.2,
          "L_lon": 0.3, "Z_col": -0.8, "N_ped": 0.7, "N_col": 0.2, "tau_L_lon": 0.07,
          "tau_M_lat": 0.11}


def _model(delays=True, **changes) -> xr.Dataset:
    values = {**VALUES, **changes}
    if not delays:
        values = {k: v for k, v in values.items() if not k.startswith("tau")}
    s = six_dof_structure(theta0=3.0, phi0=-2.0, values=values,
                          delays={"tau_L_lon": "p,lon", "tau_M_lat": "q,lat"} if delays else None,
                          trim_input=TRIM_IN, trim_output=TRIM_OUT)
    return s.to_dataset(attrs={"method": "frequency_domain"})


def _inputs(kind: str, axis: str, dt: float = 0.01) -> xr.Dataset:
    return multistep(kind, axis, base_width=0.5, amplitude=2.0, dt=dt, lead_out=4.0)


@pytest.fixture(scope="module")
def delayed(tmp_path_factory):
    ds = _model()
    return ds, export_fmu(ds, tmp_path_factory.mktemp("exp") / "delayed.fmu")


@pytest.fixture(scope="module")
def fractional(tmp_path_factory):
    # 0.073 s and 0.1149 s are not whole samples: the FMU must interpolate the history as
    # simulate does.
    ds = _model(tau_L_lon=0.073, tau_M_lat=0.1149)
    return ds, export_fmu(ds, tmp_path_factory.mktemp("exp") / "frac.fmu")


@pytest.fixture(scope="module")
def pade(tmp_path_factory):
    ds = _model()
    return ds, export_fmu(ds, tmp_path_factory.mktemp("exp") / "pade.fmu", me_delay="pade")


@pytest.fixture(scope="module")
def undelayed(tmp_path_factory):
    ds = _model(delays=False)
    return ds, export_fmu(ds, tmp_path_factory.mktemp("exp") / "plain.fmu")


# ------------------------------------------------------------------------------------------
# (a) against sysid.models.simulate


@pytest.mark.parametrize("kind,axis", [("3211", "lon"), ("2311", "lat"), ("3211", "ped")])
def test_cosimulation_matches_reference_simulation(delayed, kind, axis):
    ds, fmu = delayed
    err = roundtrip_error(ds, fmu, _inputs(kind, axis), mode="cs")
    assert err.attrs["max_relative_error"] < 1e-6


def test_cosimulation_with_fractional_delays(fractional):
    ds, fmu = fractional
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "lat")])
    assert roundtrip_error(ds, fmu, inputs, mode="cs").attrs["max_relative_error"] < 1e-6


def test_cosimulation_with_longer_steps(delayed):
    # One doStep of 0.02 s per two samples: the discretisation is recomputed for the new step
    # and the delays (3.5 and 5.5 steps) interpolate; simulate on the decimated grid agrees.
    ds, fmu = delayed
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "lat")])
    got = simulate_exported(fmu, inputs, mode="cs", step_size=0.02)
    coarse = inputs.isel(time=slice(None, None, 2))
    full = coarse.assign(col=coarse.lon * 0, ped=coarse.lon * 0)
    ref = simulate(ds, full, absolute=False)
    for name in ("p", "q", "theta"):
        y = got[name].values[::2] - ds.trim_output.sel(output=name).item()
        peak = np.max(np.abs(ref[name].values))
        assert np.max(np.abs(y - ref[name].values)) < 1e-9 * peak


def test_model_exchange_without_delays_matches_reference(undelayed):
    ds, fmu = undelayed
    for kind, axis in (("3211", "lon"), ("2311", "lat")):
        err = roundtrip_error(ds, fmu, _inputs(kind, axis), mode="me")
        assert err.attrs["max_relative_error"] < 1e-3


def _pade_model(ds: xr.Dataset, order: int) -> xr.Dataset:
    """The Pade-augmented model of python-control as a delay-free model Dataset."""
    sys = statespace(ds, pade_order=order)
    n = sys.nstates
    states = [f"s{i}" for i in range(n)]
    outs = [str(o) for o in ds.output.values]
    return xr.Dataset(
        {"A": (("state_dot", "state"), np.asarray(sys.A)),
         "B": (("state_dot", "input"), np.asarray(sys.B)),
         "C": (("output", "state"), np.asarray(sys.C)),
         "D": (("output", "input"), np.asarray(sys.D))},
        coords={"state_dot": states, "state": states, "input": list(ds.input.values),
                "output": outs})


@pytest.mark.parametrize("delays", ["integer", "fractional"])
@pytest.mark.parametrize("kind,axis", [("3211", "lon"), ("2311", "lat")])
def test_model_exchange_with_delays_matches_reference(delayed, fractional, delays, kind, axis):
    # Default me_delay="buffer": the delayed inputs come from the input history held between
    # input updates, simulate's convention, so CVode (rtol 1e-10) reproduces simulate on
    # every channel, the rates fed through a delayed B entry (p from lon, q from lat)
    # included. Measured ~4e-7 of the peak, the level of the model without delays.
    ds, fmu = delayed if delays == "integer" else fractional
    err = roundtrip_error(ds, fmu, _inputs(kind, axis), mode="me")
    assert err.attrs["max_relative_error"] < 1e-5
    assert err["relative_error"].sel(output=["p", "q", "phi", "theta"]).max() < 1e-5


def test_model_exchange_buffer_and_pade_layouts(delayed, pade):
    # The buffer needs no extra states but fmi2CompletedIntegratorStep (its step events);
    # the Pade variant has n states per delay and needs no completed-step calls.
    from fmpy import read_model_description

    for (_, fmu), n_states, not_needed in ((delayed, 9, "false"), (pade, 9 + 2 * 6, "true")):
        md = read_model_description(str(fmu))
        assert md.numberOfContinuousStates == n_states
        assert _description(fmu).find("ModelExchange").get(
            "completedIntegratorStepNotNeeded") == not_needed


def test_model_exchange_pade_option_is_the_pade_model(pade):
    # me_delay="pade": the ME FMU is exactly the Pade-augmented model (to CVode accuracy);
    # against the exact delays its error is the Pade approximation error, bounded by
    # ~0.17 tau / n per unit step on a rate fed through a delayed B entry
    # (fmus/linear/README.md): 3.5e-3 of the peak roll rate here.
    ds, fmu = pade
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "lat")])
    got = simulate_exported(fmu, inputs, mode="me")
    full = inputs.assign(col=inputs.lon * 0, ped=inputs.lon * 0)
    ref = simulate(_pade_model(ds, 6), full)
    exact = roundtrip_error(ds, fmu, inputs, mode="me")
    for name in ("p", "q", "phi", "theta", "u"):
        y = got[name].values - ds.trim_output.sel(output=name).item()
        peak = np.max(np.abs(ref[name].values))
        assert np.max(np.abs(y - ref[name].values)) < 1e-5 * peak
    assert exact["relative_error"].sel(output=["phi", "theta", "u"]).max() < 1e-3
    assert exact.attrs["max_relative_error"] < 1e-2
    # co-simulation does not use the Pade states: still exact
    assert roundtrip_error(ds, fmu, inputs, mode="cs").attrs["max_relative_error"] < 1e-6


class _MELoop:
    """A user's own model-exchange loop (not fmpy's): inputs set at the sample instants,
    fixed-step RK4 between them, fmpy's order of calls (integrate to t_k+1, set time and
    inputs, fmi2CompletedIntegratorStep, event iteration if asked for)."""

    def __init__(self, fmu, dt=0.01, substeps=4):
        from fmpy import extract, read_model_description

        self.md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.unzip = extract(str(fmu))
        self.nx = self.md.numberOfContinuousStates
        self.dt, self.substeps = dt, substeps
        self.model = self.instance("me")
        self.events = []

    def instance(self, name):
        from fmpy.fmi2 import FMU2Model

        m = FMU2Model(guid=self.md.guid, unzipDirectory=self.unzip,
                      modelIdentifier=self.md.modelExchange.modelIdentifier, instanceName=name)
        m.instantiate()
        return m

    def start(self, lon):
        m = self.model
        m.setupExperiment(startTime=0.0)
        m.enterInitializationMode()
        m.setReal([self.vr["lon"]], [lon])
        m.exitInitializationMode()
        m.newDiscreteStates()
        m.enterContinuousTimeMode()

    def derivatives(self, t, x):
        from ctypes import c_double

        m = self.model
        m.setTime(t)
        m.setContinuousStates((c_double * self.nx)(*x), self.nx)
        dx = (c_double * self.nx)()
        m.getDerivatives(dx, self.nx)
        return np.array(dx[:])

    def run(self, k0, levels):
        """Samples k0, k0+1, ...: hold lon at each level for one sample interval; returns
        (p, q) after each."""
        from ctypes import c_double

        m, out = self.model, []
        x = (c_double * self.nx)()
        m.getContinuousStates(x, self.nx)
        x = np.array(x[:])
        for j, level in enumerate(levels):
            t0 = (k0 + j) * self.dt
            h = self.dt / self.substeps
            for i in range(self.substeps):
                t = t0 + i * h
                k1 = self.derivatives(t, x)
                k2 = self.derivatives(t + h / 2, x + h / 2 * k1)
                k3 = self.derivatives(t + h / 2, x + h / 2 * k2)
                k4 = self.derivatives(t + h, x + h * k3)
                x = x + h / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
            t1 = (k0 + j + 1) * self.dt
            m.setTime(t1)
            m.setContinuousStates((c_double * self.nx)(*x), self.nx)
            m.setReal([self.vr["lon"]], [level])
            event, _ = m.completedIntegratorStep()
            if event:
                self.events.append(k0 + j + 1)
                m.enterEventMode()
                m.newDiscreteStates()
                m.enterContinuousTimeMode()
            out.append(tuple(m.getReal([self.vr["p"], self.vr["q"]])))
        return out

    def close(self):
        self.model.terminate()
        self.model.freeInstance()
        shutil.rmtree(self.unzip, ignore_errors=True)


def test_model_exchange_step_events_where_a_delayed_input_jumps(delayed):
    # lon steps at sample 20 and back at 50; tau_L_lon = 0.07 s = 7 samples: the delayed
    # input of p jumps at samples 27 and 57 and only there (rounding of t - tau may raise
    # the event one sample early with a jump in the last bits - harmless). Updates with
    # unchanged delayed inputs raise no events.
    _, fmu = delayed
    loop = _MELoop(fmu)
    try:
        loop.start(TRIM_IN["lon"])
        loop.run(0, [TRIM_IN["lon"]] * 19 + [60.0] * 30 + [TRIM_IN["lon"]] * 40)
    finally:
        loop.close()
    assert 27 in loop.events and 57 in loop.events
    assert set(loop.events) <= {26, 27, 56, 57}


def test_model_exchange_fmu_state_holds_the_input_history(delayed):
    # A snapshot taken while a step of lon is still inside the delay, serialised and restored
    # into a fresh instance (empty history), continues exactly like the original: the history
    # and the pending step event are part of the FMU state.
    _, fmu = delayed
    loop = _MELoop(fmu)
    try:
        loop.start(TRIM_IN["lon"])
        loop.run(0, [60.0] * 4)  # lon stepped at sample 1..4; delayed entry still at trim
        state = loop.model.getFMUstate()
        blob = loop.model.serializeFMUstate(state)
        first = loop.run(4, [40.0] * 30)
        events_first = loop.events[:]
        loop.model.setFMUstate(state)
        loop.events = []
        again = loop.run(4, [40.0] * 30)
        events_again = loop.events[:]
        loop.model.freeFMUstate(state)
        loop.model.terminate()
        loop.model.freeInstance()
        loop.model = loop.instance("fresh")
        loop.model.setupExperiment(startTime=0.0)
        loop.model.enterInitializationMode()
        loop.model.exitInitializationMode()
        restored = loop.model.deSerializeFMUstate(blob)
        loop.model.setFMUstate(restored)
        loop.model.freeFMUstate(restored)
        loop.events = []
        third = loop.run(4, [40.0] * 30)
        events_third = loop.events[:]
    finally:
        loop.close()
    assert again == first and third == first
    assert events_again == events_first == events_third
    assert 8 in events_first  # 60 % reaches p at 1 + 7 samples
    # the restored history is what makes p move: the delayed 60 % step arrives at sample 8
    p = np.array([v[0] for v in third])
    assert np.any(p != p[0])


# ------------------------------------------------------------------------------------------
# variables, units, parameters


def _description(fmu) -> ET.Element:
    with zipfile.ZipFile(fmu) as zf:
        return ET.fromstring(zf.read("modelDescription.xml"))


def test_fmu_passes_fmpy_validation(delayed, undelayed, pade):
    from fmpy.validation import validate_fmu

    for _, fmu in (delayed, undelayed, pade):
        assert validate_fmu(str(fmu)) == []


def test_variables_units_and_parameters(delayed):
    ds, fmu = delayed
    root = _description(fmu)
    var = {v.get("name"): v for v in root.iter("ScalarVariable")}
    real = {n: v.find("Real") for n, v in var.items()}
    for name, unit in (("u", "m/s"), ("q", "rad/s"), ("theta", "rad"), ("lon", "%")):
        assert real[name].get("unit") == unit
    assert var["u"].get("causality") == "output"
    assert var["lon"].get("causality") == "input"
    assert float(real["lon"].get("start")) == TRIM_IN["lon"]
    # every identified parameter is an FMU parameter holding its value
    for name, value in zip(ds.parameter.values, ds.value.values):
        assert var[str(name)].get("causality") == "parameter"
        assert float(real[str(name)].get("start")) == pytest.approx(float(value), abs=0)
    assert real["M_q"].get("unit") == "1/s"
    assert real["tau_L_lon"].get("unit") == "s"
    assert float(real["trim_theta"].get("start")) == pytest.approx(3.0 * DEG, rel=1e-15)
    units = {u.get("name"): u for u in root.iter("Unit")}
    # X_lon: (ft/s2)/% = 0.3048 / 0.01 (m/s2) per unit fraction
    xlon = units[real["X_lon"].get("unit")].find("BaseUnit")
    assert float(xlon.get("factor")) == pytest.approx(FT / 0.01)
    assert xlon.get("m") == "1" and xlon.get("s") == "-2"
    sources = [f.get("name") for f in root.find("CoSimulation").iter("File")]
    assert sources == ["fmu_core.c", "fmi2_functions.c", "model.c"]
    with zipfile.ZipFile(fmu) as zf:
        names = zf.namelist()
    for f in ("fmu_core.c", "fmi2_functions.c", "model.c", "model.h", "fmu_model.h",
              "model_variables.h", "linear_dims.h", "linear_tables.h", "fmi2Functions.h"):
        assert f"sources/{f}" in names
    # FMI 2.0 has no build description (its <SourceFiles> say it); never an FMI 3.0 one
    assert "sources/buildDescription.xml" not in names
    assert not any("fmi3" in n for n in names)


def test_outputs_start_at_trim_in_si(delayed):
    ds, fmu = delayed
    quiet = _inputs("3211", "lon").isel(time=slice(0, 50))  # lead-in: zeros
    got = simulate_exported(fmu, quiet * 0, mode="cs")  # analysis units back
    assert got["theta"].values[0] == pytest.approx(3.0, rel=1e-12)
    assert got["psi"].values[-1] == pytest.approx(10.0, rel=1e-12)
    assert got["u"].values[0] == pytest.approx(0.5, rel=1e-12)


def test_tuned_parameter_changes_the_model(delayed):
    # Setting M_q and tau_L_lon in the FMU equals exporting a model with those values.
    ds, fmu = delayed
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "lat")])
    got = simulate_exported(fmu, inputs, mode="cs",
                            parameters={"M_q": -2.0, "tau_L_lon": 0.05})
    ref_ds = _model(M_q=-2.0, tau_L_lon=0.05)
    full = inputs.assign(col=inputs.lon * 0, ped=inputs.lon * 0)
    ref = simulate(ref_ds, full)
    for name in ("p", "q", "theta"):
        y = got[name].values - ds.trim_output.sel(output=name).item()
        assert np.max(np.abs(y - ref[name].values)) < 1e-9 * np.max(np.abs(ref[name].values))


#: A structure whose parameters set several entries (``also``): a tied A and a tied B, the
#: latter onto an entry a held parameter gives a known part (the parts add).
TIED = {"states": ["u", "w", "q", "theta"], "inputs": ["lon", "col"],
        "outputs": ["u", "w", "q", "theta"],
        "A": {"X_u": -0.02, "Z_w": -0.3, "M_q": -1.0, "theta,q": {"value": 1.0, "free": False},
              "u,theta": {"value": -32.17, "free": False},
              "M_w": {"value": 0.02, "also": [["u,w", 0.5]]}},
        "B": {"M_lon": -0.9, "Z_col": {"value": -0.8, "also": [["q,col", 0.4]]},
              "q,col": {"value": 0.3, "free": False}}}


def test_tuned_tied_parameter_changes_every_entry_it_sets(tmp_path):
    # Setting a tied parameter in the FMU moves all its entries, as in the structure (and
    # keeps the held part of an entry it shares).
    st = structure_from_dict(TIED, source="tied")
    fmu = export_fmu(st.to_dataset(attrs={"method": "frequency_domain"}), tmp_path / "tied.fmu")
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "col")])
    changes = {"M_w": 0.05, "Z_col": -1.2}
    got = simulate_exported(fmu, inputs, mode="cs", parameters=changes)
    theta = st.theta0.copy()
    for name, value in changes.items():
        theta[list(st.free_names).index(name)] = value
    ref = simulate(st.to_dataset(theta), inputs)
    for name in ("u", "w", "q"):
        scale = np.max(np.abs(ref[name].values))
        assert np.max(np.abs(got[name].values - ref[name].values)) < 1e-9 * scale, name
    # the untuned tie: the coupling entries the tied values set matter to the response
    plain = simulate(st.replace_parameters({"Z_col": {"also": ()}}).to_dataset(theta), inputs)
    assert np.max(np.abs(plain["q"].values - ref["q"].values)) > 1e-3 * np.max(
        np.abs(ref["q"].values))


def test_variable_steps_match_stepwise_exact_discretisation(undelayed):
    # Alternating steps 0.01 / 0.025 / 0.004 s: each step uses exp(A h) for its own h.
    ds, fmu = undelayed
    with _initialised_slave(fmu) as (slave, vr):
        _check_variable_steps(slave, vr, ds)


def _check_variable_steps(slave, vr, ds):
    A, B = ds.A.values, ds.B.values
    x = np.zeros(9)
    t = 0.0
    rng = np.random.default_rng(3)
    for k in range(60):
        h = (0.01, 0.025, 0.004)[k % 3]
        du = rng.normal(size=4)
        slave.setReal([vr[c] for c in ("lon", "lat", "col", "ped")],
                      list(np.array(list(TRIM_IN.values())) + du))
        slave.doStep(t, h)
        M = np.zeros((13, 13))
        M[:9, :9], M[:9, 9:] = A * h, B * h
        E = scipy.linalg.expm(M)
        x = E[:9, :9] @ x + E[:9, 9:] @ du
        t += h
    q = slave.getReal([vr["q"]])[0] / DEG
    assert q == pytest.approx(x[4], rel=1e-10, abs=1e-12)


def test_fmu_state_snapshot_restores_buffers(delayed):
    _, fmu = delayed
    with _initialised_slave(fmu) as (slave, vr):
        _check_snapshot(slave, vr)


def _check_snapshot(slave, vr):
    lon, out = vr["lon"], [vr["p"], vr["q"]]

    def run(t0, n, level):
        t = t0
        for _ in range(n):
            slave.setReal([lon], [level])
            slave.doStep(t, 0.01)
            t += 0.01
        return t, slave.getReal(out)

    t, _ = run(0.0, 30, 60.0)  # the history now holds a step the delay has not yet passed
    state = slave.getFMUstate()
    blob = slave.serializeFMUstate(state)
    _, first = run(t, 40, 40.0)
    slave.setFMUstate(state)
    _, again = run(t, 40, 40.0)
    restored = slave.deSerializeFMUstate(blob)
    slave.setFMUstate(restored)
    _, third = run(t, 40, 40.0)
    assert again == first and third == first
    slave.freeFMUstate(state)
    slave.freeFMUstate(restored)


@contextlib.contextmanager
def _initialised_slave(fmu):
    """An initialised co-simulation instance of ``fmu`` and its value references."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave

    md = read_model_description(str(fmu))
    unzip = extract(str(fmu))
    slave = FMU2Slave(guid=md.guid, unzipDirectory=unzip,
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="t")
    slave.instantiate()
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        yield slave, {v.name: v.valueReference for v in md.modelVariables}
        slave.terminate()
    finally:
        slave.freeInstance()
        shutil.rmtree(unzip, ignore_errors=True)


# ------------------------------------------------------------------------------------------
# names, bad models, atomicity


def test_names_illegal_in_c_and_xml_are_escaped(tmp_path):
    from fmpy.validation import validate_fmu

    states = ["a<b", "c&d", "1st state"]
    inputs = ["lon", "in.put"]
    params = [Parameter("k<1>", "A", "a<b", "a<b", -1.0),
              Parameter("x & y", "A", "c&d", "c&d", -2.0),
              Parameter("2nd.gain", "B", "a<b", "lon", 1.5),
              Parameter('say "hi"\\', "B", "1st state", "in.put", 0.5),
              Parameter("sp ace", "delay", "a<b", "lon", 0.03)]
    s = LinearStructure(states=states, inputs=inputs, A0=np.diag([0.0, 0.0, -0.7]),
                        B0=np.array([[0, 0], [1.0, 0], [0, 0]]), parameters=params,
                        name="odd")
    ds = s.to_dataset(attrs={"method": "odd names"})
    fmu = export_fmu(ds, tmp_path / "odd.fmu", model_name="3 odd<model>")
    assert validate_fmu(str(fmu)) == []
    names = {v.get("name") for v in _description(fmu).iter("ScalarVariable")}
    for p in params:
        assert p.name in names
    assert {"a<b", "c&d", "1st state", "in.put", "x_a<b", "trim_in.put"} <= names
    u = multistep("3211", "lon", base_width=0.3, amplitude=1.0, lead_out=1.0)
    u = u.assign({"in.put": ("time", np.roll(u.lon.values, 20))})
    assert roundtrip_error(ds, fmu, u, mode="cs").attrs["max_relative_error"] < 1e-6


@pytest.mark.parametrize("where", ["A", "value", "delay", "trim_output"])
def test_non_finite_model_is_refused_naming_the_entry(tmp_path, where):
    ds = _model()
    if where == "A":
        ds["A"].loc[{"state_dot": "q", "state": "u"}] = np.nan
        expected = r"A\[q, u\]"
    elif where == "value":
        ds["value"].loc[{"parameter": "M_q"}] = np.inf
        expected = r"value\[M_q\]"
    elif where == "delay":
        ds["delay"].loc[{"state_dot": "p", "input": "lon"}] = np.nan
        expected = r"delay\[p, lon\]"
    else:
        ds["trim_output"].loc[{"output": "theta"}] = np.nan
        expected = r"trim_output\[theta\]"
    with pytest.raises(InputDataError, match=expected):
        export_fmu(ds, tmp_path / "bad.fmu")
    assert list(tmp_path.iterdir()) == []


def test_compiler_failure_leaves_no_fmu(tmp_path, monkeypatch):
    target = tmp_path / "model.fmu"
    monkeypatch.setenv("CC", "/bin/false")
    with pytest.raises(FMUError, match="compiling"):
        export_fmu(_model(), target)
    assert list(tmp_path.iterdir()) == []
    # an existing FMU is left untouched by a failed export
    target.write_bytes(b"previous")
    with pytest.raises(FMUError):
        export_fmu(_model(), target)
    assert target.read_bytes() == b"previous"
    assert list(tmp_path.iterdir()) == [target]


def test_bad_options_give_clear_errors(tmp_path):
    with pytest.raises(InputDataError, match="fmi_version"):
        export_fmu(_model(), tmp_path / "m.fmu", fmi_version=1)
    with pytest.raises(InputDataError, match="me_delay"):
        export_fmu(_model(), tmp_path / "m.fmu", me_delay="history")
    with pytest.raises(InputDataError, match="pade_order"):
        export_fmu(_model(), tmp_path / "m.fmu", me_delay="pade", pade_order=0)
    assert list(tmp_path.iterdir()) == []


# ------------------------------------------------------------------------------------------
# rebuilding from the sources inside the FMU


def _cmake_available() -> bool:
    return shutil.which("cmake") is not None


@pytest.mark.skipif(not _cmake_available(),
                    reason="cmake not found (pip install cmake) for fmpy.build")
def test_rebuild_from_sources_gives_the_same_results(delayed, tmp_path):
    from fmpy.build import build_platform_binary

    ds, fmu = delayed
    unzip = tmp_path / "unzipped"
    with zipfile.ZipFile(fmu) as zf:
        zf.extractall(unzip)
    shutil.rmtree(unzip / "binaries")
    build_platform_binary(unzip, build_dir=None)
    rebuilt = tmp_path / "rebuilt.fmu"
    with zipfile.ZipFile(rebuilt, "w") as zf:
        for path in sorted(unzip.rglob("*")):
            if path.is_file():
                zf.write(path, path.relative_to(unzip).as_posix())
    inputs = xr.merge([_inputs("3211", "lon"), _inputs("2311", "lat")])
    for mode in ("cs", "me"):
        a = simulate_exported(fmu, inputs, mode=mode)
        b = simulate_exported(rebuilt, inputs, mode=mode)
        for name in a.data_vars:
            scale = max(1.0, float(np.max(np.abs(a[name].values))))
            assert np.max(np.abs(a[name].values - b[name].values)) <= 1e-12 * scale


# ------------------------------------------------------------------------------------------
# (c) envelopes


def _frequency_response(ds, factor=None, coherence=None) -> xr.Dataset:
    from sysid.models import frequency_response

    omega = np.logspace(-1, 1.5, 60)
    H = frequency_response(ds, omega).sel(output=["p", "q"], input=["lon", "lat"])
    if factor is not None:
        H = H * factor(omega)
    coh = xr.ones_like(H.real) if coherence is None else coherence(H)
    return xr.Dataset({"H": H, "partial_coherence": coh})


def test_envelope_check_of_an_exact_model_is_inside_muad():
    ds = _model()
    out = envelope_check(ds, _frequency_response(ds))
    assert set(out.fraction_inside.dims) == {"envelope", "output", "input"}
    assert np.all(out.fraction_inside.values == 1.0)
    assert np.allclose(out.magnitude.values, 0.0, atol=1e-9)


def test_envelope_check_counts_the_coherent_band_only(tmp_path):
    ds = _model()
    omega_split = 2.0
    # the data differ by 20 dB above 2 rad/s, where the coherence is poor
    fr = _frequency_response(
        ds, factor=lambda w: np.where(w > omega_split, 10.0, 1.0),
        coherence=lambda H: xr.where(H.frequency > omega_split, 0.3, 0.9))
    out = envelope_check(ds, fr)
    assert np.all(out.fraction_inside.values == 1.0)
    fr["partial_coherence"][:] = 0.9
    half = envelope_check(ds, fr).fraction_inside
    expected = np.mean(fr.frequency.values <= omega_split)
    assert np.allclose(half.values, expected)


def test_envelope_check_with_a_user_envelope_file(tmp_path):
    ds = _model()
    toml = tmp_path / "aee.toml"
    toml.write_text('name = "tight"\ncitation = "test"\n'
                    '[magnitude.upper]\nfrequency = [0.01, 100.0]\nvalue = [1.0, 1.0]\n'
                    '[magnitude.lower]\nfrequency = [0.01, 100.0]\nvalue = [-1.0, -1.0]\n'
                    '[phase.upper]\nfrequency = [0.01, 100.0]\nvalue = [5.0, 5.0]\n'
                    '[phase.lower]\nfrequency = [0.01, 100.0]\nvalue = [-5.0, -5.0]\n')
    # 2 dB mismatch: inside MUAD near 1 rad/s, outside the +-1 dB user bounds everywhere
    fr = _frequency_response(ds, factor=lambda w: np.full_like(w, 10 ** (-2 / 20)))
    from sysid.assess.envelopes import MUAD

    out = envelope_check({"a": ds, "b": ds}, fr, [MUAD, toml])
    assert list(out.envelope.values) == ["MUAD", "tight"]
    assert np.all(out.fraction_inside.sel(envelope="tight").values == 0.0)
    assert np.allclose(out.worst_magnitude_excess.sel(envelope="tight").values, 1.0)
    assert np.all(out.fraction_inside.sel(envelope="MUAD").values > 0.0)
    assert out.sizes["model"] == 2


# ------------------------------------------------------------------------------------------
# (b) against the truth FMU, and the CLI


@pytest.fixture(scope="module")
def linearization(truth_fmu, hover_trim):
    from sysid.truth import linearize

    return linearize(hover_trim).quasi_steady


@pytest.mark.fmu
def test_linearization_round_trip_and_truth_comparison(truth_fmu, hover_trim, linearization,
                                                       tmp_path):
    fmu = export_fmu(linearization, tmp_path / "lin.fmu", model_name="linearization")
    for kind, axis in (("3211", "lon"), ("2311", "lat")):
        inputs = multistep(kind, axis, base_width=0.4, amplitude=2.0, lead_out=2.0)
        assert roundtrip_error(linearization, fmu, inputs, mode="cs"
                               ).attrs["max_relative_error"] < 1e-6
        assert roundtrip_error(linearization, fmu, inputs, mode="me"
                               ).attrs["max_relative_error"] < 1e-3
        ver = compare_with_truth(fmu, truth_fmu, inputs, trim=hover_trim)
        assert list(ver.source.values) == ["truth", "linearization"]
        assert ver["q"].dims == ("source", "time")
        assert ver.tic.dims == ("source", "channel")
        assert float(ver.j_rms.sel(source="truth")) == 0.0
        # the quasi-steady model tracks the truth over a short multistep from trim
        assert float(ver.j_rms.sel(source="linearization")) < 1.0
        assert float(ver.tic.sel(source="linearization", channel=["p", "q", "phi",
                                                                 "theta"]).max()) < 0.3
        # both start at the same trim
        assert np.allclose(ver["theta"].isel(time=0).values[0],
                           ver["theta"].isel(time=0).values[1], atol=1e-9)


def _campaign(tmp_path):
    from sysid.data.netcdf import write_campaign

    ds = _model()
    tree = xr.DataTree.from_dict({"/": xr.Dataset(attrs={"name": "test"}),
                                  "/frequency_response": _frequency_response(ds),
                                  "/models/frequency_domain": ds})
    path = tmp_path / "campaign.nc"
    write_campaign(tree, path)
    return path


def test_cli_export_and_validate(tmp_path, capsys):
    from sysid.cli import main
    from sysid.data.netcdf import read_campaign

    path = _campaign(tmp_path)
    out = tmp_path / "model.fmu"
    assert main(["export", str(path), "--model", "frequency_domain", "-o", str(out),
                 "--quiet"]) == 0
    assert out.is_file()
    assert main(["export", str(path), "--model", "nope", "-o", str(out)]) == 1
    assert main(["export", str(path), "--model", "frequency_domain", "-o",
                 str(tmp_path / "m3.fmu"), "--fmi", "3", "--quiet"]) == 0
    assert 'fmiVersion="3.0"' in zipfile.ZipFile(tmp_path / "m3.fmu").read(
        "modelDescription.xml").decode()
    capsys.readouterr()
    assert main(["validate", str(path), "--no-truth", "--quiet"]) == 0
    text = capsys.readouterr().out
    assert "frequency_domain" in text and "MUAD" in text
    val = read_campaign(path)["validation/frequency_domain"].to_dataset()
    assert float(val.roundtrip_cs.max()) < 1e-6
    assert np.all(val.fraction_inside.values == 1.0)


def test_validate_reports_an_unusable_model_and_validates_the_others(tmp_path, capsys,
                                                                    monkeypatch):
    """A model whose exported FMU cannot be simulated (seen in a batch: a diverged fit with
    derivatives near 1e19 made CVode fail) is a validation result stored and printed, not a
    crash; the other models are still validated."""
    from sysid.assess import validation
    from sysid.data import netcdf as io
    from sysid.cli import main

    real = validation.roundtrip_error

    def failing_for_broken(model, fmu_path, inputs, **kwargs):
        if "broken" in str(fmu_path):
            raise RuntimeError("CVode error: the right-hand side failed repeatedly")
        return real(model, fmu_path, inputs, **kwargs)

    monkeypatch.setattr(validation, "roundtrip_error", failing_for_broken)
    path = tmp_path / "campaign.nc"
    io.update_campaign(path, "models/good", _model())
    io.update_campaign(path, "models/broken", _model())
    assert main(["validate", str(path), "--no-truth", "--quiet", "--fmu-dir",
                 str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "broken: validation FAILED: RuntimeError: CVode error" in out
    tree = io.read_campaign(path)
    assert "CVode" in tree["validation/broken"].attrs["error"]
    assert float(tree["validation/good"].to_dataset().roundtrip_cs.max()) < 1e-6
