"""Parity with the original SWAT code: the same weights and inputs give the same numbers.

The fixtures in ``tests/data/original`` were written by the original PyTorch code itself
(``tests/original_parity_data.py``, run in its own environment; no PyTorch is needed here). Its
weights are read in with :mod:`swat_jax.networks.original_weights`, the converter's mapping, and every
comparison is at float32 tolerance.
"""

from __future__ import annotations

import dataclasses
import functools
import types
from pathlib import Path

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
import pytest
from original_parity_data import assert_structure_inputs_equal, filled_state_dict, flat_ids, stored_shapes
from scipy import stats

from swat_jax.envs.observation import limb_observation
from swat_jax.morphology import load, pad_structures
from swat_jax.networks import make_actor_critic, network_config
from swat_jax.networks.original_weights import actor_params, critic_params
from swat_jax.td3.learner import Learner, LearnerState, TD3Config
from swat_jax.td3.replay import Transitions

DATA = np.load(Path(__file__).parent / "data" / "original" / "networks.npz")
UPDATES = np.load(Path(__file__).parent / "data" / "original" / "updates.npz")
BODIES = tuple(sorted({key.split("/")[1] for key in DATA.files if key.startswith("structure/")}))
TOLERANCE = {"rtol": 1e-4, "atol": 1e-5}
ARCHITECTURES = {"swat": "swat", "amorpheus": "amorpheus", "smp": "smp"}


def config(architecture: str, data, max_children: int):
    return network_config(
        architecture,
        width=int(data["attention_embedding_size"]),
        heads=int(data["attention_heads"]),
        feedforward=int(data["attention_hidden_size"]),
        layers=int(data["attention_layers"]),
        message_width=int(data["message_width"]),
        max_children=max_children,
    )


def stored_or_filled(data, architecture: str, state: str, network: str, seed: int) -> dict[str, np.ndarray]:
    """The state dict of one original network: stored (``init``) or filled the generator's way."""
    if state == "filled":
        return filled_state_dict(stored_shapes(data, f"{architecture}/{network}"), seed)
    prefix = f"{architecture}/{state}/{network}/"
    return {key[len(prefix) :]: data[key] for key in data.files if key.startswith(prefix)}


STRUCTURE = pad_structures([load(body) for body in BODIES], reference_inorder=True)
LIMBS = STRUCTURE.limb_mask.shape[1]


def padded_inputs(body: str) -> tuple[np.ndarray, np.ndarray]:
    """The fixture's observation [B, limbs * F] and action [B, limbs] of ``body``, padded to [B, L, F], [B, L]."""
    observation, action = DATA[f"inputs/{body}/observation"], DATA[f"inputs/{body}/action"]
    limbs = action.shape[1]
    observation = observation.reshape(observation.shape[0], limbs, -1)
    pad = LIMBS - limbs
    return np.pad(observation, ((0, 0), (0, pad), (0, 0))), np.pad(action, ((0, 0), (0, pad)))


@pytest.mark.parametrize("body", BODIES)
def test_structure_inputs_equal_the_original(body):
    assert_structure_inputs_equal(STRUCTURE, BODIES.index(body), DATA, body, TOLERANCE)


@functools.cache
def network_outputs(architecture: str, state: str):
    """Our actor's actions and critic's (q1, q2) for every fixture body, [K, B, L] each."""
    net_config = config(architecture, DATA, int(DATA["max_children"]))
    actor, critic = make_actor_critic(net_config, int(DATA["features"]))
    actor_weights = actor_params(stored_or_filled(DATA, architecture, state, "actor", 1), net_config)
    critic_weights = critic_params(stored_or_filled(DATA, architecture, state, "critic", 2), net_config)
    inputs = [padded_inputs(body) for body in BODIES]
    observation = jnp.asarray(np.stack([obs for obs, _ in inputs]))
    action = jnp.asarray(np.stack([act for _, act in inputs]))

    @jax.jit
    def outputs(observation, action, structure):
        over_bodies = functools.partial(jax.vmap, in_axes=(None, 0, 0))
        actions = over_bodies(actor.apply)(actor_weights, observation, structure)
        q1, q2 = jax.vmap(critic.apply, in_axes=(None, 0, 0, 0))(
            critic_weights, observation, action, structure
        )
        return actions, q1, q2

    return net_config, jax.device_get(outputs(observation, action, STRUCTURE))


