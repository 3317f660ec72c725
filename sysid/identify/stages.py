"""Identification stages on a campaign: its data in, a fitted model out, nothing written.

The two fits of the study read what a campaign holds (:class:`sysid.data.campaign.
CampaignData`): the frequency-domain fit its composite responses ``/frequency_response``, the
time-domain fit its manoeuvres; both take the trim from the ``trim_<channel>`` attributes and
their start values from the campaign (:func:`start_values`). On data that carry the states,
both start from the leakage-free responses (docs/methods.md, "Leakage-free conditioning"): the
frequency-domain fit consumes ``/frequency_response`` (leakage-free by default) and, without a
truth linearisation, starts from its equation error; the time-domain fit starts from the
frequency-domain model, else the linearisation, else the same equation error. Each model
records which responses its start came from (attributes ``start_source`` and
``frequency_response_transient_states``). They return the fit result,
whose ``model`` Dataset (``docs/data_model.md``) the caller stores as ``/models/<method>``
(the ``sysid identify`` commands and :func:`sysid.pipeline.study.run_study` do).

Example
-------
>>> from sysid.data.campaign import CampaignData                      # doctest: +SKIP
>>> data = CampaignData.read("campaign.nc")                            # doctest: +SKIP
>>> result = fit_frequency_domain(data, structure="hover_6dof")        # doctest: +SKIP
>>> print(result.table())                                              # doctest: +SKIP
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.identify.frequency_domain import (N_POINTS, FrequencyFitResult,
                                             equation_error_start, identify_frequency_domain)
from sysid.identify.filter_error import (NOISE_STARTS, FilterErrorResult, identify_filter_error,
                                        process_noise_states)
from sysid.identify.time_domain import TimeFitResult, identify_time_domain
from sysid.models import LinearStructure, load_structure
from sysid.truth.linearize import truth_for_structure

__all__ = ["FREQUENCY_DOMAIN_STARTS", "TIME_DOMAIN_STARTS", "start_values",
           "fit_frequency_domain", "fit_time_domain", "fit_filter_error",
           "FILTER_ERROR_PROCESS_NOISE"]

#: Start-value choices of the frequency-domain fit: the campaign's ``/linearization`` when
#: it has one (``auto``), that linearisation or an error (``linearization``), the
#: frequency-domain equation error (``equation-error``), the structure's own values.
FREQUENCY_DOMAIN_STARTS = ("auto", "linearization", "equation-error", "structure")
#: Start-value choices of the time-domain fit: ``auto`` takes ``/models/frequency_domain``,
#: else ``/linearization``, else the frequency-domain equation error of
#: ``/frequency_response``, else the structure's values; the others insist on one of them.
TIME_DOMAIN_STARTS = ("auto", "frequency_domain", "linearization", "equation-error",
                      "structure")


def start_values(data: CampaignData, structure: LinearStructure, kind: str, *,
                 fit: str, progress: Progress | None = None, label: str | None = None
                 ) -> xr.Dataset | np.ndarray | None:
    """Start values of a fit chosen by ``kind`` from what the campaign holds.

    ``fit`` is ``"frequency_domain"`` (choices :data:`FREQUENCY_DOMAIN_STARTS`) or
    ``"time_domain"`` (:data:`TIME_DOMAIN_STARTS`). Returns a model Dataset (a stored model
    or the truth linearisation over the structure's states), the structure's parameter
    vector, or None for the fit's own default (equation error in the frequency domain, the
    structure's values in the time domain). A start that ``kind`` insists on and the
    campaign lacks raises :class:`~sysid.core.errors.InputDataError`. ``label`` names the
    command in the progress lines (default by ``fit``).
    """
    progress = progress or Progress(quiet=True)
    choices = FREQUENCY_DOMAIN_STARTS if fit == "frequency_domain" else TIME_DOMAIN_STARTS
    if fit not in ("frequency_domain", "time_domain") or kind not in choices:
        raise InputDataError(f"start values {kind!r} for the {fit} fit: expected one of "
                             f"{choices}")
    label = label or ("identify" if fit == "frequency_domain" else "identify-time")
    if fit == "time_domain" and kind in ("auto", "frequency_domain"):
        if data.has("models/frequency_domain"):
            progress.message(f"[sysid] {label}: start values from /models/frequency_domain")
            return data.tree["models/frequency_domain"].to_dataset()
        if kind == "frequency_domain":
            raise InputDataError(f"campaign {data.source} has no /models/frequency_domain; "
                                 f"run 'sysid identify' first or choose another --start")
    if kind in ("auto", "linearization"):
        lin = data.linearization(structure.states)
        if lin is None and "linearization_full" in data.tree.children:
            lin = data.tree["linearization_full"].to_dataset()  # e.g. for flapping states
        if lin is not None:
            progress.message(f"[sysid] {label}: start values from /linearization")
            have = {str(s) for s in lin["A"].state.values}
            outs = {str(o) for o in lin["C"].output.values}
            if have != set(structure.states) and outs >= set(structure.outputs):
                # a higher-order structure (e.g. flapping states): the truth reduced to its
                # states, outputs and normalisation (truth_for_structure)
                return truth_for_structure(lin, structure)
            return lin
        if kind == "linearization":
            raise InputDataError(f"campaign {data.source} has no /linearization model over "
                                 f"the states {list(structure.states)}")
    if fit == "frequency_domain" and kind == "structure":
        return structure.theta0
    if fit == "time_domain" and kind in ("auto", "equation-error"):
        fr = data.frequency_response()
        if fr is not None:
            states = list(fr.attrs.get("transient_states", []))
            progress.message(f"[sysid] {label}: start values from the equation error of "
                             f"/frequency_response (leakage conditioning: "
                             f"{', '.join(states) if states else 'off'})")
            return equation_error_start(fr, structure)
        if kind == "equation-error":
            raise InputDataError(f"campaign {data.source} has no /frequency_response for "
                                 f"equation-error start values; run 'sysid frequency-response' "
                                 f"first or choose another --start")
    return None


def _start_source(data: CampaignData, start, fit: str) -> str:
    """Where a fit's start values came from, for the model's ``start_source`` attribute."""
    if isinstance(start, xr.Dataset):
        method = start.attrs.get("method")
        return f"/models/{method}" if method in ("frequency_domain", "time_domain") \
            else "/linearization"
    if start is None:
        return ("equation error of /frequency_response" if fit == "frequency_domain"
                else "structure")
    return ("equation error of /frequency_response" if fit == "time_domain"
            and data.frequency_response() is not None else "structure")


def _record_responses(model: xr.Dataset, data: CampaignData) -> None:
    """Record in ``model`` which leakage conditioning the campaign's responses had."""
    fr = data.frequency_response()
    if fr is not None:
        model.attrs["frequency_response_transient_states"] = ",".join(
            str(c) for c in fr.attrs.get("transient_states", []))


def fit_frequency_domain(data: CampaignData, *, structure: str = "hover_6dof",
                         start: str = "auto", pairs=None,
                         coherence_min: float | None = None, n_points: int = N_POINTS,
                         fallback_coherence_min: float | None = None,
                         frequency_range: tuple[float, float] | None = None,
                         reduce: bool = True, seed: int = 0,
                         progress: Progress | None = None) -> FrequencyFitResult:
    """Frequency-domain identification of a campaign's composite responses.

    ``structure`` is a built-in name or a TOML file, loaded about the campaign's trim
    (:meth:`CampaignData.trim`); ``start`` one of :data:`FREQUENCY_DOMAIN_STARTS`; the other
    options are those of :func:`sysid.identify.frequency_domain.identify_frequency_domain`.
    The result's ``model`` records the campaign in attribute ``campaign_file``.
    """
    fr = data.frequency_response()
    if fr is None:
        raise InputDataError(f"campaign {data.source} has no /frequency_response group; "
                             f"compute the composite frequency responses first")
    loaded = load_structure(structure, trim=data.trim())
    begin = start_values(data, loaded, start, fit="frequency_domain", progress=progress)
    result = identify_frequency_domain(
        fr, loaded, pairs=pairs, start=begin,
        frequency_range=frequency_range, fallback_coherence_min=fallback_coherence_min,
        coherence_min=coherence_min, n_points=n_points, reduce=reduce, seed=seed,
        progress=progress)
    result.model.attrs["campaign_file"] = data.source
    result.model.attrs["start_source"] = _start_source(data, begin, "frequency_domain")
    _record_responses(result.model, data)
    return result


#: Process noise of :func:`fit_filter_error` by default: on the states the structure declares
#: (TOML ``process_noise``: where its disturbances enter), else one independent entry per
#: equation of a measured state. Measured states: on the truth helicopter's hover 3211s
#: every dominant derivative's scatter came within 0.78-1.89 of its corrected bound over 20
#: seeds; on flight data without u, v, w noise on the unmeasured speeds absorbed the
#: collective response (the reduction removed Z_col, 2311_col J_rms 2.41; measured states
#: only: 0.40-0.69; docs/notes/2026-11-27-filter-error-default.md). ``hover_hybrid``
#: declares the force, yaw and flapping rows: the gusts reach roll and pitch through the
#: flapping (docs/notes/2026-11-27-hybrid-process-noise.md).
FILTER_ERROR_PROCESS_NOISE = "auto"


def fit_filter_error(data: CampaignData, *, maneuvers: str = "*",
                     structure: str = "hover_6dof", start: str = "auto",
                     outputs: Sequence[str] | None = None,
                     process_noise=FILTER_ERROR_PROCESS_NOISE, reduce: bool = True,
                     noise_starts: Sequence[tuple[float, float]] = NOISE_STARTS,
                     progress: Progress | None = None) -> FilterErrorResult:
    """Filter-error identification (process and measurement noise) on the manoeuvres
    matching ``maneuvers``; structure, trim and ``start`` (:data:`TIME_DOMAIN_STARTS`) as
    for :func:`fit_time_domain`, ``process_noise``, ``reduce`` (the output-error fit's
    model reduction) and ``noise_starts`` as for
    :func:`sysid.identify.filter_error.identify_filter_error`. The
    result's ``model`` records the campaign in attribute ``campaign_file``."""
    records = list(data.maneuvers(maneuvers).values())
    loaded = load_structure(structure, trim=data.trim(maneuvers))
    begin = start_values(data, loaded, start, fit="time_domain", progress=progress,
                         label="identify-filter-error")
    process_noise = process_noise_states(process_noise, loaded)
    if progress is not None:
        progress.message(f"[sysid] identify-filter-error: {len(records)} record(s), "
                         f"{len(loaded.free_index)} parameters, process noise "
                         f"{process_noise if isinstance(process_noise, str) else list(process_noise)}")
    result = identify_filter_error(records, loaded, start=begin, outputs=outputs,
                                   process_noise=process_noise, reduce=reduce,
                                   noise_starts=noise_starts, progress=progress)
    result.model.attrs["campaign_file"] = data.source
    result.model.attrs["start_source"] = _start_source(data, begin, "time_domain")
    _record_responses(result.model, data)
    return result


def fit_time_domain(data: CampaignData, *, maneuvers: str = "*",
                    structure: str = "hover_6dof", start: str = "auto",
                    outputs: Sequence[str] | None = None, biases: bool = True,
                    initial_state: bool = True, reduce: bool = True,
                    progress: Progress | None = None) -> TimeFitResult:
    """Time-domain output-error identification on the manoeuvres matching ``maneuvers``.

    ``structure`` is loaded about the selected manoeuvres' trim; ``start`` is one of
    :data:`TIME_DOMAIN_STARTS`; the other options are those of
    :func:`sysid.identify.time_domain.identify_time_domain`. The result's ``model`` records
    the campaign in attribute ``campaign_file``.
    """
    records = list(data.maneuvers(maneuvers).values())
    loaded = load_structure(structure, trim=data.trim(maneuvers))
    begin = start_values(data, loaded, start, fit="time_domain", progress=progress)
    result = identify_time_domain(
        records, loaded, start=begin,
        outputs=outputs, biases=biases, initial_state=initial_state, reduce=reduce,
        progress=progress)
    result.model.attrs["campaign_file"] = data.source
    result.model.attrs["start_source"] = _start_source(data, begin, "time_domain")
    _record_responses(result.model, data)
    return result
