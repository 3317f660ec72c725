"""Shared helpers: units, rigid-body kinematics, atomic writes, CLI error handling."""

import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from sysid.core import units
from sysid.cli import main
from sysid.core.errors import SysidError
from sysid.core.kinematics import derivative_name, rigid_body_terms
from sysid.core.util import atomic_path, rng


def test_conversions_match_definitions():
    assert units.convert(1.0, "ft/s", "m/s") == pytest.approx(0.3048)
    assert units.convert(math.pi, "rad", "deg") == pytest.approx(180.0)
    assert units.convert(1.0, "kt", "ft/s") == pytest.approx(1852 / 3600 / 0.3048)
    assert units.convert(9.80665, "m/s2", "ft/s^2") == pytest.approx(32.174049, rel=1e-7)
    with pytest.raises(ValueError, match="different dimensions"):
        units.convert(1.0, "m", "rad")
    with pytest.raises(ValueError, match="unknown unit"):
        units.convert(1.0, "furlong", "m")


def test_percent_is_the_dimensionless_hundredth_in_every_table():
    """One unit table: % is 1/100 of the dimensionless unit (SI; FMI 2.0 factor 0.01), for
    conversion and for the FMI unit definitions of the truth and the exported FMUs."""
    from sysid.fmi.description import UnitDefinition

    assert units.convert(50.0, "%", "1") == pytest.approx(0.5)
    assert units.convert(12.5, "%", "percent") == 12.5
    assert units.convert(12.5, "%", "%") == 12.5
    with pytest.raises(ValueError, match="different dimensions"):
        units.convert(1.0, "%", "rad")
    percent = UnitDefinition.of("%")
    assert percent.exponents == () and percent.factor == 0.01
    # N.m = kg m2 s-2 in FMI's base-unit order; rad/s displays deg/s at 180/pi
    assert UnitDefinition.of("N.m").exponents == (("kg", 1), ("m", 2), ("s", -2))
    (name, factor), = UnitDefinition.of("rad/s").displays
    assert name == "deg/s" and factor == pytest.approx(180.0 / math.pi, rel=1e-15)


def test_rigid_body_terms_against_nonlinear_kinematics():
    """Finite-difference the nonlinear gravity/Euler equations and compare with the terms."""
    theta0, phi0, u0, v0, w0 = 6.76, -2.87, 12.0, -1.5, 3.0
    g = units.G0 / units.FT
    d2r = math.pi / 180

    def f(x):  # x = u v w p q r phi theta psi in ft/s, deg/s, deg; no aerodynamic forces
        u, v, w, p, q, r, phi, th, _ = x
        p, q, r, phi, th = p * d2r, q * d2r, r * d2r, phi * d2r, th * d2r
        return np.array([
            r * v - q * w - g * math.sin(th),
            p * w - r * u + g * math.cos(th) * math.sin(phi),
            q * u - p * v + g * math.cos(th) * math.cos(phi),
            0.0, 0.0, 0.0,
            (p + math.tan(th) * (q * math.sin(phi) + r * math.cos(phi))) / d2r,
            (q * math.cos(phi) - r * math.sin(phi)) / d2r,
            ((q * math.sin(phi) + r * math.cos(phi)) / math.cos(th)) / d2r,
        ])

    x0 = np.array([u0, v0, w0, 0, 0, 0, phi0, theta0, 0.0])
    jac = np.empty((9, 9))
    for k in range(9):
        dx = np.zeros(9)
        dx[k] = 1e-5
        jac[:, k] = (f(x0 + dx) - f(x0 - dx)) / 2e-5
    terms = rigid_body_terms(theta0=theta0, phi0=phi0, u0=u0, v0=v0, w0=w0)
    # The steady-flight terms neglect products with trim rates (zero here) only.
    np.testing.assert_allclose(terms.values, jac, atol=1e-7)
    assert derivative_name("q", "u") == "M_u" and derivative_name("r", "ped") == "N_ped"


def test_atomic_path_leaves_nothing_on_failure(tmp_path):
    target = tmp_path / "out.nc"
    with pytest.raises(RuntimeError):
        with atomic_path(target) as tmp:
            tmp.write_text("half")
            raise RuntimeError("boom")
    assert list(tmp_path.iterdir()) == []
    with atomic_path(target) as tmp:
        tmp.write_text("whole")
    assert target.read_text() == "whole" and len(list(tmp_path.iterdir())) == 1


