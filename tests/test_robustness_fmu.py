"""Hostile and foreign FMU archives, and an unstable campaign.

Every hostile archive is made from the real truth-helicopter FMU (``sysid.truth.build_fmu``,
cached) with one thing wrong, and must be refused by :func:`sysid.truth.load_fmu` and by the
exported-FMU runner of :mod:`sysid.assess.exported` with a one-line FMUError naming the archive
and the problem -- before anything is extracted: the FMU cache, the working directory, the
temporary folder and the folders around the archive gain no file.

A foreign FMU (valid FMI 2.0, but not our helicopter) loads, and using it as the truth model
names every missing variable. A campaign whose second manoeuvre diverges raises
SimulationDiverged naming the manoeuvre and the time, with the first manoeuvre kept on disk.
"""

import struct
import tempfile
import uuid
import zipfile
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from sysid.core.errors import FMUError, SimulationDiverged

pytestmark = pytest.mark.fmu

BINARY = "binaries/linux64/helicopter.so"


def _members(fmu: Path) -> dict[str, bytes]:
    with zipfile.ZipFile(fmu) as zf:
        return {name: zf.read(name) for name in zf.namelist()}


def write_archive(path: Path, members, extra_infos=()) -> Path:
    """A zip at ``path`` from ``{name: bytes}`` plus ``(ZipInfo, bytes)`` entries."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
        for info, data in extra_infos:
            zf.writestr(info, data)
    return path


def _description(members) -> str:
    return members["modelDescription.xml"].decode()


def _with_description(members, text: str) -> dict:
    return {**members, "modelDescription.xml": text.encode()}


def _declare_size(path: Path, member: str, size: int) -> None:
    """Patch the central-directory entry of ``member`` to declare ``size`` bytes
    uncompressed (a zip bomb's lie, made without inflating anything)."""
    data = bytearray(path.read_bytes())
    name = member.encode()
    pos = data.find(b"PK\x01\x02")
    while pos >= 0:
        n_name = struct.unpack_from("<H", data, pos + 28)[0]
        if bytes(data[pos + 46:pos + 46 + n_name]) == name:
            struct.pack_into("<I", data, pos + 24, size)
            path.write_bytes(bytes(data))
            return
        pos = data.find(b"PK\x01\x02", pos + 4)
    raise AssertionError(f"{member} not found in the central directory")


@pytest.fixture()
def sandbox(tmp_path, monkeypatch, truth_fmu):
    """Fresh cache, temporary folder and working directory; the truth FMU's members; a
    unique marker name for files a traversal would write."""
    cache = tmp_path / "cache"
    tmp = tmp_path / "tmp"
    cwd = tmp_path / "work" / "cwd"
    for folder in (cache, tmp, cwd):
        folder.mkdir(parents=True)
    monkeypatch.setenv("SYSID_CACHE_DIR", str(cache))
    monkeypatch.setattr(tempfile, "tempdir", str(tmp))
    monkeypatch.chdir(cwd)
    archives = tmp_path / "archives" / "deep"
    archives.mkdir(parents=True)
    return {"root": tmp_path, "cache": cache, "tmp": tmp, "cwd": cwd, "archives": archives,
            "members": _members(truth_fmu), "marker": f"evil-{uuid.uuid4().hex[:8]}.txt"}


def _hostile_cases(members, marker):
    """``(label, builder(path), message regex)``: archives with one thing wrong."""
    md = _description(members)

    def add(name, data=b"owned"):
        return lambda p: write_archive(p, {**members, name: data})

    def symlink(p):
        info = zipfile.ZipInfo("resources/link")
        info.create_system = 3
        info.external_attr = (0o120777 << 16)
        return write_archive(p, members, [(info, b"../../../../etc/passwd")])

    def fifo(p):
        info = zipfile.ZipInfo("resources/pipe")
        info.create_system = 3
        info.external_attr = (0o010644 << 16)
        return write_archive(p, members, [(info, b"")])

    def without(name):
        return lambda p: write_archive(p, {k: v for k, v in members.items() if k != name})

    def description(text):
        return lambda p: write_archive(p, _with_description(members, text))

    def garbage_binary(p):
        return write_archive(p, {**members, BINARY: b"this is not a shared library" * 10})

    def duplicate(p):
        with zipfile.ZipFile(p, "w") as zf:
            for name, data in members.items():
                zf.writestr(name, data)
            import warnings
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # zipfile warns about the duplicate name
                zf.writestr("modelDescription.xml", md.replace("sysid helicopter", "other"))
        return p

    def declared_bomb(p):
        write_archive(p, {**members, "resources/big.bin": b"\0" * 4096})
        _declare_size(p, "resources/big.bin", 0xFFFFFFF0)
        return p

    def not_a_zip(p):
        p.write_bytes(np.random.default_rng(5).bytes(4096))
        return p

    def truncated(p):
        write_archive(p, members)
        p.write_bytes(p.read_bytes()[:1500])
        return p

    entity = md.replace('<?xml version="1.0" encoding="UTF-8"?>',
                        '<?xml version="1.0" encoding="UTF-8"?>\n<!DOCTYPE fmiModelDescription '
                        '[<!ENTITY a "aaaaaaaaaa"><!ENTITY b "&a;&a;&a;&a;&a;&a;&a;&a;">]>', 1)
    return [
        ("traversal", add(f"../../{marker}"), r"'\.\./\.\./evil-.*' has a '\.\.' path"),
        ("traversal_nested", add(f"resources/../../../{marker}"), r"path traversal"),
        ("traversal_backslash", add(f"..\\..\\{marker}"), r"path traversal"),
        ("absolute", add(f"/tmp/{marker}"), r"absolute path"),
        ("absolute_windows", add(f"C:/{marker}"), r"absolute path"),
        ("symlink", symlink, r"'resources/link' is a symbolic link"),
        ("special_file", fifo, r"special file"),
        ("duplicate_member", duplicate, r"'modelDescription.xml' appears twice"),
        ("no_description", without("modelDescription.xml"), r"no modelDescription\.xml"),
        ("malformed_xml", description(md[: len(md) // 2]), r"not well-formed XML"),
        ("wrong_root", description("<?xml version='1.0'?><html/>"), r"root element <html>"),
        ("entities", description(entity), r"DOCTYPE/ENTITY"),
        ("fmi3", description(md.replace('fmiVersion="2.0"', 'fmiVersion="3.0"')),
         r"FMI version '3\.0' is not supported"),
        ("fmi1", description(md.replace('fmiVersion="2.0"', 'fmiVersion="1.0"')),
         r"FMI version '1\.0' is not supported"),
        ("no_guid", description(md.replace('guid="', 'uuid="', 1)), r"has no guid"),
        ("no_cosimulation", description(md.replace("<CoSimulation", "<Other").replace(
            "</CoSimulation>", "</Other>")), r"no <CoSimulation> element"),
        ("identifier_path", description(md.replace('modelIdentifier="helicopter"',
                                                   'modelIdentifier="../../x"')),
         r"modelIdentifier '\.\./\.\./x' is not a C identifier"),
        ("identifier_mismatch", description(md.replace(
            '<ModelExchange modelIdentifier="helicopter"',
            '<ModelExchange modelIdentifier="rotor"')),
         r"no binary for platform linux64 \(expected binaries/linux64/rotor\.so\)"),
        ("no_binary", without(BINARY), r"no binary for platform linux64 .*carries C sources"),
        ("garbage_binary", garbage_binary, r"helicopter\.so is not a shared library"),
        ("zip_bomb", declared_bomb, r"declare \d+ bytes uncompressed.*zip bomb"),
        ("not_a_zip", not_a_zip, r"not a readable zip archive"),
        ("truncated", truncated, r"not a readable zip archive"),
    ]


_CASES = [label for label, _, _ in _hostile_cases({"modelDescription.xml": b""}, "x")]


def _assert_nothing_written(sandbox, before_root):
    marker = sandbox["marker"]
    assert not list(sandbox["cache"].rglob("*")), "the FMU cache gained files"
    assert not list(sandbox["tmp"].rglob("*")), "the temporary folder gained files"
    assert not list(sandbox["cwd"].rglob("*")), "the working directory gained files"
    after_root = {p for p in sandbox["root"].rglob("*") if "cache" not in p.parts}
    assert after_root == before_root, f"new files: {sorted(after_root - before_root)}"
    for base in (sandbox["archives"], sandbox["cwd"], sandbox["root"], Path("/tmp")):
        for up in range(4):
            target = base.joinpath(*[".."] * up, marker).resolve()
            assert not target.exists(), f"{target} was written"


@pytest.mark.parametrize("label", _CASES)
def test_hostile_archive_is_refused_before_extraction(sandbox, label):
    from sysid.truth import load_fmu

    case = {c[0]: c for c in _hostile_cases(sandbox["members"], sandbox["marker"])}[label]
    _, build, message = case
    path = build(sandbox["archives"] / f"{label}.fmu")
    before = {p for p in sandbox["root"].rglob("*") if "cache" not in p.parts}
    with pytest.raises(FMUError, match=message) as info:
        load_fmu(path)
    text = str(info.value)
    assert str(path) in text and "\n" not in text
    _assert_nothing_written(sandbox, before)

    # the exported-FMU runner has its own loader: it must refuse the same way
    from sysid.assess.exported import simulate_exported

    t = np.arange(5) * 0.01
    inputs = xr.Dataset({"lon": ("time", np.zeros(5))}, coords={"time": t})
    if label == "fmi3":
        # it runs FMI 3.0 too, so the relabelled FMI 2.0 description fails its 3.0 checks
        message = "has no instantiationToken"
    for mode in ("cs", "me"):
        with pytest.raises(FMUError, match=message) as info:
            simulate_exported(path, inputs, mode=mode)
        assert str(path) in str(info.value) and "\n" not in str(info.value)
    _assert_nothing_written(sandbox, before)


def test_real_zip_bomb_refused_by_declared_size(sandbox, monkeypatch):
    """A member that really inflates far beyond its compressed size (32 MB of zeros in
    ~32 kB) is refused from the sizes the archive declares, without inflating it."""
    from sysid.fmi import runtime
    from sysid.truth import load_fmu

    monkeypatch.setattr(runtime, "MAX_ARCHIVE_BYTES", 16 << 20)
    path = write_archive(sandbox["archives"] / "bomb.fmu",
                         {**sandbox["members"], "resources/zeros.bin": bytes(32 << 20)})
    assert path.stat().st_size < 1 << 20
    before = {p for p in sandbox["root"].rglob("*") if "cache" not in p.parts}
    with pytest.raises(FMUError, match=r"zip bomb") as info:
        load_fmu(path)
    assert str(path) in str(info.value)
    _assert_nothing_written(sandbox, before)


def test_valid_copy_of_the_truth_fmu_still_loads(sandbox):
    """The checks refuse the hostile archives, not a re-zipped copy of a good one; the
    extraction lands in the cache only."""
    from sysid.truth import load_fmu

    path = write_archive(sandbox["archives"] / "copy.fmu", sandbox["members"])
    model = load_fmu(path)
    assert model.identifier == "helicopter"
    assert model.unzip_dir.is_relative_to(sandbox["cache"])
    assert (model.unzip_dir / BINARY).is_file()
    assert not list(sandbox["tmp"].rglob("*")) and not list(sandbox["cwd"].rglob("*"))


# -------------------------------------------------------------------------------------------
# foreign FMU: loadable, but not the helicopter

RENAMED = {"lon": "stick_x", "lat": "stick_y", "q": "pitch_rate", "mass": "m_total",
           "u_gust": "wind_x"}


@pytest.fixture()
def foreign_fmu(sandbox):
    md = _description(sandbox["members"])
    for old, new in RENAMED.items():
        assert f'name="{old}"' in md
        md = md.replace(f'name="{old}"', f'name="{new}"')
    md = md.replace('modelName="sysid helicopter"', 'modelName="water pump"')
    return write_archive(sandbox["archives"] / "pump.fmu",
                         _with_description(sandbox["members"], md))


def test_foreign_fmu_names_missing_variables_in_cosimulation(foreign_fmu):
    from sysid.truth import CoSimulation, load_fmu

    model = load_fmu(foreign_fmu)  # a valid FMI 2.0 archive: it loads
    assert model.name == "water pump"
    with pytest.raises(FMUError) as info:
        CoSimulation(foreign_fmu)
    text = str(info.value)
    assert str(foreign_fmu) in text and "\n" not in text
    for name in ("lon", "lat", "u_gust", "q"):
        assert f"'{name}'" in text, text
    assert "'col'" not in text  # only what is missing


def test_foreign_fmu_names_missing_variables_in_trim(foreign_fmu):
    from sysid.truth import trim

    with pytest.raises(FMUError) as info:
        trim(0.0, fmu=foreign_fmu)
    text = str(info.value)
    assert str(foreign_fmu) in text and "trim" in text
    for name in ("lon", "lat", "q", "mass"):
        assert f"'{name}'" in text, text


def test_guid_mismatch_refused_at_instantiation(sandbox):
    """A description whose GUID does not match the binary: the binary's own check refuses
    it, reported as a one-line FMUError."""
    from sysid.truth import Instance, load_fmu

    md = _description(sandbox["members"])
    start = md.index('guid="{') + len('guid="{')
    md = md[:start] + "00000000" + md[start + 8:]
    path = write_archive(sandbox["archives"] / "guid.fmu",
                         _with_description(sandbox["members"], md))
    model = load_fmu(path)
    with pytest.raises(FMUError, match=r"cannot instantiate guid\.fmu.*GUID") as info:
        Instance(model, "cs")
    assert "\n" not in str(info.value)


# -------------------------------------------------------------------------------------------
# unstable simulation inside a campaign


def test_diverging_campaign_keeps_completed_maneuvers(tmp_path, truth_fmu):
    """Stabilisation off: a small 3211 completes, then a large low-frequency sweep diverges.
    SimulationDiverged names the sweep and a time inside it; the netCDF written so far holds
    the completed 3211 (and no partial sweep)."""
    from sysid.data.campaign import list_maneuvers
    from sysid.data.importers import validate_time_history
    from sysid.data.netcdf import read_campaign
    from sysid.flight_test.campaign import Campaign, Maneuver, Stabilisation, run_campaign

    campaign = Campaign(
        name="unstable", sample_rate=50.0, seed=3,
        maneuvers=[
            Maneuver("3211_lon", "3211", "lon", amplitude=0.5, duration=1.4, base_width=0.2,
                     lead_in=0.5, lead_out=0.5),
            Maneuver("sweep_lon_1", "sweep", "lon", amplitude=10.0, duration=60.0,
                     omega_min=0.3, omega_max=2.0, long_period_cycles=1.0,
                     lead_in=1.0, lead_out=1.0),
        ],
        stabilisation=Stabilisation(enabled=False))
    out = tmp_path / "unstable.nc"
    with pytest.raises(SimulationDiverged) as info:
        run_campaign(campaign, out, quiet=True, fmu=truth_fmu)
    err = info.value
    assert err.maneuver == "sweep_lon_1"
    assert err.time is not None and 0.0 < err.time < 62.0
    assert "'sweep_lon_1'" in str(err) and f"t = {err.time:.2f} s" in str(err)
    tree = read_campaign(out)
    assert list_maneuvers(tree) == ["3211_lon"]
    first = tree["maneuvers/3211_lon"].to_dataset()
    validate_time_history(first, required=["lon", "q", "theta"])
    assert float(abs(first["theta"] - first.attrs["trim_theta"]).max()) < 60.0
    assert not [p.name for p in tmp_path.iterdir() if p.name.startswith(".unstable")]
