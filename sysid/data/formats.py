"""MATLAB (v5, v7.3) and HDF5 files of time histories: sniffing, raw reading and writing.

This module knows the containers, not the channels: :func:`read_groups` returns, for every
manoeuvre a file holds, its named numeric arrays, units and attributes (a :class:`Group`);
:mod:`sysid.data.importers` picks the time vector and channels, converts units and checks
them. :func:`write_groups` writes manoeuvres in the layout below, which
:func:`read_groups` reads back exactly.

Layout written (and the one read without options)
    One struct (MAT) or group (HDF5) per manoeuvre, named by the manoeuvre; inside, the time
    vector ``time`` (s) and one numeric column vector per channel, named by the channel.
    Units: in MAT files a ``units`` sub-struct of char fields (``units.q = 'deg/s'``); in
    HDF5 files a ``units`` string attribute on each dataset. Manoeuvre attributes: in MAT
    files a char field ``sysid_attrs`` holding them as JSON (typed as the campaign file
    types them, :func:`sysid.data.netcdf.encode_attrs`); in HDF5 files the group's own
    attributes (the same encoding). ``units`` and ``sysid_attrs`` are metadata, never
    channels. A MATLAB variable name must be an identifier (a letter first, at most 63
    letters, digits and ``_``), so a manoeuvre such as ``3211_lon_1`` is stored as struct
    ``m3211_lon_1`` and its name is restored from ``sysid_attrs``.

Layouts read
    MAT v5/v7 (``scipy.io.loadmat``), MAT v7.3 and plain HDF5 (``h5py``): every top-level
    struct/group is a manoeuvre named by it; a file with no top-level struct/group but
    numeric vectors is one manoeuvre of those vectors (named by the file). Numeric classes
    (``double single int* uint* logical``) and char are read; cell arrays, struct arrays,
    sparse, complex, objects, strings and function handles are refused with an error
    naming the variable and its class when they are the time vector or a mapped channel,
    and otherwise skipped and listed in the manoeuvre's ``ignored_fields`` (flight-test
    files often carry channel-name cells and such). MAT v4 files are refused (re-save them
    with ``-v7`` or ``-v7.3``).

MAT v7.3 facts used (public MathWorks descriptions of the format and the hdf5storage
package's storage-format documentation): an HDF5 file with a 512-byte user block whose first
116 bytes are the text header ``MATLAB 7.3 MAT-file, ...`` padded with spaces, then 8 bytes of
subsystem offset, version ``0x0200`` and the endian indicator ``IM``; every dataset and group
carries a ``MATLAB_class`` attribute (ASCII: ``double``, ``char``, ``struct``...); char
arrays are ``uint16`` code units with ``MATLAB_int_decode = 2``; arrays are stored in
MATLAB's column-major order, so an ``n x 1`` column vector is an HDF5 dataset of shape
``(1, n)``; a struct group lists its fields in ``MATLAB_fields`` (variable-length arrays of
single characters); empty arrays carry ``MATLAB_empty = 1`` and hold their dimensions.

References
----------
.. [MAT] The MathWorks, *MAT-File Format*, version 7 (2004): the level-5 header (116 bytes
   of text starting ``MATLAB 5.0 MAT-file``, version, endian indicator ``IM``/``MI``); the
   v7.3 files are HDF5 with the same 128-byte header in the user block.
.. [H5S] hdf5storage documentation, *Storage Format* (MATLAB file header, ``MATLAB_class``,
   ``MATLAB_int_decode``, ``MATLAB_empty``, ``MATLAB_fields``).
"""

from __future__ import annotations

import datetime
import json
import os
import re
from collections.abc import Mapping
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from sysid import __version__
from sysid.core.errors import InputDataError
from sysid.core.util import atomic_path
from sysid.data.netcdf import decode_attrs, encode_attrs, json_default

