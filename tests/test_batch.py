"""sysid.pipeline.batch: many flight conditions on a Dask LocalCluster, fault tolerance, resume.

The default run flies two reduced (``quick``) hover seeds (the
reduced form of the bounds' Monte Carlo calibration), one impossible condition (400 kt:
the trim refuses it), one with an injected divergence, one whose identification stages
fail on a structure file with a typo (its exception must reach batch.nc) and, with forked
workers, one whose worker process dies (restarted and killed again until Dask gives up) on
a 2-worker LocalCluster (one study takes about a minute of CPU); the exhaustive form
(SYSID_EXHAUSTIVE=1) runs the issue's six full-size conditions plus the failing one.
Numbers are checked against the truth model's own linearisation, not against the code's
output.
"""

import json
import os
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from sysid.assess.comparison import DOMINANT
from sysid.pipeline import batch as batch_module
from sysid.pipeline.batch import (WORKER_CONFIG, Condition, _ReadyParts, calibration, combine,
                                  conditions, format_calibration, format_monte_carlo,
                                  group_positions, load_conditions, monte_carlo,
                                  plot_calibration, plot_derivatives, run_batch, structure_for,
                                  study_settings)
from sysid.core.errors import InputDataError

EXHAUSTIVE = os.environ.get("SYSID_EXHAUSTIVE") == "1"


def test_conditions_and_structures():
    cs = conditions([0, 20, 40, 80], seeds=[1, 2])
    assert len(cs) == 8 and len({c.name for c in cs}) == 8
    assert [c.structure_name for c in cs[::2]] == ["hover_6dof", "hover_6dof", "forward_6dof",
                                                  "forward_6dof"]
    assert structure_for(29.9) == "hover_6dof" and structure_for(30) == "forward_6dof"
    # the study's coherence admission changes with the structure: 0.6 in hover, 0.4 forward
    from sysid.pipeline.study import StudySettings

    assert StudySettings(airspeed_kt=29.9).fd_coherence == 0.6
    assert StudySettings(airspeed_kt=30.0).fd_coherence == 0.4
    assert StudySettings(airspeed_kt=80.0, fd_coherence_min=0.5).fd_coherence == 0.5
    # a structure that declares its own admission (TOML coherence_min) gets it, unless the
    # study is told one
    assert StudySettings(structure="hover_hybrid").fd_coherence == 0.4
    assert StudySettings(structure="hover_hybrid", fd_coherence_min=0.6).fd_coherence == 0.6


def test_ready_parts_go_out_critical_path_first():
    """The driver's queue of ready parts: data, then the frequency-domain fit, the
    time-domain fit, the results (PART_PRIORITY), first come first served within one."""
    a, b = Condition(0.0, seed=1, quick=True), Condition(0.0, seed=2, quick=True)
    ready = _ReadyParts()
    for c, part in ((a, "time_domain"), (a, "frequency_domain"), (b, "results"), (b, "data"),
                    (a, "results"), (b, "time_domain")):
        ready.add(c, part)
    order = [(c.name, part) for c, part in (ready.pop() for _ in range(len(ready)))]
    assert order == [(b.name, "data"), (a.name, "frequency_domain"), (a.name, "time_domain"),
                     (b.name, "time_domain"), (b.name, "results"), (a.name, "results")]
    assert not ready


