"""Flight data end to end with no truth model (issue 23): ``sysid run --data``.

Fast: the measured outputs, pairs and structure; the accelerometers' velocity responses
against the analytic ones of a known system; the example files' jittered clock; and the
whole chain on a known linear system of its own (tests/trust_system.py, the test bed of
issue 21) measured the way the example is (p q r phi theta psi ax ay az, no u v w), written as
CSV files: the identified derivatives against the system's truth, the report in Chromium
(the chain runs once per session: ``known_system_chain`` in conftest.py).

Slow (``SYSID_EXHAUSTIVE=1 pytest -m slow``; 2-5 min on the shared machine; the known-system
chain is its reduced form in the default run): the README's worked example, the
truth helicopter's hover campaign written as jittered MAT v7.3 files without u v w and run
through ``sysid run --data ... --resample auto``, against the truth FMU's linearisation for
the same structure (:func:`sysid.truth.linearize.truth_for_structure`).
"""

from __future__ import annotations

import json
import os
import re
import tomllib
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from browser import chromium  # noqa: F401  (pytest fixture)

import trust_system
from test_identify_frequency import analytic_response, truth_values
from test_measurement_equations import accelerometer_spec

from sysid.cli import main
from sysid.core.errors import InputDataError
from sysid.core.units import CHANNELS
from sysid.data.campaign import CampaignData
from sysid.data.importers import write_csv
from sysid.flight_test.example import jittered_record
from sysid.identify.frequency_domain import with_derived_states
from sysid.models import load_structure, structure_from_dict, structure_path
from sysid.report.read import pair_costs
from sysid.truth import linearize, trim
from sysid.truth.linearize import truth_for_structure
from sysid.pipeline.flight_data import (measured_outputs, measured_pairs, measured_structure,
                                        read_flight_data, structure_toml)

EXHAUSTIVE = os.environ.get("SYSID_EXHAUSTIVE") == "1"
ACC_OUTPUTS = ("p", "q", "r", "phi", "theta", "psi", "ax", "ay", "az")
#: Noise of the known system's accelerometers, ft/s^2.
ACC_NOISE = 0.1


# -- outputs, pairs, structure ---------------------------------------------------------------


def test_pairs_take_the_accelerometer_of_an_unmeasured_velocity():
    pairs = measured_pairs(ACC_OUTPUTS)
    assert ("ax", "lon") in pairs and ("ay", "lat") in pairs and ("az", "col") in pairs
    assert ("ay", "ped") in pairs and ("q", "lon") in pairs and ("r", "ped") in pairs
    assert not any(o in ("u", "v", "w") for o, _ in pairs)
    assert len(pairs) == 13
    # with the velocities measured, the paper's pairs
    assert ("u", "lon") in measured_pairs(("u", "v", "w", "p", "q", "r", "ax"))


def test_measured_structure_moves_delays_off_the_rows_the_accelerometers_read():
    spec = measured_structure("hover_6dof", ACC_OUTPUTS)
    assert spec["outputs"] == list(ACC_OUTPUTS)
    assert spec["delays"]["tau_ped"]["entry"] == "r,ped"       # Y_ped is read by ay
    assert spec["delays"]["tau_M_lon"]["entry"] == "q,lon"     # per-entry delays stay
    st = structure_from_dict(spec, trim={"theta": 3.0, "phi": -2.0})
    assert st.outputs == ACC_OUTPUTS and st.has_output_equations
    hybrid = measured_structure("hover_hybrid", ACC_OUTPUTS)
    # tau_col on every row: Z_col is read by az; L_col, M_col, N_col keep one delay each
    assert {k: v["entry"] for k, v in hybrid["delays"].items() if k.startswith("tau_col")} \
        == {"tau_col_p": "p,col", "tau_col_q": "q,col", "tau_col_r": "r,col"}
    structure_from_dict(hybrid, trim={"theta": 3.0, "phi": -2.0})
    # without accelerometers nothing moves
    assert measured_structure("hover_6dof", ("u", "v", "w", "p", "q", "r"))["delays"][
        "tau_ped"]["entry"] == "ped"
    with pytest.raises(InputDataError, match="none of its states"):
        measured_structure("hover_6dof", ("h",))


