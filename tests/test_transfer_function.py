"""Transfer-function fits, ADS-33E-PRF bandwidth / phase delay and loop margins on analytic
systems whose values are solved here independently (scipy.optimize.brentq on the closed-form
phase and gain equations), not taken from the code under test."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from scipy.optimize import brentq

from sysid.assess.handling_qualities import (ADS33_BOUNDARIES, ads33_level,
                                             bandwidth_phase_delay, boundary_bandwidth)
from sysid.assess.margins import broken_loop_response, crossings, loop_margins
from sysid.identify.frequency_domain import W_G, W_P, coherence_weight
from sysid.identify.transfer_function import (fit_transfer_function, pair_response,
                                              parse_order, roots_table)

OMEGA = np.logspace(-2, 2.5, 4000)


def _second_order(wn, zeta, tau):
    def phase(w):  # rad, continuous
        return -np.arctan2(2 * zeta * wn * w, wn**2 - w**2) - tau * w

    def gain_db(w):
        return 20 * np.log10(wn**2 / np.hypot(wn**2 - w**2, 2 * zeta * wn * w))

    def H(w):
        s = 1j * w
        return wn**2 * np.exp(-tau * s) / (s**2 + 2 * zeta * wn * s + wn**2)

    return phase, gain_db, H


def _rate_lag(K, T, tau):
    def phase(w):
        return -np.pi / 2 - np.arctan(T * w) - tau * w

    def gain_db(w):
        return 20 * np.log10(K / (w * np.hypot(1.0, T * w)))

    def H(w):
        s = 1j * w
        return K * np.exp(-tau * s) / (s * (T * s + 1))

    return phase, gain_db, H


def _expected(phase, gain_db, lo=1e-2, hi=300.0):
    """omega_180, phase and gain bandwidths and tau_p from the closed forms."""
    w180 = brentq(lambda w: phase(w) + np.pi, lo, hi)
    bw_p = brentq(lambda w: phase(w) + 0.75 * np.pi, lo, w180)
    g180 = gain_db(w180)
    bw_g = brentq(lambda w: gain_db(w) - (g180 + 6.0), lo, w180)
    tau_p = -(phase(2 * w180) + np.pi) / (2 * w180)
    return w180, bw_p, bw_g, tau_p


@pytest.mark.parametrize("response_type", ["attitude", "rate"])
@pytest.mark.parametrize("system", [(_second_order, (4.0, 0.7, 0.05)),
                                    (_second_order, (2.5, 0.4, 0.12)),
                                    (_rate_lag, (3.0, 0.1, 0.04)),
                                    (_rate_lag, (6.0, 0.25, 0.08))])
def test_bandwidth_and_phase_delay_match_the_closed_forms(system, response_type):
    make, args = system
    phase, gain_db, H = make(*args)
    w180, bw_p, bw_g, tau_p = _expected(phase, gain_db)
    out = bandwidth_phase_delay(OMEGA, H(OMEGA), response_type=response_type)
    assert out["omega_180"] == pytest.approx(w180, rel=0.01)
    assert out["bandwidth_phase"] == pytest.approx(bw_p, rel=0.01)
    assert out["bandwidth_gain"] == pytest.approx(bw_g, rel=0.01)
    assert out["tau_p"] == pytest.approx(tau_p, rel=0.01)
    governing = bw_p if response_type == "attitude" else min(bw_p, bw_g)
    assert out["bandwidth"] == pytest.approx(governing, rel=0.01)


def test_random_error_gives_the_bandwidth_uncertainty_of_a_shifted_phase():
    """A phase error of (180/pi) eps deg moves the -135 deg crossing by
    sigma_phase / |d phase / d ln omega|: check it against the crossing of the curve shifted by
    one sigma, solved in closed form."""
    phase, gain_db, H = _rate_lag(3.0, 0.1, 0.04)
    eps = 0.02
    out = bandwidth_phase_delay(OMEGA, H(OMEGA), random_error=np.full(OMEGA.size, eps),
                                coherence=np.full(OMEGA.size, 0.9), response_type="attitude")
    bw = brentq(lambda w: phase(w) + 0.75 * np.pi, 0.01, 100)
    shifted = brentq(lambda w: phase(w) + eps + 0.75 * np.pi, 0.01, 100)
    assert out["bandwidth_std"] == pytest.approx(abs(bw - shifted), rel=0.05)
    assert out["coherence_tau_p"] == pytest.approx(0.9)
    assert np.isfinite(out["tau_p_std"]) and out["tau_p_std"] > 0


@pytest.mark.parametrize("K,T,tau", [(2.0, 0.2, 0.05), (0.8, 0.5, 0.1), (5.0, 0.05, 0.02)])
def test_loop_margins_match_the_closed_forms(K, T, tau):
    _, _, L = _rate_lag(K, T, tau)
    wc = brentq(lambda w: K / (w * math.hypot(1.0, T * w)) - 1.0, 1e-3, 1e3)
    pm = 180.0 - 90.0 - math.degrees(math.atan(T * wc) + tau * wc)
    wp = brentq(lambda w: math.pi / 2 + math.atan(T * w) + tau * w - math.pi, 1e-3, 1e3)
    gm_db = -20 * math.log10(K / (wp * math.hypot(1.0, T * wp)))
    m = loop_margins(L(OMEGA), OMEGA)
    assert m["gain_crossover"] == pytest.approx(wc, rel=0.01)
    assert m["phase_margin"] == pytest.approx(pm, rel=0.01)
    assert m["phase_crossover"] == pytest.approx(wp, rel=0.01)
    assert m["gain_margin_db"] == pytest.approx(gm_db, rel=0.01)


def test_loop_margins_of_a_second_order_loop_with_delay():
    wn, zeta, tau, K = 3.0, 0.3, 0.1, 2.0
    phase, gain_db, H = _second_order(wn, zeta, tau)
    wc = brentq(lambda w: gain_db(w) + 20 * math.log10(K), 0.1, 50)
    wp = brentq(lambda w: phase(w) + math.pi, 0.1, 50)
    m = loop_margins(K * H(OMEGA), OMEGA)
    assert m["gain_crossover"] == pytest.approx(wc, rel=0.01)
    assert m["phase_margin"] == pytest.approx(180 + math.degrees(phase(wc)), rel=0.01)
    assert m["gain_margin_db"] == pytest.approx(-(gain_db(wp) + 20 * math.log10(K)), rel=0.01)


def test_broken_loop_of_a_state_feedback_is_the_scalar_loop():
    """x' = a x + b u with u = k x: broken at u the loop is -k b / (s - a)."""
    a, b, k = -1.0, 2.0, -3.0
    A, B, K = np.array([[a]]), np.array([[b, 0.0]]), np.array([[k], [0.0]])
    s = 1j * OMEGA
    L = broken_loop_response(A, B, K, 0, OMEGA)
    np.testing.assert_allclose(L, -k * b / (s - a), rtol=1e-12)
    m = loop_margins(L, OMEGA)
    assert m["gain_crossover"] == pytest.approx(math.sqrt((k * b) ** 2 - a**2), rel=1e-3)