__all__ = ["FORMATS", "Group", "Unsupported", "sniff_format", "read_groups", "write_groups",
           "matlab_name", "METADATA_FIELDS"]

#: Formats :func:`write_groups` writes.
FORMATS = ("mat5", "mat73", "hdf5")
#: Fields/attributes of a manoeuvre that hold metadata, never channels.
METADATA_FIELDS = ("units", "sysid_attrs")

_HDF5_SIGNATURE = b"\x89HDF\r\n\x1a\n"
_CDF_MAGIC = (b"CDF\x01", b"CDF\x02", b"CDF\x05")
_USER_BLOCK = 512
_NUMERIC_CLASSES = ("double", "single", "int8", "uint8", "int16", "uint16", "int32",
                    "uint32", "int64", "uint64", "logical")
_MATLAB_NAME = re.compile(r"[A-Za-z][A-Za-z0-9_]{0,62}")


@dataclass(frozen=True)
class Unsupported:
    """A variable of a class sysid does not read (cell, sparse, complex, ...): refused with
    ``message`` only when it is needed (the time vector or a mapped channel); otherwise
    listed in ``ignored_fields``, since flight-test files often carry such metadata."""

    message: str
    cls: str


@dataclass
class Group:
    """One manoeuvre as stored in a file, before channels are chosen.

    ``fields``: name -> numpy array (numeric, squeezed to the array's own shape) or str;
    ``units``: field -> unit string; ``attrs``: the manoeuvre's attributes (decoded);
    ``where``: how messages name it (``file F, struct 'S'``); ``name``: the struct/group
    name (None for the flat layout: the caller uses the file stem); ``ignored``: what was
    found but is not a numeric array (nested structs, char fields, other top-level data).
    """

    where: str
    name: str | None
    fields: dict = field(default_factory=dict)
    units: dict = field(default_factory=dict)
    attrs: dict = field(default_factory=dict)
    ignored: list = field(default_factory=list)
    unsupported: dict = field(default_factory=dict)  #: field -> Unsupported


# --------------------------------------------------------------------------------------------
# sniffing


def sniff_format(path: str | os.PathLike) -> str:
    """The container of ``path`` from its first bytes, not its name.

    ``"mat5"`` (header text ``MATLAB 5.0 MAT-file``), ``"mat73"`` (HDF5 signature at byte
    512), ``"netcdf"`` (netCDF-3 magic, or HDF5 at byte 0 holding netCDF-4 markers),
    ``"hdf5"`` (other HDF5 at byte 0), ``"mat4"`` (a MAT v4 matrix header), else ``"text"``.
    """
    path = Path(path)
    with open(path, "rb") as fh:
        head = fh.read(_USER_BLOCK + 8)
    if head[:4] in _CDF_MAGIC:
        return "netcdf"
    if head.startswith(b"MATLAB 5.0 MAT-file"):
        return "mat5"
    if head[_USER_BLOCK:_USER_BLOCK + 8] == _HDF5_SIGNATURE:
        return "mat73"
    if head.startswith(_HDF5_SIGNATURE):
        return "netcdf" if _is_netcdf4(path) else "hdf5"
    if _looks_like_mat4(head):
        return "mat4"
    return "text"


def _is_netcdf4(path: Path) -> bool:
    """HDF5 at ``path`` written by the netCDF-4 library (its root attribute or dimension
    scales), as opposed to a plain HDF5 file."""
    import h5py  # deferred: only HDF5 files need it

    try:
        with h5py.File(path, "r") as f:
            if "_NCProperties" in f.attrs:
                return True
            found = []

            def visit(name, obj):
                if isinstance(obj, h5py.Dataset) and obj.attrs.get("CLASS") == b"DIMENSION_SCALE":
                    found.append(name)
                    return True
                return None

            f.visititems(visit)
            return bool(found)
    except Exception:  # h5py raises OSError, KeyError, RuntimeError... for broken files
        return True  # unreadable as HDF5: the netCDF reader reports it


