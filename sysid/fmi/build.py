"""Build FMUs from the C sources in ``fmus/``: generate, compile, package, cache.

One source of truth for the variables: each model folder holds ``variables.csv`` (name, kind,
unit, display unit, start, nominal, description) and ``model.toml`` (identifier, description,
source files). From them this module generates, at build time, both the
``modelDescription.xml`` and the C header ``model_variables.h`` with the value references,
start values and variable kinds, so the two can never disagree.

The shared library is compiled with the machine's C compiler (``$CC``, else ``cc``, ``gcc``
or ``clang`` on the ``PATH``) directly, without a build system. The FMU is cached under
``sysid.core.paths.cache_dir() / "fmus"`` by a hash of every source file, the FMI headers and the
compiler flags, and written atomically: a failed build leaves nothing in the cache.
"""

from __future__ import annotations

import csv
import hashlib
import os
import shutil
import sys
import tempfile
import tomllib
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path

import sysid
from sysid.core.errors import FMUError
from sysid.core.native import find_compiler, run_compiler
from sysid.core.paths import cache_dir, fmu_sources_dir
from sysid.core.units import DERIVATIVE_UNIT, DISPLAY_UNITS, UNITS
from sysid.core.util import atomic_path
from sysid.fmi.description import (FMI_VERSIONS, FmuDescription, ScalarVariable,
                                   UnitDefinition, boilerplate_sources, build_description,
                                   model_description, variables_header)

#: Bump when the generated files change shape, so that cached FMUs are rebuilt
#: (2: one generator, sysid.fmi.description, for the truth and the exported FMUs;
#: 3: the version-independent core fmu_core.c, FMI 3.0).
GENERATOR_VERSION = "3"

#: Compiler flags (part of the cache key). -fno-math-errno lets sqrt compile to one
#: instruction; hidden visibility exports only the FMI functions (FMI2_Export).
CFLAGS = ("-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-fno-math-errno")

#: The FMI headers shipped with fmpy, per FMI version, copied into the FMU's sources/.
FMI_HEADERS = {2: ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h"),
               3: ("fmi3Functions.h", "fmi3FunctionTypes.h", "fmi3PlatformTypes.h")}
#: Shared boilerplate headers (fmus/common) every FMU includes.
COMMON_HEADERS = ("fmu_model.h",)

KINDS = ("parameter", "input", "state", "output")


@dataclass(frozen=True)
class Variable:
    """One Real variable of a model, as listed in ``variables.csv`` (or derived from it)."""

    name: str
    kind: str  #: parameter, input, state, derivative, output
    unit: str
    display_unit: str
    start: float | None
    nominal: float | None
    description: str
    vr: int
    state_of: str | None = None  #: for derivatives: the state's name

    @property
    def causality(self) -> str:
        return {"parameter": "parameter", "input": "input", "state": "output",
                "derivative": "local", "output": "output"}[self.kind]

    @property
    def variability(self) -> str:
        return "fixed" if self.kind == "parameter" else "continuous"

    @property
    def initial(self) -> str | None:
        return {"parameter": "exact", "input": None, "state": "exact",
                "derivative": None, "output": "calculated"}[self.kind]


@dataclass(frozen=True)
class ModelSources:
    """A model folder: metadata, variables and the files that make its FMU."""

    folder: Path
    identifier: str
    name: str
    description: str
    sources: tuple[str, ...]
    headers: tuple[str, ...]
    experiment: dict
    variables: tuple[Variable, ...]

    @property
    def states(self) -> tuple[Variable, ...]:
        return tuple(v for v in self.variables if v.kind == "state")


def _number(text: str, what: str) -> float | None:
    text = text.strip()
    if not text:
        return None
    try:
        return float(text)
    except ValueError:
        raise FMUError(f"{what}: {text!r} is not a number") from None


