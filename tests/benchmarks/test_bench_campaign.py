"""Time and peak memory to fly the default hover campaign (issue target: under 15 s on one
core). Runs once as a plain test by default (--benchmark-disable) on a reduced campaign (one
sweep and one multistep per axis); ``SYSID_EXHAUSTIVE=1`` or --benchmark-enable flies the
whole default campaign (8 sweeps of 150 s, 8 multisteps) and reports the numbers in
``benchmark.extra_info``, including the simulated seconds per wall-clock second.
"""

import os
import resource
import time

import pytest

from sysid.flight_test.campaign import default_campaign, run_campaign
from sysid.spectral.cross_control import campaign_summary

pytestmark = pytest.mark.fmu


def test_default_hover_campaign(benchmark, truth_fmu, tmp_path):
    campaign = default_campaign()
    full = os.environ.get("SYSID_EXHAUSTIVE") == "1" or not benchmark.disabled
    if not full:
        campaign = campaign.select("*_1").select("sweep_*")
        campaign.maneuvers += [m for m in default_campaign().maneuvers if m.kind == "2311"]
    simulated = sum(m.duration + m.lead_in + m.lead_out for m in campaign.maneuvers)

    def fly():
        # Peak resident memory of the process (getrusage, KiB on Linux); tracemalloc would
        # slow the stepping loop tenfold and distort the time.
        start = time.perf_counter()
        tree = run_campaign(campaign, tmp_path / "campaign.nc", quiet=True, fmu=truth_fmu,
                            summaries=[campaign_summary])
        elapsed = time.perf_counter() - start
        peak = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss * 1024
        return tree, elapsed, peak

    tree, elapsed, peak = benchmark.pedantic(fly, rounds=1, iterations=1)
    benchmark.extra_info.update(
        maneuvers=len(campaign.maneuvers), simulated_s=simulated, wall_s=round(elapsed, 2),
        real_time_factor=round(simulated / elapsed, 1), peak_rss_MB=round(peak / 2**20, 1))
    print(f"\ncampaign: {len(campaign.maneuvers)} manoeuvres, {simulated:.0f} s simulated in "
          f"{elapsed:.1f} s ({simulated / elapsed:.0f}x real time), peak RSS "
          f"{peak / 2**20:.0f} MB")
    assert len(tree["maneuvers"].children) == len(campaign.maneuvers)
