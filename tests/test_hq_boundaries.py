"""ADS-33E-PRF Level boundaries against public sources, the phase-branch rule and the removal
of the campaign's zero-order hold (fast: analytic responses only).

Truth here is independent of the code under test: the one boundary value a public source
confirms (Padfield's Fig. 6.64, from ADS-33), a qualitative statement of the hover/low-speed
criteria, phases assembled factor by factor from a transfer function (continuous by
construction, no unwrapping) and the exact zero-order-hold equivalent of a state-space model
(matrix exponential), and the nonlinear truth FMU flown at small amplitude.
"""

from __future__ import annotations

import dataclasses
import math

import numpy as np
import pytest
import scipy.linalg
import scipy.optimize
import xarray as xr

from sysid.assess.handling_qualities import (ADS33_BOUNDARIES, ADS33_CONFIRMED, ADS33_SOURCE,
                                             MTES, ads33_level, bandwidth_phase_delay,
                                             boundary_bandwidth, carries_sample_hold,
                                             describing_function, sweep_amplitude,
                                             zero_order_hold)
from sysid.assess.margins import crossings, linear_replay
from sysid.data.campaign import CampaignData
from sysid.flight_test.campaign import Maneuver, default_campaign, excitation, run_campaign
from sysid.signals import inputs

# -- Level boundaries -------------------------------------------------------------------------


def test_yaw_tracking_level_1_starts_at_the_published_3_5_rad_s():
    """Padfield, Helicopter Flight Dynamics, 2nd ed., 2007, Fig. 6.64(a) (ADS-33 yaw
    bandwidth, hover/low speed target acquisition and tracking): 'Level 1 boundary at
    3.5 rad/s'. Below 3.5 rad/s no phase delay gives Level 1; just above it, with a small
    phase delay, the point is Level 1."""
    assert ads33_level(3.6, 0.0, axis="yaw", mte="tracking") == 1
    for tau in (0.0, 0.05, 0.1, 0.2):
        assert ads33_level(3.4, tau, axis="yaw", mte="tracking") in (2, 3), tau
        assert ads33_level(3.0, tau, axis="yaw", mte="tracking") in (2, 3), tau
    value, source = ADS33_CONFIRMED[("yaw", "tracking", "L1")]
    assert value == 3.5 and "Fig. 6.64" in source


def test_yaw_minimum_bandwidths_are_above_the_pitch_ones():
    """Hover/low-speed criteria: the yaw bandwidth criterion is like the pitch one with higher
    minimum limits (heli-air.net, 'HLSR - Yaw Axis Response Criteria', 2016, summarising
    ADS-33). A bandwidth just at the pitch minimum is therefore below Level 1 in yaw."""
    for mte in MTES:
        for level in ("L1", "L2"):
            w_pitch = float(boundary_bandwidth(ADS33_BOUNDARIES[("pitch", mte)][level], 0.0))
            w_yaw = float(boundary_bandwidth(ADS33_BOUNDARIES[("yaw", mte)][level], 0.0))
            assert w_yaw > w_pitch, (mte, level)
        w_pitch_l1 = float(boundary_bandwidth(ADS33_BOUNDARIES[("pitch", mte)]["L1"], 0.0))
        assert ads33_level(w_pitch_l1, 0.0, axis="yaw", mte=mte) > 1, mte


def test_unverified_boundaries_say_so():
    """Only what a public source confirms is presented as confirmed: every confirmed entry is a
    boundary of the table at that value, and the source string calls the rest unverified."""
    for (axis, mte, level), (value, source) in ADS33_CONFIRMED.items():
        assert float(boundary_bandwidth(ADS33_BOUNDARIES[(axis, mte)][level], 0.0)) == value
        assert source
    assert "unverified" in ADS33_SOURCE
    assert len(ADS33_CONFIRMED) < 2 * len(ADS33_BOUNDARIES)


def test_an_unknown_axis_or_mte_is_refused():
    with pytest.raises(Exception, match="no ADS-33E-PRF boundary"):
        ads33_level(2.0, 0.1, axis="heave", mte="tracking")


# -- crossings and the phase branch -----------------------------------------------------------


def test_crossings_can_keep_only_falling_ones():
    w = np.array([1.0, 10.0, 100.0])
    y = [0.0, 1.0, 0.0]
    assert crossings(w, y, 0.5, direction="up") == pytest.approx([math.sqrt(10)])
    assert crossings(w, y, 0.5, direction="down") == pytest.approx([math.sqrt(1000)])
    with pytest.raises(Exception, match="direction"):
        crossings(w, y, 0.5, direction="sideways")


#: An attitude response with an unstable low-frequency oscillation (like the hover's
#: pitch-roll mode): K e^{-tau s} wq^2 / (s (s^2 - 2 zp wp s + wp^2) (s^2 + 2 zq wq s + wq^2)
#: (s/p + 1)). Its phase is positive between wp and wq.
K, TAU, WP, ZP, WQ, ZQ, P = 0.5, 0.03, 0.4, 0.1, 1.5, 0.5, 10.0


