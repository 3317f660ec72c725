"""Campaign description, TOML round trip and hold-loop design (no FMU needed)."""

import control
import numpy as np
import pytest
import xarray as xr

from sysid.errors import InputDataError
from sysid.maneuvers import Campaign, Maneuver, Stabilisation, default_campaign, design_loops
from sysid.units import CONTROLS, STATES_6DOF


def test_default_campaign_mirrors_the_paper():
    c = default_campaign()
    sweeps = [m for m in c.maneuvers if m.kind == "sweep"]
    assert sorted((m.axis for m in sweeps)) == sorted(CONTROLS * 2)      # two records per axis
    assert all(m.omega_min <= 0.1 and m.omega_max >= 20.0 for m in sweeps)
    for kind in ("3211", "2311"):
        assert sorted(m.axis for m in c.maneuvers if m.kind == kind) == sorted(CONTROLS)
    assert c.noise and c.turbulence > 0                  # realistic levels on by default
    quiet = default_campaign(noise=False)
    assert not quiet.noise and quiet.turbulence == 0


def test_toml_round_trip(tmp_path):
    c = default_campaign(40.0, seed=7)
    c.stabilisation.conditional = True
    path = tmp_path / "campaign.toml"
    path.write_text(c.to_toml())
    assert Campaign.from_toml(path) == c


@pytest.mark.parametrize("change, message", [
    ({"kind": "chirp"}, "kind 'chirp'"),
    ({"axis": "throttle"}, "axis 'throttle'"),
    ({"amplitude": -1.0}, "amplitude"),
    ({"omega_min": 5.0, "omega_max": 1.0}, "omega_min < omega_max"),
])
def test_bad_maneuvers_are_named(change, message):
    spec = {"name": "sweep_lon_1", "kind": "sweep", "axis": "lon", **change}
    with pytest.raises(InputDataError, match=message) as err:
        Campaign.from_dict({"maneuvers": [spec]})
    assert "sweep_lon_1" in str(err.value)


def test_bad_campaign_fields_are_named(tmp_path):
    m = {"name": "a", "kind": "3211", "axis": "lat"}
    with pytest.raises(InputDataError, match="duplicated manoeuvre names"):
        Campaign.from_dict({"maneuvers": [m, m]})
    with pytest.raises(InputDataError, match="unknown channels"):
        Campaign.from_dict({"maneuvers": [m], "noise": {"qq": 0.1}})
    with pytest.raises(InputDataError, match="unexpected keyword"):
        Campaign.from_dict({"maneuvers": [m], "sampel_rate": 50})
    path = tmp_path / "broken.toml"
    path.write_text("name = [")
    with pytest.raises(InputDataError, match="broken.toml"):
        Campaign.from_toml(path)


def _hover_like_linearization():
    """A quasi-steady model Dataset with realistic on-axis damping and control power."""
    n = len(STATES_6DOF)
    A = np.zeros((n, n))
    B = np.zeros((n, 4))
    idx = {s: k for k, s in enumerate(STATES_6DOF)}
    A[idx["p"], idx["p"]], A[idx["q"], idx["q"]], A[idx["r"], idx["r"]] = -9.0, -3.0, -0.3
    A[idx["w"], idx["w"]] = -0.32
    B[idx["p"], 1], B[idx["q"], 0], B[idx["r"], 3], B[idx["w"], 2] = 4.0, -2.5, -3.0, -1.2
    coords = {"state_dot": list(STATES_6DOF), "state": list(STATES_6DOF), "input": list(CONTROLS)}
    return xr.Dataset({"A": (("state_dot", "state"), A), "B": (("state_dot", "input"), B)},
                      coords=coords)


@pytest.mark.parametrize("crossover", [0.3, 0.5, 1.0])
def test_hold_loops_cross_over_where_asked(crossover):
    lin = _hover_like_linearization()
    loops = design_loops(lin, Stabilisation(crossover=crossover, heading_crossover=crossover / 2))
    for control_name, rate in (("lat", "p"), ("lon", "q"), ("ped", "r")):
        loop = loops[control_name]
        wanted = crossover / 2 if control_name == "ped" else crossover
        damping = float(lin.A.sel(state_dot=rate, state=rate))
        derivative = float(lin.B.sel(state_dot=rate, input=control_name))
        # Airframe: angle'' = damping angle' + derivative * delta. The design crossover is
        # that of the attitude loop broken at the attitude error, rate loop closed.
        s = control.tf("s")
        plant = derivative / (s * (s - damping))
        inner = control.feedback(plant, loop.k_rate * s / derivative)
        outer = inner * (loop.k_error / derivative)
        assert abs(control.evalfr(outer, 1j * wanted)) == pytest.approx(1.0, rel=1e-9)
        assert np.all(np.real(control.poles(control.feedback(outer))) < 0)
