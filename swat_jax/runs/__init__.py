"""Training runs: the frozen config and presets, the run directory's checkpoints and metrics, and the
experiment a config builds (the train/eval/export commands are swat_jax/train.py, eval.py, export.py)."""

from swat_jax.runs.checkpoint import CheckpointError, CheckpointInfo, Checkpoints
from swat_jax.runs.config import PRESETS, ConfigError, EnvConfig, NetworkSizes, TrainConfig, load_config
from swat_jax.runs.experiment import Experiment
from swat_jax.runs.trained import TrainedPolicy, load_policy

__all__ = [
    "PRESETS",
    "CheckpointError",
    "CheckpointInfo",
    "Checkpoints",
    "ConfigError",
    "EnvConfig",
    "Experiment",
    "NetworkSizes",
    "TrainConfig",
    "TrainedPolicy",
    "load_config",
    "load_policy",
]
