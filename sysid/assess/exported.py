"""Validation of exported FMUs (``sysid.fmi.export``) against independent references.

(a) :func:`roundtrip_error`: the exported FMU, run in co-simulation (stepped at the sample
    interval, inputs set per step) or model exchange (fmpy's CVode, inputs zero-order held by
    repeated time stamps), against :func:`sysid.models.simulate` of the model it came from.
(b) :func:`compare_with_truth`: the exported FMU and the truth helicopter FMU side by side from
    trim with the same inputs; J_rms and Theil's inequality coefficient in the
    ``/verification`` layout of ``docs/data_model.md``.
(c) :func:`envelope_check`: the model's mismatch (paper Eq. 20) against composite frequency
    responses, judged against MUAD and user envelopes over the coherent band.

Time histories here are in analysis units (ft/s, deg/s, deg, %), absolute.
"""

from __future__ import annotations

import contextlib
import os
import tempfile
import zipfile
import zlib
from pathlib import Path
from typing import Iterable, Mapping

import numpy as np
import xarray as xr

from sysid.core.errors import FMUError, InputDataError
from sysid.core.guidelines import COHERENCE_MIN
from sysid.core.units import CHANNELS, channel_attrs, conversion_factor
from sysid.fmi.runtime import inspect_archive
from sysid.models import frequency_response
from sysid.models import simulate as simulate_model
from sysid.signals.inputs import multistep
from sysid.truth import build_fmu
from sysid.truth import simulate as simulate_truth
from sysid.truth import trim as trim_truth
from sysid.assess.envelopes import MUAD, Envelope, check_envelope, load_envelope, mismatch
from sysid.assess.metrics import j_rms, theil_inequality

__all__ = ["simulate_exported", "roundtrip_error", "compare_with_truth", "envelope_check",
           "verification_inputs", "directional_jacobian", "EXPORTED_FMI_VERSIONS"]

#: FMI versions of the exported FMUs these checks run (through fmpy).
EXPORTED_FMI_VERSIONS = ("2.0", "3.0")


# ------------------------------------------------------------------------------------------
# running an exported FMU


def _time_grid(inputs: xr.Dataset) -> np.ndarray:
    if not isinstance(inputs, xr.Dataset) or "time" not in inputs.coords:
        raise InputDataError("inputs must be an xarray.Dataset with a 'time' coordinate (s)")
    t = np.asarray(inputs["time"].values, dtype=float)
    if t.size < 2 or np.any(np.diff(t) <= 0):
        raise InputDataError("inputs 'time' needs at least 2 strictly increasing samples")
    dt = np.diff(t)
    if np.max(np.abs(dt - dt.mean())) > 1e-6 * dt.mean():
        raise InputDataError("inputs 'time' must be uniform")
    return t


def _check_crc(path: Path) -> None:
    """FMUError unless every member of the archive inflates to its recorded CRC (a
    corrupted member otherwise surfaces as zipfile's BadZipFile or zlib's error from inside
    fmpy's extraction)."""
    try:
        with zipfile.ZipFile(path) as zf:
            bad = zf.testzip()
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError,
            NotImplementedError) as exc:
        raise FMUError(f"exported FMU {path} is corrupted ({type(exc).__name__}: {exc})"
                       ) from None
    if bad is not None:
        raise FMUError(f"exported FMU {path} is corrupted: member {bad!r} fails its CRC check")


