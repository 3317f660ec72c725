"""The frequency-response stage end to end, against analytic responses of known systems."""

import io

import numpy as np
import scipy.signal
import pytest
import xarray as xr

import linear_systems as ls
from sysid.core.errors import InputDataError
from sysid.identify.frequency_domain import coherence_random_error
from sysid.spectral.response import frequency_response, siso_frequency_response
from sysid.core.units import db
from sysid.core.util import Progress


@pytest.fixture(scope="module")
def mimo_records():
    """Reference MIMO system (3 inputs, 2 outputs, lightly damped mode at 5 rad/s, 0.1 s delay
    on a -> y2, input c without path to y2), correlated inputs, noise-free; 8 records of
    100 s at 50 Hz, outputs exact continuous-time steady-state responses."""
    return ls.periodic_records(ls.PATHS, ls.MIXING, ls.INPUTS, ls.OUTPUTS, n=5000, dt=0.02,
                               band=(0.05, 40.0), seeds=range(1, 9))


def test_conditioned_composite_matches_analytic_response(mimo_records):
    """Within 0.5 dB and 3 deg of the analytic G(j omega) wherever the multiple coherence
    exceeds 0.9, over 0.25-30 rad/s (two decades); the single-input estimate misses by far
    more on the same data."""
    ds = frequency_response(mimo_records, ls.INPUTS, ls.OUTPUTS, omega_max=30.0,
                            n_frequencies=100)
    siso = siso_frequency_response(mimo_records, ls.INPUTS, ls.OUTPUTS, omega_max=30.0,
                                   n_frequencies=100)
    truth = ls.truth(ls.PATHS, ls.INPUTS, ls.OUTPUTS, ds["frequency"])
    w = ds["frequency"]
    # the inputs are correlated: cross-control coherence a-b about 0.67 over the band
    assert float(ds["cross_coherence"].sel(input="a", input_j="b").mean()) > 0.5
    assert not bool(ds["collinear"].any())
    checked = (ds["multiple_coherence"] > 0.9) & (w >= 0.25)
    for o in ls.OUTPUTS:
        sel = checked.sel(output=o).values
        assert w.values[sel].max() / w.values[sel].min() >= 99.0
        assert sel.mean() > 0.6
    worst_db, worst_deg, siso_db = 0.0, 0.0, 0.0
    for (o, i) in ls.PATHS:
        sel = checked.sel(output=o).values
        ratio = (ds["H"] / truth).sel(output=o, input=i).values[sel]
        worst_db = max(worst_db, np.abs(db(ratio)).max())
        worst_deg = max(worst_deg, np.abs(np.angle(ratio, deg=True)).max())
        siso_ratio = (siso["H"] / truth).sel(output=o, input=i).values[sel]
        siso_db = max(siso_db, np.abs(db(siso_ratio)).max())
    print(f"conditioned composite: max {worst_db:.3f} dB, {worst_deg:.2f} deg; "
          f"single-input: max {siso_db:.2f} dB")
    assert worst_db < 0.5
    assert worst_deg < 3.0
    assert siso_db > 3.0          # the test is sensitive: ignoring the correlation fails
    # no path c -> y2: the conditioned estimate is small next to the a -> y2 path
    leak = abs(ds["H"].sel(output="y2", input="c")) / abs(truth.sel(output="y2", input="a"))
    assert float(leak.where(checked.sel(output="y2")).max()) < 0.1


def noisy_seeds(mimo: bool, n_seeds: int = 50, sigma: float = 1.0):
    """The same inputs, ``n_seeds`` independent output-noise realisations as outputs y0..."""
    paths = {("y", "a"): ls.tf([2.0], [1.0, 1.0], delay=0.1)}
    mixing = {("a", 0): 1.0}
    inputs = ["a"]
    if mimo:
        paths[("y", "b")] = ls.tf([3.0], [1.0, 3.0])
        mixing.update({("b", 0): 0.8, ("b", 1): 0.6})   # cross-control coherence 0.64
        inputs = ["a", "b"]
    outputs = [f"y{k}" for k in range(n_seeds)]
    per_seed = {(o, i): g for o in outputs for (_, i), g in paths.items()}
    recs = ls.periodic_records(per_seed, mixing, inputs, outputs, n=2000, dt=0.05,
                               band=(0.05, 9.0), seeds=[1, 2],
                               noise={o: sigma for o in outputs}, noise_seed=17)
    return recs, per_seed, inputs, outputs


