"""Time-domain fit metrics of a simulated response against measured data: J_rms and TIC.

Channels are in analysis units (ft/s, deg/s, deg) on a common ``time`` dimension:

    J_rms = sqrt( 1/(n_t n_o) sum_t sum_j W_j (z_j - y_j)^2 )
    TIC   = rms(z - y) / (rms(z) + rms(y))

with measured ``z`` and simulated ``y``. Guidelines: ``J_rms <= 1-2`` (unit weights) and
``TIC <= 0.25-0.3`` (:data:`J_RMS_GUIDELINE`, :data:`TIC_GUIDELINE`).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 14 (time-domain verification, J_rms and TIC guidelines).
* Theil, H., *Applied Economic Forecasting*, North-Holland, 1966 (inequality coefficient).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.guidelines import J_RMS_MAX as J_RMS_GUIDELINE
from sysid.core.guidelines import TIC_MAX as TIC_GUIDELINE

__all__ = ["j_rms", "theil_inequality", "J_RMS_GUIDELINE", "TIC_GUIDELINE"]


def theil_inequality(measured: xr.DataArray, simulated: xr.DataArray, dim: str = "time"):
    """Theil's inequality coefficient ``rms(z - y) / (rms(z) + rms(y))`` along ``dim``.

    0 is a perfect match, 1 the worst; <= 0.25-0.3 is the customary guideline.
    """
    rms = lambda x: np.sqrt((x**2).mean(dim))  # noqa: E731
    return rms(measured - simulated) / (rms(measured) + rms(simulated))


def j_rms(measured: xr.Dataset, simulated: xr.Dataset, weights: dict | None = None,
          dim: str = "time") -> float:
    """``J_rms = sqrt( 1/(n_t n_o) sum_t sum_j W_j (z_j - y_j)^2 )`` over common channels.

    Channels are in analysis units; the default weights are 1 per ft/s, deg/s and deg, the
    customary choice that makes ``J_rms <= 1-2`` the acceptance guideline.
    """
    names = [n for n in simulated.data_vars if n in measured.data_vars]
    if not names:
        raise InputDataError("j_rms: measured and simulated data share no channel")
    weights = weights or {}
    total = sum(float(weights.get(n, 1.0) * ((measured[n] - simulated[n]) ** 2).sum(dim))
                for n in names)
    n_t = measured.sizes[dim]
    return float(np.sqrt(total / (n_t * len(names))))
