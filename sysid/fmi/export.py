"""Export identified linear models as FMI 2.0 or FMI 3.0 FMUs (model exchange and co-simulation).

An exported FMU is the model of ``docs/data_model.md`` (``A B C D``, a delay on any B entry,
trim) in the *same absolute units as the truth helicopter FMU*, so that a tool can swap one
for the other:

- inputs ``lon lat col ped``: absolute %, as in the truth FMU;
- outputs (``u v w`` m/s, ``p q r`` rad/s, ``phi theta psi`` rad, ``ax ay az`` m/s2):
  ``y = trim_y + C x + D (u - trim_u)``, converted from the model's analysis units with
  :mod:`sysid.core.units`; outputs that are not channels of :data:`sysid.core.units.CHANNELS` keep the
  model's units;
- states ``x_<state>``: perturbations from trim in SI (display units ft/s, deg/s, deg);
- parameters: every identified parameter of the model under its own name (``M_q``,
  ``X_lon``, ``tau_L_lon``, ...), in the model's analysis units (the units of the paper's
  derivative tables), plus ``trim_<input>`` (%) and ``trim_<output>`` (SI). The matrices are
  assembled from the fixed parts and these parameters in ``model_initialize``, so a user can
  inspect and tune them before initialisation; a tied parameter (``also``) sets every entry
  it ties, each times its scale.

The C code is the generic template ``fmus/linear`` plugged into the shared boilerplate
``fmus/common`` (the same one the truth helicopter uses: ``fmu_core.c`` with
``fmi2_functions.c`` or ``fmi3_functions.c``); the per-model numbers go into generated
headers. The FMU is a source-code FMU: ``sources/`` holds every ``.c``/``.h`` file (FMI
headers and generated tables included); FMI 2.0 lists the source files in
``modelDescription.xml``, FMI 3.0 in ``sources/buildDescription.xml``, so
:func:`fmpy.build.build_platform_binary` can rebuild it anywhere. Both versions provide exact
directional derivatives (from A, B, C, D). See ``fmus/linear/README.md`` for the numerical
choices (exact zero-order hold in co-simulation; in model exchange delays from an input
history held between input updates, or optionally Pade approximants; a history that grows).
"""

from __future__ import annotations

import hashlib
import math
import re
import shutil
import tempfile
import uuid
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

import sysid
from sysid.core.errors import FMUError, InputDataError
from sysid.core.paths import fmu_sources_dir
from sysid.core.units import CHANNELS, DERIVATIVE_UNIT, UNITS, Unit, conversion_factor
from sysid.core.util import Progress
from sysid.fmi.build import (COMMON_HEADERS, FMI_HEADERS, compile_shared_library,
                             fmi_header_dir, package_fmu, platform_folder)
from sysid.fmi.description import (FMI_VERSIONS, FmuDescription, ScalarVariable,
                                   UnitDefinition, boilerplate_sources, build_description,
                                   c_string, model_description, variables_header)
from sysid.models import parse_tied_entries

__all__ = ["export_fmu", "ExportSpec", "export_spec", "DEFAULT_STEP", "DEFAULT_PADE_ORDER",
           "ME_DELAY_MODES"]

#: Default communication step of the exported FMU (DefaultExperiment stepSize), s.
DEFAULT_STEP = 0.01
#: Default order of the Pade approximants of the delays in model exchange (me_delay="pade").
DEFAULT_PADE_ORDER = 6
#: How model exchange represents the delays: "buffer" (input history, exact for inputs held
#: between updates, the default) or "pade" (approximants with their own states).
ME_DELAY_MODES = ("buffer", "pade")
#: Files of the C template (fmus/linear).
TEMPLATE_FILES = ("model.c", "model.h")
_MATRIX_CODE = {"A": 0, "B": 1, "C": 2, "D": 3, "delay": 4}



# ------------------------------------------------------------------------------------------
# names


def c_identifier(name: str) -> str:
    """A C identifier for ``name``: characters outside ``[A-Za-z0-9_]`` become ``_xHH_``
    (their code point in hex) and a leading digit gets a ``v_`` prefix. Injective for names
    without ``_x`` sequences of that form, and the caller checks uniqueness."""
    out = "".join(ch if (ch.isascii() and (ch.isalnum() or ch == "_")) else f"_x{ord(ch):X}_"
                  for ch in str(name))
    if not out or out[0].isdigit():
        out = "v_" + out
    return out


