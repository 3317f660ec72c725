"""Small readers of model Datasets: parameter values by name, the non-zero delays.

A model Dataset (``docs/data_model.md``) has a ``parameter`` dimension with a ``value``
variable (analysis units) and a ``delay`` variable ``(state_dot, input)`` in s.
"""

from __future__ import annotations

from typing import Sequence

import numpy as np
import xarray as xr

__all__ = ["parameter_values", "delays_summary"]


def parameter_values(model: xr.Dataset | None, names: Sequence[str]) -> np.ndarray:
    """Values of the parameters ``names`` in a model (or truth) Dataset with a ``parameter``
    dimension and a ``value`` variable, in that order; NaN for a name the model lacks (or
    for every name when ``model`` is None)."""
    out = np.full(len(names), np.nan)
    if model is None:
        return out
    index = {str(p): k for k, p in enumerate(model.parameter.values)}
    values = model["value"].values
    for j, name in enumerate(names):
        if name in index:
            out[j] = float(values[index[name]])
    return out


def delays_summary(model: xr.Dataset) -> dict[str, float]:
    """Non-zero delays of a model Dataset as ``"state_dot/input" -> seconds``."""
    tau = model["delay"]
    out = {}
    for r in tau.state_dot.values:
        for c in tau.input.values:
            v = float(tau.sel(state_dot=r, input=c))
            if v:
                out[f"{r}/{c}"] = v
    return out
