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
import re
import shutil
import tempfile
import zipfile
from dataclasses import dataclass, field
from functools import cached_property
from pathlib import Path
from xml.etree import ElementTree

import numpy as np

from sysid.core.paths import cache_dir, prune_cache, touch
from sysid.core.errors import FMUError, InputDataError

# fmpy is imported inside the functions that load or run an FMU: it loads native helper
# libraries (0.14 s), which the modules that only read results never need.

#: ctypes pointer types of the FMI value arrays (for callers of :attr:`Instance.functions`).
c_double_p = ctypes.POINTER(ctypes.c_double)
c_uint_p = ctypes.POINTER(ctypes.c_uint)
#: fmi2Status names by value (FMI 2.0: fmi2OK = 0 ... fmi2Pending = 5).
STATUS = ("OK", "warning", "discard", "error", "fatal", "pending")
#: fmi2Warning: the largest status that is not a failure.
WARNING = 1
#: fmi2Discard: the FMU could not complete the call (a step computed only up to
#: fmi2LastSuccessfulTime, a state outside its domain); our FMUs return it when the
#: simulation diverges, so it maps to SimulationDiverged.
DISCARD = 2
#: fmi2StatusKind fmi2LastSuccessfulTime (for fmi2GetRealStatus).
LAST_SUCCESSFUL_TIME = 2


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

    def require(self, names, purpose: str) -> None:
        """Raise :class:`FMUError` listing every one of ``names`` the FMU does not have."""
        missing = [n for n in names if n not in self.variables]
        if missing:
            raise FMUError(f"{self.path} cannot be used {purpose}: it has no variable(s) "
                           f"{missing} (model {self.name!r}; is it the helicopter FMU?)")

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


# --------------------------------------------------------------------------------------------
# archive safety: everything below is checked on the zip directory and modelDescription.xml
# *before* fmpy reads the archive or anything is extracted


#: Largest total uncompressed size (bytes) an FMU archive may declare (zip-bomb guard). The
#: truth helicopter is well below 1 MB; zipfile never inflates a member beyond the size its
#: directory entry declares, so this bounds what extraction can write.
MAX_ARCHIVE_BYTES = 1 << 30
#: Largest modelDescription.xml read into memory, bytes.
MAX_DESCRIPTION_BYTES = 64 << 20
#: FMI versions load_fmu runs (FMI 2.0 model exchange + co-simulation); inspect_archive
#: also checks FMI 3.0 archives when asked (the exported-FMU checks run those through fmpy).
SUPPORTED_FMI_VERSIONS = ("2.0",)
#: Leading bytes of a shared library, by extension (ELF, Mach-O thin/fat, PE).
_LIBRARY_MAGIC = {
    ".so": (b"\x7fELF",),
    ".dylib": (b"\xcf\xfa\xed\xfe", b"\xce\xfa\xed\xfe", b"\xca\xfe\xba\xbe"),
    ".dll": (b"MZ",),
}
_C_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _unsafe_member(info: zipfile.ZipInfo) -> str | None:
    """Why ``info`` must not be extracted (absolute path, ``..``, symlink...), or None."""
    name = info.filename
    parts = re.split(r"[/\\]", name)
    if name.startswith(("/", "\\")) or re.match(r"[A-Za-z]:", name):
        return "has an absolute path"
    if ".." in parts:
        return "has a '..' path component (path traversal)"
    if "\0" in name:
        return "has a NUL byte in its name"
    mode = (info.external_attr >> 16) & 0o170000
    if mode == 0o120000:
        return "is a symbolic link"
    if mode not in (0, 0o100000, 0o040000):
        return "is a special file (device, FIFO or socket)"
    if info.flag_bits & 0x1:
        return "is encrypted"
    return None


