"""SET, SGRL's subequivariant transformer (Chen et al. 2023): parity with SGRL's own modules, its symmetry,
its 3D-only check and one TD3 update (swat_jax.networks.subequivariant).

The fixtures in ``tests/data/sgrl/set.npz`` were written by SGRL's PyTorch ``SEPolicy`` and ``SECritic``
(``tests/sgrl_set_data.py``, run in its own environment; no PyTorch is needed here) with every weight drawn
by :func:`original_parity_data.filled_state_dict`, which draws the same weights here.
"""

from __future__ import annotations

import functools
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from original_parity_data import assert_structure_inputs_equal, filled_state_dict, stored_shapes
from scipy.spatial.transform import Rotation

from swat_jax.morphology import RELATION_NAMES, TRAVERSAL_NAMES, load, pad_structures
from swat_jax.networks import ArchitectureMismatch, check_structures, make_actor_critic, network_config
from swat_jax.networks.original_weights import ORIGINAL_RELATION_ORDER
from swat_jax.td3.learner import Learner, TD3Config
from swat_jax.td3.replay import Transitions
from swat_jax.train import main as train_main

DATA = np.load(Path(__file__).parent / "data" / "sgrl" / "set.npz")
BODIES = tuple(
    key.split("/")[1] for key in DATA.files if key.startswith("structure/") and key.endswith("parents")
)
MAX_LIMBS = 13
"""Larger than the largest fixture body (11 limbs): every body is padded."""
FEATURES, MOTORS = 41, 3
TOLERANCE = {"rtol": 1e-4, "atol": 1e-5}
CONFIG = network_config(
    "set",
    width=int(DATA["attention_embedding_size"]),
    heads=int(DATA["attention_heads"]),
    feedforward=int(DATA["attention_hidden_size"]),
    layers=int(DATA["attention_layers"]),
)
STRUCTURE = pad_structures([load(body) for body in BODIES], MAX_LIMBS, reference_inorder=True)

SGRL_LAYER = {
    ("attention", "gram_frame"): "self_attn.g_proj",
    ("attention", "gram_mlp", "hidden"): "self_attn.linear_g1",
    ("attention", "gram_mlp", "output"): "self_attn.linear_g2",
    ("attention", "query"): "self_attn.q_proj",
    ("attention", "key"): "self_attn.k_proj",
    ("attention", "value"): "self_attn.v_proj",
    ("attention", "vector_value"): "self_attn.vg_proj",
    ("attention", "output"): "self_attn.ng_out",
    ("attention", "vector_output"): "self_attn.g_out",
    ("attention_norm",): "norm1",
    ("gram_frame",): "g_proj2",
    ("gram_mlp", "hidden"): "linear_g1",
    ("gram_mlp", "output"): "linear_g2",
    ("mixing_frame",): "g_proj3",
    ("frame_mixing", "mixing", "hidden"): "linear3",
    ("frame_mixing", "mixing", "output"): "linear4",
    ("vector_feedforward",): "linear5",
    ("feedforward", "hidden"): "linear1",
    ("feedforward", "output"): "linear2",
    ("feedforward_norm",): "norm2",
}
"""Our names in ``layer_i`` and SGRL's in ``transformer_encoder.layers.i`` (its MyTransformerEncoderLayer)."""
SGRL_MODEL = {
    ("vector_encoder",): "g_encoder",
    ("limb_encoder",): "encoder",
    ("final_norm",): "transformer_encoder.norm",
    ("head", "gram_frame"): "gg_proj",
    ("head", "gram_mlp", "hidden"): "linear1_g",
    ("head", "gram_mlp", "output"): "linear2_g",
    ("head", "scalar_mlp", "hidden"): "linear1_ng",
    ("head", "scalar_mlp", "output"): "linear2_ng",
    ("head", "value"): "decoder_ng",
    ("head", "frame_mixing", "mixing", "hidden"): "linear1_m",
    ("head", "frame_mixing", "mixing", "output"): "linear2_m",
    ("head", "mixing_frame"): "g_proj",
    ("head", "output_vector"): "decoder_g",
}
"""Our names and SGRL's in its TransformerModel, outside the layers (the critic has no ``linear*_m``,
``g_proj``, ``decoder_g``; the actor no ``decoder_ng``)."""
SGRL_UNUSED = ("in_proj_weight", "in_proj_bias", "out_proj.weight", "out_proj.bias", "rel_encoder.bias")
"""SGRL's weights that do not change its outputs: its attention's PyTorch projections (its forward never
reads them) and the relation map's bias (a constant on every logit of a head, cancelled by the softmax)."""


