"""Print the parameter counts of the paper-sized actor and critic: ``python -m swat_jax.networks``."""

from __future__ import annotations

import jax

from swat_jax.networks.config import network_config
from swat_jax.networks.policies import make_actor_critic, param_count

PLANAR = ("swat", "amorpheus", "smp")
"""The networks of planar bodies; SET takes 3D bodies only."""
SETS = (
    ("Animal-Walkers", 21, 1, PLANAR),
    ("CWHH++", 19, 1, PLANAR),
    ("3D-SGRL", 41, 3, (*PLANAR, "set")),
)
"""(environment set, observation values per limb, actions per limb, the networks that take its bodies)."""


def parameter_table() -> list[tuple[str, int, str, int, int]]:
    """Rows (set, features per limb, network, actor parameters, critic parameters); shapes only, no weights."""
    rows = []
    for set_name, features, motors, networks in SETS:
        for name in networks:
            actor, critic = make_actor_critic(network_config(name), features, motors=motors)
            rng = jax.random.key(0)
            actor_params, critic_params = jax.eval_shape(actor.init, rng), jax.eval_shape(critic.init, rng)
            rows.append((set_name, features, name, param_count(actor_params), param_count(critic_params)))
    return rows


def main() -> None:
    print(f"{'set':<16}{'features':>9}  {'network':<10}{'actor':>10}{'critic':>11}")
    for set_name, features, name, actor, critic in parameter_table():
        print(f"{set_name:<16}{features:>9}  {name:<10}{actor:>10,}{critic:>11,}")


if __name__ == "__main__":
    main()