def fmi_name(name: str) -> str:
    """The FMI variable name of a model name (flat naming convention: any characters but
    carriage return, line feed and tab, which become spaces). XML escaping happens when the
    description is written."""
    return re.sub(r"[\r\n\t]", " ", str(name))


# ------------------------------------------------------------------------------------------
# the model, checked and laid out for the C template


@dataclass
class FmuVariable:
    """One Real variable of the exported FMU."""

    name: str  #: FMI name (any characters)
    c_name: str  #: C identifier (value-reference macro)
    kind: str  #: state, derivative, input, output, parameter
    unit: str | None
    display_unit: str | None
    start: float | None
    description: str
    vr: int = -1
    state_of: str | None = None


@dataclass
class ExportSpec:
    """Everything the generator needs about one model, in the FMU's layout.

    Matrices are the fixed parts (the model's matrices minus the parameters' contributions),
    analysis units, shapes (n_x, n_x), (n_x, n_u), (n_y, n_x), (n_y, n_u).
    """

    name: str
    states: list[str]
    inputs: list[str]
    outputs: list[str]
    A0: np.ndarray
    B0: np.ndarray
    C0: np.ndarray
    D0: np.ndarray
    #: (name, matrix, row index, column index, value); for delays row = group index
    parameters: list[tuple[str, str, int, int, float]]
    #: per delay group: (input index, parameter index, rows)
    groups: list[tuple[int, int, list[int]]]
    trim_input: np.ndarray
    trim_output: np.ndarray  #: analysis units
    x_scale: np.ndarray  #: FMU (SI) unit per analysis unit, per state
    y_scale: np.ndarray
    descriptions: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    #: further entries of tied parameters: (parameter index, matrix, row, column, scale)
    ties: list[tuple[int, str, int, int, float]] = field(default_factory=list)

    @property
    def entry_group(self) -> np.ndarray:
        """Delay group of each B entry (-1: undelayed), shape (n_x, n_u)."""
        out = -np.ones((len(self.states), len(self.inputs)), dtype=int)
        for g, (col, _, rows) in enumerate(self.groups):
            out[rows, col] = g
        return out


def _finite(arr, what: str, rows, cols=None) -> np.ndarray:
    """Raise InputDataError naming the first non-finite entry of ``arr``."""
    arr = np.asarray(arr, dtype=float)
    bad = np.argwhere(~np.isfinite(arr))
    if len(bad):
        idx = tuple(bad[0])
        label = (f"{what}[{rows[idx[0]]}, {cols[idx[1]]}]" if cols is not None
                 else f"{what}[{rows[idx[0]]}]")
        raise InputDataError(f"cannot export the model: {label} is {arr[idx]} "
                             f"(all matrices, delays, trims and parameters must be finite)")
    return arr


def _names(ds: xr.Dataset, var: str, dim: str) -> list[str]:
    return [str(s) for s in ds[var][dim].values]