def test_cli_time_domain_method_applies_to_every_condition(tmp_path, monkeypatch):
    """``sysid batch --time-domain-method filter-error`` sets every condition's estimator,
    over the speeds file's choice, and names the condition folders after it."""
    import sysid.cli.batch as cli_batch
    from sysid.cli import main
    from sysid.flight_test.campaign import default_campaign

    seen = {}

    class Captured(Exception):
        pass

    def fake_run_batch(conditions, out, **kwargs):
        seen["conditions"] = list(conditions)
        raise Captured

    monkeypatch.setattr(cli_batch, "run_batch", fake_run_batch)
    speeds = tmp_path / "speeds.toml"
    speeds.write_text('speeds = [0, 80]\nseeds = [1, 2]\ntime_domain_method = "output_error"\n')
    with pytest.raises(Captured):
        main(["batch", str(speeds), "--time-domain-method", "filter-error", "-o",
              str(tmp_path / "out"), "-q"])
    assert len(seen["conditions"]) == 4
    assert {c.time_domain_method for c in seen["conditions"]} == {"filter_error"}
    assert all(c.name.endswith("_filter_error") for c in seen["conditions"])
    assert not any(c.calm_sweeps for c in seen["conditions"])
    with pytest.raises(Captured):
        main(["batch", str(speeds), "--calm-sweeps", "-o", str(tmp_path / "out"), "-q"])
    assert all(c.calm_sweeps for c in seen["conditions"])
    design = tmp_path / "design.toml"
    design.write_text(default_campaign(0.0).select("3211_*").to_toml())
    speeds.write_text("speeds = [0]\nseeds = [1, 2]\n")
    with pytest.raises(Captured):
        main(["batch", str(speeds), "--campaign", str(design), "-o", str(tmp_path / "out"),
              "-q"])
    assert {c.campaign for c in seen["conditions"]} == {str(design.resolve())}
    with pytest.raises(SystemExit):  # argparse refuses an unknown estimator
        main(["batch", "--time-domain-method", "least-squares"])


def test_speeds_file(tmp_path):
    path = tmp_path / "speeds.toml"
    path.write_text('speeds = [0, 60]\nseeds = [3]\nnoise = false\n'
                    '[structures]\npaper_hover = [0, 10]\n'
                    '[[conditions]]\nairspeed_kt = 50\nseed = 7\n')
    cs = load_conditions(path)
    assert [(c.airspeed_kt, c.seed, c.noise) for c in cs] == [(0, 3, False), (60, 3, False),
                                                              (50, 7, True)]
    assert cs[0].structure_name == "paper_hover" and cs[1].structure_name == "forward_6dof"
    path.write_text("speed = [0]\n")
    with pytest.raises(InputDataError, match="unknown keys.*speed"):
        load_conditions(path)
    path.write_text("speeds = ['fast']\n")
    with pytest.raises(InputDataError, match="speeds must be numbers"):
        load_conditions(path)
    # the time-domain estimator: in every condition, its name and its study settings
    path.write_text('speeds = [0]\nseeds = [1, 2]\ntime_domain_method = "filter_error"\n')
    cs = load_conditions(path)
    assert [c.name for c in cs] == ["0kt_seed1_filter_error", "0kt_seed2_filter_error"]
    assert study_settings(cs[0], tmp_path).time_domain_method == "filter_error"
    # the default: filter error (the calibrated bounds), output error for quick conditions
    assert Condition(0.0).time_domain_method == "auto"
    assert Condition(0.0).name == "0kt_seed20261121"
    assert Condition(0.0).time_domain_estimator == "filter_error"
    assert Condition(0.0, quick=True).time_domain_estimator == "output_error"
    assert Condition(0.0, quick=True, time_domain_method="filter_error").time_domain_estimator \
        == "filter_error"
    # calm sweeps (hybrid structures): named, passed to the study; a condition without it
    # keeps the marker dict of earlier batches, so their resume still matches
    path.write_text('speeds = [0]\ncalm_sweeps = true\n[structures]\nhover_hybrid = [0, 10]\n')
    calm = load_conditions(path)[0]
    assert calm.calm_sweeps and calm.name == "0kt_seed20261121_calmsweeps_hover_hybrid"
    assert study_settings(calm, tmp_path).calm_sweeps
    assert calm.to_dict()["calm_sweeps"] is True
    assert "calm_sweeps" not in Condition(0.0).to_dict()
    assert Condition(**calm.to_dict()) == calm
    path.write_text('speeds = [0]\ntime_domain_method = "kalman"\n')
    with pytest.raises(InputDataError, match="time_domain_method 'kalman'; expected one of"):
        load_conditions(path)


