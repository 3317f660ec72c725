"""Resampling of imported records (sysid.data.resample, read_time_histories(resample=...)).

Against independent truth: analytic signals sampled at jittered times, and the truth FMU's
clean record, whose composite frequency responses the resampled jittered record must
reproduce (issue 23: 20 % jitter, one 0.5 s gap, within 0.2 dB / 1 deg over the coherent
band, 3 seeds).
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
import xarray as xr
from scipy.interpolate import CubicSpline

from sysid.core.errors import InputDataError
from sysid.core.guidelines import COHERENCE_MIN, GAP_MAX_STEPS
from sysid.data import importers
from sysid.data.resample import resample_record


def _jittered(seed, n=3000, dt=0.01, jitter=0.2):
    g = np.random.default_rng(seed)
    return np.arange(n) * dt + g.uniform(-jitter, jitter, n) * dt


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_jitter_is_measured_and_interpolated_to_the_analytic_signal(seed):
    t = _jittered(seed)
    signal = lambda x: np.column_stack([np.sin(2.0 * x), np.cos(15.0 * x + 0.3)])  # noqa: E731
    (piece,) = resample_record(t, signal(t), rate="auto")
    assert piece.attrs["resample_rate_hz"] == pytest.approx(100.0, rel=1e-4)
    # uniform +-20 % of the step: the largest sample offset over 3000 samples is near 0.2
    assert 0.19 < piece.attrs["resample_max_jitter"] < 0.21
    assert np.allclose(np.diff(piece.time), 1 / piece.attrs["resample_rate_hz"], rtol=1e-9)
    # cubic spline error at 15 rad/s, 100 Hz: (w dt)^4 scale, ~1e-5 of the amplitude
    np.testing.assert_allclose(piece.values, signal(piece.time), atol=2e-5)
    assert piece.attrs["resample_gaps_filled"] == [] == piece.attrs["resample_gaps_split"]
    assert "none" in piece.attrs["resample_filter"]


def test_short_gaps_are_bridged_and_long_ones_split_at_the_guideline():
    t = np.arange(1000) * 0.01
    short = int(GAP_MAX_STEPS) - 1  # samples missing: a gap of GAP_MAX_STEPS steps
    long = int(GAP_MAX_STEPS)  # one more: longer than the limit
    keep = np.ones(t.size, bool)
    keep[200:200 + short] = False
    keep[600:600 + long] = False
    t = t[keep]
    x = np.sin(3.0 * t)[:, None]
    pieces = resample_record(t, x, rate="auto")
    assert [p.attrs["resample_piece"] for p in pieces] == ["a", "b"]
    filled, = pieces[0].attrs["resample_gaps_filled"]
    assert filled == pytest.approx([1.99, GAP_MAX_STEPS * 0.01])
    split, = pieces[0].attrs["resample_gaps_split"]
    assert split == pytest.approx([5.99, (long + 1) * 0.01])
    assert pieces[0].time[-1] == pytest.approx(5.99) and pieces[1].time[0] == pytest.approx(6.04)
    for p in pieces:
        np.testing.assert_allclose(p.values[:, 0], np.sin(3.0 * p.time), atol=1e-6)


@pytest.mark.parametrize("jitter, tone_hz", [(0.0, 40.0), (0.2, 15.0)])
def test_antialiasing_removes_what_would_fold_and_keeps_the_band_without_delay(jitter,
                                                                               tone_hz):
    # 25 Hz from 100 Hz: 40 Hz would fold to 15 Hz, 15 Hz to 10 Hz. With jitter the tone is
    # one the spline follows (the interpolation of a tone near the old Nyquist is itself in
    # error, over the whole band: not what this test is about).
    t = _jittered(5, n=6000, jitter=jitter)
    low, high = 2 * np.pi * 1.0, 2 * np.pi * tone_hz
    x = np.column_stack([np.sin(low * t), np.sin(high * t)])
    (piece,) = resample_record(t, x, rate=25.0)
    assert "Hamming" in piece.attrs["resample_filter"]
    inner = slice(50, -50)  # away from the ends
    ref = np.sin(low * piece.time)
    err = piece.values[inner, 0] - ref[inner]
    assert np.max(np.abs(err)) < 3e-3  # pass band flat to 0.02 dB (Hamming), no delay
    # phase: project on sin/cos: the zero-phase filter adds no lag
    c = np.mean(piece.values[inner, 0] * np.cos(low * piece.time[inner]))
    s = np.mean(piece.values[inner, 0] * np.sin(low * piece.time[inner]))
    assert abs(np.degrees(np.arctan2(c, s))) < 0.05
    # without the filter the tone would alias into the band at full amplitude
    assert np.max(np.abs(piece.values[inner, 1])) < 0.01
    unfiltered = np.sin(high * piece.time)
    assert np.max(np.abs(unfiltered)) > 0.9


def test_without_resample_a_jittered_csv_is_refused_at_its_file_line(tmp_path):
    t = _jittered(3, n=50)
    t[:10] = np.arange(10) * 0.01  # the first ten samples on the grid
    lines = ["# logger v2", "", "time [s],q [deg/s]"]
    lines += [f"{a:.17g},{np.sin(a):.17g}" for a in t]
    path = tmp_path / "flight.csv"
    path.write_text("\n".join(lines) + "\n")
    first_bad = 3 + 10 + 1  # comment, blank, header, ten good rows: sample 10 on line 14
    with pytest.raises(InputDataError, match=rf"not uniform at line {first_bad}:.*--resample"):
        importers.read_time_histories(path)
    records = importers.read_time_histories(path, resample="auto")
    assert list(records) == ["flight"]
    ds = records["flight"]
    assert ds.attrs["resample_max_jitter"] == pytest.approx(np.max(np.abs(t[10:] - np.round(
        t[10:] / 0.01) * 0.01)) / 0.01, abs=0.02)  # against the fitted grid of 50 samples
    importers.validate_time_history(ds, ["q"])


def test_a_split_record_becomes_two_manoeuvres_with_the_records_trim(tmp_path):
    t = np.arange(2000) * 0.01
    t = t[(t < 8.0) | (t >= 8.5)]
    q = 1.0 + np.sin(t)
    path = tmp_path / "sweep_lon_3.csv"
    path.write_text("time [s],q [deg/s]\n" + "\n".join(f"{a:.17g},{b:.17g}"
                                                      for a, b in zip(t, q)))
    records = importers.read_time_histories(path, resample=100.0)
    assert list(records) == ["sweep_lon_3_a", "sweep_lon_3_b"]
    a, b = records.values()
    assert a.attrs["split_from"] == b.attrs["split_from"] == "sweep_lon_3"
    assert a.attrs["kind"] == "sweep" and b.attrs["axis"] == "lon"
    assert b.attrs["time_offset"] == pytest.approx(8.5) and b.time.values[0] == 0.0
    # one trim for both pieces: the first second of the record
    assert a.attrs["trim_q"] == b.attrs["trim_q"] == pytest.approx(np.mean(q[:100]))
    np.testing.assert_allclose(b.q.values, 1.0 + np.sin(b.time.values + 8.5), atol=1e-6)
    with pytest.raises(InputDataError, match="split the record into 2 pieces"):
        importers.read_time_history(path, resample=100.0)


def test_resample_errors_name_the_sample():
    with pytest.raises(InputDataError, match="not strictly increasing at sample 3"):
        resample_record(np.array([0.0, 0.01, 0.02, 0.015, 0.04]), np.zeros(5), rate="auto")
    with pytest.raises(InputDataError, match="expected a rate in Hz or 'auto'"):
        resample_record(np.arange(5.0), np.zeros(5), rate="fast")
    with pytest.raises(InputDataError, match="positive"):
        resample_record(np.arange(5.0), np.zeros(5), rate=-1.0)


# -- the truth FMU: composite responses of a jittered record with a gap ----------------------
_GAP = (20.0, 20.5)
_INPUTS, _OUTPUTS = ["lon"], ["q", "theta", "u", "w", "ax", "az"]
_OPTIONS = dict(windows=[3.0, 6.0, 10.0],
                frequencies=np.logspace(np.log10(0.7), np.log10(25.0), 80))


@pytest.fixture(scope="module")
def fine_sweep(truth_fmu):
    """A 60 s longitudinal sweep of the truth FMU, noise-free, recorded at 400 Hz."""
    from sysid.flight_test.campaign import default_campaign, run_campaign

    c = default_campaign(0.0, noise=False)
    sweeps = [dataclasses.replace(m, duration=60.0, omega_min=0.5) for m in c.maneuvers
              if m.name == "sweep_lon_1"]
    c = dataclasses.replace(c, maneuvers=sweeps, sample_rate=400.0)
    return run_campaign(c, quiet=True, fmu=truth_fmu)["maneuvers/sweep_lon_1"].to_dataset()


def _cut(ds):
    a = ds.sel(time=slice(None, _GAP[0] - 1e-9))
    b = ds.sel(time=slice(_GAP[1], None))
    return [a.assign_attrs(maneuver="a"), b.assign_coords(time=b.time - b.time[0]).assign_attrs(
        maneuver="b")]


def _db_deg(fr, ref):
    coherent = (ref.coherence >= COHERENCE_MIN) & (fr.coherence >= COHERENCE_MIN)
    ratio = (fr.H / ref.H).where(coherent)
    db = float(np.abs(20 * np.log10(np.abs(ratio))).max())
    deg = float(np.abs(xr.apply_ufunc(np.angle, ratio, kwargs={"deg": True})).max())
    return db, deg, int(coherent.sum())


@pytest.mark.fmu
def test_resampled_jittered_record_gives_the_clean_composite_responses(fine_sweep, tmp_path):
    """Clean record: the 400 Hz simulation taken at every 4th sample (100 Hz). Jittered
    record: the same flight sampled at t_i = i dt + U(-0.2, 0.2) dt (a cubic spline through
    the 400 Hz samples, 4x finer than the effect) with no sample in 20-20.5 s, written as
    MAT v7.3 and imported with resample="auto". The resampled record is split at the gap;
    the reference is the clean record cut at the same gap (the missing 0.5 s is data lost,
    not a resampling error); against the whole clean record the difference is what the cut
    alone makes plus the resampling's share."""
    from sysid.spectral.response import frequency_response

    clean = fine_sweep.isel(time=slice(None, None, 4))
    ref_cut = frequency_response(_cut(clean), _INPUTS, _OUTPUTS, **_OPTIONS)
    ref_whole = frequency_response([clean], _INPUTS, _OUTPUTS, **_OPTIONS)
    names = list(fine_sweep.data_vars)
    spline = CubicSpline(fine_sweep.time.values,
                         np.column_stack([fine_sweep[c].values for c in names]), axis=0)
    end = float(clean.time[-1])
    cut_db, cut_deg, _ = _db_deg(ref_cut, ref_whole)
    assert cut_db < 0.3 and cut_deg < 1.5
    for seed in (1, 2, 3):
        t = _jittered(seed, n=clean.sizes["time"])
        t = t[(t > 0) & (t < end) & ((t < _GAP[0]) | (t >= _GAP[1]))]
        values = spline(t)
        jittered = xr.Dataset({c: ("time", values[:, j], fine_sweep[c].attrs)
                               for j, c in enumerate(names)},
                              coords={"time": ("time", t, {"units": "s"})},
                              attrs=dict(fine_sweep.attrs))
        path = tmp_path / f"flight_{seed}.mat"
        # write_time_histories checks the grid; the file is what a logger would hand over
        _write_unchecked_mat73(path, "sweep_lon_1", jittered)
        records = importers.read_time_histories(path, resample="auto")
        assert list(records) == ["sweep_lon_1_a", "sweep_lon_1_b"]
        a = records["sweep_lon_1_a"]
        assert 0.19 < a.attrs["resample_max_jitter"] < 0.21
        (start, length), = a.attrs["resample_gaps_split"]
        assert start == pytest.approx(_GAP[0], abs=0.02) and length > 0.5
        fr = frequency_response(list(records.values()), _INPUTS, _OUTPUTS, **_OPTIONS)
        db, deg, n = _db_deg(fr, ref_cut)
        assert n > 300 and db < 0.2 and deg < 1.0, (seed, db, deg)
        # measured on seeds 1-3: 0.036 dB / 0.28 deg against the cut record
        assert db < 0.1 and deg < 0.5, (seed, db, deg)
        # Against the whole clean record the difference is the missing 0.5 s itself (the
        # cut clean record is 0.19 dB / 1.0 deg from it, u/lon and ax/lon at the band
        # edge) plus the resampling's share above.
        db, deg, n = _db_deg(fr, ref_whole)
        assert n > 300 and db < cut_db + 0.05 and deg < cut_deg + 0.3, (seed, db, deg)


