"""Validation in the frequency domain: mismatch envelopes (paper Eq. 20).

Frequency domain
    The mismatch of a model against reference data is ``M(jw) = T_model(jw) / T_ref(jw)``
    (paper Eq. 20), expressed as magnitude in dB and phase in deg. It is judged against
    envelopes of "unnoticeable" added dynamics: the MUAD bounds (Hoh; MIL-STD-1797A low-order
    equivalent-system mismatch bounds) ship built in, and users can load their own envelopes
    (e.g. the AEE of Mitchell et al. 2006, whose coefficients we could not verify from public
    sources and therefore do not ship) from a TOML file.

The time-domain metrics (J_rms, TIC) are in :mod:`sysid.assess.metrics`.

References
----------
* *Comparison of frequency and time domain identification of a helicopter in hover*
  (Eq. 20).
* Hoh, R. H., MUAD bounds; MIL-STD-1797A, *Flying Qualities of Piloted Aircraft*, 1990.
* Mitchell, D. G. et al., allowable error envelopes, 2006 (not shipped).
* docs/methods.md, "Validation envelopes".
"""

from __future__ import annotations

import tomllib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN


@dataclass(frozen=True)
class Bound:
    """One envelope boundary as a function of frequency (rad/s).

    Either a transfer function ``num(s)/den(s) * exp(-delay s)`` whose magnitude (dB) or phase
    (deg) is the bound, or a breakpoint table interpolated linearly in log-frequency.
    """

    num: tuple = ()
    den: tuple = ()
    delay: float = 0.0
    frequency: tuple = ()
    value: tuple = ()

    def response(self, omega: np.ndarray) -> np.ndarray:
        s = 1j * np.asarray(omega, dtype=float)
        return np.polyval(self.num, s) / np.polyval(self.den, s) * np.exp(-self.delay * s)

    def magnitude_db(self, omega) -> np.ndarray:
        if self.frequency:
            return self._table(omega)
        return 20.0 * np.log10(np.abs(self.response(omega)))

    def phase_deg(self, omega) -> np.ndarray:
        if self.frequency:
            return self._table(omega)
        return np.degrees(np.unwrap(np.angle(self.response(omega))))

    def _table(self, omega) -> np.ndarray:
        return np.interp(np.log10(omega), np.log10(self.frequency), self.value,
                         left=np.nan, right=np.nan)


@dataclass(frozen=True)
class Envelope:
    """Upper and lower bounds on mismatch magnitude (dB) and phase (deg)."""

    name: str
    citation: str
    magnitude_upper: Bound
    magnitude_lower: Bound
    phase_upper: Bound
    phase_lower: Bound
    notes: str = field(default="")

    def bounds(self, omega) -> xr.Dataset:
        """The four bounds on ``omega`` (rad/s) as a Dataset over ``frequency``."""
        omega = np.asarray(omega, dtype=float)
        coords = {"frequency": ("frequency", omega, {"units": "rad/s"})}
        return xr.Dataset(
            {
                "magnitude_upper": ("frequency", self.magnitude_upper.magnitude_db(omega),
                                    {"units": "dB"}),
                "magnitude_lower": ("frequency", self.magnitude_lower.magnitude_db(omega),
                                    {"units": "dB"}),
                "phase_upper": ("frequency", self.phase_upper.phase_deg(omega), {"units": "deg"}),
                "phase_lower": ("frequency", self.phase_lower.phase_deg(omega), {"units": "deg"}),
            },
            coords=coords,
            attrs={"envelope": self.name, "citation": self.citation},
        )


#: Maximum unnoticeable added dynamics (Hoh; MIL-STD-1797A). Coefficients with the delay terms
#: as in docs/methods.md, "Validation envelopes"; checked against the published plot
#: (lower phase bound about -14 deg at 1 rad/s).
MUAD = Envelope(
    name="MUAD",
    citation="Hoh, R. H., MUAD bounds as in MIL-STD-1797A (LOES mismatch envelopes)",
    magnitude_upper=Bound(num=(3.16, 31.61, 22.79), den=(1.0, 27.14, 1.84)),
    magnitude_lower=Bound(num=(0.0955, 9.92, 2.15), den=(1.0, 11.6, 4.95)),
    phase_upper=Bound(num=(68.89, 1100.12, -275.22), den=(1.0, 39.94, 9.99), delay=-0.0059),
    phase_lower=Bound(num=(475.32, 184100.0, 29456.1), den=(1.0, 11.66, 0.0389), delay=0.0072),
)


