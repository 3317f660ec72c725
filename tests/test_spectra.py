"""Windowed spectra (paper Eq. 1-6) against independent references."""

import numpy as np
import pytest
import scipy.signal
import xarray as xr

from sysid.spectral import spectra
from sysid.core.errors import InputDataError


def record(channels: dict, dt: float, **attrs) -> xr.Dataset:
    n = len(next(iter(channels.values())))
    return xr.Dataset({k: ("time", np.asarray(v, float)) for k, v in channels.items()},
                      coords={"time": np.arange(n) * dt}, attrs=attrs)


def noise_records(seed, n_records=2, n=3000, dt=0.01):
    rng = np.random.default_rng(seed)
    out = []
    for r in range(n_records):
        x = rng.normal(size=n)
        y = np.convolve(x, [0.5, 0.3, 0.2], mode="same") + 0.1 * rng.normal(size=n)
        out.append(record({"x": x, "y": y}, dt, maneuver=f"rec{r}"))
    return out


def test_matches_scipy_csd_on_fft_bins():
    """At the DFT bins of the segment, Eq. 1-6 with the sqrt(8/3) Hann correction are exactly
    scipy's one-sided Welch densities (Hann, no detrending), pooled over records by segment
    count."""
    dt, n_win, n_over = 0.01, 200, 160   # 80 % overlap
    recs = noise_records(1)
    sig = spectra.perturbations(recs, ["x", "y"], ["x"])
    k = np.arange(1, 60)
    omega = 2 * np.pi * k / (n_win * dt)
    ds = spectra.window_spectra(sig, ["x"], ["y"], n_win * dt, omega, overlap=0.8)
    num_xy, num_xx, num_yy, count = 0, 0, 0, 0
    for s in sig:
        x, y = s.sel(channel="x").values, s.sel(channel="y").values
        n_seg = (x.size - n_win) // (n_win - n_over) + 1
        kw = dict(fs=1 / dt, window="hann", nperseg=n_win, noverlap=n_over, detrend=False)
        num_xy = num_xy + n_seg * scipy.signal.csd(x, y, **kw)[1][k]
        num_xx = num_xx + n_seg * scipy.signal.welch(x, **kw)[1][k]
        num_yy = num_yy + n_seg * scipy.signal.welch(y, **kw)[1][k]
        count += n_seg
    assert int(ds["n_segments"]) == count
    np.testing.assert_allclose(ds["Gxy"].sel(output="y", input="x"), num_xy / count, rtol=1e-10)
    np.testing.assert_allclose(ds["Gxx"].sel(input="x", input_j="x").real, num_xx / count,
                               rtol=1e-10)
    np.testing.assert_allclose(ds["Gyy"].sel(output="y"), num_yy / count, rtol=1e-10)


def test_exact_dft_between_bins():
    """The transform at an arbitrary frequency is the exact tapered Fourier sum."""
    dt, n = 0.02, 150
    rng = np.random.default_rng(3)
    x = rng.normal(size=(2, 1000))
    omega = np.array([0.37, 1.234, 9.87, 50.0])
    kernel = spectra._dft_kernel(n, dt, omega)
    coef = spectra._segment_transforms(x, n, np.arange(0, 1000 - n + 1, 30), kernel)
    t = np.arange(n) * dt
    w = 0.5 * (1 - np.cos(2 * np.pi * np.arange(n) / n))
    for s in (0, 7):
        seg = x[1, 30 * s:30 * s + n]
        ref = dt * np.sqrt(8 / 3) * np.sum(seg * w * np.exp(-1j * np.outer(omega, t)), axis=1)
        np.testing.assert_allclose(coef[1, s], ref, rtol=1e-12, atol=1e-14)


def test_white_noise_level_and_sine_power():
    """One-sided density of white noise is 2 sigma^2 dt; a sine's density integrates to A^2/2."""
    dt, n = 0.01, 60000
    rng = np.random.default_rng(5)
    sigma, amp, w0 = 0.7, 2.0, 12.0
    t = np.arange(n) * dt
    recs = [record({"x": rng.normal(0, sigma, n), "y": amp * np.sin(w0 * t + 0.3)}, dt)]
    sig = spectra.perturbations(recs, ["x", "y"], ["x"])
    grid = np.linspace(w0 - 6, w0 + 6, 801)
    ds = spectra.window_spectra(sig, ["x"], ["y"], 5.0, grid, overlap=0.8)
    level = float(ds["Gxx"].sel(input="x", input_j="x").real.mean())
    assert level == pytest.approx(2 * sigma ** 2 * dt, rel=0.03)
    power = np.trapezoid(ds["Gyy"].sel(output="y").values, grid / (2 * np.pi))
    assert power == pytest.approx(amp ** 2 / 2, rel=0.01)


def test_delay_phase_and_conjugate_convention():
    """y(t) = x(t - tau) gives Gxy = Gxx exp(-j omega tau): H = Gxy / Gxx."""
    dt, n, shift = 0.01, 20000, 7
    rng = np.random.default_rng(11)
    x = rng.normal(size=n + shift)
    recs = [record({"x": x[shift:], "y": x[:-shift]}, dt)]
    sig = spectra.perturbations(recs, ["x", "y"], ["x"])
    omega = np.geomspace(1, 40, 20)
    ds = spectra.window_spectra(sig, ["x"], ["y"], 20.0, omega)
    h = ds["Gxy"].sel(output="y", input="x") / ds["Gxx"].sel(input="x", input_j="x")
    np.testing.assert_allclose(np.angle(h), -omega * shift * dt, atol=0.02)


