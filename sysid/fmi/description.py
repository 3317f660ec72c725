"""One generator of ``modelDescription.xml`` and of the C variable header, for every FMU.

The truth helicopter (:mod:`sysid.fmi.build`) and the exported linear models
(:mod:`sysid.fmi.export`) describe their FMU with the same data model, :class:`FmuDescription`
(variables with causality, variability, initial, unit and start; unit definitions from
:data:`sysid.core.units.UNITS`; the model structure follows from the variables), and this
module writes it: :func:`fmi2_model_description` (FMI 2.0 XML),
:func:`fmi3_model_description` (FMI 3.0 XML), :func:`build_description` (the FMI 3.0
``sources/buildDescription.xml``) and :func:`variables_header` (``model_variables.h`` for the
shared boilerplate ``fmus/common``, the same for both versions). The data model holds no XML
text; :func:`model_description` picks the writer of a version.

References
----------
Modelica Association, *Functional Mock-up Interface for Model Exchange and Co-Simulation*,
version 2.0.4 (2022) and *Functional Mock-up Interface Specification*, version 3.0.2 (2024),
https://fmi-standard.org.
"""

from __future__ import annotations

from dataclasses import dataclass
from xml.sax.saxutils import quoteattr

from sysid.core.units import UNITS, display_units

__all__ = ["UnitDefinition", "ScalarVariable", "FmuDescription", "KIND_CODE", "FMI_VERSIONS",
           "fmi2_model_description", "fmi3_model_description", "model_description",
           "build_description", "boilerplate_sources", "variables_header", "c_string"]

#: FMI versions the writers and the boilerplate support.
FMI_VERSIONS = (2, 3)
#: Name of the independent variable of FMI 3.0 FMUs.
TIME_NAME = "time"

#: The shared boilerplate's C files compiled into an FMU of each FMI version (fmus/common).
_BOILERPLATE = {2: ("fmu_core.c", "fmi2_functions.c"), 3: ("fmu_core.c", "fmi3_functions.c")}


def boilerplate_sources(fmi_version: int) -> tuple[str, ...]:
    """C files of ``fmus/common`` compiled into an FMU of ``fmi_version`` (2 or 3)."""
    try:
        return _BOILERPLATE[fmi_version]
    except KeyError:
        raise ValueError(f"FMI version must be one of {FMI_VERSIONS}, got {fmi_version!r}") \
            from None

#: Role of a variable in the boilerplate's value table (``MODEL_VAR_KIND`` in the header).
KIND_CODE = {"parameter": 0, "input": 1, "state": 2, "derivative": 3, "output": 4}


@dataclass(frozen=True)
class UnitDefinition:
    """An FMI unit: SI base-unit exponents, factor (SI value = factor * value), display units
    ``(name, factor)`` with display value = factor * value."""

    name: str
    exponents: tuple[tuple[str, int], ...] = ()
    factor: float = 1.0
    displays: tuple[tuple[str, float], ...] = ()

    @classmethod
    def of(cls, name: str) -> "UnitDefinition":
        """The definition of a unit of :data:`sysid.core.units.UNITS`, with its display units."""
        unit = UNITS[name]
        return cls(name, unit.exponents, unit.factor, display_units(name))


@dataclass(frozen=True)
class ScalarVariable:
    """One Real variable of an FMU.

    ``kind`` is its role in the C boilerplate (parameter, input, state, derivative, output);
    ``causality``, ``variability`` and ``initial`` are what the FMU declares (the truth FMU
    makes its states outputs, the exported models keep them local). ``derivative_of`` names
    the state a derivative belongs to.
    """

    name: str
    c_name: str
    value_reference: int
    kind: str
    causality: str
    variability: str
    initial: str | None = None
    description: str = ""
    unit: str | None = None
    display_unit: str | None = None
    start: float | None = None
    nominal: float | None = None
    derivative_of: str | None = None


