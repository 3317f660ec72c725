"""The ``sysid build``, ``sysid trim`` and ``sysid linearize`` commands."""

import pytest

from sysid.cli import main

pytestmark = pytest.mark.fmu


def test_build_prints_the_fmu_path(capsys, truth_fmu):
    assert main(["build"]) == 0
    assert capsys.readouterr().out.strip() == str(truth_fmu)


def test_trim_prints_table_1(capsys, truth_fmu):
    assert main(["trim", "--speed", "0"]) == 0
    out = capsys.readouterr().out
    for label in ("u_0", "phi_0", "theta_0", "delta_lon_0", "delta_ped_0", "Total mass"):
        assert label in out


def test_linearize_prints_derivatives_and_eigenvalues(capsys, truth_fmu):
    assert main(["linearize", "--speed", "40"]) == 0
    out = capsys.readouterr().out
    assert "Stability derivatives" in out and "Control derivatives" in out
    assert "Eigenvalues, quasi-steady" in out and "Eigenvalues, full model" in out


def test_bad_speed_is_one_line_error(capsys):
    assert main(["trim", "--speed", "-10"]) == 1
    err = capsys.readouterr().err.strip()
    assert err.startswith("sysid trim: error:") and "\n" not in err
