"""Reading and writing time histories and campaigns (netCDF and CSV).

A campaign is an :class:`xarray.DataTree` saved as one netCDF-4 file with groups (see
``docs/data_model.md``). netCDF knows neither complex numbers, nor booleans, nor attributes
holding ``None``, dictionaries or lists of strings, so :func:`encode_complex` maps every
dataset onto what netCDF stores and :func:`decode_complex` maps it back. The rules:

Variables (data variables and coordinates)
    * complex ``(..., )`` -> real ``(..., complex)`` with ``complex = ["real", "imag"]`` and
      attribute ``sysid_complex = 1`` (``complex64`` <-> ``float32``, ``complex128`` <->
      ``float64``, so the round trip is bit-exact);
    * bool -> ``int8`` (0/1) with attribute ``sysid_bool = 1``.

Attributes (of datasets and variables)
    * ``str``, real numbers and 1-D numeric arrays of two or more elements are stored as they
      are (plain readers see them unchanged);
    * ``bool`` -> integer 0/1, ``None`` -> ``""``, complex -> ``[real, imag]``;
    * lists and tuples of numbers -> numeric arrays; every other value (dict, list of str,
      nested or empty lists, length-1 or multi-dimensional arrays) -> a JSON string;
    * the original type of every attribute so altered is recorded in the JSON attribute
      ``sysid_attr_types`` (``{"name": "bool" | "none" | "complex" | "list" | "tuple" |
      "ndarray" | "json"}``), which :func:`decode_complex` uses to restore it exactly.

Files are always written atomically (temporary file next to the target, then rename) and read
fully into memory, so a campaign file can be replaced while its contents are in use.

CSV time histories (:func:`write_csv`, :func:`read_time_history`) have one header row naming
the columns as ``name [unit]`` (``time [s],lon [%],q [deg/s]``) and one row per sample;
:func:`write_csv` adds a first comment line ``# sysid-attrs: {...}`` with the dataset
attributes as JSON (typed by the attribute rules above), which :func:`read_time_history` restores.
"""

from __future__ import annotations

import contextlib
import fnmatch
import json
import os
import re
import shutil
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import xarray as xr

from sysid import __version__
from sysid.core.errors import InputDataError
from sysid.core.units import CHANNELS, CONTROLS, conversion_factor
from sysid.core.util import atomic_path

__all__ = [
    "encode_complex",
    "decode_complex",
    "write_campaign",
    "read_campaign",
    "update_campaign",
    "group_attrs",
    "set_group_attrs",
    "append_maneuver",
    "list_maneuvers",
    "maneuvers",
    "validate_time_history",
    "write_csv",
    "read_time_history",
]

#: Name of the trailing dimension holding real and imaginary parts of complex variables.
COMPLEX_DIM = "complex"
#: Relative tolerance on the sample interval of a "uniform" time grid.
TIME_RTOL = 1e-6
#: Manoeuvre kinds recognised from the first token of a manoeuvre name.
KINDS = ("sweep", "3211", "2311", "doublet", "multisine")
#: Length (s) of the initial stretch whose mean is taken as trim for imported data.
TRIM_WINDOW = 1.0

_TYPES_ATTR = "sysid_attr_types"
_CSV_ATTRS_PREFIX = "# sysid-attrs:"
_NETCDF_MAGIC = (b"CDF\x01", b"CDF\x02", b"CDF\x05", b"\x89HDF\r\n\x1a\n")


# --------------------------------------------------------------------------------------------
# encoding for netCDF


