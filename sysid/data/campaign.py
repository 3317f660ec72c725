"""The campaign accessor: what the stages read from a campaign DataTree, each rule once.

A campaign (``docs/data_model.md``) is an :class:`xarray.DataTree`: manoeuvres under
``/maneuvers/<name>``, the truth's trim and linearisations, and the result groups the stages
add (``/frequency_response``, ``/models/<method>``, ``/verification/<maneuver>``,
``/comparison``, ``/validation/<model>``). :class:`CampaignData` wraps one tree and answers
the questions every stage asks of it:

- :meth:`~CampaignData.maneuvers` / :meth:`~CampaignData.list_maneuvers`: the records
  matching a glob, in natural order (``sweep_lon_2`` before ``sweep_lon_10``);
- :meth:`~CampaignData.trim`: ``channel -> trim`` from the ``trim_<channel>`` attributes;
  :func:`record_trim` is the one rule for a single record (its attribute, else the mean of
  its first :data:`TRIM_WINDOW` seconds), used by the spectra, both fits and verification;
- :meth:`~CampaignData.linearization`: the truth linearisation a fit starts from;
- :meth:`~CampaignData.models` and the result groups.

The accessor never touches a file: :meth:`CampaignData.read` reads one with
:func:`sysid.data.netcdf.read_campaign`, and :meth:`CampaignData.with_groups` returns the tree
with some groups replaced, as :func:`sysid.data.netcdf.update_campaign_groups` writes them.
"""

from __future__ import annotations

import fnmatch
import os
import re
from collections.abc import Iterable, Mapping
from dataclasses import dataclass

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.units import CONTROLS, STATES_6DOF
from sysid.data.netcdf import read_campaign, with_groups

__all__ = ["TRIM_WINDOW", "CampaignData", "list_maneuvers", "maneuvers", "record_trim",
           "first_window_mean", "trim_from_attrs", "pick_linearization"]

#: Length (s) of the initial stretch whose mean is a record's trim when it has no
#: ``trim_<channel>`` attribute (docs/data_model.md: imported data).
TRIM_WINDOW = 1.0


# --------------------------------------------------------------------------------------------
# trim: one rule


def first_window_mean(time, values, window: float = TRIM_WINDOW) -> float:
    """Mean of ``values`` over the samples in the first ``window`` seconds of ``time``.

    The samples counted are those with ``time - time[0] < window - dt / 2`` (exactly
    ``window / dt`` samples on a uniform grid), and at least the first one.
    """
    t = np.asarray(time, dtype=float)
    x = np.asarray(values, dtype=float)
    dt = (t[-1] - t[0]) / (t.size - 1) if t.size > 1 else 0.0
    first = (t - t[0]) < window - 0.5 * dt
    first[0] = True
    return float(np.mean(x[first]))


def record_trim(record: xr.Dataset, channel: str, *, name: str | None = None,
                missing: str = "first_second") -> float:
    """Trim of ``channel`` in one record (analysis units): the one rule of the data model.

    The record's ``trim_<channel>`` attribute when it holds a finite number; when the
    attribute is missing, ``None`` or NaN, the mean of the channel's first
    :data:`TRIM_WINDOW` seconds (:func:`first_window_mean`): the aircraft starts a
    manoeuvre from trim. Any other attribute value raises
    :class:`~sysid.core.errors.InputDataError` naming the record (``name``, else its
    ``maneuver`` attribute).

    ``missing="record_mean"`` takes the whole record's mean instead where there is no
    attribute. Spectral estimates use it: they need no trim level, only a signal whose
    constant part leaks least into the lowest frequency bins (with the first-second mean, a
    noise-free periodic record lost its coherent band below 0.32 rad/s;
    tests/test_frequency_response.py).
    """
    if missing not in ("first_second", "record_mean"):
        raise ValueError(f"record_trim: missing={missing!r}; expected 'first_second' or "
                         "'record_mean'")
    key = f"trim_{channel}"
    value = record.attrs.get(key)
    if value is not None:
        try:
            value = float(value)
        except (TypeError, ValueError):
            name = name or record.attrs.get("maneuver", "?")
            raise InputDataError(f"record {name!r}: attribute {key} = {record.attrs[key]!r}; "
                                 "expected a number (the channel's trim value)") from None
        if np.isfinite(value):
            return value
    if missing == "record_mean":
        return float(np.mean(np.asarray(record[channel].values, dtype=float)))
    return first_window_mean(record["time"].values, record[channel].values)


