"""Loading FMUs and talking to their instances through fmpy's low-level classes.

Everything that touches ctypes lives here. Hot paths (derivatives for trim and
linearisation, co-simulation steps) call the FMI functions of the shared library directly
with preallocated value-reference and value arrays, so a call costs a few microseconds and
no Python lists or dicts are built per call.
"""

from __future__ import annotations

import ctypes
import hashlib
import os
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path

import numpy as np

from sysid._paths import cache_dir
from sysid.errors import FMUError, InputDataError

_c_double_p = ctypes.POINTER(ctypes.c_double)
_c_uint_p = ctypes.POINTER(ctypes.c_uint)
_STATUS = ("OK", "warning", "discard", "error", "fatal", "pending")


@dataclass
class FMUModel:
    """A loaded FMU: its model description, extracted files and variable lookup.

    Attributes
    ----------
    path : Path
        The ``.fmu`` file.
    description : fmpy.model_description.ModelDescription
    unzip_dir : Path
        Folder the FMU was extracted to (cached by the file's hash).
    """

    path: Path
    description: object
    unzip_dir: Path
    variables: dict = field(default_factory=dict)

    @property
    def name(self) -> str:
        return self.description.modelName

    @property
    def guid(self) -> str:
        return self.description.guid

    @property
    def identifier(self) -> str:
        return self.description.coSimulation.modelIdentifier

    @cached_property
    def state_names(self) -> tuple[str, ...]:
        """Continuous states in the order of the FMU's state vector."""
        return tuple(d.variable.derivative.name for d in self.description.derivatives)

    @cached_property
    def input_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.description.modelVariables if v.causality == "input")

    @cached_property
    def output_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.description.modelVariables
                     if v.causality == "output")

    @cached_property
    def parameter_names(self) -> tuple[str, ...]:
        return tuple(v.name for v in self.description.modelVariables
                     if v.causality == "parameter")

    def variable(self, name: str):
        try:
            return self.variables[name]
        except KeyError:
            raise FMUError(f"{self.path.name} has no variable {name!r}") from None

    def vrs(self, names) -> np.ndarray:
        """Value references of ``names`` as a C-contiguous ``uint32`` array."""
        return np.ascontiguousarray([self.variable(n).valueReference for n in names],
                                    dtype=np.uint32)

    def unit(self, name: str) -> str:
        """The unit the FMU declares for ``name`` (``"1"`` when none)."""
        var = self.variable(name)
        unit = var.unit or (var.declaredType.unit if var.declaredType is not None else None)
        return unit or "1"

    def start(self, name: str) -> float:
        return float(self.variable(name).start)


def _file_digest(path: Path) -> str:
    digest = hashlib.sha256()
    with path.open("rb") as fh:
        for chunk in iter(lambda: fh.read(1 << 20), b""):
            digest.update(chunk)
    return digest.hexdigest()


def _extract(path: Path) -> Path:
    """Extract the FMU once into the cache (atomically: temp folder, then rename)."""
    target = cache_dir() / "unzipped" / _file_digest(path)[:16]
    if (target / "modelDescription.xml").is_file():
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".extract-", dir=target.parent))
    try:
        with zipfile.ZipFile(path) as zf:
            zf.extractall(tmp)
        try:
            os.replace(tmp, target)
        except OSError:  # another process was faster; use its copy
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    return target


_LOADED: dict[tuple[str, float], FMUModel] = {}