def _response(w):
    s = 1j * w
    return (K * WQ**2 * np.exp(-TAU * s)
            / (s * (s**2 - 2 * ZP * WP * s + WP**2) * (s**2 + 2 * ZQ * WQ * s + WQ**2)
               * (s / P + 1)))


def _phase(w):
    """The phase of :func:`_response` (deg) as a sum of continuous factor phases."""
    unstable = -np.degrees(np.arctan2(-2 * ZP * WP * w, WP**2 - w**2))  # 0 -> +180
    stable = -np.degrees(np.arctan2(2 * ZQ * WQ * w, WQ**2 - w**2))     # 0 -> -180
    return -90.0 + unstable + stable - np.degrees(np.arctan(w / P)) - np.degrees(TAU * w)


def test_branch_is_right_when_the_band_starts_where_the_phase_is_positive():
    """The band starts at 0.45 rad/s, where the phase is about +28 deg: the bandwidth, the
    phase delay and omega_180 are those of the analytic phase (root finding), to 0.1 %."""
    ref = 0.45
    assert _phase(ref) > 0
    w180 = scipy.optimize.brentq(lambda w: _phase(w) + 180.0, 2.0, 30.0)
    wbw = scipy.optimize.brentq(lambda w: _phase(w) + 135.0, 2.0, w180)
    tau_p = -(_phase(2 * w180) + 180.0) / (57.3 * 2 * w180)
    g180 = abs(_response(np.array([w180]))[0])
    wg = scipy.optimize.brentq(lambda w: abs(_response(np.array([w]))[0]) - g180 * 10**0.3,
                               ref, w180)
    w = np.logspace(-1.5, 2, 6000)
    out = bandwidth_phase_delay(w, _response(w), omega_ref=ref, branch_band=(ref, 20.0))
    assert out["omega_180"] == pytest.approx(w180, rel=1e-3)
    assert out["bandwidth_phase"] == pytest.approx(wbw, rel=1e-3)
    assert out["bandwidth_gain"] == pytest.approx(wg, rel=1e-3)
    assert out["bandwidth"] == pytest.approx(min(wbw, wg), rel=1e-3)
    assert out["tau_p"] == pytest.approx(tau_p, abs=2e-4)


def test_without_a_minus_180_crossing_the_phase_bandwidth_governs():
    """K / (s (s + a)) never reaches -180 deg: its phase bandwidth is a (phase -90 - 45),
    omega_180, the gain bandwidth and tau_p are undefined (a quasi-steady model)."""
    a = 2.5
    w = np.logspace(-1, 2, 3000)
    out = bandwidth_phase_delay(w, 4.0 / (1j * w * (1j * w + a)))
    assert out["bandwidth_phase"] == pytest.approx(a, rel=1e-4)
    assert out["bandwidth"] == pytest.approx(a, rel=1e-4) and out["governing"] == "phase"
    assert all(math.isnan(out[k]) for k in ("omega_180", "bandwidth_gain", "tau_p"))


# -- the campaign's zero-order hold -----------------------------------------------------------


def test_dividing_out_the_hold_recovers_the_continuous_bandwidth_and_phase_delay():
    """Data sampled with a 10 ms zero-order hold (recorded at the start of each hold) are the
    exact ZOH equivalent of the continuous system; dividing ``zero_order_hold`` out gives the
    continuous system's bandwidth and phase delay (a rate response with rotor lag: pitch-like,
    roll-like)."""
    dt = 0.01
    for damping, gain, rotor in ((1.2, 8.0, 14.0), (4.0, 40.0, 12.0)):
        # x = (theta, q, rotor): theta' = q, q' = -damping q + gain b, b' = rotor (u - b)
        A = np.array([[0.0, 1.0, 0.0], [0.0, -damping, gain], [0.0, 0.0, -rotor]])
        B = np.array([[0.0], [0.0], [rotor]])
        C = np.array([[1.0, 0.0, 0.0]])
        n = A.shape[0]
        M = np.zeros((n + 1, n + 1))
        M[:n, :n], M[:n, n:] = A * dt, B * dt
        E = scipy.linalg.expm(M)
        Phi, Gamma = E[:n, :n], E[:n, n:]
        w = np.logspace(-1, 2, 4000)
        sampled = np.array([(C @ np.linalg.solve(np.exp(1j * x * dt) * np.eye(n) - Phi,
                                                 Gamma))[0, 0] for x in w])
        continuous = np.array([(C @ np.linalg.solve(1j * x * np.eye(n) - A, B))[0, 0]
                               for x in w])
        truth = bandwidth_phase_delay(w, continuous)
        raw = bandwidth_phase_delay(w, sampled)
        fixed = bandwidth_phase_delay(w, sampled / zero_order_hold(w, dt))
        assert fixed["bandwidth"] == pytest.approx(truth["bandwidth"], rel=1e-3)
        assert fixed["tau_p"] == pytest.approx(truth["tau_p"], abs=1e-4)
        # without the correction the 5 ms hold shows (why it is removed)
        assert raw["tau_p"] - truth["tau_p"] == pytest.approx(dt / 2, abs=1e-3)