NETWORK_CASES = [
    (architecture, state)
    for architecture in ARCHITECTURES
    for state in (("filled",) if architecture == "smp" else ("init", "filled"))
]


@pytest.mark.parametrize(("architecture", "state"), NETWORK_CASES)
def test_networks_equal_the_original(architecture, state):
    """Actor actions and both critics' Q on five bodies of every family; SMP's Q is the body's sum."""
    net_config, (actions, q1, q2) = network_outputs(architecture, state)
    for row, body in enumerate(BODIES):
        limbs = int(STRUCTURE.num_limbs[row])
        expected = DATA[f"{architecture}/{state}/{body}/actor"]
        np.testing.assert_allclose(actions[row, :, :limbs], expected, **TOLERANCE, err_msg=f"{body} actor")
        for name, ours in (("q1", q1), ("q2", q2)):
            ours = ours[row, :, :limbs]
            if net_config.sums_limb_values:
                ours = ours.sum(axis=-1, keepdims=True)
            expected = DATA[f"{architecture}/{state}/{body}/{name}"]
            np.testing.assert_allclose(ours, expected, **TOLERANCE, err_msg=f"{body} {name}")


def initial_weight_mismatches(architecture: str, initialisation: str) -> list[str]:
    """The weights of our freshly initialised actor and critic whose distribution differs from the original's
    own initialisation (the fixture's ``init`` state, read in by the converter): a constant array (zeros, a
    LayerNorm's ones) on either side that the other does not equal, or a two-sample Kolmogorov-Smirnov or Levene (equal
    spread) p below 1e-3."""
    net_config = config(architecture, DATA, int(DATA["max_children"]))
    net_config = dataclasses.replace(net_config, initialisation=initialisation)
    actor, critic = make_actor_critic(net_config, int(DATA["features"]))
    theirs = {
        "actor": actor_params(stored_or_filled(DATA, architecture, "init", "actor", 0), net_config),
        "critic": critic_params(stored_or_filled(DATA, architecture, "init", "critic", 0), net_config),
    }
    ours = {"actor": actor.init(jax.random.key(1)), "critic": critic.init(jax.random.key(2))}
    mismatches = []
    for (path, mine), original in zip(
        jax.tree_util.tree_leaves_with_path(ours), jax.tree.leaves(theirs), strict=True
    ):
        mine, original = np.asarray(mine).ravel(), np.asarray(original).ravel()
        if np.ptp(original) == 0 or np.ptp(mine) == 0:
            matches = np.array_equal(mine, original)
        else:
            matches = min(stats.ks_2samp(mine, original).pvalue, stats.levene(mine, original).pvalue) > 1e-3
        if not matches:
            mismatches.append(jax.tree_util.keystr(path))
    return mismatches


@pytest.mark.parametrize("architecture", ["swat", "amorpheus"])
def test_the_original_initialisation_draws_what_the_original_code_draws(architecture):
    """``initialisation="original"``: every weight as the original's (docs/fidelity.md, rows 6-11), Flax's
    defaults differ where the table says (the limb encoder's bias and scale, the traversal tables)."""
    assert initial_weight_mismatches(architecture, "original") == []
    differing = " ".join(initial_weight_mismatches(architecture, "flax"))
    for weight in (
        "['limb_encoder']['kernel']",
        "['limb_encoder']['bias']",
        "['feedforward_hidden']['bias']",
    ):
        assert weight in differing
    if architecture == "swat":
        assert "['in_order']['embedding']" in differing