@dataclass(frozen=True)
class FmuDescription:
    """Everything an FMU's model description says, independent of the FMI version's XML."""

    model_name: str
    identifier: str
    guid: str
    description: str
    generation_tool: str
    source_files: tuple[str, ...]
    variables: tuple[ScalarVariable, ...]
    units: tuple[UnitDefinition, ...] = ()
    #: DefaultExperiment: any of ``start``, ``stop``, ``step`` (s)
    experiment: tuple[tuple[str, float], ...] = ()
    #: False when the model-exchange FMU needs fmi2CompletedIntegratorStep (step events)
    completed_integrator_step_not_needed: bool = True
    #: the model implements exact directional derivatives (MODEL_HAS_DIRECTIONAL_DERIVATIVE)
    provides_directional_derivative: bool = False
    #: interfaces the FMU offers: "me" (model exchange) and/or "cs" (co-simulation)
    interfaces: tuple[str, ...] = ("me", "cs")

    def index(self) -> dict[str, int]:
        """1-based position of each variable (FMI 2.0 ``<ModelVariables>`` order)."""
        return {v.name: k + 1 for k, v in enumerate(self.variables)}

    def outputs(self) -> list[int]:
        index = self.index()
        return [index[v.name] for v in self.variables if v.causality == "output"]

    def derivatives(self) -> list[int]:
        index = self.index()
        return [index[v.name] for v in self.variables if v.derivative_of is not None]

    def initial_unknowns(self) -> list[int]:
        """Outputs computed at initialisation (initial not ``exact``) and the derivatives."""
        index = self.index()
        return sorted(index[v.name] for v in self.variables
                      if v.derivative_of is not None
                      or (v.causality == "output" and v.initial != "exact"))


# ------------------------------------------------------------------------------------------
# FMI 2.0


def _attr(name: str, value) -> str:
    return f" {name}={quoteattr(str(value))}"


def _variable_attrs(v) -> str:
    """The attributes both FMI versions write on a variable: name, value reference,
    description, causality, variability and initial."""
    attrs = (_attr("name", v.name) + _attr("valueReference", v.value_reference)
             + _attr("description", v.description) + _attr("causality", v.causality)
             + _attr("variability", v.variability))
    return attrs + (_attr("initial", v.initial) if v.initial else "")


def _real(value: float) -> str:
    return repr(float(value))


def _bool(value: bool) -> str:
    return "true" if value else "false"


def _fmi2_capabilities(desc: FmuDescription) -> str:
    """Capability flags both interfaces declare (the boilerplate implements them)."""
    return (' canGetAndSetFMUstate="true" canSerializeFMUstate="true"'
            ' canNotUseMemoryManagementFunctions="true"'
            f' providesDirectionalDerivative="{_bool(desc.provides_directional_derivative)}"')


_EXPERIMENT = (("startTime", "start"), ("stopTime", "stop"), ("stepSize", "step"))


def fmi2_model_description(desc: FmuDescription) -> str:
    """``modelDescription.xml`` (FMI 2.0, model exchange and co-simulation, source files)."""
    files = "\n".join(f"      <File{_attr('name', f)}/>" for f in desc.source_files)
    not_needed = _bool(desc.completed_integrator_step_not_needed)
    capabilities = _fmi2_capabilities(desc)
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<fmiModelDescription fmiVersion="2.0"' + _attr("modelName", desc.model_name)
           + _attr("guid", desc.guid) + _attr("description", desc.description)
           + _attr("generationTool", desc.generation_tool)
           + ' variableNamingConvention="flat" numberOfEventIndicators="0">']
    if "me" in desc.interfaces:
        out += [f"  <ModelExchange{_attr('modelIdentifier', desc.identifier)}"
                f' completedIntegratorStepNotNeeded="{not_needed}"{capabilities}>',
                "    <SourceFiles>", files, "    </SourceFiles>", "  </ModelExchange>"]
    if "cs" in desc.interfaces:
        out += [f"  <CoSimulation{_attr('modelIdentifier', desc.identifier)}"
                f' canHandleVariableCommunicationStepSize="true"{capabilities}>',
                "    <SourceFiles>", files, "    </SourceFiles>", "  </CoSimulation>"]
    out += _unit_definitions(desc)
    out += _default_experiment(desc)
    out.append("  <ModelVariables>")
    index = desc.index()
    for v in desc.variables:
        attrs = _variable_attrs(v)
        real = ""
        if v.unit:
            real += _attr("unit", v.unit)
        if v.display_unit:
            real += _attr("displayUnit", v.display_unit)
        if v.derivative_of:
            real += _attr("derivative", index[v.derivative_of])
        if v.start is not None:
            real += _attr("start", _real(v.start))
        if v.nominal is not None:
            real += _attr("nominal", _real(v.nominal))
        out += [f"    <ScalarVariable{attrs}>", f"      <Real{real}/>", "    </ScalarVariable>"]
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    for tag, items in (("Outputs", desc.outputs()), ("Derivatives", desc.derivatives()),
                       ("InitialUnknowns", desc.initial_unknowns())):
        if not items:  # the schema refuses empty lists
            continue
        out.append(f"    <{tag}>")
        out += [f'      <Unknown index="{i}"/>' for i in items]
        out.append(f"    </{tag}>")
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def _unit_definitions(desc: FmuDescription) -> list[str]:
    """``<UnitDefinitions>`` (the same element in FMI 2.0 and 3.0)."""
    out = []
    if desc.units:
        out.append("  <UnitDefinitions>")
        for unit in sorted(desc.units, key=lambda u: u.name):
            out.append(f"    <Unit{_attr('name', unit.name)}>")
            base = "".join(_attr(k, v) for k, v in unit.exponents)
            if unit.factor != 1.0:
                base += _attr("factor", _real(unit.factor))
            if base:
                out.append(f"      <BaseUnit{base}/>")
            for name, factor in unit.displays:
                out.append(f"      <DisplayUnit{_attr('name', name)}"
                           f"{_attr('factor', _real(factor))}/>")
            out.append("    </Unit>")
        out.append("  </UnitDefinitions>")
    return out


