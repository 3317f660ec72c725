"""Model structures, frequency responses, conversion and simulation against independent truth
(python-control, scipy's ZOH discretisation, analytic step responses)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import scipy.signal
import xarray as xr

from sysid.core.errors import InputDataError
from sysid.core.kinematics import rigid_body_terms
from sysid.models import (ALL_ROWS, LinearStructure, Parameter, builtin_structures,
                          declared_coherence_min, discretize, frequency_response,
                          load_structure, matrix_powers, model_from_dataset, model_matrices,
                          propagate,
                          simulate, six_dof_structure, statespace)
from sysid.core.units import CONTROLS, STATES_6DOF


def _random_six_dof(seed=0, delays=None):
    """A 6-DoF structure with every derivative free at seeded random values (stable A)."""
    rng = np.random.default_rng(seed)
    if delays is None:
        delays = {"tau_L_lon": "p,lon", "tau_M_lat": "q,lat", "tau_ped": "ped"}
    st = six_dof_structure(theta0=6.0, phi0=-3.0, u0=5.0, w0=1.0, delays=delays)
    theta = 0.3 * rng.standard_normal(st.theta0.size)
    A0 = st.A0
    names = st.free_names
    for k, n in enumerate(names):  # strong damping on the diagonal for a stable A
        row, col = n.split("_") if not n.startswith("tau") else ("", "")
        if col and {"X": "u", "Y": "v", "Z": "w", "L": "p", "M": "q", "N": "r"}[row] == col:
            theta[k] = -2.0 - abs(theta[k])
    for k, n in enumerate(names):
        if n.startswith("tau"):
            theta[k] = rng.uniform(0.02, 0.25)
    assert A0.shape == (9, 9)
    return st, theta


def _control_response_with_delays(A, B, C, D, tau, omega):
    """python-control's frequency response of each B entry's path, delayed analytically."""
    control = pytest.importorskip("control")
    T = np.zeros((C.shape[0], B.shape[1], len(omega)), complex)
    for i in range(B.shape[0]):
        for k in range(B.shape[1]):
            if B[i, k] == 0:
                continue
            Bi = np.zeros((B.shape[0], 1))
            Bi[i, 0] = B[i, k]
            sys = control.ss(A, Bi, C, np.zeros((C.shape[0], 1)))
            resp = sys.frequency_response(omega)
            T[:, k, :] += np.asarray(resp.complex).reshape(C.shape[0], len(omega)) \
                * np.exp(-1j * omega * tau[i, k])
    return T + D[:, :, None]


def test_six_dof_structure_layout():
    st = six_dof_structure(theta0=6.76, phi0=-2.87, free=["M_q", "L_lat"],
                           values={"M_q": -3.0, "X_u": -0.02},
                           delays={"tau_L_lon": "p,lon", "tau_lat": "lat"})
    assert st.states == STATES_6DOF and st.inputs == CONTROLS
    assert len([p for p in st.parameters if p.matrix in "AB"]) == 60
    assert st.free_names == ("L_lat", "M_q", "tau_L_lon", "tau_lat")  # row by row, then delays
    A, B, C, D, tau = st.matrices()
    kin = rigid_body_terms(theta0=6.76, phi0=-2.87).values
    expected = kin.copy()
    expected[4, 4] += -3.0
    expected[0, 0] += -0.02
    np.testing.assert_array_equal(A, expected)
    np.testing.assert_array_equal(C, np.eye(9))
    assert not D.any()
    assert tau[3, 0] == 0.05 and np.all(tau[:, 1] == 0.05) and tau[4, 0] == 0
    assert st.parameter("tau_lat").row == ALL_ROWS
    assert st.bounds[0][-1] == 0.0 and st.bounds[1][-1] == 0.3


def test_frequency_response_matches_python_control_with_delays():
    st, theta = _random_six_dof()
    A, B, C, D, tau = st.matrices(theta)
    omega = np.logspace(-2, 2, 120)
    T = st.frequency_response(omega, theta).values
    expected = _control_response_with_delays(A, B, C, D, tau, omega)
    assert np.max(np.abs(T - expected)) <= 1e-10 * np.max(np.abs(expected))
    # model-Dataset route gives the same
    ds = st.to_dataset(theta)
    np.testing.assert_allclose(frequency_response(ds, omega).values, T, rtol=1e-13, atol=0)
    # the delay-free part matches python-control's StateSpace directly
    sys = statespace(ds)
    free = np.asarray(sys.frequency_response(omega).complex)
    T0 = LinearStructure(states=st.states, inputs=st.inputs, A0=A, B0=B).frequency_response(
        omega).values
    assert np.max(np.abs(free - T0)) <= 1e-10 * np.max(np.abs(T0))


def test_pair_response_and_jacobian():
    st, theta = _random_six_dof(seed=3)
    s = 1j * np.array([0.3, 1.0, 4.0, 9.0])
    out = np.array([3, 4, 0, 5])
    inp = np.array([0, 1, 2, 3])
    T, dT = st.pair_response(theta, s, out, inp, jacobian=True)
    full = st.frequency_response(s.imag, theta).values
    np.testing.assert_allclose(T, full[out, inp, np.arange(4)], rtol=1e-12)
    for j in range(theta.size):
        h = 1e-7 * max(1.0, abs(theta[j]))
        tp, tm = theta.copy(), theta.copy()
        tp[j] += h
        tm[j] -= h
        fd = (st.pair_response(tp, s, out, inp) - st.pair_response(tm, s, out, inp)) / (2 * h)
        np.testing.assert_allclose(dT[:, j], fd, rtol=1e-5, atol=1e-8 * np.abs(dT).max())


def test_pade_statespace_approximates_delays():
    st, theta = _random_six_dof(seed=1)
    ds = st.to_dataset(theta)
    omega = np.logspace(-1, 0.7, 30)
    sys = statespace(ds, pade_order=8)
    approx = np.asarray(sys.frequency_response(omega).complex)
    exact = frequency_response(ds, omega).values
    assert np.max(np.abs(approx - exact)) <= 1e-6 * np.max(np.abs(exact))
    assert sys.nstates > 9


def test_dataset_round_trip():
    st, theta = _random_six_dof(seed=2)
    ds = st.to_dataset(theta, attrs={"method": "test"})
    for name in ("A", "B", "C", "D", "delay", "trim_input", "trim_output", "value",
                 "cramer_rao", "cramer_rao_percent", "insensitivity", "insensitivity_percent",
                 "free", "matrix", "row", "column", "correlation"):
        assert name in ds, name
    assert ds["A"].dims == ("state_dot", "state") and ds["delay"].dims == ("state_dot", "input")
    assert ds["correlation"].dims == ("parameter", "parameter_j")
    st2, theta2 = model_from_dataset(ds)
    np.testing.assert_array_equal(theta2, theta)
    for a, b in zip(st.matrices(theta), st2.matrices(theta2)):
        np.testing.assert_array_equal(a, b)
    assert st2.free_names == st.free_names
    np.testing.assert_allclose(st.with_values(np.zeros(theta.size)).values_from_model(ds),
                               theta, rtol=0, atol=1e-14)


def test_dataset_round_trip_through_netcdf(tmp_path):
    io = pytest.importorskip("sysid.data.netcdf")
    st, theta = _random_six_dof(seed=4)
    ds = st.to_dataset(theta)
    path = tmp_path / "campaign.nc"
    io.update_campaign(path, "models/frequency_domain", ds)
    back = io.read_campaign(path)["models/frequency_domain"].to_dataset()
    st2, theta2 = model_from_dataset(back)
    np.testing.assert_array_equal(theta2, theta)
    for a, b in zip(model_matrices(ds), model_matrices(back)):
        np.testing.assert_array_equal(a, b)


TOML = """
name = "test_structure"
states = ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]
inputs = ["lon", "lat", "col", "ped"]

