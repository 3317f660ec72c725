"""Known linear systems with exactly known responses, for testing the frequency-response stage.

Signals are periodic random-phase multisines: every record is one period of ``n`` samples, so
its spectral lines sit on the DFT bins ``omega_k = 2 pi k / (n dt)``. The output of a
continuous LTI system (with pure delays) to such an input, in steady state, is exactly
``irfft(G(j omega_k) U_k)`` sampled at ``dt`` -- no discretisation (ZOH/FOH) error and exact
delays ``exp(-j omega tau)``. The truth to compare estimates against is therefore the analytic
``G(j omega)`` of the continuous transfer functions at any frequency.

Correlated inputs are built in the frequency domain from independent seeded multisines
``e_k`` through a mixing matrix of transfer functions, ``U_i = sum_k M_ik(j omega) E_k``.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np
import xarray as xr

TransferFunction = Callable[[np.ndarray], np.ndarray]


def tf(num: Sequence[float], den: Sequence[float], delay: float = 0.0) -> TransferFunction:
    """``G(s) = num(s) / den(s) * exp(-s delay)`` (coefficients highest power first)."""
    num = np.asarray(num, float)
    den = np.asarray(den, float)

    def g(s):
        s = np.asarray(s, complex)
        return np.polyval(num, s) / np.polyval(den, s) * np.exp(-s * delay)

    return g


def zero_tf(s):
    """The transfer function of a missing path."""
    return np.zeros(np.shape(s), complex)


def bin_frequencies(n: int, dt: float) -> np.ndarray:
    """Frequencies of the rfft bins of an ``n``-sample record, rad/s."""
    return 2.0 * np.pi * np.fft.rfftfreq(n, dt)


def multisine_lines(n: int, dt: float, band: tuple[float, float], seed: int,
                    shape: TransferFunction | None = None) -> np.ndarray:
    """rfft coefficients of a unit-RMS multisine with random phases on every bin in ``band``
    (rad/s), optionally shaped by ``|shape(j omega)|``."""
    rng = np.random.default_rng(seed)
    w = bin_frequencies(n, dt)
    amp = ((w >= band[0]) & (w <= band[1])).astype(float)
    if shape is not None:
        amp = amp * np.abs(shape(1j * w))
    lines = amp * np.exp(2j * np.pi * rng.random(w.size))
    x = np.fft.irfft(lines, n)
    return lines / np.sqrt(np.mean(x ** 2))


def periodic_records(
    paths: Mapping[tuple[str, str], TransferFunction],
    mixing: Mapping[tuple[str, int], TransferFunction | float],
    inputs: Sequence[str], outputs: Sequence[str], *,
    n: int, dt: float, band: tuple[float, float], seeds: Sequence[int],
    noise: Mapping[str, float] | None = None, noise_seed: int | None = None,
    n_sources: int | None = None,
) -> list[xr.Dataset]:
    """One exact steady-state record per seed.

    Parameters
    ----------
    paths : {(output, input): G}
        Transfer functions (missing pairs are zero).
    mixing : {(input, source_index): M or constant}
        How inputs are made from the independent multisines ``e_k`` (missing = 0).
    n, dt : record length (samples) and sample interval (s).
    band : (omega_lo, omega_hi) rad/s of the multisines.
    seeds : one seed per record; source ``k`` of record ``r`` uses ``seed_r * 100 + k``.
    noise : {output: standard deviation} of white Gaussian measurement noise.
    noise_seed : seed of the noise (required with ``noise``).
    """
    w = bin_frequencies(n, dt)
    s = 1j * w
    n_sources = n_sources or 1 + max(k for (_, k) in mixing)
    noise = dict(noise or {})
    noise_rng = np.random.default_rng(noise_seed) if noise else None
    records = []
    for r, seed in enumerate(seeds):
        sources = [multisine_lines(n, dt, band, seed * 100 + k) for k in range(n_sources)]
        u = {}
        for i in inputs:
            acc = np.zeros(w.size, complex)
            for k in range(n_sources):
                m = mixing.get((i, k), 0.0)
                acc += (m(s) if callable(m) else m) * sources[k]
            u[i] = acc
        data = {i: ("time", np.fft.irfft(u[i], n)) for i in inputs}
        for o in outputs:
            acc = np.zeros(w.size, complex)
            for i in inputs:
                g = paths.get((o, i))
                if g is not None:
                    acc += g(s) * u[i]
            y = np.fft.irfft(acc, n)
            if o in noise:
                y = y + noise_rng.normal(0.0, noise[o], n)
            data[o] = ("time", y)
        records.append(xr.Dataset(data, coords={"time": np.arange(n) * dt},
                                  attrs={"maneuver": f"multisine_{r}"}))
    return records


def truth(paths: Mapping[tuple[str, str], TransferFunction], inputs: Sequence[str],
          outputs: Sequence[str], frequency) -> xr.DataArray:
    """Analytic ``G(j omega)`` as ``(output, input, frequency)``."""
    w = np.asarray(getattr(frequency, "values", frequency), float)
    arr = np.zeros((len(outputs), len(inputs), w.size), complex)
    for a, o in enumerate(outputs):
        for b, i in enumerate(inputs):
            g = paths.get((o, i))
            if g is not None:
                arr[a, b] = g(1j * w)
    return xr.DataArray(arr, dims=("output", "input", "frequency"),
                        coords={"output": list(outputs), "input": list(inputs), "frequency": w})


# ---------------------------------------------------------------------------------------------
# The reference MIMO test system: 3 inputs, 2 outputs, a lightly damped mode, a pure delay,
# correlated inputs, and input c with no path to output y2.
# ---------------------------------------------------------------------------------------------

INPUTS = ("a", "b", "c")
OUTPUTS = ("y1", "y2")
DELAY = 0.1  #: s, on the path a -> y2
PATHS = {
    ("y1", "a"): tf([25.0 / 5.0, 25.0], [1.0, 2 * 0.1 * 5.0, 25.0]),   # zeta = 0.1 at 5 rad/s
    ("y1", "b"): tf([2.0], [1.0, 2.0]),
    ("y1", "c"): tf([1.5, 1.5], [1.0, 3.0]),
    ("y2", "a"): tf([2.0], [1.0, 1.0], delay=DELAY),
    ("y2", "b"): tf([3.0], [1.0, 3.0]),
}
#: a = e0, b = F(s) e0 + 0.7 e1, c = 0.6 e0 + 0.8 e2 (independent unit multisines e_k):
#: cross-control coherence a-b about 0.67, a-c 0.36.
MIXING = {
    ("a", 0): 1.0,
    ("b", 0): tf([1.0], [1.0 / 60.0, 1.0]), ("b", 1): 0.7,
    ("c", 0): 0.6, ("c", 2): 0.8,
}
