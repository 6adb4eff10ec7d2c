"""swat_jax: structure-aware transformers for multi-morphology RL (Hong et al., ICLR 2022) in JAX."""

from swat_jax.compilation_cache import enable_compilation_cache

enable_compilation_cache()

__version__ = "0.1.0"
