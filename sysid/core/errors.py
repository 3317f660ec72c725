"""Exceptions raised for bad input.

Every error the user can cause (a missing channel, NaN, a broken FMU, a diverging simulation)
is raised as a :class:`SysidError` subclass whose message names what was wrong, where, and
what was expected. The command line prints the message on one line instead of a traceback.
"""


class SysidError(Exception):
    """Base class of all errors caused by user input or by the modelled system."""


class InputDataError(SysidError, ValueError):
    """Time histories, spectra or files that are malformed (missing channel, NaN, bad grid)."""


class FMUError(SysidError):
    """An FMU that cannot be built, loaded or run (corrupted archive, missing compiler...)."""


class SimulationDiverged(SysidError):
    """A simulation left its physical envelope; carries the manoeuvre name and time."""

    def __init__(self, message, *, maneuver=None, time=None):
        super().__init__(message)
        self.maneuver = maneuver
        self.time = time


class IdentificationError(SysidError):
    """A fit that cannot be posed or did not converge (e.g. no coherent frequency range)."""
