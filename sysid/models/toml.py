"""Structures from TOML files: the format, the parser and the built-in structures.

:func:`structure_from_dict` documents the format; :func:`load_structure` reads a file or a
built-in structure by name from :data:`STRUCTURES_DIR` (``sysid/models/structures/*.toml``).
Values are in analysis units (ft/s, deg/s, deg, % of travel; delays in s; frequency range in
rad/s); A/B entries on the 6-DoF force rows are named like the derivatives of paper Eq. 18.

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 7 (state-space models with time delays).
* "Comparison of frequency and time domain identification of a helicopter in hover" (the
  reference paper of this project), Eq. 18-19.
"""

from __future__ import annotations

import math
import tomllib
from pathlib import Path
from typing import Mapping

import numpy as np

from sysid.core.errors import InputDataError
from sysid.core.kinematics import FORCE_LETTER, derivative_name, rigid_body_terms
from sysid.core.units import CONTROLS
from sysid.models.structure import (DELAY_BOUNDS, LinearStructure, Parameter, entry_name,
                                    parse_delay_entry)

__all__ = ["structure_from_dict", "load_structure", "structure_path", "builtin_structures",
           "declared_coherence_min", "STRUCTURES_DIR", "ACCELEROMETER_ROWS"]

#: Folder of the built-in TOML structures.
STRUCTURES_DIR = Path(__file__).resolve().parent / "structures"


def _parse_entry_key(key: str, matrix: str, states) -> tuple[str, str, str]:
    """``"M_q"`` or ``"q,u"`` -> (name, row, column)."""
    if "," in key:
        row, col = (x.strip() for x in key.split(","))
        if matrix in "AB" and row in FORCE_LETTER and (col in FORCE_LETTER or col in CONTROLS):
            return derivative_name(row, col), row, col
        return entry_name(matrix, row, col), row, col
    letters = {v: k for k, v in FORCE_LETTER.items()}
    if "_" in key and key.split("_", 1)[0] in letters:
        letter, col = key.split("_", 1)
        return key, letters[letter], col
    raise InputDataError(f"matrix {matrix} entry {key!r}: use 'row,column' or a derivative name "
                         f"like 'M_q'")


