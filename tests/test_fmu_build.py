"""Building, packaging and loading the FMU; FMI conformance; one source of truth."""

import zipfile
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from sysid.core.errors import FMUError

pytestmark = pytest.mark.fmu


def test_fmpy_validation_reports_nothing(truth_fmu):
    from fmpy.validation import validate_fmu

    assert validate_fmu(str(truth_fmu)) == []


def test_build_is_cached_by_source_hash(truth_fmu):
    from sysid.truth import build_fmu

    assert build_fmu() == truth_fmu
    assert truth_fmu.name.startswith("helicopter-") and truth_fmu.suffix == ".fmu"


def test_fmu_is_also_a_source_fmu(truth_fmu):
    with zipfile.ZipFile(truth_fmu) as zf:
        names = set(zf.namelist())
        desc = ET.fromstring(zf.read("modelDescription.xml"))
    for f in ("fmu_core.c", "fmi2_functions.c", "model.c", "holds.c", "fmu_model.h", "model.h",
              "holds.h", "model_variables.h", "fmi2Functions.h", "fmi2FunctionTypes.h",
              "fmi2TypesPlatform.h"):
        assert f"sources/{f}" in names
    listed = {f.get("name") for f in desc.iter("File")}
    assert listed == {"fmu_core.c", "fmi2_functions.c", "model.c", "holds.c"}
    assert "sources/buildDescription.xml" not in names  # FMI 2.0: none, never an FMI 3.0 one
    assert desc.find("ModelExchange") is not None and desc.find("CoSimulation") is not None


def test_header_and_model_description_agree(truth_fmu):
    """The generated C header and modelDescription.xml list the same variables and VRs."""
    import re

    with zipfile.ZipFile(truth_fmu) as zf:
        header = zf.read("sources/model_variables.h").decode()
        desc = ET.fromstring(zf.read("modelDescription.xml"))
    in_header = {m.group(1): int(m.group(2))
                 for m in re.finditer(r"#define VR_(\w+) (\d+)", header)
              if m.group(1) not in ("STATE0", "DERIV0")}
    in_xml = {v.get("name").replace("der(", "der_").replace(")", ""): int(v.get("valueReference"))
              for v in desc.iter("ScalarVariable")}
    assert in_header == in_xml
    # states occupy 0..n-1 and their derivatives n..2n-1, as the boilerplate expects
    n = int(re.search(r"#define N_STATES (\d+)", header).group(1))
    derivs = desc.find("ModelStructure/Derivatives")
    variables = list(desc.iter("ScalarVariable"))
    for k, unknown in enumerate(derivs):
        der = variables[int(unknown.get("index")) - 1]
        state = variables[int(der.find("Real").get("derivative")) - 1]
        assert int(der.get("valueReference")) == n + k
        assert int(state.get("valueReference")) == k


def test_units_declared_with_display_units(truth_fmu):
    from sysid.truth import load_fmu

    model = load_fmu(truth_fmu)
    assert model.unit("u") == "m/s" and model.unit("p") == "rad/s"
    assert model.unit("phi") == "rad" and model.unit("ax") == "m/s2"
    assert model.unit("lon") == "%"
    assert model.variable("u").displayUnit == "ft/s"
    assert model.variable("theta").displayUnit == "deg"


def test_every_parameter_has_a_default(truth_fmu):
    from sysid.truth import load_fmu

    model = load_fmu(truth_fmu)
    assert len(model.parameter_names) > 60
    for name in model.parameter_names:
        assert model.variable(name).start is not None, name


def test_missing_compiler_gives_one_line_fmu_error(monkeypatch, tmp_path):
    from sysid.truth import build_fmu

    monkeypatch.setenv("SYSID_CACHE_DIR", str(tmp_path))
    monkeypatch.setenv("CC", "/nonexistent/cc")
    with pytest.raises(FMUError) as info:
        build_fmu(force=True)
    message = str(info.value)
    assert "/nonexistent/cc" in message and "compiler" in message
    assert "\n" not in message
    assert not list(tmp_path.rglob("*.fmu"))  # nothing half-written in the cache


def test_compile_error_leaves_no_fmu(monkeypatch, tmp_path):
    """A failing compiler run is reported in one line and leaves the cache clean."""
    import shutil

    from sysid.core.paths import fmu_sources_dir
    from sysid.truth import build_model_fmu

    src = tmp_path / "broken"
    shutil.copytree(fmu_sources_dir() / "helicopter", src)
    (src / "model.c").write_text((src / "model.c").read_text() + "\nthis is not C;\n")
    monkeypatch.setenv("SYSID_CACHE_DIR", str(tmp_path / "cache"))
    with pytest.raises(FMUError, match="compiling the helicopter FMU failed") as info:
        build_model_fmu(src, common_folder=fmu_sources_dir() / "common")
    assert "\n" not in str(info.value)
    assert not list((tmp_path / "cache").rglob("*.fmu"))


def test_corrupted_fmu_gives_one_line_fmu_error(tmp_path, truth_fmu):
    from sysid.truth import load_fmu

    bad = tmp_path / "broken.fmu"
    bad.write_bytes(truth_fmu.read_bytes()[:2000])
    with pytest.raises(FMUError, match="is not a valid FMU") as info:
        load_fmu(bad)
    assert "\n" not in str(info.value)
    missing = tmp_path / "missing.fmu"
    with pytest.raises(FMUError, match="does not exist"):
        load_fmu(missing)


def test_fmu_state_get_set_and_serialisation(truth_fmu, hover_trim):
    """fmi2GetFMUstate/SetFMUstate restore the trajectory exactly; serialisation too."""
    from sysid.truth import CoSimulation

    with CoSimulation(truth_fmu) as sim:
        sim.reset(hover_trim)
        controls = sim.trim_controls + np.array([2.0, -1.0, 0.5, 1.0])
        for _ in range(50):
            sim.step(controls)
        snap = sim.get_state()
        a = [sim.step(controls) for _ in range(50)]
        sim.set_state(snap)
        b = [sim.step(controls) for _ in range(50)]
        np.testing.assert_array_equal(a, b)
        fmu = sim._inst.fmu
        blob = fmu.serializeFMUstate(snap[0])
        restored = fmu.deSerializeFMUstate(blob)
        sim.set_state((restored, snap[1]))
        c = [sim.step(controls) for _ in range(50)]
        np.testing.assert_array_equal(a, c)
        sim.free_state(snap)


def test_rk4_lands_on_communication_points(truth_fmu, hover_trim):
    """An odd communication step (not a multiple of h_rk4) ends exactly at t + dt, and
    splitting a step into pieces changes the result only at the RK4 truncation level."""
    from sysid.truth import CoSimulation

    with CoSimulation(truth_fmu) as sim:
        sim.reset(hover_trim)
        c = sim.trim_controls + np.array([3.0, 0, 0, 0])
        y1 = sim.step(c, dt=0.0123)
        assert sim._inst.fmu.getRealStatus(2) == pytest.approx(0.0123, abs=1e-15)
        sim.reset(hover_trim)
        for _ in range(3):
            y2 = sim.step(c, dt=0.0041)
        np.testing.assert_allclose(y1, y2, rtol=1e-3, atol=1e-6)