@pytest.mark.parametrize("mimo", [False, True], ids=["eq9_siso", "eq13_conditioned"])
def test_random_error_predicts_scatter_over_50_seeds(mimo):
    """Eq. 9 (single input) and Eq. 13 (conditioned, correlated inputs) predict the scatter of
    H over 50 noise seeds within a factor 1.5.

    Compared: for input a, at each frequency, observed = standard deviation over seeds of
    the relative magnitude error |H|/|H_true| - 1 and of the phase error (rad), pooled
    (Bendat & Piersol: eps_r is the standard deviation of each); predicted = mean over seeds
    of the random_error output. Both are averaged over 1-8 rad/s. Checked per window (Eq. 9/13
    directly) and for the composite.
    """
    recs, paths, inputs, outputs = noisy_seeds(mimo)
    ds, per_window = frequency_response(recs, inputs, outputs, omega_min=1.0, omega_max=8.0,
                                        n_frequencies=30, n_windows=3, keep_windows=True)
    truth = ls.truth(paths, inputs, outputs, ds["frequency"])

    def ratio(d):
        r = (d["H"] / truth).sel(input="a")
        mag = abs(r) - 1
        phase = xr.apply_ufunc(np.angle, r)
        observed = np.sqrt(0.5 * (mag.var("output") + phase.var("output")))
        predicted = d["random_error"].sel(input="a").mean("output")
        return float(predicted.mean() / observed.mean())

    ratios = [ratio(per_window.sel(window=T)) for T in per_window["window"].values]
    ratios.append(ratio(ds))
    print("predicted / observed random error:", np.round(ratios, 3))
    for r in ratios:
        assert r > 1 / 1.5 and r < 1.5   # predicted / observed within a factor of 1.5


@pytest.mark.parametrize("mimo", [False, True], ids=["siso", "conditioned"])
def test_coherence_random_error_predicts_its_scatter_over_50_seeds(mimo):
    """The coherence's own random error (Bendat & Piersol, with the averages Eq. 9/13 imply),
    which the point-selection bootstrap draws from, predicts the scatter of the composite
    coherence of input a over 50 noise seeds within a factor 1.5 (averaged over 1-8 rad/s)."""
    recs, _, inputs, outputs = noisy_seeds(mimo, sigma=2.0)
    ds = frequency_response(recs, inputs, outputs, omega_min=1.0, omega_max=8.0,
                            n_frequencies=30, n_windows=3)
    g2 = ds["partial_coherence"].sel(input="a")
    observed = g2.std("output", ddof=1)
    predicted = coherence_random_error(ds).sel(input="a").mean("output")
    ratio = float(predicted.mean() / observed.mean())
    print(f"coherence {float(g2.mean()):.2f}, predicted / observed scatter {ratio:.3f}")
    assert 0.3 < float(g2.mean()) < 0.9      # a coherence that does scatter
    assert abs(np.log(ratio)) < np.log(1.5)   # within a factor 1.5 either way


