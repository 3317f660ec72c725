"""Shared fixtures.

``truth_fmu`` builds the truth helicopter FMU once per test session (cached by source hash,
so later sessions reuse it) and ``hover_trim`` trims it in hover. Tests that need them are
marked ``@pytest.mark.fmu``. The expensive results several modules read are made once per
session here: ``hover_study`` (the README's study on the truth FMU) and
``known_system_chain`` (the flight-data chain on a known linear system).

The suite runs on pytest-xdist workers (``addopts`` in pyproject.toml). Each module goes to
one worker whole, so its module fixtures are built once; modules that read one of the
session results above go to the same worker, so each is made once per run.
"""

import pytest
from sysid.core.util import blas_threads

# One BLAS thread for the whole session, as the sysid command and workflows use: the suite
# is many mid-sized matrix products, which multi-threaded OpenBLAS slows by up to 10x on the
# 2-core CI machine (measured).
_BLAS_LIMIT = blas_threads()


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Timed benchmarks (``--benchmark-enable``) run in one process: pytest-benchmark turns
    itself off under xdist workers, which would leave a timing run silently untimed."""
    if config.getoption("benchmark_enable", False) and config.option.numprocesses:
        config.option.numprocesses = 0


# Session fixtures too costly to build on more than one worker.
SHARED_SESSION_FIXTURES = ("hover_study", "known_system_chain")


@pytest.hookimpl(tryfirst=True)
def pytest_collection_modifyitems(config, items):
    """Give every test an ``xdist_group``: its module, or the first of
    :data:`SHARED_SESSION_FIXTURES` that any test of its module reads (so those modules share
    one worker). A test's own ``xdist_group`` mark wins."""
    module_group = {}
    for item in items:
        module = item.nodeid.split("::", 1)[0]
        shared = next((f for f in SHARED_SESSION_FIXTURES if f in item.fixturenames), None)
        if shared and not module_group.get(module, "").startswith("session:"):
            module_group[module] = f"session:{shared}"
        module_group.setdefault(module, module)
    for item in items:
        if item.get_closest_marker("xdist_group") is None:
            item.add_marker(pytest.mark.xdist_group(module_group[item.nodeid.split("::", 1)[0]]))


@pytest.fixture(scope="session")
def truth_fmu():
    """Path of the truth helicopter FMU, built from fmus/ with the machine's C compiler."""
    from sysid.truth import build_fmu

    return build_fmu()


@pytest.fixture(scope="session")
def hover_trim(truth_fmu):
    """Hover trim of the truth helicopter (sysid.truth.TrimResult)."""
    from sysid.truth import trim

    return trim(0.0, fmu=truth_fmu)


@pytest.fixture(scope="session")
def hover_study(tmp_path_factory, truth_fmu):
    """The README's hover study (default settings), run once per session:
    ``{"dir", "report", "tree"}`` (output folder, report.html, the campaign DataTree)."""
    from sysid.pipeline.study import StudySettings, run_study, study_tree

    out = tmp_path_factory.mktemp("hover_study_session")
    report = run_study(out, StudySettings(), quiet=True)
    return {"dir": out, "report": report, "tree": study_tree(out)}


@pytest.fixture(scope="session")
def known_system_chain(tmp_path_factory):
    """Output folder of ``run_flight_data`` on the known system's files (seed 3), the
    flight-data chain of tests/test_flight_data.py, run once per session: that module and
    tests/test_report_cli.py read it."""
    import trust_system
    from sysid.pipeline.flight_data import run_flight_data
    from test_flight_data import known_system_files

    root = tmp_path_factory.mktemp("known_system_chain")
    files = known_system_files(root, 3)
    run_flight_data(files, root / "out", structure=trust_system.STRUCTURE_FILE, quiet=True)
    return root / "out"
