"""The coherence guideline applied to composite frequency responses: where each pair is usable.

:func:`format_coherent_ranges` lists, per input/output pair, the frequency range where the
(partial) coherence reaches :data:`sysid.core.guidelines.COHERENCE_MIN` and the pair's mean
coherence (printed by ``sysid frequency-response`` and in the study's log).
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from sysid.core.guidelines import COHERENCE_MIN

__all__ = ["format_coherent_ranges"]


def format_coherent_ranges(ds: xr.Dataset, *, coherence_min: float = COHERENCE_MIN) -> str:
    """One line per pair: coherent range (coherence >= ``coherence_min``) and mean coherence."""
    name = "partial_coherence" if ds.attrs.get("conditioned") else "coherence"
    w = ds["frequency"].values
    lines = [f"{'pair':>16}  {'coherent range (rad/s)':>24}  {'mean ' + name:>24}"]
    for o in ds["output"].values:
        for i in ds["input"].values:
            g2 = ds[name].sel(output=o, input=i).values
            ok = np.nan_to_num(g2) >= coherence_min
            rng = f"{w[ok].min():8.3g} .. {w[ok].max():<8.3g}" if ok.any() else "none"
            mean = np.nanmean(g2) if np.isfinite(g2).any() else np.nan  # no empty-slice warning
            lines.append(f"{f'{o}/{i}':>16}  {rng:>24}  {mean:24.2f}")
    return "\n".join(lines)
