"""Handling qualities, transfer-function fits and hold margins on the truth FMU's hover study.

Uses the session's hover study (``hover_study`` in conftest.py: default campaign, seed
20261121, noise and light turbulence). Truth: the FMU's full linearisation
(``/linearization_full``). The campaign holds each control sample for one 10 ms step and
records the response at the step's start, so its data carry a 5 ms zero-order-hold delay the
continuous linearisation lacks; the bandwidth check compares with the truth through that
hold (``handling_qualities``' default), the phase-delay check with the plain truth as well.
Measured on seeds 1, 2, 3 and 20261121 (sweeps only): docs/notes/2026-11-24-handling-qualities-hover.md.
"""

from __future__ import annotations

import numpy as np
import pytest

from sysid.assess.handling_qualities import AXES, handling_qualities
from sysid.assess.margins import hold_margins
from sysid.data.campaign import CampaignData
from sysid.identify.transfer_function import fit_campaign

pytestmark = pytest.mark.fmu


@pytest.fixture(scope="module")
def campaign(hover_study):
    return CampaignData(hover_study["tree"], source="hover study")


@pytest.fixture(scope="module")
def hq(campaign):
    return handling_qualities(campaign)


def test_bandwidth_and_phase_delay_of_the_data_match_the_truth(hq, campaign):
    plain = handling_qualities(campaign, sources=["linearization_full"], sample_hold=None)
    for axis in AXES:
        data = hq.sel(axis=axis, source="data")
        truth = hq.sel(axis=axis, source="linearization_full")
        assert abs(float(data.bandwidth) / float(truth.bandwidth) - 1) <= 0.05, axis
        assert abs(float(data.tau_p) - float(truth.tau_p)) <= 0.010, axis
        raw = plain.sel(axis=axis, source="linearization_full")
        assert abs(float(data.tau_p) - float(raw.tau_p)) <= 0.010, axis
        # the random error gives a finite uncertainty, the coherence is reported
        assert 0 < float(data.bandwidth_std) < 0.2 * float(data.bandwidth)
        assert 0 < float(data.coherence_bandwidth_phase) <= 1
    # the identified models are assessed beside them
    assert {"frequency_domain", "time_domain"} <= set(hq.source.values)
    assert np.isfinite(hq["bandwidth"].sel(source="frequency_domain")).all()


def test_second_order_plus_delay_fit_recovers_the_short_term_pitch_response(campaign):
    fits = fit_campaign(campaign, "q/lon", sources=["data", "linearization_full"],
                        order="0/2", delay=True)
    data, truth = fits["data"], fits["linearization_full"]
    assert data.J <= 50
    assert abs(data.delay - truth.delay) <= 0.010
    assert data.band == truth.band  # the same band and weights
    assert data.statistics.identifiable.all()


def test_holds_cross_over_near_their_design_and_keep_margins(campaign):
    m = hold_margins(campaign)
    design = m.attrs["design_crossover"]
    for hold in ("lon", "lat"):
        # secondary-axis attitude holds (full strength) on the full linearisation
        wc = m["gain_crossover"].sel(hold=hold).drop_sel(excited=hold).values
        assert np.all((wc > 0.5 * design) & (wc < 2 * design)), (hold, wc)
        assert np.all(m["phase_margin"].sel(hold=hold).values > 30), hold
        assert np.all(m["gain_margin_db"].sel(hold=hold).values > 6), hold


def test_report_shows_the_charts_and_the_hold_margins(hover_study):
    html = hover_study["report"].read_text()
    assert 'id="handling_qualities"' in html
    assert 'id="fig-handling_qualities_ads33"' in html
    assert 'id="table-hold-margins"' in html