class _Exported:
    """The FMI view of an exported FMU: names, value references, units, trims."""

    def __init__(self, path):
        from fmpy import read_model_description  # deferred: fmpy is slow to import

        self.path = Path(path)
        if not self.path.is_file():
            raise FMUError(f"exported FMU {self.path} does not exist")
        # Refuse hostile or broken archives before fmpy reads or extracts anything.
        self.fmi_version = inspect_archive(self.path, fmi_versions=EXPORTED_FMI_VERSIONS
                                           )["fmi_version"]
        _check_crc(self.path)
        try:
            self.md = read_model_description(str(self.path), validate=False)
        except Exception as exc:  # fmpy raises plain exceptions for broken descriptions
            message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise FMUError(f"exported FMU {self.path} is not a valid FMU: {message}") from None
        self.vars = {v.name: v for v in self.md.modelVariables}
        self.inputs = [v.name for v in self.md.modelVariables if v.causality == "input"]
        self.outputs = [v.name for v in self.md.modelVariables if v.causality == "output"]
        self.override: dict[str, float] = {}  #: trim parameters changed by the caller (FMU units)

    def to_analysis(self, name: str) -> float:
        """Factor from the FMU's unit of ``name`` to its analysis unit (1 if not a channel)."""
        unit = self.vars[name].unit
        if name in CHANNELS and unit:
            return conversion_factor(unit, CHANNELS[name].unit)
        return 1.0

    def trim(self, name: str) -> float:
        """Trim of an input (%) or output (analysis units) from the trim_<name> parameter."""
        var = self.vars.get(f"trim_{name}")
        if var is None:
            return float(self.vars[name].start or 0.0)
        value = self.override.get(name, float(var.start))
        return value * (self.to_analysis(name) if name in self.outputs else 1.0)


def _input_matrix(fmu: _Exported, inputs: xr.Dataset, absolute: bool) -> np.ndarray:
    """Absolute inputs (%), shape (n_time, n_input); missing inputs held at trim."""
    n = inputs.sizes["time"]
    cols = []
    for name in fmu.inputs:
        if name in inputs:
            values = np.asarray(inputs[name].values, dtype=float)
            if not np.all(np.isfinite(values)):
                raise InputDataError(f"input {name!r} contains NaN or inf")
            cols.append(values if absolute else values + fmu.trim(name))
        else:
            cols.append(np.full(n, fmu.trim(name)))
    return np.column_stack(cols) if cols else np.zeros((n, 0))


def _result(fmu: _Exported, t, Y: np.ndarray, how: str) -> xr.Dataset:
    data = {}
    for j, name in enumerate(fmu.outputs):
        attrs = channel_attrs(name) if name in CHANNELS else {}
        data[name] = ("time", Y[:, j] * fmu.to_analysis(name), attrs)
    return xr.Dataset(data, coords={"time": ("time", t, {"units": "s"})},
                      attrs={"simulation": how, "fmu_name": fmu.md.modelName})


def simulate_exported(fmu_path, inputs: xr.Dataset, *, mode: str = "cs",
                      absolute: bool = False, rtol: float = 1e-10,
                      step_size: float | None = None,
                      parameters: Mapping[str, float] | None = None) -> xr.Dataset:
    """Run an exported FMU on sampled inputs; absolute outputs in analysis units.

    Parameters
    ----------
    fmu_path : path-like
        FMU written by :func:`sysid.fmi.export.export_fmu`.
    inputs : xr.Dataset
        Uniform ``time`` (s); variables named like the FMU inputs (%), perturbations from
        the FMU's ``trim_<input>`` unless ``absolute``. Missing inputs stay at trim.
    mode : {"cs", "me"}
        ``"cs"``: one ``fmi2DoStep`` per sample interval, inputs set before each step (a
        zero-order hold exactly at the samples). ``"me"``: fmpy's CVode with the inputs
        zero-order held by repeated time stamps.
    rtol : float
        CVode relative tolerance (model exchange).
    step_size : float, optional
        Co-simulation only: one ``fmi2DoStep`` of this length instead of one per sample
        (must be a multiple of the sample interval; inputs are sampled at the step starts).
    parameters : mapping, optional
        FMU parameter values set before initialisation (e.g. ``{"M_q": -1.5}``, analysis
        units for identified parameters, SI for trims).

    Returns
    -------
    xr.Dataset with every FMU output on ``time`` (analysis units, absolute).
    """
    fmu = _Exported(fmu_path)
    t = _time_grid(inputs)
    params = dict(parameters or {})
    unknown = [k for k in params if k not in fmu.vars or fmu.vars[k].causality != "parameter"]
    if unknown:
        raise InputDataError(f"{fmu.path.name} has no parameters {unknown}")
    if any(k.startswith("trim_") for k in params):
        fmu.override = {k[5:]: float(v) for k, v in params.items() if k.startswith("trim_")}
    U = _input_matrix(fmu, inputs, absolute)
    if mode == "cs":
        Y = _run_cs(fmu, t, U, step_size, params)
        how = "co-simulation, exact zero-order hold"
    elif mode == "me":
        Y = _run_me(fmu, t, U, rtol, params)
        how = f"model exchange, CVode rtol = {rtol:g}"
    else:
        raise InputDataError(f"mode must be 'cs' or 'me', got {mode!r}")
    return _result(fmu, t - t[0], Y, how)