def _default_experiment(desc: FmuDescription) -> list[str]:
    experiment = dict(desc.experiment)
    if not experiment:
        return []
    return ["  <DefaultExperiment" + "".join(
        _attr(attr, _real(experiment[key])) for attr, key in _EXPERIMENT
        if key in experiment) + "/>"]


# ------------------------------------------------------------------------------------------
# FMI 3.0


def fmi3_model_description(desc: FmuDescription) -> str:
    """``modelDescription.xml`` (FMI 3.0, model exchange and co-simulation as declared in
    ``desc.interfaces``). Variables are ``<Float64>``; ``derivative`` names the state's value
    reference; ``instantiationToken`` is the GUID. FMI 3.0 lists the source files in
    ``sources/buildDescription.xml`` (:func:`build_description`), not here."""
    common = (' canGetAndSetFMUState="true" canSerializeFMUState="true"'
              f' providesDirectionalDerivatives="{_bool(desc.provides_directional_derivative)}"')
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<fmiModelDescription fmiVersion="3.0"' + _attr("modelName", desc.model_name)
           + _attr("instantiationToken", desc.guid) + _attr("description", desc.description)
           + _attr("generationTool", desc.generation_tool)
           + ' variableNamingConvention="flat">']
    if "me" in desc.interfaces:
        needs = _bool(not desc.completed_integrator_step_not_needed)
        out.append(f"  <ModelExchange{_attr('modelIdentifier', desc.identifier)}"
                   f' needsCompletedIntegratorStep="{needs}"{common}/>')
    if "cs" in desc.interfaces:
        out.append(f"  <CoSimulation{_attr('modelIdentifier', desc.identifier)}"
                   f' canHandleVariableCommunicationStepSize="true" hasEventMode="false"'
                   f"{common}/>")
    out += _unit_definitions(desc)
    out += _default_experiment(desc)
    out.append("  <ModelVariables>")
    by_name = {v.name: v for v in desc.variables}
    if TIME_NAME in by_name:
        raise ValueError(f"FMI 3.0 export: a variable may not be called {TIME_NAME!r}, the "
                         "independent variable")
    # FMI 3.0 needs exactly one independent variable; its value reference follows the Real
    # table (VR_TIME in model_variables.h), where fmu_core.c answers with the time.
    time_unit = _attr("unit", "s") if any(u.name == "s" for u in desc.units) else ""
    out.append(f'    <Float64 name="{TIME_NAME}" valueReference="{len(desc.variables)}"'
               f' description="simulation time" causality="independent"'
               f' variability="continuous"{time_unit}/>')
    for v in desc.variables:
        attrs = _variable_attrs(v)
        if v.unit:
            attrs += _attr("unit", v.unit)
        if v.display_unit:
            attrs += _attr("displayUnit", v.display_unit)
        if v.start is not None:
            attrs += _attr("start", _real(v.start))
        if v.derivative_of:
            attrs += _attr("derivative", by_name[v.derivative_of].value_reference)
        if v.nominal is not None:
            attrs += _attr("nominal", _real(v.nominal))
        out.append(f"    <Float64{attrs}/>")
    out.append("  </ModelVariables>")
    out.append("  <ModelStructure>")
    vr = {v.name: v.value_reference for v in desc.variables}
    names = [v.name for v in desc.variables]
    for tag, items in (("Output", desc.outputs()), ("ContinuousStateDerivative",
                                                     desc.derivatives()),
                       ("InitialUnknown", desc.initial_unknowns())):
        out += [f'    <{tag} valueReference="{vr[names[i - 1]]}"/>' for i in items]
    out.append("  </ModelStructure>")
    out.append("</fmiModelDescription>")
    return "\n".join(out) + "\n"


