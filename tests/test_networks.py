"""Actor and critic networks: padding invariance, structure sensitivity, relational bias per head,
SMP message passing, gradients, compile counts and vmap over tasks (swat_jax.networks)."""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from swat_jax.morphology import (
    RELATION_NAMES,
    TRAVERSAL_NAMES,
    StructureBatch,
    load,
    pad_structures,
    relation_features,
    traversal_positions,
)
from swat_jax.networks import (
    NAMED_VARIANTS,
    StructureMismatch,
    check_structures,
    make_actor_critic,
    network_config,
    param_count,
)
from swat_jax.networks.smp import child_slot_matrix, most_children, parent_messages
from swat_jax.networks.transformer import traversal_embedding_widths

SMALL = {
    "width": 16,
    "heads": 2,
    "layers": 2,
    "feedforward": 32,
    "max_traversal_positions": 16,
    "decoder_hidden": (16,),
    "message_width": 8,
    "up_hidden": (16, 16),
    "down_hidden": (16, 16),
}
ARCHITECTURES = ("swat", "amorpheus", "smp")
FEATURES = 19
BATCH = 2
BODIES = ("humanoid_2d_9_full", "nervenet_ostrich", "hopper_3")
"""Two bodies of 9 limbs (different trees) and one of 3."""


class Traced:
    """A jitted function that counts how often JAX traces it."""

    def __init__(self, function: Callable[..., Any]) -> None:
        self.traces = 0
        self._function = function
        self._jitted = jax.jit(self._counted)

    def _counted(self, *args: Any) -> Any:
        self.traces += 1
        return self._function(*args)

    def __call__(self, *args: Any) -> Any:
        return self._jitted(*args)


@dataclasses.dataclass(frozen=True)
class Bundle:
    """A small actor and critic, their parameters and their task-vmapped jitted applies."""

    actor: Any
    critic: Any
    actor_params: Any
    critic_params: Any
    act: Traced
    """(params, obs [K, B, L, F], structures) -> actions [K, B, L]."""
    criticize: Traced
    """(params, obs [K, B, L, F], actions [K, B, L], structures) -> (q1, q2)."""


def make_bundle(name: str, **overrides: Any) -> Bundle:
    actor, critic = make_actor_critic(network_config(name, **{**SMALL, **overrides}), FEATURES)
    return Bundle(
        actor=actor,
        critic=critic,
        actor_params=actor.init(jax.random.key(1)),
        critic_params=critic.init(jax.random.key(2)),
        act=Traced(jax.vmap(actor.apply, in_axes=(None, 0, 0))),
        criticize=Traced(jax.vmap(critic.apply, in_axes=(None, 0, 0, 0))),
    )


@pytest.fixture(scope="module")
def bundles() -> dict[str, Bundle]:
    return {name: make_bundle(name) for name in ARCHITECTURES}


@pytest.fixture(scope="module")
def bodies() -> list:
    return [load(name) for name in BODIES]


@pytest.fixture(scope="module")
def structures9(bodies) -> StructureBatch:
    return pad_structures(bodies, 9)


@pytest.fixture(scope="module")
def structures13(bodies) -> StructureBatch:
    return pad_structures(bodies, 13)


def structure_from_parents(parents: tuple[int, ...], max_limbs: int) -> StructureBatch:
    """One body's slice (no task axis) for a tree given only by its parents."""
    n = len(parents)
    pad = max_limbs - n
    return StructureBatch(
        limb_mask=np.arange(max_limbs) < n,
        parents=np.array(list(parents) + [-1] * pad, np.int32),
        traversal_positions=np.pad(traversal_positions(parents), ((0, pad), (0, 0))),
        relations=np.pad(relation_features(parents), ((0, pad), (0, pad), (0, 0))),
        limb_types=np.full(max_limbs, -1, np.int32),
        motor_mask=np.zeros((max_limbs, 1), bool),
        num_limbs=np.int32(n),
    )


def task(structures: StructureBatch, index: int) -> StructureBatch:
    return jax.tree.map(lambda array: array[index], structures)


def random_inputs(seed: int, structures: StructureBatch, batch: int = BATCH) -> tuple[np.ndarray, np.ndarray]:
    """Observations [K, B, L, F] and actions [K, B, L]: unit noise on real limbs, zero on padding."""
    rng = np.random.default_rng(seed)
    tasks, limbs = structures.limb_mask.shape
    mask = structures.limb_mask[:, None, :]
    obs = rng.normal(size=(tasks, batch, limbs, FEATURES)).astype(np.float32) * mask[..., None]
    actions = rng.uniform(-1, 1, size=(tasks, batch, limbs)).astype(np.float32) * mask
    return obs, actions