def test_speeds_file_with_a_campaign_design(tmp_path, monkeypatch):
    """A campaign TOML flown instead of the built-in one (a test-input design compared over
    seeds): read next to the speeds file, named, passed to the study (and reduced for a
    quick condition), refused before any work at another airspeed or when unreadable; an
    edited campaign file makes a finished condition run again."""
    from sysid.flight_test.campaign import Campaign, default_campaign
    from sysid.pipeline.batch import _write_marker, completed

    design = tmp_path / "designs" / "multisteps.toml"
    design.parent.mkdir()
    flown = default_campaign(0.0).select("[32]*")  # the multisteps only, no sweeps
    design.write_text(flown.to_toml())
    speeds = tmp_path / "speeds.toml"
    speeds.write_text('speeds = [0]\nseeds = [1, 2]\ncampaign = "designs/multisteps.toml"\n'
                      '[[conditions]]\nairspeed_kt = 0\nseed = 3\nquick = true\n'
                      'campaign = "designs/multisteps.toml"\n')
    monkeypatch.chdir(tmp_path / "designs")  # relative to the speeds file, not the cwd
    cs = load_conditions(speeds)
    assert [c.campaign for c in cs] == [str(design.resolve())] * 3
    assert [c.name for c in cs] == ["0kt_seed1_multisteps", "0kt_seed2_multisteps",
                                    "0kt_seed3_quick_multisteps"]
    assert cs[0].to_dict()["campaign"] == str(design.resolve())
    assert "campaign" not in Condition(0.0).to_dict()
    assert Condition(**cs[0].to_dict()) == cs[0]
    assert study_settings(cs[0], tmp_path / "c0").campaign_file == str(design.resolve())
    # a structure file named relative to the speeds file is read there too
    from sysid.models.toml import structure_path

    mine = tmp_path / "designs" / "mine.toml"
    mine.write_text(structure_path("hover_6dof").read_text())
    (tmp_path / "s.toml").write_text('speeds = [0]\n[structures]\n"designs/mine.toml" = [0, 10]\n'
                                     '[[conditions]]\nairspeed_kt = 0\n'
                                     'structure = "designs/mine.toml"\n')
    assert [c.structure for c in load_conditions(tmp_path / "s.toml")] == [str(mine.resolve())] * 2
    quick = Campaign.from_toml(study_settings(cs[2], tmp_path / "c2").campaign_file)
    assert [m.name for m in quick.maneuvers] == [m.name for m in flown.maneuvers]
    # resume: the same condition and files are done; an edited design is not
    folder = tmp_path / "done"
    folder.mkdir()
    (folder / "campaign.nc").write_bytes(b"")
    _write_marker(folder, {"status": "ok", "condition": cs[2].to_dict(),
                           "inputs": cs[2].inputs_digest()})
    assert completed(cs[2], folder)
    design.write_text(flown.select("3211_*").to_toml())
    assert not completed(cs[2], folder)
    # refused up front: another airspeed, a missing file
    (tmp_path / "fast.toml").write_text(default_campaign(80.0).select("3211_*").to_toml())
    speeds.write_text('speeds = [0]\ncampaign = "fast.toml"\n')
    with pytest.raises(InputDataError, match="flies at 80 kt, the condition is at 0 kt"):
        load_conditions(speeds)
    with pytest.raises(InputDataError, match="flies at 80 kt"):
        run_batch([Condition(0.0, campaign=str(tmp_path / "fast.toml"))], tmp_path / "out")
    speeds.write_text('speeds = [0]\ncampaign = "missing.toml"\n')
    with pytest.raises(InputDataError, match="cannot read campaign file missing.toml"):
        load_conditions(speeds)


def _fake_summary(value, cr, truth):
    params = ["M_q", "L_p"]
    return xr.Dataset({
        "value": (("model", "parameter"), np.array([value])),
        "cramer_rao": (("model", "parameter"), np.array([cr])),
        "cramer_rao_percent": (("model", "parameter"), 100 * np.array([cr]) / np.abs(value)),
        "truth": (("parameter",), np.array(truth)),
        "J_ave": (("model",), [10.0]), "j_rms": (("model",), [1.0])},
        coords={"model": ["frequency_domain"], "parameter": params})