def read_model(folder: str | os.PathLike) -> ModelSources:
    """Read ``model.toml`` and ``variables.csv`` of a model folder and assign value references.

    States get the value references ``0..n-1`` (the state vector), their derivatives
    ``der(x)`` ``n..2n-1``, then the other variables in table order.
    """
    folder = Path(folder)
    meta_path, table_path = folder / "model.toml", folder / "variables.csv"
    for path in (meta_path, table_path):
        if not path.is_file():
            raise FMUError(f"model folder {folder} has no {path.name}")
    try:
        meta = tomllib.loads(meta_path.read_text())
        model = meta["model"]
    except (tomllib.TOMLDecodeError, KeyError) as exc:
        raise FMUError(f"{meta_path}: invalid model metadata ({exc})") from None
    with table_path.open(newline="") as fh:
        rows = list(csv.DictReader(fh))
    required = {"name", "kind", "unit", "display_unit", "start", "nominal", "description"}
    if not rows or not required <= set(rows[0]):
        raise FMUError(f"{table_path}: expected the columns {sorted(required)}")
    seen: set[str] = set()
    for line, row in enumerate(rows, start=2):
        where = f"{table_path}:{line}"
        name, kind, unit = row["name"].strip(), row["kind"].strip(), row["unit"].strip()
        if not name.isidentifier() or name in seen:
            raise FMUError(f"{where}: variable name {name!r} is not a new C identifier")
        seen.add(name)
        if kind not in KINDS:
            raise FMUError(f"{where}: kind {kind!r} is not one of {KINDS}")
        if unit not in UNITS:
            raise FMUError(f"{where}: unit {unit!r} is not defined; known: {sorted(UNITS)}")
        display = row["display_unit"].strip()
        if display and display not in DISPLAY_UNITS.get(unit, ()):
            raise FMUError(f"{where}: {display!r} is not a display unit of {unit!r}")
        if kind != "output" and _number(row["start"], where) is None:
            raise FMUError(f"{where}: {kind} {name} needs a start value")
        if kind == "state" and unit not in DERIVATIVE_UNIT:
            raise FMUError(f"{where}: no derivative unit known for state unit {unit!r}")

    states = [r for r in rows if r["kind"].strip() == "state"]
    others = [r for r in rows if r["kind"].strip() != "state"]
    variables: list[Variable] = []

    def make(row, vr):
        return Variable(
            name=row["name"].strip(), kind=row["kind"].strip(), unit=row["unit"].strip(),
            display_unit=row["display_unit"].strip(),
            start=_number(row["start"], row["name"]), nominal=_number(row["nominal"], row["name"]),
            description=row["description"].strip(), vr=vr)

    for k, row in enumerate(states):
        variables.append(make(row, k))
    for k, state in enumerate(list(variables)):
        unit = DERIVATIVE_UNIT[state.unit]
        variables.append(Variable(
            name=f"der({state.name})", kind="derivative", unit=unit,
            display_unit=DISPLAY_UNITS[unit][0] if state.display_unit else "", start=None, nominal=None,
            description=f"time derivative of {state.name}", vr=len(states) + k,
            state_of=state.name))
    for k, row in enumerate(others):
        variables.append(make(row, 2 * len(states) + k))

    experiment = meta.get("default_experiment", {})
    return ModelSources(
        folder=folder, identifier=model["identifier"], name=model.get("name", model["identifier"]),
        description=model.get("description", ""), sources=tuple(model.get("sources", ["model.c"])),
        headers=tuple(model.get("headers", ["model.h"])), experiment=experiment,
        variables=tuple(variables))


# ------------------------------------------------------------------------------------------
# code generation

def _c_name(name: str) -> str:
    return name.replace("der(", "der_").replace(")", "")


def describe(model: ModelSources, guid: str, version: str = sysid.__version__,
             fmi_version: int = 2) -> FmuDescription:
    """The FMU of a model folder in the data model of :mod:`sysid.fmi.description`."""
    variables = tuple(
        ScalarVariable(name=v.name, c_name=_c_name(v.name), value_reference=v.vr, kind=v.kind,
                       causality=v.causality, variability=v.variability, initial=v.initial,
                       description=v.description, unit=v.unit,
                       display_unit=v.display_unit or None, start=v.start,
                       nominal=v.nominal if v.kind == "state" else None,
                       derivative_of=v.state_of)
        for v in model.variables)
    experiment = tuple((key, float(model.experiment[key])) for key in ("start", "stop", "step")
                       if key in model.experiment)
    return FmuDescription(
        model_name=model.name, identifier=model.identifier, guid=guid,
        description=model.description, generation_tool=f"sysid {version}",
        source_files=(*boilerplate_sources(fmi_version), *model.sources), variables=variables,
        units=tuple(UnitDefinition.of(u) for u in sorted({v.unit for v in model.variables})),
        experiment=experiment)


