"""The ``/validation/<model>`` datasets: every identified model exported as an FMU and checked.

For each model of a campaign, :func:`validate_model` exports it (:func:`sysid.fmi.export.
export_fmu`) and runs the checks of :mod:`sysid.assess.exported` on the exported FMU:

(a) round trip: the FMU in co-simulation and in model exchange against
    :func:`sysid.models.simulate` on the verification inputs (a 3211 on every control, a 2311
    on lon and lat): ``roundtrip_cs``, ``roundtrip_me`` (maneuver), max error / peak response;
(b) the truth: the FMU beside the truth helicopter FMU from the campaign's trim on the same
    inputs: ``j_rms`` (maneuver) and ``tic`` (maneuver, channel);
(c) the envelopes: the model's mismatch against the composite responses judged by MUAD (and
    user envelopes) over the coherent band: ``fraction_inside``, ``mismatch_magnitude`` ...

:func:`validate_models` does it for every ``/models/<name>``; a model that cannot be
validated (e.g. a diverged fit whose FMU the integrator cannot run) gives a Dataset with only
the attributes ``model`` and ``error`` ("Type: message"), so one unusable model does not stop
the others. Attributes of every Dataset: ``model``, and ``fmu`` (the exported file's name).
"""

from __future__ import annotations

import os
from collections.abc import Iterable
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError, SysidError
from sysid.data.campaign import CampaignData
from sysid.fmi.export import export_fmu
from sysid.truth import build_fmu
from sysid.truth import trim as trim_truth
from sysid.assess.envelopes import MUAD, Envelope, load_envelope
from sysid.assess.exported import (compare_with_truth, envelope_check, roundtrip_error,
                                   verification_inputs)

__all__ = ["truth_reference", "validate_model", "validate_models", "format_validation",
           "validation_envelopes", "validation_folder"]


def truth_reference(data: CampaignData):
    """``(truth FMU path, trim)`` at the campaign's airspeed, or ``(None, reason)`` when the
    truth FMU cannot be built or trimmed there (the truth check is then skipped)."""
    try:
        path = build_fmu()
        return path, trim_truth(data.airspeed_kt, fmu=path)
    except SysidError as exc:
        return None, f"truth FMU not available ({exc})"


def validation_envelopes(envelopes: Iterable) -> list[Envelope]:
    """The envelopes to judge against: :class:`~sysid.assess.envelopes.Envelope` objects
    as they are, TOML paths read by :func:`~sysid.assess.envelopes.load_envelope`. A missing
    or malformed file raises :class:`~sysid.core.errors.InputDataError` naming it, before any
    model is exported or any result written."""
    out = []
    for item in envelopes:
        if isinstance(item, Envelope):
            out.append(item)
            continue
        path = Path(item)
        if not path.is_file():
            raise InputDataError(f"envelope file {path} does not exist"
                                 + (" (it is a directory)" if path.is_dir() else ""))
        try:
            out.append(load_envelope(path))
        except UnicodeDecodeError as exc:
            raise InputDataError(f"envelope file {path}: not UTF-8 text (byte {exc.start}); "
                                 "expected a TOML file") from None
    return out


def validation_folder(fmu_dir: str | Path) -> Path:
    """``fmu_dir`` as a folder the exported FMUs can be written to (created if missing);
    :class:`~sysid.core.errors.InputDataError` when it names a file or cannot be created."""
    folder = Path(fmu_dir)
    if folder.exists() and not folder.is_dir():
        raise InputDataError(f"FMU folder {folder} is a file; expected a folder to keep the "
                             "exported FMUs in")
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputDataError(f"FMU folder {folder} cannot be created ({exc})") from None
    if not os.access(folder, os.W_OK | os.X_OK):
        raise InputDataError(f"FMU folder {folder} is not writable")
    return folder


