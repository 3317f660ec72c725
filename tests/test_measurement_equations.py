"""Outputs that are not states: accelerometer output equations, unmeasured u, v, w.

Truth: the known hover system of ``tests/test_identify_frequency.py`` (Padfield's Bo-105 hover
derivatives in analysis units, cyclic delays on the moment rows) measured by rate gyros,
attitude sensors and a CG accelerometer only: outputs p, q, r, phi, theta, ax, ay, az. The
accelerometer reads the specific force, ``ax = X/m`` = the aerodynamic and control part of
the u row, so its truth response is built here independently of the structure code from
the quasi-steady force equations (ax = u' + W0 q - V0 r + g cos(theta0) theta ..., i.e. u'
minus the gravity and velocity terms), and the same X_* parameters must come out of the
fit in both domains.
"""

import math

import numpy as np
import pytest
import xarray as xr

from known_systems import TRIM, multistep_records
from test_identify_frequency import (PHI0, THETA0, TRUE_DELAYS, analytic_response,
                                     truth_structure, truth_values)

from sysid.core.errors import InputDataError
from sysid.core.kinematics import rigid_body_terms
from sysid.identify import identify_frequency_domain
from sysid.identify.time_domain import identify_time_domain
from sysid.models import model_from_dataset, simulate, structure_from_dict
from sysid.models.structure import LinearStructure

OUTPUTS = ["p", "q", "r", "phi", "theta", "ax", "ay", "az"]
G_FT = 9.80665 / 0.3048
RAD = math.pi / 180


def accelerometer_spec(values, *, arm=None, free_delays=True, delays=True):
    """The TOML description (parsed) of the known system with accelerometer outputs."""
    A = {k: {"value": v} for k, v in values.items()
         if k not in TRUE_DELAYS and k.split("_")[1] in "uvwpqr"}
    B = {k: {"value": v} for k, v in values.items()
         if k not in TRUE_DELAYS and k.split("_")[1] not in "uvwpqr"}
    spec = {"name": "acc_hover", "states": ["u", "v", "w", "p", "q", "r", "phi", "theta",
                                            "psi"],
            "inputs": ["lon", "lat", "col", "ped"], "outputs": OUTPUTS,
            "kinematics": {"theta0": THETA0, "phi0": PHI0, "u0": 0.0, "v0": 0.0, "w0": 0.0},
            "A": A, "B": B,
            "delays": {"tau_L_lon": {"entry": "p,lon", "value": TRUE_DELAYS["tau_L_lon"],
                                     "free": free_delays},
                       "tau_M_lat": {"entry": "q,lat", "value": TRUE_DELAYS["tau_M_lat"],
                                     "free": free_delays}}}
    if not delays:
        del spec["delays"]
    if arm is not None:
        spec["sensors"] = {"accelerometer": list(arm)}
    return spec


def independent_accelerations(values, x, u):
    """Specific force at the CG from the derivatives by hand: X/m = sum X_j x_j + X_c u_c
    over the aerodynamic entries only (no gravity, no velocity cross-products); x (N, 9)
    in u..psi order, u (N, 4) in lon lat col ped order."""
    cols = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]
    out = {}
    for name, letter in (("ax", "X"), ("ay", "Y"), ("az", "Z")):
        a = np.zeros(len(x))
        for j, c in enumerate(cols):
            a += values.get(f"{letter}_{c}", 0.0) * x[:, j]
        for k, c in enumerate(["lon", "lat", "col", "ped"]):
            a += values.get(f"{letter}_{c}", 0.0) * u[:, k]
        out[name] = a
    return out


def test_accelerometer_rows_are_the_force_rows_without_kinematics():
    values = truth_values()
    st = structure_from_dict(accelerometer_spec(values))
    A, B, C, D, tau = st.matrices()
    K = rigid_body_terms(theta0=THETA0, phi0=PHI0).values
    for out, row in (("ax", 0), ("ay", 1), ("az", 2)):
        o = OUTPUTS.index(out)
        np.testing.assert_allclose(C[o], A[row] - K[row], atol=1e-14)
        np.testing.assert_allclose(D[o], B[row], atol=1e-14)
    # X_lon is one parameter acting on B[u,lon] and D[ax,lon]
    moved = st.with_values(st.theta0 + 0.5 * (np.array(st.free_names) == "X_lon"))
    C2, D2 = moved.matrices()[2:4]
    assert D2[OUTPUTS.index("ax"), 0] - D[OUTPUTS.index("ax"), 0] == pytest.approx(0.5)
    assert moved.matrices()[1][0, 0] - B[0, 0] == pytest.approx(0.5)
    # and the hand-built specific force agrees on a random state and input
    rng = np.random.default_rng(3)
    x, u = rng.standard_normal((5, 9)), rng.standard_normal((5, 4))
    y = x @ C.T + u @ D.T
    ref = independent_accelerations(values, x, u)
    for out in ("ax", "ay", "az"):
        np.testing.assert_allclose(y[:, OUTPUTS.index(out)], ref[out], rtol=1e-12, atol=1e-12)


