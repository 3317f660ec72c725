"""Tests of sysid.signals.inputs against definitions and analytic spectra."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy import signal

from sysid.signals import inputs
from sysid.core.errors import InputDataError

AXES = ("lon", "lat", "col", "ped")


def _runs(x):
    """(start, length, value) of the constant non-zero runs of ``x``."""
    edges = np.flatnonzero(np.diff(x) != 0) + 1
    starts = np.concatenate([[0], edges])
    ends = np.concatenate([edges, [x.size]])
    return [(s, e - s, x[s]) for s, e in zip(starts, ends) if x[s] != 0]


# --------------------------------------------------------------------------------------------
# peak factor


def test_peak_factor_definition():
    t = np.linspace(0, 10, 100001)
    assert inputs.peak_factor(3 * np.sin(2 * np.pi * t)) == pytest.approx(1.0, rel=1e-4)
    # square wave: (2a) / (2 sqrt(2) a)
    assert inputs.peak_factor(np.sign(np.sin(2 * np.pi * t + 0.1))) == pytest.approx(
        1 / math.sqrt(2), rel=1e-3)
    with pytest.raises(InputDataError):
        inputs.peak_factor(np.zeros(5))


# --------------------------------------------------------------------------------------------
# frequency sweep


def _band_energies(x, dt, edges):
    """Energy (x^2 s) of ``x`` in each band between consecutive ``edges`` (rad/s), from the
    periodogram.

    The sweep record starts and ends at zero (trim lead-in/out), so a rectangular window
    of the whole record has no leakage and the periodogram is its energy spectrum.
    """
    # zero-padded to 16x: fine frequency resolution, same energy
    nfft = 16 * x.size
    f, p = signal.periodogram(x, fs=1 / dt, window="boxcar", detrend=False, nfft=nfft)
    w = 2 * np.pi * f
    energy = p * (f[1] - f[0]) * x.size * dt
    return np.array([energy[(w >= lo) & (w < hi)].sum() for lo, hi in zip(edges[:-1], edges[1:])])


def _band_levels(x, dt, edges, per):
    """Band levels (dB re their median) of the autospectrum per unit log-frequency
    (``per="log"``) or per rad/s (``per="rad/s"``)."""
    e = _band_energies(x, dt, edges)
    width = np.log(edges[1:] / edges[:-1]) if per == "log" else np.diff(edges)
    level = 10 * np.log10(e / width)
    return level - np.median(level)


def test_sweep_autospectrum_covers_the_band_within_10_db():
    wmin, wmax, amp, dt = 0.3, 20.0, 10.0, 0.01
    ds = inputs.frequency_sweep("lon", omega_min=wmin, omega_max=wmax, amplitude=amp, dt=dt)
    x = ds["lon"].values
    # energy per third-octave band = autospectrum per unit log-frequency, the measure on the
    # log frequency axis where responses are identified
    edges = wmin * 2 ** (np.arange(0, 40) / 3)
    edges = edges[edges <= wmax * 1.0001]
    dev = _band_levels(x, dt, edges, per="log")
    print(f"sweep band levels re median (dB): {np.round(dev, 2)}")
    assert edges[0] == wmin and edges[-1] > 0.79 * wmax
    assert np.all(np.abs(dev) < 10.0), dev


def test_default_campaign_sweeps_autospectrum_within_10_db_per_rad_s():
    """The sweeps the default campaign flies: autospectrum per rad/s (Gxx, Eq. 3), averaged
    over bands of a third of an octave or less from 0.1 to 20 rad/s, within 10 dB of its
    median. A constant-amplitude sweep cannot do this (it spends 55x longer per rad/s at
    the bottom than at the top, plus the long-period dwell: +18/-8 dB); the campaign's
    low-frequency amplitude schedule, there to bound the attitude excursions, also flattens
    the spectrum."""
    from sysid.flight_test.campaign import default_campaign, excitation

    dt = 0.01
    for m in default_campaign(0.0).maneuvers:
        if m.kind != "sweep":
            continue
        x = excitation(m, dt, seed=1)
        n_bands = math.ceil(3 * math.log2(m.omega_max / m.omega_min))
        edges = np.geomspace(m.omega_min, m.omega_max, n_bands + 1)
        dev = _band_levels(x, dt, edges, per="rad/s")
        print(f"{m.name}: band levels per rad/s re median {dev.min():+.1f} .. "
              f"{dev.max():+.1f} dB")
        assert np.all(np.abs(dev) < 10.0), (m.name, np.round(dev, 1))


def test_sweep_energy_matches_stationary_phase_prediction():
    """Energy in a band = (A^2 / 2) x time the sweep spends in it (independent of the
    implementation: time from inverting the sweep law omega(t))."""
    wmin, wmax, amp, dt, C1, C2 = 0.3, 20.0, 10.0, 0.01, 4.0, 0.0187
    ds = inputs.frequency_sweep("lat", omega_min=wmin, omega_max=wmax, amplitude=amp, dt=dt)
    x = ds["lat"].values
    t_exp = ds.attrs["t_exp"]
    T = C1 * t_exp / math.log(1 + 1 / C2)  # K(t_exp) = 1

    def time_at(w):  # inverse of omega = wmin + C2 (exp(C1 t/T) - 1)(wmax - wmin)
        return T / C1 * math.log(1 + (w - wmin) / (C2 * (wmax - wmin)))

    edges = np.geomspace(0.6, 18.0, 9)
    for lo, hi, measured in zip(edges[:-1], edges[1:], _band_energies(x, dt, edges)):
        predicted = 0.5 * amp ** 2 * (time_at(hi) - time_at(lo))
        assert 10 * np.log10(measured / predicted) == pytest.approx(0.0, abs=0.5), (lo, hi)
    # total energy: dwell + exponential part at mean square A^2/2
    assert np.sum(x ** 2) * dt == pytest.approx(
        0.5 * amp ** 2 * (ds.attrs["t_dwell"] + t_exp), rel=1e-2)


def test_sweep_shape_lead_in_and_final_frequency():
    dt = 0.01
    ds = inputs.frequency_sweep("col", omega_min=0.4, omega_max=15.0, duration=80.0,
                                amplitude=12.0, lead_in=2.0, lead_out=4.0, dt=dt)
    x = ds["col"].values
    t = ds.time.values
    assert t[0] == 0.0 and np.allclose(np.diff(t), dt)
    assert t[-1] == pytest.approx(2.0 + 80.0 + 4.0)
    assert np.all(x[t < 2.0] == 0.0) and np.all(x[t > 2.0 + 80.0] == 0.0)
    assert np.abs(x).max() == pytest.approx(12.0, rel=1e-3)
    # dwell: first two cycles at omega_min (zero crossings every pi / omega_min)
    on = np.flatnonzero(x)
    sweep = x[on[0] - 1:on[-1] + 2]
    crossings = np.flatnonzero(np.sign(sweep[1:]) * np.sign(sweep[:-1]) < 0) * dt
    assert np.diff(crossings[:4]) == pytest.approx(np.full(3, math.pi / 0.4), abs=2 * dt)
    # the final half-cycles are at omega_max: half period pi / omega
    zc = []
    for i in np.flatnonzero(np.sign(sweep[1:]) * np.sign(sweep[:-1]) < 0):
        zc.append(i + sweep[i] / (sweep[i] - sweep[i + 1]))  # linear interpolation
    zc = np.array(zc) * dt
    assert math.pi / (zc[-1] - zc[-2]) == pytest.approx(15.0, rel=0.03)
    # starts and ends without a step
    assert abs(sweep[1]) < 12.0 * 0.4 * dt * 1.01 and abs(x[on[-1]]) < 12.0 * 15.0 * dt


def test_sweep_amplitude_shape_delays_the_rise():
    """With the same phase, the shaped sweep over the linear one is the ratio of their
    schedules, (f + (1 - f) x^k) / (f + (1 - f) x) with x the log-frequency position: 1 at
    the start and from full_amplitude_omega on, its minimum in between known in closed form."""
    f, k = 0.15, 3.0
    kw = dict(omega_min=0.1, omega_max=20.0, duration=150.0, amplitude=8.0,
              long_period_cycles=1.0, low_frequency_fraction=f, full_amplitude_omega=1.2)
    linear = inputs.frequency_sweep("lat", **kw)
    shaped = inputs.frequency_sweep("lat", amplitude_shape=k, **kw)
    assert shaped.attrs["amplitude_shape"] == k and linear.attrs["amplitude_shape"] == 1.0
    a, b = linear["lat"].values, shaped["lat"].values
    moving = np.abs(a) > 0.05
    ratio = b[moving] / a[moving]
    x = np.linspace(0.0, 1.0, 100001)
    expected_min = np.min((f + (1 - f) * x ** k) / (f + (1 - f) * x))
    assert ratio.min() == pytest.approx(expected_min, abs=2e-3)
    assert ratio.max() == pytest.approx(1.0, abs=1e-9)
    assert np.abs(b).max() == pytest.approx(8.0, rel=1e-3)
    with pytest.raises(InputDataError, match="amplitude_shape"):
        inputs.frequency_sweep("lat", amplitude_shape=0.0, **kw)


def test_sweep_rejects_bad_parameters():
    with pytest.raises(InputDataError, match="axis"):
        inputs.frequency_sweep("yaw")
    with pytest.raises(InputDataError, match="Nyquist"):
        inputs.frequency_sweep("lon", omega_max=200.0, dt=0.01)
    with pytest.raises(InputDataError, match="long-period|cycles"):
        inputs.frequency_sweep("lon", omega_min=0.1, duration=90.0)
    with pytest.raises(ValueError, match="seed"):
        inputs.frequency_sweep("lon", perturbation=0.2)


def test_sweep_perturbation_is_seeded_and_band_limited():
    a = inputs.frequency_sweep("ped", perturbation=0.3, seed=11)
    b = inputs.frequency_sweep("ped", perturbation=0.3, seed=11)
    c = inputs.frequency_sweep("ped", perturbation=0.3, seed=12)
    clean = inputs.frequency_sweep("ped")
    assert a["ped"].values.tobytes() == b["ped"].values.tobytes()
    assert not np.array_equal(a["ped"].values, c["ped"].values)
    noise = a["ped"].values - clean["ped"].values
    on = clean["ped"].values != 0
    sweep_rms = np.sqrt(np.mean(clean["ped"].values[on] ** 2))
    assert np.sqrt(np.mean(noise[on] ** 2)) / sweep_rms == pytest.approx(0.3, rel=0.02)
    assert np.all(noise[: 300] == 0.0)
    assert a.attrs["seed"] == 11 and clean.attrs["seed"] == -1


# --------------------------------------------------------------------------------------------
# multisteps


@pytest.mark.parametrize("kind, widths, func", [
    ("3211", (3, 2, 1, 1), inputs.input_3211),
    ("2311", (2, 3, 1, 1), inputs.input_2311),
    ("doublet", (1, 1), inputs.doublet),
])
@pytest.mark.parametrize("sign", [1, -1])
def test_multistep_widths_and_signs_exact(kind, widths, func, sign):
    dt, base, amp, lead_in = 0.01, 0.7, 4.5, 1.5
    ds = func("lat", base_width=base, amplitude=amp, sign=sign, dt=dt, lead_in=lead_in,
              lead_out=5.0)
    x = ds["lat"].values
    runs = _runs(x)
    assert [n for _, n, _ in runs] == [round(w * base / dt) for w in widths]
    assert [v for _, _, v in runs] == [sign * (-1) ** i * amp for i in range(len(widths))]
    # first edge exactly on the sample at t = lead_in; pulses are contiguous
    t = ds.time.values
    assert runs[0][0] == 150 and t[runs[0][0]] == pytest.approx(lead_in, abs=1e-12)
    assert all(runs[i][0] + runs[i][1] == runs[i + 1][0] for i in range(len(runs) - 1))
    end = runs[-1][0] + runs[-1][1]
    assert np.all(x[end:] == 0) and (x.size - 1 - end) * dt == pytest.approx(5.0)
    assert ds.attrs["kind"] == kind and ds.attrs["hold"] == "previous"


def test_multistep_rejects_widths_off_the_grid():
    with pytest.raises(InputDataError, match="whole number of samples"):
        inputs.input_3211("lon", base_width=0.505, amplitude=1.0, dt=0.01)
    with pytest.raises(InputDataError, match="kind"):
        inputs.multistep("4321", "lon", base_width=1.0, amplitude=1.0)


# --------------------------------------------------------------------------------------------
# multisines


@pytest.mark.parametrize("deal, ripple_db", [("round-robin", 2.0), ("dyadic", 2.0),
                                             ("round-robin", 0.0), ("dyadic", 0.0)])
def test_multisines_orthogonal_flat_and_low_peak_factor(deal, ripple_db):
    wmin, wmax, T, amp, dt = 0.3, 20.0, 90.0, 10.0, 0.01
    ds = inputs.orthogonal_multisines(AXES, omega_min=wmin, omega_max=wmax, duration=T,
                                      amplitude=amp, dt=dt, deal=deal, ripple_db=ripple_db)
    assert ds.attrs["deal"] == deal and ds.attrs["ripple_db"] == ripple_db
    x = np.stack([ds[a].values for a in AXES])
    n = x.shape[1]
    assert n == round(T / dt)
    corr = np.corrcoef(x)
    off = np.abs(corr[~np.eye(4, dtype=bool)])
    print(f"max |correlation| between axes: {off.max():.2e}")
    assert off.max() < 0.05
    # each axis owns its harmonics, amplitudes within ripple_db (as reported), and together
    # they tile the band
    spectra = np.abs(np.fft.rfft(x, axis=1)) / (n / 2)
    w = 2 * np.pi * np.fft.rfftfreq(n, dt)
    band = (w >= wmin - 1e-9) & (w <= wmax + 1e-9)
    owned = spectra > 1e-6 * spectra.max()
    assert np.all(owned.sum(axis=0)[band] == 1) and not owned[:, ~band].any()
    for a, row, mask in zip(AXES, spectra, owned):
        assert row[mask] == pytest.approx(ds.attrs[f"harmonic_amplitudes_{a}"], rel=1e-9)
        spread = 20 * np.log10(row[mask].max() / row[mask].min())
        assert spread <= ripple_db + 1e-9
    # peak = amplitude; starts near zero (no step from trim)
    assert np.abs(x).max(axis=1) == pytest.approx(np.full(4, amp))
    assert np.all(np.abs(x[:, 0]) < 0.05 * amp)

    pf = np.array([inputs.peak_factor(r) for r in x])
    for a, p in zip(AXES, pf):
        assert ds.attrs[f"peak_factor_{a}"] == pytest.approx(p, rel=1e-9)
    sweep = inputs.frequency_sweep("lon", omega_min=wmin, omega_max=wmax, duration=T - 6.0,
                                   amplitude=amp, dt=dt, lead_in=3.0, lead_out=3.0)
    pf_sweep = inputs.peak_factor(sweep["lon"])
    schroeder = inputs.orthogonal_multisines(AXES, omega_min=wmin, omega_max=wmax,
                                             duration=T, amplitude=amp, dt=dt,
                                             optimise=False, deal=deal)
    pf_schroeder = np.array([schroeder.attrs[f"peak_factor_{a}"] for a in AXES])
    print(f"peak factors ({deal}, {ripple_db} dB): multisine {np.round(pf, 4)}, Schroeder only "
          f"{np.round(pf_schroeder, 4)}, sweep {pf_sweep:.4f}")
    # optimisation lowers every axis's peak factor below the Schroeder start
    assert np.all(pf < pf_schroeder)
    if deal == "dyadic" or ripple_db > 0:
        # every one of the four simultaneous inputs has a lower peak factor than one sweep
        # of the same band, amplitude and record length (the default: round-robin, 2 dB)
        assert np.all(pf < pf_sweep)
    else:
        # equal amplitudes, round-robin: the two axes holding odd harmonics (k = 1, 3 mod 4)
        # stay near 1.05 (see the docstring): on average below the sweep, none 3 % above it
        assert pf.mean() < pf_sweep
        assert pf.max() < 1.03 * pf_sweep


def test_multisines_dyadic_deal_halves_the_lines_axis_by_axis():
    ds = inputs.orthogonal_multisines(AXES, omega_min=0.3, omega_max=20.0, duration=90.0,
                                      dt=0.01, optimise=False, deal="dyadic")
    k = {a: ds.attrs[f"harmonics_{a}"] for a in AXES}
    assert np.all(k["lon"] % 2 == 1) and np.all(k["lat"] % 4 == 2)
    assert np.all(k["col"] % 8 == 4) and np.all(k["ped"] % 8 == 0)
    assert [v.size for v in k.values()] == [141, 71, 35, 35]
    assert np.array_equal(np.sort(np.concatenate(list(k.values()))), np.arange(5, 287))
    # one or two axes: the same lines as round-robin when the band starts at an odd harmonic
    kw = dict(omega_min=0.3, omega_max=20.0, duration=90.0, dt=0.01, optimise=False)
    for axes in (["lon"], ["lon", "lat"]):
        a = inputs.orthogonal_multisines(axes, deal="dyadic", **kw)
        b = inputs.orthogonal_multisines(axes, **kw)
        for ax in axes:
            assert np.array_equal(a.attrs[f"harmonics_{ax}"], b.attrs[f"harmonics_{ax}"])
    with pytest.raises(InputDataError, match="deal"):
        inputs.orthogonal_multisines(AXES, deal="snake", **kw)
    # 11 lines (k = 2..12) are enough for 4 axes round-robin, not dyadic (ped gets k = 8 only)
    short = dict(omega_min=1.0, omega_max=8.0, duration=10.0, optimise=False)
    inputs.orthogonal_multisines(AXES, **short)
    with pytest.raises(InputDataError, match="harmonics"):
        inputs.orthogonal_multisines(AXES, deal="dyadic", **short)


def test_multisines_seeded_restarts_are_reproducible():
    kw = dict(omega_min=0.5, omega_max=10.0, duration=40.0, amplitude=5.0, dt=0.02,
              restarts=1)
    a = inputs.orthogonal_multisines(["lon", "lat"], seed=4, **kw)
    b = inputs.orthogonal_multisines(["lon", "lat"], seed=4, **kw)
    for ax in ("lon", "lat"):
        assert a[ax].values.tobytes() == b[ax].values.tobytes()
    with pytest.raises(InputDataError, match="harmonics"):
        inputs.orthogonal_multisines(AXES, omega_min=1.0, omega_max=1.5, duration=10.0)


# --------------------------------------------------------------------------------------------
# Dryden turbulence


def _dryden_psd(comp, w, sigma, L, V):
    """MIL-F-8785C one-sided spectra in rad/s."""
    x = (L * w / V) ** 2
    if comp == "u":
        return sigma ** 2 * 2 * L / (math.pi * V) / (1 + x)
    return sigma ** 2 * L / (math.pi * V) * (1 + 3 * x) / (1 + x) ** 2


def test_dryden_low_altitude_parameters():
    h = 150.0  # m
    p = inputs.dryden_parameters(h, "moderate")
    h_ft = h / 0.3048
    assert p["sigma_w"] == pytest.approx(0.1 * 30 * 1852 / 3600)
    assert p["sigma_u"] == pytest.approx(p["sigma_w"] / (0.177 + 0.000823 * h_ft) ** 0.4)
    assert p["L_w"] == pytest.approx(h)
    assert p["L_u"] == pytest.approx(h_ft / (0.177 + 0.000823 * h_ft) ** 1.2 * 0.3048)
    assert inputs.dryden_parameters(h, 1.5)["sigma_w"] == 1.5
    with pytest.raises(InputDataError, match="intensity"):
        inputs.dryden_parameters(h, "extreme")


def test_dryden_variance_and_spectra_match_the_standard():
    dt, V, h, duration = 0.1, 40.0, 150.0, 4000.0
    seeds = (1, 2, 3, 4)
    runs = [inputs.dryden_turbulence(duration, dt=dt, airspeed=V, altitude=h,
                                     intensity="moderate", seed=s) for s in seeds]
    p = inputs.dryden_parameters(h, "moderate")
    for comp in ("u", "v", "w"):
        data = np.stack([r[f"{comp}_gust"].values for r in runs])
        sigma, L = p[f"sigma_{comp}"], p[f"L_{comp}"]
        rms = np.sqrt(np.mean(data ** 2))
        # independent records of ~550 correlation times each: a few % statistical error
        assert rms == pytest.approx(sigma, rel=0.08), comp
        f, psd = signal.welch(data, fs=1 / dt, nperseg=4096, axis=-1)
        w, psd = 2 * np.pi * f, psd.mean(axis=0) / (2 * np.pi)  # per rad/s
        edges = np.geomspace(0.05, 5.0, 7)
        for lo, hi in zip(edges[:-1], edges[1:]):
            band = (w >= lo) & (w < hi)
            ratio = psd[band].mean() / _dryden_psd(comp, w[band], sigma, L, V).mean()
            assert ratio == pytest.approx(1.0, rel=0.15), (comp, lo, hi, ratio)


def test_dryden_seeds_and_hover_floor():
    kw = dict(dt=0.05, airspeed=0.0, altitude=30.0, intensity=1.0)
    a = inputs.dryden_turbulence(60.0, seed=5, **kw)
    b = inputs.dryden_turbulence(60.0, seed=5, **kw)
    c = inputs.dryden_turbulence(60.0, seed=6, **kw)
    for v in ("u_gust", "v_gust", "w_gust"):
        assert a[v].values.tobytes() == b[v].values.tobytes()
        assert not np.array_equal(a[v].values, c[v].values)
        assert a[v].attrs["units"] == "m/s"
        assert np.all(np.isfinite(a[v].values))
    assert a.attrs["convection_speed"] == inputs.MIN_GUST_AIRSPEED
    assert a.sizes["time"] == 1201 and a.time.values[-1] == pytest.approx(60.0)
    with pytest.raises(InputDataError, match="seed"):
        inputs.dryden_turbulence(10.0, dt=0.1, airspeed=10.0, altitude=50.0, seed=None)


def test_sweep_amplitude_schedule_follows_instantaneous_frequency():
    from sysid.signals.inputs import frequency_sweep

    full = frequency_sweep("lon", omega_min=0.2, omega_max=20.0, duration=90.0, amplitude=8.0,
                           lead_in=0.0, lead_out=0.0, long_period_cycles=1.0)
    shaped = frequency_sweep("lon", omega_min=0.2, omega_max=20.0, duration=90.0,
                             amplitude=8.0, lead_in=0.0, lead_out=0.0, long_period_cycles=1.0,
                             low_frequency_fraction=0.25, full_amplitude_omega=2.0)
    t_dwell = shaped.attrs["t_dwell"]
    dwell = shaped.time < t_dwell
    # During the long-period cycle (omega = omega_min) the amplitude is the given fraction.
    assert float(abs(shaped.lon.where(dwell)).max()) == pytest.approx(2.0, rel=1e-3)
    # Once the sweep is past 2 rad/s both signals are identical.
    omega = np.gradient(np.unwrap(np.angle(signal.hilbert(full.lon.values))), 0.01)
    late = (shaped.time > t_dwell).values & (omega > 2.5)
    late &= np.arange(late.size) < late.size - 200   # away from the Hilbert edge effect
    np.testing.assert_allclose(shaped.lon.values[late], full.lon.values[late], atol=1e-12)