def _looks_like_mat4(head: bytes) -> bool:
    """A MAT v4 matrix header: five int32 (type MOPT, rows, columns, imaginary flag, name
    length) whose type digits are in range and whose name follows, NUL-terminated."""
    if len(head) < 21:
        return False
    for order in ("<", ">"):
        mopt, mrows, ncols, imagf, namlen = np.frombuffer(head[:20], dtype=f"{order}i4")
        if not 0 <= mopt < 5000 or imagf not in (0, 1) or not 0 < namlen < 64:
            continue
        m, o, p, t = mopt // 1000, (mopt // 100) % 10, (mopt // 10) % 10, mopt % 10
        if m > 4 or o != 0 or p > 5 or t > 2 or mrows < 0 or ncols < 0:
            continue
        name = head[20:20 + int(namlen)]
        if len(name) == namlen and name.endswith(b"\x00") and name[:-1].isascii():
            return True
    return False


# --------------------------------------------------------------------------------------------
# reading


def read_groups(path: str | os.PathLike, kind: str) -> list[Group]:
    """Every manoeuvre of a MAT v5 (``kind="mat5"``), MAT v7.3 (``"mat73"``) or HDF5
    (``"hdf5"``) file, in file order. Raises InputDataError for unreadable files and
    unsupported MATLAB classes."""
    path = Path(path)
    if kind == "mat4":
        raise InputDataError(
            f"file {path} is a MAT v4 file, which holds no structs or units; save it again "
            "with save(..., '-v7') or '-v7.3' (or as CSV)")
    if kind == "mat5":
        return _read_mat5(path)
    if kind in ("mat73", "hdf5"):
        return _read_hdf5(path, matlab=kind == "mat73")
    raise InputDataError(f"file {path}: format {kind!r} is not one of mat5, mat73, hdf5")


def _split_metadata(where: str, name, fields: dict, units: dict, attrs: dict) -> Group:
    """A Group from raw fields: ``units`` (struct of char) and ``sysid_attrs`` (JSON char)
    become metadata; unsupported classes are kept aside (``Group.unsupported``)."""
    for key in METADATA_FIELDS:
        if isinstance(fields.get(key), Unsupported):
            raise InputDataError(fields[key].message)
    unit_field = fields.pop("units", None)
    if unit_field is not None:
        if not isinstance(unit_field, dict):
            raise InputDataError(f"{where}: field 'units' must be a struct of char fields "
                                 f"(units.q = 'deg/s'), got {_describe(unit_field)}")
        for key, value in unit_field.items():
            if not isinstance(value, str):
                raise InputDataError(f"{where}: units.{key} must be char (e.g. 'deg/s'), got "
                                     f"{_describe(value)}")
            units[key] = value.strip()
    meta = fields.pop("sysid_attrs", None)
    if meta is not None:
        if not isinstance(meta, str):
            raise InputDataError(f"{where}: field 'sysid_attrs' must be char (JSON), got "
                                 f"{_describe(meta)}")
        try:
            decoded = json.loads(meta)
            decoded = decode_attrs(decoded) if isinstance(decoded, dict) else decoded
        except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
            raise InputDataError(f"{where}: field 'sysid_attrs' is not the JSON sysid writes "
                                 f"({exc})") from exc
        if not isinstance(decoded, dict):
            raise InputDataError(f"{where}: field 'sysid_attrs' must hold a JSON object")
        attrs.update(decoded)
    group = Group(where=where, name=name, units=units, attrs=attrs)
    for key, value in fields.items():
        if isinstance(value, Unsupported):
            group.unsupported[key] = value
            group.ignored.append(f"{key} ({value.cls})")
        elif isinstance(value, dict):
            group.ignored.append(f"{key} (struct)")
        elif isinstance(value, str):
            group.ignored.append(f"{key} (char)")
        else:
            group.fields[key] = value
    return group