def test_combine_and_monte_carlo_statistics():
    """Known scatter: values drawn with std 0.2 around the truth, CR bound 0.1 -> ratio ~2."""
    rng = np.random.default_rng(5)
    cs = [Condition(0.0, seed=s) for s in range(40)] + [Condition(400.0)]
    records = []
    for c in cs[:-1]:
        v = np.array([-3.0, -11.0]) + 0.2 * rng.standard_normal(2)
        records.append({"name": c.name, "status": "ok", "elapsed_s": 1.0,
                        "summary": _fake_summary(v, [0.1, 0.1], [-3.0, -11.0])})
    records.append({"name": cs[-1].name, "status": "failed", "error_type": "InputDataError",
                    "message": "trim airspeed must be between 0 and 160 kt", "summary": None})
    ds = combine(cs, records)
    assert ds.sizes["condition"] == 41
    assert list(ds.status.values).count("failed") == 1
    assert "InputDataError" in str(ds.error.values[-1])
    assert np.isnan(ds["value"].isel(condition=-1)).all()
    mc = monte_carlo(ds)
    ratio = mc["ratio"].sel(group="0kt", model="frequency_domain")
    assert np.allclose(ratio, 2.0, atol=0.5)
    assert int(mc["n_seeds"].sel(group="0kt")) == 40
    assert float(mc.airspeed_kt.sel(group="0kt")) == 0.0


def test_seeds_are_pooled_only_within_one_setting(tmp_path):
    """Two structures flown at one airspeed are two groups of seeds, not one: each group's
    scatter is the standard deviation of its own estimates (pooled, the offset between the
    structures would count as scatter); the derivative figure draws them side by side."""
    rng = np.random.default_rng(7)
    cs = [Condition(0.0, seed=s, structure=st) for st in ("hover_6dof", "hover_hybrid")
          for s in range(6)] + [Condition(0.0, seed=99, structure="paper_hover")]
    offset = {"hover_6dof": 0.0, "hover_hybrid": 2.0, "paper_hover": 0.0}
    records = []
    for c in cs:
        v = np.array([-3.0, -11.0]) + offset[c.structure] + 0.1 * rng.standard_normal(2)
        records.append({"name": c.name, "status": "ok", "elapsed_s": 1.0,
                        "summary": _fake_summary(v, [0.1, 0.1], [-3.0, -11.0])})
    ds = combine(cs, records)
    assert list(ds.group.values[::6]) == ["0kt_hover_6dof", "0kt_hover_hybrid",
                                          "0kt_paper_hover"]
    mc = monte_carlo(ds)
    assert list(mc.group.values) == ["0kt_hover_6dof", "0kt_hover_hybrid"]  # one seed: none
    cal = calibration(ds)
    assert list(cal.calibration_group.values) == list(mc.group.values)
    for label in mc.group.values:
        mine = ds["value"].sel(model="frequency_domain", parameter="M_q").values[
            ds.group.values == label]
        assert np.std(mine, ddof=1) < 0.3  # the 2.0 offset between structures not in it
        assert float(mc["std"].sel(group=label, model="frequency_domain", parameter="M_q")) \
            == pytest.approx(np.std(mine, ddof=1), rel=1e-12)
        assert float(cal["calibration_scatter"].sel(
            calibration_group=label, dominant="M_q", bound="frequency_domain")) == \
            pytest.approx(np.std(mine, ddof=1), rel=1e-12)
    assert "0kt_hover_hybrid (6 seeds)" in format_monte_carlo(mc)
    # drawn side by side at 0 kt, left to right in the order given; 80 kt stays where it is
    x, moved = group_positions(ds, span=40.0)
    assert moved == ["0kt_hover_6dof", "0kt_hover_hybrid", "0kt_paper_hover"]
    assert list(np.unique(x)) == [-2.0, 0.0, 2.0]
    assert np.all(x[:6] == -2.0) and np.all(x[6:12] == 0.0) and x[12] == 2.0
    alone = combine([Condition(0.0, seed=1), Condition(80.0, seed=1)], [
        {"name": c, "status": "ok", "elapsed_s": 1.0,
         "summary": _fake_summary([-3.0, -11.0], [0.1, 0.1], [-3.0, -11.0])}
        for c in ("0kt_seed1", "80kt_seed1")])
    assert group_positions(alone, span=80.0)[0].tolist() == [0.0, 80.0]
    assert group_positions(alone, span=80.0)[1] == []
    assert plot_derivatives(ds, tmp_path / "d.png").stat().st_size > 5_000


