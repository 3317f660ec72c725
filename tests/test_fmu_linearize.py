"""Linearisation: numerical consistency, eigenvalues, and Padfield's Bo-105 hover data.

Reference (docs/methods.md, "The truth helicopter"): Padfield's Helisim Bo-105 hover derivatives, SI and rad,
for a 2200 kg aircraft with Ixx, Iyy, Izz = 1433, 4973, 4099 kg m^2.

Scaling to our aircraft: the truth model keeps the Bo-105 rotor, geometry and aerodynamics
and scales mass and inertias by k = 2800 / 2200 (same radii of gyration). The forces and
moments per unit motion are then unchanged, so force derivatives per unit mass (X_, Y_, Z_)
and moment derivatives per unit inertia (L_, M_, N_) scale by 1 / k. Control derivatives per
radian of blade angle become per percent of travel through our gearing, d(angle)/d(percent):
collective 16 deg / 100 %, longitudinal 15.5 deg / 100 % (theta_1s, aft positive), lateral
-10 deg / 100 % for Padfield's theta_1c (our lat stick to the right tilts the disc to
starboard, Padfield's theta_1c positive tilts it to port), pedal -24 deg / 100 %.
"""

import math

import numpy as np
import pytest

pytestmark = pytest.mark.fmu

K = 2800.0 / 2200.0
FT, DEG = 0.3048, math.pi / 180.0

PADFIELD_STABILITY = dict(
    X_u=-0.0211, X_w=0.0113, X_q=0.7086, Z_w=-0.3220, M_u=0.1045, M_w=-0.0151, M_q=-3.7472,
    M_v=0.0900, M_p=-0.0972, Y_v=-0.0405, Y_p=-0.7365, Y_r=0.1017, L_u=0.3402, L_v=-0.4114,
    L_q=0.3688, L_p=-14.1949, L_r=0.1277, N_u=0.0607, N_v=-0.0173, N_p=-2.4296, N_r=-0.3185)
# per rad of (theta_0, theta_1s, theta_1c, theta_0TR); None where Padfield lists none
PADFIELD_CONTROL = {
    "X": (3.653, -8.477, 3.308, None), "Z": (-92.96, None, None, None),
    "M": (-5.682, 44.997, -17.559, None), "Y": (-0.553, -3.308, -8.477, 5.043),
    "L": (4.993, -66.37, -170.08, 6.197), "N": (19.73, -11.80, -30.24, -15.46)}
# blade angle (Padfield's signs) per percent of travel, rad/%: col, lon, lat, ped
GEARING = {"col": 16 * DEG / 100, "lon": 15.5 * DEG / 100, "lat": -10 * DEG / 100,
           "ped": -24 * DEG / 100}
CONTROL_INDEX = {"col": 0, "lon": 1, "lat": 2, "ped": 3}
# SI -> analysis units of a derivative's row (force rows ft/s^2, moment rows deg/s^2) and
# column (velocity columns ft/s, rate columns deg/s, controls %)
ROW = {"X": 1 / FT, "Y": 1 / FT, "Z": 1 / FT, "L": 1 / DEG, "M": 1 / DEG, "N": 1 / DEG}
COL = {"u": 1 / FT, "v": 1 / FT, "w": 1 / FT, "p": 1 / DEG, "q": 1 / DEG, "r": 1 / DEG}


def padfield_stability(name):
    """Padfield's value scaled to our mass/inertia, converted to analysis units."""
    letter, col = name.split("_")
    return PADFIELD_STABILITY[name] / K * ROW[letter] / COL[col]


def padfield_control(letter, control):
    per_rad = PADFIELD_CONTROL[letter][CONTROL_INDEX[control]]
    if per_rad is None:
        return None
    return per_rad / K * GEARING[control] * ROW[letter]


@pytest.fixture(scope="module")
def hover_lin(hover_trim):
    from sysid.truth import linearize

    return linearize(hover_trim)


