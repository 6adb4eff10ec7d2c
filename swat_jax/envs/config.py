"""How a run's bodies are simulated and observed: :class:`EnvConfig`, the ``--envs.*`` flags."""

from __future__ import annotations

import dataclasses

from swat_jax.envs.physics import PHYSICS, Physics
from swat_jax.errors import ConfigError, require_positive
from swat_jax.morphology.variants import Variation


@dataclasses.dataclass(frozen=True)
class EnvConfig:
    """How the bodies are simulated and observed (``--envs.*``)."""

    copies: int = 1
    """Parallel environment copies per body."""
    variants: int = 0
    """Train on variants: copy j of each body runs variant j mod K of K variants drawn from it (its limbs' lengths, radii, masses, joint ranges, damping and gears scaled; docs/bodies-and-environments.md), fixed for the run, all through one program per body; at most --envs.copies. 0: the bodies themselves."""
    variation: float = 0.2
    """With --envs.variants: spread of the variants' factors, each uniform in [1 - variation, 1 + variation]; in [0, 1)."""
    variant_seed: int = 0
    """With --envs.variants: seed of the variants' draw (python -m swat_jax.morphology variants BODY -k K --variation X --seed S writes the same bodies)."""
    physics: Physics = "auto"
    """Where the physics runs: c (MuJoCo's C library, called from the jitted program: nothing to compile, the fastest on a CPU), jax (MJX compiled into the XLA program: for GPUs), warp (MuJoCo Warp kernels called from it; needs pip install -e '.[warp]'), or auto: c where JAX runs on the CPU, jax on a GPU (docs/training.md, "Physics")."""
    torso_relative_x: bool = False
    """Limb x relative to the torso, as the paper intends (the fast preset); off (the paper preset) reproduces the original code's quirk: the torso reads x = 0, every other limb its world x, and the torso's linear velocity is that of the point (0, y, z) (docs/fidelity.md)."""
    shared_reset_key: bool = False
    """Every body of a seed draws its resets from one random key, so copy j of every body starts its episodes from the same random numbers, as the original code seeds every body's environment with the run's seed (docs/fidelity.md, row 39); off (both presets): a key per body."""
    stale_kinematics: bool = True
    """Observe the positions, orientations and sites that MuJoCo's step leaves (the last integrator stage's), with velocities from them and the new qvel, as the original code does (the paper preset; needs --envs.physics jax, c or auto); off: kinematics of the state after the step (the fast preset)."""

    def __post_init__(self) -> None:
        require_positive("--envs.copies", self.copies)
        if not 0 <= self.variants <= self.copies:
            raise ConfigError(
                f"--envs.variants must be 0 (off) or a number up to --envs.copies ({self.copies}): each copy "
                f"runs one variant; got {self.variants}"
            )
        try:
            self.variant_draw()
        except ValueError:
            raise ConfigError(
                f"--envs.variation must lie in [0, 1) (factors stay positive), got {self.variation}"
            ) from None
        if self.physics not in PHYSICS:
            raise ConfigError(f"--envs.physics must be one of {', '.join(PHYSICS)}, got {self.physics!r}")
        if self.variants and self.physics == "warp":
            raise ConfigError(
                "--envs.variants runs on --envs.physics c, jax or auto (the variants' numbers are inputs of "
                "the step; Warp's model is not)"
            )
        if self.stale_kinematics and self.physics == "warp":
            raise ConfigError(
                "--envs.stale-kinematics reads what MuJoCo's step leaves, which Warp does not keep; add "
                "--envs.no-stale-kinematics or use --envs.physics c, jax or auto"
            )

    def variant_draw(self) -> Variation:
        """How the run's variants are drawn (--envs.variation, --envs.variant-seed); ValueError for a bad spread."""
        return Variation(self.variation, self.variant_seed)
