"""The campaign file: one netCDF-4 file with groups, and the codec that makes it possible.

A campaign is an :class:`xarray.DataTree` saved as one netCDF-4 file with groups (see
``docs/data_model.md``). netCDF knows neither complex numbers, nor booleans, nor attributes
holding ``None``, dictionaries or lists of strings, so :func:`encode_complex` maps every
dataset onto what netCDF stores and :func:`decode_complex` maps it back. The rules:

Variables (data variables and coordinates)
    * complex ``(..., )`` -> real ``(..., complex)`` with ``complex = ["real", "imag"]`` and
      attribute ``sysid_complex = 1`` (``complex64`` <-> ``float32``, ``complex128`` <->
      ``float64``, so the round trip is bit-exact);
    * bool -> ``int8`` (0/1) with attribute ``sysid_bool = 1``.

Attributes (of datasets and variables; :func:`encode_attrs`, :func:`decode_attrs`)
    * ``str``, real numbers and 1-D numeric arrays of two or more elements are stored as they
      are (plain readers see them unchanged);
    * ``bool`` -> integer 0/1, ``None`` -> ``""``, complex -> ``[real, imag]``;
    * lists and tuples of numbers -> numeric arrays; every other value (dict, list of str,
      nested or empty lists, length-1 or multi-dimensional arrays) -> a JSON string;
    * the original type of every attribute so altered is recorded in the JSON attribute
      ``sysid_attr_types`` (``{"name": "bool" | "none" | "complex" | "list" | "tuple" |
      "ndarray" | "json"}``), which :func:`decode_complex` uses to restore it exactly.

Files are always written atomically (temporary file next to the target, then rename) and read
fully into memory, so a campaign file can be replaced while its contents are in use. A
campaign path that is a symbolic link is written through to the link's target (the link
stays a link). An interrupt (Ctrl-C, SIGINT) that arrives while a file is being written is
held until the netCDF library has closed it, then raised as :class:`KeyboardInterrupt`: the
temporary is removed, the campaign is left as it was and the lock is released (an interrupt
inside the library's own file locks used to deadlock the process).
:func:`update_campaign` and :func:`update_campaign_groups` replace some groups and keep the
rest; :func:`group_attrs` and :func:`set_group_attrs` read and stamp one group's attributes
without loading the data.

Concurrent writers: every write (:func:`write_campaign`, the updates, :func:`add_maneuvers`
used by ``sysid import``) is a read-modify-write serialised between the processes of one
machine by :func:`campaign_lock` (``flock`` on the folder; re-entrant within a thread). It is
not a guarantee across machines; :mod:`sysid.pipeline` therefore never lets two tasks write
the same campaign file at once (see :mod:`sysid.pipeline.study`).

Stale temporaries: a writer's temporary is ``.<NAME>.<pid>-<random>.nc`` next to the
campaign ``NAME``. A writer that was killed (SIGKILL, power loss) leaves it behind; the next
writer of that campaign, once it holds the lock, removes every temporary of the campaign
whose writer process no longer exists on this machine, and every temporary without a pid
(older sysid versions) last modified before it acquired the lock -- no writer that follows
the lock can still be writing either (:func:`remove_stale_temporaries`).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import threading
import time
from collections.abc import Mapping
from pathlib import Path

import numpy as np
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.util import atomic_path
from sysid.data.stale import STAMP_ATTRS, stale_groups

__all__ = [
    "COMPLEX_DIM",
    "encode_attrs",
    "decode_attrs",
    "encode_complex",
    "decode_complex",
    "write_campaign",
    "read_campaign",
    "update_campaign",
    "update_campaign_groups",
    "with_groups",
    "group_attrs",
    "set_group_attrs",
    "append_maneuver",
    "add_maneuvers",
    "campaign_lock",
    "campaign_target",
    "remove_stale_temporaries",
]

#: Name of the trailing dimension holding real and imaginary parts of complex variables.
COMPLEX_DIM = "complex"

_TYPES_ATTR = "sysid_attr_types"


# --------------------------------------------------------------------------------------------
# encoding for netCDF


def json_default(value):
    """JSON for numpy scalars and arrays inside attribute values."""
    if isinstance(value, np.generic):
        return value.item()
    if isinstance(value, np.ndarray):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON serialisable")


def encode_attrs(attrs: Mapping, owner: str) -> dict:
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
                out[key] = json.dumps(payload, default=json_default)
            except (TypeError, ValueError) as exc:
                raise InputDataError(
                    f"attribute {key!r} of {owner} cannot be stored in netCDF: {exc}; "
                    "expected str, numbers, bool, None, lists, dicts or numeric arrays"
                ) from exc
    if types:
        out[_TYPES_ATTR] = json.dumps(types, sort_keys=True)
    return out


def decode_attrs(attrs: Mapping) -> dict:
    """Inverse of :func:`encode_attrs`."""
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
    return xr.Variable(dims, data, encode_attrs(attrs, owner))


def _decode_variable(var: xr.Variable) -> xr.Variable:
    attrs = decode_attrs(var.attrs)
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
    out = xr.Dataset(data_vars, coords, attrs=encode_attrs(ds.attrs, f"dataset {name}"))
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
    return xr.Dataset(data_vars, coords, attrs=decode_attrs(ds.attrs)).drop_encoding()


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
    with campaign_lock(path), _atomic_campaign(path) as tmp:
        encoded.to_netcdf(tmp, engine="netcdf4", mode="w")


def read_campaign(path: str | os.PathLike) -> xr.DataTree:
    """Read a campaign written by :func:`write_campaign`, fully into memory.

    The file is closed on return. Times and delays are left as seconds (no datetime
    decoding); complex, bool and typed attributes are rebuilt by :func:`decode_complex`.
    """
    path = Path(path)
    if path.is_dir():
        raise InputDataError(f"campaign file {path} is a directory; expected a netCDF file")
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
    Processes of one machine updating the same file at once are serialised by
    :func:`campaign_lock`, so each update sees the others' groups.

    A group that is new to the file, under parents that hold no variables, is appended to a
    copy of the file; anything else rereads and rewrites the whole campaign. Both end in
    the same file contents; the append is what keeps a study's many small updates cheap
    (measured on the hover study's campaign: a full rewrite 3.6 s, an append 0.7 s; the
    cost is per group and variable, not per byte; tests/benchmarks/test_bench_campaign_io.py).
    """
    update_campaign_groups(path, {group: dataset})


