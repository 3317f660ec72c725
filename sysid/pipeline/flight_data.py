"""Flight data end to end, with no truth model: files -> campaign -> responses -> both fits
-> verification -> FMUs -> report.

:func:`run_flight_data` is the library call behind ``sysid run --data``. It runs the stages
of :func:`sysid.pipeline.study.run_study` (the same stage functions, caching and files) on
time histories read from files instead of a campaign flown on the truth FMU:

1. import: every manoeuvre of every file (:mod:`sysid.data.importers`), one campaign;
2. the conditioned composite responses of the sweeps (``sweep_*``) for every measured
   output;
3. frequency-domain identification of the measured pairs, and time-domain identification on
   the 3211s (every manoeuvre when there are none), started from the frequency-domain model:
   with no truth linearisation that is the best start the data give;
4. verification on the 2311s (every manoeuvre when there are none: then not independent);
5. export of both models as FMUs, checked against sysid's own simulation and the data;
6. the report (no truth curves: nothing reads ``/linearization``).

The model's outputs are the measured channels (:func:`measured_structure`): the structure's
states that are measured, plus the accelerometers ``ax ay az`` through their measurement
equations (body-axis specific force; :mod:`sysid.models.toml`), so that data without
``u v w`` are fitted on ``ax ay az`` in their place (:func:`measured_pairs`).

References
----------
* Tischler, M. B. and Remple, R. K., *Aircraft and Rotorcraft System Identification*, 2nd ed.,
  AIAA, 2012, ch. 11 (accelerometer measurement equations) and ch. 13 (frequency-domain start
  values for a time-domain fit).
"""

from __future__ import annotations

import hashlib
import math
import tomllib
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TextIO

import numpy as np
import xarray as xr

import sysid
from sysid.core.errors import InputDataError
from sysid.core.units import ACCELERATIONS, CONTROLS, STATES_6DOF
from sysid.core.util import atomic_path, numeric_settings
from sysid.data import importers
from sysid.identify.frequency_domain import DEFAULT_PAIRS, parse_pairs
from sysid.models import structure_path
from sysid.models.toml import ACCELEROMETER_ROWS, structure_from_dict
from sysid.data.netcdf import read_campaign
from sysid.pipeline.study import (PARTS, TIME_DOMAIN_AUTO, StudySettings, _group_key, _key,
                                  _Study)

__all__ = ["FLIGHT_DATA_STRUCTURE", "read_flight_data", "measured_outputs", "measured_pairs",
           "measured_structure", "structure_toml", "run_flight_data"]

#: The structure fitted to flight data when none is named.
FLIGHT_DATA_STRUCTURE = "hover_6dof"


# --------------------------------------------------------------------------------------------
# import


def read_flight_data(files: Sequence[str | Path], *, mapping: Mapping[str, str] | None = None,
                     units: Mapping[str, str] | None = None,
                     trim: Mapping[str, float] | None = None, time: str = "time",
                     resample: float | str | None = None) -> dict[str, xr.Dataset]:
    """``{manoeuvre: time history}`` of every manoeuvre in ``files``, in file order.

    Each file (CSV, netCDF, MATLAB v5/v7.3 or HDF5; several manoeuvres in one MAT/HDF5 file)
    is read by :func:`sysid.data.importers.read_time_histories`. ``resample`` (None, a rate
    in Hz or ``"auto"``) puts a jittered record on a uniform grid; with ``"auto"`` every
    record gets the same rate (the median of the records' own, to 4 significant digits), as
    the spectra need. ``time`` names the time vector. A manoeuvre name given by two files
    is refused.
    """
    if not files:
        raise InputDataError("flight data: no files given")
    out: dict[str, xr.Dataset] = {}
    for file in files:
        path = Path(file)
        read = importers.read_time_histories(path, mapping=dict(mapping or {}) or None,
                                             units=units, trim=trim, time=time,
                                             resample=resample)
        for name, ds in read.items():
            if name in out:
                raise InputDataError(f"{path}: manoeuvre {name!r} is also in "
                                     f"{out[name].attrs.get('source_file', 'another file')}")
            out[name] = ds
    rates = {float(ds.attrs.get("resample_rate_hz", 0.0)) for ds in out.values()}
    if resample == "auto" and len(rates) > 1:
        # each record's own median step differs in the last digits; the spectra need one
        # rate: the median one, to 4 significant digits
        common = float(f"{float(np.median(sorted(rates))):.4g}")
        return read_flight_data(files, mapping=mapping, units=units, trim=trim, time=time,
                                resample=common)
    return out