def export_spec(model: xr.Dataset, name: str | None = None) -> ExportSpec:
    """Check a model Dataset and lay it out for export (fixed parts, parameters, groups).

    Raises :class:`~sysid.core.errors.InputDataError` naming the entry for NaN/inf values,
    negative delays, missing variables or parameters that do not match the matrices.
    """
    if not isinstance(model, xr.Dataset):
        raise InputDataError(f"export needs a model xarray.Dataset, got {type(model).__name__}")
    for var in ("A", "B", "C", "D"):
        if var not in model:
            raise InputDataError(f"cannot export the model: it has no variable {var!r} "
                                 f"(see docs/data_model.md)")
    states = _names(model, "A", "state")
    inputs = _names(model, "B", "input")
    outputs = _names(model, "C", "output")
    A = _finite(model["A"].sel(state_dot=states, state=states).values, "A", states, states)
    B = _finite(model["B"].sel(state_dot=states, input=inputs).values, "B", states, inputs)
    C = _finite(model["C"].sel(output=outputs, state=states).values, "C", outputs, states)
    D = _finite(model["D"].sel(output=outputs, input=inputs).values, "D", outputs, inputs)
    tau = (model["delay"].sel(state_dot=states, input=inputs).values.astype(float)
           if "delay" in model else np.zeros_like(B))
    tau = _finite(tau, "delay", states, inputs)
    if np.any(tau < 0):
        i, k = np.argwhere(tau < 0)[0]
        raise InputDataError(f"cannot export the model: delay[{states[i]}, {inputs[k]}] = "
                             f"{tau[i, k]} s is negative")
    trim_in = (model["trim_input"].sel(input=inputs).values.astype(float)
               if "trim_input" in model else np.zeros(len(inputs)))
    trim_out = (model["trim_output"].sel(output=outputs).values.astype(float)
                if "trim_output" in model else np.zeros(len(outputs)))
    trim_in = _finite(trim_in, "trim_input", inputs)
    trim_out = _finite(trim_out, "trim_output", outputs)

    fixed = {"A": A.copy(), "B": B.copy(), "C": C.copy(), "D": D.copy()}
    axes = {"A": (states, states), "B": (states, inputs), "C": (outputs, states),
            "D": (outputs, inputs), "delay": (states, inputs)}
    parameters: list[tuple[str, str, int, int, float]] = []
    groups: list[tuple[int, int, list[int]]] = []
    descriptions: dict[str, str] = {}
    covered = np.zeros_like(B, dtype=bool)
    ties: list[tuple[int, str, int, int, float]] = []
    if "parameter" in model.dims and "matrix" in model:
        pnames = [str(p) for p in model["parameter"].values]
        values = _finite(model["value"].values, "value", pnames)
        for k, pname in enumerate(pnames):
            matrix = str(model["matrix"].values[k])
            row, col = str(model["row"].values[k]), str(model["column"].values[k])
            if matrix not in axes:
                raise InputDataError(f"cannot export the model: parameter {pname!r} acts on "
                                     f"matrix {matrix!r}, expected one of {list(axes)}")
            rows_ax, cols_ax = axes[matrix]
            if col not in cols_ax or (row not in rows_ax and not (matrix == "delay"
                                                                  and row == "*")):
                raise InputDataError(f"cannot export the model: parameter {pname!r} names "
                                     f"the entry {matrix}[{row},{col}], which the model "
                                     f"does not have")
            c = cols_ax.index(col)
            value = float(values[k])
            if matrix == "delay":
                rows = list(range(len(states))) if row == "*" else [states.index(row)]
                if value < 0:
                    raise InputDataError(f"cannot export the model: delay parameter {pname!r} "
                                         f"= {value} s is negative")
                if np.any(covered[rows, c]):
                    raise InputDataError(f"cannot export the model: delay parameter {pname!r} "
                                         f"overlaps another delay on input {col!r}")
                disagree = [i for i in rows if B[i, c] != 0 and abs(tau[i, c] - value) > 1e-12]
                if disagree:
                    raise InputDataError(
                        f"cannot export the model: delay parameter {pname!r} = {value} s but "
                        f"delay[{states[disagree[0]]}, {col}] = {tau[disagree[0], c]} s")
                covered[rows, c] = True
                parameters.append((pname, "delay", len(groups), c, value))
                groups.append((c, len(parameters) - 1, rows))
            else:
                r = rows_ax.index(row)
                fixed[matrix][r, c] -= value
                parameters.append((pname, matrix, r, c, value))
                text = model["also"].values[k] if "also" in model else ""
                for trow, tcol, scale in parse_tied_entries(text or ""):
                    if trow not in rows_ax or tcol not in cols_ax:
                        raise InputDataError(f"cannot export the model: parameter {pname!r} "
                                             f"also sets {matrix}[{trow},{tcol}], which the "
                                             f"model does not have")
                    r2, c2 = rows_ax.index(trow), cols_ax.index(tcol)
                    fixed[matrix][r2, c2] -= scale * value
                    ties.append((len(parameters) - 1, matrix, r2, c2, scale))
            descriptions[pname] = _parameter_description(model, k, matrix, row, col)
    # Delays that no parameter covers (e.g. a hand-made Dataset): one group per input and
    # delay value, exposed as a parameter tau_<input>[_<n>].
    for c, col in enumerate(inputs):
        extra = sorted({float(tau[i, c]) for i in range(len(states))
                        if tau[i, c] > 0 and not covered[i, c]})
        for j, value in enumerate(extra):
            rows = [i for i in range(len(states)) if not covered[i, c] and tau[i, c] == value]
            pname = f"tau_{col}" if len(extra) == 1 else f"tau_{col}_{j + 1}"
            parameters.append((pname, "delay", len(groups), c, value))
            groups.append((c, len(parameters) - 1, rows))
            descriptions[pname] = (f"delay of the B entries ({', '.join(states[i] for i in rows)})"
                                   f" of input {col}, s")
    x_scale = np.array([_si_scale(s) for s in states])
    y_scale = np.array([_si_scale(s) for s in outputs])
    method = str(model.attrs.get("method", "model"))
    return ExportSpec(
        name=name or f"sysid_{method}", states=states, inputs=inputs, outputs=outputs,
        A0=fixed["A"], B0=fixed["B"], C0=fixed["C"], D0=fixed["D"], parameters=parameters,
        ties=ties, groups=groups, trim_input=trim_in, trim_output=trim_out, x_scale=x_scale,
        y_scale=y_scale, descriptions=descriptions,
        attrs={k: v for k, v in model.attrs.items() if isinstance(v, (str, int, float))})