def load_fmu(path: str | os.PathLike | None = None) -> FMUModel:
    """Load an FMU (default: the truth helicopter, built on first use).

    Raises :class:`~sysid.errors.FMUError` with a one-line message if the file is missing,
    not an FMU archive or lacks a binary for this platform.
    """
    from fmpy import platform, read_model_description

    if path is None:
        from sysid.fmu._build import build_fmu

        path = build_fmu()
    path = Path(path)
    if not path.is_file():
        raise FMUError(f"FMU file {path} does not exist")
    key = (str(path.resolve()), path.stat().st_mtime)
    if key in _LOADED:
        return _LOADED[key]
    try:
        description = read_model_description(str(path), validate=False)
    except zipfile.BadZipFile:
        raise FMUError(f"{path} is not a valid FMU: not a zip archive (corrupted file?)") from None
    except Exception as exc:  # fmpy raises plain exceptions for broken descriptions
        message = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise FMUError(f"{path} is not a valid FMU: {message}") from None
    if description.fmiVersion != "2.0" or description.coSimulation is None \
            or description.modelExchange is None:
        raise FMUError(f"{path} must be an FMI 2.0 FMU with model exchange and co-simulation")
    try:
        unzip_dir = _extract(path)
    except (zipfile.BadZipFile, OSError) as exc:
        raise FMUError(f"{path} is not a valid FMU: cannot extract it ({exc})") from None
    identifier = description.coSimulation.modelIdentifier
    from fmpy import sharedLibraryExtension

    library = unzip_dir / "binaries" / platform / f"{identifier}{sharedLibraryExtension}"
    if not library.is_file():
        raise FMUError(f"{path} has no binary for platform {platform} "
                       f"(expected binaries/{platform}/{library.name})")
    model = FMUModel(path=path, description=description, unzip_dir=unzip_dir,
                     variables={v.name: v for v in description.modelVariables})
    _LOADED[key] = model
    return model


class _Logger:
    """Collects the FMU's log messages so that errors can be reported in one line."""

    def __init__(self):
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy.fmi1 import calloc, free

        self.messages: list[str] = []

        def log(env, instance, status, category, message):
            text = message.decode("utf-8", "replace") if message else ""
            if status >= 3:
                self.messages.append(text)

        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(log)
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:  # fmpy's native proxy formats the variadic message; optional
            from fmpy.logging import addLoggerProxy

            addLoggerProxy(ctypes.byref(self.callbacks))
        except Exception:
            pass

    def last(self, default: str) -> str:
        return self.messages[-1] if self.messages else default