def test_rng_requires_seed_and_is_reproducible():
    with pytest.raises(ValueError, match="seed"):
        rng(None)
    assert rng(3).standard_normal(5).tobytes() == rng(3).standard_normal(5).tobytes()


def test_cli_reports_user_errors_on_one_line(capsys, monkeypatch):
    import argparse

    import sysid.cli as cli

    def failing(args):
        raise SysidError("channel 'q' missing in record sweep_lon_1")

    real = cli.build_parser

    def parser_with_failing_command():
        parser = real()
        sub = next(a for a in parser._actions if isinstance(a, argparse._SubParsersAction))
        sub.add_parser("boom").set_defaults(func=failing)
        return parser

    monkeypatch.setattr(cli, "build_parser", parser_with_failing_command)
    assert main(["boom"]) == 1
    err = capsys.readouterr().err.strip()
    assert err == "sysid boom: error: channel 'q' missing in record sweep_lon_1"


def test_atomic_path_gives_the_permissions_open_would(tmp_path):
    """mkstemp makes owner-only files; a written campaign or FMU must be readable like any
    other file the user writes (0o666 less the umask), and a rewrite keeps the old mode."""
    import os
    import stat

    from sysid.core.util import _umask

    fresh = tmp_path / "fresh.nc"
    with atomic_path(fresh) as tmp:
        tmp.write_text("x")
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o666 & ~_umask()
    with open(tmp_path / "plain.nc", "w") as f:
        f.write("x")
    assert stat.S_IMODE(fresh.stat().st_mode) == stat.S_IMODE(
        (tmp_path / "plain.nc").stat().st_mode)
    os.chmod(fresh, 0o640)
    with atomic_path(fresh) as tmp:
        tmp.write_text("y")
    assert stat.S_IMODE(fresh.stat().st_mode) == 0o640 and fresh.read_text() == "y"


@pytest.mark.skipif((os.cpu_count() or 1) < 2, reason="one core: every BLAS has one thread")
def test_blas_threads_limits_every_blas_even_before_scipy_is_imported():
    """numpy and scipy ship separate OpenBLAS builds; threadpoolctl limits only loaded ones.
    Called first thing (as tests/conftest.py does), the limit must still reach scipy's."""
    code = ("from sysid.core.util import blas_threads\n"
            "limit = blas_threads()\n"
            "import scipy.linalg\n"
            "from threadpoolctl import threadpool_info\n"
            "print(sorted({i['num_threads'] for i in threadpool_info()"
            " if i['user_api'] == 'blas'}))\n")
    env = {k: v for k, v in os.environ.items()
           if k not in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS",
                        "SYSID_BLAS_THREADS")}
    out = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True,
                         text=True, check=True).stdout
    assert out.strip() == "[1]", out


@pytest.mark.parametrize("module, entry, inner", [
    ("sysid.identify.time_domain", "identify_time_domain", "fit_inputs"),
    ("sysid.identify.frequency_domain", "identify_frequency_domain", "select_fit_data"),
    ("sysid.identify.filter_error", "identify_filter_error", "_best_start")])
def test_identification_entry_points_set_their_numerics(monkeypatch, module, entry, inner):
    """Called from a user's script with BLAS at two threads, a fit runs its numerics with one
    and gives the two back (output error on the hover study: 10.1 s of wall at two threads,
    4.8 s at one), and it steadies the heap first (steady_heap)."""
    import importlib
    import types

    from threadpoolctl import threadpool_info, threadpool_limits

    import sysid.core.util as util

    steadied = []
    monkeypatch.setattr(util, "steady_heap", lambda: steadied.append(True))

    def blas():
        return {i["num_threads"] for i in threadpool_info() if i["user_api"] == "blas"}

    mod = importlib.import_module(module)
    seen = []

    def probe(*args, **kwargs):
        seen.append(blas())
        raise RuntimeError("probe: stop here")

    monkeypatch.setattr(mod, inner, probe)
    with threadpool_limits(limits=2, user_api="blas"):
        with pytest.raises(RuntimeError, match="probe"):
            getattr(mod, entry)(None, types.SimpleNamespace(attrs={}))
        assert blas() == {2}
    assert seen == [{1}] and steadied == [True]


