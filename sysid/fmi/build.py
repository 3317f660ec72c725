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
import math
import os
import shutil
import subprocess
import sys
import tempfile
import tomllib
import uuid
import zipfile
from dataclasses import dataclass
from pathlib import Path
from xml.sax.saxutils import escape, quoteattr

from sysid.core.paths import cache_dir, fmu_sources_dir
from sysid.core.errors import FMUError
from sysid.core.util import atomic_path

#: Bump when the generated files change shape, so that cached FMUs are rebuilt.
GENERATOR_VERSION = "1"

#: Compiler flags (part of the cache key). -fno-math-errno lets sqrt compile to one
#: instruction; hidden visibility exports only the FMI functions (FMI2_Export).
CFLAGS = ("-O2", "-fPIC", "-shared", "-fvisibility=hidden", "-fno-math-errno")

#: The FMI 2.0 headers shipped with fmpy, copied into the FMU's sources/ folder.
FMI_HEADERS = ("fmi2Functions.h", "fmi2FunctionTypes.h", "fmi2TypesPlatform.h")

KINDS = ("parameter", "input", "state", "output")
_KIND_CODE = {"parameter": 0, "input": 1, "state": 2, "derivative": 3, "output": 4}

#: Unit definitions: SI base-unit exponents (plus factor) and display units with the FMI
#: factor (display value = factor * value).
_FT = 0.3048
UNITS: dict[str, tuple[dict, dict]] = {
    "1": ({}, {}),
    "%": ({"factor": "0.01"}, {}),
    "s": ({"s": 1}, {}),
    "m": ({"m": 1}, {"ft": 1 / _FT}),
    "m/s": ({"m": 1, "s": -1}, {"ft/s": 1 / _FT, "kt": 3600 / 1852}),
    "m/s2": ({"m": 1, "s": -2}, {"ft/s2": 1 / _FT}),
    "rad": ({"rad": 1}, {"deg": 180 / math.pi}),
    "rad/s": ({"rad": 1, "s": -1}, {"deg/s": 180 / math.pi}),
    "rad/s2": ({"rad": 1, "s": -2}, {"deg/s2": 180 / math.pi}),
    "1/rad": ({"rad": -1}, {}),
    "kg": ({"kg": 1}, {}),
    "kg.m2": ({"kg": 1, "m": 2}, {}),
    "kg/m3": ({"kg": 1, "m": -3}, {}),
    "m2": ({"m": 2}, {}),
    "m3": ({"m": 3}, {}),
    "N": ({"kg": 1, "m": 1, "s": -2}, {}),
    "N.m": ({"kg": 1, "m": 2, "s": -2}, {}),
    "N.m/rad": ({"kg": 1, "m": 2, "s": -2, "rad": -1}, {}),
    "W": ({"kg": 1, "m": 2, "s": -3}, {}),
}
#: Unit of the time derivative of a state with the given unit (and its display unit).
_DERIVATIVE_UNIT = {
    "m": ("m/s", "ft/s"), "m/s": ("m/s2", "ft/s2"), "rad": ("rad/s", "deg/s"),
    "rad/s": ("rad/s2", "deg/s2"),
}


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
                "derivative": "calculated", "output": "calculated"}[self.kind]


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
        if display and display not in UNITS[unit][1]:
            raise FMUError(f"{where}: {display!r} is not a display unit of {unit!r}")
        if kind != "output" and _number(row["start"], where) is None:
            raise FMUError(f"{where}: {kind} {name} needs a start value")
        if kind == "state" and unit not in _DERIVATIVE_UNIT:
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
        unit, display = _DERIVATIVE_UNIT[state.unit]
        variables.append(Variable(
            name=f"der({state.name})", kind="derivative", unit=unit,
            display_unit=display if state.display_unit else "", start=None, nominal=None,
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


def _c_double(value: float | None) -> str:
    if value is None:
        return "NAN"
    return repr(float(value))


def generate_header(model: ModelSources, guid: str) -> str:
    """The C header ``model_variables.h``: value references and variable tables."""
    n_states = len(model.states)
    lines = [
        "/* Generated by sysid.truth from variables.csv and model.toml; do not edit. */",
        "#ifndef MODEL_VARIABLES_H",
        "#define MODEL_VARIABLES_H",
        "#include <math.h>",
        "",
        f"#define MODEL_IDENTIFIER {model.identifier}",
        f'#define MODEL_GUID "{guid}"',
        f"#define N_REALS {len(model.variables)}",
        f"#define N_STATES {n_states}",
        "#define VR_STATE0 0",
        f"#define VR_DERIV0 {n_states}",
        "",
    ]
    for var in model.variables:
        lines.append(f"#define VR_{_c_name(var.name)} {var.vr}")
    lines += ["", "static const double MODEL_START[N_REALS] = {"]
    lines += [f"    {_c_double(v.start)}, /* {v.name} */" for v in model.variables]
    lines += ["};", "", "static const double MODEL_STATE_NOMINAL[N_STATES] = {"]
    lines += [f"    {_c_double(v.nominal or 1.0)}, /* {v.name} */" for v in model.states]
    lines += ["};", "", "static const unsigned char MODEL_VAR_KIND[N_REALS] = {"]
    lines += [f"    {_KIND_CODE[v.kind]}, /* {v.name} */" for v in model.variables]
    lines += ["};", "", "static const char *const MODEL_VAR_NAMES[N_REALS] = {"]
    lines += [f'    "{v.name}",' for v in model.variables]
    lines += ["};", "", "#endif", ""]
    return "\n".join(lines)


def _attr(name: str, value) -> str:
    return f" {name}={quoteattr(str(value))}"


def _fmt(value: float) -> str:
    return repr(float(value))


def generate_model_description(model: ModelSources, guid: str, version: str) -> str:
    """The ``modelDescription.xml`` (FMI 2.0, model exchange and co-simulation)."""
    c_files = "".join(f'      <File name="{name}"/>\n'
                      for name in ("fmi2_functions.c", *model.sources))
    common_caps = (' canGetAndSetFMUstate="true" canSerializeFMUstate="true"'
                   ' canNotUseMemoryManagementFunctions="true"'
                   ' providesDirectionalDerivative="false"')
    used = {v.unit for v in model.variables}
    out = [
        '<?xml version="1.0" encoding="UTF-8"?>',
        '<fmiModelDescription fmiVersion="2.0"'
        + _attr("modelName", model.name) + _attr("guid", guid)
        + _attr("description", model.description)
        + _attr("generationTool", f"sysid {version}")
        + f' numberOfEventIndicators="0">',
        f'  <ModelExchange modelIdentifier="{model.identifier}"'
        f' completedIntegratorStepNotNeeded="true"{common_caps}>',
        "    <SourceFiles>", c_files.rstrip("\n"), "    </SourceFiles>",
        "  </ModelExchange>",
        f'  <CoSimulation modelIdentifier="{model.identifier}"'
        f' canHandleVariableCommunicationStepSize="true"{common_caps}>',
        "    <SourceFiles>", c_files.rstrip("\n"), "    </SourceFiles>",
        "  </CoSimulation>",
        "  <UnitDefinitions>",
    ]
    for unit in sorted(used):
        base, displays = UNITS[unit]
        out.append(f"    <Unit{_attr('name', unit)}>")
        if base:
            attrs = "".join(_attr(k, v) for k, v in base.items())
            out.append(f"      <BaseUnit{attrs}/>")
        for dname, factor in displays.items():
            out.append(f"      <DisplayUnit{_attr('name', dname)}{_attr('factor', _fmt(factor))}/>")
        out.append("    </Unit>")
    out.append("  </UnitDefinitions>")
    exp = model.experiment
    if exp:
        out.append("  <DefaultExperiment"
                   + "".join(_attr(k, _fmt(exp[key])) for k, key in
                             (("startTime", "start"), ("stopTime", "stop"), ("stepSize", "step"))
                             if key in exp) + "/>")
    out.append("  <ModelVariables>")
    index = {v.name: k + 1 for k, v in enumerate(model.variables)}
    for var in model.variables:
        attrs = (_attr("name", var.name) + _attr("valueReference", var.vr)
                 + _attr("description", var.description) + _attr("causality", var.causality)
                 + _attr("variability", var.variability))
        if var.initial and var.kind != "derivative":
            attrs += _attr("initial", var.initial)
        real = _attr("unit", var.unit)
        if var.display_unit:
            real += _attr("displayUnit", var.display_unit)
        if var.state_of:
            real += _attr("derivative", index[var.state_of])
        if var.start is not None:
            real += _attr("start", _fmt(var.start))
        if var.kind == "state" and var.nominal is not None:
            real += _attr("nominal", _fmt(var.nominal))
        out.append(f"    <ScalarVariable{attrs}>")
        out.append(f"      <Real{real}/>")
        out.append("    </ScalarVariable>")
    out.append("  </ModelVariables>")
    outputs = [index[v.name] for v in model.variables if v.causality == "output"]
    derivatives = [index[v.name] for v in model.variables if v.kind == "derivative"]
    initial = sorted(index[v.name] for v in model.variables
                     if v.kind in ("output", "derivative"))
    out += model_structure(outputs, derivatives, initial)
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def model_structure(outputs, derivatives, initial_unknowns) -> list[str]:
    """The ``<ModelStructure>`` lines of an FMI 2.0 modelDescription.xml (indices are the
    1-based positions of the variables in ``<ModelVariables>``)."""
    out = ["  <ModelStructure>"]
    for tag, items in (("Outputs", outputs), ("Derivatives", derivatives),
                       ("InitialUnknowns", initial_unknowns)):
        out.append(f"    <{tag}>")
        out += [f'      <Unknown index="{i}"/>' for i in items]
        out.append(f"    </{tag}>")
    out.append("  </ModelStructure>")
    return out


# ------------------------------------------------------------------------------------------
# compiler, hashing, packaging

def fmi_header_dir() -> Path:
    """Folder of the FMI 2.0 C headers installed with fmpy."""
    import fmpy

    folder = Path(fmpy.__file__).parent / "c-code"
    missing = [h for h in FMI_HEADERS if not (folder / h).is_file()]
    if missing:
        raise FMUError(f"FMI headers {missing} not found in {folder}; reinstall fmpy")
    return folder


def find_compiler() -> list[str]:
    """The C compiler command: ``$CC`` if set (no fallback), else cc, gcc or clang."""
    env = os.environ.get("CC", "").strip()
    if env:
        parts = env.split()
        if shutil.which(parts[0]) is None:
            raise FMUError(f"C compiler CC={env!r} not found; install a C compiler or fix $CC")
        return parts
    for name in ("cc", "gcc", "clang"):
        if shutil.which(name):
            return [name]
    raise FMUError("no C compiler found (tried $CC, cc, gcc, clang); install one "
                   "(e.g. gcc or clang) to build the FMU from its sources")


def platform_folder() -> tuple[str, str]:
    """FMI 2.0 binaries folder name and shared-library extension of this machine."""
    from fmpy import platform, sharedLibraryExtension

    return platform, sharedLibraryExtension


def _source_files(model: ModelSources, common: Path) -> list[Path]:
    files = [common / "fmi2_functions.c", common / "fmu_model.h"]
    files += [model.folder / name for name in (*model.sources, *model.headers)]
    for path in files:
        if not path.is_file():
            raise FMUError(f"FMU source file {path} is missing")
    return files


def source_hash(model: ModelSources, common: Path) -> str:
    """SHA-256 over the sources, the variable table, the FMI headers and the flags."""
    digest = hashlib.sha256()
    digest.update(f"generator {GENERATOR_VERSION}\nflags {' '.join(CFLAGS)}\n".encode())
    headers = fmi_header_dir()
    inputs = [*_source_files(model, common), model.folder / "variables.csv",
              model.folder / "model.toml", *(headers / h for h in FMI_HEADERS)]
    for path in inputs:
        digest.update(path.name.encode() + b"\0" + path.read_bytes() + b"\0")
    return digest.hexdigest()


def _guid(digest: str) -> str:
    return "{" + str(uuid.UUID(hex=digest[:32])) + "}"


def _compile(model: ModelSources, common: Path, workdir: Path) -> tuple[Path, Path]:
    """Generate the header, compile the shared library; return (library, sources dir)."""
    src = workdir / "sources"
    src.mkdir()
    for path in _source_files(model, common):
        shutil.copy2(path, src / path.name)
    for name in FMI_HEADERS:
        shutil.copy2(fmi_header_dir() / name, src / name)
    digest = source_hash(model, common)
    (src / "model_variables.h").write_text(generate_header(model, _guid(digest)))
    _, ext = platform_folder()
    library = workdir / f"{model.identifier}{ext}"
    c_files = [src / "fmi2_functions.c", *(src / n for n in model.sources)]
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
    compiler = find_compiler()
    flags = [f for f in CFLAGS if not (sys.platform == "win32" and f == "-fPIC")]
    cmd = [*compiler, *flags, "-I", str(include_dir), *(str(f) for f in c_files),
           "-o", str(library), "-lm"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=300)
    except OSError as exc:
        raise FMUError(f"could not run the C compiler {compiler[0]!r}: {exc}") from None
    except subprocess.TimeoutExpired:
        raise FMUError(f"the C compiler {compiler[0]!r} did not finish within 300 s") from None
    if proc.returncode != 0 or not library.is_file():
        text = proc.stderr + proc.stdout
        first = next((line for line in text.splitlines() if "error" in line.lower()),
                     text.strip()[:300] or f"exit status {proc.returncode}, no output")
        where = ""
        if log is not None:
            log.write_text(" ".join(cmd) + "\n\n" + text)
            where = f" (full log: {log})"
        raise FMUError(f"compiling {what} failed: {first.strip()} "
                       f"(compiler: {' '.join(compiler)}){where}")
    return library


def fmu_cache_path(model: ModelSources, common: Path) -> Path:
    """Where the FMU built from these sources is (or will be) cached."""
    return cache_dir() / "fmus" / f"{model.identifier}-{source_hash(model, common)[:16]}.fmu"


def build_model_fmu(model_folder: str | os.PathLike, *, force: bool = False,
                    common_folder: str | os.PathLike | None = None) -> Path:
    """Build (or reuse from the cache) the FMU of the model in ``model_folder``.

    ``model_folder`` holds ``model.toml``, ``variables.csv``, ``model.h`` and the C sources;
    ``common_folder`` defaults to ``fmus/common``. Returns the path of the cached ``.fmu``.
    Raises :class:`~sysid.core.errors.FMUError` naming the problem (no compiler, compile error...).
    """
    from sysid import __version__

    model = read_model(model_folder)
    common = Path(common_folder) if common_folder else fmu_sources_dir() / "common"
    target = fmu_cache_path(model, common)
    if target.is_file() and not force:
        return target
    digest = source_hash(model, common)
    guid = _guid(digest)
    with tempfile.TemporaryDirectory(prefix=f"sysid-build-{model.identifier}-") as tmp:
        workdir = Path(tmp)
        library, src = _compile(model, common, workdir)
        package_fmu(target, generate_model_description(model, guid, __version__), library,
                    model.identifier, src)
    return target


def package_fmu(target: Path, description: str, library: Path, identifier: str,
                sources: Path) -> Path:
    """Write the ``.fmu`` archive atomically: ``modelDescription.xml``, the binary for this
    platform and every file of ``sources`` (a source-code FMU other tools can rebuild)."""
    platform, ext = platform_folder()
    with atomic_path(target) as partial:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr("modelDescription.xml", description)
            zf.write(library, f"binaries/{platform}/{identifier}{ext}")
            for path in sorted(sources.iterdir()):
                zf.write(path, f"sources/{path.name}")
    return target


def build_fmu(force: bool = False, model: str = "helicopter") -> Path:
    """Build the truth helicopter FMU from ``fmus/`` (cached by source hash); its path.

    Parameters
    ----------
    force : bool
        Rebuild even if an FMU with the same source hash is cached.
    model : str
        Model folder under ``fmus/`` (default ``"helicopter"``).
    """
    return build_model_fmu(fmu_sources_dir() / model, force=force)