def structure_from_dict(spec: Mapping, *, trim: Mapping[str, float] | None = None,
                        source: str = "<dict>") -> LinearStructure:
    """Build a structure from its TOML description (already parsed).

    Format (every table optional except ``states`` and ``inputs``)::

        name = "hover_6dof"
        description = "..."
        base = "hover_hybrid"              # optional: a built-in name or a path (relative
                                           # to this file) whose TOML this one extends: its
                                           # [A], [B], [delays]... entries are added or
                                           # replaced one by one, other keys replaced
        remove = ["tau_col"]               # optional: base entries (as the base names
                                           # them) to drop
        states  = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]
        inputs  = ["lon", "lat", "col", "ped"]
        outputs = [...]                    # default: the states (C = I)
        process_noise = ["u", "v", "w"]    # optional: the states whose equations carry the
                                           # filter error's process noise (where the
                                           # disturbances enter); default its "measured"
        frequency_range = [0.3, 20.0]      # optional: rad/s, the band where the structure
                                           # is valid (its frequency-domain fit's band)
        pairs = ["q/lon", "p/lat"]         # optional: "output/input" responses its
                                           # frequency-domain fit uses; default the paper's
        coherence_min = 0.4                # optional: that fit's coherence admission;
                                           # default the guideline's 0.6

        [kinematics]                       # fixed rigid-body terms in A (6-DoF states only)
        theta0 = "trim"                    # deg; "trim" = from the data's trim_theta
        phi0 = "trim"                      # deg; "trim" = trim_phi
        u0 = "trim"                        # ft/s (also v0, w0); default "trim", else 0 if absent

        [trim]                             # absolute trim values (optional; data trim wins)
        lon = 66.18

        [A]                                # entries "row,column" or derivative names
        M_q = { value = -3.5 }             # free (default), start value
        X_u = { value = 0.0, free = false }
        "q,u" = 0.02                       # shorthand: free, start 0.02
        L_p = { value = -10, lower = -50, upper = 0 }
        "a1,a1" = { value = -14, also = ["b1,b1"] }        # one parameter on two entries
        "a1,b1" = { value = 1, also = [["b1,a1", -1.0]] }  # ... the second one negated

        [B]
        M_lon = { value = 1.0 }

        [C]                                # added to the default C (identity selection)
        [D]

        [output_equations]                 # outputs that are not states (optional)
        h_dot = { state = { w = -1.0 } }   # y = sum c x + sum m (x' - K x) + sum d u; tables
                                           # state, derivative, input (fixed coefficients)

        [sensors]                          # accelerometer position from the CG, body axes, ft
        accelerometer = [0.0, 0.0, 0.0]    # x fwd, y right, z down; default the CG

        [delays]                           # per B entry ("row,input") or per input ("input")
        tau_L_lon = { entry = "p,lon", value = 0.1 }             # bounds default 0 .. 0.3 s
        tau_L_lat = { entry = "p,lat", value = 0.1, keep = true }  # never removed by reduction
        tau_ped = { entry = "ped", value = 0.05, free = false }

    A/B entries on the 6-DoF force rows get derivative names (``"q,u"`` -> ``M_u``); other
    entries are named ``A[row,column]``. Entries not listed are fixed at the fixed part
    (kinematics for A, zero otherwise). ``also`` (A and B) ties further entries of the same
    matrix to the parameter, each ``"row,column"`` (same value) or ``["row,column", scale]``
    (``scale`` times the value): one physical constant in several equations is one unknown,
    e.g. the tail rotor's thrust in the roll and yaw rows (``scale`` from its arms).

    Outputs that are not states need an output equation: ``ax ay az`` have a built-in one,
    the body-axis specific force at the accelerometer (ft/s^2, gravity excluded): the
    aerodynamic and control part of the ``u v w`` force rows (``x' - K x`` with ``K`` the
    ``[kinematics]`` terms), plus the lever-arm terms ``omega' x r`` of ``[sensors]
    accelerometer`` (:data:`ACCELEROMETER_ROWS`; :mod:`sysid.models.structure`). Any other
    is given in ``[output_equations]``.

    Parameters
    ----------
    spec : mapping
        The parsed TOML.
    trim : mapping, optional
        ``channel -> absolute trim value`` (analysis units), e.g. from a campaign's
        ``trim_<channel>`` attributes; used for ``"trim"`` kinematics and the trim Dataset
        variables.
    source : str
        File name for error messages.
    """
    trim = dict(trim or {})
    if not isinstance(spec, Mapping):
        raise InputDataError(f"structure {source}: expected a table of keys, got "
                             f"{type(spec).__name__}")
    for key in ("states", "inputs"):
        if key not in spec:
            raise InputDataError(f"structure {source}: missing required key {key!r}")
    states = _names(spec["states"], f"structure {source}: states")
    inputs = _names(spec["inputs"], f"structure {source}: inputs")
    outputs = _names(spec.get("outputs", states), f"structure {source}: outputs")
    name = _text(spec.get("name", Path(source).stem), f"structure {source}: name")
    _text(spec.get("description", ""), f"structure {source}: description")
    for table in ("kinematics", "trim", "A", "B", "C", "D", "delays", "output_equations",
                  "sensors"):
        if table in spec and not isinstance(spec[table], Mapping):
            raise InputDataError(f"structure {source}: [{table}] must be a table, got "
                                 f"{spec[table]!r}")
    known_tables = {"name", "description", "states", "inputs", "outputs", "kinematics", "trim",
                    "frequency_range", "pairs", "coherence_min", "process_noise",
                    "output_equations", "sensors", "A", "B", "C", "D", "delays"}
    extra = set(spec) - known_tables
    if extra:
        raise InputDataError(f"structure {source}: unknown keys {sorted(extra)}; "
                             f"known: {sorted(known_tables)}")
    A0 = np.zeros((len(states), len(states)))
    attrs = {}
    if "kinematics" in spec:
        kin = dict(spec["kinematics"])
        resolved = {}
        for key, channel in (("theta0", "theta"), ("phi0", "phi"), ("u0", "u"), ("v0", "v"),
                             ("w0", "w")):
            val = kin.get(key, "trim")
            if val != "trim":
                val = _number(val, f"structure {source}: [kinematics] {key}",
                              "a number or \"trim\"")
            if val == "trim":
                if channel in trim:
                    val = trim[channel]
                elif key in ("theta0", "phi0"):
                    raise InputDataError(
                        f"structure {source}: [kinematics] {key} = 'trim' needs the trim "
                        f"attitude trim_{channel} (deg) from the data; none was given")
                else:
                    val = 0.0
            resolved[key] = float(val)
        try:
            A0 = rigid_body_terms(**resolved, states=states).values
        except ValueError as exc:
            raise InputDataError(f"structure {source}: [kinematics] {exc}") from None
        attrs = {"theta0_deg": resolved["theta0"], "phi0_deg": resolved["phi0"],
                 "u0_ft_s": resolved["u0"], "v0_ft_s": resolved["v0"],
                 "w0_ft_s": resolved["w0"], "kinematics": 1}
    if "frequency_range" in spec:
        # The band where the structure is a valid model (a quasi-steady model is only valid
        # below the rotor, inflow and actuator modes); fits use it unless told otherwise.
        band = spec["frequency_range"]
        try:
            lo, hi = (float(v) for v in band)
        except (TypeError, ValueError):
            raise InputDataError(f"structure {source}: frequency_range must be two numbers "
                                 f"[omega_min, omega_max] in rad/s, got {band!r}") from None
        if not 0.0 <= lo < hi:
            raise InputDataError(f"structure {source}: frequency_range needs 0 <= omega_min < "
                                 f"omega_max, got {band!r}")
        attrs.update(fit_omega_min=lo, fit_omega_max=hi)
    if "pairs" in spec:
        # the responses the structure is fitted to, where they differ from the paper's
        pairs = _names(spec["pairs"], f"structure {source}: pairs")
        bad = [p for p, (o, _, i) in zip(pairs, (p.partition("/") for p in pairs))
               if o not in outputs or i not in inputs]
        if bad or not pairs or len(set(pairs)) != len(pairs):
            raise InputDataError(f"structure {source}: pairs must be distinct 'output/input' "
                                 f"names with an output of {outputs} and an input of "
                                 f"{inputs}; got {bad or pairs}")
        attrs["fit_pairs"] = ",".join(pairs)
    gate = _coherence_min(spec, source)
    if gate is not None:
        attrs["fit_coherence_min"] = gate
    if "process_noise" in spec:
        noisy = _names(spec["process_noise"], f"structure {source}: process_noise")
        unknown = [s for s in noisy if s not in states]
        if unknown:
            raise InputDataError(f"structure {source}: process_noise names {unknown}, which "
                                 f"are not states; expected some of {states}")
        attrs["process_noise"] = ",".join(noisy)
    trim_all = {str(k): _number(v, f"structure {source}: [trim] {k}")
                for k, v in dict(spec.get("trim", {})).items()}
    trim_all.update(trim)
    params: list[Parameter] = []
    for matrix in "ABCD":
        for key, item in dict(spec.get(matrix, {})).items():
            nm, row, col = _parse_entry_key(key, matrix, states)
            item = {"value": item} if not isinstance(item, Mapping) else dict(item)
            where = f"structure {source}: [{matrix}] {key}"
            _check_fields(item, {"value", "free", "lower", "upper", "name", "keep", "also"},
                          where)
            params.append(Parameter(_text(item.get("name", nm), f"{where}: name"), matrix,
                                    row, col,
                                    _number(item.get("value", 0.0), f"{where}: value"),
                                    _flag(item.get("free", True), f"{where}: free"),
                                    _number(item.get("lower", -math.inf), f"{where}: lower"),
                                    _number(item.get("upper", math.inf), f"{where}: upper"),
                                    _flag(item.get("keep", False), f"{where}: keep"),
                                    _also(item.get("also", []), matrix, f"{where}: also")))
    for nm, item in dict(spec.get("delays", {})).items():
        item = dict(item) if isinstance(item, Mapping) else {"entry": item}
        if "entry" not in item:
            raise InputDataError(f"structure {source}: [delays] {nm}: missing 'entry' "
                                 f"('row,input' or 'input')")
        where = f"structure {source}: [delays] {nm}"
        _check_fields(item, {"entry", "value", "free", "lower", "upper", "keep"}, where)
        try:
            row, col = parse_delay_entry(_text(item["entry"], f"{where}: entry"), nm)
        except InputDataError as exc:
            raise InputDataError(f"structure {source}: {exc}") from None
        params.append(Parameter(str(nm), "delay", row, col,
                                _number(item.get("value", 0.05), f"{where}: value"),
                                _flag(item.get("free", True), f"{where}: free"),
                                _number(item.get("lower", DELAY_BOUNDS[0]), f"{where}: lower"),
                                _number(item.get("upper", DELAY_BOUNDS[1]), f"{where}: upper"),
                                _flag(item.get("keep", False), f"{where}: keep")))
    K = A0.copy()  # the kinematic part: all of the fixed A a [kinematics] table builds
    C0, D0, M = _output_equations(spec, states, inputs, outputs, source)
    try:
        return LinearStructure(states=states, inputs=inputs, outputs=outputs, A0=A0,
                               C0=C0, D0=D0, output_equation=M, kinematic=K,
                               parameters=params,
                               trim_input={k: v for k, v in trim_all.items() if k in inputs},
                               trim_output={k: v for k, v in trim_all.items()
                                            if k in outputs},
                               name=name, description=str(spec.get("description", "")),
                               attrs=attrs)
    except (InputDataError, ValueError) as exc:
        # e.g. a parameter on a row or column the structure does not have
        raise InputDataError(f"structure {source}: {exc}") from None


