"""``sysid report CAMPAIGN.nc``: the report of any campaign, at every stage it may hold.

The campaign is the known-system flight-data chain of tests/test_flight_data.py (no truth
model; the session's ``known_system_chain`` in conftest.py), cut back to what a user has
after each stage: imported data only; plus the frequency responses; plus the identified
models; everything (verification, comparison, validation). Each report must open in headless Chromium with every image decoded and the
page's script run, and hold exactly the sections whose groups exist.
"""

from __future__ import annotations

import re

import pytest
import xarray as xr
from browser import chromium  # noqa: F401  (pytest fixture)

from sysid.cli import main
from sysid.data.netcdf import read_campaign, write_campaign

#: Groups kept at each level, and the sections the report must have there.
LEVELS = {
    "data": (("maneuvers",), ["trim", "inputs", "provenance"]),
    "responses": (("maneuvers", "frequency_response", "frequency_response_siso",
                   "frequency_response_no_transient"),
                  ["trim", "inputs", "conditioning", "pairs", "guidelines",
                   "handling_qualities", "provenance"]),
    "models": (("maneuvers", "frequency_response", "frequency_response_siso",
                "frequency_response_no_transient", "models"),
               ["trim", "inputs", "conditioning", "pairs", "derivatives", "guidelines",
                "reduction", "handling_qualities", "provenance"]),
    "full": (None, ["trim", "inputs", "conditioning", "pairs", "time", "derivatives",
                    "guidelines", "reduction", "handling_qualities", "provenance"]),
}


def _campaign(level: str, folder, chain) -> str:
    tree = read_campaign(chain / "campaign.nc")
    keep, _ = LEVELS[level]
    if keep is not None:
        missing = [g for g in keep if g not in tree.children]
        assert not missing, missing
        tree = xr.DataTree.from_dict({"/": tree.to_dataset(inherit=False),
                                      **{f"/{g}": tree[g] for g in keep}})
    path = folder / f"{level}.nc"
    write_campaign(tree, path)
    return str(path)


@pytest.mark.parametrize("level", list(LEVELS))
def test_report_of_each_stage_opens_with_its_sections(level, tmp_path, known_system_chain,
                                                     chromium, capsys):  # noqa: F811
    path = _campaign(level, tmp_path, known_system_chain)
    out = tmp_path / f"report_{level}"
    assert main(["report", path, "-o", str(out), "-q"]) == 0
    printed = capsys.readouterr().out.strip()
    assert printed == str((out / "report.html").resolve())
    html = (out / "report.html").read_text()
    assert re.findall(r'<section id="([a-z_]+)"', html) == LEVELS[level][1]
    assert "Not available" not in html and ">nan<" not in html
    dom = chromium.dump_dom(out / "report.html")
    m = re.search(r'id="image-check"[^>]*data-loaded="(\d+)"[^>]*data-total="(\d+)"', dom)
    assert m, "the page's script did not run"
    files = list((out / "figures").glob("*.png"))
    assert int(m.group(2)) == len(files) == int(m.group(1)) > 0


def test_report_refuses_a_missing_campaign_and_a_file_as_folder(tmp_path, known_system_chain,
                                                                capsys):
    assert main(["report", str(tmp_path / "none.nc")]) == 1
    assert "does not exist" in capsys.readouterr().err
    path = _campaign("data", tmp_path, known_system_chain)
    (tmp_path / "file").write_text("x")
    assert main(["report", path, "-o", str(tmp_path / "file")]) == 1
    assert "is a file" in capsys.readouterr().err


def test_run_data_refuses_a_study_name_with_data(capsys):
    assert main(["run", "hover", "--data", "x.csv"]) == 1
    assert "drop the study name" in capsys.readouterr().err
    assert main(["run"]) == 1
    assert "--data" in capsys.readouterr().err