def test_jacobian_independent_of_step(hover_trim):
    """Central differences with steps 1e-4 and 1e-5 (relative to the states' nominal values)
    agree to 1e-4 relative on every significant entry: |A_ij| >= 1e-4 max_k |A_ik| (rows
    scaled by their largest entry, so that entries below the row's numerical noise floor are
    not judged), same for B."""
    from sysid.truth import jacobians_si

    A1, B1 = jacobians_si(hover_trim, step=1e-4)
    A2, B2 = jacobians_si(hover_trim, step=1e-5)
    assert (np.abs(A2.values) > 0).sum() > 100
    for M1, M2 in ((A1.values, A2.values), (B1.values, B2.values)):
        scale = np.max(np.abs(M2), axis=1, keepdims=True)
        significant = (np.abs(M2) >= 1e-4 * scale) & (np.abs(M2) > 0)
        assert significant.sum() >= 4
        rel = np.abs(M1 - M2)[significant] / np.abs(M2)[significant]
        assert rel.max() < 1e-4, rel.max()


def test_hover_eigenvalues(hover_lin):
    full = hover_lin.eigenvalues_full
    slow = full[np.abs(full) < 1.5]
    # unstable low-frequency pitch/roll oscillation (Padfield: +0.24 +- 0.53i)
    unstable = slow[(slow.real > 0) & (np.abs(slow.imag) > 0.1)]
    assert unstable.size == 2
    assert np.all(np.abs(unstable) < 1.0)
    # rotor flapping and inflow modes: every mode of the fast subsystem faster than 10 rad/s
    A = hover_lin.full["A"]
    rotor = ["a1", "b1", "vi_mr", "vi_tr"]
    ev_rotor = np.linalg.eigvals(A.sel(state_dot=rotor, state=rotor).values)
    assert np.all(np.abs(ev_rotor) > 10.0)
    fast = full[np.abs(full) > 10.0]
    assert np.sum(np.abs(fast.imag) > 5.0) >= 2          # coupled flap/roll pair
    assert np.all(fast.real < -5.0)
    # the quasi-steady model keeps the unstable oscillation
    red = hover_lin.eigenvalues_reduced
    assert np.any((red.real > 0) & (np.abs(red.imag) > 0.1))


def test_eigenvector_of_unstable_mode_is_pitch_roll(hover_lin):
    """The unstable oscillation moves pitch and roll attitude (coupled through the hingeless
    rotor, with yaw following), not heave: in analysis units (deg, ft/s) both theta and phi
    have at least 30 % of the largest eigenvector component and w less than 20 %."""
    A = hover_lin.full["A"]
    ev, vec = np.linalg.eig(A.values)
    k = int(np.argmax(np.where(np.abs(ev.imag) > 0.1, ev.real, -np.inf)))
    mag = np.abs(vec[:, k]) / np.abs(vec[:, k]).max()
    mag = dict(zip(A.state.values, mag))
    assert mag["theta"] > 0.3 and mag["phi"] > 0.3
    assert mag["w"] < 0.2


@pytest.mark.parametrize("name", sorted(PADFIELD_STABILITY))
def test_hover_stability_derivative_signs(hover_lin, name):
    """Every one of Padfield's 21 hover stability derivatives has his sign, L_r included
    (the default flapping drive is Heffley & Mnich's and Helisim's: body p and q)."""
    assert np.sign(float(hover_lin.derivatives().sel(parameter=name))) == \
        np.sign(PADFIELD_STABILITY[name])


@pytest.fixture(scope="module")
def exact_kinematics_lin(truth_fmu):
    """Hover linearisation with exact shaft kinematics: r sin(i) in the flapping drive."""
    from sysid import truth

    parameters = {"yaw_rate_flapping": 1.0}
    return truth.linearize(truth.trim(0.0, fmu=truth_fmu, parameters=parameters),
                           fmu=truth_fmu)


def test_exact_shaft_kinematics_option_turns_l_r_negative(hover_lin, exact_kinematics_lin):
    """With ``yaw_rate_flapping = 1`` the 3 deg forward shaft tilt turns a yaw rate into a
    roll rate about the shaft (r sin i_s), which the rotor's roll damping opposes
    (L_p sin i_s ~ -0.6 1/s) more strongly than the high tail rotor pushes the other way:
    L_r changes sign, and the difference is the rotor's roll damping seen through the tilt."""
    import math

    L_p = float(hover_lin.derivatives().sel(parameter="L_p"))
    L_r = float(hover_lin.derivatives().sel(parameter="L_r"))
    L_r_exact = float(exact_kinematics_lin.derivatives().sel(parameter="L_r"))
    assert L_r_exact < 0 < L_r
    assert abs(L_r_exact) < 0.1 * abs(L_p)
    assert L_r_exact - L_r == pytest.approx(L_p * math.sin(math.radians(3.0)), rel=0.3)