def test_crossings_interpolate_in_log_frequency():
    w = np.array([1.0, 10.0, 100.0])
    assert crossings(w, [0.0, 1.0, 0.0], 0.5) == pytest.approx([math.sqrt(10), math.sqrt(1000)])
    assert crossings(w, [0.0, 1.0, 2.0], 5.0).size == 0


def test_level_boundaries_classify_points():
    for (axis, mte), bounds in ADS33_BOUNDARIES.items():
        w1 = boundary_bandwidth(bounds["L1"], 0.0)
        w2 = boundary_bandwidth(bounds["L2"], 0.0)
        assert w1 > w2 > 0
        assert ads33_level(w1 * 1.01, 0.0, axis=axis, mte=mte) == 1
        assert ads33_level(0.5 * (w1 + w2), 0.0, axis=axis, mte=mte) == 2
        assert ads33_level(w2 * 0.99, 0.0, axis=axis, mte=mte) == 3
        assert ads33_level(np.nan, 0.0, axis=axis, mte=mte) == 0
        # more phase delay never improves the Level
        assert ads33_level(w1 * 1.01, 1.0, axis=axis, mte=mte) >= 2


# -- transfer-function fits -----------------------------------------------------------------


def _fr(H, omega, output="q", input="lon", coherence=0.95):
    return xr.Dataset(
        {"H": (("output", "input", "frequency"), np.asarray(H)[None, None, :]),
         "coherence": (("output", "input", "frequency"),
                       np.full((1, 1, omega.size), coherence)),
         "random_error": (("output", "input", "frequency"),
                          np.full((1, 1, omega.size), 0.02))},
        coords={"output": [output], "input": [input], "frequency": omega})


