"""Benchmark: the full conditioned composite frequency response of a hover-sized campaign.

4 controls x 9 outputs, 8 records of 90 s at 100 Hz (two per control axis, the excited axis
strong, the others weaker and partly correlated with it), 5 windows, 200 frequencies, from a
synthetic stable 9-state linear system. Reference: a plain loop of ``scipy.signal.csd`` calls
producing the single-input spectra (Gxx_ii, Gyy, Gxy on the FFT bins) of the same windows;
the ratio of the two run times is printed and stored in ``benchmark.extra_info``.
"""

import sys
import time
from pathlib import Path

import numpy as np
import scipy.signal

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
import linear_systems as ls  # noqa: E402

from sysid.spectral.response import frequency_response  # noqa: E402

INPUTS = ["lon", "lat", "col", "ped"]
OUTPUTS = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]


def hover_like_system(seed=3):
    """Stable 9-state model with C = I: {(output, input): G} callables."""
    rng = np.random.default_rng(seed)
    a = rng.normal(scale=0.6, size=(9, 9))
    a -= (np.max(np.linalg.eigvals(a).real) + 0.3) * np.eye(9)
    b = rng.normal(size=(9, 4))

    def path(o, i):
        def g(s):
            s = np.atleast_1d(s)
            m = s[:, None, None] * np.eye(9) - a
            return np.linalg.solve(m, b[None, :, i, None])[:, o, 0]
        return g

    return {(OUTPUTS[o], INPUTS[i]): path(o, i) for o in range(9) for i in range(4)}


def campaign():
    paths = hover_like_system()
    records = []
    for axis in range(4):
        mixing = {(name, k): (1.0 if k == axis else 0.25) for k, name in enumerate(INPUTS)}
        mixing.update({(INPUTS[(axis + 1) % 4], axis): 0.3})      # a correlated secondary
        records += ls.periodic_records(paths, mixing, INPUTS, OUTPUTS, n=9000, dt=0.01,
                                       band=(0.1, 60.0), seeds=[10 * axis + 1, 10 * axis + 2],
                                       noise={o: 0.05 for o in OUTPUTS}, noise_seed=axis)
    return records


def csd_loop(records, windows, overlap=0.8):
    """Single-input spectra of every window with scipy.signal.csd, pooled over records."""
    out = {}
    for T in windows:
        n = int(round(T / 0.01))
        kw = dict(fs=100.0, window="hann", nperseg=n, noverlap=n - int(round(n * (1 - overlap))),
                  detrend=False)
        acc = {}
        for r in records:
            for i in INPUTS:
                x = r[i].values - r[i].values.mean()
                acc[(i, i)] = acc.get((i, i), 0) + scipy.signal.csd(x, x, **kw)[1]
                for o in OUTPUTS:
                    y = r[o].values - r[o].values.mean()
                    acc[(o, i)] = acc.get((o, i), 0) + scipy.signal.csd(x, y, **kw)[1]
            for o in OUTPUTS:
                y = r[o].values - r[o].values.mean()
                acc[(o, o)] = acc.get((o, o), 0) + scipy.signal.csd(y, y, **kw)[1]
        out[T] = acc
    return out


def test_bench_conditioned_composite_hover_campaign(benchmark):
    records = campaign()
    times = []

    def run():
        start = time.perf_counter()
        result = frequency_response(records, INPUTS, OUTPUTS, n_windows=5, omega_max=40.0,
                                    n_frequencies=200)
        times.append(time.perf_counter() - start)
        return result

    ds = benchmark(run)
    windows = ds.attrs["windows"]
    start = time.perf_counter()
    csd_loop(records, windows)
    t_csd = time.perf_counter() - start
    ratio = min(times) / t_csd
    benchmark.extra_info.update(frequency_response_s=min(times), csd_loop_s=t_csd,
                                ratio_to_csd_loop=ratio, windows_s=list(map(float, windows)))
    print(f"\nfrequency_response (4x9, 8 x 90 s at 100 Hz, 5 windows, 200 frequencies): "
          f"{min(times):.2f} s; scipy.signal.csd loop (single-input spectra, same windows, "
          f"FFT bins): {t_csd:.2f} s; ratio {ratio:.2f}")
    assert ds["H"].shape == (9, 4, 200)
    assert int(ds["multiple_coherence"].notnull().sum()) > 0
