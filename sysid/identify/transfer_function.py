"""Transfer-function fits with an equivalent delay (CIFER's NAVFIT; low-order equivalent systems).

One input/output pair ``y/u`` of a composite frequency response (or of a model's response) is
fitted by

    T(s) = (b_m s^m + ... + b_1 s + b_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0) e^{-tau s}

(order ``m/n``, monic denominator) with the CIFER cost of the state-space fit, over the pair's
coherent band (the longest run of frequencies with coherence >= 0.6, ``n_points`` = 20
log-spaced points) and with its weights ``W_g``, ``W_p``, ``W_gamma``: the same point
selection (:func:`sysid.identify.frequency_domain.select_fit_data`) and residuals
(:func:`~sysid.identify.frequency_domain.response_residuals`), so ``J`` here and a pair's
``J`` of the state-space fit mean the same thing (``J <= 50``: the two are nearly
indistinguishable).

Accuracy: Cramer-Rao bounds and insensitivities of the coefficients and the delay from the
Jacobian of the weighted residuals, CIFER convention (:func:`sysid.identify.statistics.parameter_statistics`).
Equivalent modal parameters: each pole and zero as a natural frequency (rad/s) and damping
ratio (complex pairs) or a time constant ``-1/lambda`` (s; negative for an unstable real root).

Minimisation: trust-region least squares with the delay bounded to 0..0.3 s
(``sysid.models.DELAY_BOUNDS``), started from a Sanathanan-Koerner iterated linear fit of the
coefficients at each of a few fixed delays; the best is kept.

A *LOES of a model* fits the model's response on the data's frequencies with the data's
coherence (:func:`model_response_dataset`), so the model's equivalent delay is measured over
the same band with the same weights as the data's.

Attitudes that were not measured come from the rate responses by integration,
``theta/u = (q/u) / (j omega)`` (:func:`pair_response`); the coherence and random error are the
rate's (a division by ``j omega`` changes neither).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 11 (transfer-function modelling, NAVFIT, equivalent delays, LOES).
* Sanathanan, C. K. and Koerner, J., "Transfer function synthesis as a ratio of two complex
  polynomials", *IEEE Trans. Automatic Control* 8, 1963.
* docs/methods.md, "Transfer-function fits".
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
import scipy.optimize
import xarray as xr

from sysid.core.errors import IdentificationError, InputDataError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.data.campaign import CampaignData
from sysid.identify.frequency_domain import (N_POINTS, FitData, parse_pairs,
                                             response_jacobian, response_residuals,
                                             select_fit_data)
from sysid.identify.statistics import ParameterStatistics, parameter_statistics
from sysid.models import DELAY_BOUNDS, frequency_response

__all__ = ["RATE_OF", "parse_order", "pair_response", "model_response_dataset",
           "TransferFunctionFit", "fit_transfer_function", "roots_table",
           "START_DELAYS", "TRUTH_SOURCES", "campaign_sources", "fit_campaign"]

#: The rate whose integral is each attitude (small-angle Euler kinematics about trim).
RATE_OF = {"phi": "p", "theta": "q", "psi": "r"}
#: Fixed delays (s) the linear start fits are made at; the best converged fit is kept.
START_DELAYS = (0.0, 0.02, 0.05, 0.1, 0.15, 0.2)
#: Sanathanan-Koerner re-weighting passes of the linear start fit.
SK_ITERATIONS = 5


def parse_order(order) -> tuple[int, int]:
    """``"1/2"`` or ``(1, 2)`` -> ``(m, n)``: numerator and denominator degree."""
    if isinstance(order, str):
        parts = order.split("/")
        if len(parts) != 2:
            raise InputDataError(f"order {order!r}: expected 'N/D', e.g. '1/2'")
        try:
            order = (int(parts[0]), int(parts[1]))
        except ValueError:
            raise InputDataError(f"order {order!r}: N and D must be integers") from None
    m, n = (int(x) for x in order)
    if m < 0 or n < 1 or m > n + 1:
        raise InputDataError(f"order {m}/{n}: need 0 <= N <= D + 1 and D >= 1")
    return m, n


def _coherence_variable(fr: xr.Dataset) -> str:
    cvar = "partial_coherence" if "partial_coherence" in fr else "coherence"
    if cvar not in fr:
        raise InputDataError("frequency-response Dataset has neither 'partial_coherence' nor "
                             "'coherence'")
    return cvar


def pair_response(fr: xr.Dataset, output: str, input: str) -> tuple[xr.Dataset, str]:
    """One pair of a composite frequency-response Dataset as a small Dataset of the same layout.

    Returns ``(dataset, origin)``: dims ``output`` (one), ``input`` (one), ``frequency``;
    ``H``, the coherence variable and ``random_error`` when present. ``origin`` is
    ``"measured"``, or ``"integrated"`` when ``output`` is an attitude (``phi theta psi``)
    the Dataset lacks (or holds only NaN for) and its rate (``p q r``) is there:
    ``H = H_rate / (j omega)`` (module docstring).
    """
    if "H" not in fr:
        raise InputDataError("frequency-response Dataset has no variable 'H'")
    outputs = [str(x) for x in fr["output"].values]
    inputs = [str(x) for x in fr["input"].values]
    if input not in inputs:
        raise InputDataError(f"pair {output}/{input}: input {input!r} not in the frequency "
                             f"response (inputs {inputs})")
    cvar = _coherence_variable(fr)
    names = [v for v in ("H", cvar, "random_error") if v in fr]
    measured = output in outputs and bool(
        np.any(np.isfinite(fr["H"].sel(output=output, input=input).values)))
    if measured:
        ds = fr[names].sel(output=[output], input=[input])
        return ds, "measured"
    rate = RATE_OF.get(output)
    if rate is None or rate not in outputs:
        raise InputDataError(f"pair {output}/{input}: output {output!r} not in the frequency "
                             f"response (outputs {outputs})"
                             + (f" and neither is its rate {rate!r}" if rate else ""))
    ds = fr[names].sel(output=[rate], input=[input])
    ds["H"] = ds["H"] / (1j * ds["frequency"])
    ds = ds.assign_coords(output=[output])
    ds.attrs = dict(fr.attrs)
    return ds, "integrated"


def model_response_dataset(model: xr.Dataset, fr: xr.Dataset, output: str, input: str,
                           ) -> xr.Dataset:
    """A model's response of one pair laid out like :func:`pair_response`, carrying the
    data's coherence (and random error) on the data's frequencies, so that a fit of it uses
    the data's band and weights (a LOES of the model). A model without the attitude output
    gives it from its rate by integration."""
    data, _ = pair_response(fr, output, input)
    omega = data["frequency"].values
    T = frequency_response(model, omega)
    outs = [str(x) for x in T["output"].values]
    if input not in [str(x) for x in T["input"].values]:
        raise InputDataError(f"model {model.attrs.get('method', '')!r} has no input {input!r}")
    if output in outs:
        H = T.sel(output=output, input=input).values
    elif RATE_OF.get(output) in outs:
        H = T.sel(output=RATE_OF[output], input=input).values / (1j * omega)
    else:
        raise InputDataError(f"model {model.attrs.get('method', '')!r} has no output "
                             f"{output!r} (outputs {outs})")
    out = data.copy()
    out["H"] = (("output", "input", "frequency"), H[None, None, :])
    out.attrs = {"source": str(model.attrs.get("method", "model"))}
    return out


# --------------------------------------------------------------------------------------------
# the model and its fit


def _names(m: int, n: int, delay: bool) -> tuple[str, ...]:
    return (tuple(f"b{k}" for k in range(m + 1)) + tuple(f"a{k}" for k in range(n))
            + (("tau",) if delay else ()))


class _Model:
    """Parameter vector <-> coefficients, and T(s) with its analytic derivatives."""

    def __init__(self, m: int, n: int, delay: bool, fixed: Mapping[str, float]):
        self.m, self.n, self.delay = m, n, delay
        self.names = _names(m, n, delay)
        unknown = [k for k in fixed if k not in self.names]
        if unknown:
            raise InputDataError(f"fixed parameters {unknown} are not among {list(self.names)}")
        self.fixed = {k: float(v) for k, v in fixed.items()}
        self.free = tuple(k for k in self.names if k not in self.fixed)
        if not self.free:
            raise InputDataError("every parameter is fixed; nothing to fit")

    def full(self, theta) -> dict[str, float]:
        values = dict(self.fixed)
        values.update(zip(self.free, np.asarray(theta, float)))
        values.setdefault("tau", 0.0)
        return values

    def coefficients(self, theta) -> tuple[np.ndarray, np.ndarray, float]:
        """``(b, a, tau)``: b0..bm and a0..a_{n-1} (ascending powers), delay."""
        v = self.full(theta)
        b = np.array([v[f"b{k}"] for k in range(self.m + 1)])
        a = np.array([v[f"a{k}"] for k in range(self.n)])
        return b, a, v["tau"]

    def response(self, theta, s, jacobian: bool = False):
        b, a, tau = self.coefficients(theta)
        powers = s[:, None] ** np.arange(max(self.m, self.n) + 1)
        N = powers[:, :self.m + 1] @ b
        D = powers[:, self.n] + powers[:, :self.n] @ a
        E = np.exp(-s * tau)
        T = N / D * E
        if not jacobian:
            return T
        cols = []
        for name in self.free:
            k = int(name[1:]) if name != "tau" else -1
            if name == "tau":
                cols.append(-s * T)
            elif name[0] == "b":
                cols.append(powers[:, k] / D * E)
            else:
                cols.append(-T * powers[:, k] / D)
        return T, np.stack(cols, axis=1)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        lo = np.array([DELAY_BOUNDS[0] if k == "tau" else -np.inf for k in self.free])
        hi = np.array([DELAY_BOUNDS[1] if k == "tau" else np.inf for k in self.free])
        return lo, hi


def _linear_start(model: _Model, s, H, weight, tau: float) -> np.ndarray:
    """Coefficients at a fixed delay: Sanathanan-Koerner iterations of
    ``N(s) - H e^{s tau} D(s) = 0``, each equation scaled by ``sqrt(weight) / |H D_prev|``
    (a relative equation error, so all frequencies count alike)."""
    Hd = H * np.exp(s * tau)
    free = [k for k in model.free if k != "tau"]
    fixed = model.full(np.zeros(len(model.free)))
    fixed.update(model.fixed)
    D_prev = np.ones_like(s)
    theta = np.zeros(len(free))
    for _ in range(SK_ITERATIONS):
        rhs = Hd * s ** model.n
        cols = []
        for name in model.names:
            if name == "tau":
                continue
            k = int(name[1:])
            col = s ** k if name[0] == "b" else -Hd * s ** k
            if name in free:
                cols.append(col)
            else:
                rhs = rhs - fixed[name] * col
        X = np.stack(cols, axis=1)
        scale = np.sqrt(weight) / np.maximum(np.abs(Hd * D_prev), 1e-300)
        Xr = np.vstack([(X * scale[:, None]).real, (X * scale[:, None]).imag])
        yr = np.concatenate([(rhs * scale).real, (rhs * scale).imag])
        theta = np.linalg.lstsq(Xr, yr, rcond=None)[0]
        values = dict(fixed)
        values.update(zip(free, theta))
        D_prev = s ** model.n + sum(values[f"a{k}"] * s ** k for k in range(model.n))
    out = dict(zip(free, theta))
    out["tau"] = tau
    return np.array([out[k] for k in model.free])


@dataclass
class TransferFunctionFit:
    """Outcome of :func:`fit_transfer_function`.

    Attributes
    ----------
    pair : str
        ``"output/input"``.
    order : (int, int)
        Numerator and denominator degree.
    numerator, denominator : ndarray
        Coefficients in *descending* powers of s (``numpy.polyval`` / python-control order);
        the denominator is monic.
    delay : float
        Equivalent delay, s (0 when not fitted).
    statistics : ParameterStatistics
        Cramer-Rao bounds and insensitivities of the free parameters (``b0..bm``,
        ``a0..a_{n-1}``, ``tau``; ``bk`` multiplies ``s^k``).
    J : float
        CIFER cost over the fitted points.
    data : FitData
        The points fitted (band in ``data.ranges``).
    source : str
        ``"data"`` or the model's method name.
    origin : str
        ``"measured"`` or ``"integrated"`` (an attitude from its rate) for data, ``"model"``
        for a model's response.
    fixed : dict
        Parameters held at given values.
    """

    pair: str
    order: tuple[int, int]
    numerator: np.ndarray
    denominator: np.ndarray
    delay: float
    statistics: ParameterStatistics
    J: float
    data: FitData
    source: str
    origin: str
    fixed: dict

    @property
    def band(self) -> tuple[float, float]:
        """Fitted band (rad/s)."""
        return next(iter(self.data.ranges.values()))

    def response(self, omega) -> np.ndarray:
        """``T(j omega)`` of the fitted transfer function with its delay."""
        s = 1j * np.asarray(omega, float)
        return (np.polyval(self.numerator, s) / np.polyval(self.denominator, s)
                * np.exp(-s * self.delay))

    def modes(self) -> xr.Dataset:
        """Poles and zeros with their natural frequency, damping and time constant
        (:func:`roots_table`)."""
        return roots_table(poles=np.roots(self.denominator), zeros=np.roots(self.numerator))

    def to_dataset(self) -> xr.Dataset:
        """The fit as a labelled Dataset: ``value``, ``cramer_rao``, ``cramer_rao_percent``,
        ``insensitivity``, ``insensitivity_percent`` (parameter), the roots (``root``), and
        attributes ``pair``, ``order``, ``J``, ``delay_s``, ``omega_min``, ``omega_max``,
        ``source``, ``origin``."""
        stats = self.statistics.to_dataset().drop_vars(["correlation", "parameter_j"],
                                                        errors="ignore")
        lo, hi = self.band
        ds = xr.merge([stats, self.modes()])
        ds.attrs = {"pair": self.pair, "order": f"{self.order[0]}/{self.order[1]}",
                    "J": float(self.J), "delay_s": float(self.delay),
                    "numerator": [float(x) for x in self.numerator],
                    "denominator": [float(x) for x in self.denominator],
                    "omega_min": float(lo), "omega_max": float(hi), "source": self.source,
                    "origin": self.origin, "fixed": ",".join(f"{k}={v:g}"
                                                             for k, v in self.fixed.items()),
                    "coherence_min": float(self.data.coherence_min),
                    "n_points": int(self.data.n_points)}
        return ds

    def table(self) -> str:
        """Plain-text summary: the transfer function, coefficients with CR % and I %, the
        roots as frequency/damping/time constant, J and the band."""
        lo, hi = self.band

        def poly(c):
            n = len(c) - 1
            return " + ".join(f"{x:.5g}" + (f" s^{n - k}" if n - k > 1 else " s" if n - k == 1
                                            else "") for k, x in enumerate(c))

        lines = [f"Transfer-function fit of {self.pair} ({self.source}, {self.origin}), order "
                 f"{self.order[0]}/{self.order[1]}, band {lo:.3g}-{hi:.3g} rad/s, "
                 f"J = {self.J:.2f}",
                 f"  T(s) = [{poly(self.numerator)}] / [{poly(self.denominator)}]"
                 + (f" e^(-{self.delay:.4f} s)" if self.delay else ""),
                 self.statistics.table()]
        if self.fixed:
            lines.append("fixed: " + ", ".join(f"{k} = {v:g}" for k, v in self.fixed.items()))
        modes = self.modes()
        for k in range(modes.sizes["root"]):
            r = modes.isel(root=k)
            lam = complex(float(r["real"]), float(r["imag"]))
            if abs(lam.imag) > 0:
                what = (f"omega_n = {float(r['frequency']):.4g} rad/s, "
                        f"zeta = {float(r['damping']):.4g}")
            elif lam == 0:
                what = "at the origin"
            else:
                what = f"time constant {float(r['time_constant']):.4g} s"
            lines.append(f"  {str(r['kind'].values)} {lam.real:+.4g}{lam.imag:+.4g}j: {what}")
        return "\n".join(lines)


def roots_table(*, poles, zeros) -> xr.Dataset:
    """Roots as a Dataset over ``root``: ``kind`` (pole/zero), ``real``, ``imag`` (1/s),
    ``frequency`` ``|lambda|`` (rad/s), ``damping`` ``-Re lambda / |lambda|``,
    ``time_constant`` ``-1/lambda`` for real roots (s; NaN for complex ones and at 0)."""
    roots = [("pole", complex(p)) for p in np.atleast_1d(poles)]
    roots += [("zero", complex(z)) for z in np.atleast_1d(zeros)]
    lam = np.array([r for _, r in roots], complex)
    mag = np.abs(lam)
    real = np.abs(lam.imag) <= 1e-9 * np.maximum(mag, 1e-300)
    with np.errstate(divide="ignore", invalid="ignore"):
        damping = np.where(mag > 0, -lam.real / mag, np.nan)
        tc = np.where(real & (mag > 0), -1.0 / lam.real, np.nan)
    return xr.Dataset(
        {"kind": ("root", [k for k, _ in roots]),
         "real": ("root", lam.real, {"units": "1/s"}),
         "imag": ("root", np.where(real, 0.0, lam.imag), {"units": "rad/s"}),
         "frequency": ("root", mag, {"units": "rad/s", "long_name": "natural frequency"}),
         "damping": ("root", damping, {"units": "1", "long_name": "damping ratio"}),
         "time_constant": ("root", tc, {"units": "s", "long_name": "-1/lambda (real roots)"})},
        coords={"root": np.arange(len(roots))})


def fit_transfer_function(fr: xr.Dataset, pair: str, *, order="1/2", delay: bool = True,
                          model: xr.Dataset | None = None,
                          fixed: Mapping[str, float] | None = None,
                          coherence_min: float = COHERENCE_MIN, n_points: int = N_POINTS,
                          frequency_range: tuple[float, float] | None = None,
                          start_delays: Sequence[float] = START_DELAYS,
                          tol: float = 1e-12) -> TransferFunctionFit:
    """Fit ``T(s) = N(s)/D(s) e^{-tau s}`` to one pair with the CIFER cost (module docstring).

    Parameters
    ----------
    fr : xr.Dataset
        Composite frequency responses (``docs/data_model.md``): ``H``, ``partial_coherence``
        or ``coherence``, ``random_error``. An attitude pair it lacks is built from the rate
        (:func:`pair_response`).
    pair : str
        ``"output/input"``, e.g. ``"theta/lon"`` or ``"q/lon"``.
    order : str or (int, int)
        ``"N/D"``: numerator and (monic) denominator degree.
    delay : bool
        Fit an equivalent delay (bounded 0..0.3 s); else none.
    model : xr.Dataset, optional
        Fit this model's response instead of the data, on the data's band with the data's
        coherence weights (a LOES of the model, :func:`model_response_dataset`).
    fixed : mapping, optional
        Parameters held at given values, e.g. ``{"a0": 0.0}`` for a free integrator.
    coherence_min, n_points, frequency_range
        Point selection as in the state-space fit (0.6, 20 points; optional band limit, rad/s).
    start_delays : sequence of float
        Delays of the linear start fits (s).

    Returns
    -------
    TransferFunctionFit

    Examples
    --------
    >>> from sysid.data.campaign import CampaignData
    >>> data = CampaignData.read("campaign.nc")
    >>> fit = fit_transfer_function(data.frequency_response(), "q/lon", order="1/2")
    >>> print(fit.table())             # coefficients with CR %, delay, poles, J
    >>> truth = fit_transfer_function(data.frequency_response(), "q/lon", order="1/2",
    ...                               model=data.group("linearization_full"))
    >>> fit.delay - truth.delay        # equivalent delay of the data against the truth's
    """
    ((output, input),) = parse_pairs([pair])
    m, n = parse_order(order)
    ds, origin = pair_response(fr, output, input)
    source = "data"
    if model is not None:
        ds = model_response_dataset(model, fr, output, input)
        source, origin = str(model.attrs.get("method", "model")), "model"
        if source == "linearization" and model.attrs.get("structure") == "full":
            source = "linearization_full"
    data = select_fit_data(ds, [(output, input)], coherence_min=coherence_min,
                           n_points=n_points, frequency_range=frequency_range)
    tf = _Model(m, n, delay, dict(fixed or {}))
    s = 1j * data.omega
    H = data.H
    lo, hi = tf.bounds()
    best = None
    starts = sorted({float(np.clip(t, *DELAY_BOUNDS)) for t in start_delays}) if delay else [0.0]
    for tau0 in starts:
        theta0 = _linear_start(tf, s, H, data.weight, tau0)
        if not np.all(np.isfinite(theta0)):
            continue
        span = np.where(np.isfinite(hi - lo), hi - lo, 1.0)
        theta0 = np.clip(theta0, lo + 1e-9 * span, hi - 1e-9 * span)
        res = scipy.optimize.least_squares(
            lambda th: response_residuals(tf.response(th, s), data), theta0,
            jac=lambda th: response_jacobian(*tf.response(th, s, jacobian=True), data),
            bounds=(lo, hi), method="trf", x_scale="jac", ftol=tol, xtol=tol, gtol=tol)
        J = float(np.sum(res.fun ** 2))
        if best is None or J < best[0]:
            best = (J, res.x)
    if best is None:
        raise IdentificationError(f"transfer-function fit of {pair}: no start value was finite "
                                  "(the response has no usable points)")
    J, theta = best
    T, dT = tf.response(theta, s, jacobian=True)
    stats = parameter_statistics(response_jacobian(T, dT, data), theta, tf.free)
    b, a, tau = tf.coefficients(theta)
    return TransferFunctionFit(f"{output}/{input}", (m, n), b[::-1].copy(),
                               np.concatenate([[1.0], a[::-1]]), float(tau), stats, J, data,
                               source, origin, dict(tf.fixed))


#: Campaign groups holding the truth's linearisations, by source name.
TRUTH_SOURCES = ("linearization_full", "linearization")


def campaign_sources(data: CampaignData) -> dict[str, xr.Dataset | None]:
    """What a campaign can fit: ``{"data": None}`` when it has ``/frequency_response``, the
    truth's linearisations (``linearization_full``, ``linearization``) and ``/models/*``,
    each as its model Dataset."""
    out: dict[str, xr.Dataset | None] = {}
    if data.frequency_response() is not None:
        out["data"] = None
    for name in TRUTH_SOURCES:
        ds = data.group(name)
        if ds is not None and "A" in ds and "B" in ds:
            out[name] = ds
    out.update(data.models())
    return out


def fit_campaign(data: CampaignData, pair: str, *, sources: Sequence[str] = ("data",),
                 **kw) -> dict[str, TransferFunctionFit]:
    """:func:`fit_transfer_function` of one pair for several sources of a campaign:
    ``"data"`` (the composite response) and model sources of :func:`campaign_sources`, each
    a LOES on the data's band and weights. ``kw`` go to :func:`fit_transfer_function`.
    Returns ``{source: fit}`` in the order given."""
    fr = data.frequency_response()
    if fr is None:
        raise InputDataError(f"campaign {data.source}: no /frequency_response group (the band "
                             "and weights of every fit come from it); run "
                             "'sysid frequency-response' first")
    available = campaign_sources(data)
    unknown = [s for s in sources if s not in available]
    if unknown:
        raise InputDataError(f"campaign {data.source}: unknown sources {unknown} (available: "
                             f"{list(available)})")
    return {s: fit_transfer_function(fr, pair, model=available[s], **kw) for s in sources}
