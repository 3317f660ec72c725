"""Fuzzed files: the CSV importer and the structure TOML reader end in the project's own
errors (``sysid.core.errors.SysidError``) or a valid result, never another exception.

Issue 26 asks for 2,000 generated files per reader: that is the exhaustive form
(``SYSID_EXHAUSTIVE=1 pytest -m slow tests/test_fuzz.py``); the default suite runs 200 of
each. Hypothesis is derandomised, so every run generates the same files.

There is no MAT (or HDF5) time-history importer in sysid: ``sysid import`` reads CSV and
netCDF (netCDF files are fuzzed in tests/test_robustness_io.py).

The CSV generator builds files from parts a careless export or a broken logger produces:
headers with and without units (known, unknown, wrong-dimension units), the four delimiters,
decimal commas, comment and ``# sysid-attrs`` lines with random JSON, cells that are numbers
(ordinary, huge, tiny, NaN, inf), text or empty, ragged rows, time columns that jump, repeat
or run backwards; and raw bytes. The structure generator writes TOML documents from the
format's own vocabulary (tables, keys, inline tables) with values of every TOML type in
every place, plus byte-level mutations of the built-in structures.
"""

from __future__ import annotations

import json
import math
import os

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from sysid.core.errors import SysidError
from sysid.data.importers import read_time_history
from sysid.models.toml import builtin_structures, load_structure

EXHAUSTIVE = os.environ.get("SYSID_EXHAUSTIVE") == "1"
N_FILES = 2000 if EXHAUSTIVE else 200
FUZZ = settings(max_examples=N_FILES, deadline=None, derandomize=True, database=None,
                suppress_health_check=list(HealthCheck))

# --------------------------------------------------------------------------------------------
# CSV

NAMES = ["time", "t", "Time", "lon", "lat", "col", "ped", "u", "v", "w", "p", "q", "r",
         "phi", "theta", "psi", "ax", "x1", "", "q q", "lon[", "a,b"]
UNITS = [None, "s", "ms", "%", "deg", "rad", "deg/s", "rad/s", "ft/s", "m/s", "ft/s^2",
         "kg", "furlong", "", "seconds since 2020-01-01"]
NUMBERS = st.one_of(
    st.floats(allow_nan=True, allow_infinity=True),
    st.floats(min_value=-1e3, max_value=1e3),
    st.sampled_from([0.0, 1e300, -1e300, 1e-300, 5e3, 1e5]),
    st.integers(-10**20, 10**20))
CELLS = st.one_of(NUMBERS.map(repr), NUMBERS.map(str), st.sampled_from(
    ["", "nan", "NaN", "inf", "-inf", "abc", "1,5", "1.2.3", "0x10", "--1", " ", "1e309"]),
    st.text(max_size=6))


@st.composite
def csv_texts(draw) -> bytes:
    if draw(st.integers(0, 19)) == 0:
        return draw(st.binary(max_size=400))
    # Half the files are nearly valid (known columns and units, a uniform time, numbers in
    # range, a rare bad cell) so that the reader's success path is exercised too.
    clean = draw(st.booleans())
    delimiter = draw(st.sampled_from([",", ";", "\t"] if clean else [",", ";", "\t", " ", "|"]))
    if clean:
        names = ["time"] + draw(st.lists(st.sampled_from(["lon", "lat", "p", "q", "theta",
                                                          "x1"]), min_size=1, max_size=4,
                                         unique=True))
        n_cols = len(names)
        good = {"time": ["s", "ms", None], "lon": ["%", None], "lat": ["%"],
                "p": ["deg/s", "rad/s"], "q": ["deg/s", None], "theta": ["deg", "rad"],
                "x1": [None, "kg"]}
        units = [draw(st.sampled_from(good[n])) for n in names]
    else:
        n_cols = draw(st.integers(1, 5))
        names = [draw(st.sampled_from(NAMES)) for _ in range(n_cols)]
        if draw(st.booleans()):
            names[0] = "time"
        units = [draw(st.sampled_from(UNITS)) for _ in range(n_cols)]
    header = delimiter.join(f"{n} [{u}]" if u is not None else n for n, u in zip(names, units))
    lines = []
    if draw(st.integers(0, 3 if clean else 1)) == 0:
        attrs = draw(st.dictionaries(st.sampled_from(
            ["maneuver", "kind", "axis", "trim_lon", "trim_q", "seed", "sysid_attr_types",
             "time_offset", "x"]), st.one_of(st.none(), st.booleans(), NUMBERS, st.text(max_size=8),
                                             st.lists(st.integers(), max_size=3)), max_size=4))
        text = json.dumps(attrs) if clean or draw(st.booleans()) else draw(st.text(max_size=30))
        lines.append(f"# sysid-attrs: {text}")
    if draw(st.booleans()):
        lines.append("# a comment")
    lines.append(header)
    n_rows = draw(st.integers(2 if clean else 0, 40))
    dt = draw(st.sampled_from([0.01, 0.02, 1.0] + ([] if clean else [1e-9, 1e9])))
    time_style = "uniform" if clean and draw(st.integers(0, 3)) else draw(
        st.sampled_from(["uniform", "gap", "repeat", "backwards", "random"]))
    bad_cell = 400 if clean else 3
    for k in range(n_rows):
        t = k * dt
        if time_style == "gap" and k > n_rows // 2:
            t += 5 * dt
        elif time_style == "repeat" and k == n_rows // 2:
            t = (k - 1) * dt
        elif time_style == "backwards":
            t = -t
        elif time_style == "random":
            t = draw(NUMBERS)
        cells = [repr(t)] + [draw(CELLS) if draw(st.integers(0, bad_cell)) == 0
                             else repr(draw(st.floats(-1, 1) if clean else st.floats(-50, 150)))
                             for _ in range(n_cols - 1)]
        if draw(st.integers(0, 15 if not clean else 600)) == 0:
            cells = cells[:-1] if draw(st.booleans()) else cells + ["1"]
        if delimiter == ";" and draw(st.booleans()):
            cells = [c.replace(".", ",") for c in cells]
        lines.append(delimiter.join(cells))
    text = "\n".join(lines) + "\n"
    encoding = draw(st.sampled_from(["utf-8", "utf-8-sig"] if clean
                                    else ["utf-8", "utf-8-sig", "latin-1", "utf-16"]))
    try:
        return text.encode(encoding)
    except UnicodeEncodeError:
        return text.encode("utf-8", errors="replace")


