"""The stabilisation holds compiled into the truth FMU (fmus/helicopter/holds.c) against the
Python reference (sysid.flight_test.campaign._hold_commands), and CoSimulation.run against
CoSimulation.step.

The FMU's law repeats the reference's floating-point operations in the same order (same
libm, no fused multiply-adds), so the campaigns must be equal to the last bit, not to a
tolerance: any difference means the two laws differ.
"""

import dataclasses

import numpy as np
import pytest

from sysid.core.errors import FMUError, SimulationDiverged
from sysid.core.units import CONTROLS
from sysid.flight_test import campaign as cp

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def hover(truth_fmu, hover_trim):
    from sysid import truth

    model = truth.load_fmu(truth_fmu)
    linearization = truth.linearize(hover_trim, fmu=model)
    with truth.CoSimulation(model, outputs=cp.MEASUREMENTS) as sim:
        yield model, hover_trim, linearization, sim


def _short(campaign, names=("sweep_lat_1", "2311_lon", "3211_col", "2311_ped")):
    """A few manoeuvres of ``campaign`` with the sweeps cut to 20 s (test time)."""
    chosen = [dataclasses.replace(m, duration=20.0, omega_min=0.5) if m.kind == "sweep" else m
              for m in campaign.maneuvers if m.name in names]
    return dataclasses.replace(campaign, maneuvers=chosen)


def _fly_both(hover, campaign):
    _, trim, linearization, sim = hover
    loops = cp.design_loops(linearization.quasi_steady, campaign.stabilisation)
    return [{m.name: cp.fly(sim, trim, loops, m, campaign, holds=holds)
             for m in campaign.maneuvers} for holds in ("python", "fmu")]


def _assert_same_bytes(reference, fmu):
    assert reference.keys() == fmu.keys()
    for name in reference:
        a, b = reference[name], fmu[name]
        assert list(a.data_vars) == list(b.data_vars)
        for var in a.data_vars:
            assert a[var].values.tobytes() == b[var].values.tobytes(), (name, var)
        assert a.attrs == b.attrs


@pytest.mark.parametrize("seed", [1, 2])
def test_fmu_holds_fly_the_python_campaign_to_the_last_bit(hover, seed):
    """Default hover campaign (noise, turbulence, off-axis activity, velocity hold)."""
    reference, fmu = _fly_both(hover, _short(cp.default_campaign(seed=seed)))
    _assert_same_bytes(reference, fmu)
    # the holds act: the off-axis controls move by more than the pilot's activity
    sweep = fmu["sweep_lat_1"]
    trim = sweep.attrs
    assert float(abs(sweep["lon"] - trim["trim_lon"]).max()) > 1.0


@pytest.mark.parametrize("variant", ["conditional", "no_velocity_hold", "forward_flight"])
def test_fmu_holds_match_every_branch_of_the_law(hover, variant):
    """Dead bands (conditional holds), no outer velocity loop, and a quiet campaign: the
    branches of the law the default campaign does not take."""
    campaign = _short(cp.default_campaign(seed=5))
    stab = campaign.stabilisation
    if variant == "conditional":
        stab = dataclasses.replace(stab, conditional=True,
                                   dead_band={"attitude": 0.5, "rate": 1.0,
                                              "vertical_speed": 0.3})
    elif variant == "no_velocity_hold":
        stab = dataclasses.replace(stab, velocity_hold=0.0, secondary_perturbation=0.0,
                                   primary_fraction=0.6)
    else:  # the forward-flight stabilisation, flown quietly in hover
        stab = cp.default_campaign(80.0).stabilisation
        campaign = dataclasses.replace(campaign, noise={}, turbulence=0.0)
    reference, fmu = _fly_both(hover, dataclasses.replace(campaign, stabilisation=stab))
    _assert_same_bytes(reference, fmu)