@pytest.mark.parametrize("letter", ["X", "Y", "Z", "L", "M", "N"])
def test_hover_control_derivative_signs(hover_lin, letter):
    for control in ("lon", "lat", "col", "ped"):
        ref = padfield_control(letter, control)
        if ref is None:
            continue
        ours = float(hover_lin.derivatives().sel(parameter=f"{letter}_{control}"))
        assert np.sign(ours) == np.sign(ref), (letter, control, ours, ref)


@pytest.mark.parametrize("name", ["Z_w", "M_q", "L_p", "N_r"])
def test_main_damping_within_factor_2(hover_lin, name):
    ours = float(hover_lin.derivatives().sel(parameter=name))
    ref = padfield_stability(name)
    assert 0.5 <= ours / ref <= 2.0, (ours, ref)


@pytest.mark.parametrize("letter,control", [("M", "lon"), ("L", "lat"), ("Z", "col"),
                                            ("N", "ped")])
def test_main_control_power_within_factor_2(hover_lin, letter, control):
    ours = float(hover_lin.derivatives().sel(parameter=f"{letter}_{control}"))
    ref = padfield_control(letter, control)
    assert 0.5 <= ours / ref <= 2.0, (ours, ref)


def test_named_derivatives_remove_rigid_body_terms(truth_fmu):
    """At 80 kt, A_r[w, q] = Z_q + U0 (deg->rad): the named derivative excludes U0."""
    from sysid.truth import linearize, trim
    from sysid.core.kinematics import rigid_body_terms

    t = trim(80.0, fmu=truth_fmu)
    lin = linearize(t)
    ds = lin.quasi_steady
    v = t.channel_values()
    kin = rigid_body_terms(theta0=v["theta"], phi0=v["phi"], u0=v["u"], v0=v["v"], w0=v["w"])
    a_wq = float(ds["A"].sel(state_dot="w", state="q"))
    assert float(ds["value"].sel(parameter="Z_q")) == pytest.approx(
        a_wq - float(kin.sel(state_dot="w", state="q")))
    assert float(kin.sel(state_dot="w", state="q")) == pytest.approx(v["u"] * DEG)


def test_model_dataset_follows_data_model(hover_lin):
    ds = hover_lin.quasi_steady
    assert ds.attrs["method"] == "linearization"
    assert list(ds.state.values) == ["u", "v", "w", "p", "q", "r", "phi", "theta", "psi"]
    assert list(ds.input.values) == ["lon", "lat", "col", "ped"]
    for var, dims in (("A", ("state_dot", "state")), ("B", ("state_dot", "input")),
                      ("C", ("output", "state")), ("D", ("output", "input")),
                      ("delay", ("state_dot", "input")), ("trim_input", ("input",)),
                      ("trim_output", ("output",)), ("value", ("parameter",))):
        assert ds[var].dims == dims
    assert ds.sizes["parameter"] == 60
    assert {"X_u", "N_r", "X_lon", "N_ped"} <= set(ds.parameter.values)
    # the quasi-steady model reproduces the full model's steady state (DC gain)
    # (heading psi is a pure integrator and left out of the comparison)
    full = hover_lin.full
    keep = [s for s in full.state.values if s != "psi"]
    Af = full["A"].sel(state_dot=keep, state=keep).values
    Bf = full["B"].sel(state_dot=keep).values
    x_full = -np.linalg.solve(Af, Bf)
    six = [s for s in ds.state.values if s != "psi"]
    Ar = ds["A"].sel(state_dot=six, state=six).values
    x_red = -np.linalg.solve(Ar, ds["B"].sel(state_dot=six).values)
    np.testing.assert_allclose(x_red, x_full[[keep.index(s) for s in six]], rtol=1e-6,
                               atol=1e-9)