def test_steady_heap_sets_glibc_thresholds_unless_the_environment_does():
    """steady_heap fixes glibc's thresholds once per process: six 4 MB arrays alive together
    and then freed, as a fit's temporaries are at every evaluation, are reused from the heap
    on the next round without a page fault, where glibc's adaptive thresholds (trim at twice
    the largest block freed) hand the 24 MB back and fault them in again every round. A
    process whose environment sets a threshold, or SYSID_STEADY_HEAP=0, keeps its own."""
    import platform

    if platform.libc_ver()[0] != "glibc":
        pytest.skip("glibc's malloc only")
    code = ("import resource, numpy as np\n"
            "from sysid.core.native import steady_heap\n"
            "applied = steady_heap()\n"
            "def faults():\n"
            "    f0 = resource.getrusage(resource.RUSAGE_SELF).ru_minflt\n"
            "    for _ in range(5):\n"
            "        arrays = [np.ones(500_000) for _ in range(6)]; del arrays\n"
            "    return resource.getrusage(resource.RUSAGE_SELF).ru_minflt - f0\n"
            "faults()\n"
            "print(applied, steady_heap() is applied, faults())\n")
    base = {k: v for k, v in os.environ.items() if not k.startswith("MALLOC_")}
    base.pop("SYSID_STEADY_HEAP", None)
    runs = {}
    for name, extra in (("default", {}), ("off", {"SYSID_STEADY_HEAP": "0"}),
                        ("owner", {"MALLOC_TRIM_THRESHOLD_": "65536"})):
        out = subprocess.run([sys.executable, "-c", code], env={**base, **extra},
                             capture_output=True, text=True, check=True).stdout.split()
        runs[name] = (out[0], out[1], int(out[2]))
    assert runs["default"][:2] == ("True", "True") and runs["default"][2] < 100, runs
    for name in ("off", "owner"):
        assert runs[name][0] == "False" and runs[name][2] > 5 * 6 * 500, runs


def test_native_kernels_fall_back_and_rebuild(monkeypatch, tmp_path):
    """A kernel is built into the cache and loaded; a cached file that does not load is
    rebuilt; without a compiler, or with SYSID_NATIVE=0, the caller gets None (its numpy
    path) and native_status says why."""
    import sysid.models.simulation as simulation
    from sysid.core.native import native_library, native_status

    source = str(Path(simulation.__file__).with_name("recursion.c"))
    monkeypatch.setenv("SYSID_CACHE_DIR", str(tmp_path))
    native_library.cache_clear()
    try:
        monkeypatch.setenv("CC", str(tmp_path / "no-such-cc"))
        assert native_library("recursion", source) is None
        assert "no-such-cc" in native_status()["recursion"]
        native_library.cache_clear()
        monkeypatch.setenv("SYSID_NATIVE", "0")
        monkeypatch.delenv("CC")
        assert native_library("recursion", source) is None
        assert native_status()["recursion"].startswith("off")
        native_library.cache_clear()
        monkeypatch.delenv("SYSID_NATIVE")
        try:
            from sysid.core.native import find_compiler
            find_compiler()
        except Exception:
            pytest.skip("no C compiler here")
        assert native_library("recursion", source) is not None
        built = list((tmp_path / "native").glob("recursion-*.so"))
        assert len(built) == 1 and native_status()["recursion"] == f"native ({built[0].name})"
        built[0].write_bytes(b"not a shared library")  # e.g. a truncated copy
        # a fresh process (this one has the library loaded under that name already)
        code = ("from sysid.core.native import native_library, native_status\n"
                f"print(native_library('recursion', {source!r}) is not None,"
                " native_status()['recursion'])\n")
        out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True,
                             check=True, env={**os.environ, "SYSID_CACHE_DIR": str(tmp_path)})
        assert out.stdout.strip() == f"True native ({built[0].name})", out
        assert built[0].read_bytes() != b"not a shared library"
        assert list((tmp_path / "native").iterdir()) == built  # no temporary file left
    finally:
        native_library.cache_clear()


def test_forkserver_start_is_an_optimisation_that_never_fails_the_caller(monkeypatch):
    # where the forkserver cannot start (no sockets, a platform without it) the study goes
    # on: the pools start it later or fall back; in a daemonic process nothing is started
    import multiprocessing
    import multiprocessing.forkserver

    from sysid.core.util import start_forkserver

    def refuse():
        raise OSError("no forkserver here")

    monkeypatch.setattr(multiprocessing.forkserver, "ensure_running", refuse)
    start_forkserver()   # no error
    calls = []
    monkeypatch.setattr(multiprocessing.forkserver, "ensure_running", lambda: calls.append(1))
    monkeypatch.setattr(multiprocessing.current_process(), "_config",
                        {**multiprocessing.current_process()._config, "daemon": True})
    start_forkserver()
    assert calls == []
