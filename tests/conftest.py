"""Shared fixtures.

``truth_fmu`` builds the truth helicopter FMU once per test session (cached by source hash,
so later sessions reuse it) and ``hover_trim`` trims it in hover. Tests that need them are
marked ``@pytest.mark.fmu``. The expensive results several modules read are made once per
session here: ``hover_study`` (the README's study on the truth FMU) and
``known_system_chain`` (the flight-data chain on a known linear system).

The suite runs on pytest-xdist workers (``addopts`` in pyproject.toml). Each module goes to
one worker whole, so its module fixtures are built once; the modules that read one of the
session results above go to the same worker, so each is made once per run.
"""

import os

import pytest
from sysid.core.util import blas_threads

# One BLAS thread for the whole session, as the sysid command and workflows use: the suite
# is many mid-sized matrix products, which multi-threaded OpenBLAS slows by up to 10x on the
# 2-core CI machine (measured).
_BLAS_LIMIT = blas_threads()

# Under two or more xdist workers the cores are already full: a fit's own parallelism (the
# filter-error screening processes, its threads over records, the report's figure
# processes) would only oversubscribe them. Tests that exercise it set these themselves.
if int(os.environ.get("PYTEST_XDIST_WORKER_COUNT", "1")) > 1:
    for _variable in ("SYSID_FIT_PROCESSES", "SYSID_REPORT_PROCESSES"):
        os.environ.setdefault(_variable, "1")


@pytest.hookimpl(tryfirst=True)
def pytest_cmdline_main(config):
    """Timed benchmarks (``--benchmark-enable``) run in one process: pytest-benchmark turns
    itself off under xdist workers, which would leave a timing run silently untimed."""
    if config.getoption("benchmark_enable", False) and config.option.numprocesses:
        config.option.numprocesses = 0


#: Modules that read a session fixture too costly to build twice, by fixture: each set runs
#: on one worker. A module that reads one and is not listed stops the run (see below).
SHARED_SESSION_MODULES = {
    "hover_study": ("tests/test_handling_qualities.py", "tests/test_hover_study.py",
                    "tests/test_hybrid.py"),
    "known_system_chain": ("tests/test_flight_data.py", "tests/test_report_cli.py"),
}
_GROUP = {module: f"session:{fixture}" for fixture, modules in SHARED_SESSION_MODULES.items()
          for module in modules}

#: Groups handed to the workers first, longest first (105, 62, 55, 43, 36, 22, 19, 19, 18,
#: 17, 14 s in one serial run; docs/notes/2026-11-26-suite-on-two-workers.md), so that no long
#: group starts last; the others follow in collection order. A stale list costs only balance.
LONGEST_FIRST = ("tests/test_bound_calibration.py", "session:hover_study",
                 "tests/test_identify_time.py", "session:known_system_chain",
                 "tests/test_batch.py", "tests/test_report.py",
                 "tests/test_robustness_spectral.py", "tests/test_identify_frequency.py",
                 "tests/test_fmi_exchange.py", "tests/benchmarks/test_bench_identify_time.py",
                 "tests/benchmarks/test_bench_report.py")


def worker_group(nodeid: str) -> str:
    """The worker group of a test: its module, or ``session:<fixture>`` for the modules of
    :data:`SHARED_SESSION_MODULES`."""
    module = nodeid.split("::", 1)[0]
    return _GROUP.get(module, module)


def pytest_collection_modifyitems(config, items):
    """Refuse a module that reads a shared session fixture without being listed in
    :data:`SHARED_SESSION_MODULES`, and order the groups :data:`LONGEST_FIRST`."""
    for item in items:
        for fixture, modules in SHARED_SESSION_MODULES.items():
            module = item.nodeid.split("::", 1)[0]
            if fixture in item.fixturenames and module not in modules:
                raise pytest.UsageError(
                    f"{module} reads the session fixture {fixture!r}: add it to "
                    f"SHARED_SESSION_MODULES[{fixture!r}] in tests/conftest.py so that the "
                    "fixture is built on one worker only")
    rank = {group: k for k, group in enumerate(LONGEST_FIRST)}
    items.sort(key=lambda item: rank.get(worker_group(item.nodeid), len(rank)))


@pytest.hookimpl(tryfirst=True)
def pytest_xdist_make_scheduler(config, log):
    """Whole groups (:func:`worker_group`) per worker, in collection order. xdist's own
    ``loadgroup`` marks tests by renaming their node ids, which pytest 9.2 no longer
    honours (it silently split the groups); this scheduler reads the ids as they are."""
    from xdist.scheduler import LoadScopeScheduling

    class GroupScheduling(LoadScopeScheduling):
        def _split_scope(self, nodeid: str) -> str:
            return worker_group(nodeid)

    return GroupScheduling(config, log)


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
