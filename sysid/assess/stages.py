"""Verification stage on a campaign: the ``/verification/<maneuver>`` datasets.

:func:`verify_models` holds each identified model of a campaign fixed and runs it on
manoeuvres it was (normally) not fitted to (:func:`sysid.assess.verification.verify`,
estimating only output biases and input reference shifts), one Dataset per manoeuvre with a
``source`` entry per model, merged with the sources the campaign already holds for that
manoeuvre (:func:`sysid.assess.verification.merge_verifications`). Nothing is written: the
caller stores the result (``sysid verify``, :func:`sysid.pipeline.study.run_study`).
"""

from __future__ import annotations

from collections.abc import Sequence

import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.assess.verification import ESTIMATES, merge_verifications, verify

__all__ = ["verify_models"]


def verify_models(data: CampaignData, *, models: Sequence[str] | None = None,
                  maneuvers: str = "*", estimate: Sequence[str] = ESTIMATES,
                  progress: Progress | None = None) -> dict[str, xr.Dataset]:
    """``{maneuver: /verification/<maneuver> Dataset}`` of the models named ``models``
    (default: every ``/models/<method>``) on the manoeuvres matching ``maneuvers``.

    ``estimate`` is a subset of :data:`sysid.assess.verification.ESTIMATES`. A manoeuvre
    that a model was fitted to (its ``records`` attribute) is verified anyway, with a note
    on ``progress``: that check is not independent.
    """
    progress = progress or Progress(quiet=True)
    available = sorted(data.models())
    wanted = list(models) if models else available
    missing = [m for m in wanted if m not in available]
    if missing or not wanted:
        raise InputDataError(f"campaign {data.source}: no model(s) {missing or wanted} under "
                             f"/models (available: {available or 'none'})")
    bad = set(estimate) - set(ESTIMATES)
    if bad:
        raise InputDataError(f"verification: unknown estimate(s) {sorted(bad)}; choose from "
                             f"{ESTIMATES}")
    records = data.maneuvers(maneuvers)
    stored = data.results("verification")
    chosen = {m: data.model(m) for m in wanted}
    out = {}
    for name, record in records.items():
        record.attrs.setdefault("maneuver", name)
        parts = [stored[name]] if name in stored else []
        for method, model in chosen.items():
            if name in str(model.attrs.get("records", "")).split(","):
                progress.message(f"[sysid] verify: note: {name} was used to fit {method}; "
                                 f"this is not an independent check")
            parts.append(verify(model, record, estimate=tuple(estimate), source=method))
        out[name] = merge_verifications(parts)
    return out