def generate_header(model: ModelSources, guid: str) -> str:
    """The C header ``model_variables.h``: value references and variable tables."""
    return variables_header(describe(model, guid))


def generate_model_description(model: ModelSources, guid: str, version: str,
                               fmi_version: int = 2) -> str:
    """The ``modelDescription.xml`` (FMI 2.0 or 3.0, model exchange and co-simulation)."""
    return model_description(describe(model, guid, version, fmi_version), fmi_version)


# ------------------------------------------------------------------------------------------
# compiler, hashing, packaging

def fmi_header_dir() -> Path:
    """Folder of the FMI 2.0 and 3.0 C headers installed with fmpy."""
    import fmpy  # deferred: fmpy (native helpers, 0.14 s), needed only to build

    folder = Path(fmpy.__file__).parent / "c-code"
    missing = [h for v in FMI_VERSIONS for h in FMI_HEADERS[v] if not (folder / h).is_file()]
    if missing:
        raise FMUError(f"FMI headers {missing} not found in {folder}; reinstall fmpy")
    return folder


def platform_folder(fmi_version: int = 2) -> tuple[str, str]:
    """Binaries folder name (FMI 2.0: e.g. ``linux64``; FMI 3.0: the platform tuple, e.g.
    ``x86_64-linux``) and shared-library extension of this machine."""
    from fmpy import platform, platform_tuple, sharedLibraryExtension  # deferred: fmpy

    return (platform if fmi_version == 2 else platform_tuple), sharedLibraryExtension


def _source_files(model: ModelSources, common: Path, fmi_version: int = 2) -> list[Path]:
    files = [common / n for n in (*boilerplate_sources(fmi_version), *COMMON_HEADERS)]
    files += [model.folder / name for name in (*model.sources, *model.headers)]
    for path in files:
        if not path.is_file():
            raise FMUError(f"FMU source file {path} is missing")
    return files


def source_hash(model: ModelSources, common: Path, fmi_version: int = 2) -> str:
    """SHA-256 over the sources, the variable table, the FMI headers and the flags."""
    digest = hashlib.sha256()
    digest.update(f"generator {GENERATOR_VERSION}\nflags {' '.join(CFLAGS)}\n"
                  f"fmi {fmi_version}\n".encode())
    headers = fmi_header_dir()
    inputs = [*_source_files(model, common, fmi_version), model.folder / "variables.csv",
              model.folder / "model.toml", *(headers / h for h in FMI_HEADERS[fmi_version])]
    for path in inputs:
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _guid(digest: str) -> str:
    return "{" + str(uuid.UUID(hex=digest[:32])) + "}"


def _compile(model: ModelSources, common: Path, workdir: Path,
             fmi_version: int = 2) -> tuple[Path, Path]:
    """Generate the header, compile the shared library; return (library, sources dir)."""
    src = workdir / "sources"
    src.mkdir()
    for path in _source_files(model, common, fmi_version):
        shutil.copy2(path, src / path.name)
    for name in FMI_HEADERS[fmi_version]:
        shutil.copy2(fmi_header_dir() / name, src / name)
    digest = source_hash(model, common, fmi_version)
    desc = describe(model, _guid(digest), sysid.__version__, fmi_version)
    (src / "model_variables.h").write_text(variables_header(desc))
    if fmi_version == 3:
        (src / "buildDescription.xml").write_text(build_description(desc))
    _, ext = platform_folder(fmi_version)
    library = workdir / f"{model.identifier}{ext}"
    c_files = [src / n for n in desc.source_files]
    compile_shared_library(c_files, src, library, what=f"the {model.identifier} FMU",
                           log=cache_dir() / f"build-{model.identifier}.log")
    return library, src