def model_description(desc: FmuDescription, fmi_version: int) -> str:
    """``modelDescription.xml`` of ``desc`` for FMI ``fmi_version`` (2 or 3)."""
    if fmi_version == 2:
        return fmi2_model_description(desc)
    if fmi_version == 3:
        return fmi3_model_description(desc)
    raise ValueError(f"FMI version must be one of {FMI_VERSIONS}, got {fmi_version!r}")


def build_description(desc: FmuDescription) -> str:
    """``sources/buildDescription.xml`` of an FMI 3.0 FMU: one C99 source-file set with
    ``desc.source_files`` (FMI 3.0, section 2.4.8). FMI 2.0 has no build description: its
    ``<SourceFiles>`` in the model description say the same."""
    files = "\n".join(f"      <SourceFile{_attr('name', f)}/>" for f in desc.source_files)
    return ('<?xml version="1.0" encoding="UTF-8"?>\n'
            '<fmiBuildDescription fmiVersion="3.0">\n'
            f"  <BuildConfiguration{_attr('modelIdentifier', desc.identifier)}>\n"
            '    <SourceFileSet language="C99">\n'
            f"{files}\n"
            "    </SourceFileSet>\n"
            "  </BuildConfiguration>\n"
            "</fmiBuildDescription>\n")


# ------------------------------------------------------------------------------------------
# the C header of the shared boilerplate (fmus/common)


def _c_double(value: float | None) -> str:
    return "NAN" if value is None else repr(float(value))


def c_string(text: str) -> str:
    """A C string literal holding ``text`` (UTF-8; quotes, backslashes and non-printable
    bytes escaped in octal)."""
    out = []
    for byte in text.encode("utf-8"):
        ch = chr(byte)
        if ch in '"\\?':
            out.append("\\" + ch)
        elif 32 <= byte < 127:
            out.append(ch)
        else:
            out.append(f"\\{byte:03o}")
    return '"' + "".join(out) + '"'


def variables_header(desc: FmuDescription) -> str:
    """``model_variables.h``: value references, start values, state nominals and variable
    kinds in value-reference order, as ``fmus/common/fmu_core.c`` expects (states at
    ``0..n-1``, their derivatives at ``n..2n-1``)."""
    variables = sorted(desc.variables, key=lambda v: v.value_reference)
    states = [v for v in variables if v.kind == "state"]
    lines = [
        "/* Generated by sysid.fmi.description; do not edit. */",
        "#ifndef MODEL_VARIABLES_H",
        "#define MODEL_VARIABLES_H",
        "#include <math.h>",
        "",
        f"#define MODEL_IDENTIFIER {desc.identifier}",
        f'#define MODEL_GUID "{desc.guid}"',
        f"#define N_REALS {len(variables)}",
        f"#define N_STATES {len(states)}",
        "/* C has no zero-length arrays: a model without states still gets one slot */",
        f"#define N_STATES_ALLOC {max(1, len(states))}",
        "#define VR_STATE0 0",
        f"#define VR_DERIV0 {len(states)}",
        "/* the independent variable (FMI 3.0 declares it): read-only, the FMU's time */",
        "#define VR_TIME N_REALS",
        "",
    ]
    lines += [f"#define VR_{v.c_name} {v.value_reference}" for v in variables]
    lines += ["", "static const double MODEL_START[N_REALS] = {"]
    lines += [f"    {_c_double(v.start)}, /* {v.c_name} */" for v in variables]
    lines += ["};", "", "static const double MODEL_STATE_NOMINAL[N_STATES_ALLOC] = {"]
    lines += [f"    {_c_double(v.nominal or 1.0)}, /* {v.c_name} */" for v in states]
    lines += ["    1.0, /* (no states) */"] if not states else []
    lines += ["};", "", "static const unsigned char MODEL_VAR_KIND[N_REALS] = {"]
    lines += [f"    {KIND_CODE[v.kind]}, /* {v.c_name} */" for v in variables]
    lines += ["};", "", "static const char *const MODEL_VAR_NAMES[N_REALS] = {"]
    lines += [f"    {c_string(v.name)}," for v in variables]
    lines += ["};", "", "#endif", ""]
    return "\n".join(lines)
