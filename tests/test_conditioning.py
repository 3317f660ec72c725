"""MIMO conditioning (paper Eq. 7-13) against algebraic truth and known linear systems."""

import numpy as np
import pytest
import xarray as xr

import linear_systems as ls
from sysid.spectral import conditioning, spectra
from sysid.spectral.response import frequency_response


def exact_spectra(seed, n_in=4, n_out=3, n_f=25):
    """Spectral matrices of ``y = H x + n`` with known ``H`` and noise spectra ``Gnn``."""
    rng = np.random.default_rng(seed)
    a = rng.normal(size=(n_f, n_in, n_in)) + 1j * rng.normal(size=(n_f, n_in, n_in))
    gxx = a @ np.conj(np.swapaxes(a, -1, -2)) + 0.3 * np.eye(n_in)       # Hermitian PD
    h = rng.normal(size=(n_f, n_out, n_in)) + 1j * rng.normal(size=(n_f, n_out, n_in))
    gnn = rng.uniform(0.1, 2.0, size=(n_f, n_out))
    gxy = h @ np.swapaxes(gxx, -1, -2)                  # Gxy[o, i] = sum_j Gxx[i, j] H[o, j]
    gyy = np.real(np.einsum("foi,fij,foj->fo", np.conj(h), gxx, h)) + gnn
    inputs = [f"x{k}" for k in range(n_in)]
    outputs = [f"y{k}" for k in range(n_out)]
    coords = {"frequency": np.arange(1, n_f + 1.0), "input": inputs, "input_j": inputs,
              "output": outputs}
    ds = xr.Dataset({"Gxx": (("frequency", "input", "input_j"), gxx),
                     "Gxy": (("frequency", "output", "input"), gxy),
                     "Gyy": (("frequency", "output"), gyy), "n_d": 10.0}, coords=coords)
    return ds, h, gnn, gxx, gxy, gyy


@pytest.mark.parametrize("method", ["matrix", "recursion"])
def test_conditioned_spectra_against_algebraic_truth(method):
    """Conditioned H recovers the true H; partial coherence equals the partial correlation
    from the inverse of the augmented spectral matrix; multiple coherence is 1 - Gnn/Gyy."""
    ds, h, gnn, gxx, gxy, gyy = exact_spectra(1)
    res = conditioning.conditioned_response(ds, method=method, collinear_threshold=1.0)
    np.testing.assert_allclose(res["H"].transpose("frequency", "output", "input"), h,
                               rtol=1e-10)
    np.testing.assert_allclose(res["multiple_coherence"].transpose("frequency", "output"),
                               1 - gnn / gyy, rtol=1e-10)
    n_f, n_out, n_in = h.shape
    for o in range(n_out):
        aug = np.zeros((n_f, n_in + 1, n_in + 1), complex)
        aug[:, :n_in, :n_in] = gxx
        aug[:, :n_in, n_in] = gxy[:, o]
        aug[:, n_in, :n_in] = np.conj(gxy[:, o])
        aug[:, n_in, n_in] = gyy[:, o]
        p = np.linalg.inv(aug)
        for i in range(n_in):
            expect = np.abs(p[:, i, n_in]) ** 2 / np.real(p[:, i, i] * p[:, n_in, n_in])
            got = res["partial_coherence"].isel(output=o, input=i).values
            np.testing.assert_allclose(got, expect, rtol=1e-9)


def test_recursion_and_matrix_agree_on_measured_spectra():
    """Eq. 10 recursion and the matrix solve agree to 1e-10 on spectra of noisy MIMO data."""
    recs = ls.periodic_records(ls.PATHS, ls.MIXING, ls.INPUTS, ls.OUTPUTS, n=3000, dt=0.02,
                               band=(0.05, 40.0), seeds=[1, 2, 3],
                               noise={"y1": 0.3, "y2": 0.3}, noise_seed=2)
    sig = spectra.perturbations(recs, ls.INPUTS + ls.OUTPUTS, ls.INPUTS)
    spec = spectra.spectra(sig, ls.INPUTS, ls.OUTPUTS, [6.0, 15.0],
                           spectra.log_frequencies(0.5, 30, 60))
    a = conditioning.conditioned_response(spec, method="matrix")
    b = conditioning.conditioned_response(spec, method="recursion")
    assert not bool(a["collinear"].any())
    for name in ("H", "Gxy_pair"):
        scale = abs(a[name]).max(("frequency",))
        assert float((abs(a[name] - b[name]) / scale).max()) < 1e-10, name
    for name in ("partial_coherence", "multiple_coherence", "random_error"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-10, atol=1e-12)
    for name in ("Gxx_pair", "Gyy_pair"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-10)


