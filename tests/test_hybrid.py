"""Hybrid (flapping) structures against the truth FMU's linearisation.

Independent checks: the FMU's accelerometer outputs (specific force computed inside model.c)
against its own state derivatives (u' minus the gravity and velocity terms), the hybrid
reduction residualised once more against the quasi-steady 6-DoF linearisation computed by
the original path, and the flapping normalisation of truth_for_structure.
"""

import numpy as np
import pytest

from sysid.core.kinematics import rigid_body_terms
from sysid.core.units import STATES_6DOF
from sysid.models import load_structure, residualize_model

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def hover_lin(hover_trim):
    from sysid.truth import linearize

    return linearize(hover_trim)


def test_accelerometer_rows_are_specific_force(hover_lin, hover_trim):
    """C[ax] = (A - A_kin)[u] and D[ax] = B[u] on the full model (and likewise ay/v, az/w):
    the FMU's accelerometer output, differentiated, equals its force equation without the
    gravity and velocity cross-product terms."""
    full = hover_lin.full
    vals = hover_trim.channel_values()
    states = [str(s) for s in full.state.values]
    K = np.zeros((len(states), len(states)))
    k6 = rigid_body_terms(theta0=vals["theta"], phi0=vals["phi"], u0=vals["u"], v0=vals["v"],
                          w0=vals["w"]).values
    idx = [states.index(s) for s in STATES_6DOF]
    K[np.ix_(idx, idx)] = k6
    A, B = full["A"].values, full["B"].values
    for out, row in (("ax", "u"), ("ay", "v"), ("az", "w")):
        i = states.index(row)
        c = full["C"].sel(output=out).values
        d = full["D"].sel(output=out).values
        scale = np.abs(A[i] - K[i]).max()
        np.testing.assert_allclose(c, A[i] - K[i], atol=1e-5 * scale)
        np.testing.assert_allclose(d, B[i], atol=1e-5 * np.abs(B[i]).max())


def test_hybrid_truth_reduces_to_the_quasi_steady_linearisation(hover_lin, hover_trim):
    from sysid.truth.linearize import truth_for_structure

    st = load_structure("hover_hybrid", trim=hover_trim.channel_values())
    tr = truth_for_structure(hover_lin.full, st)
    # the normalisation holds the structure's fixed flapping entries exactly
    A = tr["A"].to_pandas()
    assert A.loc["a1", "q"] == pytest.approx(-1.0, abs=1e-9)
    assert A.loc["b1", "p"] == pytest.approx(-1.0, abs=1e-9)
    assert A.loc["a1", "p"] == pytest.approx(0.0, abs=1e-9)
    assert A.loc["b1", "q"] == pytest.approx(0.0, abs=1e-9)
    # parameters read back: value = entry minus fixed part
    values = dict(zip(tr.parameter.values, tr.value.values))
    assert values["L_b1"] == pytest.approx(A.loc["p", "b1"], rel=1e-12)
    assert values["A[a1,a1]"] == pytest.approx(A.loc["a1", "a1"], rel=1e-12)
    # flapping time constant near Padfield's 16/(gamma Omega) estimate for this rotor
    tau_f = -1.0 / values["A[a1,a1]"]
    assert 0.05 < tau_f < 0.09, tau_f
    # residualising the flapping of the hybrid truth gives the original quasi-steady model
    qs = residualize_model(tr, list(STATES_6DOF))
    ref = hover_lin.quasi_steady
    for key in ("A", "B"):
        a = qs[key].values
        b = ref[key].sel(state_dot=list(STATES_6DOF)).values
        if key == "A":
            b = ref[key].sel(state_dot=list(STATES_6DOF), state=list(STATES_6DOF)).values
        np.testing.assert_allclose(a, b, atol=1e-8 * np.abs(b).max())
    # the hybrid keeps the full model's low-frequency modes (flap-roll and slower)
    ev_h = np.sort(np.abs(np.linalg.eigvals(tr["A"].values)))
    ev_f = np.sort(np.abs(hover_lin.eigenvalues_full))
    for e in ev_h[ev_h > 0.1]:
        assert np.min(np.abs(ev_f - e)) < 0.03 * e, e