def test_only_frequency_domain_fits_carry_the_hold():
    assert carries_sample_hold(xr.Dataset(attrs={"J_ave": 12.0}))
    assert not carries_sample_hold(xr.Dataset(attrs={"J_rms": 1.1}))


# -- linear replay of a campaign ---------------------------------------------------------------


@pytest.mark.fmu
def test_a_small_sweep_replayed_through_the_linearisation_matches_the_fmu():
    """At 0.05 % of pedal (calm, noise-free, no off-axis activity) the truth FMU is linear: the
    replay of its recorded pilot command through /linearization_full with the holds closed
    reproduces the recorded heading, rates and applied pedal to 1 % (the independent truth is
    the nonlinear FMU; a one-sample misalignment of the hold law would leave ~10 % at the
    sweep's 10 rad/s). The replay of the replay is the replay (the pilot command is exact)."""
    base = default_campaign(0.0, seed=7, noise=False)
    campaign = dataclasses.replace(
        base, stabilisation=dataclasses.replace(base.stabilisation, secondary_perturbation=0.0),
        maneuvers=[Maneuver("sweep_ped_small", "sweep", "ped", amplitude=0.05, duration=30.0,
                            omega_min=0.5, omega_max=10.0, long_period_cycles=1.0)])
    tree = run_campaign(campaign, quiet=True)
    recorded = tree["maneuvers/sweep_ped_small"].to_dataset()
    replay = linear_replay(CampaignData(tree, source="small sweep"))
    again = linear_replay(CampaignData(replay, source="replay"))
    out = replay["maneuvers/sweep_ped_small"].to_dataset()
    twice = again["maneuvers/sweep_ped_small"].to_dataset()
    for c in ("psi", "r", "ped", "p", "q", "v"):
        rec = recorded[c].values - recorded[c].values[0]
        rms = np.sqrt(np.mean(rec**2))
        err = np.sqrt(np.mean((out[c].values - recorded[c].values) ** 2))
        assert err <= 0.01 * rms, (c, err, rms)
        np.testing.assert_allclose(twice[c].values, out[c].values, rtol=0, atol=1e-9 * rms)
    assert replay.attrs["linear_replay"] == "linearization_full"
    assert "frequency_response" not in replay.children


# -- the describing function's inputs -----------------------------------------------------------


def test_sweep_amplitude_is_the_envelope_of_the_flown_sweep():
    """The amplitude the describing function flies at omega is the envelope of the campaign's
    pedal sweep where its instantaneous frequency is omega: every peak of the generated signal
    between 0.2 and 3 rad/s is the amplitude at its instantaneous frequency, to 2 % (1.5 % at
    0.26 rad/s, where the amplitude rises fast within a half period and moves the peak)."""
    campaign = default_campaign(0.0)
    sweep = next(m for m in campaign.maneuvers if m.axis == "ped" and m.kind == "sweep")
    dt = 1.0 / campaign.sample_rate
    x = excitation(sweep, dt, seed=0)
    ds = inputs.frequency_sweep("ped", omega_min=sweep.omega_min, omega_max=sweep.omega_max,
                                duration=sweep.duration, dt=dt,
                                long_period_cycles=sweep.long_period_cycles)
    t = np.arange(int(round((ds.attrs["t_dwell"] + ds.attrs["t_exp"]) / dt))) * dt
    omega_t = np.gradient(inputs.sweep_phase(
        t, omega_min=sweep.omega_min, omega_max=sweep.omega_max, t_dwell=ds.attrs["t_dwell"],
        t_exp=ds.attrs["t_exp"], C1=4.0, C2=0.0187), dt)
    a = np.abs(x[int(round(sweep.lead_in / dt)):][:t.size])
    peaks = np.flatnonzero((a[1:-1] > a[:-2]) & (a[1:-1] >= a[2:])) + 1
    peaks = peaks[(omega_t[peaks] >= 0.2) & (omega_t[peaks] <= 3.0)]
    assert peaks.size > 5
    np.testing.assert_allclose(sweep_amplitude(sweep, omega_t[peaks]), a[peaks], rtol=0.02)
    assert float(sweep_amplitude(sweep, 5.0)) == sweep.amplitude


def test_describing_function_refuses_what_it_cannot_fly():
    campaign = default_campaign(0.0)
    with pytest.raises(Exception, match="axis 'heave'"):
        describing_function(campaign, omega=[0.3], axis="heave")
    with pytest.raises(Exception, match="ascending"):
        describing_function(campaign, omega=[0.5, 0.3])
    with pytest.raises(Exception, match="no sweep on 'ped'"):
        describing_function(campaign.select("3211_*"), omega=[0.3])
    with pytest.raises(Exception, match="a sine needs omega_min"):
        Maneuver("s", "sine", "ped", omega_min=0.0).validate()