def inspect_archive(path: str | os.PathLike, *, interfaces=("coSimulation", "modelExchange"),
                    check_binary: bool = True,
                    fmi_versions: tuple[str, ...] = SUPPORTED_FMI_VERSIONS) -> dict:
    """Check an FMU archive without extracting it; raise FMUError on anything hostile.

    Refused, each with a one-line :class:`~sysid.core.errors.FMUError` naming the archive and the
    problem: a file that is not a zip archive; members with absolute paths, ``..``
    components, symbolic links, special files or encryption; duplicated member names; a total
    declared uncompressed size above :data:`MAX_ARCHIVE_BYTES` (zip bomb); a missing, oversized
    or malformed ``modelDescription.xml``; an FMI version other than 2.0; a missing GUID,
    a missing interface in ``interfaces`` or a model identifier that is not a C identifier;
    and (``check_binary``) a missing binary ``binaries/<platform>/<identifier><ext>`` for
    each interface, or one that is not a shared library of this platform.

    Returns ``{"fmi_version", "guid", "model_name", "identifiers": {interface: identifier},
    "members": [names]}``.
    """
    # deferred: see above
    from fmpy import platform as fmi2_platform, platform_tuple, sharedLibraryExtension

    path = Path(path)
    where = f"FMU {path}"
    if not path.is_file():
        raise FMUError(f"FMU file {path} does not exist")
    try:
        zf = zipfile.ZipFile(path)
    except (zipfile.BadZipFile, zipfile.LargeZipFile, OSError, ValueError, EOFError,
            NotImplementedError) as exc:  # NotImplementedError: a corrupted version field
        raise FMUError(f"{where} is not a valid FMU: not a readable zip archive "
                       f"({type(exc).__name__}: {exc})") from None
    with zf:
        infos = zf.infolist()
        names = [i.filename for i in infos]
        seen = set()
        total = 0
        for info in infos:
            problem = _unsafe_member(info)
            if problem:
                raise FMUError(f"{where} refused: archive member {info.filename!r} {problem}")
            if info.filename in seen:
                raise FMUError(f"{where} refused: archive member {info.filename!r} appears "
                               "twice")
            seen.add(info.filename)
            total += info.file_size
        if total > MAX_ARCHIVE_BYTES:
            raise FMUError(f"{where} refused: its members declare {total} bytes uncompressed, "
                           f"more than the limit of {MAX_ARCHIVE_BYTES} bytes (zip bomb?)")
        if "modelDescription.xml" not in seen:
            raise FMUError(f"{where} is not a valid FMU: no modelDescription.xml at the top "
                           "of the archive")
        md_info = zf.getinfo("modelDescription.xml")
        if md_info.file_size > MAX_DESCRIPTION_BYTES:
            raise FMUError(f"{where} refused: modelDescription.xml declares "
                           f"{md_info.file_size} bytes (limit {MAX_DESCRIPTION_BYTES})")
        try:
            text = zf.read(md_info)
        except Exception as exc:  # bad CRC, unsupported compression, truncated data
            raise FMUError(f"{where} is not a valid FMU: cannot read modelDescription.xml "
                           f"({type(exc).__name__}: {exc})") from None
        if b"<!DOCTYPE" in text or b"<!ENTITY" in text:
            raise FMUError(f"{where} refused: modelDescription.xml has a DOCTYPE/ENTITY "
                           "declaration (not used by FMI; entity expansion is refused)")
        try:
            root = ElementTree.fromstring(text)
        except ElementTree.ParseError as exc:
            raise FMUError(f"{where} is not a valid FMU: modelDescription.xml is not "
                           f"well-formed XML ({exc})") from None
        if root.tag != "fmiModelDescription":
            raise FMUError(f"{where} is not a valid FMU: modelDescription.xml has root element "
                           f"<{root.tag}>, expected <fmiModelDescription>")
        version = root.get("fmiVersion", "")
        if version not in fmi_versions:
            raise FMUError(f"{where}: FMI version {version or '(missing)'!r} is not supported; "
                           f"expected an FMI {' or '.join(fmi_versions)} FMU")
        # FMI 3.0 calls the GUID instantiationToken and names binary folders by tuple
        guid = root.get("guid" if version == "2.0" else "instantiationToken", "")
        # binary folders: FMI 2 names them by platform (linux64), FMI 3 by tuple (x86_64-linux)
        platform = fmi2_platform if version == "2.0" else platform_tuple
        if not guid.strip():
            raise FMUError(f"{where} is not a valid FMU: modelDescription.xml has no "
                           f"{'guid' if version == '2.0' else 'instantiationToken'}")
        identifiers = {}
        for kind in interfaces:
            tag = kind[0].upper() + kind[1:]
            element = root.find(tag)
            if element is None:
                raise FMUError(f"{where}: modelDescription.xml has no <{tag}> element; "
                               f"expected an FMI {version} FMU with {' and '.join(interfaces)}")
            identifier = element.get("modelIdentifier", "")
            if not _C_IDENTIFIER.fullmatch(identifier):
                raise FMUError(f"{where}: <{tag}> modelIdentifier {identifier!r} is not a C "
                               "identifier")
            identifiers[kind] = identifier
        if check_binary:
            has_sources = any(n.startswith("sources/") and n.endswith(".c") for n in names)
            magic = _LIBRARY_MAGIC.get(sharedLibraryExtension, ())
            for kind, identifier in identifiers.items():
                binary = f"binaries/{platform}/{identifier}{sharedLibraryExtension}"
                if binary not in seen:
                    hint = (" (it carries C sources, but sysid does not compile source FMUs: "
                            "build a binary with fmpy first)" if has_sources else "")
                    raise FMUError(f"{where} has no binary for platform {platform} "
                                   f"(expected {binary}){hint}")
                try:
                    with zf.open(binary) as fh:
                        head = fh.read(4)
                except Exception as exc:
                    raise FMUError(f"{where}: cannot read {binary} "
                                   f"({type(exc).__name__}: {exc})") from None
                if magic and not head.startswith(magic):
                    raise FMUError(f"{where}: {binary} is not a shared library for "
                                   f"{platform} (leading bytes {head!r})")
    return {"fmi_version": version, "guid": guid, "model_name": root.get("modelName", ""),
            "identifiers": identifiers, "members": names}


