"""TD3 across all tasks (paper section 5): per-task replay buffers and one vmapped update."""

from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import (
    ReplayBuffer,
    Transitions,
    buffer_bytes,
    check_buffer_fits,
    free_memory_bytes,
    init_buffer,
    insert,
    sample,
)

__all__ = [
    "Learner",
    "LearnerState",
    "ReplayBuffer",
    "TD3Config",
    "Transitions",
    "buffer_bytes",
    "check_buffer_fits",
    "free_memory_bytes",
    "init_buffer",
    "insert",
    "sample",
]