def _run_cs(fmu: _Exported, t: np.ndarray, U: np.ndarray, step_size: float | None,
            params: dict):
    with tempfile.TemporaryDirectory(prefix="sysid-fmu-") as unzip:
        return _run_cs_in(fmu, t, U, step_size, params, unzip)


def _slave(fmu: _Exported, unzip: str):
    """An fmpy co-simulation instance of the FMU's version with FMI-2-style methods."""
    from fmpy.fmi2 import FMU2Slave  # deferred: fmpy is slow to import
    from fmpy.fmi3 import FMU3Slave

    ident = fmu.md.coSimulation.modelIdentifier
    if fmu.fmi_version == "2.0":
        return FMU2Slave(guid=fmu.md.guid, unzipDirectory=unzip, modelIdentifier=ident,
                         instanceName="sysid_validation")
    return _Fmi3Slave(FMU3Slave(guid=fmu.md.guid, unzipDirectory=unzip, modelIdentifier=ident,
                                instanceName="sysid_validation"))


class _Fmi3Slave:
    """The calls of :func:`_run_cs_in` on an FMI 3.0 instance (fmpy's FMU3Slave)."""

    def __init__(self, slave):
        self.slave = slave
        self.start = 0.0

    def instantiate(self):
        self.slave.instantiate()

    def setupExperiment(self, startTime=0.0):
        self.start = startTime

    def setReal(self, vr, values):
        self.slave.setFloat64(vr, values)

    def getReal(self, vr):
        return self.slave.getFloat64(vr)

    def enterInitializationMode(self):
        self.slave.enterInitializationMode(startTime=self.start)

    def exitInitializationMode(self):
        self.slave.exitInitializationMode()

    def doStep(self, currentCommunicationPoint, communicationStepSize):
        self.slave.doStep(currentCommunicationPoint=currentCommunicationPoint,
                          communicationStepSize=communicationStepSize)

    def terminate(self):
        self.slave.terminate()

    def freeInstance(self):
        self.slave.freeInstance()

    def freeLibrary(self):
        self.slave.freeLibrary()


def _run_cs_in(fmu: _Exported, t, U, step_size, params: dict, unzip: str):
    from fmpy import extract  # deferred: fmpy is slow to import

    extract(str(fmu.path), unzipdir=unzip)
    slave = _slave(fmu, unzip)
    vr_in = [fmu.vars[n].valueReference for n in fmu.inputs]
    vr_out = [fmu.vars[n].valueReference for n in fmu.outputs]
    dt = float(t[1] - t[0])
    stride = 1 if step_size is None else int(round(step_size / dt))
    if stride < 1 or abs(stride * dt - (step_size or dt)) > 1e-9 * stride * dt:
        raise InputDataError(f"step_size {step_size} s must be a multiple of the sample "
                             f"interval {dt} s")
    Y = np.full((len(t), len(vr_out)), np.nan)
    with _fmpy_session(slave, f"co-simulation of {fmu.path.name}"):
        slave.instantiate()
        slave.setupExperiment(startTime=0.0)
        if params:
            slave.setReal([fmu.vars[k].valueReference for k in params], list(params.values()))
        slave.enterInitializationMode()
        slave.exitInitializationMode()
        time = 0.0
        for k in range(0, len(t), stride):
            slave.setReal(vr_in, list(U[k]))
            Y[k] = slave.getReal(vr_out)
            if k + stride < len(t):
                slave.doStep(currentCommunicationPoint=time, communicationStepSize=stride * dt)
                time = (k + stride) * dt
        slave.terminate()
    return Y


