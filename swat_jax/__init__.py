"""swat_jax: structure-aware transformers for multi-morphology RL (Hong et al., ICLR 2022) in JAX.

Importing it changes no JAX setting; ``swat_jax.enable_caches()`` turns on the compilation caches the
commands use.
"""

import os

from swat_jax.compilation_cache import enable_caches

# Rendering is headless by default; MuJoCo reads this once, when it is first imported.
os.environ.setdefault("MUJOCO_GL", "egl")

__version__ = "0.1.0"
__all__ = ["enable_caches"]