def with_garbage(seed: int, obs: np.ndarray, actions: np.ndarray, structures: StructureBatch):
    """The same inputs with large random values on every padded limb."""
    rng = np.random.default_rng(seed)
    padding = ~structures.limb_mask[:, None, :]
    obs = obs + 100 * rng.normal(size=obs.shape).astype(np.float32) * padding[..., None]
    actions = actions + 100 * rng.normal(size=actions.shape).astype(np.float32) * padding
    return obs, actions


# Configuration


def test_named_variants_change_only_their_fields():
    swat = network_config("swat")
    assert swat.traversals == TRAVERSAL_NAMES and swat.relations == RELATION_NAMES
    assert (swat.width, swat.heads, swat.layers, swat.feedforward) == (128, 2, 3, 256)
    assert not swat.relation_bias_in_every_layer
    assert network_config("swat_no_pe").traversals == () and network_config("swat_no_pe").relations
    assert network_config("swat_no_re").relations == () and network_config("swat_no_re").traversals
    amorpheus = network_config("amorpheus")
    assert (amorpheus.architecture, amorpheus.traversals, amorpheus.relations) == ("amorpheus", (), ())
    assert network_config("smp").architecture == "smp"
    assert network_config("swat", width=64, traversals=["pre"]).traversals == ("pre",)


@pytest.mark.parametrize(
    ("name", "overrides", "message"),
    [
        ("transformer", {}, "valid names: swat, amorpheus, smp, swat_no_pe, swat_no_re, swat_no_pe_re"),
        ("swat", {"depth": 3}, "unknown NetworkConfig fields"),
        ("swat", {"width": 0}, "width must be a positive integer"),
        ("swat", {"width": 15}, "divisible by heads"),
        ("swat", {"traversals": ("pre", "level")}, "unknown ['level']"),
        ("swat", {"relations": ("spd", "spd")}, "twice"),
        ("swat", {"traversals": "pre"}, "must be a tuple"),
        ("swat", {"architecture": "gnn"}, "architecture must be one of"),
        ("amorpheus", {"relations": ("spd",)}, "AMORPHEUS has no structural embeddings"),
        ("smp", {"down_hidden": (64, -1)}, "every entry of down_hidden"),
    ],
)
def test_invalid_configs_fail_clearly(name, overrides, message):
    with pytest.raises(ValueError) as error:
        network_config(name, **overrides)
    assert message in str(error.value)


def test_traversal_tables_split_the_width_as_the_original_code():
    assert traversal_embedding_widths(128, 3) == (42, 42, 44)
    assert traversal_embedding_widths(16, 2) == (8, 8)
    assert traversal_embedding_widths(7, 1) == (7,)


def test_paper_sized_parameter_counts_differ_by_the_structural_embeddings():
    counts = {}
    for name in ("swat", "amorpheus", "swat_no_pe", "swat_no_re"):
        actor, critic = make_actor_critic(network_config(name), 21)
        shapes = (jax.eval_shape(network.init, jax.random.key(0)) for network in (actor, critic))
        counts[name] = tuple(param_count(params) for params in shapes)
    traversal_tables = 15 * 128
    relation_map = 3 * 2
    assert counts["swat"][0] - counts["amorpheus"][0] == traversal_tables + relation_map
    assert counts["swat"][0] - counts["swat_no_pe"][0] == traversal_tables
    assert counts["swat"][0] - counts["swat_no_re"][0] == relation_map
    assert counts["swat"][1] - counts["amorpheus"][1] == 2 * (traversal_tables + relation_map)


def test_check_structures_refuses_bodies_the_config_cannot_take(structures13):
    check_structures(network_config("swat"), structures13)
    check_structures(network_config("smp"), structures13)
    with pytest.raises(StructureMismatch, match="body 0 has 9 limbs, more than the 8 positions") as raised:
        check_structures(network_config("swat", max_traversal_positions=8), structures13)
    assert (raised.value.setting, raised.value.needed) == ("max_traversal_positions", 9)
    names = [f"walker_{index}" for index in range(len(structures13.limb_mask))]
    with pytest.raises(StructureMismatch, match="with 4 children, more than SMP's 3 child slots") as raised:
        check_structures(network_config("smp", max_children=3), structures13, names)
    assert str(raised.value).startswith("walker_")
    assert (raised.value.setting, raised.value.needed) == ("max_children", 4)


# Padding and structure


