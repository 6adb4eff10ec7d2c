"""JAX's persistent compilation cache, on by default for everything that imports swat_jax.

MJX programs take tens of seconds to compile; the cache makes the second run of any command start
in seconds. The cache lives in ``$SWAT_JAX_CACHE_DIR`` (default ``~/.cache/swat_jax/jax``, per user);
``SWAT_JAX_COMPILATION_CACHE=0`` turns it off. An explicit ``JAX_COMPILATION_CACHE_DIR`` wins.

The cache is keyed by the lowered program, and JAX's in-memory caches of traced functions change how a
program lowers after others in the same process (the training iteration, lowered a second time from a
new ``Experiment``, gains a duplicated helper function): :func:`lower_afresh` lowers the large
programs as a fresh process would, so a second run in one process (tests, notebooks, a resume
on another device layout) finds the first run's programs in the cache.
"""

from __future__ import annotations

import os
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any

DISABLE_VARIABLE = "SWAT_JAX_COMPILATION_CACHE"
DIRECTORY_VARIABLE = "SWAT_JAX_CACHE_DIR"
MIN_COMPILE_SECONDS = 1.0
"""Programs that compile faster than this are not worth a disk entry."""


def cache_directory() -> Path | None:
    """Where compiled programs are cached, or None when the cache is turned off."""
    if os.environ.get(DISABLE_VARIABLE, "1").strip().lower() in ("0", "false", "no", "off"):
        return None
    if "JAX_COMPILATION_CACHE_DIR" in os.environ:
        return Path(os.environ["JAX_COMPILATION_CACHE_DIR"])
    default = Path(os.environ.get("XDG_CACHE_HOME", Path.home() / ".cache")) / "swat_jax" / "jax"
    return Path(os.environ.get(DIRECTORY_VARIABLE, default)).expanduser()


def enable_compilation_cache() -> Path | None:
    """Point JAX at the cache directory (before or after jax is imported); returns it, or None if off."""
    directory = cache_directory()
    if directory is None:
        return None
    settings = {
        "jax_compilation_cache_dir": str(directory),
        "jax_persistent_cache_min_compile_time_secs": MIN_COMPILE_SECONDS,
    }
    for name, value in settings.items():
        if name.upper() in os.environ:
            continue  # the user's JAX_* variable wins
        if "jax" in sys.modules:
            sys.modules["jax"].config.update(name, value)
        else:
            os.environ[name.upper()] = str(value)
    return directory


def lower_afresh(function: Any, *args: Any) -> Any:
    """``function.lower(*args)`` (``function`` a ``jax.jit`` result) after clearing JAX's in-memory trace and
    lowering caches: the ``jax.stages.Lowered`` program, and so its persistent-cache key, is the one a fresh
    process lowers. Callers compile it and hold the result (jitted functions not held are traced again on
    their next call)."""
    return lower_built_afresh(lambda: function, *args)


def lower_built_afresh(build: Callable[[], Any], *args: Any) -> Any:
    """:func:`lower_afresh` of the ``jax.jit`` result ``build()``, built after the caches are cleared: a
    build that traces the same function on the way (``jax.eval_shape`` for its output shardings) leaves
    that trace in the cache for the lowering, so the function is traced once."""
    import jax

    jax.clear_caches()
    return build().lower(*args)


def compiled_at_first_call(function: Any) -> Callable[..., Any]:
    """``function`` (a ``jax.jit`` result) lowered with :func:`lower_afresh` and compiled when first called,
    for the arguments of that call; later calls run that program."""
    compiled = None

    def call(*args: Any) -> Any:
        nonlocal compiled
        if compiled is None:
            compiled = lower_afresh(function, *args).compile()
        return compiled(*args)

    return call