@contextlib.contextmanager
def _fmpy_session(instance, what: str):
    """Run the body on an fmpy FMU instance; any failure becomes ``FMUError("<what> failed:
    ...")``, and the instance and its library are freed either way."""
    try:
        yield instance
    except Exception as exc:
        raise FMUError(f"{what} failed: {exc}") from None
    finally:
        instance.freeInstance()
        instance.freeLibrary()


def _run_me(fmu: _Exported, t: np.ndarray, U: np.ndarray, rtol: float, params: dict):
    from fmpy import simulate_fmu  # deferred: fmpy is slow to import

    tt = t - t[0]
    rows = [(tt[0], *U[0])]
    for k in range(1, len(tt)):
        if np.any(U[k] != U[k - 1]):
            rows.append((tt[k], *U[k - 1]))  # a repeated time stamp: a step exactly at t_k
        rows.append((tt[k], *U[k]))
    signal = np.array(rows, dtype=[("time", np.float64)] + [(n, np.float64)
                                                             for n in fmu.inputs])
    try:
        res = simulate_fmu(str(fmu.path), validate=False, fmi_type="ModelExchange",
                           solver="CVode", relative_tolerance=rtol, start_time=0.0,
                           stop_time=float(tt[-1]), output_interval=float(tt[1] - tt[0]),
                           input=signal, output=list(fmu.outputs), record_events=False,
                           start_values=params)
    except Exception as exc:
        raise FMUError(f"model-exchange simulation of {fmu.path.name} failed: {exc}") from None
    return np.column_stack([np.interp(tt, res["time"], res[n]) for n in fmu.outputs])


def directional_jacobian(fmu_path) -> xr.Dataset:
    """The Jacobians of an FMU from its directional derivatives, after initialisation.

    One ``fmi2GetDirectionalDerivative`` / ``fmi3GetDirectionalDerivative`` call per state and
    input (seed 1) on a model-exchange instance at its start values, through fmpy.

    Returns
    -------
    xr.Dataset
        ``A (state_dot, state)``, ``B (state_dot, input)``, ``C (output, state)``,
        ``D (output, input)`` in the FMU's own units, labelled with the FMU's variable names
        (``state_dot`` holds the state names, the rows being their derivatives).
    """
    from fmpy import extract  # deferred: fmpy is slow to import
    from fmpy.fmi2 import FMU2Model
    from fmpy.fmi3 import FMU3Model

    fmu = _Exported(fmu_path)
    if fmu.md.modelExchange is None:
        raise FMUError(f"{fmu.path.name} has no model-exchange interface")
    derivs = [d.variable for d in fmu.md.derivatives]
    states = [v.derivative for v in derivs]
    vr = {v.name: v.valueReference for v in fmu.md.modelVariables}
    unknowns = [v.valueReference for v in derivs] + [vr[n] for n in fmu.outputs]
    knowns = [s_.name for s_ in states] + list(fmu.inputs)
    columns = []
    with tempfile.TemporaryDirectory(prefix="sysid-fmu-") as unzip:
        extract(str(fmu.path), unzipdir=unzip)
        kwargs = dict(guid=fmu.md.guid, unzipDirectory=unzip, instanceName="sysid_jacobian",
                      modelIdentifier=fmu.md.modelExchange.modelIdentifier)
        model = FMU2Model(**kwargs) if fmu.fmi_version == "2.0" else FMU3Model(**kwargs)
        with _fmpy_session(model, f"directional derivatives of {fmu.path.name}"):
            model.instantiate()
            if fmu.fmi_version == "2.0":
                model.setupExperiment(startTime=0.0)
                model.enterInitializationMode()
            else:
                model.enterInitializationMode(startTime=0.0)
            model.exitInitializationMode()
            for name in knowns:
                columns.append(model.getDirectionalDerivative(unknowns, [vr[name]], [1.0]))
            model.terminate()
    J = np.array(columns, dtype=float).T  # (unknowns, knowns)
    nx = len(states)
    names = [s_.name for s_ in states]
    return xr.Dataset(
        {"A": (("state_dot", "state"), J[:nx, :nx]), "B": (("state_dot", "input"), J[:nx, nx:]),
         "C": (("output", "state"), J[nx:, :nx]), "D": (("output", "input"), J[nx:, nx:])},
        coords={"state_dot": names, "state": names, "input": list(fmu.inputs),
                "output": list(fmu.outputs)},
        attrs={"fmu": fmu.path.name, "fmi_version": fmu.fmi_version,
               "units": "the FMU's own (SI for the exported models)"})


