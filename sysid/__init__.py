"""Rotorcraft system identification on FMI.

Data flows one way, one stage per module::

    inputs -> fmu / maneuvers -> (time histories) -> spectra -> conditioning
    -> composite -> models / identify -> validate / export / report

Every stage exchanges labelled :mod:`xarray` objects (see ``docs/data_model.md``).
"""

from importlib.metadata import PackageNotFoundError, version as _version

try:
    __version__ = _version("sysid")
except PackageNotFoundError:  # running from a source tree without installation
    __version__ = "0.0.0+source"

from sysid.core.errors import SysidError  # noqa: E402

__all__ = ["SysidError", "__version__"]
