"""Reading a campaign DataTree for the report: groups, models, manoeuvres, costs, reductions.

Every function takes the campaign tree (``docs/data_model.md``) and returns plain Datasets,
dicts or lists, ``None``/empty when the group is absent, so a section can say "not available".
Values keep the tree's units (analysis units; costs dimensionless).
"""

from __future__ import annotations

import json
import re
from collections.abc import Mapping

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.units import CONTROLS, STATES_6DOF

__all__ = ["group", "dataset", "as_complex", "children", "models", "linearization", "maneuvers",
           "natural", "pair_costs", "j_ave", "reduction", "dropped", "coherence", "trim_values"]


def group(tree: xr.DataTree, path: str) -> xr.DataTree | None:
    try:
        return tree[path]
    except KeyError:
        return None


def dataset(tree: xr.DataTree, path: str) -> xr.Dataset | None:
    """The group's own Dataset (no inherited coordinates), or None when absent or empty."""
    node = group(tree, path)
    if node is None:
        return None
    ds = node.to_dataset(inherit=False)
    return ds if (ds.data_vars or ds.attrs) else None


def as_complex(da: xr.DataArray) -> xr.DataArray:
    """A complex variable, rebuilt from a trailing ``complex`` (real, imag) dim if stored so."""
    if "complex" in da.dims:
        return da.sel(complex="real", drop=True) + 1j * da.sel(complex="imag", drop=True)
    return da


def children(tree: xr.DataTree, path: str) -> dict[str, xr.DataTree]:
    node = group(tree, path)
    return dict(node.children) if node is not None else {}


def models(tree: xr.DataTree) -> dict[str, xr.Dataset]:
    """``/models/<method>`` Datasets that hold a state-space model, by method."""
    out = {}
    for name, node in children(tree, "models").items():
        ds = node.to_dataset(inherit=False)
        if "A" in ds and "B" in ds:
            out[name] = ds
    return out


def linearization(tree: xr.DataTree) -> xr.Dataset | None:
    ds = dataset(tree, "linearization")
    return ds if ds is not None and "A" in ds and "B" in ds else None


def maneuvers(tree: xr.DataTree) -> dict[str, xr.Dataset]:
    return {name: node.to_dataset(inherit=False)
            for name, node in sorted(children(tree, "maneuvers").items(),
                                     key=lambda kv: natural(kv[0]))}


def natural(name: str):
    """Sort key: the paper's control order (lon, lat, col, ped) first, then natural order."""
    rank = min((CONTROLS.index(p) for p in re.split(r"[_\W]", name) if p in CONTROLS),
               default=len(CONTROLS))
    return [rank] + [int(t) if t.isdigit() else t for t in re.split(r"(\d+)", name)]


def pair_costs(model: xr.Dataset) -> dict[str, float]:
    """Cost per pair (``"q/lon" -> J``): ``pair_cost`` (pair) or ``cost`` (output, input)."""
    if "pair_cost" in model:
        da = model["pair_cost"]
        dim = da.dims[0]
        return {str(p): float(v) for p, v in zip(da[dim].values, da.values) if np.isfinite(v)}
    if "cost" in model and set(model["cost"].dims) == {"output", "input"}:
        da = model["cost"].transpose("output", "input")
        return {f"{o}/{i}": float(da.sel(output=o, input=i))
                for o in da.output.values for i in da.input.values
                if np.isfinite(float(da.sel(output=o, input=i)))}
    return {}


def j_ave(model: xr.Dataset) -> float | None:
    if "J_ave" in model.attrs:
        return float(model.attrs["J_ave"])
    costs = pair_costs(model)
    return float(np.mean(list(costs.values()))) if costs else None


def reduction(tree: xr.DataTree, method: str, model: xr.Dataset) -> list[dict]:
    """Reduction steps of a model: the ``reduction`` sub-group (dim ``step``) or the model's
    ``reduction_steps`` JSON attribute; one dict per step."""
    ds = dataset(tree, f"models/{method}/reduction")
    if ds is not None and "step" in ds.dims:
        names = [v for v in ds.data_vars if ds[v].dims == ("step",)]
        return [{v: _py(ds[v].values[k]) for v in names} for k in range(ds.sizes["step"])]
    raw = model.attrs.get("reduction_steps")
    if isinstance(raw, str) and raw.strip():
        try:
            steps = json.loads(raw)
        except json.JSONDecodeError:
            raise InputDataError(f"model /models/{method}: attribute 'reduction_steps' is not "
                                 f"valid JSON") from None
        return [dict(s) for s in steps if isinstance(s, Mapping)]
    return []


def _py(value):
    if isinstance(value, np.generic):
        return value.item()
    return value


def dropped(tree: xr.DataTree, method: str, model: xr.Dataset) -> set[str]:
    """Parameters removed by model reduction."""
    out = {s.strip() for s in str(model.attrs.get("removed_parameters", "")).split(",")
           if s.strip()}
    for step in reduction(tree, method, model):
        name = step.get("dropped", step.get("parameter"))
        if name is not None and bool(step.get("accepted", True)):
            out.add(str(name))
    return out


def coherence(fr: xr.Dataset) -> xr.DataArray:
    """The coherence that goes with the conditioned ``H``: partial, else ordinary."""
    return fr["partial_coherence"] if "partial_coherence" in fr else fr["coherence"]


def trim_values(tree: xr.DataTree) -> tuple[dict[str, float], dict, str] | None:
    ds = dataset(tree, "trim")
    if ds is not None:
        values = {k: float(ds[k]) for k in (*STATES_6DOF, *CONTROLS) if k in ds}
        return values, dict(ds.attrs), "/trim"
    for name, m in maneuvers(tree).items():
        values = {k: float(m.attrs[f"trim_{k}"]) for k in (*STATES_6DOF, *CONTROLS)
                  if f"trim_{k}" in m.attrs}
        if values:
            return values, dict(m.attrs), f"trim_* attributes of /maneuvers/{name}"
    return None