# ------------------------------------------------------------------------------------------
# (a) round trip against sysid.models.simulate


def roundtrip_error(model_ds: xr.Dataset, fmu_path, inputs: xr.Dataset, *,
                    mode: str = "cs", rtol: float = 1e-10) -> xr.Dataset:
    """Exported FMU vs :func:`sysid.models.simulate` of the model on the same inputs.

    ``inputs`` are perturbations (%) from the model's trim. Returns per ``output`` the
    ``max_abs_error`` (analysis units) and ``relative_error``: the largest deviation divided
    by the peak of the model's response (perturbation); attr ``max_relative_error`` is the
    largest over the outputs that respond.
    """
    names = [str(k) for k in model_ds["B"].input.values]
    full = inputs.assign({k: ("time", np.zeros(inputs.sizes["time"]))
                          for k in names if k not in inputs})
    ref = simulate_model(model_ds, full, absolute=False)
    got = simulate_exported(fmu_path, inputs, mode=mode, rtol=rtol)
    outputs = [str(o) for o in model_ds["C"].output.values]
    trim = (model_ds["trim_output"].sel(output=outputs).values if "trim_output" in model_ds
            else np.zeros(len(outputs)))
    abs_err, rel_err, peaks = [], [], []
    for j, name in enumerate(outputs):
        y_ref = np.asarray(ref[name].values)
        y_fmu = np.asarray(got[name].values) - trim[j]
        err = float(np.max(np.abs(y_fmu - y_ref)))
        peak = float(np.max(np.abs(y_ref)))
        abs_err.append(err)
        peaks.append(peak)
        rel_err.append(err / peak if peak > 0 else (0.0 if err == 0 else np.inf))
    rel = np.array(rel_err)
    responding = np.array(peaks) > 1e-9 * max(max(peaks), 1e-300)
    return xr.Dataset(
        {"max_abs_error": ("output", abs_err, {"long_name": "largest deviation",
                                               "units": "analysis units"}),
         "relative_error": ("output", rel, {"long_name": "largest deviation / peak response"}),
         "peak_response": ("output", peaks)},
        coords={"output": outputs},
        attrs={"mode": mode, "max_relative_error": float(np.max(rel[responding]))
               if responding.any() else 0.0, "reference": "sysid.models.simulate"})


# ------------------------------------------------------------------------------------------
# (b) side by side with the truth FMU


def verification_inputs(dt: float = 0.01) -> dict[str, xr.Dataset]:
    """The default verification manoeuvres: a 3211 on every control and a 2311 on lon and
    lat (perturbations, %); short pulses and lead-outs keep the unstable hover modes of the
    truth model within its linear range."""
    out = {}
    for kind, axis, width, amp in (("3211", "lon", 0.4, 2.0), ("3211", "lat", 0.3, 2.0),
                                   ("3211", "col", 0.5, 3.0), ("3211", "ped", 0.4, 3.0),
                                   ("2311", "lon", 0.4, 2.0), ("2311", "lat", 0.3, 2.0)):
        out[f"{kind}_{axis}"] = multistep(kind, axis, base_width=width, amplitude=amp, dt=dt,
                                          lead_in=1.0, lead_out=2.0)
    return out