def test_dataset_contract(mimo_records):
    ds, per_window = frequency_response(mimo_records[:3], ls.INPUTS, ls.OUTPUTS, omega_max=20.0,
                                        n_frequencies=40, n_windows=3, keep_windows=True)
    assert ds["H"].dims == ("output", "input", "frequency")
    assert ds["H"].dtype == complex
    for name in ("coherence", "partial_coherence", "random_error", "Gxy"):
        assert ds[name].dims == ("output", "input", "frequency"), name
    assert ds["multiple_coherence"].dims == ("output", "frequency")
    assert ds["Gxx"].dims == ("input", "input_j", "frequency")
    assert ds["cross_coherence"].dims == ("input", "input_j", "frequency")
    assert ds["Gyy"].dims == ("output", "frequency")
    assert ds["collinear"].dims == ("frequency",) and ds["collinear"].dtype == bool
    assert "window" not in ds.dims
    assert per_window["H"].dims == ("output", "input", "frequency", "window")
    assert per_window["Gxx"].dims == ("input", "input_j", "frequency", "window")
    np.testing.assert_allclose(per_window["window"], ds.attrs["windows"])
    assert ds.attrs["records"] == ["multisine_0", "multisine_1", "multisine_2"]
    assert ds.attrs["overlap"] == 0.8 and ds.attrs["C_eps"] == 0.7
    assert ds.attrs["conditioned"] is True
    np.testing.assert_allclose(ds["frequency"], np.geomspace(2 * np.pi / ds.attrs["windows"][-1],
                                                             20.0, 40))
    # Eq. 17: H is the ratio of the composite pair spectra
    np.testing.assert_allclose(ds["H"], ds["Gxy_pair"] / ds["Gxx_pair"], rtol=1e-12)


def test_trim_attributes_are_subtracted(mimo_records):
    """Offsets removed by trim attributes (or by the record mean) leave H unchanged."""
    base = frequency_response(mimo_records[:3], ls.INPUTS, ls.OUTPUTS, omega_max=20.0,
                              n_frequencies=20, n_windows=2)
    shifted = []
    for r in mimo_records[:3]:
        s = r.copy()
        s["a"] = s["a"] + 40.0
        s.attrs["trim_a"] = 40.0
        s["y1"] = s["y1"] + 3.0             # no trim attribute: its mean is removed
        shifted.append(s)
    other = frequency_response(shifted, ls.INPUTS, ls.OUTPUTS, omega_max=20.0,
                               n_frequencies=20, n_windows=2)
    np.testing.assert_allclose(other["H"], base["H"], rtol=1e-8)


def test_progress_lines_and_quiet(mimo_records):
    stream = io.StringIO()
    frequency_response(mimo_records[:3], ls.INPUTS, ls.OUTPUTS, omega_max=20.0,
                       n_frequencies=10, n_windows=2, progress=Progress(stream=stream))
    text = stream.getvalue()
    assert "spectra of 2 windows" in text and "composite windowing done" in text
    quiet = io.StringIO()
    frequency_response(mimo_records[:3], ls.INPUTS, ls.OUTPUTS, omega_max=20.0,
                       n_frequencies=10, n_windows=2, progress=Progress(quiet=True, stream=quiet))
    assert quiet.getvalue() == ""


def test_bad_input_errors_name_the_problem(mimo_records):
    recs = [r.copy() for r in mimo_records[:3]]
    slow = recs[1].isel(time=slice(None, None, 2))
    slow = slow.assign_coords(time=np.arange(slow.sizes["time"]) * 0.04)
    with pytest.raises(InputDataError, match=r"multisine_1.*25 Hz.*multisine_0.*50 Hz"):
        frequency_response([recs[0], slow], ls.INPUTS, ls.OUTPUTS)
    with pytest.raises(InputDataError,
                       match=r"record 'multisine_2' lasts 20 s, shorter than the 30 s"):
        frequency_response([recs[0], recs[1], recs[2].isel(time=slice(0, 1000))],
                           ls.INPUTS, ls.OUTPUTS, windows=[5.0, 30.0])
    const = [r.assign(b=r["b"] * 0 + 2.0) for r in recs]
    with pytest.raises(InputDataError, match=r"input channel\(s\) \['b'\] constant"):
        frequency_response(const, ls.INPUTS, ls.OUTPUTS)
    bad = recs[2].copy()
    bad["y2"] = bad["y2"].where(bad["time"] != 12.0)
    with pytest.raises(InputDataError, match=r"multisine_2.*'y2'.*NaN.*t = 12"):
        frequency_response([recs[0], bad], ls.INPUTS, ls.OUTPUTS)
    t = recs[0]["time"].values.copy()
    t[100:] += 0.001
    with pytest.raises(InputDataError, match=r"multisine_0.*not uniformly sampled"):
        frequency_response([recs[0].assign_coords(time=t)], ls.INPUTS, ls.OUTPUTS)
    with pytest.raises(InputDataError, match=r"no channel\(s\) \['psi'\]"):
        frequency_response(recs, ls.INPUTS, ["y1", "psi"])
    with pytest.raises(InputDataError, match=r"window 100 s gives only 3.00 averages"):
        frequency_response(recs, ls.INPUTS, ls.OUTPUTS, windows=[100.0])


