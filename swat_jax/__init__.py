"""swat_jax: structure-aware transformers for multi-morphology RL (Hong et al., ICLR 2022) in JAX."""

import os

from swat_jax.compilation_cache import enable_compilation_cache

enable_compilation_cache()
# Rendering is headless by default; MuJoCo reads this once, when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
