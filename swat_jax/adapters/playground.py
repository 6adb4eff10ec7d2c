"""A swat_jax body as a MuJoCo Playground environment, which Brax's trainers run.

:class:`PlaygroundBody` wraps :class:`~swat_jax.envs.body.BodyEnv` in Playground's ``MjxEnv`` interface
(``reset``, ``step``, a ``State`` with ``data``, ``obs``, ``reward``, ``done``, ``metrics`` and ``info``,
``observation_size``, ``action_size``, ``mj_model``, ``mjx_model``), as a Playground user expects of a
single-robot task:

- the observation is the body's per-limb observation flattened, limb after limb: [n * F] float32;
- the action is one value per actuator, [nu] in [-1, 1], in MuJoCo's actuator order (``mj_model.nu``
  values, what a Brax MLP outputs); the environment spreads it onto the limb tokens it drives;
- ``done`` is the body's termination only; the time limit is the training wrapper's ``episode_length``
  (Brax's ``EpisodeWrapper``, 1000 steps in the benchmark), as in every Playground environment;
- ``metrics`` hold the step's ``reward`` and ``distance`` (the torso's progress along x), which Brax's
  episode wrapper sums over an episode; ``info["swat_jax"]`` the body's episode state beyond the simulator
  state (its 3D target, counters).

The reward, termination and observation are ``BodyEnv``'s, on MuJoCo C (``physics="c"``, the default on
a CPU) or MJX. Brax's PPO and SAC train on it through Playground's own wrapper, once
:func:`restore_device_put_replicated` has given jax back the function Brax 0.14.2 still calls::

    from brax.training.agents.ppo import train as ppo
    from mujoco_playground import wrapper

    restore_device_put_replicated()
    env = PlaygroundBody("hopper_3")
    make_policy, params, metrics = ppo.train(
        environment=env, num_timesteps=1_000_000, episode_length=1000,
        wrap_env_fn=wrapper.wrap_for_brax_training, ...)

Playground's registry is left as it is: its names are Playground's own tasks, and swat_jax's bodies are
named by the benchmark (``PlaygroundBody("walker_7_main")``) or by an MJCF file. A set of bodies is one
environment per body (a specialist each, ``experiments/specialists.py``); one policy over a set is what
swat_jax's own trainer does. Needs ``pip install -e '.[playground]'`` (in ``dev``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import mujoco
import numpy as np
from ml_collections import config_dict
from mujoco_playground._src import mjx_env

from swat_jax.envs.body import BodyEnv, EnvState
from swat_jax.envs.physics import Physics
from swat_jax.morphology.types import Morphology

STATE_KEY = "swat_jax"
"""The key of ``State.info`` that holds the body's episode state beyond the simulator state."""


def restore_device_put_replicated() -> None:
    """Give jax back ``jax.device_put_replicated``, which jax 0.10 removed and Brax 0.14.2's PPO and SAC still
    call to place their training state before ``jax.pmap``: here the value stacked once per device on a new
    leading axis, on the default device (``pmap`` moves each slice to its device). Nothing changes where jax
    still has the function."""
    try:
        jax.device_put_replicated  # noqa: B018 (jax 0.10 raises AttributeError for the removed name)
    except AttributeError:
        jax.device_put_replicated = _device_put_replicated


def _device_put_replicated(value: Any, devices: list) -> Any:
    """Every leaf of ``value`` [...] as [len(devices), ...] copies."""
    return jax.tree.map(lambda leaf: jnp.stack([jnp.asarray(leaf)] * len(devices)), value)


def default_config(env: BodyEnv) -> config_dict.ConfigDict:
    """Playground's environment config of ``env``: its control and simulation timesteps, the benchmark's
    episode length."""
    return config_dict.create(
        ctrl_dt=float(env.morphology.control_dt),
        sim_dt=float(env.morphology.timestep),
        episode_length=int(env.morphology.family.max_episode_steps),
    )


class PlaygroundBody(mjx_env.MjxEnv):
    """One swat_jax body as a Playground ``MjxEnv`` (module docstring).

    Args:
        body: a benchmark body name, an MJCF file, or a loaded body.
        physics: "c", "jax", "warp" or "auto" (:class:`~swat_jax.envs.body.BodyEnv`).
        torso_relative_x: the observation's x convention (:class:`~swat_jax.envs.body.BodyEnv`); the
            paper's intent by default.
        stale_kinematics: observe what MuJoCo's step leaves, as the original code does (off by default).
    """

    def __init__(
        self,
        body: str | Path | Morphology,
        *,
        physics: Physics = "auto",
        torso_relative_x: bool = True,
        stale_kinematics: bool = False,
    ):
        self.body = BodyEnv(
            body, physics=physics, torso_relative_x=torso_relative_x, stale_kinematics=stale_kinematics
        )
        super().__init__(default_config(self.body))
        self._motor_entries = jnp.asarray(self.body.motor_actions)
        self._limb_actions = int(np.prod(self.body.action_shape))

    def reset(self, rng: jax.Array) -> mjx_env.State:
        """A new episode of the body (``BodyEnv.reset``)."""
        return self._state(self.body.reset(rng))

    def step(self, state: mjx_env.State, action: jax.Array) -> mjx_env.State:
        """One environment step under ``action`` [nu] (one value per actuator, clipped to [-1, 1])."""
        episode = state.info[STATE_KEY].replace(data=state.data)
        tokens = jnp.zeros(self._limb_actions, action.dtype).at[self._motor_entries].set(action)
        stepped = self.body.step(episode, tokens.reshape(self.body.action_shape))
        distance = stepped.data.qpos[0] - state.data.qpos[0]
        return self._state(stepped, distance, dict(state.info))

    def _state(
        self, episode: EnvState, distance: jax.Array | float = 0.0, info: dict[str, Any] | None = None
    ) -> mjx_env.State:
        """Playground's state of the body's ``episode`` after a step that moved the torso ``distance`` along x;
        ``info`` the previous step's (wrappers keep theirs in it)."""
        info = {} if info is None else info
        info[STATE_KEY] = episode.replace(data=None, observation=None)
        return mjx_env.State(
            data=episode.data,
            obs=episode.observation.reshape(-1),
            reward=episode.reward,
            done=episode.terminated.astype(jnp.float32),
            metrics={"reward": episode.reward, "distance": jnp.asarray(distance, jnp.float32)},
            info=info,
        )

    @property
    def xml_path(self) -> str:
        return str(self.body.morphology.path)

    @property
    def action_size(self) -> int:
        """nu: one action per actuator."""
        return self.body.mj_model.nu

    @property
    def mj_model(self) -> mujoco.MjModel:
        return self.body.mj_model

    @property
    def mjx_model(self) -> Any:
        """The body's ``mjx.Model`` (put on the device on first use)."""
        from swat_jax.envs.quiet_mjx import mjx

        if not hasattr(self, "_mjx_model"):
            self._mjx_model = mjx.put_model(self.body.mj_model)
        return self._mjx_model
