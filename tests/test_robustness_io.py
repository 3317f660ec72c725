"""Fuzzed readers: malformed CSV and netCDF files end in InputDataError, never another
exception, and a failed ``sysid`` command leaves its output as it was.

The CSV fuzzer starts from a valid time history (as written by :func:`sysid.data.importers.write_csv`, or
a plain one-header-row file from another tool) and applies up to three hypothesis-chosen
mutations: truncation, another delimiter, a lost or duplicated header, bad cells (NaN, inf,
huge numbers, text, decimal commas), swapped, repeated or deleted rows (non-monotonic or
non-uniform time), extra fields, a corrupted ``# sysid-attrs`` comment; plus raw random bytes
and random text. The netCDF fuzzer truncates a valid campaign file at random offsets or flips
random bits, and a table of hand-made bad files covers wrong dimensions and types, a campaign
without ``/maneuvers``, a time coordinate of strings.

Properties checked for every input:

* :func:`sysid.data.importers.read_time_history` / :func:`sysid.data.netcdf.read_campaign` either succeed with a
  valid result (uniform increasing finite time, finite channels) or raise InputDataError
  with a one-line message;
* ``sysid import`` and ``sysid frequency-response`` (through :func:`sysid.cli.main`) return
  0, or 1 with one line on stderr; after a failure the output file does not exist (fresh
  output) or is byte-identical to before (existing campaign), and no temporary file is left.
"""

import contextlib
import io as _stdio
import json
import tempfile
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from hypothesis import HealthCheck, event, given, settings
from hypothesis import strategies as st

from sysid.data import campaign, importers, netcdf
from sysid.cli import main
from sysid.core.errors import InputDataError

FUZZ = settings(max_examples=50, deadline=None, derandomize=True, database=None,
                suppress_health_check=[HealthCheck.too_slow])
FEW = settings(FUZZ, max_examples=25)

DT = 0.05
N = 240  # 12 s


def time_history(name="sweep_lon_1", seed=0):
    """A valid small time history: two controls and two rates, with units."""
    rng = np.random.default_rng(seed)
    t = np.arange(N) * DT
    lon = 50 + 5 * np.sin(1.3 * t) + rng.standard_normal(N)
    lat = 50 + 4 * np.sin(2.1 * t + 1) + rng.standard_normal(N)
    p = 0.8 * (lat - 50) + 0.2 * rng.standard_normal(N)
    q = -1.1 * (lon - 50) + 0.3 * (lat - 50) + 0.2 * rng.standard_normal(N)
    data = {"lon": ("time", lon, {"units": "%", "long_name": "longitudinal cyclic"}),
            "lat": ("time", lat, {"units": "%", "long_name": "lateral cyclic"}),
            "p": ("time", p, {"units": "deg/s", "long_name": "roll rate"}),
            "q": ("time", q, {"units": "deg/s", "long_name": "pitch rate"})}
    return xr.Dataset(data, coords={"time": ("time", t, {"units": "s"})},
                      attrs={"maneuver": name, "kind": "sweep", "axis": name.split("_")[1],
                             "trim_lon": 50.0, "trim_lat": 50.0, "seed": seed})


def campaign_tree():
    nodes = {"/": xr.Dataset(attrs={"campaign": "fuzz"})}
    for k, name in enumerate(["sweep_lon_1", "sweep_lat_1", "sweep_lon_2"]):
        nodes[f"/maneuvers/{name}"] = time_history(name, seed=k)
    return xr.DataTree.from_dict(nodes)


class _Files(dict):
    """Bytes by file name, with a short repr for hypothesis' failure reports."""

    def __repr__(self):
        return f"<valid files {sorted(self)}>"