def compare_with_truth(exported_fmu, truth_fmu=None, inputs: xr.Dataset | None = None, *,
                       trim=None, model_name: str | None = None,
                       channels: Iterable[str] = ("u", "v", "w", "p", "q", "r", "phi",
                                                  "theta", "psi")) -> xr.Dataset:
    """Run the exported FMU and the truth FMU side by side from trim (co-simulation).

    Parameters
    ----------
    exported_fmu : path-like
        Exported linear model (its trim should be the truth trim, e.g. a model identified
        from data flown at that trim, or the truth's own linearisation).
    truth_fmu : path-like, optional
        Truth helicopter FMU (default: built from ``fmus/helicopter``).
    inputs : xr.Dataset
        Control perturbations from trim (%), uniform ``time``; both models get
        ``trim + perturbation``.
    trim : sysid.truth.TrimResult, optional
        Truth trim (default: the trim at the exported model's ``airspeed_kt`` attr, or hover).
    model_name : str, optional
        Label of the model in ``source`` (default: the FMU's model name).

    Returns
    -------
    xr.Dataset
        ``/verification`` layout: one variable per channel with dims ``(source, time)``,
        ``source = ["truth", <model>]`` (analysis units, absolute); ``tic (source, channel)``
        and ``j_rms (source)`` of each source against the truth (0 for the truth itself).
    """
    if inputs is None:
        raise InputDataError("compare_with_truth needs the inputs (control perturbations, %)")
    truth_path = Path(truth_fmu) if truth_fmu is not None else build_fmu()
    fmu = _Exported(exported_fmu)
    if trim is None:
        trim = trim_truth(0.0, fmu=truth_path)
    label = model_name or fmu.md.modelName
    t = _time_grid(inputs)
    controls = trim.channel_values()
    absolute = xr.Dataset({c: ("time", np.asarray(inputs[c].values, float) + controls[c]
                               if c in inputs else np.full(len(t), controls[c]),
                               {"units": "%"}) for c in ("lon", "lat", "col", "ped")},
                          coords={"time": t}, attrs=dict(inputs.attrs))
    truth = simulate_truth(absolute, trim, mode="cs", fmu=truth_path)
    model = simulate_exported(fmu.path, absolute, mode="cs", absolute=True)
    channels = [c for c in channels if c in truth and c in model]
    if not channels:
        raise InputDataError(f"the exported FMU {fmu.path.name} shares no channel with the "
                             f"truth FMU")
    sources = ["truth", label]
    data = {}
    for c in channels:
        stacked = np.stack([truth[c].values, model[c].values])
        data[c] = (("source", "time"), stacked, channel_attrs(c))
    ds = xr.Dataset(data, coords={"source": sources, "channel": channels,
                                  "time": ("time", t - t[0], {"units": "s"})})
    meas = ds.sel(source="truth")
    tic = np.zeros((2, len(channels)))
    jr = np.zeros(2)
    sim = ds.sel(source=label)
    tic[1] = [float(theil_inequality(meas[c], sim[c])) for c in channels]
    jr[1] = j_rms(meas[channels], sim[channels])
    ds["tic"] = (("source", "channel"), tic,
                 {"long_name": "Theil inequality coefficient against the truth"})
    ds["j_rms"] = ("source", jr, {"long_name": "J_rms against the truth (unit weights)"})
    ds.attrs.update({"maneuver": str(inputs.attrs.get("kind", "")) + "_" +
                     str(inputs.attrs.get("axis", "")), "truth_fmu": truth_path.name,
                     "model": label, "simulation": "co-simulation from trim",
                     "flight_condition": trim.flight_condition})
    return ds


