"""Independent NumPy computations from MuJoCo C data that the tests compare swat_jax against."""

from __future__ import annotations

import mujoco
import numpy as np
from scipy.spatial.transform import Rotation


def numpy_observation(body, model, data, torso_relative_x=True) -> np.ndarray:
    """The benchmark's per-limb observation, written out limb by limb from MuJoCo C data and Jacobians.

    ``torso_relative_x=False`` does what the original code does: it subtracts the torso's x inside
    ``data.xpos`` (restored afterwards) before reading positions and Jacobians, so the torso's velocity
    is taken at that shifted point."""
    rows = []
    torso_x = data.xpos[1, 0]
    if not torso_relative_x:
        data.xpos[1, 0] = 0.0
    for limb in range(body.num_limbs):
        b = limb + 1
        position = data.xpos[b].copy()
        if torso_relative_x:
            position[0] -= torso_x
        # Velocity of the frame origin = frame Jacobian @ qvel (not mj_objectVelocity: that is the COM's).
        jacobian_linear, jacobian_angular = np.zeros((3, model.nv)), np.zeros((3, model.nv))
        mujoco.mj_jacBody(model, data, jacobian_linear, jacobian_angular, b)
        linear, angular = jacobian_linear @ data.qvel, jacobian_angular @ data.qvel
        w, x, y, z = data.xquat[b]
        rotation = Rotation.from_quat([x, y, z, w]).as_rotvec()
        one_hot = np.zeros(body.family.num_limb_types)
        if body.limb_types[limb] >= 0:
            one_hot[body.limb_types[limb]] = 1
        joint = np.zeros(3)
        if limb > 0:
            ((low, high),) = body.joint_ranges[limb]
            address = model.jnt_qposadr[
                mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, body.joint_names[limb][0])
            ]
            angle = np.degrees(data.qpos[address])
            joint = np.array([(angle - low) / (high - low), (180 + low) / 360, (180 + high) / 360])
        rows.append(np.concatenate([position, np.clip(linear, -10, 10), angular, rotation, one_hot, joint]))
    data.xpos[1, 0] = torso_x
    return np.array(rows)


def mujoco_c_rollout(
    model: mujoco.MjModel, start, actions: np.ndarray, motor_actions: np.ndarray, frame_skip: int
) -> tuple[np.ndarray, np.ndarray, mujoco.MjData]:
    """Plain ``mujoco.mj_step`` from ``start``'s qpos and qvel (an MJX state's data) under ``actions``
    [steps, n] (per limb; the motors' clipped to [-1, 1]), ``frame_skip`` physics steps each: qpos
    [steps, nq] and qvel [steps, nv] after every environment step, and the final data (``mj_forward``
    applied)."""
    data = mujoco.MjData(model)
    data.qpos[:], data.qvel[:] = start.qpos, start.qvel
    qpos, qvel = [], []
    for action in actions:
        data.ctrl[:] = np.clip(action[motor_actions], -1, 1)
        for _ in range(frame_skip):
            mujoco.mj_step(model, data)
        qpos.append(data.qpos.copy())
        qvel.append(data.qvel.copy())
    mujoco.mj_forward(model, data)
    return np.array(qpos), np.array(qvel), data


def float64_state(data) -> tuple[np.ndarray, np.ndarray]:
    """qpos [..., nq] and qvel [..., nv] of a simulator state as float64: an MJX state's own, a C physics
    state's rounding plus its two remainders (``swat_jax.envs.c_physics.CData``)."""
    qpos, qvel = np.asarray(data.qpos, np.float64), np.asarray(data.qvel, np.float64)
    if not hasattr(data, "remainder"):
        return qpos, qvel
    nq, nv = qpos.shape[-1], qvel.shape[-1]
    size = data.remainder.shape[-1] // 2
    remainder = np.asarray(data.remainder, np.float64)
    parts = remainder[..., :size] + remainder[..., size:]
    return qpos + parts[..., :nq], qvel + parts[..., nq : nq + nv]