def validate_model(name: str, model: xr.Dataset, *, fmu_dir: str | Path, truth=None,
                   trim=None, frequency_response: xr.Dataset | None = None,
                   envelopes: Iterable | None = None, quiet: bool = True) -> xr.Dataset:
    """Export ``model`` as ``<fmu_dir>/<name>.fmu`` and check it; one ``/validation/<name>``.

    Checks (a) always, (b) when ``truth`` (the truth FMU) and its ``trim`` are given, (c)
    when ``frequency_response`` is given, with ``envelopes`` (default MUAD); see the module
    docstring for the variables.
    """
    path = export_fmu(model, Path(fmu_dir) / f"{name}.fmu", model_name=f"sysid_{name}",
                      quiet=quiet)
    manoeuvres = verification_inputs()
    names = list(manoeuvres)
    ds = xr.Dataset(coords={"maneuver": names})
    ds["roundtrip_cs"] = ("maneuver", [roundtrip_error(model, path, manoeuvres[m], mode="cs")
                                       .attrs["max_relative_error"] for m in names],
                          {"long_name": "co-simulation vs sysid.models.simulate, "
                                        "max error / peak response"})
    ds["roundtrip_me"] = ("maneuver", [roundtrip_error(model, path, manoeuvres[m], mode="me")
                                       .attrs["max_relative_error"] for m in names],
                          {"long_name": "model exchange (CVode, delays from the input "
                                        "history) vs sysid.models.simulate, max error / "
                                        "peak response"})
    if truth is not None:
        runs = [compare_with_truth(path, truth, manoeuvres[m], trim=trim, model_name=name)
                for m in names]
        ds["j_rms"] = ("maneuver", [float(r["j_rms"].sel(source=name)) for r in runs],
                       {"long_name": "J_rms against the truth FMU"})
        ds["tic"] = (("maneuver", "channel"),
                     np.stack([r["tic"].sel(source=name).values for r in runs]),
                     {"long_name": "Theil inequality coefficient against the truth FMU"})
        ds = ds.assign_coords(channel=runs[0]["channel"].values)
    if frequency_response is not None:
        env = envelope_check(model, frequency_response, envelopes)
        for var in env.data_vars:
            ds[var if var not in ("magnitude", "phase") else f"mismatch_{var}"] = env[var]
    ds.attrs.update({"fmu": path.name, "model": name})
    return ds


def validate_models(data: CampaignData, *, fmu_dir: str | Path, truth=None, trim=None,
                    envelopes: Iterable = (MUAD,), quiet: bool = True
                    ) -> dict[str, xr.Dataset]:
    """``{name: /validation/<name> Dataset}`` for every ``/models/<name>`` of the campaign.

    ``truth``/``trim`` as from :func:`truth_reference` (None: no truth check); the envelope
    check runs when the campaign has ``/frequency_response``. A model whose validation
    raises gives ``Dataset(attrs={"model": name, "error": "Type: message"})``. Bad
    arguments (a missing or malformed envelope file, ``fmu_dir`` naming a file) raise
    :class:`~sysid.core.errors.InputDataError` before anything is exported, so a caller
    never stores their failure in place of earlier results.
    """
    envelopes = validation_envelopes(envelopes)
    fmu_dir = validation_folder(fmu_dir)
    models = data.models()
    if not models:
        raise InputDataError(f"campaign {data.source} has no identified models (/models/<name>); "
                             "run 'sysid identify' first")
    fr = data.frequency_response()
    results = {}
    for name, model in models.items():
        try:
            results[name] = validate_model(name, model, fmu_dir=fmu_dir, truth=truth,
                                           trim=trim, frequency_response=fr,
                                           envelopes=list(envelopes), quiet=quiet)
        except Exception as exc:  # noqa: BLE001 - one model's failure is a result
            # A model can be unusable (e.g. a diverged fit whose FMU CVode cannot
            # integrate); that is a validation outcome to report and store, and the
            # other models are still validated.
            results[name] = xr.Dataset(attrs={"model": name,
                                              "error": f"{type(exc).__name__}: {exc}"})
    return results


def format_validation(results: dict[str, xr.Dataset]) -> str:
    """The validation table: one line per validated model (round-trip errors, J_rms mean and
    TIC max against the truth, mean fraction inside each envelope); failures first."""
    lines = [f"{name}: validation FAILED: {ds.attrs['error']}"
             for name, ds in results.items() if "error" in ds.attrs]
    rows = [(name, ds) for name, ds in results.items() if "error" not in ds.attrs]
    if not rows:
        return "\n".join(lines + [f"no model could be validated ({', '.join(results)})"])
    header = f"{'model':<20}{'CS err':>10}{'ME err':>10}{'J_rms':>8}{'TIC max':>9}"
    env_names = ([str(e) for e in rows[0][1]["envelope"].values]
                 if "envelope" in rows[0][1].coords else [])
    header += "".join(f"{e[:12] + ' in':>16}" for e in env_names)
    lines.append(header)
    for name, ds in rows:
        line = (f"{name:<20}{float(ds.roundtrip_cs.max()):>10.1e}"
                f"{float(ds.roundtrip_me.max()):>10.1e}")
        line += (f"{float(ds.j_rms.mean()):>8.3f}{float(ds.tic.max()):>9.3f}" if "j_rms" in ds
                 else f"{'-':>8}{'-':>9}")
        for e in env_names:
            frac = float(ds.fraction_inside.sel(envelope=e).mean())
            line += f"{100 * frac:>15.0f}%"
        lines.append(line)
    lines.append("(errors: max deviation / peak response vs sysid.models.simulate; J_rms mean "
                 "and TIC max over the verification 3211/2311 inputs; envelope: mean fraction "
                 "of the coherent band inside the bounds)")
    return "\n".join(lines)