@pytest.mark.parametrize("name", ARCHITECTURES)
def test_real_limbs_ignore_padding_contents_and_padding_width(name, bundles, structures9, structures13):
    bundle = bundles[name]
    obs13, actions13 = random_inputs(0, structures13)
    obs9, actions9 = obs13[:, :, :9], actions13[:, :, :9]
    obs13, actions13 = with_garbage(1, obs13, actions13, structures13)
    obs9, actions9 = with_garbage(2, obs9, actions9, structures9)

    outputs13 = [bundle.act(bundle.actor_params, obs13, structures13)]
    outputs13 += bundle.criticize(bundle.critic_params, obs13, actions13, structures13)
    outputs9 = [bundle.act(bundle.actor_params, obs9, structures9)]
    outputs9 += bundle.criticize(bundle.critic_params, obs9, actions9, structures9)

    mask9 = np.broadcast_to(structures9.limb_mask[:, None, :], outputs9[0].shape)
    for wide, narrow in zip(outputs13, outputs9, strict=True):
        wide, narrow = np.asarray(wide), np.asarray(narrow)
        np.testing.assert_allclose(wide[..., :9][mask9], narrow[mask9], atol=1e-5)
        assert (
            np.all(wide[..., :9][~mask9] == 0) and np.all(wide[..., 9:] == 0) and np.all(narrow[~mask9] == 0)
        )
    assert np.all(np.abs(outputs9[0]) <= 1)


def permute_limbs(structures: StructureBatch, order: np.ndarray) -> StructureBatch:
    """Reorder the limbs of every per-limb array (parents are left alone: the transformer ignores them)."""
    return structures._replace(
        limb_mask=structures.limb_mask[:, order],
        traversal_positions=structures.traversal_positions[:, order],
        relations=structures.relations[:, order][:, :, order],
    )


def test_amorpheus_is_permutation_equivariant_over_limbs(bundles, structures9):
    bundle = bundles["amorpheus"]
    obs, actions = random_inputs(3, structures9)
    order = np.random.default_rng(4).permutation(9)
    permuted = permute_limbs(structures9, order)

    actions_out = bundle.act(bundle.actor_params, obs, structures9)
    permuted_out = bundle.act(bundle.actor_params, obs[:, :, order], permuted)
    np.testing.assert_allclose(permuted_out, np.asarray(actions_out)[..., order], atol=1e-5)
    q_values = bundle.criticize(bundle.critic_params, obs, actions, structures9)
    permuted_q = bundle.criticize(bundle.critic_params, obs[:, :, order], actions[:, :, order], permuted)
    for q, q_permuted in zip(q_values, permuted_q, strict=True):
        np.testing.assert_allclose(q_permuted, np.asarray(q)[..., order], atol=1e-5)


def swap_first_two_bodies(structures: StructureBatch) -> StructureBatch:
    """The structures of tasks 0 and 1 exchanged (both have 9 limbs, so the masks stay the same)."""
    order = np.array([1, 0, *range(2, structures.limb_mask.shape[0])])
    return jax.tree.map(lambda array: array[order], structures)


@pytest.mark.parametrize(("name", "sees_structure"), [("swat", True), ("amorpheus", False)])
def test_only_swat_sees_the_structure(name, sees_structure, bundles, structures9):
    bundle = bundles[name]
    assert structures9.num_limbs[0] == structures9.num_limbs[1] == 9
    obs, _ = random_inputs(5, structures9)
    original = np.asarray(bundle.act(bundle.actor_params, obs, structures9))
    swapped = np.asarray(bundle.act(bundle.actor_params, obs, swap_first_two_bodies(structures9)))
    difference = np.abs(original[:2] - swapped[:2]).max()
    if sees_structure:
        assert difference > 1e-3
    else:
        assert difference < 1e-6


# Relational bias (eq. 5)


