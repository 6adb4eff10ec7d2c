"""A stand-in for wandb that keeps what SGRL's trainer logs.

SGRL's logger sends every number it logs to ``wandb.log({name: value}, step=counter)`` and nowhere else (its
TensorBoard writer is commented out). Placed first on the trainer's PYTHONPATH, this module appends each
call's ``performance/`` and ``times/`` values (the returns, lengths and timings; not the losses) as one JSON
line, ``{"step": counter, "time": seconds since the epoch, name: value}``, to the file named by
``$SWAT_JAX_SGRL_LOG``; without it, it records nothing. ``init``, ``finish`` and ``util.generate_id`` do what
SGRL needs of them and nothing else (no network, no files).
"""

import json
import os
import time
import types
import uuid

KEPT = ("performance/", "times/")
"""Prefixes of the logged names that are recorded."""

util = types.SimpleNamespace(generate_id=lambda: uuid.uuid4().hex[:8])


def init(*args, **kwargs):
    return None


def finish(*args, **kwargs):
    return None


def log(data, step=None, **kwargs):
    """Append ``data``'s recorded values at ``step`` to ``$SWAT_JAX_SGRL_LOG``."""
    path = os.environ.get("SWAT_JAX_SGRL_LOG")
    kept = {name: float(value) for name, value in data.items() if name.startswith(KEPT)}
    if path and kept:
        with open(path, "a") as file:
            file.write(json.dumps({"step": step, "time": time.time(), **kept}) + "\n")
