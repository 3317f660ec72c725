"""Fast co-simulation stepping for closed-loop flight-test campaigns.

:class:`CoSimulation` wraps one co-simulation instance of the truth FMU for loops written in
Python, e.g. a 100 Hz sweep with secondary-axis controllers::

    from sysid.truth import CoSimulation, trim

    t0 = trim(0.0)
    with CoSimulation() as sim:
        y = sim.reset(t0)                      # outputs at trim, analysis units
        i_phi = sim.output_names.index("phi")
        controls = sim.trim_controls.copy()    # lon lat col ped, %
        for k in range(6000):                  # 60 s at 100 Hz
            # roll-attitude hold on the lateral cyclic (gain in % per deg)
            controls[1] = sim.trim_controls[1] - 0.5 * (y[i_phi] - t0.phi_deg)
            y = sim.step(controls, dt=0.01)

Each :meth:`CoSimulation.step` sets the seven inputs, advances the FMU's internal RK4 by
``dt`` (inputs held constant over the step) and reads the outputs, through the FMI C functions
with preallocated arrays: no dict, list or xarray object is created per step, and the
outputs come back as one NumPy array in analysis units (ft/s, deg/s, deg, ft/s^2, %, ft).
A step raises :class:`~sysid.core.errors.SimulationDiverged` (with the time) when an output leaves
the physical envelope or a state becomes non-finite, and
:class:`~sysid.core.errors.InputDataError` for a NaN or mis-shaped control vector.

:meth:`CoSimulation.run` flies whole input histories known in advance (controls and gusts
per step) with three FMI calls and no NumPy operation per step, reading the outputs straight
into one preallocated array: with the stabilisation holds computed inside the FMU
(``hold_*`` parameters, see ``fmus/helicopter/holds.h``) this is how the flight-test campaign
steps at 100 Hz, several times faster than :meth:`~CoSimulation.step`.
"""

from __future__ import annotations

import ctypes
from dataclasses import dataclass
from typing import Callable

import numpy as np

from sysid.core.errors import FMUError, InputDataError, SimulationDiverged
from sysid.core.units import CONTROLS, conversion_factor
from sysid.fmi.runtime import (DISCARD, WARNING, FMUModel, Instance, ReleasedOnExit,
                               c_double_p, c_uint_p)
from sysid.truth.fmu import load_fmu
from sysid.truth.linearize import analysis_unit, si_to_analysis
from sysid.truth.trim import TrimResult