@pytest.mark.parametrize("every_layer", [False, True])
def test_relational_bias_reaches_its_head(every_layer, structures13):
    """g = -1e4 * SPD on head 1 only: head 1 attends to itself alone, head 0 does not."""
    actor, _ = make_actor_critic(
        network_config("swat", **SMALL, relation_bias_in_every_layer=every_layer), FEATURES
    )
    params = actor.init(jax.random.key(0))
    g = np.zeros((len(RELATION_NAMES), 2), np.float32)
    g[RELATION_NAMES.index("spd"), 1] = -1e4
    params["params"]["policy"]["relational_embedding"]["g"]["kernel"] = jnp.asarray(g)

    structure = task(structures13, 1)
    obs, _ = random_inputs(6, structures13)
    _, state = actor.apply(params, obs[1], structure, mutable=["intermediates"])
    real = np.flatnonzero(structure.limb_mask)
    padding = np.flatnonzero(~structure.limb_mask)
    assert real.size == 9 and padding.size == 4
    layers = state["intermediates"]["policy"]
    for layer in range(SMALL["layers"]):
        (weights,) = layers[f"layer_{layer}"]["attention"]["attention_weights"]
        weights = np.asarray(weights)  # [batch, heads, limbs, limbs]
        assert np.all(weights[..., padding] == 0), "padded limbs must get no attention"
        head0, head1 = weights[:, 0][:, real][:, :, real], weights[:, 1][:, real][:, :, real]
        identity = np.broadcast_to(np.eye(real.size), head1.shape)
        assert np.abs(head0 - identity).max() > 0.1
        biased = layer == 0 or every_layer
        assert (np.abs(head1 - identity).max() < 1e-5) == biased


# SMP


def test_child_slots_follow_pre_order_and_skip_padding():
    parents = np.array([-1, 0, 1, 0, 3, 0, 5, 0, 7, -1, -1], np.int32)  # humanoid_2d_9_full + 2 padded
    mask = np.arange(11) < 9
    slots = np.asarray(child_slot_matrix(jnp.asarray(parents), jnp.asarray(mask), 4))
    assert slots.shape == (11, 4, 11)
    for parent, children in {0: [1, 3, 5, 7], 1: [2], 3: [4], 5: [6], 7: [8]}.items():
        expected = np.zeros((4, 11))
        expected[np.arange(len(children)), children] = 1
        np.testing.assert_array_equal(slots[parent], expected)
    assert slots[[2, 4, 6, 8, 9, 10]].sum() == 0
    assert most_children(parents) == 4


def test_each_child_reads_its_own_slot_of_the_parent_message():
    config = network_config("smp", message_width=2, max_children=4)
    parents = np.array([-1, 0, 0, 0, 2], np.int32)
    slots = child_slot_matrix(jnp.asarray(parents), jnp.ones(5, bool), 4)
    down = np.arange(5 * 4 * 2, dtype=np.float32).reshape(1, 5, 8) + 1  # [batch, limbs, slots * width]
    received = np.asarray(parent_messages(jnp.asarray(down), slots, config))[0]
    np.testing.assert_array_equal(received[0], [0, 0])  # the torso has no parent
    for limb, (parent, slot) in {1: (0, 0), 2: (0, 1), 3: (0, 2), 4: (2, 0)}.items():
        np.testing.assert_array_equal(received[limb], down[0, parent, 2 * slot : 2 * slot + 2])


@pytest.fixture(scope="module")
def smp_dependency(bundles) -> Callable[[StructureBatch], np.ndarray]:
    """dependency[i, j]: whether the actor's output on limb i changes with limb j's input."""
    bundle = bundles["smp"]

    @jax.jit
    def jacobian(obs: jax.Array, structure: StructureBatch) -> jax.Array:
        def actions(limb_obs):
            return bundle.actor.apply(bundle.actor_params, limb_obs[None], structure)[0]

        return jax.jacrev(actions)(obs)  # [limbs, limbs, features]

    def dependency(structure: StructureBatch) -> np.ndarray:
        obs = np.random.default_rng(7).normal(size=(structure.limb_mask.size, FEATURES)).astype(np.float32)
        return np.abs(np.asarray(jacobian(obs, structure))).max(axis=-1) > 0

    return dependency


@pytest.mark.parametrize(
    "parents",
    [
        (-1, 0, 1, 2, 3),  # chain: the torso and the far leaf see each other only through 4 hops
        (-1, 0, 0, 0, 0),  # star: siblings see each other only through the torso
        (-1, 0, 1, 2, 0, 4, 5, 0, 7, 8, 0, 10, 11),  # nervenet_fullcheetah: 4 branches of 3
    ],
    ids=["chain", "star", "fullcheetah"],
)
def test_smp_messages_travel_the_whole_tree(parents, smp_dependency):
    """Up then down reaches every limb from every limb; a broken pass leaves a zero block."""
    dependency = smp_dependency(structure_from_parents(parents, 13))
    n = len(parents)
    assert dependency[:n, :n].all(), f"limbs not reached: {np.argwhere(~dependency[:n, :n]).tolist()}"
    assert not dependency[:, n:].any() and not dependency[n:].any()


# Gradients, shapes, compile counts, vmap


