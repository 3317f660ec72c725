"""Numbers of a linear model Dataset: its matrices, frequency response and python-control form.

A model Dataset (``docs/data_model.md``) holds ``A B C D delay`` in analysis units (ft/s,
deg/s, deg, % of travel; delays in s). Its transfer matrix, shape ``(output, input,
frequency)``, is

    T(s) = C (sI - A)^-1 (B o exp(-s tau)) + D                                    (Eq. 19)

with one delay ``tau`` per B entry.

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 7 (state-space models with time delays).
* "Comparison of frequency and time domain identification of a helicopter in hover" (the
  reference paper of this project), Eq. 18-19.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError

__all__ = ["model_matrices", "transfer_matrix", "frequency_response", "statespace",
           "residualize_model"]


def model_matrices(model: xr.Dataset) -> tuple[np.ndarray, ...]:
    """``(A, B, C, D, tau)`` arrays of a model Dataset in its own state/input/output order."""
    for var in ("A", "B", "C", "D"):
        if var not in model:
            raise InputDataError(f"model Dataset has no variable {var!r} "
                                 f"(see docs/data_model.md)")
    states = list(model["A"].state.values)
    A = model["A"].sel(state_dot=states, state=states).values.astype(float)
    B = model["B"].sel(state_dot=states).transpose("state_dot", "input").values.astype(float)
    C = model["C"].sel(state=states).transpose("output", "state").values.astype(float)
    D = model["D"].transpose("output", "input").sel(input=model["B"].input).values.astype(float)
    if "delay" in model:
        tau = (model["delay"].sel(state_dot=states, input=model["B"].input)
               .transpose("state_dot", "input").values.astype(float))
    else:
        tau = np.zeros_like(B)
    return A, B, C, D, tau


def transfer_matrix(A, B, C, D, tau, s) -> np.ndarray:
    """T(s) = C (sI - A)^-1 (B o exp(-s tau)) + D for every s; shape (p, m, n_s)."""
    n = A.shape[0]
    s = np.asarray(s, dtype=complex)
    M = s[:, None, None] * np.eye(n) - A
    Bd = B[None] * np.exp(-s[:, None, None] * tau[None])
    X = np.linalg.solve(M, Bd)  # batched over frequency
    T = C[None] @ X + D[None]
    return np.moveaxis(T, 0, -1)


def frequency_response(model: xr.Dataset, omega) -> xr.DataArray:
    """Frequency response of a model Dataset, with its per-entry delays (Eq. 19).

    Returns a complex DataArray ``(output, input, frequency)``; ``omega`` in rad/s.
    """
    omega = np.atleast_1d(np.asarray(omega, dtype=float))
    T = transfer_matrix(*model_matrices(model), 1j * omega)
    return xr.DataArray(T, dims=("output", "input", "frequency"),
                        coords={"output": model["C"].output.values,
                                "input": model["B"].input.values, "frequency": omega})


def statespace(model: xr.Dataset, *, pade_order: int | None = None):
    """The model Dataset as a :class:`control.StateSpace`.

    With ``pade_order=None`` the delays are *not* in the returned system: they stay in
    ``model["delay"]`` (per B entry) and must be applied separately (``T = C (sI-A)^-1
    (B o e^{-s tau}) + D``). With ``pade_order=n`` every distinct delay of every input column
    is replaced by an n-th order Pade approximant (:func:`control.pade`) feeding only the B
    entries that carry that delay, so the system has extra states ``pade_<input>_<k>_<i>``.
    """
    import control  # deferred: python-control is slow to import and only needed here

    A, B, C, D, tau = model_matrices(model)
    states = [str(s) for s in model["A"].state.values]
    inputs = [str(s) for s in model["B"].input.values]
    outputs = [str(s) for s in model["C"].output.values]
    if pade_order is None or not np.any(tau):
        return control.ss(A, B, C, D, inputs=inputs, outputs=outputs, states=states,
                          name=str(model.attrs.get("structure", "model")))
    n, m = B.shape
    Bnd = np.where(tau == 0, B, 0.0)
    blocks_A, blocks_B, extra_states = [], [], []
    for k in range(m):
        for g, d in enumerate(np.unique(tau[:, k][tau[:, k] > 0])):
            num, den = control.pade(float(d), int(pade_order))
            pss = control.ss(control.tf(num, den))
            bvec = np.where(tau[:, k] == d, B[:, k], 0.0)  # B entries with this delay
            q = pss.nstates
            blocks_A.append((np.asarray(pss.A), bvec[:, None] @ np.asarray(pss.C)))
            bp = np.zeros((q, m))
            bp[:, k] = np.asarray(pss.B)[:, 0]
            blocks_B.append(bp)
            dterm = np.zeros((n, m))
            dterm[:, k] = bvec * float(np.asarray(pss.D)[0, 0])
            Bnd = Bnd + dterm
            extra_states += [f"pade_{inputs[k]}_{g}_{i}" for i in range(q)]
    q_tot = sum(b[0].shape[0] for b in blocks_A)
    Aa = np.zeros((n + q_tot, n + q_tot))
    Ba = np.zeros((n + q_tot, m))
    Aa[:n, :n] = A
    Ba[:n] = Bnd
    off = n
    for (Ap, coupling), bp in zip(blocks_A, blocks_B):
        q = Ap.shape[0]
        Aa[off:off + q, off:off + q] = Ap
        Aa[:n, off:off + q] = coupling
        Ba[off:off + q] = bp
        off += q
    Ca = np.hstack([C, np.zeros((C.shape[0], q_tot))])
    return control.ss(Aa, Ba, Ca, D, inputs=inputs, outputs=outputs,
                      states=states + extra_states, name=str(model.attrs.get("structure", "model")))


def residualize_model(model: xr.Dataset, states, outputs=None) -> xr.Dataset:
    """The model with every state outside ``states`` residualised (quasi-steady, ``z' = 0``).

    With the kept states ``x`` and the residualised ``z``,
    ``A_r = A_xx - A_xz A_zz^-1 A_zx``, ``B_r = B_x - A_xz A_zz^-1 B_z``,
    ``C_r = C_x - C_z A_zz^-1 A_zx``, ``D_r = D - C_z A_zz^-1 B_z``: exact at zero frequency
    and accurate well below the residualised modes. ``outputs`` selects output rows
    (default all). Delays are not carried (a linearisation has none).

    References
    ----------
    * Kokotovic, P. V., Khalil, H. K. and O'Reilly, J., *Singular Perturbation Methods in
      Control*, Academic Press, 1986, ch. 1 (quasi-steady reduction).
    """
    A, B, C, D, _ = model_matrices(model)
    names = [str(s) for s in model["A"].state.values]
    states = [str(s) for s in states]
    missing = [s for s in states if s not in names]
    if missing:
        raise InputDataError(f"residualize_model: the model has no states {missing} "
                             f"(states: {names})")
    out_all = [str(o) for o in model["C"].output.values]
    outputs = out_all if outputs is None else [str(o) for o in outputs]
    absent = [o for o in outputs if o not in out_all]
    if absent:
        raise InputDataError(f"residualize_model: the model has no outputs {absent} "
                             f"(outputs: {out_all})")
    keep = [names.index(s) for s in states]
    fast = [k for k in range(len(names)) if names[k] not in states]
    rows = [out_all.index(o) for o in outputs]
    Ax, Bx, Cx = A[np.ix_(keep, keep)], B[keep], C[np.ix_(rows, keep)]
    Dr = D[rows]
    if fast:
        Azz = A[np.ix_(fast, fast)]
        SA = np.linalg.solve(Azz, A[np.ix_(fast, keep)])
        SB = np.linalg.solve(Azz, B[fast])
        Axz, Cz = A[np.ix_(keep, fast)], C[np.ix_(rows, fast)]
        Ax, Bx = Ax - Axz @ SA, Bx - Axz @ SB
        Cx, Dr = Cx - Cz @ SA, Dr - Cz @ SB
    inputs = [str(i) for i in model["B"].input.values]
    ds = xr.Dataset(
        {"A": (("state_dot", "state"), Ax), "B": (("state_dot", "input"), Bx),
         "C": (("output", "state"), Cx), "D": (("output", "input"), Dr),
         "delay": (("state_dot", "input"), np.zeros_like(Bx))},
        coords={"state_dot": states, "state": states, "input": inputs, "output": outputs},
        attrs={**model.attrs, "residualized": ",".join(names[k] for k in fast)})
    for name in ("trim_input",):
        if name in model:
            ds[name] = model[name]
    return ds
