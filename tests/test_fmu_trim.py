"""Trim of the truth helicopter against physics and the paper's hover trim pattern."""

import math

import numpy as np
import pytest

from sysid.core.errors import InputDataError

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def trims(truth_fmu):
    from sysid.truth import trim

    return {v: trim(v, fmu=truth_fmu) for v in (0, 20, 40, 50, 60, 70, 80, 90, 100)}


@pytest.mark.parametrize("speed", [0, 40, 80, 100])
def test_trim_residual_below_1e8(trims, speed):
    t = trims[speed]
    accelerations = [t.residual[s] for s in ("u", "v", "w", "p", "q", "r")]
    assert np.max(np.abs(accelerations)) < 1e-8
    # rotor, inflow and actuator states are at their own equilibrium too
    for s in ("a1", "b1", "vi_mr", "vi_tr", "theta_0", "theta_1s", "theta_1c", "theta_tr"):
        assert abs(t.residual[s]) < 1e-8, s


@pytest.mark.parametrize("speed", [0, 40, 80, 100])
def test_trim_is_level_zero_sideslip_along_x(trims, speed):
    from sysid.core.units import KT

    t = trims[speed]
    s = t.states
    assert math.hypot(s["u"], s["v"], s["w"]) == pytest.approx(speed * KT, abs=1e-9)
    assert s["v"] == 0.0
    assert t.residual["h"] == pytest.approx(0.0, abs=1e-9)   # level: no climb rate
    assert t.residual["y_e"] == pytest.approx(0.0, abs=1e-9)  # ground track along north
    assert all(s[k] == 0.0 for k in ("p", "q", "r"))


def test_hover_trim_is_plausible(trims):
    t = trims[0]
    assert abs(t.theta_deg) < 6.0 and abs(t.phi_deg) < 6.0
    # tail-rotor side force to starboard is balanced by a left roll, as in the paper
    assert t.phi_deg < -1.0
    for name, value in t.controls.items():
        assert 20.0 <= value <= 80.0, (name, value)
    # momentum theory: hover induced velocity sqrt(T / (2 rho A)) with T ~ weight
    T = t.outputs["T_mr"]
    vi_momentum = math.sqrt(T / (2 * 1.225 * math.pi * 4.91**2))
    assert t.states["vi_mr"] == pytest.approx(vi_momentum, rel=1e-3)
    assert T == pytest.approx(2800 * 9.80665, rel=0.05)


def test_collective_power_bucket(trims):
    speeds = sorted(trims)
    col = np.array([trims[v].controls["col"] for v in speeds])
    v_min = speeds[int(np.argmin(col))]
    assert 40 <= v_min <= 80
    assert trims[100].controls["col"] > col.min() + 1.0
    assert trims[100].controls["col"] > trims[80].controls["col"]
    # shaft power has its bucket too
    power = np.array([trims[v].outputs["power"] for v in speeds])
    assert 40 <= speeds[int(np.argmin(power))] <= 90


def test_forward_flight_trim_pitches_nose_down(trims):
    assert trims[100].theta_deg < trims[0].theta_deg - 2.0
    assert trims[100].controls["lon"] < trims[0].controls["lon"]  # stick forward


def test_trim_attributes_and_table(trims):
    t = trims[0]
    attrs = t.attrs()
    for channel in ("lon", "lat", "col", "ped", "u", "v", "w", "p", "q", "r", "phi", "theta",
                    "psi", "ax", "ay", "az"):
        assert f"trim_{channel}" in attrs
    assert attrs["trim_phi"] == pytest.approx(t.phi_deg)
    assert attrs["trim_az"] == pytest.approx(-9.80665 / 0.3048, rel=0.02)  # accelerometer
    text = t.table()
    assert "delta_lon_0" in text and "2800.0 kg" in text
    ds = t.to_dataset()
    assert float(ds["theta"]) == pytest.approx(t.theta_deg)


def test_trim_start_values_initialise_an_instance_at_equilibrium(truth_fmu, trims):
    from sysid.truth import CoSimulation

    t = trims[80]
    with CoSimulation(truth_fmu) as sim:
        y0 = sim.reset(t)
        for _ in range(100):
            y = sim.step(sim.trim_controls)
    i = {n: k for k, n in enumerate(sim.output_names)}
    for name in ("u", "w", "p", "q", "r", "phi", "theta"):
        assert abs(y[i[name]] - y0[i[name]]) < 1e-6, name


def test_trim_rejects_bad_airspeed():
    from sysid.truth import trim

    with pytest.raises(InputDataError, match="airspeed"):
        trim(float("nan"))
    with pytest.raises(InputDataError, match="airspeed"):
        trim(-5.0)