OPTIONS = st.one_of(st.just({}), st.fixed_dictionaries({}, optional={
    "mapping": st.dictionaries(st.sampled_from(["lon", "q", "time", "zz"]),
                               st.sampled_from(NAMES), max_size=2),
    "units": st.dictionaries(st.sampled_from(["lon", "q", "time"]),
                             st.sampled_from([u for u in UNITS if u]), max_size=2),
    "trim": st.dictionaries(st.sampled_from(["lon", "q", "zz"]), NUMBERS, max_size=2),
    "kind": st.sampled_from(["sweep", "3211", None]),
}))


def _check_time_history(ds) -> None:
    t = ds["time"].values
    assert t.ndim == 1 and t.size >= 2 and np.all(np.isfinite(t)) and np.all(np.diff(t) > 0)
    for name, var in ds.data_vars.items():
        assert var.dims == ("time",), name
        assert np.all(np.isfinite(var.values)), name


@pytest.mark.slow
@FUZZ
@given(data=csv_texts(), options=OPTIONS)
def test_fuzzed_csv_files_raise_only_sysid_errors(tmp_path_factory, data, options):
    path = tmp_path_factory.mktemp("csv", numbered=True) / "sweep_lon_1.csv"
    path.write_bytes(data)
    try:
        ds = read_time_history(path, **options)
    except SysidError as exc:
        assert "Traceback" not in str(exc) and str(exc).strip()
        return
    _check_time_history(ds)


# --------------------------------------------------------------------------------------------
# structure TOML


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, int):
        return str(value)
    if isinstance(value, float):
        if math.isnan(value):
            return "nan"
        if math.isinf(value):
            return "inf" if value > 0 else "-inf"
        return repr(value)
    if isinstance(value, str):
        return _key(value)
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, dict):
        return "{" + ", ".join(f"{_key(k)} = {_toml_value(v)}"
                               for k, v in value.items()) + "}"
    raise TypeError(value)


def _key(text: str) -> str:
    """A TOML basic string (JSON's escapes, but astral characters as they are: TOML has no
    surrogate-pair escapes)."""
    return json.dumps(text, ensure_ascii=False)


def _toml(doc: dict) -> str:
    lines = [f"{_key(k)} = {_toml_value(v)}" for k, v in doc.items()
             if not (isinstance(v, dict) and k.isidentifier())]
    for k, v in doc.items():
        if isinstance(v, dict) and k.isidentifier():
            lines.append(f"[{k}]")
            lines += [f"{_key(kk)} = {_toml_value(vv)}" for kk, vv in v.items()]
    return "\n".join(lines) + "\n"


CHANNELS = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi", "lon", "lat", "col", "ped",
            "x", ""]
ENTRY_KEYS = ["q,q", "q,u", "p,lon", "M_q", "L_p", "Z_w", "X_u", "q,lon", "x,y", "M_",
              "q", "M_lon", "tau"]
FIELDS = ["value", "free", "keep", "lower", "upper", "name", "entry", "other"]
TEXT = st.text(st.characters(exclude_categories=["Cs"]), max_size=6)
SCALARS = st.one_of(st.booleans(), st.integers(-10**30, 10**30), st.floats(), TEXT, st.sampled_from(["trim", "true", "false", "q,lon",
                                                          "lon", "0.1"]))
VALUES = st.recursive(SCALARS, lambda inner: st.one_of(
    st.lists(inner, max_size=3),
    st.dictionaries(st.sampled_from(FIELDS), inner, max_size=3)), max_leaves=6)