@pytest.fixture(scope="module")
def valid_files(tmp_path_factory):
    """Bytes of a sysid CSV, a foreign-style CSV and a campaign netCDF (built once)."""
    root = tmp_path_factory.mktemp("valid")
    importers.write_csv(time_history(), root / "sysid.csv")
    ds = time_history()
    lines = ["TIME,DLON_PCT,DLAT_PCT,P_DEGS,Q_DEGS"]
    lines += [f"{t:.3f},{a:.6f},{b:.6f},{c:.6f},{d:.6f}" for t, a, b, c, d in zip(
        ds["time"].values, ds["lon"].values, ds["lat"].values, ds["p"].values,
        ds["q"].values)]
    (root / "foreign.csv").write_text("\n".join(lines) + "\n")
    netcdf.write_campaign(campaign_tree(), root / "campaign.nc")
    netcdf.write_campaign(xr.DataTree.from_dict({"/": xr.Dataset(attrs={"campaign": "old"}),
                                             "/maneuvers/doublet_col_1":
                                                 time_history("doublet_col_1", 7)}),
                      root / "existing.nc")
    return _Files({name: (root / name).read_bytes()
                   for name in ("sysid.csv", "foreign.csv", "campaign.nc", "existing.nc")})


# -------------------------------------------------------------------------------------------
# checks shared by every example


def check_time_history(ds):
    """What a successful read must guarantee."""
    assert isinstance(ds, xr.Dataset)
    t = np.asarray(ds["time"].values, dtype=float)
    assert t.ndim == 1 and t.size >= 2 and np.all(np.isfinite(t))
    assert t[0] == 0.0 and np.all(np.diff(t) > 0)
    importers.validate_time_history(ds, required=list(ds.data_vars))
    for name, var in ds.data_vars.items():
        assert np.all(np.isfinite(var.values)), name
    for key, value in ds.attrs.items():
        if key.startswith("trim_"):
            assert np.isfinite(value), key


def read_or_input_error(reader, path, **kwargs):
    """``reader(path)``; InputDataError (one line) is the only failure allowed."""
    try:
        return reader(path, **kwargs)
    except InputDataError as exc:
        assert "\n" not in str(exc), f"multi-line message: {exc!r}"
        return None


def run_cli(argv):
    """``sysid argv`` in process: (exit code, stderr text). Only SystemExit from argparse
    would escape main(); any other exception fails the test."""
    err = _stdio.StringIO()
    with contextlib.redirect_stderr(err), contextlib.redirect_stdout(_stdio.StringIO()):
        code = main([str(a) for a in argv])
    return code, err.getvalue()


def assert_clean_failure(code, stderr, output: Path, before: bytes | None):
    """A failed command: exit 1, one line naming the command, output untouched."""
    assert code == 1, f"exit {code}, stderr {stderr!r}"
    lines = stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("sysid ") and "error:" in lines[0], stderr
    if before is None:
        assert not output.exists(), "a failed command left an output file"
    else:
        assert output.read_bytes() == before, "a failed command changed the existing output"
    leftovers = [p.name for p in output.parent.glob(f".{output.name}*")]
    assert not leftovers, f"temporary files left behind: {leftovers}"


# -------------------------------------------------------------------------------------------
# CSV mutations

BAD_CELLS = ["nan", "NaN", "inf", "-inf", "", " ", "1e999", "-1e999", "1e308", "-1.7e308",
             "abc", "0x10", "1,5", "1..2", "--1", "\u00a0", "\ufeff1"]


