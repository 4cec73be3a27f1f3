"""The project's own exceptions.

Every error that a user can cause (a bad config, a malformed log, an ill-posed
computation) is raised as an `AmbidError` subclass that names the file, key or
line at fault, so the workflow fails with a message a machine engineer can act on.
"""

__all__ = ["AmbidError", "ConfigError", "ModelError", "LogError", "settings_from_mapping"]


class AmbidError(Exception):
    """Base class of all errors raised by ambid."""


class ConfigError(AmbidError):
    """An inconsistent or invalid configuration.

    Parameters
    ----------
    key : str
        Dotted path of the offending key, e.g. ``machines.hs_eden_like.rotor.elements[3].length_m``.
    message : str
        What is wrong with it.
    source : str, optional
        The file the key came from.
    """

    def __init__(self, key, message, source=None):
        self.key = key
        self.message = message
        self.source = source
        where = f"{source}: " if source else ""
        super().__init__(f"{where}{key}: {message}")

    def __reduce__(self):  # picklable with its arguments (errors cross process pools)
        return (ConfigError, (self.key, self.message, self.source))

    def within(self, prefix=None, source=None):
        """The same error with its key nested under ``prefix`` and/or its file set."""
        key = f"{prefix}.{self.key}" if prefix and not self.key.startswith(prefix) else self.key
        return ConfigError(key, self.message, source=source or self.source)


class ModelError(AmbidError):
    """A model that cannot be evaluated (singular, unstable where stability is required, ...)."""


class LogError(AmbidError):
    """A malformed measurement log (identification or calibration).

    Parameters
    ----------
    source : str
        The file (or other origin) of the log, quoted first in the message.
    message : str
        What is wrong, naming the offending rows, e.g.
        ``rows 12-15 (excited_axis=DX, step=3): noise_std < 0``.
    """

    def __init__(self, source, message):
        self.source = source
        self.message = message
        super().__init__(f"{source}: {message}")

    def __reduce__(self):  # picklable with its arguments (errors cross process pools)
        return (type(self), (self.source, self.message))



def settings_from_mapping(cls, mapping, section):
    """A frozen settings dataclass from a config section; unknown keys raise naming ``section.key``.

    Lists become tuples (the dataclasses are frozen and hashable).
    """
    unknown = set(mapping) - set(cls.__dataclass_fields__)
    if unknown:
        raise ConfigError(f"{section}.{sorted(unknown)[0]}", "unknown setting")
    return cls(**{key: tuple(value) if isinstance(value, list) else value for key, value in mapping.items()})