def _extract(path: Path) -> Path:
    """Extract the FMU once into the cache (atomically: temp folder, then rename).

    Call :func:`inspect_archive` first: only archives whose members are all safe reach here.
    """
    target = cache_dir() / "unzipped" / _file_digest(path)[:16]
    if (target / "modelDescription.xml").is_file():
        touch(target)  # recently used: pruned last
        return target
    target.parent.mkdir(parents=True, exist_ok=True)
    tmp = Path(tempfile.mkdtemp(prefix=".extract-", dir=target.parent))
    try:
        with zipfile.ZipFile(path) as zf:
            for info in zf.infolist():
                problem = _unsafe_member(info)  # the archive may have changed since inspection
                if problem:
                    raise FMUError(f"FMU {path} refused: archive member {info.filename!r} "
                                   f"{problem}")
            zf.extractall(tmp)
        try:
            os.replace(tmp, target)
        except OSError:  # another process was faster; use its copy
            shutil.rmtree(tmp, ignore_errors=True)
    except BaseException:
        shutil.rmtree(tmp, ignore_errors=True)
        raise
    prune_cache(target.parent, keep=target)  # capped: SYSID_CACHE_MAX_BYTES (core.paths)
    return target


_LOADED: dict[tuple[str, float], FMUModel] = {}