@st.composite
def mutated_csv(draw, base: str):
    lines = base.splitlines()
    kinds = st.sampled_from(["truncate", "delimiter", "drop_header", "duplicate_column",
                             "bad_cell", "swap_rows", "repeat_row", "delete_row",
                             "extra_field", "attrs", "blank_lines", "huge_time",
                             "time_cell"])
    for kind in draw(st.lists(kinds, min_size=0, max_size=3)):
        header_at = next((k for k, line in enumerate(lines) if line and not
                          line.startswith("#")), None)
        if header_at is None:
            break
        rows = list(range(header_at + 1, len(lines)))
        if kind == "truncate":
            text = "\n".join(lines)
            cut = draw(st.integers(0, len(text)))
            lines = text[:cut].splitlines()
        elif kind == "delimiter":
            new = draw(st.sampled_from([";", "\t", " ", "|", ", ", ",,"]))
            scope = draw(st.sampled_from(["all", "header", "rows"]))
            lines = [line.replace(",", new) if (
                scope == "all" or (scope == "header") == (k == header_at)) and
                not line.startswith("#") else line for k, line in enumerate(lines)]
        elif kind == "drop_header":
            del lines[header_at]
        elif kind == "duplicate_column":
            cells = lines[header_at].split(",")
            if len(cells) > 2:
                i, j = draw(st.permutations(range(len(cells))))[:2]
                cells[j] = cells[i]
                lines[header_at] = ",".join(cells)
        elif kind in ("bad_cell", "time_cell") and rows:
            k = draw(st.sampled_from(rows))
            cells = lines[k].split(",")
            j = 0 if kind == "time_cell" else draw(st.integers(0, len(cells) - 1))
            cells[j] = draw(st.sampled_from(BAD_CELLS))
            lines[k] = ",".join(cells)
        elif kind == "swap_rows" and len(rows) > 2:
            a, b = draw(st.permutations(rows))[:2]
            lines[a], lines[b] = lines[b], lines[a]
        elif kind == "repeat_row" and rows:
            k = draw(st.sampled_from(rows))
            lines.insert(k, lines[k])
        elif kind == "delete_row" and len(rows) > 2:
            del lines[draw(st.sampled_from(rows[1:-1]))]
        elif kind == "extra_field" and rows:
            k = draw(st.sampled_from(rows))
            lines[k] += ",1.0"
        elif kind == "attrs":
            junk = draw(st.sampled_from([
                "{", "[1, 2]", "null", '{"sysid_attr_types": "{bad"}',
                '{"sysid_attr_types": "{\\"x\\": \\"complex\\"}", "x": 1}',
                '{"sysid_attr_types": "{\\"x\\": \\"ndarray\\"}", "x": "[1]"}',
                '{"trim_q": "abc"}', '{"trim_q": null}', '{"maneuver": 5}',
                '{"maneuver": "../../escape"}', '{"time_offset": "x"}', '{"seed": [1, 2]}']))
            lines.insert(0, f"# sysid-attrs: {junk}")
        elif kind == "blank_lines" and rows:
            lines.insert(draw(st.sampled_from(rows)), draw(st.sampled_from(["", "   ", "#x"])))
        elif kind == "huge_time" and rows:
            value = draw(st.sampled_from(["1e308", "-1e308", "1.7976931348623157e308"]))
            k = draw(st.sampled_from([rows[0], rows[-1]]))
            cells = lines[k].split(",")
            cells[0] = value
            lines[k] = ",".join(cells)
    return "\n".join(lines) + draw(st.sampled_from(["", "\n", "\r\n"]))


def csv_inputs(valid):
    return st.one_of(
        st.binary(max_size=600),
        st.text(max_size=400),
        mutated_csv(valid["sysid.csv"].decode()),
        mutated_csv(valid["foreign.csv"].decode()),
    )


@FUZZ
@given(data=st.data())
def test_fuzzed_csv_reads_cleanly(valid_files, data):
    content = data.draw(csv_inputs(valid_files))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "sweep_lon_9.csv"
        if isinstance(content, str):
            path.write_text(content, encoding="utf-8")
        else:
            path.write_bytes(content)
        ds = read_or_input_error(importers.read_time_history, path)
        event("read" if ds is not None else "InputDataError")
        if ds is not None:
            check_time_history(ds)
        mapped = read_or_input_error(
            importers.read_time_history, path,
            mapping={"time": "TIME", "lon": "DLON_PCT", "q": "Q_DEGS"},
            units={"q": "rad/s"})
        if mapped is not None:
            check_time_history(mapped)