#: Measurement channels of a time history (docs/data_model.md), in order.
MEASUREMENTS = ("u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "ax", "ay", "az")
#: Further outputs recorded by default: flapping, blade angles, position, airspeed.
EXTRA_OUTPUTS = ("a1", "b1", "theta_0", "theta_1s", "theta_1c", "theta_tr",
                 "x_n", "y_e", "h", "airspeed")
DEFAULT_OUTPUTS = MEASUREMENTS + EXTRA_OUTPUTS
GUSTS = ("u_gust", "v_gust", "w_gust")
#: Outputs of the truth FMU with the controls its actuators follow over each step: the inputs
#: plus its stabilisation holds, saturated (``hold_*`` parameters).
APPLIED = tuple(f"{c}_applied" for c in CONTROLS)

#: Physical envelope (analysis units): a step whose outputs exceed these magnitudes raises
#: SimulationDiverged. Attitudes stay clear of the Euler-angle singularity at 90 deg pitch.
DEFAULT_ENVELOPE = {"u": 400.0, "v": 200.0, "w": 200.0, "p": 300.0, "q": 300.0, "r": 300.0,
                    "phi": 90.0, "theta": 80.0, "airspeed": 400.0}


class CoSimulation(ReleasedOnExit):
    """One co-simulation instance of the truth helicopter, stepped from Python.

    Parameters
    ----------
    fmu : path or FMUModel, optional
        Default: the truth helicopter FMU (built on first use).
    outputs : sequence of str
        FMU outputs returned by :meth:`step`, in this order (:attr:`output_names`).
    step_size : float, optional
        Internal RK4 sub-step, s (FMU parameter ``h_rk4``; default from the FMU, 5 ms).
    parameters : dict, optional
        Further FMU parameter overrides (SI); the trim's own parameters are applied first.
    envelope : dict, optional
        ``{output: max |value|}`` in analysis units; default :data:`DEFAULT_ENVELOPE`
        (entries for outputs not requested are ignored). Pass ``{}`` to disable.
    name : str
        Manoeuvre name carried by :class:`SimulationDiverged`.
    """

    def __init__(self, fmu=None, *, outputs=DEFAULT_OUTPUTS, step_size: float | None = None,
                 parameters: dict | None = None, envelope: dict | None = None,
                 name: str | None = None):
        self.model: FMUModel = fmu if isinstance(fmu, FMUModel) else load_fmu(fmu)
        self.output_names = tuple(outputs)
        # Every missing input and output in one message (a foreign FMU lacks many).
        self.model.require(dict.fromkeys((*CONTROLS, *GUSTS, *self.output_names)),
                           "for co-simulation of the helicopter")
        #: Analysis unit of each output.
        self.output_units = tuple(analysis_unit(self.model, n) for n in self.output_names)
        self._factor = np.array([si_to_analysis(self.model, n) for n in self.output_names])
        self._gust_factor = conversion_factor("ft/s", self.model.unit("u_gust"))
        self._extra_parameters = dict(parameters or {})
        if step_size is not None:
            if not step_size > 0:
                raise InputDataError(f"step_size must be positive, got {step_size!r}")
            self._extra_parameters["h_rk4"] = float(step_size)
        envelope = DEFAULT_ENVELOPE if envelope is None else envelope
        idx = [k for k, n in enumerate(self.output_names) if n in envelope]
        self._env_index = np.array(idx, dtype=int)
        self._env_limit = np.array([envelope[self.output_names[k]] for k in idx])
        self.name = name
        self._inst: Instance | None = None
        self._vr_in = self.model.vrs((*CONTROLS, *GUSTS))
        self._vr_out = self.model.vrs(self.output_names)
        self._in = np.zeros(len(self._vr_in))
        self._out = np.empty(len(self._vr_out))
        self._vr_in_p = self._vr_in.ctypes.data_as(c_uint_p)
        self._vr_out_p = self._vr_out.ctypes.data_as(c_uint_p)
        self._in_p = self._in.ctypes.data_as(c_double_p)
        self._out_p = self._out.ctypes.data_as(c_double_p)
        self.time = 0.0
        #: Trim controls of the last :meth:`reset`, % (lon lat col ped).
        self.trim_controls = np.full(4, np.nan)

    @property
    def fmu_name(self) -> str:
        """Model name of the FMU (for the ``fmu_name`` attribute of time histories)."""
        return self.model.name

    @property
    def fmu_guid(self) -> str:
        """GUID of the FMU (for the ``fmu_guid`` attribute of time histories)."""
        return self.model.guid

    # ------------------------------------------------------------------------------------
    def reset(self, trim: TrimResult, time: float = 0.0, *,
              parameters: dict | None = None) -> np.ndarray:
        """(Re)initialise exactly at ``trim`` at ``time``; returns the outputs there.

        ``parameters`` (SI, FMU names) override FMU parameters until the next reset, e.g. the
        ``hold_*`` gains of one manoeuvre. The instance is reused: fmi2Reset restores every
        start value, so parameters left out return to their defaults.
        """
        parameters = {**trim.parameters, **self._extra_parameters, **(parameters or {})}
        if self._inst is None:
            self._inst = Instance(self.model, "cs", parameters, name="sysid_cosimulation")
            self._raw_set = self._inst.functions["fmi2SetReal"]
            self._raw_get = self._inst.functions["fmi2GetReal"]
            self._raw_step = self._inst.functions["fmi2DoStep"]
            self._c = self._inst.component
        else:
            self._inst.reset()
            self._inst.parameters = parameters
        self._inst.initialize(trim.start_values(), start_time=time)
        self.time = float(time)
        self.trim_controls = np.array([trim.controls[c] for c in CONTROLS])
        self._in[:4] = self.trim_controls
        self._in[4:] = 0.0
        return self.outputs()

    def outputs(self) -> np.ndarray:
        """Current outputs, analysis units, in the order of :attr:`output_names`."""
        if self._inst is None:
            raise FMUError("CoSimulation.reset(trim) must be called before stepping")
        status = self._raw_get(self._c, self._vr_out_p, len(self._vr_out), self._out_p)
        if status > WARNING:
            self._inst.check(status, "fmi2GetReal")
        return self._out * self._factor

    def step(self, controls, gusts=None, dt: float = 0.01) -> np.ndarray:
        """Advance by ``dt`` seconds with ``controls`` held constant over the step.

        Parameters
        ----------
        controls : array-like, shape (4,)
            Absolute ``lon lat col ped``, % of travel (the FMU saturates at 0 and 100).
        gusts : array-like, shape (3,), optional
            Wind ``u_gust v_gust w_gust`` along the body axes, ft/s.
        dt : float
            Step, s.

        Returns
        -------
        np.ndarray, shape (n_outputs,)
            Outputs at the end of the step, analysis units (a new array).
        """
        inp = self._in
        try:
            inp[0], inp[1], inp[2], inp[3] = controls
        except (TypeError, ValueError):
            raise InputDataError(f"controls must be 4 numbers (lon lat col ped, %), "
                                 f"got {controls!r}") from None
        if gusts is None:
            inp[4] = inp[5] = inp[6] = 0.0
        else:
            try:
                inp[4], inp[5], inp[6] = gusts
            except (TypeError, ValueError):
                raise InputDataError(f"gusts must be 3 numbers (u v w, ft/s), "
                                     f"got {gusts!r}") from None
            inp[4:] *= self._gust_factor
        if not np.isfinite(inp).all():
            raise InputDataError(f"step input must be finite at t = {self.time:.3f} s: "
                                 f"controls {list(controls)}, gusts {gusts}")
        if self._inst is None:
            raise FMUError("CoSimulation.reset(trim) must be called before stepping")
        status = self._raw_set(self._c, self._vr_in_p, 7, self._in_p)
        if status > WARNING:
            self._inst.check(status, "fmi2SetReal")
        status = self._raw_step(self._c, self.time, dt, 1)
        if status == DISCARD:  # FMI 2.0: the step was computed only part-way (diverged)
            reached = self._inst.last_successful_time()
            when = self.time + dt if reached is None else reached
            raise SimulationDiverged(
                f"simulation diverged at t = {when:.2f} s: "
                f"{self._inst.last_message('the FMU discarded the step')}",
                maneuver=self.name, time=when)
        if status > WARNING:
            self._inst.check(status, f"fmi2DoStep at t = {self.time:.3f} s")
        self.time += dt
        self._raw_get(self._c, self._vr_out_p, len(self._vr_out), self._out_p)
        y = self._out * self._factor
        if self._env_index.size:
            check = np.abs(y[self._env_index])
            if not (check <= self._env_limit).all():
                bad = int(np.argmax(~(check <= self._env_limit)))
                k = self._env_index[bad]
                raise SimulationDiverged(
                    f"simulation left the envelope at t = {self.time:.2f} s: "
                    f"{self.output_names[k]} = {y[k]:.4g} {self.output_units[k]} "
                    f"(limit +-{self._env_limit[bad]:g})", maneuver=self.name, time=self.time)
        return y

    def run(self, controls, gusts=None, *, dt: float,
            progress: Callable[[float], None] | None = None) -> "Flight":
        """Step through whole input histories: ``n`` steps of ``dt`` from the current time.

        Per step one fmi2SetReal (controls and gusts of the step), one fmi2DoStep and one
        fmi2GetReal straight into a preallocated array: about 3x the FMU's own cost, where
        :meth:`step` in a Python loop costs about 6x (measured:
        docs/notes/2026-11-24-campaign-holds-in-the-fmu.md). The envelope is checked on the
        whole history afterwards, with the same messages as :meth:`step`. A run that stops
        early (diverged or left the envelope) does not raise: its :attr:`Flight.failure` says
        why, so that the caller can check its own limits on the samples before it; after a
        failure, :meth:`reset` before flying again.

        Parameters
        ----------
        controls : array-like, shape (n, 4)
            Absolute ``lon lat col ped`` per step, % of travel (with the ``hold_*`` parameters
            on, the pilot command the FMU's holds add to).
        gusts : array-like, shape (n, 3), optional
            Wind ``u_gust v_gust w_gust`` along the body axes per step, ft/s.
        dt : float
            Step, s.
        progress : callable, optional
            Called with the fraction done (0-1) about 30 times.

        Returns
        -------
        Flight
            ``outputs`` (m + 1, n_outputs) at ``time + k dt`` (row 0 now) in analysis units,
            ``applied`` (m, 4) the controls the FMU applied over each step (its ``*_applied``
            outputs, %), with m = n unless the run failed at step m.
        """
        if self._inst is None:
            raise FMUError("CoSimulation.reset(trim) must be called before stepping")
        self.model.require(dict.fromkeys(APPLIED), "for CoSimulation.run")
        controls = np.asarray(controls, dtype=float)
        n = controls.shape[0] if controls.ndim == 2 else -1
        if controls.ndim != 2 or controls.shape[1] != 4:
            raise InputDataError(f"controls must have shape (n, 4) (lon lat col ped, %), got "
                                 f"{controls.shape}")
        inputs = np.zeros((n, 7))
        inputs[:, :4] = controls
        if gusts is not None:
            gusts = np.asarray(gusts, dtype=float)
            if gusts.shape != (n, 3):
                raise InputDataError(f"gusts must have shape ({n}, 3) (u v w, ft/s), got "
                                     f"{gusts.shape}")
            inputs[:, 4:] = gusts * self._gust_factor
        bad = ~np.isfinite(inputs).all(axis=1)
        if bad.any():
            k = int(np.argmax(bad))
            raise InputDataError(f"step input must be finite: step {k} (t = "
                                 f"{self.time + k * dt:.3f} s) has controls "
                                 f"{controls[k].tolist()}, gusts "
                                 f"{None if gusts is None else gusts[k].tolist()}")
        n_out = len(self._vr_out) + len(APPLIED)
        vr = np.concatenate([self._vr_out, self.model.vrs(APPLIED)]).astype(self._vr_out.dtype)
        raw = np.empty((n + 1, n_out))
        raw[0, :len(self._vr_out)] = self._out  # the outputs read by reset/step
        raw[0, len(self._vr_out):] = np.nan
        set_real, get_real, do_step = _address_functions(self._raw_set, self._raw_get,
                                                         self._raw_step)
        c, vr_in, vr_all = self._c, self._vr_in.ctypes.data, vr.ctypes.data
        in_address, in_stride = inputs.ctypes.data, inputs.strides[0]
        out_address, out_stride = raw.ctypes.data + raw.strides[0], raw.strides[0]
        t = self.time
        status = 0
        report = max(n // 30, 1)
        k = 0
        while k < n:
            stop = min(n, k + report)
            while k < stop:
                status = set_real(c, vr_in, 7, in_address)
                if status > WARNING:
                    self._inst.check(status, f"fmi2SetReal at t = {t:.3f} s")
                status = do_step(c, t, dt, 1)
                if status > WARNING:
                    break
                t += dt
                get_real(c, vr_all, n_out, out_address)
                in_address += in_stride
                out_address += out_stride
                k += 1
            if status > WARNING:
                break
            if progress is not None:
                progress(k / n)
        completed, failure = k, None
        if status == DISCARD:  # diverged: states non-finite part-way through step k
            reached = self._inst.last_successful_time()
            when = t + dt if reached is None else reached
            failure = SimulationDiverged(
                f"simulation diverged at t = {when:.2f} s: "
                f"{self._inst.last_message('the FMU discarded the step')}",
                maneuver=self.name, time=when)
        elif status > WARNING:
            self._inst.check(status, f"fmi2DoStep at t = {t:.3f} s")
        self.time = t
        outputs = raw[:completed + 1, :len(self._vr_out)] * self._factor
        applied = raw[1:completed + 1, len(self._vr_out):]
        if self._env_index.size and completed:
            check = np.abs(outputs[1:, self._env_index])
            outside = ~(check <= self._env_limit)
            rows = np.flatnonzero(outside.any(axis=1))
            if rows.size:
                j = int(rows[0]) + 1  # outputs row j = after step j - 1
                bad = int(np.argmax(outside[j - 1]))
                kk = self._env_index[bad]
                when = self.time - (completed - j) * dt
                failure = SimulationDiverged(
                    f"simulation left the envelope at t = {when:.2f} s: "
                    f"{self.output_names[kk]} = {outputs[j, kk]:.4g} {self.output_units[kk]} "
                    f"(limit +-{self._env_limit[bad]:g})", maneuver=self.name, time=when)
                completed = j - 1
                outputs, applied = outputs[:j], applied[:j - 1]
        if completed:
            self._out[:] = raw[completed, :len(self._vr_out)]
        return Flight(outputs=outputs, applied=applied, steps=completed, failure=failure)

    def get_state(self):
        """Snapshot of the FMU state (fmi2GetFMUstate) and time; restore with
        :meth:`set_state`, release with :meth:`free_state`."""
        if self._inst is None:
            raise FMUError("CoSimulation.reset(trim) must be called first")
        return self._inst.call("getFMUstate"), self.time

    def set_state(self, snapshot) -> None:
        state, time = snapshot
        self._inst.call("setFMUstate", state)
        self.time = time

    def free_state(self, snapshot) -> None:
        self._inst.call("freeFMUstate", snapshot[0])

    def close(self) -> None:
        """Free the FMU instance."""
        if self._inst is not None:
            self._inst.close()
            self._inst = None


@dataclass
class Flight:
    """The result of :meth:`CoSimulation.run`."""

    #: (steps + 1, n_outputs): outputs at the start time and after each step, analysis units.
    outputs: np.ndarray
    #: (steps, 4): ``lon lat col ped`` the FMU applied over each step, %.
    applied: np.ndarray
    #: Steps completed (the requested number unless the run failed).
    steps: int
    #: Why the run stopped at step ``steps`` (diverged or left the envelope), else None.
    failure: SimulationDiverged | None = None


def _address_functions(set_real, get_real, do_step):
    """fmi2SetReal/GetReal/DoStep at the same addresses, with array arguments declared as
    plain addresses (int), so that a loop steps through the rows of an array without creating
    a ctypes object per call."""
    address = ctypes.c_void_p
    prototypes = (ctypes.CFUNCTYPE(ctypes.c_int, address, address, ctypes.c_size_t, address),
                  ctypes.CFUNCTYPE(ctypes.c_int, address, address, ctypes.c_size_t, address),
                  ctypes.CFUNCTYPE(ctypes.c_int, address, ctypes.c_double, ctypes.c_double,
                                   ctypes.c_int))
    return [prototype(ctypes.cast(func, address).value)
            for prototype, func in zip(prototypes, (set_real, get_real, do_step))]


__all__ = ["CoSimulation", "Flight", "DEFAULT_OUTPUTS", "MEASUREMENTS", "EXTRA_OUTPUTS",
           "APPLIED", "DEFAULT_ENVELOPE"]