def _nest(tree: dict, path: tuple[str, ...], leaf: dict) -> None:
    for name in path[:-1]:
        tree = tree.setdefault(name, {})
    tree[path[-1]] = leaf


def _module(state: dict, key: str, used: set[str]) -> dict:
    """A Dense (kernel, and bias when SGRL has one) or a LayerNorm from SGRL's ``key``."""
    used.update(name for name in (f"{key}.weight", f"{key}.bias") if name in state)
    if ".norm" in f".{key}":
        return {"scale": state[f"{key}.weight"], "bias": state[f"{key}.bias"]}
    dense = {"kernel": state[f"{key}.weight"].T}
    return {**dense, "bias": state[f"{key}.bias"]} if f"{key}.bias" in state else dense


def set_params(state: dict[str, np.ndarray], prefix: str) -> tuple[dict, set[str]]:
    """Our SET parameters from the entries of SGRL's state dict under ``prefix`` (one TransformerModel), and
    the keys read."""
    used: set[str] = set()
    params: dict = {}
    for path, key in SGRL_MODEL.items():
        if f"{prefix}{key}.weight" in state:
            _nest(params, path, _module(state, prefix + key, used))
    for layer in range(CONFIG.layers):
        for path, key in SGRL_LAYER.items():
            _nest(
                params,
                (f"layer_{layer}", *path),
                _module(state, f"{prefix}transformer_encoder.layers.{layer}.{key}", used),
            )
    for column, traversal in enumerate(TRAVERSAL_NAMES):
        key = f"{prefix}pos_encoder.embeddings.{column}.weight"
        _nest(params, ("traversal_embedding", f"{traversal}_order"), {"embedding": state[key]})
        used.add(key)
    relation_map = state[f"{prefix}transformer_encoder.rel_encoder.weight"].T
    channels = [ORIGINAL_RELATION_ORDER.index(name) for name in RELATION_NAMES]
    _nest(params, ("relational_embedding", "g"), {"kernel": relation_map[channels]})
    used.add(f"{prefix}transformer_encoder.rel_encoder.weight")
    return params, used


@functools.cache
def networks():
    """Our actor's and critic's parameters from SGRL's filled weights, and their task-vmapped jitted applies:
    (params, observation, structure) -> (actions, the actor's final vector features [K, B, L, 3, width]) and
    (params, observation, action, structure) -> (q1, q2)."""
    actor, critic = make_actor_critic(CONFIG, FEATURES, motors=MOTORS)
    actor_state = filled_state_dict(stored_shapes(DATA, "actor"), 1)
    critic_state = filled_state_dict(stored_shapes(DATA, "critic"), 2)
    policy, used_actor = set_params(actor_state, "actor.")
    (q1, used_q1), (q2, used_q2) = (set_params(critic_state, f"critic{i}.") for i in (1, 2))
    for state, used in ((actor_state, used_actor), (critic_state, used_q1 | used_q2)):
        assert {key for key in state if not key.endswith(SGRL_UNUSED)} == used
    actor_params = {"params": {"policy": policy}}
    critic_params = {"params": {"q1": q1, "q2": q2}}
    for ours, network in ((actor_params, actor), (critic_params, critic)):
        shapes = jax.tree.map(np.shape, jax.eval_shape(network.init, jax.random.key(0)))
        assert jax.tree.map(np.shape, ours) == shapes

    def act(params, observation, structure):
        actions, state = actor.apply(params, observation, structure, mutable=["intermediates"])
        return actions, state["intermediates"]["policy"]["vector_features"][0]

    act = jax.jit(jax.vmap(act, in_axes=(None, 0, 0)))
    criticize = jax.jit(jax.vmap(critic.apply, in_axes=(None, 0, 0, 0)))
    return actor_params, act, critic_params, criticize