def test_partial_coherence_of_input_without_path():
    """Input c has no path to y but is strongly correlated with a, which drives y: the ordinary
    coherence c -> y stays high, the partial coherence falls to about zero.

    An estimated coherence of unrelated signals is positive (bias about 1/n_averages) and
    scatters from frequency to frequency, so "about zero" is asserted as: mean < 0.05, 90 % of
    the frequencies < 0.1, none above 0.2.
    """
    paths = {("y", "a"): ls.tf([2.0], [1.0, 1.0], delay=0.1)}
    mixing = {("a", 0): 1.0, ("c", 0): 0.9, ("c", 1): 0.4}
    recs = ls.periodic_records(paths, mixing, ["a", "c"], ["y"], n=4000, dt=0.02,
                               band=(0.05, 30.0), seeds=range(1, 9),
                               noise={"y": 0.1}, noise_seed=5)
    ds = frequency_response(recs, ["a", "c"], ["y"], omega_min=0.3, omega_max=10.0,
                            n_frequencies=60)
    ordinary = ds["coherence"].sel(output="y", input="c")
    partial = ds["partial_coherence"].sel(output="y", input="c")
    true_cross = 0.81 / (0.81 + 0.16)
    assert float(ds["cross_coherence"].sel(input="a", input_j="c").mean()) == pytest.approx(
        true_cross, abs=0.05)
    assert float(ordinary.min()) > 0.5
    assert float(partial.mean()) < 0.05
    assert float(partial.quantile(0.9)) < 0.1
    assert float(partial.max()) < 0.2
    # the driving input keeps a high partial coherence
    assert float(ds["partial_coherence"].sel(output="y", input="a").median()) > 0.8


def test_collinear_inputs_flagged_not_inverted():
    """b is a scaled copy of a: every frequency is collinear and H is NaN (no LinAlgError);
    a small independent part in b is flagged or not depending on the threshold."""
    paths = {("y", "a"): ls.tf([1.0], [1.0, 1.0]), ("y", "b"): ls.tf([1.0], [1.0, 2.0])}
    exact = {("a", 0): 1.0, ("b", 0): -0.8}
    recs = ls.periodic_records(paths, exact, ["a", "b"], ["y"], n=3000, dt=0.02,
                               band=(0.05, 30.0), seeds=[1, 2])
    sig = spectra.perturbations(recs, ["a", "b", "y"], ["a", "b"])
    spec = spectra.spectra(sig, ["a", "b"], ["y"], [6.0], spectra.log_frequencies(0.5, 20, 30))
    res = conditioning.conditioned_response(spec)
    assert bool(res["collinear"].all())
    assert bool(res["H"].isnull().all())

    nearly = {("a", 0): 1.0, ("b", 0): 1.0, ("b", 1): 0.05}   # input coherence 1/1.0025
    recs = ls.periodic_records(paths, nearly, ["a", "b"], ["y"], n=3000, dt=0.02,
                               band=(0.05, 30.0), seeds=[1, 2])
    sig = spectra.perturbations(recs, ["a", "b", "y"], ["a", "b"])
    spec = spectra.spectra(sig, ["a", "b"], ["y"], [6.0], spectra.log_frequencies(1, 20, 30))
    coh = conditioning.input_coherence(spec["Gxx"])
    assert float(coh.min()) == pytest.approx(1 / 1.0025, abs=0.002)
    assert bool(conditioning.conditioned_response(spec)["collinear"].all())
    loose = conditioning.conditioned_response(spec, collinear_threshold=0.9995)
    assert not bool(loose["collinear"].any())
    assert bool(loose["H"].notnull().all())


def test_single_input_conditioning_is_siso():
    ds, *_ = exact_spectra(3, n_in=1, n_out=2)
    a = conditioning.conditioned_response(ds)
    b = conditioning.siso_response(ds)
    for name in ("H", "random_error"):
        np.testing.assert_allclose(a[name], b[name], rtol=1e-12)
    np.testing.assert_allclose(a["partial_coherence"], b["coherence"], rtol=1e-12)


def test_random_error_formula_and_cross_coherence():
    assert float(conditioning.random_error(xr.DataArray(0.5), 10.0, 0.7)) == pytest.approx(
        0.7 / np.sqrt(20.0))
    ds, *_ = exact_spectra(4)
    cc = conditioning.cross_coherence(ds["Gxx"])
    np.testing.assert_allclose(cc.sel(input="x0", input_j="x0"), 1.0)
    g = ds["Gxx"].sel(input="x1", input_j="x2")
    expect = abs(g) ** 2 / (ds["Gxx"].sel(input="x1", input_j="x1").real
                            * ds["Gxx"].sel(input="x2", input_j="x2").real)
    np.testing.assert_allclose(cc.sel(input="x1", input_j="x2"), expect, rtol=1e-12)