# SET takes 3D bodies only; tests/test_set_network.py checks that one update moves every weight of it.
@pytest.mark.parametrize("name", [name for name in NAMED_VARIANTS if name != "set"])
def test_every_parameter_learns_and_shapes_hold(name, bundles, structures9):
    bundle = bundles[name] if name in bundles else make_bundle(name)
    obs, actions = random_inputs(8, structures9)
    mask = structures9.limb_mask[:, None, :]

    def actor_loss(params):
        out = jax.vmap(bundle.actor.apply, in_axes=(None, 0, 0))(params, obs, structures9)
        return jnp.sum(out * mask) / mask.sum() * BATCH, out

    def critic_loss(params):
        q1, q2 = jax.vmap(bundle.critic.apply, in_axes=(None, 0, 0, 0))(params, obs, actions, structures9)
        return jnp.sum((q1 - 1.0) ** 2 + q2**2), (q1, q2)

    (_, out), actor_grads = jax.jit(jax.value_and_grad(actor_loss, has_aux=True))(bundle.actor_params)
    (_, q_values), critic_grads = jax.jit(jax.value_and_grad(critic_loss, has_aux=True))(bundle.critic_params)

    for array in (out, *q_values):
        assert array.shape == (len(BODIES), BATCH, 9) and array.dtype == jnp.float32
    for grads in (actor_grads, critic_grads):
        for path, grad in jax.tree_util.tree_leaves_with_path(grads):
            assert np.isfinite(grad).all(), jax.tree_util.keystr(path)
            assert np.any(grad != 0), f"{jax.tree_util.keystr(path)} gets no gradient"
    config = network_config(name)
    network = actor_grads["params"]["policy"]
    transformer = config.architecture != "smp"
    assert ("traversal_embedding" in network) == (transformer and bool(config.traversals))
    assert ("relational_embedding" in network) == (transformer and bool(config.relations))
    if "traversal_embedding" in network:
        for column, traversal in enumerate(TRAVERSAL_NAMES):
            table = np.asarray(network["traversal_embedding"][f"{traversal}_order"]["embedding"])
            used = np.unique(structures9.traversal_positions[..., column][structures9.limb_mask])
            assert np.all(np.abs(table[used]).max(axis=-1) > 0), (
                f"a used {traversal}-order row gets no gradient"
            )
            assert np.all(table[used.max() + 1 :] == 0), f"an unused {traversal}-order row gets a gradient"


@pytest.mark.parametrize("name", ARCHITECTURES)
def test_each_network_compiles_once_per_input_shape(name, bundles, structures9, bodies):
    bundle = bundles[name]
    other_bodies = pad_structures([load("walker_7_main"), load("cheetah_4_front"), bodies[0]], 9)
    calls = ((10, structures9), (11, other_bodies), (12, structures9))
    before = (bundle.act.traces, bundle.criticize.traces)
    for seed, structures in calls:
        obs, actions = random_inputs(seed, structures, batch=5)
        bundle.act(bundle.actor_params, obs, structures)
        bundle.criticize(bundle.critic_params, obs, actions, structures)
    assert (bundle.act.traces - before[0], bundle.criticize.traces - before[1]) == (1, 1)


@pytest.mark.parametrize("name", ARCHITECTURES)
def test_vmap_over_tasks_equals_per_task_apply(name, bundles, structures13):
    bundle = bundles[name]
    obs, actions = random_inputs(9, structures13)
    actor_apply = jax.jit(bundle.actor.apply)
    critic_apply = jax.jit(bundle.critic.apply)
    vmapped_actions = bundle.act(bundle.actor_params, obs, structures13)
    vmapped_q = bundle.criticize(bundle.critic_params, obs, actions, structures13)
    for k in range(len(BODIES)):
        structure = task(structures13, k)
        np.testing.assert_allclose(
            vmapped_actions[k], actor_apply(bundle.actor_params, obs[k], structure), atol=1e-5
        )
        for vmapped, single in zip(
            vmapped_q, critic_apply(bundle.critic_params, obs[k], actions[k], structure), strict=True
        ):
            np.testing.assert_allclose(vmapped[k], single, atol=1e-5)


def test_the_docs_parameter_table_is_what_the_command_prints(capsys):
    """docs/networks.md quotes ``python -m swat_jax.networks``: every row, SET on the 3D set only."""
    from swat_jax.networks.__main__ import main

    main()
    printed = [f"    {line}" for line in capsys.readouterr().out.splitlines()]
    docs = (Path(__file__).resolve().parents[1] / "docs" / "networks.md").read_text().splitlines()
    start = docs.index(printed[0])
    assert docs[start : start + len(printed)] == printed
    assert [row.split()[0] for row in printed[1:] if row.split()[2] == "set"] == ["3D-SGRL"]