def test_calibration_of_the_bounds_against_a_known_scatter(tmp_path):
    """Both domains, three bounds: frequency-domain values scattered with std 0.2 and bound
    0.1 (ratio 2), time-domain values with std 0.3, white bound 0.03 (ratio 10) and corrected
    bound 0.3 (ratio 1); one seed where the time domain dropped L_p is left out."""
    rng = np.random.default_rng(11)
    n = 60
    cs = [Condition(0.0, seed=s) for s in range(n)]
    records = []
    for k, c in enumerate(cs):
        fd = np.array([-3.0, -11.0]) + 0.2 * rng.standard_normal(2)
        td = np.array([-3.5, -10.0]) + 0.3 * rng.standard_normal(2)
        if k == 0:
            td[1] = np.nan
        summary = xr.Dataset({
            "value": (("model", "parameter"), np.array([fd, td])),
            "cramer_rao": (("model", "parameter"), np.array([[0.1, 0.1], [0.03, 0.03]])),
            "cramer_rao_corrected": (("model", "parameter"),
                                     np.array([[np.nan] * 2, [0.3, 0.3]])),
            "truth": (("parameter",), np.array([-3.0, -11.0])),
            "J_ave": (("model",), [10.0, np.nan]), "j_rms": (("model",), [1.0, 1.0])},
            coords={"model": ["frequency_domain", "time_domain"], "parameter": ["M_q", "L_p"]})
        records.append({"name": c.name, "status": "ok", "elapsed_s": 1.0, "summary": summary})
    ds = combine(cs, records)
    cal = calibration(ds)
    ratio = cal["calibration_ratio"].sel(calibration_group="0kt")
    assert list(cal.dominant.values) == list(DOMINANT)
    assert np.allclose(ratio.sel(dominant=["M_q", "L_p"], bound="frequency_domain"), 2.0,
                       rtol=0.3)
    assert np.allclose(ratio.sel(dominant=["M_q", "L_p"], bound="time_domain_white"), 10.0,
                       rtol=0.3)
    assert np.allclose(ratio.sel(dominant=["M_q", "L_p"], bound="time_domain_corrected"), 1.0,
                       rtol=0.3)
    assert np.isnan(ratio.sel(dominant="Z_w")).all()  # not estimated anywhere
    assert int(cal["calibration_n_seeds"].sel(calibration_group="0kt", dominant="L_p",
                                              bound="time_domain_white")) == n - 1
    values = ds["value"].sel(model="time_domain", parameter="L_p").values[1:]
    assert float(cal["calibration_scatter"].sel(calibration_group="0kt", dominant="L_p",
                                                bound="time_domain_white")) == pytest.approx(
        np.std(values, ddof=1), rel=1e-12)
    text = format_calibration(ds.merge(cal))
    assert "time_domain_corrected" in text and "M_q" in text
    assert plot_calibration(ds.merge(cal), tmp_path / "c.png").stat().st_size > 5_000
    # one seed is no calibration
    assert calibration(combine(cs[:1], records[:1])) is None


