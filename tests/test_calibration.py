"""Monte Carlo calibration of the reported bounds on the truth FMU (issue 21).

Twenty noise/turbulence seeds of the hover campaign through ``sysid.pipeline.batch``: for
each dominant derivative the seed-to-seed scatter of the estimate against the mean reported
bound, frequency domain (the CIFER Cramer-Rao bound and the same scaled by the fit
residuals) and time domain (white-noise and corrected for coloured residuals). The goal is a
ratio between 0.5 and 2 for every dominant derivative in both domains, judged on the bounds
the fidelity scoreboard uses (frequency domain: the spectral random error and the point
selection's scatter in quadrature, since the CIFER and residual-scaled bounds count the
quasi-steady structure's repeatable misfit as noise; time domain: corrected); the
conventions themselves are checked on known systems in tests/test_bound_calibration.py.
Measured (docs/notes/2026-11-25-fd-selection-bootstrap-bound.md, 20 seeds): frequency domain
0.47-1.05 (7 of 8 in the band, M_lon 0.47; the random-error bound alone 1.57-6.27), time
domain (output error) corrected 1.32-2.87 with Z_w 5.70 (two solution branches), N_r 2.49
and N_ped 2.87 (closed-loop holds). Since the reduction's refits start at the conditional
minimum the frequency-domain estimates scatter less and the same bound is conservative:
0.24-1.14, 3 of 8 (docs/notes/2026-11-26-filter-error-truth-calibration.md); with the
selection bound taken as a robust scale of the bootstrap's refits 0.58-1.88 on seven and
Z_w 2.43 (one seed fits another q/col range and keeps another structure;
docs/notes/2026-11-26-robust-selection-bound.md); with the conditioned spectra charged for
the other inputs' degrees of freedom 1.04-1.91 on all eight
(docs/notes/2026-11-26-conditioning-inputs-charged.md). The time domain's default
estimator is filter error since 2026-11-27: its corrected bounds are in the band for all
eight (0.78-1.89, docs/notes/2026-11-27-filter-error-first-pass.md; 0.88-1.82 before its
noise starts), so the first test checks the default study in both domains. Since the
simulation's zero-order hold is divided out of the responses the frequency domain reads
1.02-2.01, L_lat 2.01 just outside (docs/notes/2026-11-27-zero-order-hold.md): the first
test is a strict xfail until it is back in. Output error's
corrected bounds stay outside the goal (Z_w 5.70, N_r 2.49, N_ped 2.87): the second test is
a strict xfail that says so.
The full set runs with SYSID_EXHAUSTIVE=1 (about 20 studies: an hour or more on 2 cores);
the default suite runs the reduced form inside tests/test_batch.py (two quick hover
seeds), which checks the machinery and the stored figures. Measured ratios:
docs/notes/*-bound-calibration.md, docs/notes/*-bound-convention-monte-carlo.md.
"""

import os

import numpy as np
import pytest

from sysid.assess.comparison import CALIBRATED_BOUND, DOMINANT
from sysid.pipeline.batch import (CALIBRATION_BOUNDS, CALIBRATION_GOAL, conditions,
                                  format_calibration, run_batch)

EXHAUSTIVE = os.environ.get("SYSID_EXHAUSTIVE") == "1"
N_SEEDS = 20
#: The calibration bounds the fidelity scoreboard judges the errors on.
SCOREBOARD_BOUNDS = tuple(name for name, (model, variable) in CALIBRATION_BOUNDS.items()
                          if CALIBRATED_BOUND.get(model) == variable)


def test_scoreboard_bounds_are_calibrated_in_both_domains():
    """The scatter test below judges each domain on the bound the fidelity scoreboard uses."""
    assert SCOREBOARD_BOUNDS == ("frequency_domain_total", "time_domain_corrected")


@pytest.mark.slow
@pytest.mark.fmu
@pytest.mark.skipif(not EXHAUSTIVE, reason="20 full hover studies (about 12 min on 2 cores); "
                                           "the reduced form runs in tests/test_batch.py "
                                           "(SYSID_EXHAUSTIVE=1 runs this)")
@pytest.mark.xfail(strict=True, reason="goal missed by a hair since the simulation's "
                   "zero-order hold is divided out of the responses: frequency-domain L_lat "
                   "2.01 (L_p 1.98; 1.91 and 1.90 before), docs/notes/2026-11-27-zero-order-"
                   "hold.md")
def test_bounds_match_the_scatter_over_twenty_hover_seeds(tmp_path, truth_fmu):
    """The default study (time domain by filter error): in both domains the scoreboard's
    bound within 0.5-2 of the seed-to-seed scatter for every dominant derivative (measured:
    frequency domain 1.02-2.01 since the hold is divided out, 1.04-1.91 before; filter error
    corrected 0.78-1.89; module docstring)."""
    result = run_batch(conditions([0.0], seeds=range(1, N_SEEDS + 1)), tmp_path, n_workers=2,
                       quiet=True)
    ds = result.dataset
    assert not result.failures, result.failures
    cal = ds.swap_dims(calibration_group="calibration_kt").sel(calibration_kt=0.0)
    assert int(cal["calibration_n_seeds"].max()) == N_SEEDS
    assert set(map(str, ds["time_domain_method"].values)) == {"filter_error"}
    table = format_calibration(ds)
    lo, hi = CALIBRATION_GOAL
    for bound in SCOREBOARD_BOUNDS:
        ratio = cal["calibration_ratio"].sel(bound=bound, dominant=list(DOMINANT)).values
        assert np.all((ratio >= lo) & (ratio <= hi)), (bound, table)


@pytest.mark.slow
@pytest.mark.fmu
@pytest.mark.skipif(not EXHAUSTIVE, reason="20 full hover studies with output error (SYSID_"
                                           "EXHAUSTIVE=1 runs this)")
@pytest.mark.xfail(strict=True, reason="goal not reached (module docstring): output error's "
                   "corrected bounds Z_w 5.70, N_r 2.49, N_ped 2.87")
def test_output_error_bounds_match_the_scatter_over_twenty_hover_seeds(tmp_path, truth_fmu):
    result = run_batch(conditions([0.0], seeds=range(1, N_SEEDS + 1),
                                  time_domain_method="output_error"),
                       tmp_path, n_workers=2, quiet=True)
    assert not result.failures, result.failures
    cal = result.dataset.swap_dims(calibration_group="calibration_kt").sel(calibration_kt=0.0)
    lo, hi = CALIBRATION_GOAL
    ratio = cal["calibration_ratio"].sel(bound="time_domain_corrected",
                                         dominant=list(DOMINANT)).values
    assert np.all((ratio >= lo) & (ratio <= hi)), format_calibration(result.dataset)