def compile_shared_library(c_files, include_dir: Path, library: Path, *, what: str,
                           log: Path | None = None) -> Path:
    """Compile ``c_files`` into the shared library ``library`` with the machine's C compiler
    (``$CC`` or cc/gcc/clang) and :data:`CFLAGS`.

    Raises :class:`FMUError` with the compiler's first error line (and writes the full
    command and output to ``log`` when given); no compiler is one clear line too.
    """
    flags = [f for f in CFLAGS if not (sys.platform == "win32" and f == "-fPIC")]
    return run_compiler(find_compiler(), [*flags, "-I", str(include_dir),
                                          *(str(f) for f in c_files), "-o", str(library),
                                          "-lm"], library, what=what, log=log)


def fmu_cache_path(model: ModelSources, common: Path, fmi_version: int = 2) -> Path:
    """Where the FMU built from these sources is (or will be) cached."""
    suffix = "" if fmi_version == 2 else f"-fmi{fmi_version}"
    digest = source_hash(model, common, fmi_version)[:16]
    return cache_dir() / "fmus" / f"{model.identifier}{suffix}-{digest}.fmu"


def _check_version(fmi_version) -> int:
    if fmi_version not in FMI_VERSIONS:
        raise FMUError(f"fmi_version must be one of {FMI_VERSIONS}, got {fmi_version!r}")
    return int(fmi_version)


def build_model_fmu(model_folder: str | os.PathLike, *, force: bool = False,
                    common_folder: str | os.PathLike | None = None,
                    fmi_version: int = 2) -> Path:
    """Build (or reuse from the cache) the FMU of the model in ``model_folder``.

    ``model_folder`` holds ``model.toml``, ``variables.csv``, ``model.h`` and the C sources;
    ``common_folder`` defaults to ``fmus/common``; ``fmi_version`` 2 (default) or 3 (model
    exchange and co-simulation either way). Returns the path of the cached ``.fmu``.
    Raises :class:`~sysid.core.errors.FMUError` naming the problem (no compiler, compile error...).
    """
    fmi_version = _check_version(fmi_version)
    model = read_model(model_folder)
    common = Path(common_folder) if common_folder else fmu_sources_dir() / "common"
    target = fmu_cache_path(model, common, fmi_version)
    if target.is_file() and not force:
        return target
    digest = source_hash(model, common, fmi_version)
    guid = _guid(digest)
    with tempfile.TemporaryDirectory(prefix=f"sysid-build-{model.identifier}-") as tmp:
        workdir = Path(tmp)
        library, src = _compile(model, common, workdir, fmi_version)
        package_fmu(target, generate_model_description(model, guid, sysid.__version__,
                                                       fmi_version),
                    library, model.identifier, src, fmi_version=fmi_version)
    return target


def package_fmu(target: Path, description: str, library: Path, identifier: str,
                sources: Path, *, fmi_version: int = 2) -> Path:
    """Write the ``.fmu`` archive atomically: ``modelDescription.xml``, the binary for this
    platform and every file of ``sources`` (a source-code FMU other tools can rebuild)."""
    platform, ext = platform_folder(fmi_version)
    with atomic_path(target) as partial:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", description)
            zf.write(library, f"binaries/{platform}/{identifier}{ext}")
            for path in sorted(sources.iterdir()):
                zf.write(path, f"sources/{path.name}")
    return target


def build_fmu(force: bool = False, model: str = "helicopter", fmi_version: int = 2) -> Path:
    """Build the truth helicopter FMU from ``fmus/`` (cached by source hash); its path.

    Parameters
    ----------
    force : bool
        Rebuild even if an FMU with the same source hash is cached.
    model : str
        Model folder under ``fmus/`` (default ``"helicopter"``).
    fmi_version : {2, 3}
        FMI version of the FMU (both carry model exchange and co-simulation).
    """
    return build_model_fmu(fmu_sources_dir() / model, force=force, fmi_version=fmi_version)
