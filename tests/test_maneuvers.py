"""Campaign description, TOML round trip and hold-loop design (no FMU needed)."""

import dataclasses
import tomllib

import control
import numpy as np
import pytest
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.flight_test.campaign import (HOVER_LATERAL_RISE, LINEAR_LATERAL_RISE, LINEAR_REGIME_SCALE,
                             Campaign, Maneuver, Stabilisation,
                             closed_loop_modes, default_campaign, design_loops,
                             linear_regime_campaign, preflight_check, with_calm_sweeps)
from sysid.core.units import CONTROLS, STATES_6DOF


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


def test_linear_regime_campaign_is_the_default_sweeps_smaller_in_calm_air(capsys, tmp_path):
    from sysid.cli import main

    default = {m.name: m for m in default_campaign(seed=3).maneuvers}
    calm = linear_regime_campaign(seed=3)
    assert [m.name for m in calm.maneuvers] == [n for n in default if n.startswith("sweep_")]
    for m in calm.maneuvers:
        assert m.amplitude == pytest.approx(LINEAR_REGIME_SCALE[m.axis]
                                            * default[m.name].amplitude)
        same = dataclasses.replace(m, amplitude=default[m.name].amplitude)
        if m.axis == "lat":
            # the lateral sweep rises linearly at half amplitude (the hover default is cubic)
            rise = (m.low_frequency_fraction, m.full_amplitude_omega, m.amplitude_shape)
            assert rise == LINEAR_LATERAL_RISE != HOVER_LATERAL_RISE
            d = default[m.name]
            same = dataclasses.replace(same, low_frequency_fraction=d.low_frequency_fraction,
                                       full_amplitude_omega=d.full_amplitude_omega,
                                       amplitude_shape=d.amplitude_shape)
        assert same == default[m.name]
    assert LINEAR_REGIME_SCALE["lon"] < 1 and LINEAR_REGIME_SCALE["lat"] < 1
    assert calm.turbulence == 0 and calm.noise == default_campaign().noise and calm.seed == 3
    assert main(["simulate", "--linear-regime", "--print-default", "-o", "x.nc"]) == 0
    printed = tomllib.loads(capsys.readouterr().out)
    assert Campaign.from_dict(printed) == linear_regime_campaign()
    path = tmp_path / "c.toml"
    path.write_text(default_campaign().to_toml())
    assert main(["simulate", str(path), "--linear-regime", "-o", str(tmp_path / "x.nc")]) != 0
    assert "--linear-regime applies to the built-in campaign only" in capsys.readouterr().err


def test_toml_round_trip(tmp_path):
    c = default_campaign(40.0, seed=7)
    c.stabilisation.conditional = True
    path = tmp_path / "campaign.toml"
    path.write_text(c.to_toml())
    assert Campaign.from_toml(path) == c


def test_calm_sweeps_are_the_same_campaign_with_only_the_sweeps_calm(capsys):
    """A manoeuvre's own turbulence (None: the campaign's) survives the TOML round trip; a
    campaign without it writes the TOML it always wrote (its cache keys stay)."""
    from sysid.cli import main

    c = default_campaign(seed=5)
    calm = with_calm_sweeps(c)
    assert c.turbulence == calm.turbulence > 0
    for a, b in zip(c.maneuvers, calm.maneuvers):
        assert a.turbulence is None
        assert b.turbulence == (0.0 if a.kind == "sweep" else None)
        assert dataclasses.replace(b, turbulence=None) == a
    assert Campaign.from_dict(tomllib.loads(calm.to_toml())) == calm
    assert "turbulence = 0.0" not in c.to_toml()
    assert main(["simulate", "--calm-sweeps", "--print-default", "-o", "x.nc"]) == 0
    assert Campaign.from_dict(tomllib.loads(capsys.readouterr().out)) == with_calm_sweeps(
        default_campaign())
    # printing the template needs no output file; flying one does, and says so
    assert main(["simulate", "--print-default"]) == 0
    assert Campaign.from_dict(tomllib.loads(capsys.readouterr().out)) == default_campaign()
    assert main(["simulate"]) != 0
    assert "give -o <campaign.nc>" in capsys.readouterr().err