@pytest.mark.slow
@pytest.mark.fmu
def test_batch_on_local_cluster_survives_a_failing_condition(tmp_path, truth_fmu, monkeypatch):
    # Default: only the two hover seeds the reduced calibration needs (every check below runs
    # on them; the quick 100-kt condition that flew beside them was one more whole study, and
    # forward flight is covered by the exhaustive form and by tests/test_forward_flight.py).
    good = conditions([0, 20, 40, 60, 80, 100]) if EXHAUSTIVE else []
    # Two hover seeds: the reduced form of the Monte Carlo calibration of the bounds (the full
    # 20-seed form is tests/test_calibration.py).
    good += [Condition(0.0, seed=seed, quick=True) for seed in (1, 2)]
    bad = Condition(400.0, quick=True)  # outside the flight envelope: trim refuses it
    # And a condition whose simulation "diverges" (injected inside its task).
    diverging = Condition(20.0, quick=True)
    # And one whose identification stages fail for real: its structure file has a typo that
    # only loading the structure (inside both fits, after the data part) finds.
    from sysid.models import structure_path

    typo = tmp_path / "typo" / "hover_typo.toml"
    typo.parent.mkdir()
    typo.write_text(structure_path("hover_6dof").read_text().replace(
        "N_r = { value = -0.3185 }", "N_r = { valeu = -0.3185 }"))
    broken = Condition(20.0, quick=True, structure=str(typo))
    everything = good + [bad, diverging, broken]
    # And, where the workers are forked from this process (Linux: WORKER_CONFIG), one whose
    # worker process dies in its first part (os._exit, as a segfaulting FMU or the kernel's
    # OOM killer would end it): the forked workers inherit this patch of the driver's module.
    forked = WORKER_CONFIG["distributed.worker.multiprocessing-method"] == "fork"
    dying = Condition(60.0, quick=True)
    if forked:
        study = batch_module.run_study

        def run_or_die(folder, *args, **kwargs):
            if Path(folder).name == dying.name:
                os._exit(3)
            return study(folder, *args, **kwargs)

        monkeypatch.setattr(batch_module, "run_study", run_or_die)
        everything.append(dying)
    result = run_batch(everything, tmp_path, n_workers=2, quiet=True,
                       inject_failure={diverging.name: "SimulationDiverged"})
    if forked:  # reported as the condition's failure; the batch and the others go on
        assert result.dataset.status.sel(condition=dying.name) == "failed"
        assert str(result.dataset.error.sel(condition=dying.name).values).startswith(
            "KilledWorker"), str(result.dataset.error.sel(condition=dying.name).values)
        assert not (tmp_path / dying.name / "condition.json").exists()
    assert result.dataset.status.sel(condition=diverging.name) == "failed"
    assert "SimulationDiverged" in str(result.dataset.error.sel(condition=diverging.name).values)
    ds = result.dataset
    status = dict(zip(ds.condition.values, ds.status.values))
    assert status[bad.name] == "failed"
    assert "400" in str(ds.error.sel(condition=bad.name).values)
    # The failing stage's own exception, type and message, not "stage ... failed (exit
    # status 1)": the stages are library calls inside the task.
    assert status[broken.name] == "failed"
    error = str(ds.error.sel(condition=broken.name).values)
    assert error.startswith("InputDataError: structure ") and "['valeu']" in error, error
    assert "exit status" not in error
    done = [c for c in good if status[c.name] == "ok"]
    assert {c.name for c in good} == {c.name for c in done}, \
        {str(k): str(v) for k, v in zip(ds.condition.values, ds.error.values)}
    # Written atomically and readable by plain netCDF, the failing stage's message with it.
    on_disk = xr.open_dataset(tmp_path / "batch.nc")
    assert on_disk.sizes["condition"] == len(good) + 3 + forked
    assert str(on_disk.error.sel(condition=broken.name).values) == error
    on_disk.close()
    assert (tmp_path / "batch_derivatives.png").stat().st_size > 10_000
    _check_calibration(ds, [c.name for c in done if c.airspeed_kt == 0.0])
    assert (tmp_path / "batch_calibration.png").stat().st_size > 10_000
    assert "time_domain_corrected" in (tmp_path / "monte_carlo.txt").read_text()
    # Truth linearisation present for every completed condition; signs of the dominant
    # damping derivatives are physical at every speed (truth, and the time-domain estimate).
    for c in done:
        row = ds.sel(condition=c.name)
        for p in ("M_q", "L_p"):
            assert float(row["truth"].sel(parameter=p)) < 0
            assert float(row["value"].sel(parameter=p, model="time_domain")) < 0
        assert float(row["truth"].sel(parameter="Z_col")) < 0
        assert float(row["value"].sel(parameter="Z_col", model="time_domain")) < 0
        # the truth's own linear model verified on the same 2311s: a floor, finite and
        # (light turbulence, sensor noise) above zero
        assert 0.0 < float(row["j_rms_truth"]) < float("inf")
    # Resume: a second run recomputes nothing that finished (only the failed condition).
    marker = json.loads((tmp_path / done[0].name / "condition.json").read_text())
    assert marker["status"] == "ok"
    again = run_batch(everything, tmp_path, n_workers=1, quiet=True,
                      inject_failure={diverging.name: "SimulationDiverged"})
    assert again.wall_time_s < result.wall_time_s / 2
    assert list(again.dataset.status.values) == list(ds.status.values)