@pytest.mark.parametrize("architecture", ["swat", "amorpheus"])
def test_the_original_initialisation_starts_every_layer_as_a_copy_of_the_first(architecture):
    """The original deep-copies one encoder layer (docs/fidelity.md, row 10)."""
    net_config = dataclasses.replace(
        config(architecture, DATA, int(DATA["max_children"])), initialisation="original"
    )
    actor, _ = make_actor_critic(net_config, int(DATA["features"]))
    layers = actor.init(jax.random.key(0))["params"]["policy"]
    assert net_config.layers == 2
    jax.tree.map(np.testing.assert_array_equal, layers["layer_0"], layers["layer_1"])


def test_the_original_initialisation_of_smp_is_pytorchs_default():
    """SMP's every linear layer, kernel and bias, uniform on +-1/sqrt(fan in) (docs/fidelity.md, row 20)."""
    net_config = dataclasses.replace(
        config("smp", DATA, int(DATA["max_children"])), initialisation="original"
    )
    _, critic = make_actor_critic(net_config, int(DATA["features"]))
    layers = jax.tree_util.tree_leaves_with_path(critic.init(jax.random.key(0)))
    kernels = {jax.tree_util.keystr(path[:-1]): kernel for path, kernel in layers if path[-1].key == "kernel"}
    for path, bias in layers:
        if path[-1].key != "bias":
            continue
        kernel = kernels[jax.tree_util.keystr(path[:-1])]
        bound = 1 / np.sqrt(kernel.shape[-2])
        for values in (np.asarray(kernel).ravel(), np.asarray(bias).ravel()):
            assert np.abs(values).max() <= bound
            assert stats.kstest(values, stats.uniform(-bound, 2 * bound).cdf).pvalue > 1e-3, path


def probed(params, ids_tree, probe_ids: np.ndarray) -> np.ndarray:
    """Our parameters at the original's flat positions ``probe_ids`` (NaN where we have no such weight:
    the key projection's and g's biases, which cancel in the softmax)."""
    values = np.full(probe_ids.shape, np.nan)
    for value, ids in zip(jax.tree.leaves(params), jax.tree.leaves(ids_tree), strict=True):
        ids = np.asarray(ids).astype(np.int64).ravel()
        where = np.searchsorted(probe_ids, ids)
        hit = (where < probe_ids.size) & (probe_ids[np.minimum(where, probe_ids.size - 1)] == ids)
        values[where[hit]] = np.asarray(value).ravel()[hit]
    return values