def load_fmu(path: str | os.PathLike) -> FMUModel:
    """Load an FMU (:func:`sysid.truth.load_fmu` defaults to the truth helicopter).

    The archive is checked by :func:`inspect_archive` before fmpy reads it or anything is
    extracted. Raises :class:`~sysid.core.errors.FMUError` with a one-line message naming the file
    if it is missing, not an FMU archive, hostile (path traversal, symlinks, zip bomb), not
    FMI 2.0 with both interfaces, or lacks a binary for this platform.
    """
    from fmpy import platform, read_model_description, sharedLibraryExtension  # deferred: fmpy

    path = Path(path)
    if not path.is_file():
        raise FMUError(f"FMU file {path} does not exist")
    key = (str(path.resolve()), path.stat().st_mtime)
    if key in _LOADED:
        return _LOADED[key]
    inspect_archive(path)
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
        from fmpy.fmi2 import (fmi2CallbackAllocateMemoryTYPE,  # deferred: fmpy
                               fmi2CallbackFreeMemoryTYPE,
                               fmi2CallbackFunctions, fmi2CallbackLoggerTYPE)
        from fmpy.fmi1 import calloc, free  # deferred: fmpy

        self.messages: list[str] = []

        def log(env, instance, status, category, message):
            text = message.decode("utf-8", "replace") if message else ""
            if status > WARNING:
                self.messages.append(text)

        self.callbacks = fmi2CallbackFunctions()
        self.callbacks.logger = fmi2CallbackLoggerTYPE(log)
        self.callbacks.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
        self.callbacks.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
        try:  # fmpy's native proxy formats the variadic message; optional
            from fmpy.logging import addLoggerProxy  # deferred: fmpy

            addLoggerProxy(ctypes.byref(self.callbacks))
        except Exception:
            pass

    def last(self, default: str) -> str:
        return self.messages[-1] if self.messages else default


class ReleasedOnExit:
    """Context-manager and finaliser behaviour of objects holding an FMU instance: leaving a
    ``with`` block or garbage collection calls the subclass's ``close()``, which must be
    idempotent."""

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def __del__(self):
        # The interpreter may be shutting down; a finaliser must not raise.
        try:
            self.close()
        except Exception:
            pass