def test_lever_arm_adds_angular_acceleration_terms():
    """A sensor at r = (x, y, z) ft reads a_cg + omega' x r (first order about zero rates)."""
    values = truth_values()
    arm = (2.0, -1.0, 3.0)
    st0 = structure_from_dict(accelerometer_spec(values, delays=False))
    st1 = structure_from_dict(accelerometer_spec(values, arm=arm, delays=False))
    A, B, C0, D0, _ = st0.matrices()
    C1, D1 = st1.matrices()[2:4]
    x, y, z = arm
    pdot = lambda k: (A[3 + k], B[3 + k])  # noqa: E731 (rows p, q, r of A and B)
    expect = {"ax": (z, 1, -y, 2), "ay": (x, 2, -z, 0), "az": (y, 0, -x, 1)}
    for out, (d1, r1, d2, r2) in expect.items():
        o = OUTPUTS.index(out)
        dC = RAD * (d1 * pdot(r1)[0] + d2 * pdot(r2)[0])
        dD = RAD * (d1 * pdot(r1)[1] + d2 * pdot(r2)[1])
        np.testing.assert_allclose(C1[o] - C0[o], dC, atol=1e-13)
        np.testing.assert_allclose(D1[o] - D0[o], dD, atol=1e-13)


def test_lever_arm_on_a_delayed_row_is_refused():
    """ay read at a sensor below the CG needs p', whose lon entry is delayed: the feed-through
    would need a delay, so the structure says which delay and row are in the way."""
    with pytest.raises(InputDataError, match="tau_L_lon.*B\\[p,lon\\].*'ay'"):
        structure_from_dict(accelerometer_spec(truth_values(), arm=(0.0, 0.0, 3.0)))


def test_unknown_output_and_bad_sensor_are_refused():
    spec = accelerometer_spec(truth_values())
    spec["outputs"] = OUTPUTS + ["nz"]
    with pytest.raises(InputDataError, match="'nz' is not a state and has no output equation"):
        structure_from_dict(spec)
    spec = accelerometer_spec(truth_values(), arm=(1.0, 2.0))
    with pytest.raises(InputDataError, match="accelerometer"):
        structure_from_dict(spec)


def test_custom_output_equation_and_round_trip():
    spec = accelerometer_spec(truth_values())
    spec["outputs"] = OUTPUTS + ["hdot"]
    spec["output_equations"] = {"hdot": {"state": {"w": -1.0}}}
    st = structure_from_dict(spec)
    C = st.matrices()[2]
    assert C[-1, 2] == -1.0 and np.count_nonzero(C[-1]) == 1
    ds = st.to_dataset()
    back, theta = model_from_dataset(ds)
    for a, b in zip(back.matrices(theta), st.matrices()):
        np.testing.assert_allclose(a, b, atol=1e-12)
    np.testing.assert_array_equal(back.M, st.M)
    moved = st.theta0 * 1.1
    for a, b in zip(back.matrices(moved), st.matrices(moved)):
        np.testing.assert_allclose(a, b, atol=1e-12)


def test_jacobian_with_output_equations_matches_finite_differences():
    st = structure_from_dict(accelerometer_spec(truth_values()))
    rng = np.random.default_rng(5)
    theta = st.theta0 * (1 + 0.2 * rng.uniform(-1, 1, st.theta0.size))
    n = 40
    s = 1j * np.logspace(-1, 1.3, n)
    out_idx = rng.integers(0, len(OUTPUTS), n)
    in_idx = rng.integers(0, 4, n)
    T, dT = st.pair_response(theta, s, out_idx, in_idx, jacobian=True)
    for j in range(theta.size):
        h = 1e-6 * max(1.0, abs(theta[j]))
        e = np.zeros_like(theta)
        e[j] = h
        fd = (st.pair_response(theta + e, s, out_idx, in_idx)
              - st.pair_response(theta - e, s, out_idx, in_idx)) / (2 * h)
        np.testing.assert_allclose(dT[:, j], fd, rtol=1e-5, atol=1e-7 * np.abs(T).max())


def _pairs():
    return [("q", "lon"), ("p", "lon"), ("ax", "lon"), ("az", "lon"), ("p", "lat"),
            ("q", "lat"), ("ay", "lat"), ("r", "lat"), ("az", "col"), ("ax", "col"),
            ("r", "col"), ("p", "col"), ("q", "col"), ("r", "ped"), ("ay", "ped"),
            ("theta", "lon"), ("phi", "lat")]