# --------------------------------------------------------------------------------------------
# what is measured: outputs, pairs, structure


def measured_outputs(records: Iterable[xr.Dataset], states: Sequence[str] = STATES_6DOF
                     ) -> tuple[str, ...]:
    """The channels measured in every record that a model can output: the ``states`` that
    are measured, then the accelerometers ``ax ay az``."""
    records = list(records)
    have = set.intersection(*(set(map(str, r.data_vars)) for r in records)) if records \
        else set()
    return tuple(c for c in (*states, *ACCELERATIONS) if c in have)


def measured_pairs(outputs: Sequence[str], pairs=DEFAULT_PAIRS) -> tuple[tuple[str, str], ...]:
    """The frequency-domain fit's pairs for ``outputs``: ``pairs`` (default the paper's,
    :data:`sysid.identify.frequency_domain.DEFAULT_PAIRS`; a structure's own ``pairs``), with
    the accelerometer of an unmeasured velocity in its place (``ax/lon`` for ``u/lon``) and
    the others whose output is not measured left out."""
    velocity = {row: acc for acc, row in ACCELEROMETER_ROWS.items()}
    out = []
    for o, i in parse_pairs(pairs):
        if o not in outputs and velocity.get(o) in outputs:
            o = velocity[o]
        if o in outputs and (o, i) not in out:
            out.append((o, i))
    return tuple(out)


def measured_structure(structure: str | Path, outputs: Sequence[str]) -> dict:
    """The TOML description (parsed) of ``structure`` with ``outputs`` as its outputs.

    An output equation may not read a delayed B entry (:mod:`sysid.models.structure`): a
    delay on a whole input column whose B entries an accelerometer reads (e.g. ``tau_ped``
    of ``hover_6dof`` on ``Y_ped``, read by ``ay``) becomes a delay on each entry of that
    column that no output equation reads (the same name for one entry, ``<name>_<row>`` for
    several); the entries read stay undelayed.
    """
    path = structure_path(structure)
    spec = tomllib.loads(path.read_text(encoding="utf-8"))
    states = list(spec.get("states", []))
    outputs = [o for o in outputs if o in states or o in ACCELEROMETER_ROWS]
    if not outputs:
        raise InputDataError(f"structure {path}: none of its states {states} nor ax, ay, az "
                             f"is measured")
    spec["outputs"] = outputs
    if "pairs" in spec:  # the structure's own pairs, on the measured outputs
        pairs = measured_pairs(outputs, spec["pairs"])
        if not pairs:
            raise InputDataError(f"structure {path}: none of its pairs {spec['pairs']} has a "
                                 f"measured output (measured: {outputs})")
        spec["pairs"] = [f"{o}/{i}" for o, i in pairs]
    read = {ACCELEROMETER_ROWS[o] for o in outputs if o in ACCELEROMETER_ROWS}
    if read:
        probe = structure_from_dict({**{k: v for k, v in spec.items() if k != "pairs"},
                                     "outputs": states, "delays": {}},
                                    trim={"theta": 0.0, "phi": 0.0}, source=str(path))
        entries = {e for p in probe.parameters if p.matrix == "B"
                   for e in [(p.row, p.column), *((r, c) for r, c, _ in p.also)]}
        delays = {}
        for name, item in dict(spec.get("delays", {})).items():
            item = dict(item) if isinstance(item, Mapping) else {"entry": item}
            entry = str(item.get("entry", ""))
            if "," in entry:
                delays[name] = item
                continue
            rows = [r for r in states if (r, entry) in entries]
            if not any(r in read for r in rows):
                delays[name] = item
                continue
            kept = [r for r in rows if r not in read]
            for r in kept:
                delays[name if len(kept) == 1 else f"{name}_{r}"] = {**item,
                                                                    "entry": f"{r},{entry}"}
        spec["delays"] = delays
    spec["description"] = (str(spec.get("description", "")) + f"; outputs {', '.join(outputs)}"
                           " (the measured channels)")
    structure_from_dict(spec, trim={"theta": 0.0, "phi": 0.0}, source=str(path))  # checks
    return spec