def test_a_structures_own_pairs_move_onto_the_measured_outputs(tmp_path):
    """A structure that names its pairs keeps them on flight data, the accelerometer in
    place of an unmeasured velocity and unmeasured outputs left out; none left is an error."""
    text = structure_path("hover_6dof").read_text().replace(
        '\n[kinematics]', '\npairs = ["u/lon", "q/lon", "p/ped", "psi/ped"]\n\n[kinematics]', 1)
    path = tmp_path / "own.toml"
    path.write_text(text)
    spec = measured_structure(path, ACC_OUTPUTS)
    assert spec["pairs"] == ["ax/lon", "q/lon", "p/ped", "psi/ped"]
    st = structure_from_dict(spec, trim={"theta": 3.0, "phi": -2.0})
    assert st.attrs["fit_pairs"] == "ax/lon,q/lon,p/ped,psi/ped"
    assert tomllib.loads(structure_toml(spec)) == spec
    rates = ("p", "q", "r")                                      # no u, no ax, no psi
    assert measured_structure(path, rates)["pairs"] == ["q/lon", "p/ped"]
    path.write_text(text.replace('["u/lon", "q/lon", "p/ped", "psi/ped"]', '["psi/ped"]'))
    with pytest.raises(InputDataError, match="none of its pairs"):
        measured_structure(path, rates)
    assert "pairs" not in measured_structure("hover_6dof", ACC_OUTPUTS)   # the paper's


def test_structure_toml_reads_back():
    for name in ("hover_6dof", "hover_hybrid"):
        spec = measured_structure(name, ACC_OUTPUTS)
        assert tomllib.loads(structure_toml(spec)) == spec


def test_measured_outputs_are_the_channels_of_every_record():
    t = np.arange(5.0)
    a = xr.Dataset({c: ("time", t) for c in ("q", "ax", "lon", "theta")}, coords={"time": t})
    b = a.drop_vars("theta")
    assert measured_outputs([a, b]) == ("q", "ax")


# -- accelerometers stand in for the velocities ----------------------------------------------


def test_velocity_responses_from_the_accelerometers_are_the_analytic_ones():
    """``H_u = (H_ax + K_u H) / s`` against the exact response of the same system with
    ``u v w`` as outputs (Padfield's hover derivatives, delays on the moment rows)."""
    spec = accelerometer_spec(truth_values())
    acc = structure_from_dict(spec)
    full = structure_from_dict({**spec, "outputs": spec["states"]})
    derived = with_derived_states(analytic_response(acc), acc)
    exact = analytic_response(full)
    for v in ("u", "v", "w"):
        got = derived["H"].sel(output=v).values
        want = exact["H"].sel(output=v).values
        np.testing.assert_allclose(got, want, rtol=1e-9, atol=1e-12 * np.abs(want).max())
        acc_name = {"u": "ax", "v": "ay", "w": "az"}[v]
        np.testing.assert_array_equal(derived["partial_coherence"].sel(output=v).values,
                                      derived["partial_coherence"].sel(output=acc_name).values)


# -- the example's jittered clock ------------------------------------------------------------


def test_jittered_record_samples_the_signal_at_the_jittered_instants():
    dt = 0.01
    t = np.arange(0.0, 20.0 + dt / 2, dt)
    signal = np.sin(1.3 * t) + 0.5 * np.cos(7.0 * t)
    record = xr.Dataset({c: ("time", signal, {"units": CHANNELS[c].unit})
                         for c in ("q", "ax", "lon")}, coords={"time": t},
                        attrs={"maneuver": "sweep_lon_1", "trim_q": 0.0})
    out = jittered_record(record, channels=("q", "ax", "lon"), decimation=2, jitter=0.2,
                          rng=np.random.default_rng(5))
    clock = out["time"].values
    k = np.arange(clock.size)
    off = (clock - 2 * dt * k) / (2 * dt)
    assert np.abs(off).max() <= 0.2 and np.abs(off).max() > 0.15   # 20 % of the step
    assert np.all(np.diff(clock) > 0) and clock[-1] <= t[-1]
    exact = np.sin(1.3 * clock) + 0.5 * np.cos(7.0 * clock)
    np.testing.assert_allclose(out["q"].values, exact, atol=2e-5)
    assert out.attrs == {"maneuver": "sweep_lon_1"}                 # no trim or sysid attrs
    with pytest.raises(InputDataError, match="jitter"):
        jittered_record(record, channels=("q",), jitter=0.6, rng=np.random.default_rng(0))


def test_duplicate_manoeuvre_names_are_refused(tmp_path):
    t = np.arange(0.0, 3.0, 0.02)
    ds = xr.Dataset({c: ("time", np.zeros_like(t), {"units": CHANNELS[c].unit})
                     for c in ("q", "lon")}, coords={"time": t},
                    attrs={"maneuver": "sweep_lon_1"})
    write_csv(ds, tmp_path / "a.csv")
    write_csv(ds, tmp_path / "b.csv")
    with pytest.raises(InputDataError, match="also in"):
        read_flight_data([tmp_path / "a.csv", tmp_path / "b.csv"])