class Instance:
    """One FMU instance (model exchange or co-simulation) with fast raw FMI calls.

    Parameters
    ----------
    model : FMUModel
    kind : {"me", "cs"}
    parameters : dict, optional
        Parameter values (SI, FMU names) set before initialisation.
    """

    def __init__(self, model: FMUModel, kind: str, parameters: dict | None = None,
                 name: str = "sysid"):
        from fmpy.fmi2 import FMU2Model, FMU2Slave

        if kind not in ("me", "cs"):
            raise ValueError(f"kind must be 'me' or 'cs', got {kind!r}")
        self.model = model
        self.kind = kind
        self.parameters = dict(parameters or {})
        self._logger = _Logger()
        cls = FMU2Model if kind == "me" else FMU2Slave
        try:
            self._fmu = cls(guid=model.guid, unzipDirectory=str(model.unzip_dir),
                            modelIdentifier=model.identifier, instanceName=name)
            self._fmu.instantiate(callbacks=self._logger.callbacks)
        except Exception as exc:
            raise FMUError(f"cannot instantiate {model.path.name}: "
                           f"{self._logger.last(str(exc).splitlines()[0])}") from None
        dll = self._fmu.dll
        self._c = self._fmu.component
        self._raw = {}
        for fname, args in {
            "fmi2SetReal": [ctypes.c_void_p, _c_uint_p, ctypes.c_size_t, _c_double_p],
            "fmi2GetReal": [ctypes.c_void_p, _c_uint_p, ctypes.c_size_t, _c_double_p],
            "fmi2DoStep": [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int],
            "fmi2SetContinuousStates": [ctypes.c_void_p, _c_double_p, ctypes.c_size_t],
            "fmi2GetDerivatives": [ctypes.c_void_p, _c_double_p, ctypes.c_size_t],
            "fmi2SetTime": [ctypes.c_void_p, ctypes.c_double],
        }.items():
            func = dll[fname]  # a fresh function object: fmpy's own stays untouched
            func.argtypes = args
            func.restype = ctypes.c_int
            self._raw[fname] = func
        self.time = 0.0
        self._initialised = False
        self._closed = False

    # -- checked wrappers ------------------------------------------------------------------

    def check(self, status: int, what: str) -> None:
        """Raise :class:`FMUError` with the FMU's last message if ``status`` > warning."""
        if status > 1:
            label = _STATUS[status] if 0 <= status < len(_STATUS) else str(status)
            raise FMUError(f"{what} failed ({label}): {self._logger.last('no message')}")

    def _call(self, method: str, *args, what: str | None = None):
        try:
            return getattr(self._fmu, method)(*args)
        except Exception as exc:
            if isinstance(exc, FMUError):
                raise
            raise FMUError(f"{what or method} failed: "
                           f"{self._logger.last(str(exc).splitlines()[0])}") from None

    def set_real(self, vrs: np.ndarray, values: np.ndarray) -> None:
        values = np.ascontiguousarray(values, dtype=np.float64)
        status = self._raw["fmi2SetReal"](self._c, vrs.ctypes.data_as(_c_uint_p), len(vrs),
                                          values.ctypes.data_as(_c_double_p))
        self.check(status, "fmi2SetReal")

    def get_real(self, vrs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(len(vrs)) if out is None else out
        status = self._raw["fmi2GetReal"](self._c, vrs.ctypes.data_as(_c_uint_p), len(vrs),
                                          out.ctypes.data_as(_c_double_p))
        self.check(status, "fmi2GetReal")
        return out

    def set_values(self, values: dict) -> None:
        """Set named values (SI, FMU names)."""
        if values:
            names = list(values)
            self.set_real(self.model.vrs(names), np.array([values[n] for n in names], float))

    def get_values(self, names) -> dict:
        names = list(names)
        return dict(zip(names, self.get_real(self.model.vrs(names)).tolist()))

    # -- life cycle ------------------------------------------------------------------------

    def initialize(self, start_values: dict | None = None, start_time: float = 0.0) -> None:
        """Set parameters and start values, run through initialisation mode.

        For model exchange the instance ends in continuous-time mode.
        """
        self._call("setupExperiment", None, start_time)
        self.set_values(self.parameters)
        self.set_values(start_values or {})
        self._call("enterInitializationMode")
        self._call("exitInitializationMode", what="initialisation")
        if self.kind == "me":
            while self._call("newDiscreteStates")[0]:
                pass
            self._call("enterContinuousTimeMode")
        self.time = start_time
        self._initialised = True

    def reset(self) -> None:
        self._call("reset")
        self._initialised = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self._initialised:
                self._fmu.terminate()
        except Exception:
            pass
        try:
            self._fmu.freeInstance()
        except Exception:
            pass

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        try:
            self.close()
        except Exception:
            pass


class DerivativeFunction:
    """The model-exchange right-hand side ``dx/dt = f(x, u)`` of an FMU, for trim and
    linearisation.

    Parameters
    ----------
    model : FMUModel
    parameters : dict, optional
        Parameter overrides (SI).
    inputs : sequence of str
        Names of the inputs passed to :meth:`__call__`, in order.
    """

    def __init__(self, model: FMUModel, parameters: dict | None = None,
                 inputs=("lon", "lat", "col", "ped")):
        self.model = model
        self.state_names = model.state_names
        self.input_names = tuple(inputs)
        self._inst = Instance(model, "me", parameters, name="sysid_derivatives")
        self._inst.initialize()
        self._input_vrs = model.vrs(self.input_names)
        self._n = len(self.state_names)
        self._dx = np.empty(self._n)
        self._dx_p = self._dx.ctypes.data_as(_c_double_p)

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """State derivatives (SI) for states ``x`` (SI, shape (n_states,)) and inputs ``u``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.shape != (self._n,):
            raise ValueError(f"x must have shape ({self._n},), got {x.shape}")
        inst = self._inst
        inst.set_real(self._input_vrs, u)
        inst.check(inst._raw["fmi2SetContinuousStates"](inst._c, x.ctypes.data_as(_c_double_p),
                                                          self._n), "fmi2SetContinuousStates")
        inst.check(inst._raw["fmi2GetDerivatives"](inst._c, self._dx_p, self._n),
                   "fmi2GetDerivatives")
        return self._dx.copy()

    def outputs(self, x: np.ndarray, u: np.ndarray, names) -> dict:
        """Values of the named variables (SI) at states ``x`` and inputs ``u``."""
        self(x, u)
        return self._inst.get_values(names)

    def close(self) -> None:
        self._inst.close()


def check_finite(values, what: str) -> None:
    """Raise :class:`InputDataError` naming ``what`` if ``values`` has NaN or infinities."""
    arr = np.asarray(values, dtype=float)
    if not np.all(np.isfinite(arr)):
        raise InputDataError(f"{what} must be finite, got {arr.tolist()}")