def _parameter_description(model: xr.Dataset, k: int, matrix: str, row: str, col: str) -> str:
    where = {"A": f"A[{row},{col}]", "B": f"B[{row},{col}]", "C": f"C[{row},{col}]",
             "D": f"D[{row},{col}]", "delay": f"delay of B[{row},{col}], s"}[matrix]
    text = f"identified parameter on {where}" if matrix != "delay" else where
    if "free" in model and not bool(model["free"].values[k]):
        text += ", fixed"
    if "cramer_rao_percent" in model:
        cr = float(model["cramer_rao_percent"].values[k])
        if np.isfinite(cr):
            text += f", Cramer-Rao bound {cr:.3g} %"
    return text


def _si_scale(channel: str) -> float:
    """FMU unit per analysis unit of a channel (1 for non-channels)."""
    if channel in CHANNELS:
        ch = CHANNELS[channel]
        return conversion_factor(ch.unit, ch.si_unit)
    return 1.0


def _analysis_unit(name: str) -> str | None:
    return CHANNELS[name].unit if name in CHANNELS else None


# ------------------------------------------------------------------------------------------
# units


def _ratio_unit(num: str | None, den: str | None, per_second: bool) -> UnitDefinition | None:
    """Unit of ``num / den`` (times 1/s for a state derivative row) in analysis units, or None
    when a component is unknown (non-channel states carry no unit)."""
    if num is None or den is None or num not in UNITS or den not in UNITS:
        return None
    en, fn = dict(UNITS[num].exponents), UNITS[num].factor
    ed, fd = dict(UNITS[den].exponents), UNITS[den].factor
    exps = {k: en.get(k, 0) - ed.get(k, 0) for k in set(en) | set(ed)}
    if per_second:
        exps["s"] = exps.get("s", 0) - 1
    exps = {k: v for k, v in exps.items() if v}
    factor = fn / fd
    num_name = f"{num}/s" if per_second else num
    num_name = (num_name.replace("/s/s", "/s2").replace("^2/s", "3").replace("s2/s", "s3"))
    if not exps and math.isclose(factor, 1.0):
        name, factor = "1", 1.0
    elif exps == {"s": -1} and math.isclose(factor, 1.0):
        name, factor = "1/s", 1.0
    elif den == "1":
        name = num_name
    else:
        name = f"{num_name}/{den}" if den == "%" else f"({num_name})/({den})"
    return UnitDefinition(name, Unit.of(name, factor, **exps).exponents, factor)


def _parameter_unit(spec: ExportSpec, matrix: str, row: int, col: int
                    ) -> UnitDefinition | None:
    if matrix == "delay":
        return _ratio_unit("s", "1", False)
    st, inp, out = spec.states, spec.inputs, spec.outputs
    if matrix == "A":
        return _ratio_unit(_analysis_unit(st[row]), _analysis_unit(st[col]), True)
    if matrix == "B":
        return _ratio_unit(_analysis_unit(st[row]), _analysis_unit(inp[col]), True)
    if matrix == "C":
        return _ratio_unit(_analysis_unit(out[row]), _analysis_unit(st[col]), False)
    return _ratio_unit(_analysis_unit(out[row]), _analysis_unit(inp[col]), False)


# ------------------------------------------------------------------------------------------
# variables and generated files


