"""Time histories in and out: CSV, netCDF, MATLAB (v5, v7.3) and HDF5 files, and their checks.

:func:`read_time_histories` reads every manoeuvre of a file written by another tool (CSV with
a header row or netCDF of 1-D variables on ``time``: one; MAT v5/v7.3 or HDF5: one per
top-level struct/group, or one when the file holds flat vectors; layouts in
:mod:`sysid.data.formats`), with the format sniffed from the content, not the name. Known
channels are converted to the analysis units of :data:`sysid.core.units.CHANNELS` and the
attributes of ``docs/data_model.md`` filled (trim of a channel not given:
:func:`sysid.data.campaign.first_window_mean`, the data model's one rule). A record off a
uniform grid is refused unless ``resample=`` puts it on one (:mod:`sysid.data.resample`).
:func:`read_time_history` is the one-manoeuvre form; :func:`write_time_histories` writes
campaign manoeuvres as CSV, MAT v5, MAT v7.3 or HDF5 so that reading them back gives the same
manoeuvres; :func:`validate_time_history` is the check every stage applies to a record.

CSV time histories (:func:`write_csv`, :func:`read_time_history`) have one header row naming
the columns as ``name [unit]`` (``time [s],lon [%],q [deg/s]``) and one row per sample;
:func:`write_csv` adds a first comment line ``# sysid-attrs: {...}`` with the dataset
attributes as JSON (typed by the attribute rules of :mod:`sysid.data.netcdf`), which
:func:`read_time_history` restores.
"""

from __future__ import annotations

import json
import os
import re
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from sysid import __version__
from sysid.core.errors import InputDataError
from sysid.core.units import CHANNELS, CONTROLS, PHYSICAL_RANGE, conversion_factor, physical_range
from sysid.core.util import atomic_path
from sysid.data.campaign import first_window_mean
from sysid.data.formats import FORMATS, Group, read_groups, sniff_format, write_groups
from sysid.data.netcdf import decode_attrs, decode_complex, encode_attrs, json_default
from sysid.data.resample import Piece, ordered_steps, resample_record

__all__ = ["TIME_RTOL", "KINDS", "WRITE_FORMATS", "validate_time_history", "write_csv",
           "write_time_histories", "read_time_history", "read_time_histories"]

#: Relative tolerance on the sample interval of a "uniform" time grid.
TIME_RTOL = 1e-6
#: Manoeuvre kinds recognised from the first token of a manoeuvre name.
KINDS = ("sweep", "3211", "2311", "doublet", "multisine")

#: Formats :func:`write_time_histories` writes.
WRITE_FORMATS = ("csv", *FORMATS)

_CSV_ATTRS_PREFIX = "# sysid-attrs:"
#: What the error for a non-uniform record suggests.
_RESAMPLE_HINT = ("resample it onto a uniform grid (sysid import --resample RATE|auto, or "
                  "resample= of sysid.data.importers.read_time_histories)")


def _check_time_grid(t: np.ndarray, where: str, row_label=None, rtol: float = TIME_RTOL) -> float:
    """Sample interval of a strictly increasing uniform grid; InputDataError otherwise.

    ``row_label(i)`` describes sample ``i`` in messages (e.g. the line of a CSV file).
    """
    label = row_label or (lambda i: f"sample {i}")
    steps = ordered_steps(t, where, label)
    dt = _typical_step(steps, rtol)
    off = np.flatnonzero(np.abs(steps - dt) > rtol * dt)
    if off.size:
        i = off[0] + 1
        raise InputDataError(
            f"{where}: time is not uniform at {label(i)}: step {float(steps[i - 1])!r} s, "
            f"expected {float(dt)!r} s (relative tolerance {rtol:g}); {_RESAMPLE_HINT}")
    return float((t[-1] - t[0]) / (t.size - 1))


def _typical_step(steps: np.ndarray, rtol: float) -> float:
    """The step most samples share (to ``rtol``), else the median step.

    The first offending sample is then the first one off the logger's own grid: with a gap
    (a mean step stretched by it would flag sample 1), and with jitter only in part of the
    record (a median taken among jittered steps would flag sample 1 too).
    """
    median = float(np.median(steps))
    ordered = np.sort(steps)
    # longest run of sorted steps within rtol * median of its first one
    ends = np.searchsorted(ordered, ordered + rtol * median, side="right")
    k = int(np.argmax(ends - np.arange(ordered.size)))
    run = ordered[k:ends[k]]
    return float(np.median(run)) if run.size > 1 else median


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
        _check_range(values, ch, ds[ch].attrs.get("units"), where,
                     lambda i: f"sample {i} (time {t[i]:g} s)"
                     if ds[ch].dims[:1] == ("time",) else f"element {i}")
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