#: Built-in output equations: accelerometer output -> its force row (specific force at the CG).
ACCELEROMETER_ROWS = {"ax": "u", "ay": "v", "az": "w"}
_RAD = math.pi / 180.0


def _output_equations(spec: Mapping, states, inputs, outputs, source: str):
    """``C0, D0, M`` of the outputs: identity selection of the states, the built-in
    accelerometer equations, the ``[output_equations]`` table and the lever arm of ``[sensors]``.

    Lever arm (sensor at ``r = (x, y, z)`` ft from the CG): ``a_s = a_cg + omega' x r +
    omega x (omega x r)``; about zero trim rates the last term is of second order, so
    ``ax += z q' - y r'``, ``ay += x r' - z p'``, ``az += y p' - x q'`` (p', q', r' in
    deg/s^2, hence the factor pi/180).
    """
    n, m, p = len(states), len(inputs), len(outputs)
    C0, D0, M = np.zeros((p, n)), np.zeros((p, m)), np.zeros((p, n))
    given = dict(spec.get("output_equations", {}))
    unknown = set(given) - set(outputs)
    if unknown:
        raise InputDataError(f"structure {source}: [output_equations] {sorted(unknown)} are "
                             f"not outputs ({list(outputs)})")
    sensors = dict(spec.get("sensors", {}))
    _check_fields(sensors, {"accelerometer"}, f"structure {source}: [sensors]")
    arm = sensors.get("accelerometer", [0.0, 0.0, 0.0])
    if not isinstance(arm, list) or len(arm) != 3:
        raise InputDataError(f"structure {source}: [sensors] accelerometer = {arm!r}: expected "
                             f"[x, y, z] in ft (body axes, from the CG)")
    x, y, z = (_number(v, f"structure {source}: [sensors] accelerometer") for v in arm)
    lever = {"ax": {"q": z, "r": -y}, "ay": {"r": x, "p": -z}, "az": {"p": y, "q": -x}}
    for o, out in enumerate(outputs):
        where = f"structure {source}: output {out!r}"
        if out in given:
            eq = given[out]
            if not isinstance(eq, Mapping):
                raise InputDataError(f"{where}: [output_equations] {out} must be a table with "
                                     f"'state', 'derivative' and/or 'input' tables")
            _check_fields(eq, {"state", "derivative", "input"}, where)
            for part, target, names in (("state", C0, states), ("derivative", M, states),
                                        ("input", D0, inputs)):
                for key, val in dict(eq.get(part, {})).items():
                    if key not in names:
                        raise InputDataError(f"{where}: {part} {key!r} is not one of "
                                             f"{list(names)}")
                    target[o, list(names).index(key)] += _number(val, f"{where}: {part} {key}")
        elif out in states:
            C0[o, states.index(out)] = 1.0
        elif out in ACCELEROMETER_ROWS:
            need = [ACCELEROMETER_ROWS[out]] + [r for r, d in lever[out].items() if d]
            missing = [s for s in need if s not in states]
            if missing:
                raise InputDataError(f"{where}: the accelerometer equation needs the states "
                                     f"{missing}")
            M[o, states.index(ACCELEROMETER_ROWS[out])] = 1.0
            for rate, dist in lever[out].items():
                if dist:
                    M[o, states.index(rate)] += dist * _RAD
        else:
            raise InputDataError(f"{where} is not a state and has no output equation (built-in: "
                                 f"{sorted(ACCELEROMETER_ROWS)}; others go in "
                                 f"[output_equations])")
    return C0, D0, M