def test_cli_writes_frequency_response_group(tmp_path, mimo_records, capsys):
    from sysid.cli import main
    from sysid.data.netcdf import read_campaign, write_campaign

    children = {f"maneuvers/sweep_{k}": r for k, r in enumerate(mimo_records[:3])}
    children["maneuvers/doublet_0"] = mimo_records[3]
    path = tmp_path / "campaign.nc"
    write_campaign(xr.DataTree.from_dict(children), path)
    code = main(["frequency-response", str(path), "--inputs", "a,b,c", "--outputs", "y1,y2",
                 "--omega-max", "20", "--n-frequencies", "30", "--n-windows", "3",
                 "--keep-windows"])
    assert code == 0
    out = capsys.readouterr().out
    assert "y1/a" in out and "y2/c" in out
    tree = read_campaign(path)
    ds = tree["frequency_response"].to_dataset()
    assert ds["H"].dims == ("output", "input", "frequency") and ds["H"].dtype == complex
    assert sorted(ds.attrs["records"]) == ["sweep_0", "sweep_1", "sweep_2"]   # glob sweep_*
    assert "window" in tree["frequency_response_windows"].to_dataset().dims
    direct = frequency_response(mimo_records[:3], ["a", "b", "c"], ["y1", "y2"],
                                omega_max=20.0, n_frequencies=30, n_windows=3)
    np.testing.assert_allclose(ds["H"], direct["H"], rtol=1e-12)
    # a bad request is one clear error line, exit code 1
    code = main(["frequency-response", str(path), "--inputs", "a,zz", "--outputs", "y1",
                 "--quiet"])
    assert code == 1
    assert "no channel(s) ['zz']" in capsys.readouterr().err


# -- transient (leakage) terms: an unstable plant flown in closed loop ---------------------
def _unstable_pitch_records(n_records=3, duration=150.0, dt=0.02):
    """An unstable pitch-like oscillation (poles 0.08 +- 0.49j 1/s) stabilised by attitude and
    rate feedback on its input, excited by a seeded random-phase multisine added to the
    feedback, noise-free, every record starting from trim (x = 0). Returns the records and
    the analytic open-loop q/lon of the bare plant."""
    import scipy.signal

    sigma, omega_0, b = 0.08, 0.5, 2.0
    A = np.array([[0.0, 1.0], [-omega_0 ** 2, 2 * sigma]])       # x = (theta, q)
    B = np.array([[0.0], [b]])
    K = np.array([[-0.6, -0.8]])                                  # lon = r + K x
    closed = scipy.signal.StateSpace(A + B @ K, B, np.eye(2), np.zeros((2, 1)))
    t = np.arange(int(duration / dt)) * dt
    records = []
    for seed in range(n_records):
        g = np.random.default_rng(100 + seed)
        w = np.geomspace(0.05, 5.0, 120)
        r = np.sum(np.sin(np.outer(t, w) + g.uniform(0, 2 * np.pi, w.size)), axis=1)
        r *= 3.0 / r.std()
        _, y, x = scipy.signal.lsim(closed, r, t)
        lon = r + x @ K[0]
        records.append(xr.Dataset({"lon": ("time", lon), "theta": ("time", x[:, 0]),
                                   "q": ("time", x[:, 1])}, coords={"time": t},
                                  attrs={"maneuver": f"closed_loop_{seed}"}))

    def truth(omega):
        s = 1j * np.asarray(omega)
        return b * s / (s ** 2 - 2 * sigma * s + omega_0 ** 2)
    return records, truth