def _toml_value(value) -> str:
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, (int, float)):
        if isinstance(value, float) and not math.isfinite(value):
            return ("inf" if value > 0 else "-inf") if math.isinf(value) else "nan"
        return repr(value)
    if isinstance(value, str):
        return '"' + value.replace("\\", "\\\\").replace('"', '\\"') + '"'
    if isinstance(value, list):
        return "[" + ", ".join(_toml_value(v) for v in value) + "]"
    if isinstance(value, Mapping):
        return "{ " + ", ".join(f"{_toml_key(k)} = {_toml_value(v)}"
                                for k, v in value.items()) + " }"
    raise InputDataError(f"structure TOML: cannot write {value!r}")


def _toml_key(key: str) -> str:
    bare = key.replace("_", "").replace("-", "").isalnum()
    return key if bare else _toml_value(key)


def structure_toml(spec: Mapping) -> str:
    """TOML text of a parsed structure description (scalars and lists first, then one table
    per sub-table, its entries inline); :func:`tomllib.loads` gives ``spec`` back."""
    lines = [f"{_toml_key(k)} = {_toml_value(v)}" for k, v in spec.items()
             if not isinstance(v, Mapping)]
    for table, items in spec.items():
        if isinstance(items, Mapping):
            lines += ["", f"[{table}]"] + [f"{_toml_key(k)} = {_toml_value(v)}"
                                           for k, v in items.items()]
    return "\n".join(lines) + "\n"


# --------------------------------------------------------------------------------------------
# the chain