def _json_default(value):
    """JSON for numpy scalars and arrays inside attribute values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def _encode_attrs(attrs: Mapping, owner: str) -> dict:
    """netCDF-storable attributes plus the ``sysid_attr_types`` record of altered ones."""
    out, types = {}, {}
    for key, value in attrs.items():
        if key == _TYPES_ATTR:
            continue
        if isinstance(value, (bool, np.bool_)):
            out[key], types[key] = np.int8(bool(value)), "bool"
        elif value is None:
            out[key], types[key] = "", "none"
        elif isinstance(value, (complex, np.complexfloating)):
            out[key], types[key] = np.array([value.real, value.imag]), "complex"
        elif isinstance(value, (str, int, float, np.integer, np.floating)):
            out[key] = value
        elif (isinstance(value, np.ndarray) and value.ndim == 1 and value.size >= 2
              and value.dtype.kind in "iuf"):
            out[key] = value
        elif (isinstance(value, (list, tuple)) and len(value) >= 2
              and all(isinstance(v, (int, float, np.integer, np.floating))
                      and not isinstance(v, (bool, np.bool_)) for v in value)
              and len({type(v) for v in value}) == 1):
            # Homogeneous numeric lists stay numeric arrays for plain readers.
            out[key], types[key] = np.asarray(value), type(value).__name__
        else:
            if isinstance(value, np.ndarray):
                payload = {"dtype": value.dtype.str, "shape": list(value.shape),
                           "data": value.ravel().tolist()}
                types[key] = "ndarray"
            else:
                payload = value
                types[key] = "json"
            try:
                out[key] = json.dumps(payload, default=_json_default)
            except (TypeError, ValueError) as exc:
                raise InputDataError(
                    f"attribute {key!r} of {owner} cannot be stored in netCDF: {exc}; "
                    "expected str, numbers, bool, None, lists, dicts or numeric arrays"
                ) from exc
    if types:
        out[_TYPES_ATTR] = json.dumps(types, sort_keys=True)
    return out


def _decode_attrs(attrs: Mapping) -> dict:
    """Inverse of :func:`_encode_attrs`."""
    attrs = dict(attrs)
    types = json.loads(attrs.pop(_TYPES_ATTR, "{}"))
    for key, kind in types.items():
        if key not in attrs:
            continue
        value = attrs[key]
        if kind == "bool":
            attrs[key] = bool(value)
        elif kind == "none":
            attrs[key] = None
        elif kind == "complex":
            re_im = np.atleast_1d(value)
            attrs[key] = complex(re_im[0], re_im[1])
        elif kind == "list":
            attrs[key] = np.atleast_1d(value).tolist()
        elif kind == "tuple":
            attrs[key] = tuple(np.atleast_1d(value).tolist())
        elif kind == "ndarray":
            payload = json.loads(value)
            attrs[key] = np.asarray(payload["data"], dtype=payload["dtype"]).reshape(
                payload["shape"])
        elif kind == "json":
            attrs[key] = json.loads(value)
    return attrs


def _encode_variable(var: xr.Variable, owner: str) -> xr.Variable:
    attrs = dict(var.attrs)
    data = var.data
    dims = var.dims
    if np.iscomplexobj(data):
        if COMPLEX_DIM in dims:
            raise InputDataError(
                f"complex variable {owner} already has a {COMPLEX_DIM!r} dimension; "
                f"expected complex values without a dimension named {COMPLEX_DIM!r}")
        data = np.stack([np.real(data), np.imag(data)], axis=-1)
        dims = (*dims, COMPLEX_DIM)
        attrs["sysid_complex"] = np.int8(1)
    elif np.asarray(data).dtype == bool:
        data = np.asarray(data).astype(np.int8)
        attrs["sysid_bool"] = np.int8(1)
    return xr.Variable(dims, data, _encode_attrs(attrs, owner))


def _decode_variable(var: xr.Variable) -> xr.Variable:
    attrs = _decode_attrs(var.attrs)
    data = var.values
    dims = var.dims
    if attrs.pop("sysid_complex", 0):
        data = data[..., 0] + 1j * data[..., 1]
        dims = dims[:-1]
    elif attrs.pop("sysid_bool", 0):
        data = data.astype(bool)
    elif data.dtype == object and data.size and all(isinstance(v, str) for v in data.flat):
        data = data.astype(str)
    return xr.Variable(dims, data, attrs)


def encode_complex(ds: xr.Dataset) -> xr.Dataset:
    """Map ``ds`` onto what netCDF stores (complex, bool and attribute rules above).

    Returns a new Dataset; ``ds`` is not modified. File-specific encodings left over from a
    previous read are dropped so they cannot clash with the new layout.
    """
    name = ds.attrs.get("maneuver", "dataset")
    coord_names = set(ds.coords)
    variables = {k: _encode_variable(v, f"variable {k!r} of {name}")
                 for k, v in ds.variables.items()}
    coords = {k: v for k, v in variables.items() if k in coord_names}
    data_vars = {k: v for k, v in variables.items() if k not in coord_names}
    needs_complex = any(COMPLEX_DIM in v.dims for v in variables.values())
    if needs_complex and COMPLEX_DIM not in coords:
        coords[COMPLEX_DIM] = xr.Variable(COMPLEX_DIM, np.array(["real", "imag"]))
    out = xr.Dataset(data_vars, coords, attrs=_encode_attrs(ds.attrs, f"dataset {name}"))
    return out.drop_encoding()


def decode_complex(ds: xr.Dataset) -> xr.Dataset:
    """Inverse of :func:`encode_complex`: rebuild complex, bool and typed attributes."""
    coord_names = set(ds.coords)
    variables = {k: _decode_variable(v) for k, v in ds.variables.items()}
    if any(COMPLEX_DIM in v.dims for v in ds.variables.values()
           if v.attrs.get("sysid_complex", 0)):
        still_used = any(COMPLEX_DIM in v.dims for k, v in variables.items()
                         if k != COMPLEX_DIM)
        if not still_used:
            variables.pop(COMPLEX_DIM, None)
    coords = {k: v for k, v in variables.items() if k in coord_names}
    data_vars = {k: v for k, v in variables.items() if k not in coord_names}
    return xr.Dataset(data_vars, coords, attrs=_decode_attrs(ds.attrs)).drop_encoding()


# --------------------------------------------------------------------------------------------
# campaigns


def _nodes(tree: xr.DataTree) -> dict[str, xr.Dataset]:
    """``{path: own dataset}`` of every node of ``tree`` (inherited coordinates excluded)."""
    return {node.path: node.to_dataset(inherit=False) for node in tree.subtree}


def _tree_from_nodes(nodes: Mapping[str, xr.Dataset], where: str) -> xr.DataTree:
    try:
        return xr.DataTree.from_dict(dict(nodes))
    except ValueError as exc:
        # Typically a child whose coordinates disagree with the ones it inherits.
        raise InputDataError(f"cannot assemble campaign {where}: {exc}") from exc


def write_campaign(tree: xr.DataTree, path: str | os.PathLike) -> None:
    """Write a campaign to one netCDF-4 file with groups, atomically.

    ``tree`` is an :class:`xarray.DataTree` laid out as in ``docs/data_model.md``; complex,
    bool and non-netCDF attributes are encoded by :func:`encode_complex`. Either the whole
    file appears at ``path`` or, if anything fails, ``path`` is left as it was.
    """
    if isinstance(tree, xr.Dataset):
        tree = xr.DataTree(tree)
    encoded = _tree_from_nodes({p: encode_complex(ds) for p, ds in _nodes(tree).items()},
                               f"for {path}")
    with atomic_path(path, suffix=".nc") as tmp:
        encoded.to_netcdf(tmp, engine="netcdf4", mode="w")


def read_campaign(path: str | os.PathLike) -> xr.DataTree:
    """Read a campaign written by :func:`write_campaign`, fully into memory.

    The file is closed on return. Times and delays are left as seconds (no datetime
    decoding); complex, bool and typed attributes are rebuilt by :func:`decode_complex`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"campaign file {path} does not exist")
    try:
        with xr.open_datatree(path, engine="netcdf4", decode_times=False,
                              decode_timedelta=False) as raw:
            raw.load()
            nodes = {p: decode_complex(ds) for p, ds in _nodes(raw).items()}
    except InputDataError:
        raise
    except Exception as exc:  # netCDF/HDF5 raise OSError, ValueError, KeyError...
        raise InputDataError(f"cannot read campaign file {path}: expected a netCDF-4 file "
                             f"written by sysid ({type(exc).__name__}: {exc})") from exc
    return _tree_from_nodes(nodes, f"from {path}")