ENTRY = st.one_of(VALUES, st.dictionaries(st.sampled_from(FIELDS), VALUES, max_size=5))
TABLES = {
    "A": st.dictionaries(st.sampled_from(ENTRY_KEYS), ENTRY, max_size=4),
    "B": st.dictionaries(st.sampled_from(ENTRY_KEYS), ENTRY, max_size=3),
    "C": st.dictionaries(st.sampled_from(ENTRY_KEYS), ENTRY, max_size=2),
    "D": st.dictionaries(st.sampled_from(ENTRY_KEYS), ENTRY, max_size=2),
    "delays": st.dictionaries(st.sampled_from(["tau_lon", "tau", "t2"]), ENTRY, max_size=3),
    "kinematics": st.dictionaries(st.sampled_from(["theta0", "phi0", "u0", "v0", "w0", "x"]),
                                  VALUES, max_size=3),
    "trim": st.dictionaries(st.sampled_from(CHANNELS), VALUES, max_size=3),
}


@st.composite
def structure_texts(draw) -> bytes:
    kind = draw(st.integers(0, 9))
    if kind == 0:  # raw bytes
        return draw(st.binary(max_size=300))
    if kind == 1:  # byte-level mutation of a built-in structure
        text = bytearray(draw(st.sampled_from(sorted(builtin_structures().values())))
                         .read_bytes())
        for _ in range(draw(st.integers(1, 6))):
            i = draw(st.integers(0, len(text) - 1))
            op = draw(st.integers(0, 2))
            if op == 0:
                del text[i]
            elif op == 1:
                text[i] = draw(st.integers(0, 255))
            else:
                text[i:i] = draw(st.sampled_from([b"\"", b"=", b"[", b"]", b"\n", b"true",
                                                  b"\xff", b"nan", b"{", b","]))
        return bytes(text)
    if kind <= 5:  # a valid structure, then 0-2 of its values replaced by anything
        doc = {"states": ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"],
               "inputs": ["lon"],
               "kinematics": {"theta0": draw(st.sampled_from(["trim", 2.5, 0])), "phi0": 0.0},
               "A": {"M_q": {"value": draw(st.floats(-5, 0)), "free": draw(st.booleans())},
                     "q,u": draw(st.floats(-1, 1)),
                     "X_u": {"value": -0.02, "lower": -1.0, "upper": 0.0,
                             "keep": draw(st.booleans())}},
               "B": {"M_lon": {"value": 1.0, "name": "M_lon"}},
               "delays": {"tau_lon": {"entry": "q,lon", "value": 0.05, "free": True}},
               "trim": {"lon": 50.0}, "frequency_range": [0.5, 12.0]}
        for _ in range(draw(st.integers(0, 2))):
            table = draw(st.sampled_from(sorted(doc)))
            if isinstance(doc[table], dict) and doc[table] and draw(st.booleans()):
                key = draw(st.sampled_from(sorted(doc[table])))
                item = doc[table][key]
                if isinstance(item, dict) and item and draw(st.booleans()):
                    item[draw(st.sampled_from(sorted(item)))] = draw(VALUES)
                else:
                    doc[table][key] = draw(VALUES)
            else:
                doc[table] = draw(VALUES)
        return _toml(doc).encode("utf-8", errors="surrogatepass")
    doc = {}
    for key, names in (("states", ["q", "u", "p"]), ("inputs", ["lon", "lat"])):
        if draw(st.integers(0, 5)):
            doc[key] = draw(st.one_of(st.lists(st.sampled_from(CHANNELS), min_size=0,
                                               max_size=3, unique=True),
                                      st.just(names), VALUES))
    if draw(st.booleans()):
        doc["outputs"] = draw(st.one_of(st.lists(st.sampled_from(CHANNELS), max_size=3),
                                        VALUES))
    for key in ("name", "description", "frequency_range", "extra"):
        if draw(st.integers(0, 3)) == 0:
            doc[key] = draw(VALUES)
    for table, strategy in TABLES.items():
        if draw(st.booleans()):
            doc[table] = draw(strategy) if draw(st.integers(0, 7)) else draw(SCALARS)
    return _toml(doc).encode("utf-8", errors="surrogatepass")


@pytest.mark.slow
@FUZZ
@given(data=structure_texts(), trim=st.one_of(st.none(), st.dictionaries(
    st.sampled_from(["theta", "phi", "u", "lon"]), st.floats(-90, 90), max_size=3)))
def test_fuzzed_structure_files_raise_only_sysid_errors(tmp_path_factory, data, trim):
    path = tmp_path_factory.mktemp("toml", numbered=True) / "s.toml"
    path.write_bytes(data)
    try:
        structure = load_structure(path, trim=trim)
    except SysidError as exc:
        assert str(exc).strip()
        return
    # a structure that loads is usable: its parameters are numbers and booleans
    for p in structure.parameters:
        assert isinstance(p.free, bool) and isinstance(p.keep, bool)
        assert isinstance(p.value, float) and isinstance(p.lower, float)
