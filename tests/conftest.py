"""Shared fixtures.

``truth_fmu`` builds the truth helicopter FMU once per test session (cached by source hash,
so later sessions reuse it) and ``hover_trim`` trims it in hover. Tests that need them are
marked ``@pytest.mark.fmu``. The expensive results several modules read are made once per
session here: ``hover_study`` (the README's study on the truth FMU) and
``known_system_chain`` (the flight-data chain on a known linear system).
"""

import pytest
from sysid.core.util import blas_threads

# One BLAS thread for the whole session, as the sysid command and workflows use: the suite
# is many mid-sized matrix products, which multi-threaded OpenBLAS slows by up to 10x on the
# 2-core CI machine (measured).
_BLAS_LIMIT = blas_threads()


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