def fmu_variables(spec: ExportSpec, pade_order: int) -> tuple[list[FmuVariable], dict]:
    """The FMU's variables in value-reference order and the unit definitions they use.

    Layout (what model.c expects through linear_dims.h): states ``x_*`` then the Pade states,
    their derivatives, inputs, outputs, ``trim_<input>``, ``trim_<output>``, the parameters.
    """
    units: dict[str, UnitDefinition] = {}

    def si(channel: str, derivative: bool = False):
        if channel not in CHANNELS:
            return None, None
        unit = CHANNELS[channel].si_unit
        if derivative:
            unit = DERIVATIVE_UNIT.get(unit)
            if unit is None:
                return None, None
        ud = UnitDefinition.of(unit)
        units[unit] = ud
        display = ud.displays[0][0] if ud.displays and channel not in ("lon", "lat", "col",
                                                                       "ped") else None
        return unit, display

    states, derivs, others = [], [], []
    for s in spec.states:
        unit, disp = si(s)
        states.append(FmuVariable(fmi_name(f"x_{s}"), c_identifier(f"x_{s}"), "state", unit,
                                  disp, 0.0, f"state {s}: perturbation from trim"))
    for g, (col, par, _rows) in enumerate(spec.groups):
        pname = spec.parameters[par][0]
        for i in range(pade_order):
            states.append(FmuVariable(
                fmi_name(f"pade_{pname}_{i + 1}"), f"pade_{g}_{i + 1}", "state", None, None,
                0.0, f"state {i + 1} of the order-{pade_order} Pade approximant of delay "
                     f"{pname} (model exchange only; constant in co-simulation)"))
    for v in states:
        unit, disp = (None, None)
        if v.c_name.startswith("x_") and v.unit:
            unit = DERIVATIVE_UNIT[v.unit]
            ud = UnitDefinition.of(unit)
            units[unit] = ud
            disp = ud.displays[0][0] if v.display_unit and ud.displays else None
        derivs.append(FmuVariable(f"der({v.name})", f"der_{v.c_name}", "derivative", unit, disp,
                                  None, f"time derivative of {v.name}", state_of=v.name))
    for k, name in enumerate(spec.inputs):
        unit, _ = si(name)
        others.append(FmuVariable(fmi_name(name), c_identifier(name), "input", unit, None,
                                  float(spec.trim_input[k]),
                                  f"{CHANNELS[name].long_name if name in CHANNELS else name}"
                                  f", absolute"))
    for name in spec.outputs:
        unit, disp = si(name)
        others.append(FmuVariable(fmi_name(name), c_identifier(name), "output", unit, disp, None,
                                  f"{CHANNELS[name].long_name if name in CHANNELS else name}"
                                  f", absolute (trim + C x + D u)"))
    for k, name in enumerate(spec.inputs):
        unit, _ = si(name)
        others.append(FmuVariable(fmi_name(f"trim_{name}"), c_identifier(f"trim_{name}"),
                                  "parameter", unit, None, float(spec.trim_input[k]),
                                  f"trim value of input {name}"))
    for k, name in enumerate(spec.outputs):
        unit, disp = si(name)
        others.append(FmuVariable(fmi_name(f"trim_{name}"), c_identifier(f"trim_{name}"),
                                  "parameter", unit, disp,
                                  float(spec.trim_output[k] * spec.y_scale[k]),
                                  f"trim value of output {name}"))
    for pname, matrix, row, col, value in spec.parameters:
        ud = _parameter_unit(spec, matrix, row, col)
        if ud is not None:
            units.setdefault(ud.name, ud)
        others.append(FmuVariable(fmi_name(pname), "p_" + c_identifier(pname), "parameter",
                                  ud.name if ud else None, None, float(value),
                                  spec.descriptions.get(pname, "parameter") + " (analysis units)"))
    variables = states + derivs + others
    for vr, var in enumerate(variables):
        var.vr = vr
    _check_unique(variables)
    return variables, units


def _check_unique(variables: list[FmuVariable]) -> None:
    for attr, what in (("name", "FMI variable name"), ("c_name", "C identifier")):
        seen: dict[str, str] = {}
        for v in variables:
            key = getattr(v, attr)
            if key in seen:
                raise InputDataError(f"cannot export the model: {what} {key!r} is used twice "
                                     f"(rename the state, input, output or parameter)")
            seen[key] = v.name


def _c_array(name: str, ctype: str, values, per_line: int = 6) -> str:
    values = list(values) or [0]
    items = [repr(float(v)) if ctype == "double" else str(int(v)) for v in values]
    lines = [", ".join(items[i:i + per_line]) for i in range(0, len(items), per_line)]
    return f"static const {ctype} {name}[{len(values)}] = {{\n    " + ",\n    ".join(lines) + "\n};\n"


