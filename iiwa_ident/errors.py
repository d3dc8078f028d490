"""Exceptions shared by the whole toolkit.

Every error a user can cause (a bad file, an unsafe setting, a refused
experiment) is an :class:`IiwaIdentError`; the CLI prints its message as one
line and exits non-zero, never with a traceback.
"""

__all__ = ["IiwaIdentError", "DatasetError", "PlantError", "SafetyStop"]


class IiwaIdentError(Exception):
    """Base class of all user-facing errors; ``str(err)`` is the one-line message."""


class DatasetError(IiwaIdentError):
    """A dataset file is missing, unreadable or violates the dataset format."""


class PlantError(IiwaIdentError):
    """A plant file or plant parameter is invalid (message names the key)."""


class SafetyStop(IiwaIdentError):
    """An experiment was stopped because a joint limit would have been exceeded."""
