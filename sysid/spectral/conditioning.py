"""Frequency responses from spectra: coherences, random error and MIMO conditioning.

Inputs are the spectra of :mod:`sysid.spectral.spectra` (``Gxx (input, input_j, frequency[, window])``,
``Gyy (output, ...)``, ``Gxy (output, input, ...)``); every function works over any extra
dimensions (typically ``window``). Conventions: ``Gxx[i, j] = E[conj(X_i) X_j]``,
``Gxy[o, i] = E[conj(X_i) Y_o]``, so ``Y_o = sum_i H[o, i] X_i`` and ``Gxx H[o, :] = Gxy[o, :]``.

Single input (SISO, unconditioned)
    ``H = Gxy / Gxx_ii``, ordinary coherence Eq. 7, random error Eq. 9.

Several inputs (Bendat & Piersol's conditioned spectral analysis)
    Each input/output pair is analysed with the output and the input *conditioned on all other
    inputs* (their linearly coherent parts removed). Two equivalent computations are offered:

    ``method="recursion"``
        the paper's ordered recursion Eq. 10, ``G_ij.r = G_ij.(r-1) - L_rj G_ir.(r-1)``,
        ``L_rj = G_rj.(r-1) / G_rr.(r-1)``, run once per input with that input last;
    ``method="matrix"`` (default, faster)
        the normal equations ``Gxx H = Gxy`` solved at every frequency, with
        ``A = Gxx^-1``: ``Gxx_i.rest = 1 / A_ii``, ``Gxy_i.rest = H_i / A_ii``,
        ``Gyy.rest_i = Gyy.x + |H_i|^2 / A_ii`` where ``Gyy.x = Gyy - Gxy^H A Gxy``.

    From these conditioned pair spectra: conditioned ``H = Gxy_i.rest / Gxx_i.rest``, partial
    coherence Eq. 11, conditioned random error Eq. 13 (partial coherence, same ``n_d``), and the
    multiple coherence Eq. 12 ``Gxy^H Gxx^-1 Gxy / Gyy``. Eq. 12's ordered sum is taken with each
    term normalised by the *unconditioned* ``Gyy`` (Bendat & Piersol's form); with the terms
    normalised by the conditioned output spectrum, as printed, the sum would not equal the
    multiple coherence.

Collinear inputs
    At frequencies where the inputs are nearly linearly dependent the conditioned responses are
    not identifiable. The measure is each input's multiple coherence on all the *other* inputs,
    ``gamma^2_i:rest = 1 - Gxx_i.rest / Gxx_ii``; where its largest value exceeds
    ``collinear_threshold`` (default :data:`DEFAULT_COLLINEAR_THRESHOLD` = 0.99: 99 % of an
    input's power explained by the others, i.e. the conditioned input keeps 1 % and its
    conditioned error variance grows a hundredfold) the frequency is flagged in ``collinear``
    and every conditioned result there is NaN; nothing near-singular is inverted.

References
----------
* *Comparison of frequency and time domain identification of a helicopter in hover*
  (Eq. 7-13).
* Bendat, J. S. and Piersol, A. G., *Random Data: Analysis and Measurement Procedures*,
  Wiley (conditioned spectral analysis).
* docs/methods.md, "Conditioning".
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.spectral.spectra import DEFAULT_C_EPS

#: Flag a frequency as collinear when an input's multiple coherence on the others exceeds this.
DEFAULT_COLLINEAR_THRESHOLD = 0.99
#: Reciprocal condition number below which the normalised input matrix counts as singular.
SINGULAR_RCOND = 1e-12

PAIR_DIMS = ("output", "input")


# --------------------------------------------------------------------------------------------
# coherences and random error
# --------------------------------------------------------------------------------------------

def input_autospectra(Gxx: xr.DataArray) -> xr.DataArray:
    """Diagonal of the input cross-spectral matrix, ``Gxx_ii`` (input, ...), real."""
    diag = xr.apply_ufunc(np.diagonal, Gxx, input_core_dims=[["input", "input_j"]],
                          output_core_dims=[["input"]], kwargs={"axis1": -2, "axis2": -1})
    return diag.real


def ordinary_coherence(Gxx: xr.DataArray, Gyy: xr.DataArray, Gxy: xr.DataArray) -> xr.DataArray:
    """Ordinary coherence Eq. 7, ``|Gxy|^2 / (Gxx_ii Gyy)`` (output, input, ...), 0..1."""
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = abs(Gxy) ** 2 / (input_autospectra(Gxx) * Gyy)
    return coh.clip(0.0, 1.0).transpose("output", "input", ...).assign_attrs(
        long_name="ordinary coherence (Eq. 7)", units="1")


def cross_coherence(Gxx: xr.DataArray) -> xr.DataArray:
    """Cross-control coherence Eq. 8, ``|Gxx_ij|^2 / (Gxx_ii Gxx_jj)`` (input, input_j, ...)."""
    d = input_autospectra(Gxx)
    with np.errstate(invalid="ignore", divide="ignore"):
        coh = abs(Gxx) ** 2 / (d * d.rename(input="input_j"))
    return coh.clip(0.0, 1.0).transpose("input", "input_j", ...).assign_attrs(
        long_name="cross-control coherence (Eq. 8)", units="1")


def random_error(coherence, n_d, C_eps: float = DEFAULT_C_EPS):
    """Normalised random error Eq. 9 / Eq. 13.

    ``eps_r = C_eps sqrt(1 - g2) / (sqrt(g2) sqrt(2 n_d))`` with ``g2`` the (partial)
    coherence and ``n_d = T_r / T`` the number of independent averages. It is the standard
    deviation of ``|H|`` relative to ``|H|`` and, in radians, of the phase of ``H``
    (Bendat & Piersol). ``C_eps`` (default 0.7) accounts for the Hann taper and the overlap,
    see :func:`sysid.spectral.spectra.hann_error_constant`.
    """
    g2 = coherence.clip(0.0, 1.0) if hasattr(coherence, "clip") else np.clip(coherence, 0, 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        eps = C_eps * np.sqrt(1.0 - g2) / (np.sqrt(g2) * np.sqrt(2.0 * n_d))
    if isinstance(eps, xr.DataArray):
        eps.attrs = {"long_name": "normalised random error (Eq. 9/13)", "units": "1"}
    return eps


# --------------------------------------------------------------------------------------------
# collinearity
# --------------------------------------------------------------------------------------------

def _input_coherence_core(gxx: np.ndarray) -> np.ndarray:
    """``(..., n, n) -> (..., n)``: multiple coherence of each input on the other inputs."""
    n = gxx.shape[-1]
    d = np.real(np.diagonal(gxx, axis1=-2, axis2=-1))
    with np.errstate(invalid="ignore", divide="ignore"):
        s = 1.0 / np.sqrt(d)
        gn = gxx * s[..., :, None] * s[..., None, :]
    if n == 1:
        return np.where(np.isfinite(gn[..., 0]) & (d[..., :] > 0), 0.0, 1.0).real
    finite = np.all(np.isfinite(gn), axis=(-2, -1))
    gn = np.where(finite[..., None, None], gn, np.eye(n))
    sv = np.linalg.svd(gn, compute_uv=False)
    singular = ~finite | (sv[..., -1] < SINGULAR_RCOND * sv[..., 0])
    gn = np.where(singular[..., None, None], np.eye(n), gn)
    inv_diag = np.real(np.diagonal(np.linalg.inv(gn), axis1=-2, axis2=-1))
    coh = 1.0 - 1.0 / inv_diag
    return np.where(singular[..., None], 1.0, np.clip(coh, 0.0, 1.0))


def input_coherence(Gxx: xr.DataArray) -> xr.DataArray:
    """Multiple coherence of each input on all other inputs, ``1 - Gxx_i.rest / Gxx_ii``
    (input, ...); 0 for a single input, 1 where the inputs are linearly dependent."""
    out = xr.apply_ufunc(_input_coherence_core, Gxx, input_core_dims=[["input", "input_j"]],
                         output_core_dims=[["input"]])
    return out.transpose("input", ...).assign_attrs(
        long_name="multiple coherence of the input on the other inputs", units="1")


def collinear(Gxx: xr.DataArray, threshold: float = DEFAULT_COLLINEAR_THRESHOLD,
              inputs=None) -> xr.DataArray:
    """True at frequencies where some input's multiple coherence on the others exceeds
    ``threshold`` (or the input matrix is singular or not finite). ``inputs`` restricts the
    test to those inputs (the others still count among "the others"): auxiliary regressors
    such as transient terms may be nearly dependent among themselves without harm to the
    responses of the inputs that are reported."""
    if not 0.0 < threshold <= 1.0:
        raise InputDataError(f"collinear_threshold must be in (0, 1], got {threshold}")
    coh = input_coherence(Gxx)
    if inputs is not None:
        coh = coh.sel(input=list(inputs))
    flag = (coh > threshold).any("input") | (coh >= 1.0).any("input")
    return flag.assign_attrs(long_name="inputs nearly collinear: conditioned results undefined",
                             collinear_threshold=threshold)


# --------------------------------------------------------------------------------------------
# conditioned pair spectra: matrix solve and Eq. 10 recursion (numpy cores over (..., core))
# --------------------------------------------------------------------------------------------

def _matrix_core(gxx, gxy, gyy, flag):
    """Conditioned pair spectra from ``Gxx H = Gxy``.

    Shapes: ``gxx (..., n, n)``, ``gxy (..., o, n)``, ``gyy (..., o)``, ``flag (...)``.
    Returns ``gxx_c, gyy_c (..., o, n)`` real, ``gxy_c (..., o, n)`` complex, ``mult (..., o)``.
    """
    n = gxx.shape[-1]
    safe = np.where(flag[..., None, None], np.eye(n), gxx)
    h = np.swapaxes(np.linalg.solve(safe, np.swapaxes(gxy, -1, -2)), -1, -2)  # (..., o, n)
    a_ii = np.real(np.diagonal(np.linalg.inv(safe), axis1=-2, axis2=-1))      # (..., n)
    gyy_x = gyy - np.real(np.sum(np.conj(gxy) * h, axis=-1))                   # Gyy.x
    gyy_x = np.maximum(gyy_x, 0.0)
    gxx_c = np.broadcast_to(1.0 / a_ii[..., None, :], h.shape)
    gxy_c = h * gxx_c
    gyy_c = gyy_x[..., None] + np.abs(h) ** 2 * gxx_c
    with np.errstate(invalid="ignore", divide="ignore"):
        mult = 1.0 - gyy_x / gyy
    return gxx_c, gyy_c, gxy_c, mult


def _condition_on(g, gy, yy, r):
    """One step of Eq. 10: remove input ``r`` from every remaining spectrum.

    ``g (..., n, n)`` input spectra, ``gy (..., o, n)`` input-output (``E[conj X_i Y_o]``),
    ``yy (..., o)`` output autospectra, all already conditioned on the previous inputs.
    """
    grr = np.real(g[..., r, r])
    with np.errstate(invalid="ignore", divide="ignore"):
        l_rj = g[..., r, :] / grr[..., None]          # L_rj, j over inputs
        l_ry = gy[..., :, r] / grr[..., None]         # L_ry, y over outputs
        g_new = g - g[..., :, r, None] * l_rj[..., None, :]          # G_ij - L_rj G_ir
        gy_new = gy - l_ry[..., :, None] * g[..., None, :, r]        # G_iy - L_ry G_ir
        yy_new = yy - np.real(l_ry * np.conj(gy[..., :, r]))         # G_yy - L_ry G_yr
    return g_new, gy_new, yy_new


def _recursion_core(gxx, gxy, gyy, flag):
    """Conditioned pair spectra by the ordered recursion Eq. 10 (same outputs as
    :func:`_matrix_core`): for each input ``q`` the others are removed one by one (Eq. 10),
    leaving ``G_qq.(n-1)!``, ``G_qy.(n-1)!``, ``G_yy.(n-1)!``. The multiple coherence is Eq. 12's
    ordered sum over the natural order, ``sum_r |G_ry.(r-1)!|^2 / (G_rr.(r-1)! Gyy)``."""
    n = gxx.shape[-1]
    safe = np.where(flag[..., None, None], np.eye(n), gxx)
    shape = gxy.shape
    gxx_c = np.empty(shape)
    gyy_c = np.empty(shape)
    gxy_c = np.empty(shape, complex)
    for q in range(n):
        g, gy, yy = safe, gxy, gyy
        for r in (k for k in range(n) if k != q):
            g, gy, yy = _condition_on(g, gy, yy, r)
        gxx_c[..., q] = np.real(g[..., q, q])[..., None]
        gxy_c[..., q] = gy[..., :, q]
        gyy_c[..., q] = yy
    g, gy, yy = safe, gxy, gyy
    explained = np.zeros(gyy.shape)
    for r in range(n):  # Eq. 12 in the natural order
        with np.errstate(invalid="ignore", divide="ignore"):
            explained = explained + np.abs(gy[..., :, r]) ** 2 / np.real(g[..., r, r])[..., None]
        g, gy, yy = _condition_on(g, gy, yy, r)
    with np.errstate(invalid="ignore", divide="ignore"):
        mult = explained / gyy
    return gxx_c, gyy_c, gxy_c, mult


_CORES = {"matrix": _matrix_core, "recursion": _recursion_core}


def conditioned_pair_spectra(Gxx: xr.DataArray, Gyy: xr.DataArray, Gxy: xr.DataArray,
                             flag: xr.DataArray | None = None,
                             method: str = "matrix") -> xr.Dataset:
    """Spectra of every input/output pair conditioned on all other inputs.

    Returns a Dataset with ``Gxx_pair``, ``Gyy_pair`` (real), ``Gxy_pair`` (complex), all
    (output, input, ...), and ``multiple_coherence`` (output, ...). Entries at ``flag`` (bool
    over the non-core dims, e.g. :func:`collinear`) are NaN; without ``flag``, entries where
    the input matrix is singular (linearly dependent inputs) are NaN.
    """
    if method not in _CORES:
        raise InputDataError(f"conditioning method must be one of {sorted(_CORES)}, got {method!r}")
    if flag is None:
        # Never invert a singular input matrix (e.g. x2 = 2 x1): NaN there, not an exception
        # from the solve or numbers made of rounding noise.
        flag = collinear(Gxx, 1.0)
    gxx_c, gyy_c, gxy_c, mult = xr.apply_ufunc(
        _CORES[method], Gxx, Gxy, Gyy, flag,
        input_core_dims=[["input", "input_j"], ["output", "input"], ["output"], []],
        output_core_dims=[["output", "input"]] * 3 + [["output"]],
    )
    ds = xr.Dataset({"Gxx_pair": gxx_c, "Gyy_pair": gyy_c, "Gxy_pair": gxy_c,
                     "multiple_coherence": mult.clip(0.0, 1.0)})
    ds = ds.where(~flag)
    for name in ("Gxx_pair", "Gyy_pair", "Gxy_pair"):
        ds[name] = ds[name].transpose("output", "input", ...)
    ds["multiple_coherence"] = ds["multiple_coherence"].transpose("output", ...)
    ds["Gxx_pair"].attrs["long_name"] = "input autospectrum conditioned on the other inputs"
    ds["Gyy_pair"].attrs["long_name"] = "output autospectrum conditioned on the other inputs"
    ds["Gxy_pair"].attrs["long_name"] = "cross spectrum conditioned on the other inputs (Eq. 10)"
    ds["multiple_coherence"].attrs.update(long_name="multiple coherence (Eq. 12)", units="1")
    return ds


def pair_coherence(Gxx_pair, Gyy_pair, Gxy_pair):
    """Coherence of pair spectra, ``|Gxy|^2 / (Gxx Gyy)``: Eq. 7 for ordinary spectra, the
    partial coherence Eq. 11 for conditioned ones."""
    with np.errstate(invalid="ignore", divide="ignore"):
        return (abs(Gxy_pair) ** 2 / (Gxx_pair * Gyy_pair)).clip(0.0, 1.0)


# --------------------------------------------------------------------------------------------
# frequency responses from spectra
# --------------------------------------------------------------------------------------------

def _common(spectra: xr.Dataset) -> xr.Dataset:
    """Variables shared by the SISO and the conditioned analyses."""
    Gxx, Gyy, Gxy = spectra["Gxx"], spectra["Gyy"], spectra["Gxy"]
    ds = xr.Dataset({"Gxx": Gxx, "Gyy": Gyy, "Gxy": Gxy,
                     "coherence": ordinary_coherence(Gxx, Gyy, Gxy),
                     "cross_coherence": cross_coherence(Gxx),
                     "input_coherence": input_coherence(Gxx)})
    for name in ("n_d", "n_segments"):
        if name in spectra:
            ds[name] = spectra[name]
    return ds


def siso_response(spectra: xr.Dataset, *, C_eps: float = DEFAULT_C_EPS) -> xr.Dataset:
    """Unconditioned single-input estimates for every pair, ignoring the other inputs.

    ``H = Gxy / Gxx_ii``, ordinary coherence Eq. 7, random error Eq. 9. The pair spectra
    (``Gxx_pair``, ``Gyy_pair``, ``Gxy_pair``) are the ordinary ones; ``partial_coherence``
    equals ``coherence`` and ``collinear`` is all False. ``spectra`` needs ``n_d``.
    """
    ds = _common(spectra)
    gii = input_autospectra(ds["Gxx"])
    ds["Gxx_pair"] = xr.broadcast(gii, ds["Gxy"].real)[0].transpose("output", "input", ...)
    ds["Gyy_pair"] = xr.broadcast(ds["Gyy"], ds["Gxy"].real)[0].transpose("output", "input", ...)
    ds["Gxy_pair"] = ds["Gxy"]
    ds["H"] = ds["Gxy_pair"] / ds["Gxx_pair"]
    ds["partial_coherence"] = ds["coherence"]
    with np.errstate(invalid="ignore", divide="ignore"):
        ds["multiple_coherence"] = conditioned_pair_spectra(
            ds["Gxx"], ds["Gyy"], ds["Gxy"])["multiple_coherence"]
    ds["random_error"] = random_error(ds["coherence"], spectra["n_d"], C_eps)
    ds["collinear"] = xr.zeros_like(ds["Gyy"].isel(output=0, drop=True), dtype=bool)
    ds.attrs.update(conditioned=False, C_eps=C_eps)
    return _describe(ds)


def conditioned_response(spectra: xr.Dataset, *, C_eps: float = DEFAULT_C_EPS,
                         collinear_threshold: float = DEFAULT_COLLINEAR_THRESHOLD,
                         method: str = "matrix", collinear_inputs=None) -> xr.Dataset:
    """Conditioned (MIMO) frequency responses of every input/output pair.

    Parameters
    ----------
    spectra : xr.Dataset
        ``Gxx (input, input_j, frequency, ...)``, ``Gyy (output, ...)``, ``Gxy (output, input,
        ...)`` and ``n_d`` (independent averages, may vary along ``window``).
    C_eps : float
        Random-error constant of Eq. 13 (default 0.7, Hann with 50-80 % overlap).
    collinear_threshold : float
        Flag frequencies where an input's multiple coherence on the others exceeds this
        (default 0.99); conditioned results there are NaN.
    method : {"matrix", "recursion"}
        Normal-equation solve or the paper's Eq. 10 recursion; they agree to rounding.
    collinear_inputs : sequence of str, optional
        Inputs whose collinearity is tested (default all; see :func:`collinear`).

    Returns
    -------
    xr.Dataset with ``H``, ``partial_coherence`` (Eq. 11), ``random_error`` (Eq. 13),
    ``Gxx_pair``/``Gyy_pair``/``Gxy_pair`` (conditioned pair spectra, output x input),
    ``multiple_coherence`` (Eq. 12), ``collinear``, and the unconditioned ``Gxx``, ``Gyy``,
    ``Gxy``, ``coherence`` (Eq. 7), ``cross_coherence`` (Eq. 8), ``input_coherence``.
    """
    ds = _common(spectra)
    flag = collinear(ds["Gxx"], collinear_threshold, collinear_inputs)
    ds = ds.merge(conditioned_pair_spectra(ds["Gxx"], ds["Gyy"], ds["Gxy"], flag, method))
    with np.errstate(invalid="ignore", divide="ignore"):
        ds["H"] = ds["Gxy_pair"] / ds["Gxx_pair"]
    ds["partial_coherence"] = pair_coherence(ds["Gxx_pair"], ds["Gyy_pair"], ds["Gxy_pair"])
    ds["random_error"] = random_error(ds["partial_coherence"], spectra["n_d"], C_eps)
    ds["collinear"] = flag
    ds.attrs.update(conditioned=True, C_eps=C_eps, collinear_threshold=collinear_threshold,
                    conditioning_method=method)
    return _describe(ds)


def _describe(ds: xr.Dataset) -> xr.Dataset:
    for name in ("H", "coherence", "partial_coherence", "random_error", "Gxy", "Gxx_pair",
                 "Gyy_pair", "Gxy_pair"):
        ds[name] = ds[name].transpose("output", "input", ...)
    for name in ("Gxx", "cross_coherence"):
        ds[name] = ds[name].transpose("input", "input_j", ...)
    ds["Gyy"] = ds["Gyy"].transpose("output", ...)
    ds["multiple_coherence"] = ds["multiple_coherence"].transpose("output", ...)
    ds["H"].attrs.update(long_name="frequency response (output units per input unit)")
    ds["partial_coherence"].attrs.update(long_name="partial coherence (Eq. 11)", units="1")
    if not ds.attrs.get("conditioned"):
        ds["partial_coherence"].attrs["long_name"] = "ordinary coherence (unconditioned)"
    ds["random_error"].attrs.update(long_name="normalised random error (Eq. 9/13)", units="1")
    ds["collinear"].attrs.setdefault("long_name", "inputs nearly collinear")
    return ds
