"""Time response of a linear model Dataset: exact zero-order hold with per-entry delays.

A model ``x' = A x + (B o exp(-s tau)) u, y = C x + D u`` (paper Eq. 18-19; analysis units)
is discretised exactly for inputs held over each sample interval,

    x[k+1] = Phi x[k] + Gamma u[k],   Phi = e^{A dt},   Gamma = int_0^dt e^{A s} ds B,

and a B entry with delay ``tau`` is fed ``u(t_k - tau)`` (linear interpolation between
samples). Inputs/outputs are :class:`xarray.Dataset` on a uniform ``time`` coordinate (s).

References
----------
* Van Loan, C. F., "Computing integrals involving the matrix exponential", IEEE Trans.
  Automatic Control 23(3), 1978 (``Phi`` and ``Gamma`` from one exponential).
* Franklin, G. F., Powell, J. D. and Workman, M. L., *Digital Control of Dynamic Systems*,
  3rd ed., Addison-Wesley, 1998, ch. 4 (zero-order-hold equivalents).
"""

from __future__ import annotations

import ctypes
import math
from pathlib import Path
from typing import Mapping

import numpy as np
import scipy.linalg
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.native import native_library
from sysid.core.units import CHANNELS, channel_attrs
from sysid.models.lti import model_matrices

__all__ = ["discretize", "matrix_powers", "propagate", "simulate"]

#: From this many right-hand sides on, :func:`propagate` steps the plain recursion.
_MANY_RHS = 16