def _describe(value) -> str:
    if isinstance(value, Unsupported):
        return f"MATLAB class {value.cls}"
    if isinstance(value, dict):
        return "a struct"
    if isinstance(value, str):
        return "char"
    if isinstance(value, np.ndarray):
        return f"a {value.dtype} array of shape {value.shape}"
    return type(value).__name__


# -- MAT v5 ----------------------------------------------------------------------------------


def _mat5_value(value, where: str):
    """numpy array, str or dict of a loadmat(simplify_cells=True) value; :class:`Unsupported`
    for a class sysid does not read."""
    import scipy.sparse  # deferred with scipy.io below

    if isinstance(value, dict):
        return {k: _mat5_value(v, f"{where}.{k}") for k, v in value.items()}
    if isinstance(value, str):
        return value
    if isinstance(value, (bool, int, float, np.bool_, np.integer, np.floating)):
        return np.asarray(value, dtype=float)
    if scipy.sparse.issparse(value):
        cls = "sparse"
    elif isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
        return value
    elif isinstance(value, (complex, np.complexfloating)) or (
            isinstance(value, np.ndarray) and value.dtype.kind == "c"):
        cls = "complex double"
    elif isinstance(value, (list, tuple)) or (isinstance(value, np.ndarray)
                                              and value.dtype.kind == "O"):
        cls = "cell or struct array"
    elif isinstance(value, np.ndarray) and value.dtype.kind in "SU":
        cls = "char matrix"
    else:
        cls = type(value).__name__
    return Unsupported(f"{where}: MATLAB class {cls} is not supported; expected numeric "
                       "vectors (double, single, integer, logical)", cls)


def _read_mat5(path: Path) -> list[Group]:
    import scipy.io  # deferred: only MAT files need it

    try:
        content = scipy.io.loadmat(path, simplify_cells=True, chars_as_strings=True)
    except Exception as exc:  # scipy raises many types for broken files
        raise InputDataError(f"cannot read MAT file {path} ({type(exc).__name__}: {exc}); "
                             "expected a MAT v5/v7 file") from exc
    variables = {k: v for k, v in content.items() if not k.startswith("__")}
    return _groups_from_variables(path, {k: _mat5_value(v, f"file {path}, variable {k!r}")
                                         for k, v in variables.items()}, "struct")


def _groups_from_variables(path: Path, variables: dict, word: str) -> list[Group]:
    """Top-level structs/groups are manoeuvres; without any, the numeric variables are one."""
    structs = {k: v for k, v in variables.items()
               if isinstance(v, dict) and k not in METADATA_FIELDS}
    if structs:
        groups = []
        for name, fields in structs.items():
            group = _split_metadata(f"file {path}, {word} {name!r}", name, dict(fields), {}, {})
            groups.append(group)
        others = [k for k in variables if k not in structs]
        for group in groups:
            group.ignored += [f"/{k} (top level)" for k in others]
        return groups
    if not variables:
        raise InputDataError(f"file {path} holds no variables; expected one {word} per "
                             "manoeuvre or the vectors of one manoeuvre")
    return [_split_metadata(f"file {path}", None, dict(variables), {}, {})]


# -- HDF5 and MAT v7.3 ----------------------------------------------------------------------


def _attr_text(value) -> str | None:
    if isinstance(value, bytes):
        return value.decode("utf-8", "replace")
    if isinstance(value, str):
        return value
    if isinstance(value, np.ndarray) and value.dtype.kind in "SU" and value.size == 1:
        return _attr_text(value.ravel()[0])
    return None


