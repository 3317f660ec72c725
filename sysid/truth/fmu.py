"""The truth helicopter FMU as the default model of the truth layer.

:func:`load_fmu` loads any FMU through :func:`sysid.fmi.runtime.load_fmu` and, given no
path, the truth helicopter built from ``fmus/helicopter`` (cached by source hash): the
default lives here so that :mod:`sysid.fmi` knows nothing of the truth model.
"""

from __future__ import annotations

import os

from sysid.fmi import runtime
from sysid.fmi.build import build_fmu
from sysid.fmi.runtime import FMUModel

__all__ = ["load_fmu"]


def load_fmu(path: str | os.PathLike | None = None) -> FMUModel:
    """Load an FMU (default: the truth helicopter, built on first use).

    Raises :class:`~sysid.core.errors.FMUError` with a one-line message naming the file if
    it is missing, not an FMU archive, hostile, not FMI 2.0 with both interfaces, or lacks a
    binary for this platform (see :func:`sysid.fmi.runtime.load_fmu`).
    """
    return runtime.load_fmu(build_fmu() if path is None else path)