def discretize(A, B, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """Exact zero-order-hold discretisation: ``(Phi, Gamma)`` with
    ``Phi = e^{A dt}``, ``Gamma = int_0^dt e^{A s} ds B``, from one matrix exponential of the
    augmented matrix ``[[A, B], [0, 0]] dt`` (Van Loan)."""
    A = np.asarray(A, dtype=float)
    B = np.asarray(B, dtype=float)
    n, m = B.shape
    M = np.zeros((n + m, n + m))
    M[:n, :n] = A * dt
    M[:n, n:] = B * dt
    E = scipy.linalg.expm(M)
    return E[:n, :n], E[:n, n:]


def propagate(Phi, W, x0=None, *, block: int | None = None) -> np.ndarray:
    """States of ``x[k+1] = Phi x[k] + W[k]``, ``x[0] = x0``, for all k at once.

    Exact (the plain recursion, regrouped; no approximation beyond rounding). With few
    right-hand sides (k < 16) the record is cut into blocks of L samples and the Python loop
    shrinks from N steps to about 3 sqrt(N): the forcing of every block is accumulated,
    ``F_b = sum_i Phi^(L-1-i) W[bL+i]``, for all blocks at once (L matrix products); the
    block-start states ``x[(b+1)L] = Phi^L x[bL] + F_b`` are stepped; the states inside the
    blocks follow, again for all blocks at once. The flops are twice the recursion's (the
    earlier block-Toeplitz form cost about L/2 times them). With many right-hand sides
    (sensitivities) the copies into block order cost more than the loop saves, and the
    plain recursion runs (docs/notes/2026-11-24-time-domain-speed.md), compiled where the
    machine's C compiler builds ``recursion.c`` (:mod:`sysid.core.native`: 1.1 ms against
    2.7 ms for numpy's step loop at 1361 steps of 9 states and 52 columns; the same results
    to rounding).

    Parameters
    ----------
    Phi : ndarray (n, n)
    W : ndarray (N, n) or (N, n, k)
        Forcing per step (k independent forcings are propagated together).
    x0 : ndarray (n,) or (n, k), optional
        Initial state(s), default 0.
    block : int, optional
        Samples per block (k < 16), default ``round(sqrt(N))``.

    Returns
    -------
    ndarray, shape like ``W``: ``x[0] ... x[N-1]``.
    """
    W = np.asarray(W, dtype=float)
    squeeze = W.ndim == 2
    if squeeze:
        W = W[:, :, None]
    N, n, k = W.shape
    x = np.zeros((n, k)) if x0 is None else np.asarray(x0, dtype=float).reshape(n, -1) * \
        np.ones((1, k))
    if N == 0:
        return W[:, :, 0] if squeeze else W
    if k >= _MANY_RHS:
        X = np.empty((N, n, k))
        X[0] = x
        kernel = _native_propagate()
        if kernel is not None:  # the same loop compiled (sysid.core.native)
            W = np.ascontiguousarray(W)
            kernel(N, n, k, np.ascontiguousarray(Phi, dtype=float), W, X)
            return X
        for j in range(N - 1):
            np.matmul(Phi, X[j], out=X[j + 1])
            X[j + 1] += W[j]
        return X
    L = int(block or max(1, round(math.sqrt(N))))
    nb = -(-N // L)
    Wp = np.zeros((nb * L, n, k))
    Wp[:N] = W
    # T[i] = the i-th forcing of every block, as one (n, nb k) matrix
    T = np.ascontiguousarray(Wp.reshape(nb, L, n, k).transpose(1, 2, 0, 3))
    T = T.reshape(L, n, nb * k)
    F = T[0].copy()
    for i in range(1, L):
        F = Phi @ F + T[i]
    F = F.reshape(n, nb, k)
    PL = np.linalg.matrix_power(Phi, L)
    X = np.empty((L, n, nb * k))
    starts = X[0].reshape(n, nb, k)
    for b in range(nb):
        starts[:, b] = x
        x = PL @ x + F[:, b]
    for i in range(1, L):
        np.matmul(Phi, X[i - 1], out=X[i])
        X[i] += T[i - 1]
    X = X.reshape(L, n, nb, k).transpose(2, 0, 1, 3).reshape(nb * L, n, k)[:N]
    return X[:, :, 0] if squeeze else X


def _native_propagate():
    """The compiled recursion of :func:`propagate` (``recursion.c``) as a callable
    ``(N, n, k, A, W, X)``, or ``None`` where it cannot be built
    (:func:`sysid.core.native.native_status`)."""
    library = native_library("recursion", str(Path(__file__).with_name("recursion.c")))
    if library is None:
        return None
    function = library.sysid_propagate
    if function.argtypes is None:
        array = np.ctypeslib.ndpointer(dtype=np.float64, flags="C_CONTIGUOUS")
        function.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_int, array, array, array]
        function.restype = None
    return function


def matrix_powers(A, N: int, start=None) -> np.ndarray:
    """``S A^k`` for ``k = 0 .. N-1``, shape (N, m, n), ``S`` the (m, n) ``start`` (default
    the identity), by doubling: ``S A^(j+i) = (S A^i) A^j`` for all ``i < j`` in one
    (j m x n) by (n x n) product per level, about log2(N) products instead of N."""
    A = np.asarray(A, dtype=float)
    n = A.shape[0]
    S = np.eye(n) if start is None else np.asarray(start, dtype=float)
    m = S.shape[0]
    P = np.empty((N, m, n))
    if N == 0:
        return P
    P[0] = S
    j, Aj = 1, A
    while j < N:
        c = min(j, N - j)
        np.matmul(P[:c].reshape(c * m, n), Aj, out=P[j:j + c].reshape(c * m, n))
        Aj = Aj @ Aj
        j *= 2
    return P


def _delayed(u: np.ndarray, delay_samples: float) -> np.ndarray:
    """``u(t_n - d)`` on the sample grid by linear interpolation between samples; before the
    record starts the input is held at its first sample."""
    N = len(u)
    if delay_samples == 0:
        return u
    m = int(math.floor(delay_samples))
    f = delay_samples - m
    idx = np.arange(N) - m
    a = u[np.clip(idx, 0, N - 1)]
    if f == 0:
        return a
    b = u[np.clip(idx - 1, 0, N - 1)]
    return (1.0 - f) * a + f * b


def simulate(model: xr.Dataset, inputs: xr.Dataset, *, x0=None, absolute: bool = False
             ) -> xr.Dataset:
    """Time response of a model Dataset to sampled inputs (reference linear simulation).

    Convention (documented, also used by the FMU export): every input sample is held over its
    sample interval (zero-order hold, ``u(t) = u[n]`` on ``[t_n, t_n+1)``) and the model is
    discretised exactly for that hold (:func:`discretize`, matrix exponential). A delay ``tau``
    on a B entry feeds that entry with ``u(t_n - tau)``, evaluated by linear interpolation
    between the two neighbouring samples (exact when tau is a whole number of samples), and
    held over the interval like any input. Before the first sample the input is taken equal to
    its first sample. B columns are grouped by (input, delay), so the cost does not grow with
    the number of delayed entries beyond the number of distinct delays.

    Parameters
    ----------
    model : xr.Dataset
        Model Dataset (``docs/data_model.md``).
    inputs : xr.Dataset
        Variables named like the model's inputs (``lon lat col ped``), %, on a uniform ``time``
        coordinate (s). Perturbations from trim unless ``absolute``.
    x0 : mapping or array_like, optional
        Initial state perturbation (state name -> value, or an array in model state order).
    absolute : bool
        Inputs are absolute (``trim_input`` is subtracted) and outputs are returned absolute
        (``trim_output`` added).

    Returns
    -------
    xr.Dataset
        Output variables on the same ``time`` coordinate, analysis units.
    """
    A, B, C, D, tau = model_matrices(model)
    in_names = [str(s) for s in model["B"].input.values]
    out_names = [str(s) for s in model["C"].output.values]
    states = [str(s) for s in model["A"].state.values]
    if "time" not in inputs.coords:
        raise InputDataError("simulate: the inputs Dataset has no 'time' coordinate")
    missing = [k for k in in_names if k not in inputs]
    if missing:
        raise InputDataError(f"simulate: inputs Dataset lacks the model inputs {missing} "
                             f"(has {sorted(inputs.data_vars)})")
    t = np.asarray(inputs["time"].values, dtype=float)
    if len(t) < 2:
        raise InputDataError("simulate: need at least two time samples")
    dts = np.diff(t)
    dt = float(np.mean(dts))
    if not np.all(dts > 0) or np.max(np.abs(dts - dt)) > 1e-6 * max(dt, 1e-12) + 1e-9:
        raise InputDataError("simulate: the 'time' coordinate must be uniform and increasing")
    U = np.stack([np.asarray(inputs[k].values, dtype=float) for k in in_names], axis=1)
    if not np.all(np.isfinite(U)):
        bad = [k for j, k in enumerate(in_names) if not np.all(np.isfinite(U[:, j]))]
        raise InputDataError(f"simulate: input(s) {bad} contain NaN or inf")
    if absolute and "trim_input" in model:
        U = U - model["trim_input"].sel(input=in_names).values[None, :]
    # Group B columns by (input, delay): one forcing column per group.
    groups_B, groups_V = [], []
    for k in range(len(in_names)):
        for d in np.unique(tau[:, k]):
            col = np.where(tau[:, k] == d, B[:, k], 0.0)
            if not np.any(col):
                continue
            groups_B.append(col)
            groups_V.append(_delayed(U[:, k], float(d) / dt))
    n = A.shape[0]
    if x0 is None:
        xinit = np.zeros(n)
    elif isinstance(x0, Mapping):
        unknown = set(x0) - set(states)
        if unknown:
            raise InputDataError(f"simulate: x0 names unknown states {sorted(unknown)}")
        xinit = np.array([float(x0.get(s, 0.0)) for s in states])
    else:
        xinit = np.asarray(x0, dtype=float).reshape(n)
    if groups_B:
        Bg = np.stack(groups_B, axis=1)
        V = np.stack(groups_V, axis=1)
        Phi, Gam = discretize(A, Bg, dt)
        X = propagate(Phi, V @ Gam.T, xinit)
    else:
        Phi = scipy.linalg.expm(A * dt)
        X = propagate(Phi, np.zeros((len(t), n)), xinit)
    Y = X @ C.T + U @ D.T
    if absolute and "trim_output" in model:
        Y = Y + model["trim_output"].sel(output=out_names).values[None, :]
    data = {}
    for j, name in enumerate(out_names):
        attrs = channel_attrs(name) if name in CHANNELS else {}
        data[name] = (("time",), Y[:, j], attrs)
    out = xr.Dataset(data, coords={"time": ("time", t, {"units": "s", "long_name": "time"})})
    out.attrs.update({"kind": "simulation", "model": str(model.attrs.get("structure", "model")),
                      "method": str(model.attrs.get("method", "")),
                      "absolute": int(bool(absolute)),
                      "delay_convention": "linear interpolation of u(t - tau), zero-order hold"})
    return out
