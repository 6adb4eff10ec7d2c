"""Measurements in a fresh Python process: the one way the scripts here start one.

A measurement often needs a process of its own: its compilation, memory peak and cache state its own, a
cold cache directory, or other XLA flags (fake devices). :func:`in_fresh_process` runs a :class:`Job`, a
call of a top-level function of this package with JSON arguments, as

    python -m experiments.workers MODULE:FUNCTION ARGUMENTS_JSON

which turns the caches on as every command does (``swat_jax.enable_caches``: the environment given to
the process decides where they are, or that they are off) and prints the function's JSON result as the
last line of its standard output.
"""

from __future__ import annotations

import dataclasses
import importlib
import json
import subprocess
import sys
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

REPOSITORY = Path(__file__).resolve().parents[1]
"""Where ``python -m experiments...`` finds this package."""
OUT_OF_MEMORY_MARKERS = ("RESOURCE_EXHAUSTED", "Out of memory", "out of memory")
ERROR_LINES = 15
"""Lines of a failed worker's standard error quoted in its WorkerError."""


class WorkerError(RuntimeError):
    """A worker process failed or was not run; ``out_of_memory`` tells an allocation failure, ``timed_out``
    a run stopped (or not started) for lack of time, from other errors."""

    def __init__(self, message: str, out_of_memory: bool = False, timed_out: bool = False):
        super().__init__(message)
        self.out_of_memory = out_of_memory
        self.timed_out = timed_out


@dataclasses.dataclass(frozen=True)
class Job:
    """``function(**arguments)`` to call in a fresh process: a top-level function of a module of this
    package (or of the script run with ``python -m``), JSON arguments, a JSON result."""

    function: Callable[..., Any]
    arguments: dict[str, Any] = dataclasses.field(default_factory=dict)

    @property
    def target(self) -> str:
        """``module:function``; a function of the script that runs as ``__main__`` by its module name."""
        module = self.function.__module__
        if module == "__main__":
            module = sys.modules["__main__"].__spec__.name
        return f"{module}:{self.function.__qualname__}"

    def command(self) -> list[str]:
        return [sys.executable, "-m", "experiments.workers", self.target, json.dumps(self.arguments)]

    def __str__(self) -> str:
        return f"{self.target}({', '.join(f'{k}={v!r}' for k, v in self.arguments.items())})"


def in_fresh_process(
    job: Job, environment: dict[str, str] | None = None, timeout: float | None = None
) -> Any:
    """``job``'s result, computed in a fresh Python process (with ``environment``, default this one's),
    stopped after ``timeout`` seconds; WorkerError if it fails or runs out of time."""
    try:
        completed = subprocess.run(
            job.command(),
            capture_output=True,
            text=True,
            cwd=REPOSITORY,
            env=environment,
            check=False,
            timeout=timeout,
        )
    except subprocess.TimeoutExpired as error:
        raise WorkerError(f"worker {job} stopped after {timeout:.0f} s", timed_out=True) from error
    if completed.returncode != 0:
        tail = "\n".join(completed.stderr.strip().splitlines()[-ERROR_LINES:])
        out_of_memory = any(marker in completed.stderr for marker in OUT_OF_MEMORY_MARKERS)
        raise WorkerError(f"worker {job} failed (exit {completed.returncode}):\n{tail}", out_of_memory)
    return json.loads(completed.stdout.strip().splitlines()[-1])


def main(argv: Sequence[str] | None = None) -> None:
    """Run ``MODULE:FUNCTION`` with the JSON keyword arguments; print its result as one JSON line."""
    from swat_jax.compilation_cache import enable_caches

    enable_caches()
    target, arguments = argv if argv is not None else sys.argv[1:]
    module, name = target.split(":")
    result = getattr(importlib.import_module(module), name)(**json.loads(arguments))
    print(json.dumps(result), flush=True)


if __name__ == "__main__":
    main()
