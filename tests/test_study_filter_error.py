"""The study's time-domain estimator (``StudySettings.time_domain_method``, ``sysid run
--time-domain-method``): filter error by default, output error for quick studies or on
request, anything else refused by name. The default study's filter-error model itself is
checked on the session's hover study (tests/test_hover_study.py)."""

import pytest

from sysid.core.errors import SysidError
from sysid.pipeline.batch import quick_campaign
from sysid.pipeline.study import StudySettings, run_study


def test_default_estimator_is_filter_error_and_output_error_when_quick():
    assert StudySettings().time_domain_estimator == "filter_error"
    assert StudySettings(quick=True).time_domain_estimator == "output_error"
    assert StudySettings(time_domain_method="output_error").time_domain_estimator \
        == "output_error"
    assert StudySettings(quick=True, time_domain_method="filter_error").time_domain_estimator \
        == "filter_error"


def test_unknown_time_domain_method_is_named(tmp_path):
    toml = tmp_path / "campaign.toml"
    toml.write_text(quick_campaign(0.0, noise=True, seed=3).to_toml())
    settings = StudySettings(campaign_file=str(toml), quick=True,
                             time_domain_method="kalman")
    with pytest.raises(SysidError, match=r"time_domain_method 'kalman': expected one of "
                                         r"\('output_error', 'filter_error'\) or 'auto'"):
        run_study(tmp_path / "out", settings, quiet=True, parts=("data", "time_domain"))