def _check_range(values, channel: str, unit: str | None, where: str, label) -> None:
    """InputDataError at the first value of ``channel`` outside
    :data:`sysid.core.units.PHYSICAL_RANGE` (``unit``: the values' unit; a unit that does
    not convert to the channel's is judged in the analysis unit). NaN is left to the finite
    check; ``label(i)`` names the first offending sample (the leading axis)."""
    if channel not in PHYSICAL_RANGE:
        return
    lo, hi = physical_range(channel, unit) or PHYSICAL_RANGE[channel]
    values = np.asarray(values)
    if values.dtype.kind not in "iuf" or values.size == 0:
        return
    with np.errstate(invalid="ignore"):
        out = (values < lo) | (values > hi)
    if values.ndim > 1:
        out = out.reshape(values.shape[0], -1).any(axis=1)
    bad = np.flatnonzero(out)
    if bad.size:
        i = int(bad[0])
        value = np.asarray(values[i]).ravel()
        value = value[(value < lo) | (value > hi)][0]
        shown = unit or CHANNELS[channel].unit
        raise InputDataError(
            f"{where}, {label(i)}, channel {channel!r}: value {float(value):g} {shown} is "
            f"outside the physically possible range {lo:g} .. {hi:g} {shown} "
            "(sysid.core.units.PHYSICAL_RANGE); a corrupted sample or a wrong unit?")


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
    if Path(path).is_dir():
        raise InputDataError(f"cannot write {path}: it is a directory; expected a CSV file "
                             "name")
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
        meta = json.dumps(encode_attrs(ds.attrs, f"CSV {path}"), default=json_default,
                          sort_keys=True)
    except (TypeError, ValueError) as exc:
        raise InputDataError(f"cannot write {path}: dataset attributes are not JSON "
                             f"serialisable ({exc})") from exc
    with atomic_path(path, suffix=".csv") as tmp:
        with open(tmp, "w", encoding="utf-8", newline="\n") as fh:
            fh.write(f"{_CSV_ATTRS_PREFIX} {meta}\n")
            fh.write(",".join(header) + "\n")
            np.savetxt(fh, table, delimiter=",", fmt="%.17g")


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
    # Lines as editors number them: at "\n" (a stray \x0c or \u2028 inside a line must not
    # shift the line numbers messages give); old Mac files without "\n" split at "\r".
    raw_lines = ([ln.rstrip("\r") for ln in text.split("\n")] if "\n" in text
                 else text.split("\r"))
    for number, line in enumerate(raw_lines, 1):
        stripped = line.strip()
        if stripped.startswith(_CSV_ATTRS_PREFIX):
            try:
                attrs = json.loads(stripped[len(_CSV_ATTRS_PREFIX):])
                attrs = decode_attrs(attrs) if isinstance(attrs, dict) else attrs
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


@dataclass
class _Table:
    """One manoeuvre's columns as read from a file, before channels are chosen."""

    where: str  #: how messages name the manoeuvre's source ("file F" or "file F, struct 'S'")
    name: str | None  #: struct/group name (None: the file stem or the attrs' name)
    columns: list  #: column/field names, the time column among them
    units: list  #: unit of each column in the file, or None
    rows: np.ndarray  #: (n, ncol) float
    label: Callable[[int], str]  #: names sample i in messages (file line or sample index)
    attrs: dict  #: attributes stored with the manoeuvre
    word: str = "column"  #: what the file calls a column ("column", "field", "dataset")
    time_col: str = "time"


def _time_column(columns, mapping: dict, time: str, where: str, word: str) -> str:
    """The time column: ``mapping["time"]``, else ``time``, else one named time/t (any case)."""
    if "time" in mapping:
        col = mapping["time"]
    elif time in columns:
        col = time
    elif time != "time":
        col = None
    else:
        col = next((c for c in columns if c.lower() in ("time", "t")), None)
    if col is None or col not in columns:
        asked = col or time
        raise InputDataError(
            f"{where}: no time {word} {asked!r}; {word}s: {list(columns)}; name it 'time' "
            f"or give its name (sysid import --time NAME, time=NAME, or "
            f"mapping={{'time': NAME}})")
    return col


