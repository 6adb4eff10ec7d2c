"""The error every config group raises for a value that cannot run, and the check they share.

Each config group lives beside the code it configures (``EnvConfig`` in :mod:`swat_jax.envs.config`,
``NetworkSizes`` in :mod:`swat_jax.networks.config`, the training run's in :mod:`swat_jax.runs.config`), and
each raises :class:`ConfigError`, whose message names the flag and the fix.
"""

from __future__ import annotations

from typing import Any


class ConfigError(ValueError):
    """A configuration that cannot run, or a config file that cannot be read; the message says the fix."""


def is_positive_whole(value: Any) -> bool:
    """Whether ``value`` is an int of at least 1 (a bool is not)."""
    return isinstance(value, int) and not isinstance(value, bool) and value >= 1


def require_positive(flag: str, value: Any) -> None:
    """ConfigError naming ``flag`` unless ``value`` is a whole number of at least 1 (a bool is not)."""
    if not is_positive_whole(value):
        raise ConfigError(f"{flag} must be a positive whole number, got {value!r}")