[kinematics]
theta0 = "trim"
phi0 = -2.0

[trim]
lon = 60.0

[A]
M_q = { value = -3.0, lower = -20.0, upper = 0.0 }
"q,u" = 0.5
X_u = { value = -0.1, free = false }
"phi,p" = { value = 0.0, free = false }

[B]
M_lon = { value = 4.0 }

[D]
"q,lon" = { value = 0.0, free = false }

[delays]
tau_M_lon = { entry = "q,lon", value = 0.08 }
tau_col = { entry = "col", value = 0.02, free = false }
"""


def test_toml_structure(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(TOML)
    st = load_structure(path, trim={"theta": 5.0, "lat": 50.0, "q": 0.0})
    assert st.name == "test_structure"
    assert st.free_names == ("M_q", "M_u", "M_lon", "tau_M_lon")
    assert st.parameter("M_q").lower == -20.0 and st.parameter("M_q").upper == 0.0
    assert st.parameter("A[phi,p]").matrix == "A"
    assert st.trim_input == {"lon": 60.0, "lat": 50.0, "col": 0.0, "ped": 0.0}
    A, B, C, D, tau = st.matrices()
    kin = rigid_body_terms(theta0=5.0, phi0=-2.0).values
    assert A[4, 4] == kin[4, 4] - 3.0 and A[4, 0] == kin[4, 0] + 0.5
    assert A[0, 0] == kin[0, 0] - 0.1
    assert B[4, 0] == 4.0
    assert tau[4, 0] == 0.08 and np.all(tau[:, 2] == 0.02)
    with pytest.raises(InputDataError, match="trim_theta"):
        load_structure(path, trim={})
    bad = tmp_path / "bad.toml"
    bad.write_text(TOML.replace("[trim]", "[trimm]"))
    with pytest.raises(InputDataError, match="unknown keys"):
        load_structure(bad, trim={"theta": 5.0})
    with pytest.raises(InputDataError, match="not found"):
        load_structure(tmp_path / "missing.toml")


def test_toml_keep_marks_what_model_reduction_must_not_remove(tmp_path):
    path = tmp_path / "s.toml"
    path.write_text(TOML.replace('tau_M_lon = { entry = "q,lon", value = 0.08 }',
                                 'tau_M_lon = { entry = "q,lon", value = 0.08, keep = true }')
                    .replace('"q,u" = 0.5', '"q,u" = { value = 0.5, keep = true }'))
    st = load_structure(path, trim={"theta": 5.0})
    assert st.kept_names == ("M_u", "tau_M_lon")
    assert st.fix(["M_u"]).kept_names == ("tau_M_lon",)   # only free parameters count
    hover = load_structure("hover_6dof", trim={"theta": 6.76, "phi": -2.87})
    # the heave damping, the speed derivatives and the torque coupling N_w that place the
    # merged heave/yaw pair, and the on-axis delays: the cyclic ones in the p and q rows, the
    # pedal's on the whole input
    assert hover.kept_names == ("Z_u", "Z_w", "L_v", "M_u", "M_v", "N_u", "N_w",
                                "tau_M_lon", "tau_L_lat", "tau_ped")
    for section, line in (("delays", 'tau_M_lon = { entry = "q,lon", value = 0.08 }'),
                          ("A", "M_q = { value = -3.0, lower = -20.0, upper = 0.0 }")):
        bad = tmp_path / f"bad_{section}.toml"
        bad.write_text(TOML.replace(line, line[:-2] + ", kep = true }"))
        with pytest.raises(InputDataError, match=rf"\[{section}\].*unknown fields \['kep'\]"):
            load_structure(bad, trim={"theta": 5.0})


def test_toml_process_noise_names_states(tmp_path):
    """A structure may declare where its disturbances enter (filter error's process noise);
    the names must be states."""
    path = tmp_path / "s.toml"
    path.write_text(TOML.replace("\n\n[kinematics]", '\nprocess_noise = ["u", "q"]\n\n[kinematics]', 1))
    assert load_structure(path, trim={"theta": 5.0}).attrs["process_noise"] == "u,q"
    assert "process_noise" not in load_structure("hover_6dof", trim={"theta": 6.8,
                                                                     "phi": -2.9}).attrs
    hybrid = load_structure("hover_hybrid", trim={"theta": 6.8, "phi": -2.9})
    assert hybrid.attrs["process_noise"] == "u,v,w,r,a1,b1"
    path.write_text(TOML.replace("\n\n[kinematics]", '\nprocess_noise = ["u", "a1"]\n\n[kinematics]', 1))
    with pytest.raises(InputDataError, match=r"process_noise names \['a1'\], which are not "
                                             r"states"):
        load_structure(path, trim={"theta": 5.0})


def test_toml_pairs_name_the_structures_own_responses(tmp_path):
    """A structure may declare the output/input responses its frequency-domain fit uses;
    each must pair one of its outputs with one of its inputs."""
    path = tmp_path / "s.toml"
    path.write_text(TOML.replace("\n\n[kinematics]", '\npairs = ["q/lon", "p/lat"]\n\n[kinematics]', 1))
    assert load_structure(path, trim={"theta": 5.0}).attrs["fit_pairs"] == "q/lon,p/lat"
    assert "fit_pairs" not in load_structure("hover_6dof", trim={"theta": 6.8,
                                                                 "phi": -2.9}).attrs
    for bad in ('["q/lon", "a1/lon"]', '["q/lon", "q/thrust"]', '["q-lon"]',
                '["q/lon", "q/lon"]', '[]'):
        path.write_text(TOML.replace("\n\n[kinematics]", f"\npairs = {bad}\n\n[kinematics]", 1))
        with pytest.raises(InputDataError, match="pairs must be distinct 'output/input'"
                           if bad != "[]" else "pairs = \\[\\]: expected a non-empty list"):
            load_structure(path, trim={"theta": 5.0})


def test_toml_coherence_min_is_the_structures_own_admission(tmp_path):
    """A structure may declare the coherence admission of its frequency-domain fit; it is
    read with or without a trim, and must lie in (0, 1]."""
    path = tmp_path / "s.toml"
    path.write_text(TOML.replace("\n\n[kinematics]", "\ncoherence_min = 0.45\n\n[kinematics]", 1))
    assert load_structure(path, trim={"theta": 5.0}).attrs["fit_coherence_min"] == 0.45
    assert declared_coherence_min(path) == 0.45
    assert declared_coherence_min("hover_6dof") is None
    assert declared_coherence_min("hover_hybrid") == 0.4
    for bad in ("0.0", "1.5", '"high"'):
        path.write_text(TOML.replace("\n\n[kinematics]", f"\ncoherence_min = {bad}\n\n[kinematics]", 1))
        with pytest.raises(InputDataError, match="coherence_min"):
            declared_coherence_min(path)
        with pytest.raises(InputDataError, match="coherence_min"):
            load_structure(path, trim={"theta": 5.0})


def test_toml_structure_extends_a_base(tmp_path):
    """``base`` lays a file over another structure file (built-in by name, or a path
    relative to it): its entries replace or add to the base's table by table, ``remove``
    drops base entries, other keys replace; a base that leads back, or a removal of what the
    base lacks, is refused naming the file."""
    (tmp_path / "plain.toml").write_text(
        'name = "plain"\nstates = ["w", "q"]\ninputs = ["col"]\n'
        '[A]\nZ_w = -0.3\nM_w = 0.1\n[B]\nZ_col = -0.7\nM_col = 0.2\n')
    (tmp_path / "sub").mkdir()
    derived = tmp_path / "sub" / "derived.toml"
    derived.write_text('base = "../plain.toml"\nname = "derived"\nremove = ["M_col"]\n'
                       '[A]\nZ_w = { value = -0.5, free = false }\n"q,q" = -1.0\n')
    st = load_structure(derived)
    assert st.name == "derived" and st.states == ("w", "q")
    assert st.parameter("Z_w").value == -0.5 and not st.parameter("Z_w").free
    assert {"M_w", "M_q", "Z_col"} <= set(st.parameter_names)
    assert "M_col" not in st.parameter_names
    builtin = tmp_path / "hybrid_more.toml"
    builtin.write_text('base = "hover_hybrid"\nname = "more"\n[A]\nN_w = 0.5\n')
    trim = {"theta": 2.0, "phi": -1.0, "u": 0.0, "v": 0.0, "w": 0.0}
    more, hybrid = load_structure(builtin, trim=trim), load_structure("hover_hybrid", trim=trim)
    assert more.states == hybrid.states and more.parameter("N_w").value == 0.5
    assert declared_coherence_min(builtin) == declared_coherence_min("hover_hybrid")
    (tmp_path / "loop.toml").write_text('base = "loop.toml"\nstates = ["w"]\n'
                                        'inputs = ["col"]\n')
    with pytest.raises(InputDataError, match="leads back to itself"):
        load_structure(tmp_path / "loop.toml")
    (tmp_path / "bad.toml").write_text('base = "plain.toml"\nremove = ["N_r"]\n')
    with pytest.raises(InputDataError, match="bad.toml: remove names 'N_r'"):
        load_structure(tmp_path / "bad.toml")


def test_builtin_hover_structure():
    assert {"hover_6dof", "paper_hover"} <= set(builtin_structures())
    paper = load_structure("paper_hover", trim={"theta": 6.76, "phi": -2.87})
    tau = paper.matrices()[4]   # the paper's two delays: lon -> p and lat -> q
    assert tau[3, 0] > 0 and tau[4, 1] > 0 and np.count_nonzero(tau) == 2
    st = load_structure("hover_6dof", trim={"theta": 6.76, "phi": -2.87})
    assert {"tau_L_lon", "tau_M_lat", "tau_M_lon", "tau_L_lat", "M_q", "L_p",
            "N_ped"} <= set(st.free_names)
    tau = st.matrices()[4]      # on- and off-axis cyclic delays in the p and q rows
    assert np.count_nonzero(tau[:, 0:2]) == 4 and np.all(tau[3:5, 0:2] > 0)
    assert np.count_nonzero(tau[:, 2]) == 0  # collective: none
    assert np.all(tau[:, 3] > 0)             # pedal: one delay on every entry of its column
    assert (st.attrs["fit_omega_min"], st.attrs["fit_omega_max"]) == (0.1, 8.0)
    kin = rigid_body_terms(theta0=6.76, phi0=-2.87).values
    assert st.A0 is not None and np.array_equal(st.A0, kin)


def test_structure_rejects_conflicts():
    with pytest.raises(InputDataError, match="both set"):
        LinearStructure(states=["a"], inputs=["x"], parameters=[
            Parameter("k1", "A", "a", "a"), Parameter("k2", "A", "a", "a")])
    with pytest.raises(InputDataError, match="already has a delay"):
        LinearStructure(states=["a"], inputs=["x"], parameters=[
            Parameter("t1", "delay", "a", "x", 0.1, True, 0, 0.3),
            Parameter("t2", "delay", "*", "x", 0.1, True, 0, 0.3)])
    with pytest.raises(InputDataError, match="column"):
        LinearStructure(states=["a"], inputs=["x"], parameters=[Parameter("k", "B", "a", "y")])


# ---------------------------------------------------------------------------------------------
# Simulation
# ---------------------------------------------------------------------------------------------


def _inputs(t, U, names=CONTROLS):
    return xr.Dataset({n: ("time", U[:, j]) for j, n in enumerate(names)}, coords={"time": t})


def test_discretize_matches_scipy_zoh():
    st, theta = _random_six_dof(seed=5, delays={})
    A, B, *_ = st.matrices(theta)
    Phi, Gam = discretize(A, B, 0.02)
    Ad, Bd, *_ = scipy.signal.cont2discrete((A, B, np.eye(9), np.zeros((9, 4))), 0.02, "zoh")
    np.testing.assert_allclose(Phi, Ad, rtol=0, atol=1e-13)
    np.testing.assert_allclose(Gam, Bd, rtol=0, atol=1e-13)


def test_propagate_matches_sequential_recursion():
    rng = np.random.default_rng(0)
    Phi = np.eye(4) * 0.95 + 0.02 * rng.standard_normal((4, 4))
    W = rng.standard_normal((1003, 4, 2))
    x0 = rng.standard_normal((4, 2))
    X = propagate(Phi, W, x0)
    x = x0.copy()
    for n in range(1003):
        np.testing.assert_allclose(X[n], x, rtol=1e-10, atol=1e-12)
        x = Phi @ x + W[n]


def test_compiled_recursion_matches_the_numpy_steps(monkeypatch):
    """The many-right-hand-side recursion compiled from recursion.c (where a compiler is)
    against numpy's step loop: equal to rounding, with an initial state."""
    import sysid.models.simulation as simulation

    if simulation._native_propagate() is None:
        pytest.skip("no C compiler here: propagate runs numpy's loop only")
    rng = np.random.default_rng(3)
    Phi = np.eye(9) * 0.97 + 0.02 * rng.standard_normal((9, 9))
    W = rng.standard_normal((700, 9, 52))
    x0 = rng.standard_normal((9, 52))
    native = propagate(Phi, W, x0)
    monkeypatch.setattr(simulation, "_native_propagate", lambda: None)
    numpy_loop = propagate(Phi, W, x0)
    np.testing.assert_allclose(native, numpy_loop, rtol=1e-11,
                               atol=1e-13 * np.abs(numpy_loop).max())
    np.testing.assert_array_equal(native[0], x0)


@pytest.mark.parametrize("N", [0, 1, 2, 5, 1000])
def test_matrix_powers_match_numpy_matrix_power(N):
    rng = np.random.default_rng(1)
    A = np.eye(5) * 0.97 + 0.03 * rng.standard_normal((5, 5))
    S = rng.standard_normal((3, 5))
    P, SP = matrix_powers(A, N), matrix_powers(A, N, start=S)
    assert P.shape == (N, 5, 5) and SP.shape == (N, 3, 5)
    for k in range(N):
        Ak = np.linalg.matrix_power(A, k)
        np.testing.assert_allclose(P[k], Ak, rtol=1e-10, atol=1e-12 * np.abs(Ak).max())
        np.testing.assert_allclose(SP[k], S @ Ak, rtol=1e-10,
                                   atol=1e-12 * np.abs(S @ Ak).max())


def test_simulate_matches_scipy_zoh_without_delays():
    st, theta = _random_six_dof(seed=6, delays={})
    ds = st.to_dataset(theta)
    A, B, C, D, _ = model_matrices(ds)
    dt = 0.01
    t = np.arange(2000) * dt
    U = np.random.default_rng(1).standard_normal((2000, 4))
    x0 = np.linspace(-1, 1, 9)
    y = simulate(ds, _inputs(t, U), x0=x0)
    Ad, Bd, Cd, Dd, _ = scipy.signal.cont2discrete((A, B, C, D), dt, "zoh")
    x, yd = x0.copy(), np.zeros((2000, 9))
    for n in range(2000):
        yd[n] = Cd @ x + Dd @ U[n]
        x = Ad @ x + Bd @ U[n]
    Y = np.stack([y[s].values for s in STATES_6DOF], axis=1)
    assert np.max(np.abs(Y - yd)) <= 1e-10 * np.max(np.abs(yd))
    assert y["q"].attrs["units"] == "deg/s"


def _first_order(tau_delay):
    """x' = a x + b u(t - tau) with y = x: one state, one input."""
    params = [Parameter("a", "A", "x", "x", -2.0), Parameter("b", "B", "x", "u", 3.0)]
    if tau_delay:
        params.append(Parameter("tau", "delay", "x", "u", tau_delay, True, 0.0, 0.3))
    return LinearStructure(states=["x"], inputs=["u"], parameters=params)


@pytest.mark.parametrize("delay", [0.05, 0.053])  # 5 samples; 5.3 samples
def test_simulate_delayed_step(delay):
    dt, a, b, n0 = 0.01, -2.0, 3.0, 10
    t = np.arange(300) * dt
    u = np.where(np.arange(300) >= n0, 1.0, 0.0)
    y = simulate(_first_order(delay).to_dataset(), _inputs(t, u[:, None], ["u"]))["x"].values
    # Convention: the delayed input is u(t_n - tau) interpolated linearly between samples and
    # held over the sample interval. For a delay of m + f samples this is a step of height
    # (1 - f) at sample n0 + m and the rest one sample later: the exact response is the sum
    # of two delayed continuous steps.
    m = math.floor(delay / dt + 1e-9)
    f = delay / dt - m

    def step(t_on):
        return np.where(t >= t_on - 1e-12, -b / a * (1.0 - np.exp(a * (t - t_on))), 0.0)

    expected = (1 - f) * step((n0 + m) * dt) + f * step((n0 + m + 1) * dt)
    np.testing.assert_allclose(y, expected, rtol=0, atol=1e-12)
    if f == 0:  # integer delay: identical to the continuous delayed step at the samples
        np.testing.assert_allclose(y, step(n0 * dt + delay), rtol=0, atol=1e-12)


def test_simulate_groups_delayed_entries_like_superposition():
    st, theta = _random_six_dof(seed=7)
    ds = st.to_dataset(theta)
    dt = 0.01
    t = np.arange(800) * dt
    U = np.random.default_rng(2).standard_normal((800, 4))
    y = simulate(ds, _inputs(t, U))
    A, B, C, D, tau = model_matrices(ds)
    total = np.zeros((800, 9))
    for i in range(9):
        for k in range(4):
            Bi = np.zeros_like(B)
            Bi[i, k] = B[i, k]
            Ti = np.zeros_like(tau)
            Ti[i, k] = tau[i, k]
            part = ds.copy()
            part["B"] = (("state_dot", "input"), Bi)
            part["delay"] = (("state_dot", "input"), Ti)
            yi = simulate(part, _inputs(t, U))
            total += np.stack([yi[s].values for s in STATES_6DOF], axis=1)
    Y = np.stack([y[s].values for s in STATES_6DOF], axis=1)
    np.testing.assert_allclose(Y, total, rtol=0, atol=1e-10 * np.abs(Y).max())


def test_simulate_absolute_and_errors():
    st = _first_order(0.0)
    st = LinearStructure(states=st.states, inputs=st.inputs, parameters=st.parameters,
                         trim_input={"u": 50.0}, trim_output={"x": 7.0})
    ds = st.to_dataset()
    t = np.arange(10) * 0.1
    y = simulate(ds, _inputs(t, np.full((10, 1), 50.0), ["u"]), absolute=True)
    np.testing.assert_allclose(y["x"].values, 7.0)
    with pytest.raises(InputDataError, match="lacks the model inputs"):
        simulate(ds, _inputs(t, np.zeros((10, 1)), ["v"]))
    with pytest.raises(InputDataError, match="uniform"):
        simulate(ds, _inputs(t ** 2, np.zeros((10, 1)), ["u"]))
    with pytest.raises(InputDataError, match="NaN"):
        simulate(ds, _inputs(t, np.full((10, 1), np.nan), ["u"]))