def test_segments_never_span_records_and_n_d():
    recs = noise_records(2, n_records=3, n=1000, dt=0.01)
    sig = spectra.perturbations(recs, ["x", "y"], ["x"])
    ds = spectra.window_spectra(sig, ["x"], ["y"], 2.0, [1.0, 5.0])
    # 200-sample segments, step 40: (1000 - 200) // 40 + 1 = 21 per record
    assert int(ds["n_segments"]) == 3 * 21
    assert float(ds["n_d"]) == pytest.approx(3000 / 200)


def test_trim_attributes_and_mean_removal():
    dt, n = 0.01, 2000
    rng = np.random.default_rng(4)
    x = rng.normal(size=n)
    plain = spectra.perturbations([record({"x": x}, dt)], ["x"])[0]
    shifted = spectra.perturbations([record({"x": x + 5.0}, dt)], ["x"])[0]
    np.testing.assert_allclose(plain.values, shifted.values, atol=1e-12)   # mean removed
    trimmed = spectra.perturbations([record({"x": x + 5.0}, dt, trim_x=4.0)], ["x"])[0]
    np.testing.assert_allclose(trimmed.values[0], x + 1.0, atol=1e-12)     # trim removed


def test_hann_error_constant():
    """No overlap: independent segments, C_eps = 1. Overlapped Hann: about 0.7 (Welch)."""
    assert spectra.hann_error_constant(0.0) == pytest.approx(1.0)
    assert spectra.hann_error_constant(0.5) == pytest.approx(0.73, abs=0.005)
    assert spectra.hann_error_constant(0.8) == pytest.approx(0.69, abs=0.005)
    assert abs(spectra.DEFAULT_C_EPS - spectra.hann_error_constant(0.8)) < 0.02


# --------------------------------------------------------------------------------------------
# bad input: each a clear InputDataError naming the record / channel
# --------------------------------------------------------------------------------------------

def good(n=2000, dt=0.01, seed=0, **attrs):
    rng = np.random.default_rng(seed)
    return record({"x": rng.normal(size=n), "y": rng.normal(size=n)}, dt, **attrs)


def test_different_sample_rates():
    with pytest.raises(InputDataError, match=r"record 'fast'.*100 Hz.*record 'slow'.*50 Hz"):
        spectra.perturbations({"slow": good(dt=0.02), "fast": good(dt=0.01)}, ["x", "y"], ["x"])


def test_non_uniform_time():
    ds = good(maneuver="sweep_lon_1")
    t = ds["time"].values.copy()
    t[500:] += 0.004
    ds = ds.assign_coords(time=t)
    with pytest.raises(InputDataError, match=r"sweep_lon_1.*not uniformly sampled"):
        spectra.perturbations([ds], ["x", "y"], ["x"])


def test_nan_names_channel_and_time():
    ds = good(maneuver="sweep_lat_2")
    y = ds["y"].values.copy()
    y[250] = np.nan
    ds["y"] = ("time", y)
    with pytest.raises(InputDataError, match=r"sweep_lat_2.*'y'.*NaN.*t = 2.5"):
        spectra.perturbations([ds], ["x", "y"], ["x"])


def test_missing_channel():
    with pytest.raises(InputDataError, match=r"record 'r1'.*\['q'\]"):
        spectra.perturbations({"r1": good()}, ["x", "q"], ["x"])


def test_constant_input_channel():
    a, b = good(seed=1), good(seed=2)
    a["x"] = ("time", np.full(2000, 3.0))
    b["x"] = ("time", np.full(2000, -1.0))
    with pytest.raises(InputDataError, match=r"input channel\(s\) \['x'\] constant"):
        spectra.perturbations({"a": a, "b": b}, ["x", "y"], ["x"])
    # constant in one record only (another axis' sweep) is fine
    spectra.perturbations({"a": a, "c": good(seed=3)}, ["x", "y"], ["x"])


def test_record_shorter_than_window():
    sig = spectra.perturbations({"long": good(n=5000), "short": good(n=800)}, ["x", "y"], ["x"])
    with pytest.raises(InputDataError, match=r"record 'short' lasts 8 s, shorter than the 10 s"):
        spectra.window_spectra(sig, ["x"], ["y"], 10.0, [1.0, 2.0])


def test_too_few_averages():
    sig = spectra.perturbations({"r": good(n=2000)}, ["x", "y"], ["x"])
    with pytest.raises(InputDataError, match=r"window 5 s gives only 4.00 averages"):
        spectra.window_spectra(sig, ["x"], ["y"], 5.0, [1.0, 2.0])


def test_frequency_above_nyquist():
    sig = spectra.perturbations({"r": good()}, ["x", "y"], ["x"])
    with pytest.raises(InputDataError, match="Nyquist"):
        spectra.window_spectra(sig, ["x"], ["y"], 2.0, [1.0, 400.0])


def test_segments_cover_every_record_to_its_last_sample():
    """A record that is not a whole number of steps longer than a window keeps its tail:
    segments spread evenly with at least the nominal overlap. A burst confined to the last
    0.3 s (where a sweep has its highest frequencies) must reach the spectrum."""
    dt, n, window = 0.01, 1037, 2.0
    n_win, starts = spectra.segment_layout(n, window, dt, 0.8)
    assert n_win == 200 and starts[0] == 0 and starts[-1] == n - n_win
    assert np.all(np.diff(starts) <= 40) and starts.size == 22   # ceil(837 / 40) + 1
    x = np.zeros(n)
    x[-30:] = np.sin(2 * np.pi * np.arange(30) / 10)
    recs = [record({"x": x, "y": np.random.default_rng(0).normal(size=n)}, dt)]
    sig = spectra.perturbations(recs, ["x", "y"], ["x"])
    ds = spectra.window_spectra(sig, ["x"], ["y"], window, [2 * np.pi * 10.0])
    assert int(ds["n_segments"]) == 22
    assert float(ds["Gxx"].sel(input="x", input_j="x").real.item()) > 1e-6
