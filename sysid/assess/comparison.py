"""The domain comparison: identified derivative sets beside the truth linearisation.

The paper's Tables 2-3 list, per derivative, the frequency-domain and the time-domain
estimates with their normalised Cramer-Rao bounds. :func:`derivative_table` builds that table
for any set of model Datasets (``docs/data_model.md``) plus the truth model's quasi-steady
linearisation, and :func:`sign_agreement` checks the paper's conclusion 8 (consistent signs
of the dominant derivatives). :func:`compare_models` builds a campaign's ``/comparison``
group from its ``/models`` and ``/linearization``.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.util import atomic_path
from sysid.data.campaign import CampaignData
from sysid.models import parameter_values

#: The derivatives that dominate the hover dynamics (damping and on-axis control power).
DOMINANT = ("Z_w", "M_q", "L_p", "N_r", "M_lon", "L_lat", "Z_col", "N_ped")


def derivative_table(models: Mapping[str, xr.Dataset], truth: xr.Dataset | None = None
                     ) -> xr.Dataset:
    """Value and CR % of every parameter free in any model, per method, plus the truth.

    Returns a Dataset over ``parameter`` and ``model`` (the method name) with ``value``, ``cramer_rao_percent``
    and ``free`` (False where a model fixed or dropped the parameter: its value is then
    NaN), and ``truth`` (parameter) from the linearisation (NaN for delays, which the
    quasi-steady truth does not have).
    """
    names: list[str] = []
    for model in models.values():
        for name, free in zip(model.parameter.values, model["free"].values):
            if bool(free) and str(name) not in names:
                names.append(str(name))
    methods = list(models)
    value = np.full((len(names), len(methods)), np.nan)
    cr = np.full_like(value, np.nan)
    free = np.zeros_like(value, dtype=bool)
    for j, model in enumerate(models.values()):
        present = {str(p): k for k, p in enumerate(model.parameter.values)}
        for i, name in enumerate(names):
            k = present.get(name)
            if k is None or not bool(model["free"].values[k]):
                continue
            free[i, j] = True
            value[i, j] = float(model["value"].values[k])
            cr[i, j] = float(model["cramer_rao_percent"].values[k])
    truth_values = parameter_values(truth, names)
    coords = {"parameter": names, "model": methods}
    return xr.Dataset(
        {
            "value": (("parameter", "model"), value),
            "cramer_rao_percent": (("parameter", "model"), cr, {"units": "%"}),
            "free": (("parameter", "model"), free),
            "truth": (("parameter",), truth_values,
                      {"long_name": "truth model's quasi-steady linearisation"}),
        },
        coords=coords,
        attrs={"long_name": "identified derivatives per method (paper Tables 2-3)"},
    )


def compare_models(data: CampaignData) -> xr.Dataset:
    """The ``/comparison`` Dataset of a campaign: :func:`derivative_table` of every
    ``/models/<method>`` beside the truth linearisation ``/linearization`` (when present)."""
    models = data.models()
    if not models:
        raise InputDataError(f"{data.source} has no identified models (/models/<method>); "
                             "run 'sysid identify' and/or 'sysid identify-time' first")
    return derivative_table(models, data.quasi_steady())


def write_table_csv(table: xr.Dataset, path: str | Path) -> Path:
    """Write a :func:`derivative_table` as CSV (one row per parameter and model), atomically."""
    path = Path(path)
    with atomic_path(path) as tmp:
        table.to_dataframe().reset_index().to_csv(tmp, index=False)
    return path


def relative_error(table: xr.Dataset) -> xr.DataArray:
    """``(value - truth) / |truth|`` per parameter and model."""
    return (table["value"] - table["truth"]) / abs(table["truth"])


def sign_agreement(table: xr.Dataset, parameters=DOMINANT) -> xr.DataArray:
    """True per parameter where every method that estimated it has the same sign."""
    present = [p for p in parameters if p in table.parameter.values]
    signs = np.sign(table["value"].sel(parameter=present))
    agree = (signs.max("model", skipna=True) == signs.min("model", skipna=True))
    return agree.assign_attrs(long_name="all methods agree on the sign")


def format_sign_agreement(table: xr.Dataset) -> str:
    """One line: the dominant derivatives whose sign differs between methods, if any."""
    agree = sign_agreement(table)
    differing = [str(p) for p, ok in zip(agree.parameter.values, agree.values) if not ok]
    return ("dominant derivatives with the same sign in every method: "
            + ("all" if not differing else f"all but {', '.join(differing)}"))


def format_table(table: xr.Dataset) -> str:
    """A text table like the paper's Tables 2-3 (value and CR % per method, truth)."""
    methods = [str(m) for m in table.model.values]
    head = f"{'parameter':<11}" + "".join(f"{m:>28}" for m in methods) + f"{'truth':>12}"
    sub = f"{'':<11}" + "".join(f"{'value':>16}{'CR %':>12}" for _ in methods)
    lines = [head, sub]
    for name in table.parameter.values:
        row = f"{str(name):<11}"
        for m in methods:
            cell = table.sel(parameter=name, model=m)
            if bool(cell["free"]):
                row += f"{float(cell['value']):>16.5g}{float(cell['cramer_rao_percent']):>12.1f}"
            else:
                row += f"{'dropped':>16}{'':>12}"
        truth = float(table["truth"].sel(parameter=name))
        row += f"{truth:>12.5g}" if np.isfinite(truth) else f"{'-':>12}"
        lines.append(row)
    return "\n".join(lines)