@FUZZ
@given(data=st.data(), existing=st.booleans())
def test_fuzzed_csv_import_leaves_no_partial_output(valid_files, data, existing):
    content = data.draw(csv_inputs(valid_files))
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        good = tmp / "3211_lat_1.csv"  # named by its file stem
        good.write_bytes(valid_files["foreign.csv"])
        bad = tmp / "sweep_lon_9.csv"
        if isinstance(content, str):
            bad.write_text(content, encoding="utf-8")
        else:
            bad.write_bytes(content)
        out = tmp / "campaign.nc"
        before = None
        if existing:
            out.write_bytes(valid_files["existing.nc"])
            before = valid_files["existing.nc"]
        # the good file first: a later bad file must not leave it half-imported
        code, stderr = run_cli(["import", good, bad, "-o", out, "-q"])
        event(f"exit {code}")
        if code == 0:
            tree = netcdf.read_campaign(out)
            names = campaign.list_maneuvers(tree)
            assert "3211_lat_1" in names and len(names) == 2 + existing
            assert ("doublet_col_1" in names) == existing
            for name in names:
                check_time_history(tree[f"maneuvers/{name}"].to_dataset())
        else:
            assert_clean_failure(code, stderr, out, before)


@pytest.mark.parametrize("text, expected", [
    ("", "is empty"),
    ("# only a comment\n", "is empty"),
    ("time,q\n", "no data rows"),
    ("time\n0\n1\n", "single column"),
    ("time,q,q\n0,1,2\n0.1,1,2\n", "duplicate column"),
    ("q,p\n0,1\n1,2\n", "no time column"),
    ("time,q\n0,1\n0.1,nan\n0.2,1\n", "not finite"),
    ("time,q\n0,1\n0.2,1\n0.1,1\n", "not strictly increasing"),
    ("time,q\n0,1\n0,1\n0.1,1\n", "not strictly increasing"),
    ("time,q\n0,1\n0.1,1\n0.3,1\n", "not uniform"),
    ("time,q\n0,1\n0.1,1,3\n", "2 expected|3 field"),
    ("time;q\n0;1\n0,1;2,5\n0,2;1.000,0\n", "'1.000,0' is not a number"),
    ("time,q\n0,1\n0.1,1\n", None),  # valid: checked to read
    ("# sysid-attrs: {\"trim_q\": \"abc\"}\ntime,q\n0,1\n0.1,2\n", "trim_q = 'abc'"),
    ("time,q\n-1e308,1\n1e308,2\n", "time"),
    ("time,q [rad/s]\n0,1e308\n0.1,1\n", "not finite|overflow"),
    ("time [ms],q\n0,1\n1e308,1\n", "time"),
    ("time,q\n0,1\n0.1,abc\n", "'abc' is not a number"),
    ("\xff\xfe\x00garbage", "not a UTF-8|not a number|single column"),
])
def test_malformed_csv_messages(tmp_path, text, expected):
    path = tmp_path / "x.csv"
    path.write_bytes(text.encode("latin-1") if "\xff" in text else text.encode())
    if expected is None:
        check_time_history(importers.read_time_history(path))
        return
    with pytest.raises(InputDataError, match=expected) as info:
        importers.read_time_history(path)
    assert str(path) in str(info.value) and "\n" not in str(info.value)


# -------------------------------------------------------------------------------------------
# netCDF corruption


@st.composite
def corrupted_netcdf(draw, good: bytes):
    """Truncated, bit-flipped or overwritten copies of ``good``. Positions come from a
    hypothesis-drawn seed so they spread uniformly over the file (HDF5 superblock, B-trees,
    attribute heaps and raw data alike) instead of clustering near offset 0."""
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    data = bytearray(good)
    how = draw(st.sampled_from(["truncate", "flip", "overwrite", "both"]))
    if how in ("truncate", "both"):
        data = data[:int(rng.integers(0, len(data)))]
    if how in ("flip", "both") and data:
        for pos in rng.integers(0, len(data), size=draw(st.integers(1, 8))):
            data[pos] ^= 1 << int(rng.integers(0, 8))
    if how == "overwrite":
        pos = int(rng.integers(0, len(data)))
        chunk = draw(st.binary(min_size=1, max_size=64))
        data[pos:pos + len(chunk)] = chunk
    return bytes(data)