def test_transient_terms_remove_closed_loop_leakage_near_an_unstable_mode():
    """Noise-free, linear: the paper's windowed estimate is biased by several dB near the
    unstable mode (each segment starts and ends mid-response, and (j omega - A)^-1 is large
    there); with the taper-derivative transforms of theta and q as extra inputs it is exact."""
    records, truth = _unstable_pitch_records()
    kw = dict(frequencies=np.geomspace(0.1, 3.0, 60))
    plain = frequency_response(records, ["lon"], ["q"], transient_states=(), **kw)
    assert plain.attrs["transient_states"] == [] and plain.attrs["transient_choice"] == "off"
    fixed = frequency_response(records, ["lon"], ["q"], transient_states="theta,q", **kw)
    assert fixed.attrs["transient_states"] == ["theta", "q"]
    assert fixed.attrs["transient_choice"] == "given"
    # the default picks the measured states itself (here q and theta, in LEAKAGE_STATES order)
    default = frequency_response(records, ["lon"], ["q"], **kw)
    assert default.attrs["transient_states"] == ["q", "theta"]
    assert default.attrs["transient_choice"] == "auto"
    np.testing.assert_allclose(default.H.values, fixed.H.values, rtol=1e-9, equal_nan=True)
    assert list(fixed.input.values) == ["lon"]          # the regressors are not reported
    w = plain.frequency.values
    exact = truth(w)
    err_plain = db(np.abs(plain.H.sel(output="q", input="lon").values / exact))
    h = fixed.H.sel(output="q", input="lon").values
    ok = np.isfinite(h)
    err_db = db(np.abs(h[ok] / exact[ok]))
    err_deg = np.degrees(np.angle(h[ok] / exact[ok]))
    print(f"q/lon near the unstable mode: paper's estimate max {np.abs(err_plain).max():.2f} dB;"
          f" with transient terms max {np.abs(err_db).max():.3f} dB, "
          f"{np.abs(err_deg).max():.2f} deg over {ok.sum()} of {ok.size} frequencies")
    assert np.abs(err_plain).max() > 2.0                # the test can see the bias
    assert ok.mean() > 0.95
    assert np.abs(err_db).max() < 0.3 and np.abs(err_deg).max() < 2.0
    # noise-free: near 1, less the charge of the two regressors' degrees of freedom
    assert float(fixed.partial_coherence.sel(output="q", input="lon").min()) > 0.98


def test_transient_terms_need_conditioning_and_distinct_channels():
    records, _ = _unstable_pitch_records(n_records=2, duration=120.0)
    with pytest.raises(InputDataError, match="conditioned"):
        frequency_response(records, ["lon"], ["q"], transient_states="q", conditioned=False,
                           omega_max=3.0)
    with pytest.raises(InputDataError, match="lon"):
        frequency_response(records, ["lon"], ["q"], transient_states="lon,q", omega_max=3.0)
    with pytest.raises(InputDataError, match="missing_state"):
        frequency_response(records, ["lon"], ["q"], transient_states="missing_state",
                           omega_max=3.0)


