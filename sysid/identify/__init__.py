"""Parametric identification: frequency-domain output error (CIFER-style), time-domain
maximum-likelihood output error, accuracy statistics
(Cramer-Rao bounds, insensitivities, correlations) and stepwise model reduction.

The statistics and reduction modules are generic over the fit so that the time-domain
output-error fit reuses them.
"""

from sysid.identify.frequency_domain import (
    DEFAULT_PAIRS,
    FitData,
    FrequencyFitResult,
    cifer_cost,
    coherence_weight,
    equation_error_start,
    identify_frequency_domain,
    parse_pairs,
    select_fit_data,
)
from sysid.identify.reduction import (
    GUIDELINES,
    FitOutcome,
    ReductionResult,
    ReductionStep,
    stepwise_reduction,
)
from sysid.identify.statistics import ParameterStatistics, correlated_pairs, parameter_statistics
from sysid.identify.time_domain import (MAX_COST_INCREASE, OutputErrorModel, TimeFitResult,
                                        identify_time_domain)
from sysid.identify.filter_error import FilterErrorResult, identify_filter_error  # noqa: F401

__all__ = [
    "DEFAULT_PAIRS",
    "FitData",
    "FrequencyFitResult",
    "cifer_cost",
    "coherence_weight",
    "equation_error_start",
    "identify_frequency_domain",
    "parse_pairs",
    "select_fit_data",
    "GUIDELINES",
    "FitOutcome",
    "ReductionResult",
    "ReductionStep",
    "stepwise_reduction",
    "ParameterStatistics",
    "correlated_pairs",
    "parameter_statistics",
    "MAX_COST_INCREASE",
    "OutputErrorModel",
    "TimeFitResult",
    "identify_time_domain",
]