def test_run_data_passes_the_time_domain_estimator(tmp_path, monkeypatch):
    """``sysid run --data --time-domain-method`` reaches the flight-data chain (it was once
    silently dropped there); the default is auto."""
    import sysid.cli.run as cli_run

    seen = []

    def fake(files, out, **kw):
        seen.append(kw["time_domain_method"])
        return tmp_path / "report.html"

    monkeypatch.setattr(cli_run, "run_flight_data", fake)
    for extra, expected in (([], "auto"), (["--time-domain-method", "output-error"],
                                           "output_error")):
        assert main(["run", "--data", str(tmp_path / "a.csv"), "-q", *extra]) == 0
        assert seen[-1] == expected


# -- the whole chain on a known system -------------------------------------------------------


def known_system_files(folder: Path, seed: int) -> list[Path]:
    """trust_system's sweeps (one per axis, 60 s) measured as p q r phi theta psi ax ay az:
    the accelerometers are the exact specific force (``ax = u' - K_u x``, the periodic
    records differentiated on their DFT lines) plus white noise; no u v w; CSV files."""
    st = trust_system.structure()
    clean = trust_system.records(seed, duration=60.0, records_per_axis=1, noise=0.0)
    noisy = trust_system.records(seed, duration=60.0, records_per_axis=1)
    rng = np.random.default_rng([seed, 7])
    paths = []
    for c, n in zip(clean, noisy):
        t = c["time"].values
        w = 2 * np.pi * np.fft.rfftfreq(t.size, t[1] - t[0])
        x = np.stack([c[s].values - trust_system.TRIM.get(s, 0.0) for s in st.states])
        xdot = np.fft.irfft(1j * w * np.fft.rfft(x, axis=1), t.size, axis=1)
        ds = n.drop_vars(["u", "v", "w"])
        ds.attrs = {"maneuver": n.attrs["maneuver"]}
        for acc, row in (("ax", "u"), ("ay", "v"), ("az", "w")):
            i = st.states.index(row)
            value = xdot[i] - st.K[i] @ x + ACC_NOISE * rng.standard_normal(t.size)
            ds[acc] = ("time", value, {"units": CHANNELS[acc].unit})
        path = folder / f"{n.attrs['maneuver']}.csv"
        write_csv(ds, path)
        paths.append(path)
    return paths


def _sections(html: str) -> list[str]:
    return re.findall(r'<section id="([a-z_]+)"', html)


def _images_loaded(chromium, path: Path) -> tuple[int, int]:  # noqa: F811
    dom = chromium.dump_dom(path)
    m = re.search(r'id="image-check"[^>]*data-loaded="(\d+)"[^>]*data-total="(\d+)"', dom)
    assert m, "the load script did not run"
    return int(m.group(1)), int(m.group(2))


def test_known_system_chain_writes_everything_and_reads_no_truth(known_system_chain):
    out = known_system_chain
    for name in ("campaign.nc", "frequency_domain.fmu", "time_domain.fmu", "comparison.csv",
                 "report.html", "structure.toml"):
        assert (out / name).exists(), name
    data = CampaignData.read(out / "campaign.nc")
    assert not data.has("linearization") and not data.has("linearization_full")
    assert not data.has("trim")
    for method in ("frequency_domain", "time_domain"):
        model = data.model(method)
        assert tuple(map(str, model.output.values)) == ACC_OUTPUTS
    assert data.model("time_domain").attrs["start_source"] == "/models/frequency_domain"
    # the default time-domain estimator, its process noise on the measured states only
    td = data.model("time_domain")
    assert td.attrs["method"] == "filter_error"
    noisy = {i for i, j in json.loads(td.attrs["process_noise_entries"])}
    assert noisy and not noisy & {"u", "v", "w"}
    fitted = set(pair_costs(data.model("frequency_domain")))
    assert {"ax/lon", "ay/lat", "az/col", "ay/ped"} <= fitted and not fitted & {"u/lon"}
    assert sorted(data.results("verification")) == [f"sweep_{c}_1" for c in
                                                    ("col", "lat", "lon", "ped")]
    html = (out / "report.html").read_text()
    assert _sections(html) == ["trim", "inputs", "conditioning", "pairs", "time",
                               "derivatives", "guidelines", "reduction",
                               "handling_qualities", "provenance"]
    assert 'id="pair-ax-lon"' in html and 'id="pair-az-col"' in html
    assert "Not available" not in html and ">nan<" not in html
    assert "truth linearisation" not in html