def _also(value, matrix: str, where: str) -> tuple:
    """``also = ["b1,b1", ["b1,a1", -1.0]]`` -> ``(("b1", "b1", 1.0), ("b1", "a1", -1.0))``."""
    expected = ('a list of "row,column" or ["row,column", scale] (entries of the same '
                'matrix the parameter also sets)')
    if not isinstance(value, list):
        raise InputDataError(f"{where} = {value!r}: expected {expected}")
    if value and matrix not in ("A", "B"):
        raise InputDataError(f"{where}: only [A] and [B] parameters may set further entries")
    out = []
    for item in value:
        entry, scale = (item, 1.0) if isinstance(item, str) else (
            item if isinstance(item, list) and len(item) == 2 else (None, None))
        if not isinstance(entry, str) or entry.count(",") != 1:
            raise InputDataError(f"{where}: {item!r}: expected {expected}")
        row, col = (x.strip() for x in entry.split(","))
        out.append((row, col, _number(scale, f"{where}: {entry} scale")))
    return tuple(out)


def _number(value, where: str, expected: str = "a number") -> float:
    """``value`` as float when it is a TOML integer or float (not a boolean or a string)."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise InputDataError(f"{where} = {value!r}: expected {expected}")
    return float(value)


def _flag(value, where: str) -> bool:
    """``value`` when it is a TOML boolean: ``free = "false"`` would otherwise mean free."""
    if not isinstance(value, bool):
        raise InputDataError(f"{where} = {value!r}: expected true or false (a TOML boolean, "
                             "without quotes)")
    return value


def _text(value, where: str) -> str:
    if not isinstance(value, str):
        raise InputDataError(f"{where} = {value!r}: expected a string")
    return value


def _names(value, where: str) -> list[str]:
    if (not isinstance(value, list) or not value
            or not all(isinstance(v, str) and v for v in value)):
        raise InputDataError(f"{where} = {value!r}: expected a non-empty list of names "
                             '(e.g. ["u", "q"])')
    return list(value)


def _check_fields(item: Mapping, allowed: set[str], where: str) -> None:
    bad = set(item) - allowed
    if bad:
        raise InputDataError(f"{where}: unknown fields {sorted(bad)} "
                             f"({', '.join(sorted(allowed))})")


def builtin_structures() -> dict[str, Path]:
    """Built-in TOML structures shipped in ``sysid/models/structures``: ``name -> path``."""
    return {p.stem: p for p in sorted(STRUCTURES_DIR.glob("*.toml"))}


def structure_path(source: str | Path) -> Path:
    """The TOML file of a structure: ``source`` itself, or the built-in one of that name."""
    path = Path(source)
    builtin = builtin_structures()
    if not path.exists() and str(source) in builtin:
        path = builtin[str(source)]
    if not path.exists():
        raise InputDataError(f"structure file {source} not found (built-in structures: "
                             f"{sorted(builtin)})")
    return path


def _coherence_min(spec: Mapping, source: str) -> float | None:
    """The structure's ``coherence_min`` (checked), None when it declares none."""
    if "coherence_min" not in spec:
        return None
    # a structure may need points a 0.6 admission leaves out (W_gamma weighs them down)
    gate = _number(spec["coherence_min"], f"structure {source}: coherence_min")
    if not 0.0 < gate <= 1.0:
        raise InputDataError(f"structure {source}: coherence_min must lie in (0, 1], got "
                             f"{gate}")
    return gate