def update_campaign_groups(path: str | os.PathLike,
                           groups: Mapping[str, xr.Dataset | xr.DataTree]) -> None:
    """:func:`update_campaign` for several groups in one write of the file.

    ``groups`` maps group paths to what :func:`update_campaign` takes, applied in order
    (e.g. ``{"frequency_response": fr, "frequency_response_siso": siso}``): one stage's
    results reach the file together or not at all.
    """
    new = _new_nodes(groups)
    with campaign_lock(path):
        if not _append_new_groups(path, new):
            _rewrite_groups(path, groups)


def group_attrs(path: str | os.PathLike, group: str) -> dict | None:
    """The attributes of one group of the campaign at ``path``, read without loading the rest.

    ``None`` when the file does not exist, cannot be read as netCDF-4, or has no such group.
    """
    import netCDF4  # deferred: only the file operations need the netCDF-4 library itself

    if not Path(path).is_file():
        return None
    try:
        with netCDF4.Dataset(path, "r") as nc:
            node = _nc_group(nc, _group_path(group))
            if node is None:
                return None
            return decode_attrs({k: node.getncattr(k) for k in node.ncattrs()})
    except (OSError, RuntimeError, ValueError):
        return None


def set_group_attrs(path: str | os.PathLike, group: str, attrs: Mapping) -> None:
    """Add or change attributes of an existing group of the campaign at ``path``.

    The other attributes, the group's variables and every other group are kept. Atomic and
    serialised like :func:`update_campaign`, without rewriting the campaign's data.
    """
    import netCDF4  # deferred: only the file operations need the netCDF-4 library itself

    target = _group_path(group)
    with campaign_lock(path):
        if group_attrs(path, target) is None:
            raise InputDataError(f"campaign {path} has no group {target!r} to set "
                                 f"attributes {sorted(attrs)} on")
        with _atomic_campaign(path) as tmp:
            shutil.copyfile(path, tmp)
            with netCDF4.Dataset(tmp, "a") as nc:
                node = _nc_group(nc, target)
                merged = decode_attrs({k: node.getncattr(k) for k in node.ncattrs()})
                merged.update(attrs)
                encoded = encode_attrs(merged, f"group {target}")
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


def _new_nodes(groups: Mapping[str, xr.Dataset | xr.DataTree]) -> dict[str, xr.Dataset]:
    """``{campaign path: own dataset}`` of every node ``groups`` write (checks the types)."""
    new: dict[str, xr.Dataset] = {}
    for group, dataset in groups.items():
        target = _group_path(group)
        if isinstance(dataset, xr.DataTree):
            new.update(_subtree_nodes(target, dataset))
        elif isinstance(dataset, xr.Dataset):
            new[target] = dataset
        else:
            raise InputDataError(f"group {group!r}: expected an xarray Dataset or DataTree, "
                                 f"got {type(dataset).__name__}")
    return new