def generate_dims(spec: ExportSpec, variables: list[FmuVariable], pade_order: int,
                  me_delay: str = "buffer") -> str:
    """``linear_dims.h``: sizes and value-reference offsets of the exported model;
    ``pade_order`` is 0 with ``me_delay="buffer"`` (no Pade states)."""
    first = {}
    for v in variables:
        first.setdefault(v.kind, v.vr)
    n_states = sum(v.kind == "state" for v in variables)
    n_x, n_u, n_y = len(spec.states), len(spec.inputs), len(spec.outputs)
    vr_par0 = 2 * n_states + 2 * n_u + 2 * n_y
    lines = [
        "/* Generated by sysid.fmi.export; do not edit. Sizes and value references of one model. */",
        "#ifndef LINEAR_DIMS_H", "#define LINEAR_DIMS_H", "",
        f"#define N_X {n_x}", f"#define N_U {n_u}", f"#define N_Y {n_y}",
        f"#define N_PAR {len(spec.parameters)}", f"#define N_GROUPS {len(spec.groups)}",
        f"#define N_TIE {len(spec.ties)}",
        f"#define PADE_ORDER {pade_order if spec.groups else 0}",
        "/* model exchange: delays from the input history (1) or Pade states (0) */",
        f"#define ME_DELAY_BUFFER {1 if me_delay == 'buffer' else 0}", "",
        f"#define VR_U0 {2 * n_states}", f"#define VR_Y0 {2 * n_states + n_u}",
        f"#define VR_TRIM_U0 {2 * n_states + n_u + n_y}",
        f"#define VR_TRIM_Y0 {2 * n_states + 2 * n_u + n_y}", f"#define VR_PAR0 {vr_par0}", "",
        "enum { MATRIX_A = 0, MATRIX_B = 1, MATRIX_C = 2, MATRIX_D = 3, MATRIX_DELAY = 4 };",
        "", "#endif", "",
    ]
    return "\n".join(lines)


def generate_tables(spec: ExportSpec) -> str:
    """``linear_tables.h``: fixed parts, parameter map, delay groups, unit scales."""
    groups = spec.groups
    out = ["/* Generated by sysid.fmi.export; do not edit. Included by model.c only. */",
           "#ifndef LINEAR_TABLES_H", "#define LINEAR_TABLES_H", "",
           # names may contain "*/": escape them, not the comment's own terminator
           "/* " + (f"model {spec.name}: states {', '.join(spec.states)}; inputs "
                    f"{', '.join(spec.inputs)}; outputs {', '.join(spec.outputs)}"
                    ).replace("*/", "* /").replace("/*", "/ *") + " */",
           "/* fixed parts of the matrices, analysis units, row-major */",
           f"static const double A0[N_X][N_X] = {{{_rows(spec.A0)}}};",
           f"static const double B0[N_X][N_U] = {{{_rows(spec.B0)}}};",
           f"static const double C0[N_Y][N_X] = {{{_rows(spec.C0)}}};",
           f"static const double D0[N_Y][N_U] = {{{_rows(spec.D0)}}};", "",
           "/* FMU unit per analysis unit (x_fmu = X_SCALE x, y_fmu = Y_SCALE y) */",
           _c_array("X_SCALE", "double", spec.x_scale),
           _c_array("Y_SCALE", "double", spec.y_scale),
           "/* parameter k adds to entry (PAR_ROW, PAR_COL) of PAR_MATRIX; a delay parameter",
           " * sets the delay of group PAR_ROW */",
           _c_array("PAR_MATRIX", "int", [_MATRIX_CODE[p[1]] for p in spec.parameters]),
           _c_array("PAR_ROW", "int", [p[2] for p in spec.parameters]),
           _c_array("PAR_COL", "int", [p[3] for p in spec.parameters]),
           "/* tied parameters: parameter TIE_PAR[t] also adds TIE_SCALE[t] times its value to",
           " * entry (TIE_ROW, TIE_COL) of TIE_MATRIX */",
           _c_array("TIE_PAR", "int", [t[0] for t in spec.ties]),
           _c_array("TIE_MATRIX", "int", [_MATRIX_CODE[t[1]] for t in spec.ties]),
           _c_array("TIE_ROW", "int", [t[2] for t in spec.ties]),
           _c_array("TIE_COL", "int", [t[3] for t in spec.ties]),
           _c_array("TIE_SCALE", "double", [t[4] for t in spec.ties]),
           "static const char *const PAR_NAMES[%d] = {\n    %s\n};\n" % (
               max(1, len(spec.parameters)),
               ",\n    ".join([c_string(p[0]) for p in spec.parameters] or ['""'])),
           "/* delay groups: input and parameter of each; delay group of each B entry */",
           _c_array("GROUP_INPUT", "int", [g[0] for g in groups]),
           _c_array("GROUP_PAR", "int", [g[1] for g in groups]),
           _c_array("ENTRY_GROUP", "int", spec.entry_group.ravel()),
           "#endif", ""]
    return "\n".join(out)