def trim_from_attrs(sources: Iterable) -> dict[str, float]:
    """``channel -> trim`` (analysis units) from ``trim_<channel>`` attributes.

    ``sources`` are attribute mappings (or objects with ``.attrs``) in order of preference:
    each channel takes its value from the first source that has a numeric one. Channels are
    the controls and the 6-DoF states (docs/data_model.md).
    """
    mappings = [getattr(src, "attrs", src) for src in sources]
    trim: dict[str, float] = {}
    for channel in (*CONTROLS, *STATES_6DOF):
        for attrs in mappings:
            try:
                trim[channel] = float(attrs[f"trim_{channel}"])
                break
            except (KeyError, TypeError, ValueError):
                continue
    return trim


# --------------------------------------------------------------------------------------------
# manoeuvres


def _natural_key(name: str):
    """Sort ``sweep_lon_2`` before ``sweep_lon_10``."""
    return [(0, int(tok), "") if tok.isdigit() else (1, 0, tok)
            for tok in re.split(r"(\d+)", name)]


def list_maneuvers(tree: xr.DataTree, pattern: str = "*") -> list[str]:
    """Names of the manoeuvres under ``/maneuvers`` matching the glob ``pattern``
    (:mod:`fnmatch` rules, e.g. ``"sweep_lon_*"``), in natural sort order."""
    if "maneuvers" not in tree.children:
        return []
    names = [n for n in tree["maneuvers"].children if fnmatch.fnmatchcase(n, pattern)]
    return sorted(names, key=_natural_key)


def maneuvers(tree: xr.DataTree, pattern: str = "*") -> list[xr.Dataset]:
    """Time-history Datasets of the manoeuvres matching ``pattern`` (see
    :func:`list_maneuvers`), in the same order."""
    return [tree[f"maneuvers/{n}"].to_dataset() for n in list_maneuvers(tree, pattern)]


# --------------------------------------------------------------------------------------------
# linearisation


def pick_linearization(tree: xr.DataTree, states: Iterable[str]) -> xr.Dataset | None:
    """The truth linearisation over ``states`` a fit starts from, or None.

    Among the model Datasets in ``/linearization`` and its sub-groups whose ``A`` covers
    every state: one whose path says ``quasi`` first, then the one with the fewest extra
    states.
    """
    if "linearization" not in tree.children:
        return None
    states = list(states)
    candidates = []
    for node in tree["linearization"].subtree:
        ds = node.to_dataset(inherit=False)
        if "A" not in ds or "B" not in ds or "state" not in ds["A"].dims:
            continue
        have = [str(s) for s in ds["A"].state.values]
        if not all(s in have for s in states):
            continue
        rank = (0 if "quasi" in node.path else 1, len(have) - len(states))
        candidates.append((rank, ds))
    if not candidates:
        return None
    candidates.sort(key=lambda c: c[0])
    return candidates[0][1]


# --------------------------------------------------------------------------------------------
# the accessor