def _group_path(group: str) -> str:
    parts = [p for p in str(group).strip("/").split("/") if p]
    if not parts:
        raise InputDataError(f"group {group!r} is empty; expected a path like "
                             "'frequency_response' or 'models/frequency_domain'")
    return "/" + "/".join(parts)


def update_campaign(path: str | os.PathLike, group: str,
                    dataset: xr.Dataset | xr.DataTree) -> None:
    """Insert or replace one group of the campaign at ``path``, atomically.

    ``group`` is a path such as ``"frequency_response"`` or ``"models/frequency_domain"``;
    a missing file starts an empty campaign. A :class:`~xarray.Dataset` replaces that group's
    own variables and attributes and keeps its sub-groups (so updating ``maneuvers``' attrs
    does not drop the manoeuvres); a :class:`~xarray.DataTree` replaces the whole sub-tree.
    Processes updating the same file at once are serialised by :func:`campaign_lock`, so
    each update sees the others' groups (the two fits of one study may run concurrently).

    A group that is new to the file, under parents that hold no variables, is appended to a
    copy of the file; anything else rereads and rewrites the whole campaign. Both end in
    the same file contents; the append is what keeps a study's many small updates cheap
    (measured on the hover study's campaign: a full rewrite 3.6 s, an append 0.7 s; the
    cost is per group and variable, not per byte; tests/benchmarks/test_bench_campaign_io.py).
    """
    with campaign_lock(path):
        if not _append_new_groups(path, _group_path(group), dataset):
            _update_campaign(path, group, dataset)


def group_attrs(path: str | os.PathLike, group: str) -> dict | None:
    """The attributes of one group of the campaign at ``path``, read without loading the rest.

    ``None`` when the file does not exist, cannot be read as netCDF-4, or has no such group.
    """
    import netCDF4

    if not Path(path).is_file():
        return None
    try:
        with netCDF4.Dataset(path, "r") as nc:
            node = _nc_group(nc, _group_path(group))
            if node is None:
                return None
            return _decode_attrs({k: node.getncattr(k) for k in node.ncattrs()})
    except (OSError, RuntimeError, ValueError):
        return None


def set_group_attrs(path: str | os.PathLike, group: str, attrs: Mapping) -> None:
    """Add or change attributes of an existing group of the campaign at ``path``.

    The other attributes, the group's variables and every other group are kept. Atomic and
    serialised like :func:`update_campaign`, without rewriting the campaign's data.
    """
    import netCDF4

    target = _group_path(group)
    with campaign_lock(path):
        if group_attrs(path, target) is None:
            raise InputDataError(f"campaign {path} has no group {target!r} to set "
                                 f"attributes {sorted(attrs)} on")
        with atomic_path(path, suffix=".nc") as tmp:
            shutil.copyfile(path, tmp)
            with netCDF4.Dataset(tmp, "a") as nc:
                node = _nc_group(nc, target)
                merged = _decode_attrs({k: node.getncattr(k) for k in node.ncattrs()})
                merged.update(attrs)
                encoded = _encode_attrs(merged, f"group {target}")
                for key in node.ncattrs():
                    node.delncattr(key)
                node.setncatts(encoded)