def _table_from_group(group: Group, mapping: dict, time: str) -> _Table:
    """The columns of a MAT/HDF5 manoeuvre: its time vector and every numeric vector of the
    same length (only the mapped ones when a mapping is given)."""
    last = group.where.split(", ")[-1]
    word = ("field" if last.startswith("struct ") else "dataset" if last.startswith("group ")
            else "variable")
    fields = {k: np.asarray(v) for k, v in group.fields.items()}
    names = [*fields, *group.unsupported]
    time_col = _time_column(names, mapping, time, group.where, word)
    for col in [time_col, *(c for k, c in mapping.items() if k != "time")]:
        if col in group.unsupported:
            raise InputDataError(group.unsupported[col].message)
    t = fields[time_col]
    if t.ndim > 1 and sum(d > 1 for d in t.shape) <= 1:
        t = t.ravel()
    if t.ndim != 1:
        raise InputDataError(f"{group.where}: time {word} {time_col!r} has shape {t.shape}; "
                             "expected a vector")
    n = t.size
    wanted = [c for k, c in mapping.items() if k != "time"]
    missing = {ch: col for ch, col in mapping.items() if ch != "time" and col not in names}
    if missing:
        raise InputDataError(
            f"{group.where}: {word}(s) {sorted(missing.values())} not found (asked for by "
            f"mapping {missing}); {word}s in the file: {names}")
    mapping = {k: c for k, c in mapping.items() if k != "time"}
    columns, data, ignored = [time_col], [t], list(group.ignored)
    for col in fields:
        if col == time_col:
            continue
        v = fields[col]
        vector = v.ravel() if v.size == n and sum(d > 1 for d in v.shape) <= 1 else None
        if vector is None:
            if mapping and col in wanted:
                raise InputDataError(
                    f"{group.where}: {word} {col!r} has shape {v.shape}; expected a vector of "
                    f"{n} samples like time {word} {time_col!r}")
            ignored.append(f"{col} (shape {v.shape})")
            continue
        if not mapping or col in wanted:
            columns.append(col)
            data.append(vector)
    attrs = dict(group.attrs)
    if ignored:
        attrs.setdefault("ignored_fields", ", ".join(ignored))
    if t.size < 2:
        raise InputDataError(f"{group.where}: time {word} {time_col!r} has {t.size} "
                             "sample(s); expected at least 2")
    rows = np.column_stack([np.asarray(d, dtype=float) for d in data])
    return _Table(where=group.where, name=group.name, columns=columns,
                  units=[group.units.get(c) for c in columns], rows=rows,
                  label=lambda i: f"sample {i}", attrs=attrs, word=word, time_col=time_col)


def _tables(path: Path, mapping: dict, time: str) -> list[_Table]:
    """Every manoeuvre of ``path`` as a :class:`_Table`, the format sniffed from content."""
    if not path.is_file():
        raise InputDataError(f"file {path} does not exist")
    try:
        kind = sniff_format(path)
    except OSError as exc:
        raise InputDataError(f"cannot open {path}: {exc}") from exc
    if kind in ("text", "netcdf"):
        columns, file_units, rows, lines, attrs = (
            _read_netcdf_table(path) if kind == "netcdf" else _read_csv_table(path))
        label = ((lambda i: f"sample {i}") if kind == "netcdf"
                 else (lambda i: f"line {lines[i]}"))
        where = f"file {path}"
        time_col = _time_column(columns, mapping, time, where, "column")
        return [_Table(where=where, name=None, columns=columns, units=file_units, rows=rows,
                       label=label, attrs=attrs, time_col=time_col)]
    return [_table_from_group(g, mapping, time) for g in read_groups(path, kind)]