W_DATA = np.logspace(-0.5, 1.5, 120)


@pytest.mark.parametrize("b0,a1,a0,tau", [(70.0, 13.0, 35.0, 0.03), (20.0, 2.0, 9.0, 0.08)])
def test_second_order_plus_delay_fit_recovers_a_known_system(b0, a1, a0, tau):
    s = 1j * W_DATA
    fit = fit_transfer_function(_fr(b0 * np.exp(-tau * s) / (s**2 + a1 * s + a0), W_DATA),
                                "q/lon", order="0/2", delay=True)
    # the fitted points are interpolated (log omega) from the 120-point grid: J is not 0
    assert fit.J < 1e-4
    np.testing.assert_allclose(fit.numerator, [b0], rtol=1e-3)
    np.testing.assert_allclose(fit.denominator, [1.0, a1, a0], rtol=1e-3)
    assert fit.delay == pytest.approx(tau, abs=1e-4)
    modes = fit.modes()
    poles = np.sort_complex(np.roots([1.0, a1, a0]))
    wn = abs(poles[0])
    got = modes.where(modes.kind == "pole", drop=True)
    np.testing.assert_allclose(np.sort(got.frequency.values), np.sort(np.abs(poles)), rtol=1e-3)
    if poles[0].imag:
        assert float(got.damping[0]) == pytest.approx(a1 / (2 * wn), rel=1e-3)
    assert fit.statistics.identifiable.all()


def test_fit_cost_is_the_cifer_cost_of_the_residual_mismatch():
    """A 0/1 fit (no delay) of a system with a second pole: J equals the CIFER sum written
    out here from docs/methods.md on the fit's own points."""
    s = 1j * W_DATA
    fit = fit_transfer_function(_fr(10.0 / ((s + 2.0) * (0.05 * s + 1.0)), W_DATA, coherence=0.8),
                                "q/lon", order="0/1", delay=False)
    d = fit.data
    T = fit.response(d.omega)
    Hd = 10.0 / ((1j * d.omega + 2.0) * (0.05j * d.omega + 1.0))
    e_db = 20 * np.log10(np.abs(T)) - 20 * np.log10(np.abs(Hd))
    e_ph = (np.angle(T / Hd, deg=True) + 180) % 360 - 180
    J = (20 / d.n_points) * np.sum(coherence_weight(0.8) * (W_G * e_db**2 + W_P * e_ph**2))
    assert fit.J == pytest.approx(J, rel=1e-3)  # points interpolated from the grid
    assert fit.J > 0.01


def test_integrator_held_fixed_and_attitude_from_rate():
    """theta/lon from q/lon by integration; a 0/2 fit with a0 = 0 recovers K/(s (s + a))."""
    s = 1j * W_DATA
    fr = _fr(8.0 * np.exp(-0.05 * s) / (s + 3.0), W_DATA, output="q")
    ds, origin = pair_response(fr, "theta", "lon")
    assert origin == "integrated"
    np.testing.assert_allclose(ds["H"].values[0, 0], fr["H"].values[0, 0] / s)
    fit = fit_transfer_function(fr, "theta/lon", order="0/2", delay=True, fixed={"a0": 0.0})
    np.testing.assert_allclose(fit.denominator, [1.0, 3.0, 0.0], atol=1e-3)
    assert fit.delay == pytest.approx(0.05, abs=1e-4)
    assert "a0" not in fit.statistics.names


def test_bad_orders_and_pairs_are_refused():
    from sysid.core.errors import InputDataError

    for bad in ("2", "a/b", "3/1", "0/0"):
        with pytest.raises(InputDataError):
            parse_order(bad)
    with pytest.raises(InputDataError, match="not in the frequency response"):
        fit_transfer_function(_fr(np.ones(W_DATA.size), W_DATA), "u/lon")
    with pytest.raises(InputDataError, match="not among"):
        fit_transfer_function(_fr(np.ones(W_DATA.size), W_DATA), "q/lon", fixed={"c1": 0})


def test_roots_table_time_constants_and_damping():
    t = roots_table(poles=[-2.0, -1 + 2j, -1 - 2j], zeros=[0.5])
    assert float(t.time_constant[0]) == pytest.approx(0.5)
    assert float(t.frequency[1]) == pytest.approx(math.sqrt(5))
    assert float(t.damping[1]) == pytest.approx(1 / math.sqrt(5))
    assert float(t.time_constant[3]) == pytest.approx(-2.0)  # unstable zero: negative