def _h5_attrs(obj) -> dict:
    """Attributes of an HDF5 object as Python values (bytes -> str), decoded as the
    campaign file encodes them when ``sysid_attr_types`` is present."""
    out = {}
    for key, value in obj.attrs.items():
        if key.startswith("MATLAB_") or key in ("units", "CLASS", "DIMENSION_LIST",
                                                "REFERENCE_LIST", "NAME"):
            continue
        text = _attr_text(value)
        if text is not None:
            out[key] = text
        elif isinstance(value, np.generic):
            out[key] = value.item()
        elif isinstance(value, np.ndarray) and value.dtype.kind in "biuf":
            out[key] = value if value.size > 1 else value.ravel()[0].item()
    try:
        return decode_attrs(out)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError):
        out.pop("sysid_attr_types", None)
        return out


def _h5_value(obj, where: str, matlab: bool):
    """Array, str, dict (struct/group) or :class:`Unsupported` of one HDF5 object."""
    import h5py  # deferred: only HDF5 files need it

    cls = _attr_text(obj.attrs.get("MATLAB_class")) if matlab else None
    if isinstance(obj, h5py.Group):
        if matlab and cls not in (None, "struct"):
            return Unsupported(f"{where}: MATLAB class {cls!r} is not supported; expected "
                               "struct, numeric vectors and char", str(cls))
        return {k: _h5_value(v, f"{where}.{k}", matlab) for k, v in obj.items()}
    if not isinstance(obj, h5py.Dataset):
        raise InputDataError(f"{where}: HDF5 object of type {type(obj).__name__} is not "
                             "supported")
    dtype = obj.dtype
    if matlab:
        if obj.attrs.get("MATLAB_sparse") is not None:
            cls = f"sparse {cls}"
        elif dtype.kind == "V" or dtype.names:
            cls = f"complex {cls}"
        elif dtype.kind == "O" or h5py.check_dtype(ref=dtype) is not None:
            cls = cls or "reference"
        if cls == "char":
            if obj.attrs.get("MATLAB_empty"):
                return ""
            codes = np.asarray(obj[()]).T.ravel()
            return "".join(chr(int(c)) for c in codes)
        if cls not in _NUMERIC_CLASSES:
            return Unsupported(
                f"{where}: MATLAB class {cls!r} is not supported; expected numeric vectors "
                "(double, single, integer, logical)", str(cls))
        if obj.attrs.get("MATLAB_empty"):
            return np.zeros(0)
        return np.asarray(obj[()]).T  # column-major: (1, n) in the file is n x 1
    if dtype.kind in "SU" or h5py.check_string_dtype(dtype) is not None:
        value = obj[()]
        text = _attr_text(value if not isinstance(value, np.ndarray) else value.ravel()[0]
                          if value.size == 1 else None)
        if text is None:
            return Unsupported(f"{where}: string array of shape {obj.shape} is not "
                               "supported; expected numeric vectors", "string array")
        return text
    if dtype.kind not in "biuf":
        return Unsupported(f"{where}: HDF5 dataset of type {dtype} is not supported; "
                           "expected numeric vectors", str(dtype))
    return np.asarray(obj[()])


def _read_hdf5(path: Path, matlab: bool) -> list[Group]:
    import h5py  # deferred: only HDF5 files need it

    word = "struct" if matlab else "group"
    try:
        f = h5py.File(path, "r")
    except Exception as exc:  # h5py raises OSError, KeyError, RuntimeError... for broken files
        raise InputDataError(f"cannot read {'MAT v7.3' if matlab else 'HDF5'} file {path} "
                             f"({type(exc).__name__}: {exc})") from exc
    try:
        with f:
            variables, units, attrs = {}, {}, {}
            for key, obj in f.items():
                if key.startswith("#"):  # MATLAB's #refs# and #subsystem#
                    continue
                variables[key] = _h5_value(obj, f"file {path}, variable {key!r}", matlab)
                if not matlab and isinstance(obj, h5py.Group):
                    attrs[key] = _h5_attrs(obj)
                    units[key] = {k: u for k, v in obj.items()
                                  if isinstance(v, h5py.Dataset)
                                  and (u := _attr_text(v.attrs.get("units"))) is not None}
                elif not matlab:
                    unit = _attr_text(obj.attrs.get("units"))
                    if unit is not None:
                        units.setdefault("", {})[key] = unit
            root_attrs = {} if matlab else _h5_attrs(f)
    except InputDataError:
        raise
    except Exception as exc:  # h5py raises OSError, KeyError, RuntimeError... for broken files
        raise InputDataError(f"cannot read {path} ({type(exc).__name__}: {exc}); expected "
                             f"a {'MAT v7.3' if matlab else 'HDF5'} file") from exc
    groups = _groups_from_variables(path, variables, word)
    for group in groups:
        key = group.name if group.name is not None else ""
        for name, unit in units.get(key, {}).items():
            group.units.setdefault(name, unit)
        extra = attrs.get(key, root_attrs if group.name is None else {})
        group.attrs = {**extra, **group.attrs}
    return groups