#: Largest error of each derivative against the known system's truth, per domain, from
#: seeds 3, 4, 5 (largest measured on L_p, M_q, L_lat, M_lon, N_ped: frequency domain
#: 2.8 %, time domain 3.7 %; on Z_col 3.0 % and 16 %). Z_w and N_r are not bounded: the accelerometer sees the
#: heave and yaw subsidences (0.45 rad/s) only below the coherent band of 60-s sweeps, and
#: the delay of the col input cannot stay on the row az reads; both come out 11-29 % off
#: in the frequency domain on every seed (docs/notes/2026-11-24-flight-data-end-to-end.md).
KNOWN_BOUNDS = {"frequency_domain": dict(L_p=0.05, M_q=0.05, L_lat=0.05, M_lon=0.05,
                                         N_ped=0.05, Z_col=0.05),
                "time_domain": dict(L_p=0.05, M_q=0.05, L_lat=0.05, M_lon=0.05, N_ped=0.05,
                                    Z_col=0.20)}


def test_known_system_chain_identifies_the_system(known_system_chain):
    """Both models against the system's truth: the chain read only the files."""
    data = CampaignData.read(known_system_chain / "campaign.nc")
    for method, bounds in KNOWN_BOUNDS.items():
        model = data.model(method)
        values = dict(zip(map(str, model.parameter.values), model.value.values))
        errors = {n: values[n] / trust_system.TRUE[n] - 1.0 for n in bounds}
        assert all(abs(errors[n]) <= b for n, b in bounds.items()), (method, errors)
    fd = data.model("frequency_domain")
    values = dict(zip(map(str, fd.parameter.values), fd.value.values))
    assert values["Z_w"] < 0 and values["N_r"] < 0     # stable subsidences, as in the truth


def test_known_system_report_opens_with_every_figure(known_system_chain,
                                                    chromium):  # noqa: F811
    out = known_system_chain
    loaded, total = _images_loaded(chromium, out / "report.html")
    assert total == len(list((out / "figures").glob("*.png"))) and loaded == total > 10


# -- the README example on the truth helicopter ----------------------------------------------


#: Largest error of each dominant derivative against the truth for the structure, set from
#: what the structure issue (22) reaches, not from this run: the frequency domain holds its
#: 15 % on M_q, M_lon, Z_col, N_ped, and the quasi-steady hover study's 30 % on L_lat, Z_w,
#: N_r (L_p is not held: 19-39 % low on the three seeds, 30 % in the hover study with u v w
#: measured); the time domain holds 15 % on N_ped, N_r, Z_col and 30 % on M_q, M_lon (its roll
#: and heave axes miss by 50-100 % with u v w measured too). Measured on seeds 20261121, 1,
#: 2 (docs/notes/2026-11-24-flight-data-end-to-end.md): largest errors 14.4 %, 20.4 %, 29.5 %,
#: 19.1 % (frequency domain) and 13.9 %, 24.5 % (time domain).
EXAMPLE_BOUNDS = {
    "frequency_domain": dict(M_q=0.15, M_lon=0.15, Z_col=0.15, N_ped=0.15, L_lat=0.30,
                             Z_w=0.30, N_r=0.30),
    "time_domain": dict(N_ped=0.15, N_r=0.15, Z_col=0.15, M_q=0.30, M_lon=0.30),
}


@pytest.mark.slow
@pytest.mark.skipif(not EXHAUSTIVE, reason="the README example flies the hover campaign (2-5 "
                    "min); its reduced form is the known-system chain above; "
                    "SYSID_EXHAUSTIVE=1 runs it")
def test_readme_example_identifies_the_truth(tmp_path, chromium, capsys):  # noqa: F811
    assert main(["example-data", "-o", str(tmp_path / "flight"), "-q"]) == 0
    files = sorted(str(p) for p in (tmp_path / "flight").glob("*.mat"))
    assert len(files) == 16
    out = tmp_path / "reports" / "flight"
    assert main(["run", "--data", *files, "--resample", "auto", "-o", str(out), "-q"]) == 0
    assert capsys.readouterr().out.strip().endswith("report.html")
    loaded, total = _images_loaded(chromium, out / "report.html")
    assert total == len(list((out / "figures").glob("*.png"))) and loaded == total > 20
    data = CampaignData.read(out / "campaign.nc")
    assert not data.has("linearization")
    st = load_structure(out / "structure.toml", trim=data.trim())
    truth = truth_for_structure(linearize(trim(0.0)).full, st)
    true = dict(zip(map(str, truth.parameter.values), truth.value.values))
    for method, bounds in EXAMPLE_BOUNDS.items():
        model = data.model(method)
        values = dict(zip(map(str, model.parameter.values), model.value.values))
        errors = {n: values[n] / true[n] - 1.0 for n in bounds}
        assert all(abs(errors[n]) <= b for n, b in bounds.items()), (method, errors)
    for name, ds in data.results("verification").items():
        assert float(ds.j_rms.sel(source="time_domain")) <= 1.0, name
        assert float(ds.j_rms.sel(source="frequency_domain")) <= 2.0, name
