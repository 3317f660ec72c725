"""The study's time-domain part by filter error (``StudySettings.time_domain_method``,
``sysid run --time-domain-method filter-error``) on a reduced hover campaign flown on the
truth FMU: the whole chain runs, the model stored as /models/time_domain is the reduced
filter-error model, and it is verified and scored like output error's."""

import pytest

from sysid.assess.metrics import J_RMS_GUIDELINE
from sysid.core.errors import SysidError
from sysid.pipeline.batch import quick_campaign
from sysid.pipeline.study import StudySettings, run_study, study_tree


@pytest.mark.fmu
def test_study_time_domain_part_by_filter_error(tmp_path):
    toml = tmp_path / "campaign.toml"
    toml.write_text(quick_campaign(0.0, noise=True, seed=3).to_toml())
    settings = StudySettings(campaign_file=str(toml), quick=True,
                             time_domain_method="filter_error")
    run_study(tmp_path / "out", settings, quiet=True)
    tree = study_tree(tmp_path / "out")
    model = tree["models/time_domain"].to_dataset()
    assert model.attrs["method"] == "filter_error"
    assert "cramer_rao_corrected" in model and "innovation_covariance" in model
    assert model.attrs["reduction"] == 1  # reduced as output error's model is
    for name, child in tree["verification"].children.items():
        j = float(child.to_dataset()["j_rms"].sel(source="time_domain"))
        assert j <= J_RMS_GUIDELINE, (name, j)
    table = tree["comparison"].to_dataset()
    assert "time_domain" in [str(m) for m in table.model.values]


def test_unknown_time_domain_method_is_named(tmp_path):
    toml = tmp_path / "campaign.toml"
    toml.write_text(quick_campaign(0.0, noise=True, seed=3).to_toml())
    settings = StudySettings(campaign_file=str(toml), quick=True,
                             time_domain_method="kalman")
    with pytest.raises(SysidError, match=r"time_domain_method 'kalman': expected one of "
                                         r"\('output_error', 'filter_error'\)"):
        run_study(tmp_path / "out", settings, quiet=True, parts=("data", "time_domain"))