class Instance(ReleasedOnExit):
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
        from fmpy.fmi2 import FMU2Model, FMU2Slave  # deferred: fmpy

        if kind not in ("me", "cs"):
            raise ValueError(f"kind must be 'me' or 'cs', got {kind!r}")
        self.model = model
        self.kind = kind
        self.parameters = dict(parameters or {})
        self._logger = _Logger()
        cls = FMU2Model if kind == "me" else FMU2Slave
        try:
            #: the fmpy FMU2Model / FMU2Slave object (its public methods)
            self.fmu = cls(guid=model.guid, unzipDirectory=str(model.unzip_dir),
                           modelIdentifier=model.identifier, instanceName=name)
            self.fmu.instantiate(callbacks=self._logger.callbacks)
        except Exception as exc:
            raise FMUError(f"cannot instantiate {model.path.name}: "
                           f"{self._logger.last(str(exc).splitlines()[0])}") from None
        dll = self.fmu.dll
        #: the fmi2Component handle, first argument of every function in :attr:`functions`
        self.component = self.fmu.component
        #: Raw FMI functions for hot loops (they return the fmi2Status; check it with
        #: :meth:`check`): fmi2SetReal, fmi2GetReal, fmi2DoStep, fmi2SetContinuousStates,
        #: fmi2GetDerivatives, fmi2SetTime.
        self.functions = {}
        for fname, args in {
            "fmi2SetReal": [ctypes.c_void_p, c_uint_p, ctypes.c_size_t, c_double_p],
            "fmi2GetReal": [ctypes.c_void_p, c_uint_p, ctypes.c_size_t, c_double_p],
            "fmi2DoStep": [ctypes.c_void_p, ctypes.c_double, ctypes.c_double, ctypes.c_int],
            "fmi2SetContinuousStates": [ctypes.c_void_p, c_double_p, ctypes.c_size_t],
            "fmi2GetDerivatives": [ctypes.c_void_p, c_double_p, ctypes.c_size_t],
            "fmi2SetTime": [ctypes.c_void_p, ctypes.c_double],
        }.items():
            func = dll[fname]  # a fresh function object: fmpy's own stays untouched
            func.argtypes = args
            func.restype = ctypes.c_int
            self.functions[fname] = func
        self.time = 0.0
        self._initialised = False
        self._closed = False

    # -- checked wrappers ------------------------------------------------------------------

    def check(self, status: int, what: str) -> None:
        """Raise :class:`FMUError` with the FMU's last message if ``status`` > warning."""
        if status > WARNING:
            label = STATUS[status] if 0 <= status < len(STATUS) else str(status)
            raise FMUError(f"{what} failed ({label}): {self.last_message('no message')}")

    def last_message(self, default: str = "") -> str:
        """The last message the FMU logged with a status above warning."""
        return self._logger.last(default)

    def last_successful_time(self) -> float | None:
        """fmi2GetRealStatus(fmi2LastSuccessfulTime) after a discarded step (co-simulation),
        s; None where the FMU cannot say."""
        if self.kind != "cs":
            return None
        try:
            return float(self.fmu.getRealStatus(LAST_SUCCESSFUL_TIME))
        except Exception:  # the FMU does not provide the status (fmi2Discard/Error)
            return None

    def call(self, method: str, *args, what: str | None = None):
        """Call a method of :attr:`fmu` (fmpy); an FMI failure becomes :class:`FMUError`
        with the FMU's last message."""
        try:
            return getattr(self.fmu, method)(*args)
        except Exception as exc:
            if isinstance(exc, FMUError):
                raise
            raise FMUError(f"{what or method} failed: "
                           f"{self._logger.last(str(exc).splitlines()[0])}") from None

    def set_real(self, vrs: np.ndarray, values: np.ndarray) -> None:
        values = np.ascontiguousarray(values, dtype=np.float64)
        status = self.functions["fmi2SetReal"](self.component, vrs.ctypes.data_as(c_uint_p), len(vrs),
                                          values.ctypes.data_as(c_double_p))
        self.check(status, "fmi2SetReal")

    def get_real(self, vrs: np.ndarray, out: np.ndarray | None = None) -> np.ndarray:
        out = np.empty(len(vrs)) if out is None else out
        status = self.functions["fmi2GetReal"](self.component, vrs.ctypes.data_as(c_uint_p), len(vrs),
                                          out.ctypes.data_as(c_double_p))
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
        self.call("setupExperiment", None, start_time)
        self.set_values(self.parameters)
        self.set_values(start_values or {})
        self.call("enterInitializationMode")
        self.call("exitInitializationMode", what="initialisation")
        if self.kind == "me":
            while self.call("newDiscreteStates")[0]:
                pass
            self.call("enterContinuousTimeMode")
        self.time = start_time
        self._initialised = True

    def reset(self) -> None:
        self.call("reset")
        self._initialised = False

    def close(self) -> None:
        if self._closed:
            return
        self._closed = True
        try:
            if self._initialised:
                self.fmu.terminate()
        except Exception:
            pass
        try:
            self.fmu.freeInstance()
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
        self._dx_p = self._dx.ctypes.data_as(c_double_p)

    def __call__(self, x: np.ndarray, u: np.ndarray) -> np.ndarray:
        """State derivatives (SI) for states ``x`` (SI, shape (n_states,)) and inputs ``u``."""
        x = np.ascontiguousarray(x, dtype=np.float64)
        if x.shape != (self._n,):
            raise ValueError(f"x must have shape ({self._n},), got {x.shape}")
        inst = self._inst
        inst.set_real(self._input_vrs, u)
        inst.check(inst.functions["fmi2SetContinuousStates"](
            inst.component, x.ctypes.data_as(c_double_p), self._n), "fmi2SetContinuousStates")
        inst.check(inst.functions["fmi2GetDerivatives"](inst.component, self._dx_p, self._n),
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