@pytest.mark.parametrize("architecture", ["swat", "smp"])
def test_two_td3_updates_equal_the_original(architecture):
    """Critic step, delayed actor step and target updates: the original takes the actor step in the first
    update of a body's run (its loop index 0), not the second; every limb has its own TD target (SMP: the
    sample's summed Q)."""
    data = UPDATES
    net_config = config(architecture, data, int(data[f"{architecture}/max_children"]))
    actor, critic = make_actor_critic(net_config, int(data["features"]))
    learner = Learner(actor, critic, TD3Config(batch_size=int(data["batch/0/reward"].shape[0])))
    structure = pad_structures([load(str(data["body"]))], reference_inorder=True)
    limbs = int(structure.num_limbs[0])
    weights = {
        name: filled_state_dict(stored_shapes(data, f"{architecture}/{name}"), seed)
        for name, seed in (("actor", 1), ("critic", 2))
    }
    to_params = {"actor": actor_params, "critic": critic_params}
    params = {name: to_params[name](weights[name], net_config) for name in weights}
    ids = {
        name: to_params[name](flat_ids(stored_shapes(data, f"{architecture}/{name}")), net_config)
        for name in weights
    }
    optimizer = learner.optimizer()
    state = LearnerState(
        actor_params=params["actor"],
        critic_params=params["critic"],
        target_actor_params=params["actor"],
        target_critic_params=params["critic"],
        actor_optimizer=optimizer.init(params["actor"]),
        critic_optimizer=optimizer.init(params["critic"]),
        critic_steps=jnp.zeros((), jnp.int32),
    )
    update = jax.jit(learner.update_with_noise)
    for step in range(2):
        batch = Transitions(
            observation=data[f"batch/{step}/observation"].reshape(-1, limbs, int(data["features"]))[None],
            action=data[f"batch/{step}/action"][None],
            reward=data[f"batch/{step}/reward"][:, 0][None],
            next_observation=data[f"batch/{step}/next_observation"].reshape(-1, limbs, int(data["features"]))[
                None
            ],
            terminated=data[f"batch/{step}/done"][:, 0][None],
        )
        noise = data[f"{architecture}/noise/{step}"] / learner.config.policy_noise
        state, _ = update(state, batch, structure, jnp.asarray(noise)[None], jnp.asarray(step % 2 == 0))
        for name, ours in (
            ("actor", state.actor_params),
            ("critic", state.critic_params),
            ("target_actor", state.target_actor_params),
            ("target_critic", state.target_critic_params),
        ):
            base = name.removeprefix("target_")
            probe_ids = data[f"{architecture}/{base}/probe_ids"]
            values = probed(ours, ids[base], probe_ids)
            expected = data[f"{architecture}/after/{step}/{name}"]
            present = ~np.isnan(values)
            assert present.mean() > 0.9, f"{name}: only {present.mean():.0%} of the probes map to our weights"
            np.testing.assert_allclose(
                values[present], expected[present], **TOLERANCE, err_msg=f"update {step + 1}, {name}"
            )


ENVIRONMENTS = np.load(Path(__file__).parent / "data" / "original" / "environments.npz")
ENVIRONMENT_BODIES = sorted({key.split("/")[0] for key in ENVIRONMENTS.files})


def recorded(body: str, key: str) -> np.ndarray:
    return ENVIRONMENTS[f"{body}/{key}"]


def test_the_fixtures_cover_every_benchmark_body():
    assert len(ENVIRONMENT_BODIES) == 43


@functools.cache
def body_env(body: str):
    from swat_jax.envs import BodyEnv

    return BodyEnv(body, torso_relative_x=False)


@pytest.mark.parametrize("body", ENVIRONMENT_BODIES)
def test_observation_reward_and_done_equal_the_original(body):
    """From the state the original's step ended in: the observation its kinematics give (the original's
    in-place torso-x write and its in-order included), the reward and the termination."""
    env = body_env(body)
    model = env.mj_model
    data = mujoco.MjData(model)
    limbs = slice(1, env.num_limbs + 1)
    for index in range(len(recorded(body, "reward"))):
        data.qpos[:], data.qvel[:] = recorded(body, "qpos_after")[index], recorded(body, "qvel_after")[index]
        data.ctrl[:] = recorded(body, "action")[index]
        mujoco.mj_forward(model, data)
        ours = limb_observation(
            env.layout,
            data.qpos,
            data.xpos[limbs],
            data.xquat[limbs],
            data.cvel[limbs],
            data.subtree_com[1],
            torso_relative_x=False,
        )
        expected = recorded(body, "obs_fresh")[index].reshape(env.num_limbs, -1)
        np.testing.assert_allclose(np.asarray(ours), expected, **TOLERANCE, err_msg=f"{body} step {index}")
        before = types.SimpleNamespace(qpos=recorded(body, "qpos")[index])
        reward = env.task.reward(before, data)
        np.testing.assert_allclose(float(reward), recorded(body, "reward")[index], **TOLERANCE)
        assert bool(~env.task.alive(before, data)) == bool(recorded(body, "done")[index]), (
            f"{body} step {index}: done"
        )