def mjx_and_c_rollouts(name: str, steps: int, seed: int = 0, physics: str = "jax") -> dict[str, np.ndarray]:
    """The same random actions through the MJX environment (on the ``physics`` implementation) and through
    plain ``mujoco.mj_step``.

    Both start from the MJX environment's reset state. Returns per-step max abs differences of qpos
    and qvel [steps], the MJX observations [steps, n, F], rewards and termination flags [steps], and
    the NumPy observation of the final MuJoCo C state [n, F].
    """
    import jax

    from swat_jax.envs import BodyEnv

    env = BodyEnv(name, physics=physics)
    actions = (
        np.random.default_rng(seed)
        .uniform(-1, 1, (steps, env.num_limbs))
        .astype(np.float32)
        .astype(np.float64)
    )

    def rollout(rng, actions):
        start = env.reset(rng)

        def step(state, action):
            state = env.step(state, action)
            return state, state

        return start, jax.lax.scan(step, start, actions)[1]

    start, states = jax.tree_util.tree_map(np.asarray, jax.jit(rollout)(jax.random.PRNGKey(seed), actions))
    model = env.mj_model
    qpos, qvel, data = mujoco_c_rollout(
        model, start.data, actions, env.motor_actions, env.morphology.frame_skip
    )
    env_qpos, env_qvel = float64_state(states.data)
    return dict(
        qpos_error=np.abs(qpos - env_qpos).max(axis=1),
        qvel_error=np.abs(qvel - env_qvel).max(axis=1),
        start_observation=start.observation,
        observation=states.observation,
        reward=states.reward,
        terminated=states.terminated,
        episode_length=states.episode_length,
        c_final_observation=numpy_observation(env.morphology, model, data),
    )


def mjx_and_c_variant_rollouts(
    name: str, count: int, steps: int, folder: str, seed: int = 0, physics: str = "jax"
) -> dict[str, float]:
    """``count`` variants of body ``name`` (written to ``folder``, spread 0.3) stepped together by one
    vmapped environment (on the ``physics`` implementation), each against plain ``mujoco.mj_step`` on its own MJCF file, under the same
    random actions from the MJX reset state. Returns the max abs differences over variants and steps of
    qpos and qvel, and of the final observation against the NumPy one of each variant's MuJoCo C state."""
    import jax

    from swat_jax.envs import BodyEnv
    from swat_jax.morphology.variants import Variation, write_variants

    variants = write_variants(name, count, Variation(0.3, seed), folder)
    env = BodyEnv(name, variants=variants, physics=physics)
    actions = (
        np.random.default_rng(seed)
        .uniform(-1, 1, (steps, count, env.num_limbs))
        .astype(np.float32)
        .astype(np.float64)
    )

    def rollout(keys, table, actions):
        start = jax.vmap(env.reset)(keys, table)

        def step(state, action):
            state = jax.vmap(env.step)(state, action)
            return state, state

        return start, jax.lax.scan(step, start, actions)[1]

    keys = jax.random.split(jax.random.PRNGKey(seed), count)
    start, states = jax.tree_util.tree_map(np.asarray, jax.jit(rollout)(keys, env.variant_table(), actions))
    errors = dict(qpos=0.0, qvel=0.0, observation=0.0, spread=0.0)
    env_qpos, env_qvel = float64_state(states.data)
    for j, variant in enumerate(variants):
        model = mujoco.MjModel.from_xml_path(str(variant.path))
        start_j = jax.tree_util.tree_map(lambda x, j=j: x[j], start.data)
        qpos, qvel, data = mujoco_c_rollout(
            model, start_j, actions[:, j], env.motor_actions, variant.frame_skip
        )
        errors["qpos"] = max(errors["qpos"], float(np.abs(qpos - env_qpos[:, j]).max()))
        errors["qvel"] = max(errors["qvel"], float(np.abs(qvel - env_qvel[:, j]).max()))
        observed = numpy_observation(variant, model, data)
        errors["observation"] = max(
            errors["observation"], float(np.abs(observed - states.observation[-1, j]).max())
        )
    errors["spread"] = float(np.abs(states.data.qpos[-1] - states.data.qpos[-1, :1]).max())
    return errors
