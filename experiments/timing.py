"""Wall-clock timing of jitted calls, the one timer of every benchmark here."""

from __future__ import annotations

import statistics
import time
from collections.abc import Callable
from typing import Any

import jax


def median_seconds(run: Callable[[], Any], repeats: int) -> float:
    """Median wall time of ``run()`` over ``repeats`` calls after one warm-up (compiling) call, each call's
    outputs waited for (``jax.block_until_ready``)."""
    jax.block_until_ready(run())
    times = []
    for _ in range(repeats):
        start = time.perf_counter()
        jax.block_until_ready(run())
        times.append(time.perf_counter() - start)
    return statistics.median(times)


def first_call_seconds(run: Callable[[], Any]) -> float:
    """Wall time of ``run()``'s first call, its outputs waited for (tracing and compilation included)."""
    start = time.perf_counter()
    jax.block_until_ready(run())
    return time.perf_counter() - start