@pytest.mark.parametrize("seed", [7, 8, 9])
def test_frequency_domain_without_velocities_within_three_bounds(seed):
    """Composite-like responses of the truth (exact T times seeded complex noise of 8 % RMS)
    for outputs p q r phi theta ax ay az only: every parameter within 3 Cramer-Rao bounds."""
    values = truth_values()
    st = structure_from_dict(accelerometer_spec(values))
    truth = st.theta0.copy()
    fr = analytic_response(st, noise=0.08, seed=seed)
    rng = np.random.default_rng(seed + 100)
    start = truth * (1.0 + rng.uniform(-0.4, 0.4, truth.size))
    result = identify_frequency_domain(fr, st, pairs=_pairs(), start=start, reduce=False)
    stats = result.statistics
    z = (result.theta - truth) / stats.cramer_rao
    assert np.all(stats.identifiable)
    assert np.all(np.abs(z) <= 3.0), dict(zip(stats.names, np.round(z, 2)))
    # the model Dataset carries the accelerometer rows with the fitted X/Y/Z parameters
    model = result.model
    A, B, C, D, _ = (model[k].values for k in ("A", "B", "C", "D", "delay"))
    K = model["kinematic"].values
    o = list(model.output.values).index("az")
    np.testing.assert_allclose(C[o], A[2] - K[2], atol=1e-12)
    np.testing.assert_allclose(D[o], B[2], atol=1e-12)


def _accelerometer_records(st, *, noise, seed):
    """Closed-loop 3211s of the known system; outputs p q r phi theta measured as in
    known_systems, ax ay az computed from the recorded states and controls by hand
    (independent_accelerations), seeded white noise 0.2 ft/s^2 on the accelerations."""
    values = truth_values()
    base = truth_structure()
    records = multistep_records(base, noise=0.0, seed=seed, duration=12.0)
    rng = np.random.default_rng(seed)
    out = []
    for rec in records:
        x = np.stack([rec[s].values - TRIM[s] for s in base.states], 1)
        u = np.stack([rec[c].values - TRIM[c] for c in base.inputs], 1)
        acc = independent_accelerations(values, x, u)
        data = {c: rec[c] for c in base.inputs}
        std = {"p": 0.2, "q": 0.2, "r": 0.2, "phi": 0.05, "theta": 0.05}
        for s in ("p", "q", "r", "phi", "theta"):
            data[s] = rec[s] + noise * std[s] * rng.standard_normal(rec.sizes["time"])
        for a in ("ax", "ay", "az"):
            data[a] = ("time", acc[a] + noise * 0.2 * rng.standard_normal(rec.sizes["time"]),
                       {"units": "ft/s^2"})
        ds = xr.Dataset(data, coords={"time": rec.time}, attrs=dict(rec.attrs))
        ds.attrs.update({"trim_ax": 0.0, "trim_ay": 0.0, "trim_az": 0.0})
        out.append(ds)
    return out


def test_accelerometer_records_match_the_structure_simulation():
    """The hand-built accelerations equal the structure's own simulation of ax, ay, az."""
    st = structure_from_dict(accelerometer_spec(truth_values()))
    rec = _accelerometer_records(st, noise=0.0, seed=1)[0]
    u = xr.Dataset({c: ("time", rec[c].values - TRIM[c]) for c in st.inputs},
                   coords={"time": rec.time.values})
    y = simulate(st.to_dataset(), u)
    # the open-loop simulation of the unstable airframe grows rounding; compare the first 6 s
    sl = slice(0, 300)
    for a in ("ax", "ay", "az"):
        scale = np.abs(rec[a].values).max()
        np.testing.assert_allclose(y[a].values[sl], rec[a].values[sl], atol=1e-6 * scale)


@pytest.mark.parametrize("seed", [1, 2, 3])
def test_time_domain_without_velocities_within_three_bounds(seed):
    values = truth_values()
    st = structure_from_dict(accelerometer_spec(values))
    truth = st.theta0.copy()
    records = _accelerometer_records(st, noise=1.0, seed=seed)
    rng = np.random.default_rng(seed + 50)
    start = truth * (1.0 + rng.uniform(-0.2, 0.2, truth.size))
    result = identify_time_domain(records, st, start=start, reduce=False,
                                  outputs=OUTPUTS)
    stats = result.statistics
    z = (result.theta - truth) / stats.cramer_rao
    assert np.all(stats.identifiable)
    assert np.all(np.abs(z) <= 3.0), dict(zip(stats.names, np.round(z, 2)))
