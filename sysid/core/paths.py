"""Where the FMU sources live and where built artefacts are cached."""

from __future__ import annotations

import os
from pathlib import Path

from sysid.core.errors import FMUError

#: The repository root when sysid runs from a source checkout (``pip install -e .``).
SOURCE_ROOT = Path(__file__).resolve().parents[2]


def fmu_sources_dir() -> Path:
    """The ``fmus/`` folder holding the C sources of the truth FMU and the export template.

    ``SYSID_FMU_SOURCES`` overrides the location.
    """
    candidate = Path(os.environ.get("SYSID_FMU_SOURCES", SOURCE_ROOT / "fmus"))
    if not (candidate / "helicopter").is_dir():
        raise FMUError(
            f"FMU sources not found at {candidate}: install sysid from a source checkout "
            "(pip install -e .) or set SYSID_FMU_SOURCES to the repository's fmus/ folder"
        )
    return candidate


def cache_dir() -> Path:
    """Git-ignored cache for built FMUs and intermediate results.

    ``SYSID_CACHE_DIR`` overrides the default ``~/.cache/sysid``.
    """
    path = Path(os.environ.get("SYSID_CACHE_DIR", Path.home() / ".cache" / "sysid"))
    path.mkdir(parents=True, exist_ok=True)
    return path