def _datasets(table: _Table, path: Path, mapping: dict, units: Mapping | None,
              kind: str | None, name: str | None, trim: Mapping | None, rtol: float,
              resample) -> list[xr.Dataset]:
    """The manoeuvre(s) of one table: channels chosen, converted and checked; one dataset,
    or one per piece when ``resample`` split the record at a long gap."""
    columns, file_units, rows, label = table.columns, table.units, table.rows, table.label
    file_attrs, where0, word = table.attrs, table.where, table.word
    time_col = table.time_col
    mapping = {k: v for k, v in mapping.items() if k != "time"}
    if not mapping:
        mapping = {c: c for c in columns if c != time_col}
    missing = {ch: col for ch, col in mapping.items() if col not in columns}
    if missing:
        raise InputDataError(
            f"{where0}: {word}(s) {sorted(missing.values())} not found (asked for by "
            f"mapping {missing}); {word}s in the file: {columns}")

    index = {c: j for j, c in enumerate(columns)}
    t = rows[:, index[time_col]]
    where = f"{where0}, {word} {time_col!r}"
    time_unit = (units or {}).get("time") or file_units[index[time_col]] or "s"
    # CF-style "seconds" / "seconds since <epoch>": the origin is dropped below anyway.
    if re.fullmatch(r"(s|sec|secs|second|seconds)(\s+since\s.*)?", time_unit.strip(), re.I):
        time_unit = "s"
    try:
        with np.errstate(over="ignore"):
            t = t * conversion_factor(time_unit, "s")
    except ValueError as exc:
        raise InputDataError(f"{where}: {exc}") from exc
    if resample is None:
        _check_time_grid(t, where, label, rtol=rtol)

    data_vars = {}
    for ch, col in mapping.items():
        values = rows[:, index[col]]
        bad = np.flatnonzero(~np.isfinite(values))
        if bad.size:
            raise InputDataError(f"{where0}, {label(bad[0])}, {word} {col!r}: value "
                                 f"{values[bad[0]]} is not finite; expected a number")
        file_unit = (units or {}).get(ch) or file_units[index[col]]
        if ch in CHANNELS:
            target = CHANNELS[ch].unit
            try:
                factor = conversion_factor(file_unit, target) if file_unit else 1.0
            except ValueError as exc:
                raise InputDataError(f"{where0}, {word} {col!r} (channel {ch!r}): "
                                     f"{exc}") from exc
            attrs = {"units": target, "long_name": CHANNELS[ch].long_name}
            with np.errstate(over="ignore"):
                values = values * factor
            bad = np.flatnonzero(~np.isfinite(values))
            if bad.size:
                raise InputDataError(
                    f"{where0}, {label(bad[0])}, {word} {col!r}: value "
                    f"{rows[bad[0], index[col]]!r} {file_unit} overflows when converted to "
                    f"{target}; expected a finite number")
            _check_range(values, ch, target, f"{where0}, {word} {col!r}", label)
        else:
            attrs = {"units": file_unit or "1", "long_name": str(col)}
        if col != ch:
            attrs["source_column"] = str(col)
        var_name = ch if ch in CHANNELS else re.sub(r"[^A-Za-z0-9_.@+\-]", "_", ch)
        data_vars[var_name] = (values, attrs)

    name = name or file_attrs.get("maneuver") or table.name or path.stem
    if not isinstance(name, str) or not name.strip() or "/" in name or name in (".", ".."):
        raise InputDataError(f"{where0}: manoeuvre name {name!r} is not usable as a group "
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
    })
    trim = dict(trim or {})
    unknown = sorted(set(trim) - set(data_vars) - set(CHANNELS))
    if unknown:
        raise InputDataError(f"{where0}: trim given for unknown channel(s) {unknown}; "
                             f"expected channels read ({sorted(data_vars)}) or sysid channels "
                             f"({sorted(CHANNELS)})")
    for key in [k for k in attrs if str(k).startswith("trim_")]:
        value = attrs[key]
        if value is None or (isinstance(value, float) and np.isnan(value)):
            del attrs[key]  # not given: computed from the data below
        elif (isinstance(value, (bool, np.bool_)) or not isinstance(value, (int, float, np.number))
              or not np.isfinite(value)):
            raise InputDataError(f"{where0}: attribute {key} = {value!r}; expected a finite "
                                 "number (trim value in analysis units)")
    for var_name, value in trim.items():
        attrs[f"trim_{var_name}"] = float(value)

    names = list(data_vars)
    matrix = (np.column_stack([data_vars[v][0] for v in names]) if names
              else np.zeros((t.size, 0)))
    if resample is None:
        pieces = [Piece(time=t, values=matrix)]
    else:
        pieces = resample_record(t, matrix, rate=resample, where=where, label=label)
    out = []
    for k, piece in enumerate(pieces):
        piece_attrs = {**attrs, **piece.attrs, "time_offset": float(piece.time[0])}
        if len(pieces) > 1:
            piece_attrs["maneuver"] = f"{name}_{piece.attrs['resample_piece']}"
            piece_attrs["split_from"] = name
        time = piece.time - piece.time[0]
        for j, var_name in enumerate(names):
            key = f"trim_{var_name}"
            if key not in piece_attrs:
                # One trim for every piece: the first second of the record (the first
                # piece), the data model's rule; a later piece starts mid-manoeuvre.
                piece_attrs[key] = first_window_mean(pieces[0].time - pieces[0].time[0],
                                                     pieces[0].values[:, j])
        variables = {v: ("time", piece.values[:, j], data_vars[v][1])
                     for j, v in enumerate(names)}
        out.append(xr.Dataset(variables, coords={"time": ("time", time, {
            "units": "s", "long_name": "time"})}, attrs=piece_attrs))
    return out


