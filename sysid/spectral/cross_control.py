"""Cross-control coherence of a flight-test campaign's sweeps (paper Eq. 8).

Correlated controls make a MIMO identification ill-conditioned; the campaign summary shows,
per excited axis, how coherent the other controls were with the swept one. It is computed
here, on the spectral layer, and handed to :func:`sysid.flight_test.campaign.run_campaign`
as a summary hook (``summaries=[campaign_summary]``), which stores it at
``/cross_control_coherence``.
"""

from __future__ import annotations

import xarray as xr

from sysid.core.guidelines import CROSS_COHERENCE_MAX
from sysid.core.units import CONTROLS
from sysid.data.campaign import list_maneuvers
from sysid.spectral.response import frequency_response

__all__ = ["CROSS_CONTROL_BAND", "GROUP", "cross_control_summary", "format_cross_control",
           "campaign_summary"]

#: Band over which the campaign's cross-control coherence is summarised, rad/s.
CROSS_CONTROL_BAND = (0.5, 10.0)
#: Campaign group the summary is stored under.
GROUP = "cross_control_coherence"


def cross_control_summary(tree: xr.DataTree, pattern: str = "sweep_*") -> xr.Dataset | None:
    """Cross-control coherence (paper Eq. 8) of the sweeps, per excited axis.

    Returns ``cross_coherence`` (axis, input, input_j, frequency) and its mean over
    :data:`CROSS_CONTROL_BAND` as ``mean_cross_coherence`` (axis, input, input_j); the
    guideline for well-conditioned MIMO identification is a mean below
    :data:`sysid.core.guidelines.CROSS_COHERENCE_MAX`. None without sweeps.
    """
    names = list_maneuvers(tree, pattern)
    if not names:
        return None
    per_axis = {}
    for axis in CONTROLS:
        records = [tree[f"maneuvers/{n}"].to_dataset() for n in names
                   if tree[f"maneuvers/{n}"].attrs.get("axis") == axis]
        if records:
            fr = frequency_response(records, CONTROLS, ["q"], n_windows=3,
                                    transient_states=())  # input spectra only
            per_axis[axis] = fr["cross_coherence"]
    if not per_axis:
        return None
    coherence = xr.concat(list(per_axis.values()), dim=xr.DataArray(list(per_axis), dims="axis"))
    band = coherence.frequency.where((coherence.frequency >= CROSS_CONTROL_BAND[0])
                                     & (coherence.frequency <= CROSS_CONTROL_BAND[1]))
    mean = coherence.where(band.notnull()).mean("frequency")
    return xr.Dataset(
        {"cross_coherence": coherence.assign_attrs(long_name="cross-control coherence (Eq. 8)"),
         "mean_cross_coherence": mean.assign_attrs(
             long_name=f"mean cross-control coherence over {CROSS_CONTROL_BAND} rad/s")},
        attrs={"band_rad_s": list(CROSS_CONTROL_BAND), "guideline": CROSS_COHERENCE_MAX})


def format_cross_control(summary: xr.Dataset) -> str:
    """One line per excited axis: mean cross-control coherence with each other control."""
    lines = [f"cross-control coherence, mean over {CROSS_CONTROL_BAND[0]:g}-"
             f"{CROSS_CONTROL_BAND[1]:g} rad/s (guideline < {CROSS_COHERENCE_MAX:g}):"]
    mean = summary["mean_cross_coherence"]
    for axis in mean.axis.values:
        cells = [f"{other}: {float(mean.sel(axis=axis, input=axis, input_j=other)):.2f}"
                 for other in CONTROLS if other != axis]
        lines.append(f"  {axis} sweeps  " + "  ".join(cells))
    return "\n".join(lines)


def campaign_summary(tree: xr.DataTree) -> tuple[str, xr.Dataset, str] | None:
    """The summary hook of :func:`~sysid.flight_test.campaign.run_campaign`:
    ``(group, dataset, message)``, or None when the campaign has no sweeps."""
    summary = cross_control_summary(tree)
    if summary is None:
        return None
    return GROUP, summary, format_cross_control(summary)
