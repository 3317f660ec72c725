"""Forward flight: the forward_6dof structure, the 80-kt campaign, the cross-control section."""

import dataclasses
import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from sysid.models import frequency_response, load_structure

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "workflows"))
import forward_flight  # noqa: E402


@pytest.fixture(scope="module")
def lin80(truth_fmu):
    from sysid import truth as fmu

    trim = fmu.trim(80.0, fmu=truth_fmu)
    return trim, fmu.linearize(trim, fmu=truth_fmu).quasi_steady


@pytest.mark.fmu
def test_forward_structure_starts_near_the_80kt_truth(lin80):
    trim, lin = lin80
    structure = load_structure("forward_6dof", trim=trim.channel_values())
    assert structure.attrs["u0_ft_s"] > 120  # 80 kt = 135 ft/s of which u is most
    truth = dict(zip((str(p) for p in lin.parameter.values), lin["value"].values))
    for name in structure.free_names:
        if name.startswith("tau_"):
            continue
        start = structure.parameter(name).value
        assert start == pytest.approx(truth[name], rel=0.05, abs=2e-3), name
    # The model's A (kinematics + start derivatives) has the truth's eigenvalues within
    # what the fixed (small) derivatives explain: the same unstable phugoid-type pair.
    A_model = structure.matrices()[0]
    states = list(structure.states)
    A_truth = lin["A"].sel(state_dot=states, state=states).values
    ev_m = np.sort_complex(np.linalg.eigvals(A_model))
    ev_t = np.sort_complex(np.linalg.eigvals(A_truth))
    assert np.max(ev_t.real) > 0 and np.max(ev_m.real) > 0
    dominant = ev_t[np.argmin(ev_t.real)]
    assert np.min(np.abs(ev_m - dominant)) < 0.15 * abs(dominant)


@pytest.mark.fmu
def test_80kt_lon_sweep_stays_in_the_envelope(truth_fmu):
    """The lon sweep diverged at 80 kt with the hover amplitudes and velocity hold."""
    from sysid.flight_test.campaign import default_campaign, run_campaign

    c = default_campaign(80.0)
    c = dataclasses.replace(c, maneuvers=[m for m in c.maneuvers if m.name == "sweep_lon_1"])
    tree = run_campaign(c, quiet=True, fmu=truth_fmu)
    ds = tree["maneuvers/sweep_lon_1"].to_dataset()
    assert float(abs(ds["theta"] - ds.attrs["trim_theta"]).max()) < 25.0
    assert float(abs(ds["u"] - ds.attrs["trim_u"]).max()) < 40.0


def _toy_tree():
    """A campaign tree whose conditioned response is the truth and the unconditioned one
    is the truth times 2 (+6.02 dB) delayed by 0.1 s."""
    from sysid.models import six_dof_structure

    s = six_dof_structure(theta0=0.0, phi0=0.0, free=["M_q", "M_lon", "L_p", "L_lat"],
                          values={"M_q": -2.0, "M_lon": 3.0, "L_p": -5.0, "L_lat": 8.0})
    lin = s.to_dataset(attrs={"method": "linearization"})
    omega = np.logspace(-1, 1.3, 60)
    H = frequency_response(lin, omega)
    ones = xr.ones_like(H.real)
    mimo = xr.Dataset({"H": H, "coherence": ones, "partial_coherence": ones})
    siso = xr.Dataset({"H": 2 * H * np.exp(-1j * omega * 0.1), "coherence": ones})
    return xr.DataTree.from_dict({"/linearization": lin, "/frequency_response": mimo,
                                  "/frequency_response_siso": siso})


def test_conditioning_effect_against_known_errors(tmp_path):
    tree = _toy_tree()
    effect = forward_flight.conditioning_effect(tree, pairs=[("q", "lon"), ("p", "lat")])
    cond = effect.sel(estimate="conditioned")
    unc = effect.sel(estimate="unconditioned")
    assert np.allclose(cond["mag_rms_db"], 0.0, atol=1e-9)
    assert np.allclose(unc["mag_rms_db"], 20 * np.log10(2.0))
    w = tree["frequency_response"].to_dataset().frequency.values
    w = w[(w >= forward_flight.BAND[0]) & (w <= forward_flight.BAND[1])]
    assert np.allclose(unc["phase_rms_deg"], np.sqrt(np.mean(np.degrees(0.1 * w) ** 2)))
    page = forward_flight.cross_control_section({"toy": tree}, tmp_path)
    text = page.read_text()
    assert "data:image/png;base64," in text and "q/lon" in text
    assert (tmp_path / "cross_control.png").exists() and (tmp_path / "cross_control.csv").exists()
