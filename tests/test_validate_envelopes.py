"""Mismatch envelopes (paper Eq. 20) and time-domain fit metrics against definitions."""

import numpy as np
import pytest
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.assess.envelopes import MUAD, check_envelope, load_envelope, mismatch
from sysid.assess.metrics import j_rms, theil_inequality

OMEGA = np.logspace(-1, 2, 121)


def _response(values):
    return xr.DataArray(values, dims="frequency", coords={"frequency": OMEGA})


def test_muad_values_quoted_in_the_literature():
    bounds = MUAD.bounds(np.array([1.0]))
    # docs/methods.md: "at 1 rad/s the lower phase bound is about -14 deg".
    assert float(bounds.phase_lower[0]) == pytest.approx(-14.07, abs=0.1)
    # The gain bounds bracket 0 dB at every frequency (a perfect model is always inside).
    b = MUAD.bounds(OMEGA)
    assert (b.magnitude_upper > 0).all() and (b.magnitude_lower < 0).all()
    assert (b.phase_upper > 0).all() and (b.phase_lower < 0).all()


def test_mismatch_of_a_pure_delay_is_linear_phase():
    reference = _response(1.0 / (1j * OMEGA + 2.0))
    tau = 0.01
    error = mismatch(reference * np.exp(-1j * OMEGA * tau), reference)
    np.testing.assert_allclose(error.magnitude, 0.0, atol=1e-12)
    np.testing.assert_allclose(error.phase, -np.degrees(OMEGA * tau), atol=1e-9)
    # 10 ms is unnoticeable below 10 rad/s: all inside MUAD there.
    band = (OMEGA >= 1) & (OMEGA <= 10)
    result = check_envelope(error, MUAD, coherence=_response(band.astype(float)))
    assert float(result.fraction_inside) == 1.0


def test_gain_error_outside_bounds_is_counted():
    reference = _response(np.ones_like(OMEGA, dtype=complex))
    model = reference * 2.0  # +6.02 dB: above the MUAD upper gain bound between about 0.5
    result = check_envelope(mismatch(model, reference), MUAD)   # and 30 rad/s
    upper = MUAD.bounds(OMEGA).magnitude_upper.values
    expected = np.mean(upper >= 20 * np.log10(2.0))
    assert float(result.fraction_inside) == pytest.approx(expected)
    assert 0 < expected < 1
    assert float(result.worst_magnitude_excess) == pytest.approx(6.0206 - upper.min(), abs=1e-3)


def test_user_envelope_from_toml(tmp_path):
    path = tmp_path / "aee.toml"
    path.write_text(
        'name = "test envelope"\ncitation = "unit test"\n'
        "[magnitude.upper]\nfrequency = [0.1, 100.0]\nvalue = [3.0, 3.0]\n"
        "[magnitude.lower]\nfrequency = [0.1, 100.0]\nvalue = [-3.0, -3.0]\n"
        "[phase.upper]\nnum = [10.0]\nden = [1.0]\n"   # constant 0 deg phase of a gain
        "[phase.lower]\nfrequency = [0.1, 1.0, 100.0]\nvalue = [-10.0, -20.0, -20.0]\n"
    )
    env = load_envelope(path)
    b = env.bounds(np.array([0.1, np.sqrt(0.1), 1.0]))
    np.testing.assert_allclose(b.phase_lower, [-10, -15, -20])   # log-linear interpolation
    np.testing.assert_allclose(b.phase_upper, 0.0, atol=1e-12)
    reference = _response(np.ones_like(OMEGA, dtype=complex))
    inside = check_envelope(mismatch(reference * 10 ** (2 / 20), reference), env)
    assert float(inside.fraction_inside) == 1.0     # +2 dB within +-3 dB, phase 0 on the bound
    outside = check_envelope(mismatch(reference * 10 ** (4 / 20), reference), env)
    assert float(outside.fraction_inside) == 0.0
    assert float(outside.worst_magnitude_excess) == pytest.approx(1.0)


@pytest.mark.parametrize("text, message", [
    ('citation = "x"\n', "'name'"),
    ('name = "a"\ncitation = "x"\n', r"\[magnitude.upper\] is missing"),
    ('name = "a"\ncitation = "x"\n[magnitude.upper]\nfrequency = [1.0, 0.5]\nvalue = [1, 2]\n',
     "increasing"),
    ("name = = 3", "cannot read envelope file"),
])
def test_bad_envelope_files_name_the_problem(tmp_path, text, message):
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(InputDataError, match=message):
        load_envelope(path)


def test_theil_and_j_rms_definitions():
    t = np.linspace(0, 10, 1001)
    z = xr.DataArray(np.sin(t), dims="time")
    assert float(theil_inequality(z, z)) == 0.0
    assert float(theil_inequality(z, 0 * z)) == pytest.approx(1.0)
    assert float(theil_inequality(z, -z)) == pytest.approx(1.0)
    measured = xr.Dataset({"q": z, "p": 2 * z})
    simulated = xr.Dataset({"q": z + 2.0, "p": 2 * z - 2.0})
    assert j_rms(measured, simulated) == pytest.approx(2.0)
    assert j_rms(measured, simulated, weights={"q": 0.0}) == pytest.approx(np.sqrt(2.0))