def padded_inputs() -> tuple[np.ndarray, np.ndarray]:
    """The fixture's observations [K, B, L, 41] and actions [K, B, L, 3], the padded limbs random (they must
    not matter)."""
    rng = np.random.default_rng(5)
    observations, actions = [], []
    for body in BODIES:
        observation, action = DATA[f"inputs/{body}/observation"], DATA[f"inputs/{body}/action"]
        batch, limbs = action.shape[0], action.shape[1] // MOTORS
        padding = MAX_LIMBS - limbs
        observations.append(
            np.concatenate(
                [observation.reshape(batch, limbs, FEATURES), rng.normal(size=(batch, padding, FEATURES))], 1
            )
        )
        actions.append(
            np.concatenate(
                [action.reshape(batch, limbs, MOTORS), rng.uniform(-1, 1, (batch, padding, MOTORS))], 1
            )
        )
    return np.stack(observations).astype(np.float32), np.stack(actions).astype(np.float32)


@pytest.mark.parametrize("body", BODIES)
def test_structure_inputs_equal_sgrls(body):
    assert_structure_inputs_equal(STRUCTURE, BODIES.index(body), DATA, body, TOLERANCE)


def test_actor_and_twin_critic_equal_sgrls_on_every_body_padded():
    """Four 3D bodies of 4 to 11 limbs padded to 13 (random padding) in one batch: the actions (SGRL's tanh
    of the hinge-axis projections) on every motor, both critics' per-limb Q on every limb, within 1e-5 and
    within 1e-3 of each body's largest output."""
    actor_params, act, critic_params, criticize = networks()
    observation, action = padded_inputs()
    actions = np.asarray(act(actor_params, observation, STRUCTURE)[0])
    q_values = [np.asarray(q) for q in criticize(critic_params, observation, action, STRUCTURE)]
    for row, body in enumerate(BODIES):
        limbs = int(STRUCTURE.num_limbs[row])
        motors = STRUCTURE.motor_mask[row, :limbs]
        expected = DATA[f"outputs/{body}/actor"].reshape(-1, limbs, MOTORS)
        ours = actions[row, :, :limbs]
        np.testing.assert_allclose(ours[:, motors], expected[:, motors], **TOLERANCE, err_msg=body)
        assert np.all(ours[:, ~motors] == 0) and np.all(actions[row, :, limbs:] == 0)
        pairs = [(ours[:, motors], expected[:, motors])]
        for name, q in zip(("q1", "q2"), q_values, strict=True):
            np.testing.assert_allclose(
                q[row, :, :limbs], DATA[f"outputs/{body}/{name}"], **TOLERANCE, err_msg=body
            )
            assert np.all(q[row, :, limbs:] == 0)
            pairs.append((q[row, :, :limbs], DATA[f"outputs/{body}/{name}"]))
        for mine, theirs in pairs:
            assert np.abs(mine - theirs).max() <= 1e-3 * np.abs(theirs).max(), body


def rotated(observation: np.ndarray, rotation: np.ndarray, gravity_too: bool = True) -> np.ndarray:
    """``observation`` [..., 41] with its eight 3-vectors (values 0:24) multiplied by ``rotation`` [3, 3]:
    gravity (values 3:6) kept as it is unless ``gravity_too``."""
    vectors = observation[..., :24].reshape(*observation.shape[:-1], 8, 3) @ rotation.T
    if not gravity_too:
        vectors[..., 1, :] = observation[..., 3:6]
    return np.concatenate([vectors.reshape(*observation.shape[:-1], 24), observation[..., 24:]], -1)


def outputs_and_vectors(observation: np.ndarray, action: np.ndarray) -> list[np.ndarray]:
    """Actions, the actor's final vector features [K, B, L, 3, width], q1 and q2 of one input."""
    actor_params, act, critic_params, criticize = networks()
    outputs = (
        *act(actor_params, observation, STRUCTURE),
        *criticize(critic_params, observation, action, STRUCTURE),
    )
    return [np.asarray(output) for output in outputs]


