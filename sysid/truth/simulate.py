"""Open-loop simulation of the truth helicopter from input time histories.

:func:`simulate` runs the FMU from a trim, in co-simulation (the FMU's fixed-step RK4) or in
model exchange (fmpy's CVode), and returns a time-history Dataset per
``docs/data_model.md``. Inputs are zero-order held: the sample at ``time[k]`` acts over
``[time[k], time[k+1])``, which is what a digital flight-test system applies, in both modes.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

import sysid
from sysid.core.errors import FMUError, InputDataError, SimulationDiverged
from sysid.fmi.runtime import DISCARD, FMUModel
from sysid.truth.fmu import load_fmu
from sysid.truth.cosim import DEFAULT_OUTPUTS, GUSTS, CoSimulation
from sysid.truth.linearize import analysis_unit, si_to_analysis
from sysid.truth.trim import TrimResult
from sysid.core.units import CHANNELS, CONTROLS, channel_attrs, conversion_factor

#: Long names of outputs that are not channels of sysid.core.units.CHANNELS.
_LONG_NAMES = {
    "a1": "longitudinal tip-path-plane tilt (aft positive)",
    "b1": "lateral tip-path-plane tilt (starboard positive)",
    "theta_0": "collective pitch at 0.75 R",
    "theta_1s": "longitudinal cyclic pitch (aft disc tilt positive)",
    "theta_1c": "lateral cyclic pitch (starboard disc tilt positive)",
    "theta_tr": "tail-rotor collective pitch",
    "x_n": "north position", "y_e": "east position", "h": "altitude",
    "airspeed": "true airspeed", "vi_mr": "main-rotor induced velocity",
    "vi_tr": "tail-rotor induced velocity",
}


def _check_inputs(inputs: xr.Dataset) -> tuple[np.ndarray, dict]:
    """Validate the input Dataset; return time (s, from 0) and absolute inputs (analysis)."""
    if not isinstance(inputs, xr.Dataset):
        raise InputDataError(f"inputs must be an xarray.Dataset, got {type(inputs).__name__}")
    if "time" not in inputs.coords:
        raise InputDataError("inputs have no 'time' coordinate (s)")
    t = np.asarray(inputs["time"].values, dtype=float)
    if t.ndim != 1 or t.size < 2:
        raise InputDataError("inputs 'time' must be one-dimensional with at least 2 samples")
    dt = np.diff(t)
    if not np.all(np.isfinite(t)) or np.any(dt <= 0):
        raise InputDataError("inputs 'time' must be finite and strictly increasing")
    if np.max(np.abs(dt - dt.mean())) > 1e-6 * dt.mean() + 1e-12:
        raise InputDataError("inputs 'time' must be uniform (constant sample interval)")
    missing = [c for c in CONTROLS if c not in inputs]
    if missing:
        raise InputDataError(f"inputs lack the control(s) {missing} (absolute %, "
                             f"expected {list(CONTROLS)})")
    values = {}
    for name in (*CONTROLS, *GUSTS):
        if name not in inputs:
            continue
        arr = inputs[name]
        if arr.dims != ("time",):
            raise InputDataError(f"input {name!r} must have the single dimension 'time', "
                                 f"got {arr.dims}")
        data = np.asarray(arr.values, dtype=float)
        bad = ~np.isfinite(data)
        if bad.any():
            raise InputDataError(f"input {name!r} is not finite (NaN or inf) at "
                                 f"t = {t[np.argmax(bad)] - t[0]:.3f} s")
        if name in GUSTS:
            unit = arr.attrs.get("units", "ft/s")
            try:
                data = data * conversion_factor(unit, "ft/s")
            except ValueError as exc:
                raise InputDataError(f"input {name!r}: {exc}") from None
        elif arr.attrs.get("units", "%") not in ("%", "percent"):
            raise InputDataError(f"input {name!r} must be in % of travel, "
                                 f"got units {arr.attrs['units']!r}")
        values[name] = data
    return t - t[0], values


def _time_history(model: FMUModel, time, controls: dict, outputs: dict, trim: TrimResult,
                  inputs: xr.Dataset, mode: str) -> xr.Dataset:
    data = {}
    for name in CONTROLS:
        data[name] = ("time", np.clip(controls[name], 0.0, 100.0), channel_attrs(name))
    for name, values in outputs.items():
        if name in CHANNELS:
            attrs = channel_attrs(name)
        else:
            attrs = {"units": analysis_unit(model, name),
                     "long_name": _LONG_NAMES.get(name, model.variable(name).description or name)}
        data[name] = ("time", values, attrs)
    ds = xr.Dataset(data, coords={"time": ("time", time, {"units": "s", "long_name": "time"})})
    attrs = {"maneuver": "simulation", "kind": "", "axis": "", "seed": -1}
    attrs.update({k: v for k, v in inputs.attrs.items() if v is not None})
    attrs.update(trim.attrs())
    attrs.update(fmu_name=model.name, fmu_guid=model.guid, sysid_version=sysid.__version__,
                 simulation=mode)
    ds.attrs = attrs
    ds["lon"].attrs["note"] = "applied (saturated to 0-100 %) control, zero-order held"
    return ds


def _simulate_cs(model, trim, time, values, outputs, step_size, name):
    dt = float(time[1] - time[0])
    sim = CoSimulation(model, outputs=outputs, step_size=step_size, name=name)
    try:
        y = np.empty((len(time), len(outputs)))
        y[0] = sim.reset(trim)
        u = np.column_stack([values[c] for c in CONTROLS])
        gust = (np.column_stack([values.get(g, np.zeros(len(time))) for g in GUSTS])
                if any(g in values for g in GUSTS) else None)
        for k in range(len(time) - 1):
            y[k + 1] = sim.step(u[k], None if gust is None else gust[k], dt)
    finally:
        sim.close()
    h = model.start("h_rk4") if step_size is None else step_size
    return {n: y[:, j] for j, n in enumerate(outputs)}, f"co-simulation, RK4 h = {h:g} s"


def _zoh_signal(time, values: dict) -> np.ndarray:
    """fmpy input table reproducing a zero-order hold: a repeated time stamp at each change."""
    names = [n for n in (*CONTROLS, *GUSTS) if n in values]
    columns = np.column_stack([values[n] for n in names])
    rows = [(time[0], *columns[0])]
    for k in range(1, len(time)):
        if np.any(columns[k] != columns[k - 1]):
            rows.append((time[k], *columns[k - 1]))
        rows.append((time[k], *columns[k]))
    dtype = [("time", np.float64)] + [(n, np.float64) for n in names]
    return np.array(rows, dtype=dtype)


def _simulate_me(model, trim, time, values, outputs, rtol, name):
    from fmpy import simulate_fmu  # deferred: fmpy (see sysid.fmi.runtime)
    from fmpy.fmi1 import FMICallException  # deferred: fmpy

    si = dict(values)
    for g in GUSTS:  # every input gets a column, so fmpy never falls back to start values
        si[g] = si.get(g, np.zeros(len(time))) * conversion_factor("ft/s", model.unit(g))
    dt = float(time[1] - time[0])
    start = {**trim.parameters, **trim.start_values()}
    try:
        result = simulate_fmu(
            str(model.unzip_dir), validate=False, start_time=0.0, stop_time=float(time[-1]),
            solver="CVode", relative_tolerance=rtol, output_interval=dt, record_events=False,
            fmi_type="ModelExchange", start_values=start, input=_zoh_signal(time, si),
            output=list(outputs), model_description=model.description)
    except Exception as exc:
        text = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        # Classified by status, not by message: an FMI call that returned fmi2Discard, or
        # CVode itself giving up (fmpy raises RuntimeError for a negative CVode flag) while
        # every FMI call succeeded, is divergence; any other FMI status is an FMU error.
        if isinstance(exc, FMICallException):
            diverged = exc.status == DISCARD
        else:
            diverged = isinstance(exc, RuntimeError)
        if diverged:
            raise SimulationDiverged(f"model-exchange simulation failed: {text}",
                                     maneuver=name) from None
        raise FMUError(f"model-exchange simulation failed: {text}") from None
    out = {}
    for n in outputs:
        y = np.interp(time, result["time"], result[n]) * si_to_analysis(model, n)
        out[n] = y
    return out, f"model exchange, CVode rtol = {rtol:g}"


def simulate(inputs: xr.Dataset, trim: TrimResult, *, mode: str = "cs", fmu=None,
             outputs=DEFAULT_OUTPUTS, step_size: float | None = None,
             rtol: float = 1e-8) -> xr.Dataset:
    """Simulate the helicopter from ``trim`` with the given control (and gust) histories.

    Parameters
    ----------
    inputs : xr.Dataset
        Uniform ``time`` coordinate (s) and variables ``lon lat col ped`` (absolute %, held
        from one sample to the next); optionally ``u_gust v_gust w_gust`` (body-axis wind,
        ft/s unless their ``units`` attribute says otherwise). Its attributes (``maneuver``,
        ``kind``, ``axis``, ``seed``...) are copied to the result.
    trim : TrimResult
        Initial condition (and parameter overrides).
    mode : {"cs", "me"}
        Co-simulation with the FMU's RK4, or model exchange with fmpy's CVode.
    fmu : path or FMUModel, optional
        Defaults to the FMU of ``trim``.
    outputs : sequence of str
        FMU outputs to record.
    step_size : float, optional
        RK4 sub-step for ``mode="cs"`` (default: the FMU's ``h_rk4``).
    rtol : float
        CVode relative tolerance for ``mode="me"``.

    Returns
    -------
    xr.Dataset
        Time history on ``time`` (s, from 0): applied controls and outputs in analysis units,
        with ``units``/``long_name`` and attributes per ``docs/data_model.md``.
    """
    if mode not in ("cs", "me"):
        raise InputDataError(f"mode must be 'cs' or 'me', got {mode!r}")
    time, values = _check_inputs(inputs)
    model = fmu if isinstance(fmu, FMUModel) else load_fmu(fmu if fmu is not None
                                                          else trim.fmu_path)
    name = inputs.attrs.get("maneuver")
    if mode == "cs":
        out, how = _simulate_cs(model, trim, time, values, tuple(outputs), step_size, name)
    else:
        out, how = _simulate_me(model, trim, time, values, tuple(outputs), rtol, name)
    for n, y in out.items():
        if not np.all(np.isfinite(y)):
            raise SimulationDiverged(f"simulation produced non-finite {n}", maneuver=name)
    return _time_history(model, time, values, out, trim, inputs, how)
