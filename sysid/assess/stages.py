"""Verification stage on a campaign: the ``/verification/<maneuver>`` datasets.

:func:`verify_models` holds each identified model of a campaign fixed and runs it on
manoeuvres it was (normally) not fitted to (:func:`sysid.assess.verification.verify`,
estimating only output biases and input reference shifts), one Dataset per manoeuvre with a
``source`` entry per model, merged with the sources the campaign already holds for that
manoeuvre (:func:`sysid.assess.verification.merge_verifications`). Nothing is written: the
caller stores the result (``sysid verify``, :func:`sysid.pipeline.study.run_study`).

A simulation campaign (one with the truth FMU's linearisation) also verifies the truth's own
linear model of each model's structure (:func:`sysid.assess.comparison.truth_for_model`) on
the same manoeuvres, source :data:`TRUTH_SOURCE`: the J_rms a perfect linear model of that
structure reaches on data with this turbulence and noise, the floor against which a model's
J_rms says how much of it is identification error.
"""

from __future__ import annotations

from collections.abc import Sequence

import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.assess.comparison import truth_for_model
from sysid.assess.verification import ESTIMATES, merge_verifications, verify

__all__ = ["TRUTH_SOURCE", "verify_models", "truth_references"]

#: Verification source of the truth linearisation (reduced to the models' structure; with
#: models of several structures one per structure, ``linearization_<structure>``).
TRUTH_SOURCE = "linearization"


def truth_references(data: CampaignData, models: dict[str, xr.Dataset]
                     ) -> dict[str, tuple[xr.Dataset, list[str]]]:
    """``{source: (truth model, outputs)}``: the truth linearisation each model is judged
    against (:func:`~sysid.assess.comparison.truth_for_model`), one per structure, with the
    model's outputs (the truth is scored on those only, so the two J_rms compare); empty
    without a linearisation (flight data) or where it lacks a model output."""
    by_structure: dict[str, tuple[xr.Dataset, list[str]]] = {}
    for method, model in models.items():
        structure = str(model.attrs.get("structure", "")) or method
        if structure in by_structure or "C" not in model:
            continue
        truth = truth_for_model(data.tree, model)
        outputs = [str(o) for o in model["C"].output.values]
        if truth is not None and "C" in truth and set(outputs) <= set(
                map(str, truth["C"].output.values)):
            by_structure[structure] = (truth, outputs)
    if len(by_structure) == 1:
        return {TRUTH_SOURCE: next(iter(by_structure.values()))}
    return {f"{TRUTH_SOURCE}_{s}": ref for s, ref in by_structure.items()}


def verify_models(data: CampaignData, *, models: Sequence[str] | None = None,
                  maneuvers: str = "*", estimate: Sequence[str] = ESTIMATES,
                  truth: bool = True, progress: Progress | None = None
                  ) -> dict[str, xr.Dataset]:
    """``{maneuver: /verification/<maneuver> Dataset}`` of the models named ``models``
    (default: every ``/models/<method>``) on the manoeuvres matching ``maneuvers``; with
    ``truth``, also of :func:`truth_references` (module docstring).

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
    references = truth_references(data, chosen) if truth else {}
    out = {}
    for name, record in records.items():
        record.attrs.setdefault("maneuver", name)
        parts = [stored[name]] if name in stored else []
        for method, model in chosen.items():
            if name in str(model.attrs.get("records", "")).split(","):
                progress.message(f"[sysid] verify: note: {name} was used to fit {method}; "
                                 f"this is not an independent check")
            parts.append(verify(model, record, estimate=tuple(estimate), source=method))
        for source, (model, outputs) in references.items():
            measured = [o for o in outputs if o in record.data_vars]
            if measured:
                parts.append(verify(model, record, estimate=tuple(estimate),
                                    outputs=measured, source=source))
        out[name] = merge_verifications(parts)
    return out