# --------------------------------------------------------------------------------------------
# writing


def matlab_name(name: str, taken=()) -> str:
    """A valid MATLAB identifier for ``name`` (itself when it is one), not in ``taken``."""
    if _MATLAB_NAME.fullmatch(name) and name not in taken:
        return name
    base = re.sub(r"[^A-Za-z0-9_]", "_", name)
    if not base or not base[0].isalpha():
        base = "m" + base
    base = base[:63]
    out, k = base, 1
    while out in taken:
        suffix = f"_{k}"
        out, k = base[:63 - len(suffix)] + suffix, k + 1
    return out


def write_groups(path: str | os.PathLike, groups: Mapping[str, dict], *, format: str) -> None:
    """Write manoeuvres ``{name: {"fields": {name: 1-D float array}, "units": {name: str},
    "attrs": {...}}}`` (``fields`` in order, time first) as ``format`` (``mat5``, ``mat73``,
    ``hdf5``), atomically."""
    if format not in FORMATS:
        raise InputDataError(f"format {format!r}: expected one of {FORMATS} (or csv)")
    path = Path(path)
    if path.is_dir():
        raise InputDataError(f"cannot write {path}: it is a directory; expected a file name")
    suffix = ".mat" if format.startswith("mat") else ".h5"
    with atomic_path(path, suffix=path.suffix or suffix) as tmp:
        {"mat5": _write_mat5, "mat73": _write_mat73, "hdf5": _write_hdf5}[format](tmp, groups)


def _attrs_json(attrs: Mapping, owner: str) -> str:
    try:
        return json.dumps(encode_attrs(attrs, owner), default=json_default, sort_keys=True)
    except (TypeError, ValueError) as exc:
        raise InputDataError(f"cannot write {owner}: attributes are not JSON serialisable "
                             f"({exc})") from exc


def _matlab_structs(groups: Mapping[str, dict]) -> dict:
    """``{MATLAB variable: {field: value}}`` with valid names; the manoeuvre name (and any
    renamed field) is kept in ``sysid_attrs``."""
    out: dict = {}
    for name, group in groups.items():
        var = matlab_name(name, taken=out)
        fields, units = {}, {}
        for key, values in group["fields"].items():
            if key in METADATA_FIELDS:
                raise InputDataError(f"manoeuvre {name!r}: channel {key!r} clashes with the "
                                     "metadata field of the same name")
            mkey = matlab_name(key, taken=fields)
            if mkey != key:
                raise InputDataError(f"manoeuvre {name!r}: channel {key!r} is not a valid "
                                     "MATLAB field name; rename it (letters, digits, _)")
            fields[mkey] = np.asarray(values, dtype=float)
            if group["units"].get(key):
                units[mkey] = str(group["units"][key])
        attrs = dict(group["attrs"])
        attrs.setdefault("maneuver", name)
        out[var] = {**fields, "units": units,
                    "sysid_attrs": _attrs_json(attrs, f"manoeuvre {name!r}")}
    return out