@dataclass(frozen=True)
class CampaignData:
    """Read access to one campaign DataTree; ``source`` names it in error messages.

    >>> data = CampaignData(xr.DataTree(), source="empty.nc")
    >>> data.list_maneuvers(), data.models()
    ([], {})
    """

    tree: xr.DataTree
    source: str = "the campaign"

    @classmethod
    def read(cls, path: str | os.PathLike) -> CampaignData:
        """The campaign file at ``path`` (:func:`sysid.data.netcdf.read_campaign`)."""
        return cls(read_campaign(path), source=str(path))

    def with_groups(self, groups: Mapping[str, xr.Dataset | xr.DataTree]) -> CampaignData:
        """A copy with ``groups`` replaced as :func:`sysid.data.netcdf.update_campaign`
        writes them (a Dataset keeps the group's children, a DataTree replaces them)."""
        return CampaignData(with_groups(self.tree, groups), source=self.source)

    # -- groups
    def has(self, group: str) -> bool:
        """Whether the tree has the group ``group`` (e.g. ``"models/time_domain"``)."""
        node = self.tree
        for part in group.strip("/").split("/"):
            if part not in node.children:
                return False
            node = node.children[part]
        return True

    def group(self, group: str) -> xr.Dataset | None:
        """The own Dataset of ``group`` (no inherited coordinates), or None."""
        return self.tree[group].to_dataset(inherit=False) if self.has(group) else None

    def children(self, group: str) -> dict[str, xr.Dataset]:
        """``{name: own Dataset}`` of the sub-groups of ``group`` (empty when absent)."""
        if not self.has(group):
            return {}
        return {name: node.to_dataset(inherit=False)
                for name, node in self.tree[group].children.items()}

    # -- manoeuvres and trim
    def list_maneuvers(self, pattern: str = "*") -> list[str]:
        """Names of the manoeuvres matching ``pattern`` (:func:`list_maneuvers`)."""
        return list_maneuvers(self.tree, pattern)

    def maneuvers(self, pattern: str = "*", *, required: bool = True) -> dict[str, xr.Dataset]:
        """``{name: time history}`` of the manoeuvres matching ``pattern``, natural order.

        With ``required`` (default) no match raises
        :class:`~sysid.core.errors.InputDataError` listing the manoeuvres there are.
        """
        names = self.list_maneuvers(pattern)
        if not names and required:
            raise InputDataError(f"campaign {self.source}: no manoeuvre matches {pattern!r} "
                                 f"(manoeuvres: {self.list_maneuvers() or 'none'})")
        return {n: self.tree[f"maneuvers/{n}"].to_dataset() for n in names}

    def trim(self, pattern: str | None = None) -> dict[str, float]:
        """``channel -> trim`` (analysis units) from ``trim_<channel>`` attributes.

        With ``pattern``, from the matching manoeuvres in order (the first that has a
        channel's attribute gives it); without, from ``/frequency_response``, the root, then
        the first manoeuvre. For a single record's perturbations use :func:`record_trim`.
        """
        if pattern is not None:
            return trim_from_attrs(self.maneuvers(pattern).values())
        sources = [self.tree[g].attrs for g in ("frequency_response",) if g in self.tree]
        sources.append(self.tree.attrs)
        if "maneuvers" in self.tree and self.tree["maneuvers"].children:
            sources.append(next(iter(self.tree["maneuvers"].children.values())).attrs)
        return trim_from_attrs(sources)

    @property
    def airspeed_kt(self) -> float:
        """Airspeed of the campaign's trim (``/trim`` attribute ``airspeed_kt``), kt; 0."""
        trim = self.group("trim")
        return 0.0 if trim is None else float(trim.attrs.get("airspeed_kt", 0.0))

    # -- truth and results
    def linearization(self, states: Iterable[str]) -> xr.Dataset | None:
        """The truth linearisation over ``states`` (:func:`pick_linearization`), or None."""
        return pick_linearization(self.tree, states)

    def quasi_steady(self) -> xr.Dataset | None:
        """``/linearization``, the truth's quasi-steady 6-DoF derivatives, or None."""
        return self.tree["linearization"].to_dataset() if "linearization" in self.tree else None

    def frequency_response(self) -> xr.Dataset | None:
        """``/frequency_response`` (composite responses), or None."""
        return (self.tree["frequency_response"].to_dataset()
                if "frequency_response" in self.tree else None)

    def models(self) -> dict[str, xr.Dataset]:
        """``{method: model Dataset}`` of ``/models/<method>`` (empty when none)."""
        return self.children("models")

    def model(self, method: str) -> xr.Dataset:
        """``/models/<method>``; :class:`~sysid.core.errors.InputDataError` when absent."""
        models = self.models()
        if method not in models:
            raise InputDataError(f"campaign {self.source}: no model {method!r} under /models "
                                 f"(available: {sorted(models) or 'none'})")
        return models[method]

    def results(self, group: str) -> dict[str, xr.Dataset]:
        """The per-item result groups under ``group``: ``"verification"`` (per manoeuvre)
        or ``"validation"`` (per model); empty when absent."""
        return self.children(group)