def test_a_manoeuvres_own_turbulence_replaces_the_campaigns(hover):
    """A sweep flown with its own turbulence 0 in a turbulent campaign is, to the last bit,
    the sweep of the same campaign flown in calm air; the campaign's gusts are there without
    the override. The record says what it was flown in."""
    _, trim, linearization, sim = hover
    turbulent = _short(cp.default_campaign(seed=4), names=("sweep_lat_1",))
    loops = cp.design_loops(linearization.quasi_steady, turbulent.stabilisation)
    m = turbulent.maneuvers[0]
    calm = cp.fly(sim, trim, loops, m, dataclasses.replace(turbulent, turbulence=0.0))
    own = cp.fly(sim, trim, loops, dataclasses.replace(m, turbulence=0.0), turbulent)
    gusty = cp.fly(sim, trim, loops, m, turbulent)
    _assert_same_bytes({"a": calm}, {"a": own})
    assert calm.attrs["turbulence_m_s"] == 0.0 and gusty.attrs["turbulence_m_s"] == 0.3
    assert not np.array_equal(gusty["v"].values, calm["v"].values)


def test_holds_off_and_divergence_give_the_same_error(hover):
    """Stabilisation off in hover: the unstable airframe leaves the attitude limit; both
    implementations raise at the same sample naming the manoeuvre, the time and the channel."""
    campaign = cp.Campaign(
        name="unstable", seed=3, stabilisation=cp.Stabilisation(enabled=False),
        maneuvers=[cp.Maneuver("3211_lon", "3211", "lon", amplitude=0.5, duration=1.4,
                               base_width=0.2, lead_in=0.5, lead_out=0.5),
                   cp.Maneuver("sweep_lon_1", "sweep", "lon", amplitude=10.0, duration=60.0,
                               omega_min=0.3, omega_max=2.0, long_period_cycles=1.0)])
    _, trim, linearization, sim = hover
    loops = cp.design_loops(linearization.quasi_steady, campaign.stabilisation)
    small = campaign.maneuvers[0]
    _assert_same_bytes(*[{small.name: cp.fly(sim, trim, loops, small, campaign, holds=h)}
                         for h in ("python", "fmu")])
    errors = []
    for holds in ("python", "fmu"):
        with pytest.raises(SimulationDiverged) as info:
            cp.fly(sim, trim, loops, campaign.maneuvers[1], campaign, holds=holds)
        errors.append(info.value)
    assert str(errors[0]) == str(errors[1])
    assert errors[1].maneuver == "sweep_lon_1" and 0 < errors[1].time < 65
    assert "left trim by more than 60 deg" in str(errors[1])
    # a tighter limit trips earlier, in the velocity channel the sweep drives hardest
    tight = dataclasses.replace(campaign, max_velocity_excursion=5.0)
    messages = []
    for holds in ("python", "fmu"):
        with pytest.raises(SimulationDiverged, match="ft/s") as info:
            cp.fly(sim, trim, loops, tight.maneuvers[1], tight, holds=holds)
        messages.append(str(info.value))
        assert info.value.time < errors[1].time
    assert messages[0] == messages[1]


def test_run_steps_like_step_and_reports_the_envelope_the_same_way(hover):
    """Holds off, gusts on: CoSimulation.run gives step()'s outputs bit for bit, its applied
    controls are the inputs saturated, and full aft stick leaves the envelope with step()'s
    message at the same step."""
    _, trim, _, sim = hover
    rng = np.random.default_rng(7)
    n = 500
    controls = sim.trim_controls + rng.normal(0.0, 3.0, (n, 4))
    controls[:20, 1] = 120.0  # beyond the stop: the FMU saturates it
    gusts = rng.normal(0.0, 2.0, (n, 3))
    sim.reset(trim)
    flight = sim.run(controls, gusts, dt=0.01)
    sim.reset(trim)
    stepped = np.array([sim.step(controls[k], gusts[k], 0.01) for k in range(n)])
    assert flight.failure is None and flight.steps == n
    assert flight.outputs[1:].tobytes() == stepped.tobytes()
    assert flight.applied.tobytes() == np.clip(controls, 0.0, 100.0).tobytes()

    aft = np.tile(sim.trim_controls, (3000, 1))
    aft[:, 0] = 100.0
    sim.name = "runaway"
    sim.reset(trim)
    with pytest.raises(SimulationDiverged, match="left the envelope") as info:
        for k in range(3000):
            sim.step(aft[k])
    sim.reset(trim)
    flight = sim.run(aft, dt=0.01)
    assert str(flight.failure) == str(info.value) and flight.steps == k
    assert flight.failure.maneuver == "runaway"


