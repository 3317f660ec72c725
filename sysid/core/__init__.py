"""The foundation every other layer may import, which imports nothing of the package.

``core`` owns what is defined once and shared by every stage: the error types
(:mod:`~sysid.core.errors`); units, channels and the one unit table that also writes the
FMUs' unit definitions (:mod:`~sysid.core.units`); every identification and verification
guideline with its literature source (:mod:`~sysid.core.guidelines`); rigid-body kinematics
of the derivative tables (:mod:`~sysid.core.kinematics`); the package's folders and cache
(:mod:`~sysid.core.paths`); and small helpers such as atomic writes and progress lines
(:mod:`~sysid.core.util`).
"""
