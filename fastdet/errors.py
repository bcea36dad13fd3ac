"""Exceptions that carry a one-line message meant for the user.

The command line prints ``fastdet: error: <message>`` for any of these and
exits non-zero; library users can catch :class:`FastdetError`.
"""


class FastdetError(Exception):
    """Base of every error fastdet reports to its user."""


class InputError(FastdetError, ValueError):
    """An image, video, array or path that fastdet cannot use."""


class ModelError(FastdetError, ValueError):
    """A model file that is missing, corrupt, tampered with or inconsistent."""


class ConfigError(FastdetError, ValueError):
    """An invalid configuration file or value."""


class MissingExtraError(FastdetError, ImportError):
    """An optional part of fastdet whose extra (``pip install 'fastdet[...]'``) is not installed."""
