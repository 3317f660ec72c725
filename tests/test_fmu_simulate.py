"""Simulation: co-simulation vs model exchange, couplings, equivalent delay, bad input."""

import numpy as np
import pytest
import xarray as xr
from scipy.signal import lsim

from sysid.core.errors import InputDataError, SimulationDiverged

pytestmark = pytest.mark.fmu

CONTROLS = ("lon", "lat", "col", "ped")


def inputs(trim, duration, dt=0.01, **changes):
    """Trim controls plus ``changes[axis](t)`` (percent) on a uniform grid."""
    t = np.arange(0.0, duration, dt)
    data = {}
    for c in CONTROLS:
        u = np.full_like(t, trim.controls[c])
        if c in changes:
            u = u + changes[c](t)
        data[c] = ("time", u, {"units": "%"})
    return xr.Dataset(data, coords={"time": t}, attrs={"maneuver": "test", "kind": "doublet"})


def doublet(t, start=1.0, width=1.0, amp=5.0):
    return np.where((t >= start) & (t < start + width), amp,
                    np.where((t >= start + width) & (t < start + 2 * width), -amp, 0.0))


def step(t, start=0.0, amp=1.0):
    return np.where(t >= start, amp, 0.0)


def test_cs_and_me_agree_on_a_doublet(hover_trim):
    """10 s longitudinal doublet from hover: RK4 co-simulation and CVode model exchange agree
    within 1 % of the peak response (deviation from trim) in every output."""
    from sysid.truth import simulate

    u = inputs(hover_trim, 10.0, lon=lambda t: doublet(t, amp=5.0))
    cs = simulate(u, hover_trim, mode="cs")
    me = simulate(u, hover_trim, mode="me")
    compared = 0
    for name in cs.data_vars:
        if name in CONTROLS:
            continue
        peak = float(np.max(np.abs(cs[name] - cs[name][0])))
        if peak < 1e-9:  # numerically constant output (e.g. an untouched actuator)
            continue
        err = float(np.max(np.abs(cs[name] - me[name])))
        assert err <= 0.01 * peak, (name, err, peak)
        compared += 1
    assert compared >= 15


def test_time_history_follows_data_model(hover_trim):
    from sysid.truth import simulate

    ds = simulate(inputs(hover_trim, 1.0, lon=lambda t: step(t, 0.5)), hover_trim)
    assert ds["time"].values[0] == 0.0 and ds.sizes["time"] == 100
    for name in ("lon", "lat", "col", "ped", "u", "v", "w", "p", "q", "r", "phi", "theta",
                 "psi", "ax", "ay", "az"):
        assert "units" in ds[name].attrs and "long_name" in ds[name].attrs
    assert ds["u"].attrs["units"] == "ft/s" and ds["q"].attrs["units"] == "deg/s"
    assert ds["theta"].attrs["units"] == "deg" and ds["az"].attrs["units"] == "ft/s^2"
    for key in ("maneuver", "kind", "axis", "flight_condition", "airspeed_kt", "fmu_name",
                "fmu_guid", "seed", "sysid_version", "trim_lon", "trim_theta", "trim_az"):
        assert key in ds.attrs, key
    assert ds.attrs["maneuver"] == "test" and ds.attrs["flight_condition"] == "hover"
    # analysis units: trim attitude in degrees, accelerometer ~ -g in ft/s^2 at trim
    assert float(ds["theta"][0]) == pytest.approx(hover_trim.theta_deg)
    assert float(ds["az"][0]) == pytest.approx(-32.17, abs=0.7)


def test_collective_step_yaws_the_aircraft(hover_trim):
    """Main-rotor torque reaction: more collective turns the nose right (counter-clockwise
    rotor seen from above), with nothing else moved."""
    from sysid.truth import simulate

    ds = simulate(inputs(hover_trim, 2.0, col=lambda t: step(t, 0.0, 2.0)), hover_trim)
    r = ds["r"].sel(time=1.0, method="nearest")
    assert float(r) > 2.0  # deg/s
    assert float(ds["w"].sel(time=1.0, method="nearest")) < -0.5  # climbs (ft/s, z down)


def test_lateral_cyclic_pitches_the_aircraft(hover_trim):
    """Rotor cross-coupling: a lateral cyclic step produces a pitch rate of at least 10 % of
    the roll rate within the first second."""
    from sysid.truth import simulate

    ds = simulate(inputs(hover_trim, 1.0, lat=lambda t: step(t, 0.0, 1.0)), hover_trim)
    p = np.abs(ds["p"] - ds["p"][0]).max()
    q = np.abs(ds["q"] - ds["q"][0]).max()
    assert float(q) > 0.1 * float(p)
    assert float(p) > 1.0


@pytest.mark.parametrize("axis,rate", [("lon", "q"), ("lat", "p")])
def test_cyclic_rate_response_has_equivalent_delay(hover_trim, axis, rate):
    """The full model's early rate response to a cyclic step lags the quasi-steady 6-DoF
    model's by an equivalent time delay (actuators + flapping + inflow) of 50-250 ms: the
    delay tau minimising sum (q_full(t) - q_qs(t - tau))^2 over the first second."""
    from sysid.truth import linearize, simulate

    qs = linearize(hover_trim).quasi_steady
    dt, amp = 0.001, 0.5
    t = np.arange(0.0, 1.5, dt)
    full = simulate(inputs(hover_trim, 1.5, dt=dt, **{axis: lambda t: step(t, 0.0, amp)}),
                    hover_trim)
    y_full = full[rate].values - full[rate].values[0]
    sys = (qs["A"].values, qs["B"].sel(input=axis).values[:, None], np.eye(9),
           np.zeros((9, 1)))
    _, y, _ = lsim(sys, np.full_like(t, amp), t)
    y_qs = y[:, list(qs.state.values).index(rate)]
    window = t <= 1.0
    taus = np.arange(0.0, 0.4, 0.001)
    cost = [np.sum((y_full[window] - np.interp(t[window] - tau, t, y_qs, left=0.0)) ** 2)
            for tau in taus]
    tau = taus[int(np.argmin(cost))]
    assert 0.05 <= tau <= 0.25, tau