def read_time_histories(path: str | os.PathLike, *, mapping: Mapping[str, str] | None = None,
                        units: Mapping[str, str] | None = None, kind: str | None = None,
                        trim: Mapping[str, float] | None = None, time: str = "time",
                        resample: float | str | None = None,
                        rtol: float = TIME_RTOL) -> dict[str, xr.Dataset]:
    """Read every manoeuvre of a CSV, netCDF, MAT (v5, v7.3) or HDF5 file.

    The format is sniffed from the content (MAT v5 header text, HDF5 signature at byte 512
    for MAT v7.3 or at 0 for HDF5/netCDF-4, netCDF-3 magic, else delimited text), never from
    the extension. CSV and netCDF files hold one manoeuvre; MAT and HDF5 files one per
    top-level struct/group (named by it), or one when they hold flat vectors (layouts:
    :mod:`sysid.data.formats`).

    Parameters
    ----------
    path
        The file.
    mapping, units, kind, trim
        As :func:`read_time_history`; the mapping names columns (CSV, netCDF) or fields
        (MAT structs, HDF5 datasets) and applies to every manoeuvre of the file.
    time
        Name of the time column/field (s, or a unit given by ``units={"time": ...}`` or
        the file). Default ``"time"``, which also finds one named ``t`` (any case).
    resample
        ``None``: a record off a uniform grid is refused (the error names the first
        offending file line for CSV, sample index otherwise, and suggests resampling).
        A rate in Hz, or ``"auto"`` (the logger's own rate, 4 significant digits): put on a
        uniform grid by :func:`sysid.data.resample.resample_record` (cubic spline; a
        zero-phase Hamming FIR anti-aliasing filter first when the new rate is below the
        data rate; gaps up to :data:`sysid.core.guidelines.GAP_MAX_STEPS` steps bridged,
        longer ones split the record into manoeuvres ``<name>_a``, ``<name>_b``, ...,
        each with ``split_from = <name>`` and the trim of the record's first second). The
        attributes ``resample_*`` say what was done (largest jitter, gaps filled and
        split, the filter).
    rtol
        Relative tolerance on the step of a uniform grid.

    Returns
    -------
    dict
        ``{manoeuvre name: time history}`` in file order (docs/data_model.md), each as
        :func:`read_time_history` returns it. Any malformed file raises
        :class:`~sysid.core.errors.InputDataError` naming the file, struct and field.

    Examples
    --------
    >>> records = read_time_histories("flight12.mat", time="t", resample="auto",
    ...                               mapping={"lon": "DLON", "q": "Q"})  # doctest: +SKIP
    """
    path = Path(path)
    mapping = dict(mapping or {})
    out: dict[str, xr.Dataset] = {}
    for table in _tables(path, mapping, time):
        for ds in _datasets(table, path, mapping, units, kind, None, trim, rtol, resample):
            name = ds.attrs["maneuver"]
            if name in out:
                raise InputDataError(f"file {path}: two manoeuvres are named {name!r}; "
                                     "expected one struct/group per manoeuvre")
            out[name] = ds
    return out