def _write_unchecked_mat73(path, name, ds):
    """MAT v7.3 of a record off a uniform grid (write_time_histories refuses those)."""
    from sysid.data.formats import write_groups

    fields = {"time": ds.time.values, **{k: ds[k].values for k in ds.data_vars}}
    units = {"time": "s", **{k: ds[k].attrs.get("units") for k in ds.data_vars}}
    write_groups(path, {name: {"fields": fields, "units": units, "attrs": dict(ds.attrs)}},
                 format="mat73")


def test_cli_resample_reports_what_it_did_and_one_logger_gives_one_rate(tmp_path, capsys):
    """Two manoeuvres of one jittered 50 Hz logger (one with a 0.3 s gap) in a MAT v5 file:
    ``sysid import --resample auto`` puts both on the same 50 Hz grid, splits the one with
    the gap and prints jitter, gaps and split; the campaign holds three manoeuvres whose
    responses can be computed together (one rate)."""
    import scipy.io

    from sysid.cli import main
    from sysid.data import netcdf

    structs = {}
    for k, name in enumerate(("sweep_lon_1", "sweep_lon_2")):
        t = np.arange(1500) * 0.02 + np.random.default_rng(k).uniform(-0.004, 0.004, 1500)
        if k:
            t = t[(t < 10.0) | (t >= 10.3)]
        structs[name] = {"t": t, "lon": 50 + np.sin(t), "q": np.cos(3 * t)}
    path = tmp_path / "logger.mat"
    scipy.io.savemat(path, structs)
    out = tmp_path / "c.nc"
    assert main(["import", str(path), "-o", str(out), "--time", "t"]) == 1
    assert "not uniform at sample 1" in capsys.readouterr().err and not out.exists()
    assert main(["import", str(path), "-o", str(out), "--time", "t", "--resample",
                 "auto"]) == 0
    printed = capsys.readouterr().out
    assert "sweep_lon_1: resampled to 50 Hz" in printed
    assert "split into 2 manoeuvres at 9.9" in printed and "0 gap(s) interpolated" in printed
    tree = netcdf.read_campaign(out)
    names = sorted(tree["maneuvers"].children)
    assert names == ["sweep_lon_1", "sweep_lon_2_a", "sweep_lon_2_b"]
    steps = {float(np.diff(tree[f"maneuvers/{n}"].time.values).mean()) for n in names}
    assert max(steps) - min(steps) < 1e-12 and abs(steps.pop() - 0.02) < 1e-12
    for name in names:
        ds = tree[f"maneuvers/{name}"].to_dataset()
        t = ds.time.values + ds.attrs["time_offset"]
        np.testing.assert_allclose(ds.q.values, np.cos(3 * t), atol=2e-4)
    assert main(["import", str(path), "-o", str(out), "--resample", "fast"]) == 1
    assert "--resample 'fast'" in capsys.readouterr().err


def test_the_first_offending_line_is_the_first_off_the_loggers_grid(tmp_path):
    """A logger on a 0.01 s grid for 30 samples, then fast (0.0097 s) and jittered: the
    error names the first line off the 0.01 s grid (sample 30, line 35 after two comments,
    a blank line and the header), not line 6 of the data (the median step, taken among
    mostly fast steps, is off the logger's grid: the first step would be flagged)."""
    steps = np.full(99, 0.01)
    steps[29:] = 0.0097 + np.random.default_rng(4).uniform(-3e-4, 3e-4, 70)
    t = np.concatenate([[0.0], np.cumsum(steps)])
    assert abs(np.median(steps) - 0.01) > 1e-4
    lines = ["# logger v2", "# second comment", "", "time [s],q [deg/s]"]
    lines += [f"{a:.17g},{np.sin(a):.17g}" for a in t]
    path = tmp_path / "f.csv"
    path.write_text("\n".join(lines) + "\n")
    with pytest.raises(InputDataError, match=r"not uniform at line 35: .*expected 0\.01"):
        importers.read_time_history(path)