class _FlightData(_Study):
    """:func:`run_study`'s stages on imported data: no truth FMU, no linearisation."""

    td_start = "frequency_domain"
    with_truth = False

    def __init__(self, out_dir: str | Path, records: dict[str, xr.Dataset], structure: str,
                 *, quiet: bool, log: TextIO | None, source: str, transient_states: str,
                 time_domain_method: str):
        names = list(records)
        sweeps = [n for n in names if n.startswith("sweep")]
        if not sweeps:
            raise InputDataError(f"flight data: no sweep manoeuvre (names sweep_*) among "
                                 f"{names}; the frequency responses need at least one")
        missing = [c for c in CONTROLS if not all(c in r for r in records.values())]
        if missing:
            raise InputDataError(f"flight data: control(s) {missing} are not in every "
                                 f"manoeuvre; map them with --map {missing[0]}=COLUMN")
        self.outputs = measured_outputs(records.values())
        if not self.outputs:
            raise InputDataError(f"flight data: no measured output (any of "
                                 f"{[*STATES_6DOF, *ACCELERATIONS]}) in every manoeuvre")
        settings = StudySettings(
            structure=structure, transient_states=transient_states,
            time_domain_method=time_domain_method,
            time_domain_maneuvers="3211_*" if any(n.startswith("3211_") for n in names)
            else "*",
            verification_maneuvers="2311_*" if any(n.startswith("2311_") for n in names)
            else "*")
        self.open(out_dir, settings, quiet=quiet, log=log)
        self.records, self.source = records, source
        spec = measured_structure(structure, self.outputs)
        # a structure's own pairs are already on the measured outputs; else the paper's
        self.fd_pairs = None if "pairs" in spec else measured_pairs(self.outputs)
        text = structure_toml(spec)
        structure_file = self.out / "structure.toml"
        if not structure_file.exists() or structure_file.read_text() != text:
            with atomic_path(structure_file) as tmp:
                Path(tmp).write_text(text, encoding="utf-8")
        settings.structure = str(structure_file)
        digest = hashlib.sha256()
        for name, ds in records.items():
            digest.update(repr((name, sorted(map(str, ds.variables)),
                                sorted((str(k), str(v)) for k, v in ds.attrs.items()))).encode())
            for var in sorted(map(str, ds.variables)):
                digest.update(np.ascontiguousarray(ds[var].values, dtype=float).tobytes())
        self.key_campaign = _key("import", digest.hexdigest(), sysid.__version__)
        self.key_fr = _key("fr", self.key_campaign, settings.sweep_maneuvers,
                           settings.transient_states, self.outputs)
        self.key_fd = _key("fd", self.key_fr, text, settings.fd_coherence, self.fd_pairs)
        # started from the frequency-domain model, the time-domain fit depends on it
        estimator = settings.time_domain_estimator
        self.key_td = _key("td", self.key_campaign, self.key_fd, text,
                           settings.time_domain_maneuvers, self.td_start,
                           *(() if estimator == "output_error" else (estimator,)))
        self.key_models = _key(self.key_fd, self.key_td)
        self.fit_keys = {"frequency_domain": self.key_fd, "time_domain": self.key_td}

    def data(self) -> None:
        self.campaign_stage("import", self.imported)
        self.responses()

    def time_domain(self) -> None:
        # started from the frequency-domain model, which goes into the campaign first
        if not self.fitted("frequency_domain"):
            self.frequency_domain()
        if _group_key(self.path, "models/frequency_domain") != self.key_fd:
            fitted = read_campaign(self.fit_path("frequency_domain"))
            self.write({"models/frequency_domain":
                        fitted["models/frequency_domain"].to_dataset()})
        super().time_domain()

    def imported(self) -> xr.DataTree:
        root = xr.Dataset(attrs={"campaign": self.out.name or "flight data",
                                 "source": self.source, "sysid_version": sysid.__version__})
        return xr.DataTree.from_dict({"/": root, **{f"maneuvers/{n}": ds
                                                    for n, ds in self.records.items()}})


def run_flight_data(files: Sequence[str | Path], out_dir: str | Path, *,
                    mapping: Mapping[str, str] | None = None,
                    units: Mapping[str, str] | None = None,
                    trim: Mapping[str, float] | None = None, time: str = "time",
                    resample: float | str | None = None,
                    structure: str | Path = FLIGHT_DATA_STRUCTURE,
                    transient_states: str = "auto",
                    time_domain_method: str = TIME_DOMAIN_AUTO, quiet: bool = False,
                    log: TextIO | None = None) -> Path:
    """Identify a helicopter from flight-test files; return the report's path.

    ``files`` are read by :func:`read_flight_data` (``mapping``, ``units``, ``trim``,
    ``time``, ``resample`` as there). ``out_dir`` receives what :func:`sysid.pipeline.study.
    run_study` writes (``campaign.nc``, ``frequency_domain.fmu``, ``time_domain.fmu``,
    ``comparison.csv``, ``report.html``, ``figures/``) and ``structure.toml``, the
    ``structure`` with the measured outputs (:func:`measured_structure`);
    ``transient_states`` and ``time_domain_method`` are the leakage conditioning and the
    time-domain estimator of :class:`sysid.pipeline.study.StudySettings`. A re-run reuses
    every stage whose inputs did not change. Progress goes to standard error (or ``log``)
    unless ``quiet``; the stages' tables to standard output (or ``log``).

    Examples
    --------
    >>> run_flight_data(sorted(Path("flight").glob("*.mat")), "reports/flight",
    ...                 resample="auto")                                  # doctest: +SKIP
    """
    records = read_flight_data(files, mapping=mapping, units=units, trim=trim, time=time,
                               resample=resample)
    source = ", ".join(str(f) for f in files)
    with numeric_settings():
        study = _FlightData(out_dir, records, str(structure), quiet=quiet, log=log,
                            source=source, transient_states=transient_states,
                            time_domain_method=time_domain_method)
        report = None
        for part in PARTS:
            report = getattr(study, part)()
    return report