def test_run_reports_a_discarded_step_like_step(truth_fmu, hover_trim):
    """RK4 sub-steps of 0.5 s overflow the rotor states: fmi2Discard becomes the same
    SimulationDiverged from run() as from step()."""
    from sysid.truth import CoSimulation

    with CoSimulation(truth_fmu, name="coarse", step_size=0.5, envelope={}) as sim:
        sim.reset(hover_trim)
        with pytest.raises(SimulationDiverged, match="non-finite") as info:
            for k in range(200):
                sim.step(sim.trim_controls, dt=0.5)
        sim.reset(hover_trim)
        flight = sim.run(np.tile(sim.trim_controls, (200, 1)), dt=0.5)
    assert str(flight.failure) == str(info.value) and flight.steps == k
    assert flight.outputs.shape[0] == k + 1


def test_model_exchange_applies_the_law_continuously(hover):
    """Model exchange with the holds on: the derivatives equal those of the bare model driven
    by the reference law's command at the same state (no sampling)."""
    from sysid.fmi.runtime import DerivativeFunction
    from sysid.truth.linearize import si_to_analysis

    model, trim, linearization, _ = hover
    campaign = cp.default_campaign()
    stab = campaign.stabilisation
    loops = cp.design_loops(linearization.quasi_steady, stab)
    trim_y = trim.channel_values()
    holds = cp.fmu_hold_parameters(loops, stab, trim_y, "lat")
    pilot = np.array([trim.controls[c] for c in CONTROLS]) + [1.0, -2.0, 0.5, 3.0]
    x = np.array([trim.states[s] for s in model.state_names])
    rng = np.random.default_rng(11)
    x[:9] += rng.normal(0.0, 0.05, 9)  # u v w p q r phi theta psi off trim
    on = DerivativeFunction(model, {**trim.parameters, **holds})
    off = DerivativeFunction(model, trim.parameters)
    try:
        names = list(cp.MEASUREMENTS)
        y = np.array([on.outputs(x, pilot, names)[c] * si_to_analysis(model, c) for c in names])
        fractions = {c: (stab.primary_fraction if c == "lat" else 1.0) for c in CONTROLS}
        command = np.clip(pilot + cp._hold_commands(y, {c: k for k, c in enumerate(names)},
                                                     trim_y, loops, fractions, stab), 0, 100)
        assert np.abs(command - pilot).max() > 0.1  # the state is far enough off trim
        np.testing.assert_array_equal(on(x, pilot), off(x, command))
        applied = on.outputs(x, pilot, [f"{c}_applied" for c in CONTROLS])
        np.testing.assert_array_equal([applied[f"{c}_applied"] for c in CONTROLS], command)
    finally:
        on.close()
        off.close()


def test_hold_parameters_are_validated(hover_trim, truth_fmu):
    from sysid.truth import CoSimulation

    with CoSimulation(truth_fmu) as sim:
        with pytest.raises(FMUError, match="hold_derivative_lon"):
            sim.reset(hover_trim, parameters={"hold_enabled": 1.0})
        with pytest.raises(FMUError, match="hold_enabled must be 0 or 1"):
            sim.reset(hover_trim, parameters={"hold_enabled": 0.5})