# ------------------------------------------------------------------------------------------
# (c) mismatch envelopes against composite frequency responses


def _envelopes(envelopes) -> list:
    out = []
    for env in (envelopes if envelopes is not None else [MUAD]):
        if isinstance(env, Envelope):
            out.append(env)
        elif isinstance(env, (str, os.PathLike)):
            out.append(load_envelope(env))
        else:
            raise InputDataError(f"envelope {env!r}: expected an Envelope or a TOML file path")
    names = [e.name for e in out]
    if len(set(names)) != len(names):
        raise InputDataError(f"envelope names must be unique, got {names}")
    return out


def envelope_check(model_ds: xr.Dataset | Mapping[str, xr.Dataset],
                   frequency_response_ds: xr.Dataset, envelopes=None, *,
                   min_coherence: float = COHERENCE_MIN) -> xr.Dataset:
    """Mismatch of model(s) against composite frequency responses, judged by envelopes.

    Parameters
    ----------
    model_ds : xr.Dataset or mapping name -> Dataset
        Model(s) of ``docs/data_model.md``.
    frequency_response_ds : xr.Dataset
        ``H (output, input, frequency)`` complex, analysis units per %; ``partial_coherence``
        (same dims) selects the coherent band (``coherence`` if there is no partial one).
    envelopes : list of Envelope or TOML paths, optional
        Default ``[MUAD]``; user AEE files are read with :func:`sysid.assess.envelopes.load_envelope`.
    min_coherence : float
        Frequencies with coherence below this do not count.

    Returns
    -------
    xr.Dataset
        Dims ``(model, envelope, output, input)``: ``fraction_inside`` of the coherent band,
        ``worst_magnitude_excess`` (dB), ``worst_phase_excess`` (deg); and the mismatch
        ``magnitude`` (dB) and ``phase`` (deg) ``(model, output, input, frequency)``; the
        ``model`` dim is dropped for a single Dataset.
    """
    single = isinstance(model_ds, xr.Dataset)
    models = {"model": model_ds} if single else dict(model_ds)
    if "H" not in frequency_response_ds:
        raise InputDataError("the frequency-response Dataset has no variable 'H'")
    H = frequency_response_ds["H"]
    if "window" in H.dims:
        raise InputDataError("envelope_check needs composite responses (no 'window' dim)")
    coh_name = ("partial_coherence" if "partial_coherence" in frequency_response_ds
                else "coherence" if "coherence" in frequency_response_ds else None)
    envs = _envelopes(envelopes)
    omega = H["frequency"].values
    per_model = []
    for name, mds in models.items():
        T = frequency_response(mds, omega)
        outs = [o for o in H.output.values if o in T.output.values]
        ins = [i for i in H.input.values if i in T.input.values]
        if not outs or not ins:
            raise InputDataError(f"model {name!r} shares no output/input pair with the "
                                 f"frequency responses")
        ref = H.sel(output=outs, input=ins)
        err = mismatch(T.sel(output=outs, input=ins), ref)
        coh = (frequency_response_ds[coh_name].broadcast_like(H).sel(output=outs, input=ins)
               if coh_name else None)
        judged = [check_envelope(err, env, coherence=coh, min_coherence=min_coherence)
                  [["fraction_inside", "worst_magnitude_excess", "worst_phase_excess"]]
                  for env in envs]
        result = xr.concat(judged, dim="envelope", coords="minimal", compat="override")
        result = result.assign_coords(envelope=[e.name for e in envs])
        result["magnitude"] = err["magnitude"]
        result["phase"] = err["phase"]
        per_model.append(result)
    ds = xr.concat(per_model, dim="model", coords="minimal", compat="override",
                   join="outer").assign_coords(model=list(models))
    ds.attrs.update({"min_coherence": min_coherence, "coherence": coh_name or "none",
                     "citations": "; ".join(e.citation for e in envs)})
    return ds.isel(model=0, drop=True) if single else ds
