"""The truth helicopter FMU: build, load, trim, linearise, simulate, step.

Public API
----------
build_fmu(force=False, model="helicopter") -> Path
    Build the FMU from ``fmus/`` with the machine's C compiler (cached by source hash).
load_fmu(path=None) -> FMUModel
    Load an FMU (default: the truth helicopter, built on first use).
trim(airspeed_kt=0.0, *, fmu=None, parameters=None) -> TrimResult
    Steady level zero-sideslip trim; ``TrimResult.start_values()`` initialises an instance.
linearize(trim, *, step=1e-5) -> Linearization
    Full and quasi-steady 6-DoF linear models (analysis units), named derivatives,
    eigenvalues.
simulate(inputs, trim, *, mode="cs"|"me", ...) -> xr.Dataset
    Open-loop time history (co-simulation RK4 or model-exchange CVode).
CoSimulation
    Fast stepping API for closed-loop campaigns (``reset``, ``step``, ``close``).

SI inside the FMU, analysis units (ft/s, deg/s, deg, ft/s^2, %) outside; conversions use the
units the FMU declares.
"""

from sysid.fmi.build import build_fmu, build_model_fmu, read_model
from sysid.fmi.runtime import DerivativeFunction, FMUModel, Instance
from sysid.truth.cosim import (DEFAULT_ENVELOPE, DEFAULT_OUTPUTS, MEASUREMENTS, CoSimulation)
from sysid.truth.fmu import load_fmu
from sysid.truth.linearize import Linearization, jacobians_si, linearize, residualize
from sysid.truth.simulate import simulate
from sysid.truth.trim import TrimResult, trim

__all__ = [
    "build_fmu", "build_model_fmu", "read_model", "load_fmu", "FMUModel", "Instance",
    "DerivativeFunction", "trim", "TrimResult", "linearize", "Linearization", "jacobians_si",
    "residualize", "simulate", "CoSimulation", "DEFAULT_OUTPUTS", "MEASUREMENTS",
    "DEFAULT_ENVELOPE",
]