def check_campaign(tree):
    assert isinstance(tree, xr.DataTree)
    for node in tree.subtree:
        node.to_dataset()


@FUZZ
@given(data=st.data())
def test_corrupted_campaign_reads_cleanly(valid_files, data):
    content = data.draw(corrupted_netcdf(valid_files["campaign.nc"]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "campaign.nc"
        path.write_bytes(content)
        tree = read_or_input_error(netcdf.read_campaign, path)
        event("read" if tree is not None else "InputDataError")
        if tree is not None:
            check_campaign(tree)
        ds = read_or_input_error(importers.read_time_history, path)
        if ds is not None:
            check_time_history(ds)
        # a group update of a corrupted file fails before writing, or rewrites it validly
        try:
            netcdf.update_campaign(path, "notes", xr.Dataset(attrs={"note": "x"}))
        except InputDataError:
            assert path.read_bytes() == content
        else:
            check_campaign(netcdf.read_campaign(path))


@FEW
@given(data=st.data())
def test_frequency_response_cli_on_corrupted_campaign(valid_files, data):
    content = data.draw(corrupted_netcdf(valid_files["campaign.nc"]))
    with tempfile.TemporaryDirectory() as tmp:
        path = Path(tmp) / "campaign.nc"
        path.write_bytes(content)
        code, stderr = run_cli(["frequency-response", path, "--inputs", "lon,lat",
                                "--outputs", "p,q", "--maneuvers", "*", "--windows", "2,4",
                                "--n-frequencies", "8", "--quiet"])
        event(f"exit {code}")
        if code == 0:
            tree = netcdf.read_campaign(path)
            assert "frequency_response" in tree.children
        else:
            assert_clean_failure(code, stderr, path, content)


def _bad_time_histories():
    """``(label, builder(path))`` of netCDF time histories with structural faults."""
    good = time_history()
    t = good["time"].values

    def strings(path):
        xr.Dataset({"q": ("time", good["q"].values)},
                   coords={"time": ("time", np.array([f"t{k}" for k in range(N)]))}
                   ).to_netcdf(path)

    def no_time(path):
        xr.Dataset({"q": ("sample", good["q"].values)}).to_netcdf(path)

    def time_without_values(path):
        xr.Dataset({"q": ("time", good["q"].values)}).to_netcdf(path)

    def two_d_time(path):
        xr.Dataset({"q": ("time", good["q"].values)},
                   coords={"time": ("time", t), "t2": (("time", "x"), np.ones((N, 2)))}
                   ).rename_vars(t2="T").to_netcdf(path)

    def two_d_channel(path):
        xr.Dataset({"q": (("time", "axis"), np.ones((N, 3))), "p": ("time", good["p"].values)},
                   coords={"time": ("time", t)}).to_netcdf(path)

    def string_channel(path):
        xr.Dataset({"q": ("time", np.array(["a"] * N))}, coords={"time": ("time", t)}
                   ).to_netcdf(path)

    def nan_time(path):
        tt = t.copy()
        tt[5] = np.nan
        xr.Dataset({"q": ("time", good["q"].values)}, coords={"time": ("time", tt)}
                   ).to_netcdf(path)

    def reversed_time(path):
        xr.Dataset({"q": ("time", good["q"].values)}, coords={"time": ("time", t[::-1])}
                   ).to_netcdf(path)

    def one_sample(path):
        xr.Dataset({"q": ("time", [1.0])}, coords={"time": ("time", [0.0])}).to_netcdf(path)

    def empty(path):
        xr.Dataset({"q": ("time", np.zeros(0))}, coords={"time": ("time", np.zeros(0))}
                   ).to_netcdf(path)

    def bad_units(path):
        xr.Dataset({"q": ("time", good["q"].values, {"units": "furlongs"})},
                   coords={"time": ("time", t, {"units": "s"})}).to_netcdf(path)

    def bad_time_units(path):
        xr.Dataset({"q": ("time", good["q"].values)},
                   coords={"time": ("time", t, {"units": "parsecs"})}).to_netcdf(path)

    def corrupt_attr_types(path):
        xr.Dataset({"q": ("time", good["q"].values)}, coords={"time": ("time", t)},
                   attrs={"sysid_attr_types": "{not json"}).to_netcdf(path)

    def corrupt_complex(path):
        xr.Dataset({"q": ("time", good["q"].values, {"sysid_complex": 1})},
                   coords={"time": ("time", t)}).to_netcdf(path)

    def int_time_overflow(path):
        xr.Dataset({"q": ("time", good["q"].values[:3])},
                   coords={"time": ("time", np.array([0, 2**62, 2**63 - 1], dtype=np.int64))}
                   ).to_netcdf(path)

    def only_magic(path):
        path.write_bytes(b"\x89HDF\r\n\x1a\n")

    def classic_magic_garbage(path):
        path.write_bytes(b"CDF\x01" + bytes(range(256)) * 4)

    return [(f.__name__, f) for f in (
        strings, no_time, time_without_values, two_d_time, two_d_channel, string_channel,
        nan_time, reversed_time, one_sample, empty, bad_units, bad_time_units,
        corrupt_attr_types, corrupt_complex, int_time_overflow, only_magic,
        classic_magic_garbage)]


@pytest.mark.parametrize("label, build", _bad_time_histories(),
                         ids=[label for label, _ in _bad_time_histories()])
def test_malformed_netcdf_time_history(tmp_path, label, build):
    path = tmp_path / "sweep_lon_1.nc"
    build(path)
    ds = read_or_input_error(importers.read_time_history, path)
    if ds is not None:  # e.g. a 2-D channel is skipped, the 1-D ones are read
        check_time_history(ds)
    # and through the CLI into a fresh and into an existing campaign
    out = tmp_path / "out" / "campaign.nc"
    code, stderr = run_cli(["import", path, "-o", out, "-q"])
    if code != 0:
        assert_clean_failure(code, stderr, out, None)
    existing = tmp_path / "existing.nc"
    netcdf.write_campaign(campaign_tree(), existing)
    before = existing.read_bytes()
    code, stderr = run_cli(["import", path, "-o", existing, "-q"])
    if code != 0:
        assert_clean_failure(code, stderr, existing, before)


def _bad_campaigns():
    """``(label, tree builder)`` of campaigns whose content is wrong for the chain."""
    def no_maneuvers():
        return xr.DataTree.from_dict({"/": xr.Dataset(attrs={"campaign": "x"}),
                                      "/trim": xr.Dataset({"q": 0.0})})

    def replace(channel, values=None, **kw):
        def build():
            tree = campaign_tree()
            nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
            ds = nodes["/maneuvers/sweep_lon_1"]
            if values is None:
                ds = ds.drop_vars(channel)
            else:
                ds = ds.assign({channel: values(ds)})
            nodes["/maneuvers/sweep_lon_1"] = ds
            return xr.DataTree.from_dict(nodes)
        build.__name__ = kw.get("name", channel)
        return build

    def string_time():
        tree = campaign_tree()
        nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
        for key in [k for k in nodes if k.startswith("/maneuvers/")]:
            ds = nodes[key]
            nodes[key] = ds.assign_coords(time=[f"{v:.2f}s" for v in ds["time"].values])
        return xr.DataTree.from_dict(nodes)

    def non_uniform_time():
        tree = campaign_tree()
        nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
        ds = nodes["/maneuvers/sweep_lat_1"]
        t = ds["time"].values.copy()
        t[100:] += 0.013
        nodes["/maneuvers/sweep_lat_1"] = ds.assign_coords(time=t)
        return xr.DataTree.from_dict(nodes)

    def wrong_dims():
        tree = campaign_tree()
        nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
        ds = nodes["/maneuvers/sweep_lon_1"]
        nodes["/maneuvers/sweep_lon_1"] = ds.assign(
            q=(("time", "axis"), np.ones((ds.sizes["time"], 2))))
        return xr.DataTree.from_dict(nodes)

    def constant_input():
        tree = campaign_tree()
        nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
        for key in [k for k in nodes if k.startswith("/maneuvers/")]:
            nodes[key] = nodes[key].assign(lat=xr.full_like(nodes[key]["lat"], 50.0))
        return xr.DataTree.from_dict(nodes)

    def correlated_inputs():
        tree = campaign_tree()
        nodes = {n.path: n.to_dataset(inherit=False) for n in tree.subtree}
        for key in [k for k in nodes if k.startswith("/maneuvers/")]:
            ds = nodes[key]
            nodes[key] = ds.assign(lat=2 * ds["lon"] - 10).assign_attrs(
                trim_lat=2 * ds.attrs["trim_lon"] - 10)  # perturbations exactly collinear
        return xr.DataTree.from_dict(nodes)

    builders = [no_maneuvers,
                replace("q"),
                replace("q", lambda ds: ds["q"].where(ds["time"] != ds["time"][17]),
                        name="nan_sample"),
                replace("lon", lambda ds: ds["lon"] * np.inf, name="inf_input"),
                string_time, non_uniform_time, wrong_dims, constant_input]
    return [(b.__name__, b) for b in builders] + [("correlated_inputs", correlated_inputs)]


@pytest.mark.parametrize("label, build", _bad_campaigns(),
                         ids=[label for label, _ in _bad_campaigns()])
def test_frequency_response_cli_on_bad_campaign(tmp_path, label, build):
    path = tmp_path / "campaign.nc"
    netcdf.write_campaign(build(), path)
    before = path.read_bytes()
    code, stderr = run_cli(["frequency-response", path, "--inputs", "lon,lat",
                            "--outputs", "p,q", "--maneuvers", "*", "--windows", "2,4",
                            "--n-frequencies", "8", "--quiet"])
    assert_clean_failure(code, stderr, path, before)
    # and the message says what was wrong (collinear everywhere: no response at all, which
    # used to be written as an all-NaN group with exit status 0; issue 26 item 5)
    words = {"no_maneuvers": "no /maneuvers", "q": "'q'", "nan_sample": "'q'",
             "inf_input": "'lon'", "string_time": "time", "non_uniform_time": "uniform",
             "wrong_dims": "'q'", "constant_input": "'lat'",
             "correlated_inputs": "inputs lon, lat are collinear"}
    assert words[label] in stderr, stderr


def test_import_refuses_name_clash_and_keeps_existing(tmp_path, valid_files):
    """Two files with the same manoeuvre name: refused, existing campaign unchanged."""
    a = tmp_path / "a" / "sweep_lon_1.csv"
    b = tmp_path / "b" / "sweep_lon_1.csv"
    for f in (a, b):
        f.parent.mkdir()
        f.write_bytes(valid_files["sysid.csv"])
    out = tmp_path / "campaign.nc"
    out.write_bytes(valid_files["existing.nc"])
    code, stderr = run_cli(["import", a, b, "-o", out, "-q"])
    assert_clean_failure(code, stderr, out, valid_files["existing.nc"])
    assert "used by two input files" in stderr


def test_sysid_attrs_types_roundtrip_under_fuzzed_values(tmp_path):
    """Attribute encoding (the CSV comment and netCDF attributes) survives odd values."""
    ds = time_history().assign_attrs(
        note="comma, \"quotes\" and\nnewline", empty_list=[], nested={"a": [1, {"b": None}]},
        flag=True, nothing=None, z=1 + 2j, arr=np.arange(3.0), one=[1.5])
    path = tmp_path / "sweep_lon_1.csv"
    importers.write_csv(ds, path)
    back = importers.read_time_history(path)
    for key in ("note", "empty_list", "nested", "flag", "nothing", "z", "one"):
        assert back.attrs[key] == ds.attrs[key], key
    np.testing.assert_array_equal(back.attrs["arr"], ds.attrs["arr"])
    header = path.read_text().splitlines()[0]
    assert json.loads(header.split(":", 1)[1])["note"] == ds.attrs["note"]