def load_envelope(path: str | Path) -> Envelope:
    """Read a user-defined envelope from TOML.

    Format (each of the four bounds either a transfer function or a breakpoint table)::

        name = "AEE pitch, hover"
        citation = "Mitchell et al., 2006, ..."
        [magnitude.upper]
        num = [3.16, 31.61, 22.79]     # polynomial in s, highest power first
        den = [1.0, 27.14, 1.84]
        delay = 0.0                    # s, optional
        [magnitude.lower]
        frequency = [0.1, 1.0, 10.0]   # rad/s
        value = [-6.0, -2.0, -4.0]     # dB (phase tables in deg)
        [phase.upper] ...
        [phase.lower] ...
    """
    path = Path(path)
    try:
        spec = tomllib.loads(path.read_text())
    except (OSError, tomllib.TOMLDecodeError) as exc:
        raise InputDataError(f"cannot read envelope file {path}: {exc}") from None
    for key in ("name", "citation"):
        if not isinstance(spec.get(key), str) or not spec[key].strip():
            raise InputDataError(f"envelope file {path}: '{key}' (a non-empty string) is required")
    bounds = {}
    for kind in ("magnitude", "phase"):
        for side in ("upper", "lower"):
            entry = spec.get(kind, {}).get(side)
            where = f"envelope file {path}: [{kind}.{side}]"
            if not isinstance(entry, dict):
                raise InputDataError(f"{where} is missing")
            bounds[f"{kind}_{side}"] = _parse_bound(entry, where)
    return Envelope(name=spec["name"], citation=spec["citation"], **bounds,
                    notes=str(spec.get("notes", "")))


def _parse_bound(entry: dict, where: str) -> Bound:
    if "num" in entry or "den" in entry:
        try:
            num = tuple(float(v) for v in entry["num"])
            den = tuple(float(v) for v in entry["den"])
            delay = float(entry.get("delay", 0.0))
        except (KeyError, TypeError, ValueError):
            raise InputDataError(f"{where}: 'num' and 'den' must be lists of numbers") from None
        if not num or not den or not any(den):
            raise InputDataError(f"{where}: empty numerator or zero denominator")
        return Bound(num=num, den=den, delay=delay)
    try:
        freq = tuple(float(v) for v in entry["frequency"])
        value = tuple(float(v) for v in entry["value"])
    except (KeyError, TypeError, ValueError):
        raise InputDataError(
            f"{where}: give either num/den or frequency/value lists of numbers") from None
    if len(freq) != len(value) or len(freq) < 2:
        raise InputDataError(f"{where}: 'frequency' and 'value' need the same length (>= 2)")
    if not all(f > 0 for f in freq) or any(b <= a for a, b in zip(freq, freq[1:])):
        raise InputDataError(f"{where}: 'frequency' must be positive and increasing")
    if not np.all(np.isfinite(value)):
        raise InputDataError(f"{where}: 'value' contains NaN or infinity")
    return Bound(frequency=freq, value=value)


def mismatch(model: xr.DataArray, reference: xr.DataArray) -> xr.Dataset:
    """Eq. 20 mismatch ``model / reference`` as magnitude (dB) and phase (deg).

    Both arguments are complex frequency responses on the same ``frequency`` coordinate
    (any other dims broadcast, e.g. ``output`` and ``input``). Phase is wrapped to +-180 deg.
    """
    ratio = model / reference
    return xr.Dataset(
        {
            "magnitude": (20.0 * np.log10(np.abs(ratio))).assign_attrs(units="dB"),
            "phase": xr.apply_ufunc(np.angle, ratio, kwargs={"deg": True}).assign_attrs(
                units="deg"),
        }
    )


def check_envelope(
    error: xr.Dataset,
    envelope: Envelope = MUAD,
    coherence: xr.DataArray | None = None,
    min_coherence: float = COHERENCE_MIN,
) -> xr.Dataset:
    """Judge a mismatch (from :func:`mismatch`) against an envelope.

    Only frequencies where ``coherence >= min_coherence`` count (all of them without a
    coherence). Returns per pair (all dims but ``frequency``): ``inside`` (boolean per
    frequency), ``fraction_inside`` of the coherent band, and the worst magnitude and phase
    excursion beyond the bounds (dB, deg; zero when inside).

    Examples
    --------
    >>> from sysid.models import frequency_response as model_response
    >>> H = model_response(model, fr["frequency"])      # model and composite data Datasets
    >>> err = mismatch(H.sel(output="q", input="lon"), fr["H"].sel(output="q", input="lon"))
    >>> check_envelope(err, MUAD, coherence=fr["partial_coherence"].sel(output="q", input="lon")
    ...                )["fraction_inside"]
    """
    bounds = envelope.bounds(error["frequency"].values)
    mag, ph = error["magnitude"], error["phase"]
    over_mag = np.maximum(mag - bounds["magnitude_upper"], bounds["magnitude_lower"] - mag)
    over_ph = np.maximum(ph - bounds["phase_upper"], bounds["phase_lower"] - ph)
    inside = (over_mag <= 0) & (over_ph <= 0)
    counted = xr.ones_like(mag, dtype=bool)
    if coherence is not None:
        counted = coherence >= min_coherence
    counted = counted & np.isfinite(mag) & np.isfinite(bounds["magnitude_upper"])
    n_counted = counted.sum("frequency")
    fraction = (inside & counted).sum("frequency") / n_counted.where(n_counted > 0)
    fraction.attrs = {}
    return xr.Dataset(
        {
            "inside": inside,
            "counted": counted,
            "fraction_inside": fraction.assign_attrs(
                long_name=f"fraction of the coherent band inside the {envelope.name} bounds"),
            "worst_magnitude_excess": over_mag.where(counted).max("frequency").clip(min=0)
            .assign_attrs(units="dB"),
            "worst_phase_excess": over_ph.where(counted).max("frequency").clip(min=0)
            .assign_attrs(units="deg"),
        },
        attrs={"envelope": envelope.name, "citation": envelope.citation,
               "min_coherence": min_coherence},
    )
