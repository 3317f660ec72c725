"""Composite windowing (paper Eq. 14-17)."""

import numpy as np
import pytest
import scipy.optimize
import xarray as xr

import linear_systems as ls
from sysid import composite
from sysid.errors import InputDataError
from sysid.frequency_response import frequency_response


def test_default_windows_follow_the_guidelines():
    """T_max = min(T_record / 2, T_total / 5), T_min = 20 / f_max, log-spaced in between."""
    w = composite.default_windows([90.0] * 8, omega_max=2 * np.pi * 2.0, n_windows=5)
    np.testing.assert_allclose(w, np.geomspace(10.0, 45.0, 5))
    w = composite.default_windows([30.0, 100.0], omega_max=2 * np.pi * 4.0, n_windows=3)
    np.testing.assert_allclose(w, np.geomspace(5.0, 15.0, 3))        # shortest record / 2
    w = composite.default_windows([40.0], omega_max=2 * np.pi * 4.0, n_windows=3)
    np.testing.assert_allclose(w, np.geomspace(5.0, 8.0, 3))         # total / 5
    with pytest.raises(InputDataError, match=r"records too short.*20 periods, 40 s"):
        composite.default_windows([30.0], omega_max=2 * np.pi * 0.5)


def test_weights_eq14():
    eps = xr.DataArray([[0.1, 0.2, 0.05, np.nan]], dims=("frequency", "window"))
    usable = xr.DataArray([[True, True, False, True]], dims=("frequency", "window"))
    w = composite.weights(eps, usable)
    np.testing.assert_allclose(w.values, [[1.0, 1 / 16, 0.0, 0.0]])


def random_windows(seed, n_f=40, n_w=5):
    rng = np.random.default_rng(seed)
    h = rng.normal(size=n_f) + 1j * rng.normal(size=n_f)
    gxx = rng.uniform(0.5, 2, (n_f, n_w))
    coh = rng.uniform(0.2, 0.99, (n_f, n_w))
    gxy = gxx * h[:, None] * (1 + 0.3 * (rng.normal(size=(n_f, n_w))
                                         + 1j * rng.normal(size=(n_f, n_w))))
    gyy = abs(gxy) ** 2 / (gxx * coh)
    w = rng.uniform(0.01, 1, (n_f, n_w))
    w[:, 0] = 1.0
    w[rng.random((n_f, n_w)) < 0.2] = 0.0
    return gxx, gyy, gxy, coh, w


def eq16_cost(z, gxx, gyy, gxy, coh, w):
    """Eq. 16 with |Gxy| normalisation, written out directly from the paper."""
    w2 = w ** 2
    hxx, hyy = np.sum(w2 * gxx) / w2.sum(), np.sum(w2 * gyy) / w2.sum()
    hxy, hcoh = np.sum(w2 * gxy) / w2.sum(), np.sum(w2 * coh) / w2.sum()
    cxx, cyy, cxy = z[0], z[1], z[2] + 1j * z[3]
    ccoh = abs(cxy) ** 2 / (cxx * cyy)
    terms = ((cxx - gxx) / hxx) ** 2 + ((cyy - gyy) / hyy) ** 2 \
        + ((cxy.real - gxy.real) / abs(hxy)) ** 2 + ((cxy.imag - gxy.imag) / abs(hxy)) ** 2 \
        + 5.0 * ((ccoh - coh) / hcoh) ** 2
    return np.sum(w * terms)


def test_vectorised_lm_reaches_the_eq16_minimum():
    """The vectorised Levenberg-Marquardt solution is a minimum of Eq. 16 at every frequency:
    scipy's general optimiser started from it finds nothing lower, and started from the
    weighted averages it finds nothing lower either."""
    gxx, gyy, gxy, coh, w = random_windows(7)
    dims = ("frequency", "window")
    ds = composite.composite_spectra(*(xr.DataArray(a, dims=dims) for a in (gxx, gyy, gxy, coh)),
                                     xr.DataArray(w, dims=dims))
    for f in range(gxx.shape[0]):
        args = (gxx[f], gyy[f], gxy[f], coh[f], w[f])
        ours = np.array([ds["Gxx_pair"][f], ds["Gyy_pair"][f], ds["Gxy_pair"][f].real,
                         ds["Gxy_pair"][f].imag], dtype=float)
        j_ours = eq16_cost(ours, *args)
        m = np.sum(w[f] * gxx[f]) / w[f].sum(), np.sum(w[f] * gyy[f]) / w[f].sum()
        mxy = np.sum(w[f] * gxy[f]) / w[f].sum()
        for start in (ours, np.array([m[0], m[1], mxy.real, mxy.imag])):
            ref = scipy.optimize.minimize(eq16_cost, start, args=args, method="Nelder-Mead",
                                          options={"xatol": 1e-12, "fatol": 1e-14,
                                                   "maxiter": 20000})
            assert j_ours <= ref.fun * (1 + 1e-6) + 1e-12, f


def test_identical_windows_are_a_fixed_point():
    gxx, gyy, gxy, coh, w = random_windows(8, n_w=1)
    dims = ("frequency", "window")
    rep = [np.repeat(a, 4, axis=1) for a in (gxx, gyy, gxy, coh)]
    ds = composite.composite_spectra(*(xr.DataArray(a, dims=dims) for a in rep),
                                     xr.DataArray(np.ones((gxx.shape[0], 4)), dims=dims))
    np.testing.assert_allclose(ds["Gxx_pair"], gxx[:, 0], rtol=1e-9)
    np.testing.assert_allclose(ds["Gxy_pair"], gxy[:, 0], rtol=1e-9)
    np.testing.assert_allclose(ds["coherence"], coh[:, 0], rtol=1e-9)


def test_composite_beats_every_single_window():
    """Noisy MIMO data (reference system of tests/linear_systems.py, output noise 0.2): the
    composite response's RMS relative error against the analytic response is no larger than
    that of the best single window.

    The band compared is every frequency of the grid where the pair's composite partial
    coherence meets the 0.6 guideline (methods.md), over all pairs with a path. Below that
    the paper's Eq. 16 coherence term distorts H (see ``coherence_weight`` in
    :func:`sysid.frequency_response.frequency_response`); with that term off, the composite
    also beats every window over the whole grid.
    """
    recs = ls.periodic_records(ls.PATHS, ls.MIXING, ls.INPUTS, ls.OUTPUTS, n=5000, dt=0.02,
                               band=(0.05, 40.0), seeds=range(1, 9),
                               noise={"y1": 0.2, "y2": 0.2}, noise_seed=3)
    ds, per_window = frequency_response(recs, ls.INPUTS, ls.OUTPUTS, omega_max=30.0,
                                        n_frequencies=100, keep_windows=True)
    truth = ls.truth(ls.PATHS, ls.INPUTS, ls.OUTPUTS, ds["frequency"])
    band = (abs(truth) > 0) & (ds["partial_coherence"] >= 0.6)
    assert float(band.sum()) > 0.6 * float((abs(truth) > 0).sum())

    def rms(h, where):
        return float(np.sqrt((abs(h / truth - 1) ** 2).where(where).mean()))

    single = [rms(per_window["H"].sel(window=T), band) for T in per_window["window"].values]
    assert rms(ds["H"], band) <= min(single)

    plain = frequency_response(recs, ls.INPUTS, ls.OUTPUTS, omega_max=30.0, n_frequencies=100,
                               coherence_weight=0.0)
    everywhere = abs(truth) > 0
    single = [rms(per_window["H"].sel(window=T), everywhere)
              for T in per_window["window"].values]
    assert rms(plain["H"], everywhere) <= min(single)