def _rows(matrix: np.ndarray) -> str:
    return ", ".join("{" + ", ".join(repr(float(v)) for v in row) + "}" for row in matrix)


#: FMI causality, variability and initial of each kind of variable of an exported model.
_POLICY = {"state": ("local", "continuous", "exact"),
           "derivative": ("local", "continuous", None),
           "input": ("input", "continuous", None),
           "output": ("output", "continuous", "calculated"),
           "parameter": ("parameter", "fixed", "exact")}


def describe(spec: ExportSpec, variables: list[FmuVariable], units: dict, guid: str,
             identifier: str, step_size: float, source_files: list[str],
             me_delay: str = "buffer") -> FmuDescription:
    """The exported FMU in the data model of :mod:`sysid.fmi.description`.

    With delays held in an input history (``me_delay="buffer"``) the model-exchange FMU needs
    ``fmi2CompletedIntegratorStep``: it raises a step event where an input update makes a
    delayed input jump, so that the integrator restarts there.
    """
    desc = (f"Linear model {spec.attrs.get('method', '')} ({spec.attrs.get('structure', '')}) "
            f"exported by sysid: x' = A x + B~ u(t - tau), y = trim + C x + D u").strip()
    scalars = []
    for v in variables:
        causality, variability, initial = _POLICY[v.kind]
        scalars.append(ScalarVariable(
            name=v.name, c_name=v.c_name, value_reference=v.vr, kind=v.kind,
            causality=causality, variability=variability, initial=initial,
            description=v.description, unit=v.unit, display_unit=v.display_unit,
            start=v.start, derivative_of=v.state_of))
    return FmuDescription(
        model_name=spec.name, identifier=identifier, guid=guid, description=desc,
        generation_tool=f"sysid {sysid.__version__}", source_files=tuple(source_files),
        variables=tuple(scalars), units=tuple(units[name] for name in sorted(units)),
        experiment=(("start", 0.0), ("stop", 10.0), ("step", float(step_size))),
        completed_integrator_step_not_needed=not (me_delay == "buffer" and spec.groups),
        provides_directional_derivative=True)


def generate_model_description(spec: ExportSpec, variables: list[FmuVariable], units: dict,
                               guid: str, identifier: str, step_size: float,
                               source_files: list[str], me_delay: str = "buffer",
                               fmi_version: int = 2) -> str:
    """``modelDescription.xml`` (FMI 2.0 or 3.0, model exchange and co-simulation)."""
    return model_description(describe(spec, variables, units, guid, identifier, step_size,
                                      source_files, me_delay), fmi_version)


# ------------------------------------------------------------------------------------------
# compiling and packaging


def compile_library(src: Path, identifier: str, out_dir: Path,
                    source_files: list[str] | None = None) -> Path:
    """Compile the FMU's C files (``source_files`` in ``src``, default every ``*.c``) into its
    shared library with the machine's C compiler (the same compiler and flags as the truth
    FMU). Raises FMUError with the compiler's first error line."""
    _, ext = platform_folder()
    files = ([src / f for f in source_files] if source_files is not None
             else sorted(src.glob("*.c")))
    return compile_shared_library(files, src, out_dir / f"{identifier}{ext}",
                                  what=f"the exported FMU {identifier}")


