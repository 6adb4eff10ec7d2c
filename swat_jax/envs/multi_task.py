"""K bodies with n parallel copies each, stepped in one jitted function and padded to one limb count.

Bodies with different trees compile to different MJX programs, so each body is vmapped over its own
copies and the K programs sit side by side in the same jitted step (a Python loop at trace time, none at
run time). Observations and actions are padded to L = max_limbs so that the policy sees one batch
``[K, n, L, F]`` (paper section 3); the structure of the bodies, which tells real limbs from padding, is
the task set's (:func:`swat_jax.networks.task_set`), not the environment's.

Finished copies (terminated, truncated, or unstable) start a new episode in the same step. The step
returns the observation reached *before* that reset, for the replay buffer, and the state holds the
observation after it, for acting.

With ``lock_step``, the copies also run in the original code's lock-step rounds: a round lasts until every
copy has ended its first episode of the round; a copy that ended it keeps stepping (its later episodes
start as usual), and when the round ends every copy starts a new episode, cutting the ones still running.
A step *counts* (toward the step budget and the number of updates, as the original's step counter) while
the copy's first episode of the round goes on after it: neither the step that ends it nor the steps after.
The episode statistics then hold only each copy's first episode of every round, as the original logs them:
its later episodes of the round are cut when the round ends unless they are short, so counting them would
weigh short episodes more.

Several independent runs (seeds) step together as a leading seed axis [S] on every array of the state:
each seed splits its own keys, and the physics sees the seeds' copies folded into one batch of S x n.
Folding, not an outer ``vmap``, is what keeps tracing cheap: ``vmap`` over a function that already vmaps
MJX's loops batches every loop body once more (a second pass over the whole physics per seed axis).

On MuJoCo C physics with a device mesh (``mesh``), every physics call splits the folded copies over all the
mesh's devices: each device calls MuJoCo for its own block (:class:`~swat_jax.envs.c_physics.PhysicsShards`).
A body whose S x n copies do not divide by the devices gets padding copies up to the next multiple (at most
one fewer than the devices; copies of its first copy, stepped and dropped). MJX physics needs none of this:
XLA partitions its operations like the rest of the program.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct
from jax.sharding import Mesh

from swat_jax import axes
from swat_jax.envs.body import BodyEnv, EnvState, Variant
from swat_jax.envs.c_physics import PhysicsShards
from swat_jax.envs.physics import Physics, resolve_physics
from swat_jax.morphology.mjcf import load
from swat_jax.morphology.types import Morphology


@struct.dataclass
class EpisodeStats:
    """Sums over the episodes each body finished since the stats were last cleared, [K] each (with lock-step
    rounds, only each copy's first episode of a round)."""

    return_sum: jax.Array
    length_sum: jax.Array
    count: jax.Array

    @classmethod
    def zeros(cls, num_bodies: int, seeds: tuple[int, ...] = ()) -> EpisodeStats:
        """Zero sums [*seeds, K]."""
        shape = (*seeds, num_bodies)
        return cls(
            return_sum=jnp.zeros(shape, jnp.float32),
            length_sum=jnp.zeros(shape, jnp.float32),
            count=jnp.zeros(shape, jnp.int32),
        )

    def plus(self, bodies: Sequence[EnvState], logged: jax.Array) -> EpisodeStats:
        """These sums and the episodes that ``logged`` [*S, K, n] marks among ``bodies``' copies (K body
        states [*S, n, ...], stepped), by their returns and lengths."""
        axis = logged.ndim - 2

        def logged_sum(values: list[jax.Array]) -> jax.Array:
            return jnp.sum(jnp.where(logged, jnp.stack(values, axis), 0), axis=-1)

        return EpisodeStats(
            return_sum=self.return_sum + logged_sum([body.episode_return for body in bodies]),
            length_sum=self.length_sum + logged_sum([body.episode_length for body in bodies]),
            count=self.count + jnp.sum(logged, axis=-1, dtype=jnp.int32),
        )


@struct.dataclass
class MultiTaskState:
    """All copies of all bodies; K bodies, n copies, L = max_limbs, F features. With seeds, every array has
    a leading seed axis [S] before the shapes below."""

    bodies: tuple[EnvState, ...] = axes.field(copy=0)
    """K per-body states, each with a leading copy axis [n]."""
    observation: jax.Array = axes.field(task=0, copy=1)
    """[K, n, L, F] observations to act on (after any automatic reset), zero on padded limbs."""
    rng: jax.Array
    """Key for the reset noise of the next automatic resets."""
    episodes: EpisodeStats
    """Finished-episode sums per body [K], for logging; clear with ``state.replace(episodes=...)``."""
    round_ended: jax.Array = axes.field(task=0, copy=1)
    """[K, n] bool: with lock-step rounds, copies whose first episode of the current round has ended (all
    False without)."""

    @property
    def seeds(self) -> tuple[int, ...]:
        """The leading seed axes: () for a state without, (S,) for S seeds stepped together."""
        return self.observation.shape[:-4]


@struct.dataclass
class StepResult:
    """What one step of every copy produced, for the replay buffer; [K, n] unless stated (after the seed
    axes of the state, if any)."""

    next_observation: jax.Array
    """[K, n, L, F] observation reached by the step, before any automatic reset."""
    reward: jax.Array
    terminated: jax.Array
    """bool: the episode ended by a termination condition; the TD target does not bootstrap."""
    truncated: jax.Array
    """bool: the episode hit the time limit; the TD target bootstraps from ``next_observation``."""
    counted: jax.Array
    """bool: the step counts toward the budget (every step; with lock-step rounds, only while the copy's
    first episode of the round goes on after it)."""
    round_over: jax.Array
    """[] bool: with lock-step rounds, this step ended the round (every copy restarts); False without."""


class MultiTaskEnv:
    """K bodies x n copies on MJX with padded observations and automatic resets.

    Args:
        bodies: loaded bodies, benchmark names or MJCF paths (K of them); all must share one
            observation width (families with the same limb-type vocabulary).
        copies: n, parallel copies of each body.
        max_limbs: L, the padded limb count; defaults to the largest body's.
        torso_relative_x, stale_kinematics: see :class:`~swat_jax.envs.body.BodyEnv`.
        physics: "jax", "warp", "c" or "auto" (:class:`~swat_jax.envs.body.BodyEnv`).
        seeds: how many instances of this environment one program steps (a leading seed axis of the
            state, or a ``vmap``); "warp" sizes its contact buffers for ``2 * copies * seeds`` simulations
            per call (a step derives the stepped and the fresh copies together).
        lock_step: run in the original code's lock-step rounds (module docstring), each seed on its own.
        variants: per body, its variants (:mod:`swat_jax.morphology.variants`; empty: the body itself):
            copy j of a body runs its variant j mod (number of variants), in every seed, through one
            program per body whatever their number (:class:`~swat_jax.envs.body.BodyEnv`).
        mesh: the devices the program runs on; on physics "c" with more than one device, each calls MuJoCo
            for its own block of every body's copies (module docstring). None: the calls run on one device.
        shared_reset_key: every body of a seed draws its resets (and, in 3D, its targets) from one key
            instead of a key of its own: copy j of every body starts its episodes from the same random
            numbers, as the original code seeds every body's environment with the run's seed.

    Raises:
        ValueError: no bodies, ``copies`` < 1, a body larger than ``max_limbs``, or bodies whose
            observations have different widths.
    """

    def __init__(
        self,
        bodies: Sequence[Morphology | str],
        copies: int,
        *,
        max_limbs: int | None = None,
        torso_relative_x: bool = True,
        stale_kinematics: bool = False,
        physics: Physics = "jax",
        seeds: int = 1,
        lock_step: bool = False,
        variants: Sequence[Sequence[Morphology | str]] = (),
        mesh: Mesh | None = None,
        shared_reset_key: bool = False,
    ):
        if copies < 1:
            raise ValueError(f"copies must be at least 1, got {copies}")
        morphologies = [body if isinstance(body, Morphology) else load(body) for body in bodies]
        if not morphologies:
            raise ValueError("MultiTaskEnv needs at least one body")
        largest = max(morphologies, key=lambda body: body.num_limbs)
        if max_limbs is not None and max_limbs < largest.num_limbs:
            raise ValueError(f"{largest.name} has {largest.num_limbs} limbs, more than max_limbs={max_limbs}")
        if variants and len(variants) != len(morphologies):
            raise ValueError(f"variants: one sequence per body ({len(morphologies)}), got {len(variants)}")
        split = mesh is not None and mesh.devices.size > 1 and resolve_physics(physics) == "c"
        self.shards = PhysicsShards(mesh) if split else None
        """The devices the physics calls split over (None: one device, or MJX physics)."""
        self.envs = tuple(
            BodyEnv(
                body,
                torso_relative_x=torso_relative_x,
                stale_kinematics=stale_kinematics,
                physics=physics,
                worlds=2 * copies * seeds,
                variants=body_variants,
                shards=self.shards,
            )
            for body, body_variants in zip(morphologies, variants or [()] * len(morphologies), strict=True)
        )
        widths = {env.morphology.name: env.observation_features for env in self.envs}
        if len(set(widths.values())) > 1:
            raise ValueError(
                "these bodies have observations of different widths and cannot share a policy: "
                + ", ".join(f"{name} ({width} features)" for name, width in widths.items())
                + "; train families with different limb-type vocabularies separately"
            )
        self.copies = copies
        self.lock_step = lock_step
        self.shared_reset_key = shared_reset_key
        self.max_limbs = largest.num_limbs if max_limbs is None else max_limbs
        self.observation_features = self.envs[0].observation_features
        self.motors_per_limb = self.envs[0].morphology.motors_per_limb
        """M, actions per limb: 1 planar, 3 in 3D (the widths above keep planar and 3D bodies apart)."""

    @property
    def action_shape(self) -> tuple[int, ...]:
        """One task's action for every copy, after the leading seed and task axes: (n, L) or (n, L, M)."""
        return (self.copies, self.max_limbs) + ((self.motors_per_limb,) if self.motors_per_limb > 1 else ())

    @property
    def num_bodies(self) -> int:
        return len(self.envs)

    @property
    def body_names(self) -> tuple[str, ...]:
        return tuple(env.morphology.name for env in self.envs)

    def reset(self, rng: jax.Array) -> MultiTaskState:
        """Start an episode in every copy of every body; a key array ``rng`` [*S] starts S seeds, each from
        its key."""
        seeds = rng.shape if jax.dtypes.issubdtype(rng.dtype, jax.dtypes.prng_key) else rng.shape[:-1]
        rng, *keys = self._split(rng, seeds)
        bodies = tuple(
            _unfolded(
                self._over_copies(env.reset)(
                    _folded(self._copy_keys(key, seeds), seeds, self.copies), self._copy_variants(env, seeds)
                ),
                seeds,
                self.copies,
            )
            for env, key in zip(self.envs, keys, strict=True)
        )
        return MultiTaskState(
            bodies=bodies,
            observation=self._padded_observation(bodies, seeds),
            rng=rng,
            episodes=EpisodeStats.zeros(self.num_bodies, seeds),
            round_ended=jnp.zeros((*seeds, self.num_bodies, self.copies), bool),
        )

    def _copy_variants(self, env: BodyEnv, seeds: tuple[int, ...]) -> Variant | None:
        """[S x n, ...] the variant of every copy of every seed (copy j: variant j mod k), or None."""
        if not env.variants:
            return None
        rows = np.arange(self.copies * math.prod(seeds)) % self.copies % len(env.variants)
        return jax.tree_util.tree_map(lambda table: table[rows], env.variant_table())

    def step(self, state: MultiTaskState, action: jax.Array) -> tuple[MultiTaskState, StepResult]:
        """Apply ``action`` [*S, K, n, L] ([*S, K, n, L, M] in 3D; padded limbs ignored) to every copy; reset
        finished copies (and, with lock-step rounds, every copy when the round ends)."""
        seeds = state.seeds
        rng, *keys = self._split(state.rng, seeds)
        both = [
            _step_and_restart(
                env,
                self._over_copies,
                _folded(body_state, seeds, self.copies),
                _folded(self._body_action(action, k, env.num_limbs), seeds, self.copies),
                _folded(self._copy_keys(key, seeds), seeds, self.copies),
            )
            for k, (env, body_state, key) in enumerate(zip(self.envs, state.bodies, keys, strict=True))
        ]
        stepped = [_unfolded(after_step, seeds, self.copies) for after_step, _ in both]
        axis = len(seeds)
        bookkeeping = self._round_step(state.round_ended, jnp.stack([body.done for body in stepped], axis))
        continued = tuple(
            _unfolded(
                _where_done(_folded(bookkeeping.restart[..., k, :], seeds, self.copies), fresh, after_step),
                seeds,
                self.copies,
            )
            for k, (after_step, fresh) in enumerate(both)
        )
        result = StepResult(
            next_observation=self._padded_observation(stepped, seeds),
            reward=jnp.stack([body.reward for body in stepped], axis),
            terminated=jnp.stack([body.terminated for body in stepped], axis),
            truncated=jnp.stack([body.truncated for body in stepped], axis),
            counted=bookkeeping.counted,
            round_over=bookkeeping.round_over,
        )
        next_state = MultiTaskState(
            bodies=continued,
            observation=self._padded_observation(continued, seeds),
            rng=rng,
            episodes=state.episodes.plus(stepped, bookkeeping.logged),
            round_ended=bookkeeping.round_ended,
        )
        return next_state, result

    def _round_step(self, round_ended: jax.Array, finished: jax.Array) -> RoundStep:
        """One step's bookkeeping from the copies whose episode it ended, ``finished`` [*S, K, n]: the
        lock-step round's (:func:`lock_step_round`), or without rounds every finished copy restarts and
        logs its episode, and every step counts."""
        if self.lock_step:
            return lock_step_round(round_ended, finished)
        return RoundStep(
            restart=finished,
            round_ended=round_ended,
            counted=jnp.ones_like(finished),
            logged=finished,
            round_over=jnp.zeros(finished.shape[:-2], bool),
        )

    def _body_action(self, action: jax.Array, task: int, limbs: int) -> jax.Array:
        """Task ``task``'s actions [*S, n, limbs(, M)] of ``action`` [*S, K, n, L(, M)]."""
        motor_axes = len(self.action_shape) - 2
        task_axis = action.ndim - 3 - motor_axes
        body = jnp.take(action, task, axis=task_axis)
        return jax.lax.slice_in_dim(body, 0, limbs, axis=body.ndim - 1 - motor_axes)

    @property
    def longest_episode(self) -> int:
        """The longest time limit of the bodies: the most steps a copy's episode, and a lock-step round, lasts."""
        return max(env.morphology.family.max_episode_steps for env in self.envs)

    def where_seeds(self, advance: jax.Array, new: MultiTaskState, old: MultiTaskState) -> MultiTaskState:
        """Per seed, ``new`` where ``advance`` [S] else ``old`` (a seed that waits keeps its state)."""
        seeds = new.seeds
        per_copy = _folded(jnp.broadcast_to(advance[..., None], (*seeds, self.copies)), seeds, self.copies)
        bodies = tuple(
            _unfolded(
                _where_done(
                    per_copy, _folded(stepped, seeds, self.copies), _folded(kept, seeds, self.copies)
                ),
                seeds,
                self.copies,
            )
            for stepped, kept in zip(new.bodies, old.bodies, strict=True)
        )

        def chosen(stepped: jax.Array, kept: jax.Array) -> jax.Array:
            return jnp.where(
                advance.reshape(advance.shape + (1,) * (stepped.ndim - advance.ndim)), stepped, kept
            )

        others = jax.tree_util.tree_map(chosen, new.replace(bodies=()), old.replace(bodies=()))
        return others.replace(bodies=bodies)

    def describe_physics(self) -> str:
        """One line: which physics steps the bodies, on how many threads, over which devices."""
        simulator = self.envs[0].simulator
        if simulator.implementation != "c":
            return f"physics: MJX ({simulator.implementation!r}), compiled into the program"
        threads = f"{simulator.threads} thread{'s' * (simulator.threads > 1)}"
        if self.shards is None:
            return f"physics: MuJoCo C on {threads}, one call per step for every copy"
        local = len(self.shards.local())
        each = max(1, simulator.threads // local)
        return (
            f"physics: MuJoCo C; each of the mesh's {self.shards.size} devices steps its own block of every "
            f"body's copies; this process has {local} of them, {each} thread{'s' * (each > 1)} each"
        )

    def physics_calls(self) -> dict[int, int]:
        """MuJoCo C calls this process has made so far, over every body, by the id of the device that made
        them (every call on the first device without a mesh); empty on MJX."""
        calls: dict[int, int] = {}
        for env in self.envs:
            if env.simulator.implementation != "c":
                continue
            for shard, count in env.simulator.calls.items():
                device = self.shards.mesh.devices.flat[shard].id if self.shards else shard
                calls[device] = calls.get(device, 0) + count
        return calls

    def _over_copies(self, function: Callable) -> Callable:
        """``jax.vmap(function)`` over a leading copies axis; with :attr:`shards`, each device computes its
        own block of the copies, padded to a multiple of the devices (module docstring)."""
        if self.shards is None:
            return jax.vmap(function)
        mapped = jax.vmap(function, spmd_axis_name=self.shards.axes)
        devices = self.shards.size

        def over_copies(*args: Any) -> Any:
            copies = jax.tree_util.tree_leaves(args)[0].shape[0]
            padding = -copies % devices
            if not padding:
                return mapped(*args)
            padded = jax.tree_util.tree_map(
                lambda x: jnp.concatenate([x, jnp.repeat(x[:1], padding, axis=0)]), args
            )
            return jax.tree_util.tree_map(lambda x: x[:copies], mapped(*padded))

        return over_copies

    def _split(self, rng: jax.Array, seeds: tuple[int, ...]) -> tuple[jax.Array, ...]:
        """K + 1 keys [*S] from each seed's key: the seed's next key, then one per body (with
        ``shared_reset_key``, the same one K times)."""
        if self.shared_reset_key:
            rng, key = _per_seed(lambda key: tuple(jax.random.split(key)), seeds)(rng)
            return (rng, *[key] * self.num_bodies)
        return _per_seed(lambda key: tuple(jax.random.split(key, self.num_bodies + 1)), seeds)(rng)

    def _copy_keys(self, keys: jax.Array, seeds: tuple[int, ...]) -> jax.Array:
        """[*S, n]: one key per copy from each seed's body key [*S]."""
        return _per_seed(lambda key: jax.random.split(key, self.copies), seeds)(keys)

    def _padded_observation(self, bodies: Sequence[EnvState], seeds: tuple[int, ...]) -> jax.Array:
        """[*S, K, n, L, F] from K per-body observations [*S, n, limbs_k, F], zeros on padded limbs."""
        return jnp.stack(
            [
                jnp.pad(
                    body.observation,
                    ((0, 0),) * (len(seeds) + 1) + ((0, self.max_limbs - env.num_limbs), (0, 0)),
                )
                for env, body in zip(self.envs, bodies, strict=True)
            ],
            len(seeds),
        )


class RoundStep(NamedTuple):
    """One step's lock-step bookkeeping (:func:`lock_step_round`): [*S, K, n] bool unless stated."""

    restart: jax.Array
    """The copies that start a new episode: the finished ones, and every copy of a seed whose round this
    step ended (all its copies have ended their first episode)."""
    round_ended: jax.Array
    """The copies whose first episode of the (next) round has ended."""
    counted: jax.Array
    """The steps that count: the copy's first episode of the round goes on after this step."""
    logged: jax.Array
    """The copies whose first episode of the round this step ended (the episodes the original logs)."""
    round_over: jax.Array
    """[*S] bool: this step ended the seed's round."""


def lock_step_round(round_ended: jax.Array, finished: jax.Array) -> RoundStep:
    """One step of the original code's lock-step rounds (its training loop's ``done_list`` bookkeeping).

    Args:
        round_ended: [*S, K, n] bool, copies whose first episode of the round ended before this step.
        finished: [*S, K, n] bool, copies whose episode this step ended (terminated or truncated).
    """
    ended = round_ended | finished
    round_over = jnp.all(ended, axis=(-2, -1), keepdims=True)
    return RoundStep(
        restart=finished | round_over,
        round_ended=ended & ~round_over,
        counted=~ended,
        logged=finished & ~round_ended,
        round_over=round_over[..., 0, 0],
    )


def _per_seed(function: Callable, seeds: tuple[int, ...]) -> Callable:
    """``function`` mapped over the seed axes (itself when there are none): for the seeds' own keys."""
    for _ in seeds:
        function = jax.vmap(function)
    return function


def _folded(tree: Any, seeds: tuple[int, ...], copies: int) -> Any:
    """Every array [*S, n, ...] as [S x n, ...]: the seeds' copies as one batch of copies. Arrays without
    these axes (a Warp state's empty placeholders, :class:`~swat_jax.envs.physics.Simulator`) stay as
    they are."""
    lead = (*seeds, copies)
    return jax.tree_util.tree_map(
        lambda x: x.reshape(math.prod(lead), *x.shape[len(lead) :]) if x.shape[: len(lead)] == lead else x,
        tree,
    )


def _unfolded(tree: Any, seeds: tuple[int, ...], copies: int) -> Any:
    """The inverse of :func:`_folded`."""
    folded = math.prod(seeds) * copies
    return jax.tree_util.tree_map(
        lambda x: x.reshape(*seeds, copies, *x.shape[1:]) if x.shape[:1] == (folded,) else x, tree
    )


def _step_and_restart(
    env: BodyEnv,
    over_copies: Callable[[Callable], Callable],
    state: EnvState,
    action: jax.Array,
    keys: jax.Array,
) -> tuple[EnvState, EnvState]:
    """Every copy [n] stepped, and a fresh episode for every copy from its key (``keys`` [n]; used where
    the step ended one); the physics calls mapped over the copies by ``over_copies`` (``jax.vmap``'s
    contract).

    The stepped and the fresh simulator states share one kinematics pass over 2n copies, so the
    compiled step holds one kinematics program per body instead of two (with ``stale_kinematics`` the
    stepped copies only need their velocities).
    """
    copies = action.shape[0]
    variant = state.variant
    simulated = over_copies(env.simulate)(state.data, action, variant)
    initial, target = jax.vmap(env.new_episode)(keys, variant)
    if env.stale_kinematics:
        simulated = over_copies(env.step_kinematics)(simulated, variant)
        initial = over_copies(env.kinematics)(initial, variant)
    else:
        both = jax.tree_util.tree_map(_joined, simulated, initial)
        both = over_copies(env.kinematics)(both, jax.tree_util.tree_map(_joined, variant, variant))
        simulated, initial = (
            jax.tree_util.tree_map(lambda x, s=s: x[s], both)
            for s in (slice(None, copies), slice(copies, None))
        )
    return jax.vmap(env.finish_step)(state, simulated), jax.vmap(env.start)(initial, variant, target)


def _joined(first: jax.Array, second: jax.Array) -> jax.Array:
    """``first`` and ``second`` concatenated along their copy axis."""
    return jnp.concatenate([first, second])


def _where_done(done: jax.Array, fresh: EnvState, stepped: EnvState) -> EnvState:
    """Per copy, ``fresh`` where ``done`` [n] else ``stepped``.

    Selected copy by copy (vmapped) with ``mjx.Data.where``, which leaves alone the buffers a Warp state
    shares across copies (:class:`~swat_jax.envs.physics.Simulator`).
    """

    def select(done: jax.Array, fresh: EnvState, stepped: EnvState) -> EnvState:
        others = jax.tree_util.tree_map(
            lambda new, old: jnp.where(done, new, old), fresh.replace(data=None), stepped.replace(data=None)
        )
        return others.replace(data=stepped.data.where(done, fresh.data))

    return jax.vmap(select)(done, fresh, stepped)
