"""SSP 1.0 packages: FMUs, their connections and parameter values in one ``.ssp`` archive.

:func:`write_ssp` writes ``SystemStructure.ssd`` (one system of FMU components, their
connectors, the connections between them and inline parameter bindings) and the FMUs under
``resources/``, as the System Structure and Parameterization standard 1.0 describes; tools
such as libcosim (``libcosimpy.CosimExecution.from_ssp_file``) or OMSimulator load and run
it. A fixed-step co-simulation algorithm with the given step is suggested to libcosim by its
``com.opensimulationplatform`` annotation in the default experiment (other tools ignore it).

References
----------
Modelica Association, *System Structure and Parameterization*, version 1.0 (2019),
https://ssp-standard.org.
"""

from __future__ import annotations

import zipfile
from dataclasses import dataclass, field
from pathlib import Path
from xml.sax.saxutils import quoteattr

from sysid.core.errors import InputDataError
from sysid.core.util import atomic_path

__all__ = ["SspComponent", "write_ssp", "SSD_NAME"]

#: Name of the system structure description at the top of the archive.
SSD_NAME = "SystemStructure.ssd"
_NS = {"ssd": "http://ssp-standard.org/SSP1/SystemStructureDescription",
       "ssc": "http://ssp-standard.org/SSP1/SystemStructureCommon",
       "ssv": "http://ssp-standard.org/SSP1/SystemStructureParameterValues",
       "osp": "http://opensimulationplatform.com/SSP/OSPAnnotations"}


@dataclass(frozen=True)
class SspComponent:
    """One FMU in the system: its instance name, file, connectors and parameter values.

    ``inputs`` / ``outputs`` are the Real variables that take part in connections;
    ``parameters`` are Real start values bound before initialisation (any variable the FMU
    lets an importer set then, e.g. the state start values of the truth helicopter).
    """

    name: str
    fmu: Path
    inputs: tuple[str, ...] = ()
    outputs: tuple[str, ...] = ()
    parameters: dict = field(default_factory=dict)


def _a(name: str, value) -> str:
    return f" {name}={quoteattr(str(value))}"


def _ssd(name: str, components, connections, stop_time: float, step_size: float) -> str:
    out = ['<?xml version="1.0" encoding="UTF-8"?>',
           '<ssd:SystemStructureDescription' + "".join(
               f' xmlns:{k}="{v}"' for k, v in _NS.items()) + f' version="1.0"{_a("name", name)}>',
           f"  <ssd:System{_a('name', name)}>", "    <ssd:Elements>"]
    for comp in components:
        out.append(f"      <ssd:Component{_a('name', comp.name)}"
                   f' type="application/x-fmu-sharedlibrary"'
                   f"{_a('source', 'resources/' + Path(comp.fmu).name)}>")
        out.append("        <ssd:Connectors>")
        for kind, names in (("input", comp.inputs), ("output", comp.outputs)):
            out += [f"          <ssd:Connector{_a('name', n)}{_a('kind', kind)}>"
                    "<ssc:Real/></ssd:Connector>" for n in names]
        out.append("        </ssd:Connectors>")
        if comp.parameters:
            out += ["        <ssd:ParameterBindings>", "          <ssd:ParameterBinding>",
                    "            <ssd:ParameterValues>",
                    f'              <ssv:ParameterSet version="1.0"'
                    f"{_a('name', comp.name + '_start_values')}>",
                    "                <ssv:Parameters>"]
            for pname, value in comp.parameters.items():
                out.append(f"                  <ssv:Parameter{_a('name', pname)}>"
                           f"<ssv:Real{_a('value', repr(float(value)))}/></ssv:Parameter>")
            out += ["                </ssv:Parameters>", "              </ssv:ParameterSet>",
                    "            </ssd:ParameterValues>", "          </ssd:ParameterBinding>",
                    "        </ssd:ParameterBindings>"]
        out.append("      </ssd:Component>")
    out.append("    </ssd:Elements>")
    out.append("    <ssd:Connections>")
    for src, src_var, dst, dst_var in connections:
        out.append(f"      <ssd:Connection{_a('startElement', src)}{_a('startConnector', src_var)}"
                   f"{_a('endElement', dst)}{_a('endConnector', dst_var)}/>")
    out += ["    </ssd:Connections>", "  </ssd:System>",
            f'  <ssd:DefaultExperiment startTime="0.0"{_a("stopTime", repr(float(stop_time)))}>',
            "    <ssd:Annotations>",
            '      <ssc:Annotation type="com.opensimulationplatform">',
            f"        <osp:Algorithm><osp:FixedStepAlgorithm"
            f"{_a('baseStepSize', repr(float(step_size)))}/></osp:Algorithm>",
            "      </ssc:Annotation>", "    </ssd:Annotations>",
            "  </ssd:DefaultExperiment>", "</ssd:SystemStructureDescription>"]
    return "\n".join(out) + "\n"


def write_ssp(path, *, name: str, components, connections, stop_time: float,
              step_size: float) -> Path:
    """Write an SSP 1.0 archive: ``SystemStructure.ssd`` and ``resources/<fmu>``.

    Parameters
    ----------
    path : path-like
        The ``.ssp`` file, written atomically.
    name : str
        System name.
    components : sequence of SspComponent
        Unique names; FMU files with unique file names.
    connections : sequence of (start component, start connector, end component, end connector)
        Each end a connector its component declares (output to input).
    stop_time, step_size : float
        Default experiment (s): stop time and the suggested fixed communication step.

    Returns
    -------
    Path of the archive.
    """
    path = Path(path)
    if path.suffix != ".ssp":
        raise InputDataError(f"the SSP file must end in .ssp, got {path}")
    components = list(components)
    by_name = {c.name: c for c in components}
    if len(by_name) != len(components):
        raise InputDataError("SSP component names must be unique")
    files = [Path(c.fmu).name for c in components]
    if len(set(files)) != len(files):
        raise InputDataError(f"SSP component FMU file names must be unique, got {files}")
    for c in components:
        if not Path(c.fmu).is_file():
            raise InputDataError(f"FMU {c.fmu} of SSP component {c.name!r} does not exist")
    for src, src_var, dst, dst_var in connections:
        if src not in by_name or src_var not in by_name[src].outputs:
            raise InputDataError(f"connection start {src}.{src_var} is not an output "
                                 "connector of a component")
        if dst not in by_name or dst_var not in by_name[dst].inputs:
            raise InputDataError(f"connection end {dst}.{dst_var} is not an input "
                                 "connector of a component")
    if not (step_size > 0 and stop_time > 0):
        raise InputDataError("stop_time and step_size must be positive (s)")
    with atomic_path(path) as partial:
        with zipfile.ZipFile(partial, "w", zipfile.ZIP_DEFLATED) as zf:
            zf.writestr(SSD_NAME, _ssd(name, components, connections, stop_time, step_size))
            for c in components:
                zf.write(c.fmu, f"resources/{Path(c.fmu).name}")
    return path