def _append_new_groups(path, new: Mapping[str, xr.Dataset]) -> bool:
    """Append the nodes ``new`` (``{"/a/b": Dataset}``, parents first) to a copy of the
    campaign and rename it into place. False (nothing done) unless the file exists, none of
    the new groups does, and no existing ancestor holds variables or dimensions the new
    groups could inherit -- the cases where appending gives exactly what a full rewrite
    would."""
    import netCDF4  # deferred: only the file operations need the netCDF-4 library itself

    if not new or not Path(path).is_file():
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
    _tree_from_nodes(encoded, f"in {path} (groups {sorted(new)})")
    with _atomic_campaign(path) as tmp:
        shutil.copyfile(path, tmp)
        for group, ds in encoded.items():
            ds.to_netcdf(tmp, mode="a", group=group, engine="netcdf4")
    return True


_HELD = threading.local()  # folders whose campaign lock this thread holds: {folder: depth}


@contextlib.contextmanager
def campaign_lock(path: str | os.PathLike):
    """Exclusive advisory lock for a read-modify-write of the campaign at ``path``.

    ``flock`` on the folder of the campaign's target (a symbolic link is followed), not on a
    lock file, so nothing is left on disk; it holds across the processes of one machine (Dask
    workers of a LocalCluster) and between threads. It is re-entrant within a thread (an
    update holds it around the write it calls). On acquiring it, stale temporaries of the
    campaign are removed (:func:`remove_stale_temporaries`). Where ``fcntl`` does not exist
    (Windows) the lock is a no-op and concurrent updates of one file are not safe.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - not POSIX
        yield
        return
    target = campaign_target(path)
    folder = target.parent
    held = getattr(_HELD, "folders", None)
    if held is None:
        held = _HELD.folders = {}
    key = str(folder)
    if held.get(key):
        held[key] += 1
        try:
            yield
        finally:
            held[key] -= 1
        return
    folder.mkdir(parents=True, exist_ok=True)
    descriptor = os.open(folder, os.O_RDONLY)
    try:
        fcntl.flock(descriptor, fcntl.LOCK_EX)
        held[key] = 1
        remove_stale_temporaries(target, acquired=time.time())
        yield
    finally:
        held.pop(key, None)
        os.close(descriptor)  # closing the descriptor releases the lock


def campaign_target(path: str | os.PathLike) -> Path:
    """The file a write of the campaign ``path`` replaces: ``path`` itself, or the final
    target of a symbolic link (which may not exist yet), absolute."""
    path = Path(path)
    return Path(os.path.realpath(path)) if path.is_symlink() else path.absolute()


#: ``.<NAME>.<pid>-<random>.nc``: the pid of the writer, for :func:`remove_stale_temporaries`.
_TEMP_PID = re.compile(r"(\d+)-[^.]*\.nc")


def _pid_alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except (PermissionError, OverflowError, ValueError):
        return True  # another user's process (or not a pid we can ask about): keep
    return True


def remove_stale_temporaries(path: str | os.PathLike, *, acquired: float) -> list[Path]:
    """Remove the temporaries a killed writer left next to the campaign ``path``.

    Call with :func:`campaign_lock` held (``acquired``: when it was acquired, epoch s). A
    temporary ``.<NAME>.<pid>-<random>.nc`` goes when process ``pid`` no longer exists; one
    without a pid (``.<NAME>.<random>.nc``) when it was last modified before ``acquired``.
    Returns the files removed.
    """
    target = campaign_target(path)
    prefix = f".{target.name}."
    removed = []
    try:
        candidates = [p for p in target.parent.iterdir()
                      if p.name.startswith(prefix) and p.name.endswith(".nc")]
    except OSError:
        return removed
    for tmp in candidates:
        rest = tmp.name[len(prefix):]
        match = _TEMP_PID.fullmatch(rest)
        try:
            if match:
                stale = not _pid_alive(int(match.group(1)))
            else:
                stale = tmp.stat().st_mtime < acquired
            if stale and tmp.is_file() and not tmp.is_symlink():
                tmp.unlink()
                removed.append(tmp)
        except OSError:
            continue  # vanished or not ours to remove
    return removed


def _atomic_campaign(path: str | os.PathLike):
    """:func:`~sysid.core.util.atomic_path` for the campaign's target with SIGINT held while
    the netCDF library writes. A symbolic link ``path`` keeps pointing at the updated
    target."""
    target = campaign_target(path)
    if target.is_dir():
        raise InputDataError(f"campaign file {path} is a directory; expected a file name "
                             "(e.g. campaign.nc)")
    return atomic_path(target, suffix=".nc", hold_interrupts=True)


def with_groups(tree: xr.DataTree, groups: Mapping[str, xr.Dataset | xr.DataTree], *,
                where: str = "in memory") -> xr.DataTree:
    """``tree`` with ``groups`` replaced as :func:`update_campaign` does in a file: a Dataset
    replaces a group's own variables and attributes and keeps its sub-groups, a DataTree
    replaces the whole sub-tree. ``tree`` itself is not modified."""
    nodes = _nodes(tree)
    for group, dataset in groups.items():
        placed = _new_nodes({group: dataset})  # checks the type
        if isinstance(dataset, xr.DataTree):
            target = _group_path(group)
            nodes = {p: ds for p, ds in nodes.items()
                     if p != target and not p.startswith(target + "/")}
        nodes.update(placed)
    return _tree_from_nodes(nodes, f"{where} (groups {sorted(map(str, groups))})")


def _rewrite_groups(path, groups: Mapping[str, xr.Dataset | xr.DataTree]) -> None:
    """Reread the campaign at ``path`` (if any), replace ``groups`` and rewrite it all."""
    tree = read_campaign(path) if Path(path).exists() else xr.DataTree()
    write_campaign(with_groups(tree, groups, where=f"in {path}"), path)


def add_maneuvers(path: str | os.PathLike, datasets: Mapping[str, xr.Dataset], *,
                  root_attrs: Mapping | None = None, replace: bool = False) -> dict:
    """Add manoeuvres ``{name: time history}`` to the campaign at ``path``.

    One locked read-modify-write (:func:`campaign_lock`): manoeuvres that other processes add
    at the same time are kept. ``root_attrs`` are set on the root where it lacks them
    (e.g. ``campaign``, ``sysid_version``); a missing file starts a campaign. A name the
    campaign already holds is refused (InputDataError, the file untouched) unless
    ``replace``; then every group computed from the replaced manoeuvres is removed
    (:func:`sysid.data.stale.stale_groups`) and stage stamps that described the old inputs
    are dropped, so nothing is left describing old data. Everything else is kept as it was.
    Returns ``{"added": [...], "replaced": [...], "removed": {group: reason}}``.
    """
    for name in datasets:
        if not name or "/" in name:
            raise InputDataError(f"manoeuvre name {name!r} must be non-empty and contain "
                                 "no '/'")
    with campaign_lock(path):
        tree = read_campaign(path) if Path(path).exists() else xr.DataTree()
        existing = set(tree["maneuvers"].children) if "maneuvers" in tree.children else set()
        replaced = sorted(set(datasets) & existing)
        if replaced and not replace:
            raise InputDataError(
                f"campaign {path} already holds manoeuvre(s) {replaced}; pass --replace "
                "(replace=True) to replace them and remove the results computed from them")
        removed = stale_groups(tree, replaced) if replaced else {}
        root = tree.to_dataset(inherit=False)
        for key, value in (root_attrs or {}).items():
            root.attrs.setdefault(key, value)
        nodes = _nodes(tree)
        nodes["/"] = root
        for group in removed:
            nodes = {p: ds for p, ds in nodes.items()
                     if p != group and not p.startswith(group + "/")}
        if replaced:
            # Stamps say which inputs produced a group: not true any more for /maneuvers
            # nor for a parent that lost children.
            parents = {"/maneuvers"} | {g.rsplit("/", 1)[0] for g in removed}
            for parent in parents & set(nodes):
                ds = nodes[parent]
                if any(k in ds.attrs for k in STAMP_ATTRS):
                    ds = ds.copy()
                    ds.attrs = {k: v for k, v in ds.attrs.items() if k not in STAMP_ATTRS}
                    nodes[parent] = ds
        nodes.update({f"/maneuvers/{n}": ds for n, ds in datasets.items()})
        write_campaign(_tree_from_nodes(nodes, f"in {path}"), path)
    return {"added": sorted(set(datasets) - existing), "replaced": replaced,
            "removed": removed}


def _update_campaign(path, group: str, dataset) -> None:
    """The full rewrite :func:`update_campaign` avoids when it can (kept for benchmarks)."""
    _new_nodes({group: dataset})
    _rewrite_groups(path, {group: dataset})


def append_maneuver(path: str | os.PathLike, name: str, dataset: xr.Dataset) -> None:
    """Add (or replace) manoeuvre ``name`` in the campaign at ``path``: group
    ``/maneuvers/<name>``."""
    if not name or "/" in name:
        raise InputDataError(f"manoeuvre name {name!r} must be non-empty and contain no '/'")
    update_campaign(path, f"maneuvers/{name}", dataset)