def test_cli_transient_states(tmp_path):
    from sysid.cli import main
    from sysid.data.netcdf import read_campaign, write_campaign

    records, truth = _unstable_pitch_records(n_records=3)
    path = tmp_path / "campaign.nc"
    write_campaign(xr.DataTree.from_dict(
        {f"maneuvers/sweep_{k}": r for k, r in enumerate(records)}), path)
    code = main(["frequency-response", str(path), "--inputs", "lon", "--outputs", "q",
                 "--omega-min", "0.1", "--omega-max", "3", "--n-frequencies", "40",
                 "--transient-states", "theta,q", "--quiet"])
    assert code == 0
    fr = read_campaign(path)["frequency_response"].to_dataset()
    assert list(fr.attrs["transient_states"]) == ["theta", "q"]
    err = db(np.abs(fr.H.sel(output="q", input="lon").values / truth(fr.frequency.values)))
    assert np.nanmax(np.abs(err)) < 0.3
    # the default is leakage-free; --no-transient-states is the paper's plain estimate
    assert main(["frequency-response", str(path), "--inputs", "lon", "--outputs", "q",
                 "--omega-min", "0.1", "--omega-max", "3", "--n-frequencies", "40",
                 "--quiet"]) == 0
    fr = read_campaign(path)["frequency_response"].to_dataset()
    assert list(fr.attrs["transient_states"]) == ["q", "theta"]
    assert fr.attrs["transient_choice"] == "auto"
    assert main(["frequency-response", str(path), "--inputs", "lon", "--outputs", "q",
                 "--omega-min", "0.1", "--omega-max", "3", "--n-frequencies", "40",
                 "--no-transient-states", "--quiet"]) == 0
    fr = read_campaign(path)["frequency_response"].to_dataset()
    assert len(fr.attrs["transient_states"]) == 0 and fr.attrs["transient_choice"] == "off"
    err = db(np.abs(fr.H.sel(output="q", input="lon").values / truth(fr.frequency.values)))
    assert np.nanmax(np.abs(err)) > 1.0      # the leakage is back


def test_extra_regressors_are_charged_their_degrees_of_freedom():
    """n_extra regressors that explain nothing still shrink a window's residual spectrum by
    about (n_d - n_extra) / n_d, which inflates the coherence (here a true 0.5 reads 0.56);
    charge_regressors restores the residual by its degrees of freedom."""
    from sysid.spectral.response import charge_regressors

    n_d, n_extra = 40.0, 8
    explained, residual = 1.0, 1.0                       # true coherence 0.5
    raw = residual * (n_d - n_extra) / n_d               # what the extra regressors leave
    dims = ("output", "input", "frequency", "window")
    one = np.ones((1, 1, 3, 2))
    per_window = xr.Dataset(
        {"Gxx_pair": (dims, one), "Gxy_pair": (dims, one * np.sqrt(explained) + 0j),
         "Gyy_pair": (dims, one * (explained + raw)),
         "partial_coherence": (dims, one * explained / (explained + raw)),
         "random_error": (dims, one * 0.1), "n_d": (("window",), [n_d, 9.0])})
    out = charge_regressors(per_window, n_extra, C_eps=0.7)
    g2 = out.partial_coherence.isel(window=0).values
    np.testing.assert_allclose(g2, 0.5, rtol=1e-12)
    assert float(per_window.partial_coherence.isel(window=0).max()) > 0.55   # before: inflated
    # a window left with fewer than 5 averages is not used (infinite random error)
    assert np.all(np.isinf(out.random_error.isel(window=1).values))
    assert np.all(np.isfinite(out.random_error.isel(window=0).values))


def test_auto_transient_states_take_the_measured_rigid_body_states_only():
    from sysid.spectral.response import LEAKAGE_STATES, resolve_transient_states

    records, _ = _unstable_pitch_records(n_records=2, duration=60.0)
    extra = [r.assign(psi=r["q"] * 0.0 + 1.0, u=r["q"] * 0.1) for r in records]
    assert resolve_transient_states(extra, "auto", inputs=["lon"]) == (["u", "q", "theta"],
                                                                       "auto")
    # a state missing from one record is not used; psi never is; inputs never are
    partial = [extra[0], records[1]]
    assert resolve_transient_states(partial, "auto", inputs=["lon"]) == (["q", "theta"], "auto")
    assert resolve_transient_states(extra, "auto", inputs=["lon", "q"])[0] == ["u", "theta"]
    assert resolve_transient_states(extra, "auto", conditioned=False) == ([], "off")
    assert resolve_transient_states(extra, "", inputs=["lon"]) == ([], "off")
    assert resolve_transient_states(extra, (), inputs=["lon"]) == ([], "off")
    assert "psi" not in LEAKAGE_STATES and len(LEAKAGE_STATES) == 8
    # no state measured at all: off, and recorded so
    bare = [r.rename(q="y", theta="z") for r in records]
    fr = frequency_response(bare, ["lon"], ["y"], omega_max=10.0, n_frequencies=20)
    assert fr.attrs["transient_states"] == [] and fr.attrs["transient_choice"] == "off"


