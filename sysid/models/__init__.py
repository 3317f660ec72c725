"""Parametrised linear models with per-entry input delays (paper Eq. 18-19).

``structure`` (Parameter, LinearStructure, the 6-DoF structure, model Dataset <-> structure),
``toml`` (structure files, the built-ins in ``structures/``), ``lti`` (matrices, frequency
response and python-control form of a model Dataset), ``simulation`` (exact zero-order-hold
time response), ``dataset`` (small readers of model Datasets). Everything public is
re-exported here: ``from sysid.models import simulate``.
"""

from sysid.models.dataset import delays_summary, parameter_values
from sysid.models.lti import (frequency_response, model_matrices, residualize_model, statespace,
                              transfer_matrix)
from sysid.models.simulation import discretize, matrix_powers, propagate, simulate
from sysid.models.structure import (ALL_ROWS, DELAY_BOUNDS, FORCE_STATES, LinearStructure,
                                    Parameter, model_from_dataset, parse_tied_entries,
                                    six_dof_structure, structure_summary)
from sysid.models.toml import (STRUCTURES_DIR, builtin_structures, declared_coherence_min,
                               load_structure, structure_from_dict, structure_path)

__all__ = [
    "Parameter",
    "LinearStructure",
    "six_dof_structure",
    "structure_from_dict",
    "load_structure",
    "structure_path",
    "declared_coherence_min",
    "builtin_structures",
    "model_from_dataset",
    "parse_tied_entries",
    "model_matrices",
    "parameter_values",
    "frequency_response",
    "transfer_matrix",
    "statespace",
    "residualize_model",
    "discretize",
    "matrix_powers",
    "propagate",
    "simulate",
    "delays_summary",
    "structure_summary",
    "DELAY_BOUNDS",
    "ALL_ROWS",
    "FORCE_STATES",
    "STRUCTURES_DIR",
]