def test_turning_about_gravity_turns_the_vectors_and_leaves_actions_and_q():
    """Subequivariance: rotating every input vector about the vertical by a random angle, or reflecting them
    through a vertical plane, rotates the network's vector features (the layers' output) and leaves the
    actions and Q values (projections on the turned hinge axes, invariants) as they were; a rotation about
    a horizontal axis (gravity staying down) changes them, while one that also turns gravity does not (the
    network is O(3)-equivariant with gravity as an input)."""
    observation, action = padded_inputs()
    base = outputs_and_vectors(observation, action)
    mask = np.broadcast_to(STRUCTURE.limb_mask[:, None, :], base[2].shape)
    angle = np.random.default_rng(3).uniform(0, 2 * np.pi)
    about_gravity = Rotation.from_rotvec([0, 0, angle]).as_matrix()
    for rotation in (about_gravity, about_gravity @ np.diag([-1.0, 1.0, 1.0])):
        actions, vectors, q1, q2 = outputs_and_vectors(rotated(observation, rotation), action)
        np.testing.assert_allclose(vectors[mask], (rotation @ base[1])[mask], rtol=1e-4, atol=2e-4)
        for ours, before in zip((actions, q1, q2), (base[0], base[2], base[3]), strict=True):
            np.testing.assert_allclose(ours[mask], before[mask], rtol=1e-4, atol=1e-7)
    tilt = Rotation.from_rotvec([0.7, 0.4, 0.0]).as_matrix()
    actions, _, q1, _ = outputs_and_vectors(rotated(observation, tilt, gravity_too=False), action)
    for ours, before in ((actions, base[0]), (q1, base[2])):
        assert np.abs(ours - before)[mask].max() > 1e-2 * np.abs(before[mask]).max()
    actions, _, q1, _ = outputs_and_vectors(rotated(observation, tilt), action)
    np.testing.assert_allclose(actions[mask], base[0][mask], rtol=1e-4, atol=1e-7)
    np.testing.assert_allclose(q1[mask], base[2][mask], rtol=1e-4, atol=1e-7)


def test_a_planar_body_with_set_is_refused_before_anything_is_built(tmp_path, capsys):
    """The train command, the host-side structure check and the actor itself each say SET is 3D-only."""
    status = train_main(["--env", "hopper", "--algo", "set", "--run-dir", str(tmp_path / "run")])
    error = capsys.readouterr().err
    assert status == 2 and not (tmp_path / "run").exists()
    assert (
        "set cannot take the bodies of hopper: SET (--algo set) is 3D-only and hopper_3 is a planar body"
        in error
    )
    assert "train SET on a 3D-SGRL set (3d_hopper" in error
    planar = pad_structures([load("walker_7_main")])
    with pytest.raises(ArchitectureMismatch, match="walker_7_main is a planar body"):
        check_structures(CONFIG, planar, ["walker_7_main"])
    check_structures(CONFIG, STRUCTURE)
    actor, _ = make_actor_critic(CONFIG, 19)
    with pytest.raises(ValueError, match="SET acts on 3D bodies"):
        actor.init(jax.random.key(0))


def test_set_refuses_what_would_break_its_symmetry_or_its_critic():
    with pytest.raises(ValueError, match=r"observation normalisation.*would break its symmetry"):
        network_config("set", observation_normalisation=True)
    with pytest.raises(ValueError, match="a distributional critic needs"):
        make_actor_critic(CONFIG, FEATURES, atoms=51, motors=MOTORS)


@pytest.mark.slow
def test_one_td3_update_moves_every_weight_of_set():
    """From SGRL's initialisation (encoders U(+-0.1)): one critic step and one delayed actor step on two 3D
    bodies give every actor and critic weight a finite, nonzero change."""
    config = network_config("set", width=8, heads=2, feedforward=16, layers=1, initialisation="original")
    actor, critic = make_actor_critic(config, FEATURES, motors=MOTORS)
    learner = Learner(actor, critic, TD3Config(batch_size=4))
    state = jax.jit(learner.init, static_argnames="tasks")(jax.random.key(0), tasks=2)
    assert np.abs(state.actor_params["params"]["policy"]["vector_encoder"]["kernel"]).max() <= 0.1
    structure = pad_structures([load("3d_hopper_3_shin"), load("3d_walker_5_foot")], 6)
    rng = np.random.default_rng(0)
    observation = rng.normal(size=(2, 2, 4, 6, FEATURES)).astype(np.float32)
    batch = Transitions(
        observation=observation[0],
        action=rng.uniform(-1, 1, (2, 4, 6, MOTORS)).astype(np.float32),
        reward=rng.normal(size=(2, 4)).astype(np.float32),
        next_observation=observation[1],
        terminated=np.zeros((2, 4), bool),
    )
    after, _ = jax.jit(learner.update)(state, batch, structure, jax.random.key(1), jnp.asarray(True))
    for before, moved in (
        (state.actor_params, after.actor_params),
        (state.critic_params, after.critic_params),
    ):
        for (path, old), new in zip(
            jax.tree_util.tree_leaves_with_path(before), jax.tree.leaves(moved), strict=True
        ):
            assert np.isfinite(new).all() and np.any(old != new), jax.tree_util.keystr(path)