def _held_first_order(dt=0.05, a=2.0, duration=400.0, seed=5, hold="zero_order"):
    """``y' = a (u - y)`` driven by a staircase (every sample of ``u`` held over its interval,
    as a simulation is stepped), sampled at the steps: the exact recursion
    ``y[k+1] = e^(-a dt) y[k] + (1 - e^(-a dt)) u[k]``; ``u`` white, seeded."""
    n = int(duration / dt)
    u = np.random.default_rng(seed).standard_normal(n)
    phi = np.exp(-a * dt)
    y = np.zeros(n)
    y[1:] = scipy.signal.lfilter([0.0, 1.0 - phi], [1.0, -phi], u)[1:]
    attrs = {} if hold is None else {"input_hold": hold}
    return xr.Dataset({"u": ("time", u), "y": ("time", y)},
                      coords={"time": np.arange(n) * dt}, attrs=attrs)


def test_a_zero_order_hold_of_the_inputs_is_divided_out():
    """Records flown with held inputs (as the truth FMU is stepped) relate through the
    sampled system ``G_d(z) = (1 - phi) / (z - phi)``, which lags the continuous a/(s + a) by
    about omega dt / 2 (14 deg at 10 rad/s for dt = 0.05 s): the estimate without the hold
    divided out (measured data) is ``G_d``, with it ``G_d / Z``, whose phase is the continuous
    system's within 1 deg over 0.5-12 rad/s (its magnitude within 0.35 dB: at this coarse
    sampling the folded spectrum adds 0.25 dB at 12 rad/s; 0.01 s sampling leaves a tenth)."""
    dt, a = 0.05, 2.0
    kw = dict(omega_min=0.5, omega_max=12.0, n_frequencies=60)
    held = frequency_response([_held_first_order(dt, a)], ["u"], ["y"], **kw)
    plain = frequency_response([_held_first_order(dt, a, hold=None)], ["u"], ["y"], **kw)
    assert held.attrs["input_hold"] == "zero_order" and plain.attrs["input_hold"] == "none"
    w = held["frequency"].values
    z, phi = np.exp(1j * w * dt), np.exp(-a * dt)
    G_d = (1 - phi) / (z - phi)
    Z = (1 - 1 / z) / (1j * w * dt)
    for estimate, exact in ((plain, G_d), (held, G_d / Z)):
        ratio = estimate["H"].sel(output="y", input="u").values / exact
        assert np.abs(db(ratio)).max() < 0.1      # the windowed estimate's own error
        assert np.abs(np.angle(ratio, deg=True)).max() < 1.0
    G = a / (1j * w + a)
    ratio = held["H"].sel(output="y", input="u").values / G
    assert np.abs(np.angle(ratio, deg=True)).max() < 1.0
    assert np.abs(db(ratio)).max() < 0.35
    lag = np.angle(plain["H"].sel(output="y", input="u").values / G, deg=True)
    np.testing.assert_allclose(lag, -np.degrees(w * dt / 2), atol=1.0)
    # the coherence and the random error are the data's either way
    np.testing.assert_allclose(held["partial_coherence"], plain["partial_coherence"])
    with pytest.raises(InputDataError, match="disagree on how their inputs were held"):
        frequency_response([_held_first_order(dt, a), _held_first_order(dt, a, seed=6,
                                                                         hold=None)],
                           ["u"], ["y"], **kw)
    with pytest.raises(InputDataError, match="input_hold"):
        frequency_response([_held_first_order(dt, a, hold="first_order")], ["u"], ["y"], **kw)