def read_time_history(path: str | os.PathLike, mapping: Mapping[str, str] | None = None,
                      units: Mapping[str, str] | None = None, kind: str | None = None,
                      name: str | None = None, trim: Mapping[str, float] | None = None,
                      rtol: float = TIME_RTOL, *, time: str = "time",
                      resample: float | str | None = None) -> xr.Dataset:
    """Read one manoeuvre from a file written by another tool (CSV, netCDF, or a MAT/HDF5
    file holding one manoeuvre; :func:`read_time_histories` reads several).

    Parameters
    ----------
    path
        Delimited text with one header row (comma, semicolon -- with decimal comma allowed --,
        tab or whitespace; ``#`` lines are comments), a netCDF file whose variables lie
        on a ``time`` dimension, or a MAT/HDF5 file. Header cells may carry units as
        ``q [deg/s]``.
    mapping
        ``{sysid channel: file column}``, e.g. ``{"lon": "DLON_PCT", "q": "Q_DEGS"}``. With a
        mapping only the mapped columns (and time) are read; ``"time"`` may be mapped too.
        Without one every column is read under its own name. The time column is otherwise
        the one named ``time`` (``time=``) or ``t`` (any case).
    units
        ``{sysid channel: unit in the file}``. Known channels are converted to the analysis
        unit of :data:`sysid.core.units.CHANNELS`. Overrides a unit given in the header.
    kind, name
        Manoeuvre kind and name. ``name`` defaults to the file stem; ``kind`` to the first
        token of the name when it is one of ``sweep 3211 2311 doublet multisine``, else
        ``"imported"``. The excited ``axis`` is the first control name among the tokens.
    trim
        ``{channel: trim value}`` in analysis units (any sysid channel, read or not);
        channels read but not given get the mean of the first :data:`sysid.data.campaign.TRIM_WINDOW` (1 s) of
        data, as the data model prescribes for imported data.
    time, resample
        As :func:`read_time_histories` (a resampled record must stay one piece here).

    Returns
    -------
    xr.Dataset
        Time history on ``time`` (s, shifted to start at 0; the original start is in attr
        ``time_offset``), attributes per ``docs/data_model.md`` (``seed = -1``: not generated
        by sysid). Any malformed file raises :class:`~sysid.core.errors.InputDataError`.
    """
    path = Path(path)
    mapping = dict(mapping or {})
    tables = _tables(path, mapping, time)
    if len(tables) != 1:
        raise InputDataError(f"file {path} holds {len(tables)} manoeuvres "
                             f"({', '.join(str(t.name) for t in tables)}); read them with "
                             "read_time_histories")
    datasets = _datasets(tables[0], path, mapping, units, kind, name, trim, rtol, resample)
    if len(datasets) != 1:
        raise InputDataError(f"file {path}: resampling split the record into "
                             f"{len(datasets)} pieces at gaps; read them with "
                             "read_time_histories")
    return datasets[0]


def write_time_histories(path: str | os.PathLike, datasets: Mapping[str, xr.Dataset], *,
                         format: str) -> None:
    """Write manoeuvres (time histories as stored in ``/maneuvers/<name>``) to one file.

    ``format``: ``"csv"`` (one manoeuvre: :func:`write_csv`), ``"mat5"`` (MAT v5 by
    ``scipy.io.savemat``), ``"mat73"`` (MAT v7.3: HDF5 with the MATLAB user block and
    ``MATLAB_class`` attributes) or ``"hdf5"``; one struct/group per manoeuvre, named by
    the manoeuvre (MAT: made a valid MATLAB name), holding the time vector ``time`` (s) and
    every numeric variable on ``time`` alone, with units and attributes (layout:
    :mod:`sysid.data.formats`). :func:`read_time_histories` gives the same manoeuvres back
    (float64 values, the attributes plus ``source_file`` and ``time_offset``). Atomic:
    the file appears whole or not at all.

    Examples
    --------
    >>> write_time_histories("flight.mat", {"sweep_lon_1": ds}, format="mat73")  # doctest: +SKIP
    """
    if format not in WRITE_FORMATS:
        raise InputDataError(f"format {format!r}: expected one of {WRITE_FORMATS}")
    if not datasets:
        raise InputDataError(f"cannot write {path}: no manoeuvres given")
    if format == "csv":
        if len(datasets) != 1:
            raise InputDataError(f"cannot write {len(datasets)} manoeuvres to CSV {path}: a "
                                 "CSV file holds one; write one file each or use mat5, mat73 "
                                 "or hdf5")
        (name, ds), = datasets.items()
        write_csv(ds.assign_attrs(maneuver=name), path)
        return
    groups = {}
    for name, ds in datasets.items():
        if not isinstance(name, str) or not name or "/" in name:
            raise InputDataError(f"manoeuvre name {name!r} must be non-empty and contain "
                                 "no '/'")
        validate_time_history(ds, name=name)
        names = [str(k) for k, v in ds.data_vars.items()
                 if v.dims == ("time",) and v.dtype.kind in "biuf"]
        fields = {"time": np.asarray(ds["time"].values, dtype=float)}
        fields.update({k: np.asarray(ds[k].values, dtype=float) for k in names})
        units = {"time": ds["time"].attrs.get("units", "s")}
        units.update({k: ds[k].attrs["units"] for k in names if ds[k].attrs.get("units")})
        groups[name] = {"fields": fields, "units": units,
                        "attrs": {**ds.attrs, "maneuver": name}}
    write_groups(path, groups, format=format)