def declared_coherence_min(source: str | Path) -> float | None:
    """The coherence admission a structure file declares for its frequency-domain fit
    (TOML ``coherence_min``), None when it declares none; read without a trim."""
    path = structure_path(source)
    return _coherence_min(_read(path), str(path))


def load_structure(source: str | Path, *, trim: Mapping[str, float] | None = None
                   ) -> LinearStructure:
    """A structure from a TOML file, or a built-in one by name (e.g. ``"hover_6dof"``).

    See :func:`structure_from_dict` for the format and the meaning of ``trim``.
    """
    path = structure_path(source)
    return structure_from_dict(_read(path), trim=trim, source=str(path))


#: Tables a derived structure file (``base = "..."``) merges entry by entry into its
#: base's; every other key it gives replaces the base's.
MERGED_TABLES = ("kinematics", "trim", "A", "B", "C", "D", "output_equations", "sensors",
                 "delays")


def _read(path: Path, derived: tuple[Path, ...] = ()) -> dict:
    """The parsed TOML of a structure file, with errors that name it; a file with
    ``base = "<built-in name or path>"`` is its base's TOML (a path relative to the file)
    without the entries its ``remove`` list names, with its own keys laid over it
    (:data:`MERGED_TABLES` entry by entry)."""
    try:
        spec = tomllib.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError as exc:
        raise InputDataError(f"structure file {path}: not UTF-8 text (byte {exc.start}); "
                             "TOML files are UTF-8") from None
    except tomllib.TOMLDecodeError as exc:
        raise InputDataError(f"structure file {path}: invalid TOML: {exc}") from None
    except OSError as exc:
        raise InputDataError(f"structure file {path}: cannot be read ({exc})") from None
    if "base" not in spec:
        return spec
    base = _text(spec.pop("base"), f"structure file {path}: base")
    relative = path.parent / base
    base_path = structure_path(relative if relative.is_file() else base).resolve()
    chain = (*derived, path.resolve())
    if base_path in chain:
        raise InputDataError(f"structure file {path}: its base {base} leads back to itself "
                             f"({' -> '.join(str(p) for p in (*chain, base_path))})")
    merged = _read(base_path, chain)
    remove = (_names(spec.pop("remove"), f"structure file {path}: remove")
              if "remove" in spec else [])
    for name in remove:
        tables = [t for t in MERGED_TABLES
                  if isinstance(merged.get(t), Mapping) and name in merged[t]]
        if not tables:
            raise InputDataError(f"structure file {path}: remove names {name!r}, which its "
                                 f"base {base} does not have in any of {list(MERGED_TABLES)}")
        for t in tables:
            del merged[t][name]
    for key, value in spec.items():
        if key in MERGED_TABLES and isinstance(value, Mapping) and isinstance(
                merged.get(key, {}), Mapping):
            merged[key] = {**merged.get(key, {}), **value}
        else:
            merged[key] = value
    return merged