@pytest.mark.fmu
def test_worker_settings_do_not_outlive_a_cluster_that_fails_to_start(tmp_path, monkeypatch,
                                                                       truth_fmu):
    """The batch sets WORKER_CONFIG in dask's global config for its cluster's life only (it is
    set while the cluster starts): a cluster that cannot start leaves the config as it was,
    and the error reaches the caller."""
    import dask
    import distributed  # noqa: F401  (its defaults in the config, as any caller would have)

    before = dask.config.get("distributed.worker.multiprocessing-method")
    tick = dask.config.get("distributed.admin.tick.interval")

    def refuse(*args, **kwargs):
        assert dask.config.get("distributed.worker.multiprocessing-method") == \
            WORKER_CONFIG["distributed.worker.multiprocessing-method"]
        raise OSError("no cluster here")

    monkeypatch.setattr(distributed, "LocalCluster", refuse)
    with pytest.raises(OSError, match="no cluster here"):
        run_batch([Condition(0.0, seed=1, quick=True)], tmp_path, quiet=True)
    assert dask.config.get("distributed.worker.multiprocessing-method") == before
    assert dask.config.get("distributed.worker.profile.enabled") is True
    assert dask.config.get("distributed.admin.tick.interval") == tick != "1s"
    assert dask.config.get("distributed.comm.timeouts.connect")  # the section is still there


def _check_calibration(ds, hover):
    """The calibration batch.nc stores is what its own per-seed values say: scatter =
    np.std(ddof=1) of the stored estimates, bound = mean of the stored bounds, ratio finite
    and within a wide sanity band (the goal band needs 20 seeds: tests/test_calibration.py);
    the corrected time-domain bound is at least the white one (coloured residuals)."""
    assert len(hover) >= 2
    cal = ds.swap_dims(calibration_group="calibration_kt").sel(calibration_kt=0.0)
    models = {"frequency_domain": ("frequency_domain", "cramer_rao"),
              "time_domain_white": ("time_domain", "cramer_rao"),
              "time_domain_corrected": ("time_domain", "cramer_rao_corrected")}
    for name in DOMINANT:
        for bound, (model, variable) in models.items():
            cell = cal.sel(dominant=name, bound=bound)
            values = ds["value"].sel(condition=hover, model=model, parameter=name).values
            bounds = ds[variable].sel(condition=hover, model=model, parameter=name).values
            use = np.isfinite(values) & np.isfinite(bounds)
            if use.sum() < 2:  # removed by the reduction in a seed: nothing to calibrate
                assert int(cell["calibration_n_seeds"]) == use.sum()
                continue
            assert float(cell["calibration_scatter"]) == pytest.approx(
                np.std(values[use], ddof=1), rel=1e-12)
            assert float(cell["calibration_bound"]) == pytest.approx(np.mean(bounds[use]),
                                                                     rel=1e-12)
            ratio = float(cell["calibration_ratio"])
            assert np.isfinite(ratio) and 1e-3 < ratio < 1e3, (name, bound, ratio)
        white = cal["calibration_bound"].sel(dominant=name, bound="time_domain_white")
        corrected = cal["calibration_bound"].sel(dominant=name, bound="time_domain_corrected")
        if bool(np.isfinite(white)) and bool(np.isfinite(corrected)):
            assert float(corrected) > float(white), name


def test_diverged_estimates_are_drawn_off_scale(tmp_path):
    """A fit that ran off to 1e9 must not flatten its panel: the limit follows the truth and
    the median estimate, and the plot still renders."""
    from sysid.pipeline.batch import OFF_SCALE_FACTOR, _plot_limit, plot_derivatives

    values = np.array([[-11.0, -2.8e9, -12.5], [-10.0, -9.0, np.nan]])
    truth = np.array([-11.6, -11.2, -10.9])
    assert _plot_limit(values, truth) == pytest.approx(OFF_SCALE_FACTOR * 11.6)
    assert _plot_limit(np.array([np.nan]), np.array([np.nan])) == np.inf
    names = ["0kt", "20kt", "40kt"]
    ds = xr.Dataset(
        {"value": (("condition", "model", "parameter"), values.T[:, :, None]),
         "cramer_rao": (("condition", "model", "parameter"), np.full((3, 2, 1), 0.5)),
         "truth": (("condition", "parameter"), truth[:, None])},
        coords={"condition": names, "model": ["frequency_domain", "time_domain"],
                "parameter": ["L_p"], "airspeed_kt": ("condition", [0.0, 20.0, 40.0]),
                "status": ("condition", ["ok"] * 3)})
    path = plot_derivatives(ds, tmp_path / "d.png")
    assert path.stat().st_size > 5_000