def _subtree_nodes(target: str, tree: xr.DataTree) -> dict[str, xr.Dataset]:
    """``{campaign path: own dataset}`` of every node of ``tree`` placed at ``target``."""
    out = {}
    for node in tree.subtree:
        rel = node.relative_to(tree)
        out[target if rel == "." else f"{target}/{rel}"] = node.to_dataset(inherit=False)
    return out


def _nc_group(nc, target: str):
    """The netCDF4 group at ``target`` ("/a/b"), or None."""
    node = nc
    for part in target.strip("/").split("/"):
        if not part:
            continue
        if part not in node.groups:
            return None
        node = node.groups[part]
    return node


def _append_new_groups(path, target: str, dataset) -> bool:
    """Append ``dataset`` as the new group(s) at ``target`` to a copy of the campaign and
    rename it into place. False (nothing done) unless the file exists, none of the new groups
    does, and no existing ancestor holds variables or dimensions the new groups could
    inherit -- the cases where appending gives exactly what a full rewrite would."""
    import netCDF4

    if isinstance(dataset, xr.DataTree):
        new = _subtree_nodes(target, dataset)
    elif isinstance(dataset, xr.Dataset):
        new = {target: dataset}
    else:
        return False
    if not Path(path).is_file():
        return False
    try:
        with netCDF4.Dataset(path, "r") as nc:
            for group in new:
                if _nc_group(nc, group) is not None:
                    return False
                parts = group.strip("/").split("/")
                for k in range(len(parts)):
                    parent = _nc_group(nc, "/" + "/".join(parts[:k]))
                    if parent is not None and (parent.variables or parent.dimensions):
                        return False
    except (OSError, RuntimeError, ValueError):
        return False  # not readable here: the full path reports it
    # Encode (and check) everything before the file is touched.
    encoded = {g: encode_complex(ds) for g, ds in new.items()}
    _tree_from_nodes(encoded, f"in {path} (group {target})")
    with atomic_path(path, suffix=".nc") as tmp:
        shutil.copyfile(path, tmp)
        for group, ds in encoded.items():
            ds.to_netcdf(tmp, mode="a", group=group, engine="netcdf4")
    return True