def export_fmu(model_ds: xr.Dataset, path, *, fmi_version: int = 2,
               model_name: str | None = None, step_size: float = DEFAULT_STEP,
               me_delay: str = "buffer", pade_order: int = DEFAULT_PADE_ORDER,
               quiet: bool = True) -> Path:
    """Export a model Dataset as one FMU (model exchange + co-simulation, FMI 2.0 or 3.0).

    Parameters
    ----------
    model_ds : xr.Dataset
        Model of ``docs/data_model.md`` (``A B C D delay trim_input trim_output``, and the
        ``parameter`` table if identified).
    path : path-like
        The ``.fmu`` to write; written atomically (nothing appears if anything fails).
    fmi_version : {2, 3}
        FMI version. Both carry the same C model, exact directional derivatives and the C
        sources (FMI 2.0: ``<SourceFiles>`` in the model description; FMI 3.0:
        ``sources/buildDescription.xml``).
    model_name : str, optional
        ``modelName`` and (as a C identifier) ``modelIdentifier``; default
        ``sysid_<method>``.
    step_size : float
        Default communication step (s, DefaultExperiment). The input history of the delays
        grows as needed, so any step works.
    me_delay : {"buffer", "pade"}
        Delays in model exchange. ``"buffer"`` (default): an input history recorded at every
        input update (``fmi2SetReal`` / ``fmi3SetFloat64``); each delayed B entry sees
        ``u(t_k - tau)`` interpolated between the recorded samples and held until the next
        update, the convention of :func:`sysid.models.simulate`, so CVode reproduces it to
        its tolerance when the inputs are set at the sample instants (fmpy's
        ``simulate_fmu`` with a sample-and-hold input); updates that change a delayed input
        raise step events. ``"pade"``: Pade approximants with their own continuous states,
        a plain ODE independent of when inputs are set, but only approximate (error
        ~0.17 tau / n per unit step). See ``fmus/linear/README.md``.
    pade_order : int
        Order of each Pade approximant with ``me_delay="pade"`` (1-8; CVode struggles with
        the stiff higher orders). Ignored with ``"buffer"``.
    quiet : bool
        No progress lines.

    Returns
    -------
    Path of the written FMU.

    Examples
    --------
    >>> from sysid.data.netcdf import read_campaign
    >>> model = read_campaign("campaign.nc")["models/frequency_domain"].to_dataset()
    >>> export_fmu(model, "frequency_domain.fmu")        # FMI 2.0, ME and CS, C sources inside
    >>> export_fmu(model, "frequency_domain3.fmu", fmi_version=3)
    """
    progress = Progress(quiet=quiet)
    if fmi_version not in FMI_VERSIONS:
        raise InputDataError(f"fmi_version must be one of {list(FMI_VERSIONS)}, got "
                             f"{fmi_version!r}")
    if me_delay not in ME_DELAY_MODES:
        raise InputDataError(f"me_delay must be one of {list(ME_DELAY_MODES)}, got "
                             f"{me_delay!r}")
    if not (isinstance(pade_order, (int, np.integer)) and 1 <= pade_order <= 8):
        raise InputDataError(f"pade_order must be an integer from 1 to 8, got {pade_order!r}")
    if not (np.isfinite(step_size) and step_size > 0):
        raise InputDataError(f"step_size must be a positive number of seconds, got {step_size}")
    path = Path(path)
    if path.suffix != ".fmu":
        raise InputDataError(f"the exported file must end in .fmu, got {path}")

    spec = export_spec(model_ds, model_name)
    identifier = c_identifier(spec.name)
    # the buffer needs no extra states: pade_order only shapes the "pade" variant
    n_pade = int(pade_order) if me_delay == "pade" else 0
    variables, units = fmu_variables(spec, n_pade)
    source_files = [*boilerplate_sources(fmi_version), "model.c"]
    with progress.stage(f"export {spec.name} (FMI {fmi_version}) -> {path.name}"), \
            tempfile.TemporaryDirectory(prefix="sysid-export-") as tmp:
        work = Path(tmp)
        src = work / "sources"
        src.mkdir()
        _write_sources(src, spec, variables, n_pade, me_delay, fmi_version)
        digest = hashlib.sha256()
        for f in sorted(src.iterdir()):
            digest.update(f.name.encode() + b"\0" + f.read_bytes() + b"\0")
        digest.update(spec.name.encode())
        guid = "{" + str(uuid.UUID(hex=digest.hexdigest()[:32])) + "}"
        fmu = describe(spec, variables, units, guid, identifier, step_size, source_files,
                       me_delay)
        (src / "model_variables.h").write_text(variables_header(fmu))
        if fmi_version == 3:
            (src / "buildDescription.xml").write_text(build_description(fmu))
        description = model_description(fmu, fmi_version)
        library = compile_library(src, identifier, work, source_files)
        package_fmu(path, description, library, identifier, src, fmi_version=fmi_version)
    return path


def _write_sources(src: Path, spec: ExportSpec, variables, pade_order: int, me_delay: str,
                   fmi_version: int) -> None:
    """Copy the template, the shared boilerplate and the FMI headers; write the tables."""
    root = fmu_sources_dir()
    common = (*boilerplate_sources(fmi_version), *COMMON_HEADERS)
    for folder, names in ((root / "common", common), (root / "linear", TEMPLATE_FILES)):
        for name in names:
            if not (folder / name).is_file():
                raise FMUError(f"FMU source file {folder / name} is missing")
            shutil.copy2(folder / name, src / name)
    for name in FMI_HEADERS[fmi_version]:
        shutil.copy2(fmi_header_dir() / name, src / name)
    (src / "linear_dims.h").write_text(generate_dims(spec, variables, pade_order, me_delay))
    (src / "linear_tables.h").write_text(generate_tables(spec))