def step_from_the_original_state(env, data, body: str, index: int) -> None:
    """MuJoCo C's environment step of ``env``'s model in ``data``, from the original's recorded state and
    action ``index``."""
    data.qpos[:], data.qvel[:] = recorded(body, "qpos")[index], recorded(body, "qvel")[index]
    data.ctrl[:] = recorded(body, "action")[index]
    for _ in range(env.morphology.frame_skip):
        mujoco.mj_step(env.mj_model, data)


@pytest.mark.parametrize("body", ENVIRONMENT_BODIES)
def test_one_physics_step_equals_the_original(body):
    """MuJoCo 3.17 on our MJCF from the original's state and action gives the original's next state (the
    hoppers' foot contacts included: their geoms' margins are half the original's, as MuJoCo 3 adds a
    contact's two margins where MuJoCo 2 took the larger)."""
    env = body_env(body)
    model = env.mj_model
    data = mujoco.MjData(model)
    worst = 0.0
    for index in range(len(recorded(body, "reward"))):
        step_from_the_original_state(env, data, body, index)
        worst = max(
            worst,
            np.abs(data.qpos - recorded(body, "qpos_after")[index]).max(),
            np.abs(data.qvel - recorded(body, "qvel_after")[index]).max(),
        )
    assert worst < 1e-6, f"{body}: qpos/qvel differ by up to {worst}"


@pytest.mark.parametrize("body", ENVIRONMENT_BODIES)
def test_stale_kinematics_give_the_observation_the_original_step_returns(body):
    """With the original's reads (the positions ``mj_step`` leaves, their Jacobians times the new qvel):
    the observation and done the original's ``step`` returned, on MuJoCo C's step of our MJCF."""
    env = body_env(body)
    model = env.mj_model
    data = mujoco.MjData(model)
    limbs = slice(1, env.num_limbs + 1)
    for index in range(len(recorded(body, "reward"))):
        step_from_the_original_state(env, data, body, index)
        mujoco.mj_comVel(model, data)  # the stale positions' Jacobians times the new qvel
        ours = limb_observation(
            env.layout,
            data.qpos,
            data.xpos[limbs],
            data.xquat[limbs],
            data.cvel[limbs],
            data.subtree_com[1],
            torso_relative_x=False,
        )
        expected = recorded(body, "obs")[index].reshape(env.num_limbs, -1)
        np.testing.assert_allclose(np.asarray(ours), expected, **TOLERANCE, err_msg=f"{body} step {index}")
        assert bool(~env.task.alive(data, data)) == bool(recorded(body, "done")[index]), (
            f"{body} step {index}: done"
        )


@pytest.mark.slow
@pytest.mark.parametrize("physics", ["jax", "c"])
@pytest.mark.parametrize("body", ["cheetah_4_front", "walker_7_main"])
def test_the_step_reads_stale_kinematics_as_the_original(body, physics):
    """BodyEnv(stale_kinematics=True) on MJX (float32) and on MuJoCo C: from the original's state and
    action, the observation the original's step returned, for Euler (cheetah) and RK4 (walker)
    integration."""
    from swat_jax.envs import BodyEnv

    env = BodyEnv(body, torso_relative_x=False, stale_kinematics=True, physics=physics)
    start = env.start(env.kinematics(env.simulator.initial))
    step = jax.jit(env.step)
    for index in range(len(recorded(body, "reward"))):
        data = start.data.replace(
            qpos=jnp.asarray(recorded(body, "qpos")[index], jnp.float32),
            qvel=jnp.asarray(recorded(body, "qvel")[index], jnp.float32),
        )
        state = start.replace(data=env.kinematics(data))
        action = np.zeros(env.num_limbs)
        action[env.motor_actions] = recorded(body, "action")[index]
        after = step(state, jnp.asarray(action, jnp.float32))
        expected = recorded(body, "obs")[index].reshape(env.num_limbs, -1)
        np.testing.assert_allclose(
            np.asarray(after.observation), expected, rtol=1e-3, atol=2e-4, err_msg=f"step {index}"
        )