@contextlib.contextmanager
def campaign_lock(path: str | os.PathLike):
    """Exclusive advisory lock for a read-modify-write of the campaign at ``path``.

    ``flock`` on the campaign's folder, not on a lock file, so nothing is left on disk; it
    holds across the processes of one machine (Dask workers of a LocalCluster). Where
    ``fcntl`` does not exist (Windows) the lock is a no-op and concurrent updates of one
    file are not safe.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    folder = Path(path).resolve().parent
    folder.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        yield
    finally:
        os.close(descriptor)  # closing the descriptor releases the lock


def _update_campaign(path, group: str, dataset) -> None:
    target = _group_path(group)
    nodes = _nodes(read_campaign(path)) if Path(path).exists() else {"/": xr.Dataset()}
    if isinstance(dataset, xr.DataTree):
        nodes = {p: ds for p, ds in nodes.items()
                 if p != target and not p.startswith(target + "/")}
        nodes.update(_subtree_nodes(target, dataset))
    elif isinstance(dataset, xr.Dataset):
        nodes[target] = dataset
    else:
        raise InputDataError(f"group {group!r}: expected an xarray Dataset or DataTree, "
                             f"got {type(dataset).__name__}")
    tree = _tree_from_nodes(nodes, f"in {path} (group {target})")
    write_campaign(tree, path)


def append_maneuver(path: str | os.PathLike, name: str, dataset: xr.Dataset) -> None:
    """Add (or replace) manoeuvre ``name`` in the campaign at ``path``: group
    ``/maneuvers/<name>``."""
    if not name or "/" in name:
        raise InputDataError(f"manoeuvre name {name!r} must be non-empty and contain no '/'")
    update_campaign(path, f"maneuvers/{name}", dataset)


def _natural_key(name: str):
    """Sort ``sweep_lon_2`` before ``sweep_lon_10``."""
    return [(0, int(tok), "") if tok.isdigit() else (1, 0, tok)
            for tok in re.split(r"(\d+)", name)]


def list_maneuvers(tree: xr.DataTree, pattern: str = "*") -> list[str]:
    """Names of the manoeuvres under ``/maneuvers`` matching the glob ``pattern``
    (:mod:`fnmatch` rules, e.g. ``"sweep_lon_*"``), in natural sort order."""
    if "maneuvers" not in tree.children:
        return []
    names = [n for n in tree["maneuvers"].children if fnmatch.fnmatchcase(n, pattern)]
    return sorted(names, key=_natural_key)


def maneuvers(tree: xr.DataTree, pattern: str = "*") -> list[xr.Dataset]:
    """Time-history Datasets of the manoeuvres matching ``pattern`` (see
    :func:`list_maneuvers`), in the same order."""
    return [tree[f"maneuvers/{n}"].to_dataset() for n in list_maneuvers(tree, pattern)]


# --------------------------------------------------------------------------------------------
# time histories


def _check_time_grid(t: np.ndarray, where: str, row_label=None, rtol: float = TIME_RTOL) -> float:
    """Sample interval of a strictly increasing uniform grid; InputDataError otherwise.

    ``row_label(i)`` describes sample ``i`` in messages (e.g. the line of a CSV file).
    """
    label = row_label or (lambda i: f"sample {i}")
    if t.ndim != 1:
        raise InputDataError(f"{where}: time must be one-dimensional, got shape {t.shape}")
    if t.size < 2:
        raise InputDataError(f"{where}: time has {t.size} sample(s); expected at least 2")
    bad = np.flatnonzero(~np.isfinite(t))
    if bad.size:
        raise InputDataError(f"{where}: time is not finite at {label(bad[0])} ({t[bad[0]]})")
    with np.errstate(over="ignore", invalid="ignore"):
        steps = np.diff(t)
        span = t[-1] - t[0]
    if not np.isfinite(span):
        raise InputDataError(f"{where}: time span {float(t[0])!r} .. {float(t[-1])!r} "
                             "overflows; expected times in seconds of a manoeuvre")
    back = np.flatnonzero(steps <= 0)
    if back.size:
        i = back[0] + 1
        raise InputDataError(
            f"{where}: time is not strictly increasing at {label(i)}: "
            f"t = {float(t[i])!r} after {float(t[i - 1])!r}")
    dt = (t[-1] - t[0]) / (t.size - 1)
    off = np.flatnonzero(np.abs(steps - dt) > rtol * dt)
    if off.size:
        i = off[0] + 1
        raise InputDataError(
            f"{where}: time is not uniform at {label(i)}: step {float(steps[i - 1])!r} s, "
            f"expected {float(dt)!r} s (relative tolerance {rtol:g}); resample the record "
            "onto a uniform grid")
    return float(dt)


def validate_time_history(ds: xr.Dataset, required=(), name: str | None = None,
                          rtol: float = TIME_RTOL) -> float:
    """Check a time history and return its sample interval ``dt`` (s).

    Checks that coordinate ``time`` exists, is strictly increasing and uniform (every step
    within ``rtol * dt`` of ``dt``), that every channel in ``required`` is present and that
    those channels are finite. Raises :class:`~sysid.core.errors.InputDataError` naming the
    manoeuvre, the channel and the first offending sample and time.
    """
    where = name or ds.attrs.get("maneuver") or "time history"
    where = f"manoeuvre {where!r}" if not str(where).startswith(("manoeuvre", "file")) else where
    if "time" not in ds.coords and "time" not in ds.variables:
        raise InputDataError(f"{where}: no 'time' coordinate; variables: {sorted(ds.variables)}")
    t = np.asarray(ds["time"].values, dtype=float)
    dt = _check_time_grid(t, where, rtol=rtol)
    required = [required] if isinstance(required, str) else list(required)
    missing = [c for c in required if c not in ds.data_vars]
    if missing:
        raise InputDataError(f"{where}: missing channel(s) {missing}; "
                             f"available: {sorted(map(str, ds.data_vars))}")
    for ch in required:
        values = np.asarray(ds[ch].values)
        if values.dtype.kind not in "biuf":
            raise InputDataError(f"{where}: channel {ch!r} has dtype {values.dtype}; "
                                 "expected numbers")
        if values.dtype.kind == "f":
            finite = np.isfinite(values)
            if not finite.all():
                axis = ds[ch].dims.index("time") if "time" in ds[ch].dims else None
                bad_rows = (np.flatnonzero(~finite.all(axis=tuple(
                    a for a in range(values.ndim) if a != axis))) if axis is not None
                    else np.flatnonzero(~finite.ravel()))
                i = int(bad_rows[0])
                at = f"sample {i} (time {t[i]:g} s)" if axis is not None else f"element {i}"
                raise InputDataError(
                    f"{where}: channel {ch!r} is not finite (NaN or inf) at {at}; "
                    "expected finite values")
    return dt


def _infer_kind_axis(name: str) -> tuple[str, str]:
    """``("sweep", "lon")`` from ``sweep_lon_1``; ``("imported", "")`` when unrecognised."""
    tokens = re.split(r"[_\-\s.]+", name.lower())
    kind = tokens[0] if tokens and tokens[0] in KINDS else "imported"
    axis = next((tok for tok in tokens[1:] if tok in CONTROLS), "")
    return kind, axis


def _format_header(name: str, unit: str | None) -> str:
    return f"{name} [{unit}]" if unit else name


def _parse_header(cell: str) -> tuple[str, str | None]:
    """``("q", "deg/s")`` from ``q [deg/s]``; ``(name, None)`` without brackets."""
    m = re.fullmatch(r"\s*(.*?)\s*\[\s*([^\]]*?)\s*\]\s*", cell)
    if m and m.group(1):
        return m.group(1), m.group(2) or None
    return cell.strip(), None


def write_csv(ds: xr.Dataset, path: str | os.PathLike) -> None:
    """Write a time history as CSV (comma separated, ``.`` decimal point), atomically.

    Columns: ``time [s]`` then every data variable on the ``time`` dimension alone, headed
    ``name [units]``. Values are written with 17 significant digits so
    :func:`read_time_history` gets the same floats back. The first line is a comment
    ``# sysid-attrs: {...}`` holding the dataset attributes as JSON.
    """
    validate_time_history(ds)
    names = [k for k, v in ds.data_vars.items() if v.dims == ("time",)
             and v.dtype.kind in "biuf"]
    header = [_format_header("time", ds["time"].attrs.get("units", "s"))]
    header += [_format_header(str(k), ds[k].attrs.get("units")) for k in names]
    for cell in header:
        if "," in cell or "\n" in cell:
            raise InputDataError(f"cannot write {path}: column {cell!r} contains a comma or "
                                 "newline; expected plain channel names")
    table = np.column_stack([np.asarray(ds["time"].values, dtype=float)]
                            + [np.asarray(ds[k].values, dtype=float) for k in names])
    try:
        meta = json.dumps(_encode_attrs(ds.attrs, f"CSV {path}"), default=_json_default,
                          sort_keys=True)
    except (TypeError, ValueError) as exc:
        raise InputDataError(f"cannot write {path}: dataset attributes are not JSON "
                             f"serialisable ({exc})") from exc
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(f"{_CSV_ATTRS_PREFIX} {meta}\n")
            fh.write(",".join(header) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.17g")


def _is_netcdf(path: Path) -> bool:
    with open(path, "rb") as fh:
        head = fh.read(8)
    return any(head.startswith(m) for m in _NETCDF_MAGIC)


def _split(line: str, delimiter: str | None) -> list[str]:
    return [c.strip() for c in (line.split() if delimiter is None else line.split(delimiter))]


def _read_csv_table(path: Path):
    """``(columns, units, rows, line_numbers, attrs)`` of a delimited text file.

    ``columns`` are header names, ``units`` header units (or None), ``rows`` an
    ``(n, ncol)`` float array, ``line_numbers`` the 1-based file line of each row.
    """
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError as exc:
        raise InputDataError(f"file {path}: not a UTF-8 text file (byte {exc.start}); "
                             "expected CSV with a header row, or netCDF") from exc
    attrs = {}
    lines = []
    for number, line in enumerate(text.splitlines(), 1):
        stripped = line.strip()
        if stripped.startswith(_CSV_ATTRS_PREFIX):
            try:
                attrs = json.loads(stripped[len(_CSV_ATTRS_PREFIX):])
                attrs = _decode_attrs(attrs) if isinstance(attrs, dict) else attrs
            except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
                raise InputDataError(f"file {path}, line {number}: malformed sysid-attrs "
                                     f"comment ({exc})") from exc
            if not isinstance(attrs, dict):
                raise InputDataError(f"file {path}, line {number}: sysid-attrs must be a "
                                     "JSON object")
        elif stripped and not stripped.startswith("#"):
            lines.append((number, line))
    if not lines:
        raise InputDataError(f"file {path} is empty: expected a header row and data rows")
    header_line, header = lines[0]
    # Delimiter from the header: comma, then semicolon, then tab, else any whitespace.
    delimiter = next((d for d in (",", ";", "\t") if d in header), None)
    cells = _split(header, delimiter)
    if len(cells) < 2:
        raise InputDataError(
            f"file {path}, line {header_line}: header {header.strip()!r} has a single column; "
            "expected a header row of at least two columns (time and a channel) separated "
            "by commas, semicolons or whitespace")
    parsed = [_parse_header(c) for c in cells]
    columns = [c for c, _ in parsed]
    for i, col in enumerate(columns):
        if not col:
            raise InputDataError(f"file {path}, line {header_line}: column {i + 1} of the "
                                 "header is empty; expected a column name")
    dupes = sorted({c for c in columns if columns.count(c) > 1})
    if dupes:
        raise InputDataError(f"file {path}, line {header_line}: duplicate column(s) {dupes}")
    if len(lines) < 2:
        raise InputDataError(f"file {path} has a header but no data rows")
    # Semicolon files often use a decimal comma (European spreadsheets).
    decimal_comma = delimiter == ";"
    rows = np.empty((len(lines) - 1, len(columns)))
    numbers = np.empty(len(lines) - 1, dtype=int)
    name_of = {",": "comma", ";": "semicolon", "\t": "tab", None: "whitespace"}[delimiter]
    for k, (number, line) in enumerate(lines[1:]):
        fields = _split(line, delimiter)
        if len(fields) != len(columns):
            raise InputDataError(
                f"file {path}, line {number}: {len(fields)} field(s), expected {len(columns)} "
                f"({name_of}-separated like the header); check the delimiter")
        for j, cell in enumerate(fields):
            text_value = cell.replace(",", ".") if decimal_comma else cell
            try:
                rows[k, j] = float(text_value)
            except ValueError:
                raise InputDataError(
                    f"file {path}, line {number}, column {columns[j]!r}: {cell!r} is not a "
                    "number") from None
        numbers[k] = number
    return columns, [u for _, u in parsed], rows, numbers, attrs


def _read_netcdf_table(path: Path):
    """The same as :func:`_read_csv_table` for a netCDF file of 1-D variables."""
    try:
        ds = xr.load_dataset(path, decode_times=False, decode_timedelta=False)
    except Exception as exc:  # netCDF/HDF5 raise many types for broken files
        raise InputDataError(f"cannot read netCDF file {path} ({type(exc).__name__}: {exc})"
                             ) from exc
    try:
        ds = decode_complex(ds)
    except (ValueError, TypeError, KeyError, IndexError, AttributeError) as exc:
        # e.g. a corrupted sysid_attr_types JSON or a sysid_complex flag on a real variable
        raise InputDataError(f"file {path}: malformed sysid attributes "
                             f"({type(exc).__name__}: {exc})") from exc
    time_dim = next((d for d in ds.dims if str(d).lower() in ("time", "t")), None)
    if time_dim is None:
        raise InputDataError(f"file {path}: no 'time' dimension; dimensions: {list(ds.dims)}")
    names = [str(time_dim)] + [str(k) for k, v in ds.data_vars.items()
                               if v.dims == (time_dim,) and v.dtype.kind in "biuf"]
    if str(time_dim) not in ds.variables:
        raise InputDataError(f"file {path}: dimension {time_dim!r} has no coordinate values")
    if ds[time_dim].dtype.kind not in "biuf":
        raise InputDataError(f"file {path}: coordinate {time_dim!r} has dtype "
                             f"{ds[time_dim].dtype}; expected numbers (seconds)")
    rows = np.column_stack([np.asarray(ds[n].values, dtype=float) for n in names])
    units = [ds[n].attrs.get("units") for n in names]
    return names, units, rows, np.arange(rows.shape[0]), dict(ds.attrs)


def read_time_history(path: str | os.PathLike, mapping: Mapping[str, str] | None = None,
                      units: Mapping[str, str] | None = None, kind: str | None = None,
                      name: str | None = None, trim: Mapping[str, float] | None = None,
                      rtol: float = TIME_RTOL) -> xr.Dataset:
    """Read one manoeuvre from a CSV or netCDF file written by another tool.

    Parameters
    ----------
    path
        Delimited text with one header row (comma, semicolon -- with decimal comma allowed --,
        tab or whitespace; ``#`` lines are comments) or a netCDF file whose variables lie
        on a ``time`` dimension. Header cells may carry units as ``q [deg/s]``.
    mapping
        ``{sysid channel: file column}``, e.g. ``{"lon": "DLON_PCT", "q": "Q_DEGS"}``. With a
        mapping only the mapped columns (and time) are read; ``"time"`` may be mapped too.
        Without one every column is read under its own name. The time column is otherwise
        the one named ``time`` or ``t`` (any case).
    units
        ``{sysid channel: unit in the file}``. Known channels are converted to the analysis
        unit of :data:`sysid.core.units.CHANNELS`. Overrides a unit given in the header.
    kind, name
        Manoeuvre kind and name. ``name`` defaults to the file stem; ``kind`` to the first
        token of the name when it is one of ``sweep 3211 2311 doublet multisine``, else
        ``"imported"``. The excited ``axis`` is the first control name among the tokens.
    trim
        ``{channel: trim value}`` in analysis units (any sysid channel, read or not);
        channels read but not given get the mean of the first :data:`TRIM_WINDOW` (1 s) of
        data, as the data model prescribes for imported data.

    Returns
    -------
    xr.Dataset
        Time history on ``time`` (s, shifted to start at 0; the original start is in attr
        ``time_offset``), attributes per ``docs/data_model.md`` (``seed = -1``: not generated
        by sysid). Any malformed file raises :class:`~sysid.core.errors.InputDataError`.
    """
    path = Path(path)
    if not path.is_file():
        raise InputDataError(f"file {path} does not exist")
    try:
        netcdf = _is_netcdf(path)
    except OSError as exc:
        raise InputDataError(f"cannot open {path}: {exc}") from exc
    columns, file_units, rows, lines, file_attrs = (
        _read_netcdf_table(path) if netcdf else _read_csv_table(path))
    label = (lambda i: f"sample {i}") if netcdf else (lambda i: f"line {lines[i]}")

    mapping = dict(mapping or {})
    time_col = mapping.pop("time", None) or next(
        (c for c in columns if c.lower() in ("time", "t")), None)
    if time_col is None or time_col not in columns:
        raise InputDataError(
            f"file {path}: no time column {time_col or 'time'!r}; columns: {columns}; "
            "name it 'time' or map it with mapping={'time': COLUMN}")
    if not mapping:
        mapping = {c: c for c in columns if c != time_col}
    missing = {ch: col for ch, col in mapping.items() if col not in columns}
    if missing:
        raise InputDataError(
            f"file {path}: column(s) {sorted(missing.values())} not found (asked for by "
            f"mapping {missing}); columns in the file: {columns}")

    index = {c: j for j, c in enumerate(columns)}
    t = rows[:, index[time_col]]
    where = f"file {path}, column {time_col!r}"
    time_unit = (units or {}).get("time") or file_units[index[time_col]] or "s"
    # CF-style "seconds" / "seconds since <epoch>": the origin is dropped below anyway.
    if re.fullmatch(r"(s|sec|secs|second|seconds)(\s+since\s.*)?", time_unit.strip(), re.I):
        time_unit = "s"
    try:
        with np.errstate(over="ignore"):
            t = t * conversion_factor(time_unit, "s")
    except ValueError as exc:
        raise InputDataError(f"{where}: {exc}") from exc
    dt = _check_time_grid(t, where, label, rtol=rtol)

    data_vars = {}
    for ch, col in mapping.items():
        values = rows[:, index[col]]
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputDataError(f"file {path}, {label(bad[0])}, column {col!r}: value "
                                 f"{values[bad[0]]} is not finite; expected a number")
        file_unit = (units or {}).get(ch) or file_units[index[col]]
        if ch in CHANNELS:
            target = CHANNELS[ch].unit
            try:
                factor = conversion_factor(file_unit, target) if file_unit else 1.0
            except ValueError as exc:
                raise InputDataError(f"file {path}, column {col!r} (channel {ch!r}): "
                                     f"{exc}") from exc
            attrs = {"units": target, "long_name": CHANNELS[ch].long_name}
            with np.errstate(over="ignore"):
                values = values * factor
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise InputDataError(
                    f"file {path}, {label(bad[0])}, column {col!r}: value "
                    f"{rows[bad[0], index[col]]!r} {file_unit} overflows when converted to "
                    f"{target}; expected a finite number")
        else:
            attrs = {"units": file_unit or "1", "long_name": str(col)}
        if col != ch:
            attrs["source_column"] = str(col)
        var_name = ch if ch in CHANNELS else re.sub(r"[^A-Za-z0-9_.@+\-]", "_", ch)
        data_vars[var_name] = ("time", values, attrs)

    name = name or file_attrs.get("maneuver") or path.stem
    if not isinstance(name, str) or not name.strip() or "/" in name or name in (".", ".."):
        raise InputDataError(f"file {path}: manoeuvre name {name!r} is not usable as a group "
                             "name; expected a non-empty string without '/' (pass name=...)")
    guess_kind, guess_axis = _infer_kind_axis(name)
    attrs = {k: v for k, v in file_attrs.items() if not str(k).startswith("_")}
    attrs.update({
        "maneuver": name,
        "kind": kind or file_attrs.get("kind") or guess_kind,
        "axis": file_attrs.get("axis", guess_axis),
        "flight_condition": file_attrs.get("flight_condition", ""),
        "fmu_name": file_attrs.get("fmu_name", ""),
        "fmu_guid": file_attrs.get("fmu_guid", ""),
        "seed": file_attrs.get("seed", -1),
        "sysid_version": file_attrs.get("sysid_version", __version__),
        "source_file": str(path),
        "time_offset": float(t[0]),
    })
    time = (t - t[0])
    first = time < TRIM_WINDOW - 0.5 * dt
    first[0] = True  # samples further apart than the trim window: trim at the first one
    trim = dict(trim or {})
    unknown = sorted(set(trim) - set(data_vars) - set(CHANNELS))
    if unknown:
        raise InputDataError(f"file {path}: trim given for unknown channel(s) {unknown}; "
                             f"expected channels read ({sorted(data_vars)}) or sysid channels "
                             f"({sorted(CHANNELS)})")
    for key in [k for k in attrs if str(k).startswith("trim_")]:
        value = attrs[key]
        if value is None or (isinstance(value, float) and np.isnan(value)):
            del attrs[key]  # not given: computed from the data below
        elif (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number))
              or not np.isfinite(value)):
            raise InputDataError(f"file {path}: attribute {key} = {value!r}; expected a finite "
                                 "number (trim value in analysis units)")
    for var_name, value in trim.items():
        attrs[f"trim_{var_name}"] = float(value)
    for var_name, (_, values, _) in data_vars.items():
        key = f"trim_{var_name}"
        if var_name in trim:
            attrs[key] = float(trim[var_name])
        elif key not in attrs:
            attrs[key] = float(np.mean(values[first]))
    return xr.Dataset(data_vars, coords={"time": ("time", time, {"units": "s",
                                                                  "long_name": "time"})},
                      attrs=attrs)


def trim_from_attrs(sources) -> dict[str, float]:
    """``channel -> trim`` (analysis units) from ``trim_<channel>`` attributes.

    ``sources`` are attribute mappings (or objects with ``.attrs``) in order of preference:
    each channel takes its value from the first source that has a numeric one. Channels are
    the controls and the 6-DoF states (docs/data_model.md).
    """
    from sysid.core.units import CONTROLS, STATES_6DOF

    mappings = [getattr(src, "attrs", src) for src in sources]
    trim: dict[str, float] = {}
    for channel in (*CONTROLS, *STATES_6DOF):
        for attrs in mappings:
            try:
                trim[channel] = float(attrs[f"trim_{channel}"])
                break
            except (KeyError, TypeError, ValueError):
                continue
    return trim
