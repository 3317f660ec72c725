"""The study for exchange with other tools: the truth helicopter and the identified models side
by side in one SSP 1.0 package, fed by the same input.

:func:`export_study_ssp` writes ``study.ssp`` from a campaign: a signal FMU that plays back a
2311 multistep (the controls at the truth trim plus the perturbations of
:func:`sysid.assess.exported.verification_inputs`, %), the truth helicopter FMU built with
its trim as start values (:func:`trimmed_truth_fmu`: importers such as libcosim set only
inputs and parameters from an SSD, not the start values of states), and every identified
model of the campaign exported as an FMU (FMI 2.0: the version libcosim
and most SSP tools run), each fed the signal's ``lon lat col ped``. Stepped at the sample
interval, the package reproduces sysid's own co-simulation runs of the same FMUs.
"""

from __future__ import annotations

import csv
import io
import os
import shutil
import tempfile
from pathlib import Path

import xarray as xr

from sysid.core.errors import FMUError, InputDataError
from sysid.core.paths import fmu_sources_dir
from sysid.core.units import CONTROLS
from sysid.core.util import Progress
from sysid.data.campaign import CampaignData
from sysid.fmi.build import build_model_fmu
from sysid.fmi.export import export_fmu
from sysid.fmi.signal import export_signal_fmu
from sysid.fmi.ssp import SspComponent, write_ssp
from sysid.truth import build_fmu
from sysid.truth import trim as trim_truth
from sysid.assess.exported import verification_inputs

__all__ = ["export_study_ssp", "study_signal", "trimmed_truth_fmu", "SIGNAL_COMPONENT",
           "TRUTH_COMPONENT"]

#: Component names of the signal and the truth FMU in the package.
SIGNAL_COMPONENT = "input_2311"
TRUTH_COMPONENT = "truth"


def study_signal(trim, *, axis: str = "lon", dt: float = 0.01) -> xr.Dataset:
    """Absolute controls (%) of the 2311 on ``axis`` about ``trim`` (a truth TrimResult):
    ``lon lat col ped`` on a uniform ``time`` from 0 (s)."""
    key = f"2311_{axis}"
    inputs = verification_inputs(dt)
    if key not in inputs:
        raise InputDataError(f"no 2311 on axis {axis!r}; available: "
                             f"{sorted(k[5:] for k in inputs if k.startswith('2311_'))}")
    pert = inputs[key]
    t = pert["time"].values - pert["time"].values[0]
    controls = trim.channel_values()
    return xr.Dataset(
        {c: ("time", (pert[c].values if c in pert else 0.0 * t) + controls[c],
             {"units": "%", "long_name": f"{c} control, absolute"}) for c in CONTROLS},
        coords={"time": ("time", t, {"units": "s"})},
        attrs={"kind": "2311", "axis": axis})


def trimmed_truth_fmu(trim, *, model: str = "helicopter") -> Path:
    """The truth FMU built with ``trim``'s states, controls and parameters as start values.

    The same C sources (``fmus/<model>``, every file copied) with ``variables.csv`` start
    values replaced, built and cached like the truth FMU: an importer that instantiates it
    without setting anything starts exactly at the trim. Returns the cached ``.fmu``.
    """
    start = {**trim.parameters, **trim.start_values()}
    source = fmu_sources_dir() / model
    with tempfile.TemporaryDirectory(prefix="sysid-trimmed-") as tmp:
        folder = Path(tmp) / model
        shutil.copytree(source, folder)
        table = folder / "variables.csv"
        with table.open(newline="") as fh:
            reader = csv.DictReader(fh)
            fields, rows = reader.fieldnames, list(reader)
        names = {r["name"].strip() for r in rows}
        missing = sorted(set(start) - names)
        if missing:
            raise FMUError(f"the trim sets {missing}, which {source}/variables.csv lacks")
        for row in rows:
            name = row["name"].strip()
            if name in start:
                row["start"] = repr(float(start[name]))
        text = io.StringIO()
        writer = csv.DictWriter(text, fieldnames=fields, lineterminator="\n")
        writer.writeheader()
        writer.writerows(rows)
        table.write_text(text.getvalue())
        return build_model_fmu(folder, common_folder=fmu_sources_dir() / "common")


def export_study_ssp(campaign: CampaignData | str | os.PathLike, path, *, axis: str = "lon",
                     dt: float = 0.01, truth_fmu=None, quiet: bool = True) -> Path:
    """Write the SSP 1.0 package of a campaign's truth FMU and identified models.

    Parameters
    ----------
    campaign : CampaignData or path
        A campaign with ``/models/<method>`` (identified models).
    path : path-like
        The ``.ssp`` file (written atomically).
    axis : {"lon", "lat"}
        Axis of the 2311 input.
    dt : float
        Sample interval of the input and the suggested communication step, s.
    truth_fmu : path-like, optional
        Truth helicopter FMU to trim (default: built from ``fmus/helicopter``); the package
        carries the same sources built with the trim as start values.

    Returns
    -------
    Path of the package: components ``input_2311`` (signal), ``truth`` and one per model
    (its method name), connections signal -> every ``lon lat col ped`` input.

    Examples
    --------
    >>> export_study_ssp("reports/hover/campaign.nc", "study.ssp")
    >>> # libcosimpy: CosimExecution.from_ssp_file("study.ssp") runs it
    """
    progress = Progress(quiet=quiet)
    data = campaign if isinstance(campaign, CampaignData) else CampaignData.read(campaign)
    models = data.models()
    if not models:
        raise InputDataError("the campaign has no identified models (/models/<name>); run "
                             "'sysid identify' first")
    reserved = {SIGNAL_COMPONENT, TRUTH_COMPONENT} & set(models)
    if reserved:
        raise InputDataError(f"model names {sorted(reserved)} clash with the package's own "
                             "components")
    truth_path = Path(truth_fmu) if truth_fmu is not None else build_fmu()
    with progress.stage("trim the truth FMU"):
        trim = trim_truth(data.airspeed_kt, fmu=truth_path)
    signal = study_signal(trim, axis=axis, dt=dt)
    stop = float(signal["time"].values[-1])
    with tempfile.TemporaryDirectory(prefix="sysid-ssp-") as tmp:
        work = Path(tmp)
        components = [SspComponent(SIGNAL_COMPONENT,
                                   export_signal_fmu(signal, work / "input_2311.fmu",
                                                     model_name="sysid_input_2311"),
                                   outputs=CONTROLS)]
        with progress.stage("build the truth FMU trimmed at "
                            f"{trim.flight_condition}"):
            trimmed = trimmed_truth_fmu(trim)
        components.append(SspComponent(TRUTH_COMPONENT, trimmed, inputs=CONTROLS))
        for method, model in models.items():
            with progress.stage(f"export {method}"):
                fmu = export_fmu(model, work / f"{method}.fmu", model_name=f"sysid_{method}")
            components.append(SspComponent(method, fmu, inputs=CONTROLS))
        connections = [(SIGNAL_COMPONENT, c, comp.name, c) for comp in components[1:]
                       for c in CONTROLS]
        return write_ssp(path, name="sysid_study", components=components,
                         connections=connections, stop_time=stop, step_size=dt)