def _write_mat5(path: Path, groups: Mapping[str, dict]) -> None:
    import scipy.io  # deferred: only MAT files need it

    structs = _matlab_structs(groups)
    content = {var: {k: (v.reshape(-1, 1) if isinstance(v, np.ndarray) else v)
                     for k, v in s.items()} for var, s in structs.items()}
    scipy.io.savemat(path, content, format="5", oned_as="column", do_compression=False,
                     long_field_names=True)


def _mat73_header() -> bytes:
    stamp = datetime.datetime.now(datetime.timezone.utc).strftime("%a %b %d %H:%M:%S %Y")
    text = (f"MATLAB 7.3 MAT-file, Platform: sysid {__version__}, Created on: {stamp} "
            "HDF5 schema 1.00 .").encode("ascii")[:116]
    return text.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02IM"


def _h5_class(obj, cls: str) -> None:
    obj.attrs.create("MATLAB_class", np.bytes_(cls))


def _h5_char(group, name: str, text: str) -> None:
    codes = np.array([ord(c) for c in text], dtype=np.uint16)
    if any(ord(c) > 0xFFFF for c in text):
        raise InputDataError(f"text {text[:40]!r} has characters beyond UTF-16's basic plane")
    if codes.size == 0:
        ds = group.create_dataset(name, data=np.array([1, 0], dtype=np.uint64))
        _h5_class(ds, "char")
        ds.attrs.create("MATLAB_empty", np.uint8(1))
    else:
        ds = group.create_dataset(name, data=codes.reshape(-1, 1))  # 1 x k row, column-major
        _h5_class(ds, "char")
    ds.attrs.create("MATLAB_int_decode", np.int32(2))


def _h5_fields_attr(group, names) -> None:
    import h5py  # deferred: only HDF5 files need it

    vlen = h5py.vlen_dtype(np.dtype("S1"))
    value = np.empty(len(names), dtype=object)
    for i, name in enumerate(names):
        value[i] = np.array(list(name), dtype="S1")
    group.attrs.create("MATLAB_fields", value, dtype=vlen)


def _write_mat73(path: Path, groups: Mapping[str, dict]) -> None:
    import h5py  # deferred: only HDF5 files need it

    structs = _matlab_structs(groups)
    # Creation order tracked, so readers list manoeuvres and channels in the written order.
    with h5py.File(path, "w", userblock_size=_USER_BLOCK, libver="earliest",
                   track_order=True) as f:
        for var, fields in structs.items():
            g = f.create_group(var, track_order=True)
            _h5_class(g, "struct")
            for key, value in fields.items():
                if key == "units":
                    sub = g.create_group("units", track_order=True)
                    _h5_class(sub, "struct")
                    for ukey, unit in value.items():
                        _h5_char(sub, ukey, unit)
                    _h5_fields_attr(sub, list(value))
                elif key == "sysid_attrs":
                    _h5_char(g, key, value)
                else:
                    ds = g.create_dataset(key, data=value.reshape(1, -1))  # n x 1 column
                    _h5_class(ds, "double")
            _h5_fields_attr(g, list(fields))
    with open(path, "r+b") as fh:
        fh.write(_mat73_header())


def _write_hdf5(path: Path, groups: Mapping[str, dict]) -> None:
    import h5py  # deferred: only HDF5 files need it

    with h5py.File(path, "w", track_order=True) as f:
        f.attrs["sysid_version"] = __version__
        for name, group in groups.items():
            g = f.create_group(name, track_order=True)
            for key, values in group["fields"].items():
                ds = g.create_dataset(key, data=np.asarray(values, dtype=float))
                if group["units"].get(key):
                    ds.attrs["units"] = str(group["units"][key])
            encoded = encode_attrs({**group["attrs"], "maneuver": name},
                                   f"manoeuvre {name!r}")
            for key, value in encoded.items():
                g.attrs[key] = value