def test_controls_saturate_at_travel_limits(hover_trim):
    from sysid.truth import simulate

    over = simulate(inputs(hover_trim, 1.0, lon=lambda t: 150.0 - hover_trim.controls["lon"]),
                    hover_trim)
    full = simulate(inputs(hover_trim, 1.0, lon=lambda t: 100.0 - hover_trim.controls["lon"]),
                    hover_trim)
    np.testing.assert_array_equal(over["q"].values, full["q"].values)
    assert float(over["lon"].max()) == 100.0  # the applied (saturated) control is recorded
    under = simulate(inputs(hover_trim, 1.0, ped=lambda t: -hover_trim.controls["ped"] - 30),
                     hover_trim)
    zero = simulate(inputs(hover_trim, 1.0, ped=lambda t: -hover_trim.controls["ped"]),
                    hover_trim)
    np.testing.assert_array_equal(under["r"].values, zero["r"].values)
    # documented gearing: 100 % lon = +10 deg theta_1s, 0 % ped = +18 deg tail-rotor pitch
    assert float(full["theta_1s"][-1]) == pytest.approx(10.0, abs=0.01)
    assert float(zero["theta_tr"][-1]) == pytest.approx(18.0, abs=0.05)


def test_nan_input_is_a_clear_error(hover_trim):
    from sysid.truth import CoSimulation, simulate

    u = inputs(hover_trim, 1.0)
    u["lat"][30] = np.nan
    with pytest.raises(InputDataError, match=r"input 'lat' is not finite .* t = 0\.300 s") as e:
        simulate(u, hover_trim)
    assert "\n" not in str(e.value)
    with pytest.raises(InputDataError, match="lack the control"):
        simulate(u.drop_vars("ped"), hover_trim)
    with CoSimulation() as sim:
        sim.reset(hover_trim)
        with pytest.raises(InputDataError, match="finite"):
            sim.step([50.0, np.nan, 50.0, 50.0])
        with pytest.raises(InputDataError, match="4 numbers"):
            sim.step([50.0, 50.0])


def test_fmu_refuses_nan_through_fmi(hover_trim):
    """Defence in depth: the FMU itself refuses a non-finite input with a logged reason."""
    from sysid.core.errors import FMUError
    from sysid.truth import Instance, load_fmu

    model = load_fmu()
    with Instance(model, "cs") as inst:
        inst.initialize(hover_trim.start_values())
        with pytest.raises(FMUError, match="lon must be finite"):
            inst.set_values({"lon": float("nan")})


def test_divergence_raises_simulation_diverged(hover_trim):
    from sysid.truth import CoSimulation

    with CoSimulation(name="runaway") as sim:
        sim.reset(hover_trim)
        controls = sim.trim_controls.copy()
        controls[0] = 100.0  # full aft stick, held
        with pytest.raises(SimulationDiverged, match="left the envelope") as info:
            for _ in range(3000):
                sim.step(controls)
    assert 0.0 < info.value.time < 30.0
    assert info.value.maneuver == "runaway"


def test_non_finite_state_is_reported_as_a_discarded_step(hover_trim):
    """RK4 with 0.5 s sub-steps is unstable on the rotor's fast modes (time constants of a
    few hundredths of a second), so the states overflow within seconds. The FMU returns
    fmi2Discard with the last successful time (FMI 2.0), and CoSimulation raises
    SimulationDiverged from that status, naming the time and the manoeuvre."""
    from sysid.fmi.runtime import DISCARD
    from sysid.truth import CoSimulation, Instance, load_fmu

    with CoSimulation(name="coarse", step_size=0.5, envelope={}) as sim:
        sim.reset(hover_trim)
        with pytest.raises(SimulationDiverged, match="non-finite") as info:
            for _ in range(200):
                sim.step(sim.trim_controls, dt=0.5)
    assert info.value.maneuver == "coarse"
    assert 0.0 < info.value.time < 100.0 and f"t = {info.value.time:.2f} s" in str(info.value)

    model = load_fmu()
    with Instance(model, "cs", {"h_rk4": 0.5}) as inst:
        inst.initialize(hover_trim.start_values())
        do_step, t, status = inst.functions["fmi2DoStep"], 0.0, 0
        while status == 0 and t < 100.0:
            status = do_step(inst.component, t, 0.5, 1)
            t += 0.5
        assert status == DISCARD
        reached = inst.last_successful_time()
        assert 0.0 < reached < t and reached == pytest.approx(t - 0.5)


def test_gusts_act_in_body_axes(hover_trim):
    """A 10 ft/s headwind gust (u_gust = -10 ft/s: air moving aft) reads as airspeed and
    blows the rotor back: nose-up pitch rate."""
    from sysid.truth import simulate

    u = inputs(hover_trim, 1.0)
    u["u_gust"] = ("time", np.full(u.sizes["time"], -10.0), {"units": "ft/s"})
    ds = simulate(u, hover_trim)
    assert float(ds["airspeed"][-1]) == pytest.approx(10.0, abs=1.0)
    assert float(ds["q"][-1]) > 0.5