@pytest.mark.parametrize("change, message", [
    ({"turbulence": -0.1}, "turbulence must be >= 0"),
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


def _with_kinematics(lin):
    """Add phi' = p, theta' = q, psi' = r (deg and deg/s: unit coefficients) at level trim."""
    A = lin.A.copy()
    for angle, rate in (("phi", "p"), ("theta", "q"), ("psi", "r")):
        A.loc[{"state_dot": angle, "state": rate}] = 1.0
    return lin.assign(A=A)


def _level_hover_trim():
    return {c: 0.0 for c in ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi",
                             "ax", "ay", "az")}


def test_closed_loop_modes_match_the_analytic_loops():
    """Decoupled axes: each attitude loop closes to s^2 + (k_r s - D) s + k_x = 0 (weaker on
    the excited axis) and the vertical-speed loop to s = Z_w - k; u, v stay neutral."""
    lin = _with_kinematics(_hover_like_linearization())
    stab = Stabilisation(crossover=0.8, heading_crossover=0.3, vertical_speed_bandwidth=0.4,
                         primary_fraction=0.6, velocity_hold=0.0)
    loops = design_loops(lin, stab)
    modes = closed_loop_modes(lin, loops, stab, _level_hover_trim())
    for excited in CONTROLS:
        roots = [0.0, 0.0, -0.32 - 0.4 * (0.6 if excited == "col" else 1.0)]
        for control_name, rate in (("lat", "p"), ("lon", "q"), ("ped", "r")):
            loop = loops[control_name]
            scale = 0.6 if control_name == excited else 1.0
            damping = float(lin.A.sel(state_dot=rate, state=rate))
            roots += list(np.roots([1.0, scale * loop.k_rate - damping,
                                    scale**2 * loop.k_error]))
        roots = np.array(roots, dtype=complex)
        oscillatory = roots[np.abs(roots.imag) > 1e-6]
        mode = modes.sel(excited=excited)
        assert float(mode.max_real) == pytest.approx(roots.real.max(), abs=1e-6)
        assert float(mode.min_damping) == pytest.approx(
            np.min(-oscillatory.real / np.abs(oscillatory)), rel=1e-6)


def test_preflight_check_refuses_unstable_holds_and_warns_on_light_damping():
    """The design compensates the bare-airframe rate damping D, but the weaker hold on the
    excited axis (scale f) leaves s^2 + (f k_r - D) s + f^2 k_x: unstable when f k_r < D."""
    lin = _with_kinematics(_hover_like_linearization())
    unstable = lin.copy(deep=True)
    unstable.A.loc[{"state_dot": "q", "state": "q"}] = 3.0  # k_r = 3.42; 0.8 k_r < 3
    stab = Stabilisation(crossover=0.3, velocity_hold=0.0, primary_fraction=0.8)
    campaign = Campaign(name="c", maneuvers=[Maneuver("sweep_lon_1", "sweep", "lon", 5.0)],
                        stabilisation=stab)
    loops = design_loops(unstable, stab)
    with pytest.raises(InputDataError, match="lon excited.*unstable"):
        preflight_check(unstable, loops, campaign, _level_hover_trim())
    # Lightly damped: 0.45 k_r - D = 0.024 with D = 0.3, k_r = 0.72. Warned, not refused.
    light = lin.copy(deep=True)
    light.A.loc[{"state_dot": "p", "state": "p"}] = 0.3
    stab = Stabilisation(crossover=0.3, velocity_hold=0.0, primary_fraction=0.45)
    campaign = Campaign(name="c", maneuvers=[Maneuver("sweep_lat_1", "sweep", "lat", 5.0)],
                        stabilisation=stab)
    loops = design_loops(light, stab)
    with pytest.warns(UserWarning, match="damping ratio"):
        modes = preflight_check(light, loops, campaign, _level_hover_trim())
    assert 0 < float(modes.min_damping.sel(excited="lat")) < 0.1
    # Stabilisation off: nothing to check.
    off = dataclasses.replace(campaign, stabilisation=Stabilisation(enabled=False))
    assert preflight_check(unstable, loops, off, _level_hover_trim()) is None
