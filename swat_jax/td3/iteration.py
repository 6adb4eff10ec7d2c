"""One training iteration as one jitted function: collect a chunk of steps in every task, then update.

    state -> lax.scan(act + env.step + insert, chunk steps) -> the schedule's TD3 updates:
        original:  lax.scan over tasks (lax.scan(sample the task's ring + TD3 update, updates))
        all_tasks: lax.scan(sample every ring + TD3 update, updates)

The steps are named pieces that another training loop can reuse: :class:`Collection` steps every copy
and stores what it collected (a step, a chunk), and :class:`TrainIteration` chains a chunk with the
learner's statistics, the schedule's updates, the metrics and the diagnostics.

Tasks are the batch axis of collection: the multi-task environment steps every body's copies and the
replay buffer holds one ring per task. The update schedule (:attr:`IterationConfig.schedule`) is the
reference code's by default: the tasks one after another, each taking its run of updates on its own
batches (its ``TD3.train``); ``all_tasks`` instead vmaps every update's losses over all tasks. Exploration
follows the paper: uniform random actions for each task's first ``random_steps`` steps, then the policy
plus Gaussian noise (std ``exploration_noise``, or one per copy: :func:`exploration_scales`), clipped to
[-1, 1]. Updates start once every task's buffer holds a full batch.

With the original's training loop (:attr:`IterationConfig.loop` rounds, the paper
preset), a seed updates only when its round ends, after the chunk in which it ended; from that step to the
chunk's end it waits (its environments keep their state, it stores and counts nothing), so the policy that
collects a round is the one the previous round's updates left, as in the original's training loop.

Seeds are one more batch axis, always present: the state leads with a seed axis [S] (S >= 1; which
fields have it is declared with them, :mod:`swat_jax.axes`), so S independent runs are one compiled
program.
"""

from __future__ import annotations

import dataclasses
import functools
import typing
from collections.abc import Callable
from typing import Literal

import jax
import jax.numpy as jnp
from flax import struct

from swat_jax import axes
from swat_jax.envs.multi_task import EpisodeStats, MultiTaskEnv, MultiTaskState, StepResult
from swat_jax.morphology import StructureBatch
from swat_jax.networks.policies import Params, action_mask
from swat_jax.td3 import diagnostics
from swat_jax.td3.diagnostics import Acted, EpisodeValues
from swat_jax.td3.learner import Learner, LearnerState
from swat_jax.td3.replay import ReplayBuffer, Transitions, init_buffer, insert
from swat_jax.td3.reward_scaling import discounted_returns
from swat_jax.td3.schedules import Schedule, make_update_phase

Loop = Literal["rounds", "rounds_chunked", "per_body", "all_tasks"]
"""The training loops (:attr:`IterationConfig.loop`)."""
LOOPS: tuple[str, ...] = typing.get_args(Loop)
Collected = tuple[jax.Array, jax.Array | None, jax.Array, jax.Array | None, Acted | None]
"""What one collection step gives the iteration: rewards [S, K, n], the observations acted on (with
observation normalisation), [S] bool the seeds that stepped, the discounted returns after the step
[S, K, n] (with reward scaling), and what the step acted on, for the diagnostics (with them)."""


@struct.dataclass
class TrainState:
    """Everything that changes during training (what a checkpoint must hold), for S seeds: every array leads
    with the seed axis [S] but those declared shared (:mod:`swat_jax.axes`)."""

    learner: LearnerState
    buffer: ReplayBuffer
    env: MultiTaskState
    rng: jax.Array
    """[S] keys."""
    steps_per_task: jax.Array = axes.field(seeded=False)
    """[] int32 environment steps taken in each task, summed over its copies (copies x chunk per iteration;
    with round updates, the steps a seed waited included)."""
    counted: jax.Array
    """[S] int32 environment steps counted so far, summed over tasks and copies: every step, or with
    lock-step rounds (:attr:`IterationConfig.rounds`) only the steps the original code counts."""
    round_start: jax.Array | None = None
    """[S] int32 the counted steps when each seed's current round began, with
    :attr:`IterationConfig.loop` rounds (None with another loop)."""
    discounted_return: jax.Array | None = axes.field(task=0, copy=1, default=None)
    """[S, K, n] each copy's discounted return of its episode so far, with reward scaling
    (:attr:`~swat_jax.td3.TD3Config.reward_scaling`; None without)."""
    episode_values: EpisodeValues | None = None
    """[S, K, n] each copy's episode so far for the diagnostics, with :attr:`IterationConfig.diagnostics`
    (None without)."""


@dataclasses.dataclass(frozen=True)
class IterationConfig:
    """Sizes of one iteration and the order of its updates."""

    chunk: int = 100
    """Environment steps per copy collected per iteration."""
    updates: int = 100
    """TD3 updates per iteration with the chunked loops: per body with per_body, in all with all_tasks. The rounds loops set them from the counted steps instead."""
    loop: Loop = "rounds"
    """The training loop (on rounds by default, as every default here is the paper's). rounds (the original code's, the paper preset): lock-step rounds, each lasting until every copy has ended its first episode of the round, then all copies restart; only the steps of those first episodes count. When a seed's round ends, each body takes (counted steps of the round summed over bodies) / bodies updates on batches from its own replay, so the policy acting in a round is the one its previous round trained; a seed whose round ends inside a chunk waits, storing nothing, for the chunk's end. The random phase lasts random_steps x bodies counted steps, as the original's. rounds_chunked (the intended preset): the same rounds, counts and random phase, the updates after every chunk (the counted steps' remainder carried to the next). per_body: every step counts; after every chunk, body after body, each takes `updates` updates on batches from its own replay, one Adam step each, the delayed actor step in the first of every policy_delay of them. all_tasks (the fast preset): every step counts; after every chunk, `updates` updates, each one Adam step on the mean loss over a batch from every body."""
    random_steps: int = 10_000
    """Per task: steps with uniform random actions before the policy acts."""
    exploration_noise: float = 0.126
    """Std of the Gaussian noise added to the policy's actions (of the first copy, with exploration_noise_max)."""
    exploration_noise_max: float | None = None
    """With it, each copy of a body explores with its own noise std, spread evenly from exploration_noise (the first copy) to this (the last), so one run explores both near its policy and far from it (FastTD3's noise drawn per environment, Seo et al. 2025); None: every copy exploration_noise."""
    reset_next_state: bool = True
    """Store a transition that hits the time limit with the observation of the episode that starts next as its next state, bootstrapped from it, as the original does (its vectorised environment has already reset the copy); False: the observation the step reached."""
    capacity: int = 500_000
    """Replay rows per task (the paper: 500K); a run whose --steps store fewer per task gets rings of those rows rounded up to a power of two, which hold what the full ones would."""
    diagnostics: bool = True
    """Gather the learning diagnostics in collection (:mod:`swat_jax.td3.diagnostics`: the critics' estimate of each episode's start against its return, the twin critics' disagreement, saturated actions, the exploration noise applied, each body's updates), the diag/* columns of metrics.csv. They read the run and change nothing in it."""
    capacity_all: int | None = 4_000_000
    """Replay rows summed over tasks at most (the original's rb_max): a set of more tasks than capacity_all / capacity gets capacity_all / K rows per task (Cheetah++: 333,333); None: capacity rows per task whatever K."""

    @property
    def rounds(self) -> bool:
        """The copies run in the original code's lock-step rounds, and only its steps count (the rounds loops)."""
        return self.loop in ("rounds", "rounds_chunked")

    @property
    def waits(self) -> bool:
        """A seed's updates wait for the end of its lock-step round (the rounds loop)."""
        return self.loop == "rounds"

    @property
    def schedule(self) -> Schedule:
        """The order of the updates after collecting (:mod:`swat_jax.td3.schedules`): all_tasks for the
        all_tasks loop, else original (body after body, each on its own replay)."""
        return "all_tasks" if self.loop == "all_tasks" else "original"

    def rows_per_task(self, num_tasks: int) -> int:
        """The replay rows of each of ``num_tasks`` tasks' rings (:attr:`capacity`, :attr:`capacity_all`)."""
        if self.capacity_all is not None and num_tasks * self.capacity > self.capacity_all:
            return self.capacity_all // num_tasks
        return self.capacity


def exploration_scales(config: IterationConfig, copies: int) -> jax.Array:
    """[copies] std of each copy's Gaussian exploration noise (:attr:`IterationConfig.exploration_noise_max`)."""
    if config.exploration_noise_max is None:
        return jnp.full(copies, config.exploration_noise, jnp.float32)
    return jnp.linspace(config.exploration_noise, config.exploration_noise_max, copies, dtype=jnp.float32)


def init_train_state(
    env: MultiTaskEnv, learner: Learner, config: IterationConfig, rngs: jax.Array
) -> TrainState:
    """Fresh networks, empty buffers and reset environments for every key of ``rngs`` [S], on the seed axis
    (the environments reset as seeds of one :class:`MultiTaskEnv` state, see :func:`make_train_iteration`)."""
    seeds = axes.over_seeds(rngs.shape[0])
    learner_key, env_key, rng = seeds(lambda key: tuple(jax.random.split(key, 3)))(rngs)
    init_learner = functools.partial(learner.init, tasks=env.num_bodies)
    learner_state = seeds(init_learner, out_axes=axes.seed_axes(jax.eval_shape(init_learner, rngs[0])))
    buffer = init_buffer(
        env.num_bodies,
        config.capacity,
        env.max_limbs,
        env.observation_features,
        episode_ends=learner.config.episode_ends,
        motors=env.motors_per_limb,
    )
    return TrainState(
        learner=learner_state(learner_key),
        buffer=seeds(lambda _: buffer, out_axes=axes.seed_axes(buffer))(learner_key),
        env=env.reset(env_key),
        rng=rng,
        steps_per_task=jnp.zeros((), jnp.int32),
        counted=jnp.zeros(rngs.shape[:1], jnp.int32),
        round_start=jnp.zeros(rngs.shape[:1], jnp.int32) if config.waits else None,
        discounted_return=(
            jnp.zeros((rngs.shape[0], env.num_bodies, env.copies), jnp.float32)
            if learner.config.reward_scaling
            else None
        ),
        episode_values=(
            EpisodeValues.fresh((rngs.shape[0], env.num_bodies, env.copies)) if config.diagnostics else None
        ),
    )


def seed_keys(first_seed: int, seeds: int) -> jax.Array:
    """[seeds] keys of seeds ``first_seed .. first_seed + seeds - 1``; key k is ``PRNGKey(first_seed + k)``,
    so seed k of a multi-seed run is the single-seed run with that seed."""
    return jax.vmap(jax.random.PRNGKey)(jnp.arange(first_seed, first_seed + seeds))


Carry = tuple[TrainState, jax.Array]
"""What collection carries from step to step: the state and [S] bool, the seeds that wait for their round's
updates."""
Exploration = Callable[[Params, jax.Array, jax.Array, jax.Array], tuple[jax.Array, jax.Array]]
"""``explore(actor_params, observation, uniform_phase, rng) -> (action, policy)`` of one seed
(:func:`make_exploration`)."""


@dataclasses.dataclass(frozen=True, eq=False)
class Collection:
    """The collection half of an iteration: one step of every copy of every task and seed, stored in the
    replay (:meth:`step`), and a chunk of them (:meth:`chunk`). The seeds are the state's leading axis [S];
    only acting and the replay map over them (:func:`swat_jax.axes.over_seeds`)."""

    env: MultiTaskEnv
    structure: StructureBatch
    """[K, ...] the tasks' structure as arrays, padded to ``env.max_limbs``."""
    learner: Learner
    config: IterationConfig
    explore: Exploration
    """One seed's exploration (:func:`make_exploration`), with each copy's noise scale."""

    @classmethod
    def build(
        cls, env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
    ) -> Collection:
        """The collection of ``env``'s tasks, whose structure is ``structure``, by ``learner``'s actor."""
        structure = jax.tree.map(jnp.asarray, structure)
        explore = make_exploration(learner, structure, exploration_scales(config, env.copies))
        return cls(env, structure, learner, config, explore)

    def random_phase(self, state: TrainState) -> jax.Array:
        """[] bool, shared by the seeds: every task has taken fewer than ``random_steps`` steps; with rounds
        [S], per seed: fewer than ``random_steps`` x tasks steps counted (the original's rule)."""
        if self.config.rounds:
            return state.counted < self.config.random_steps * self.env.num_bodies
        return state.steps_per_task < self.config.random_steps

    def step(self, carry: Carry, _: None = None) -> tuple[Carry, Collected]:
        """One step of every copy of every task and seed, stored in the replay; its rewards, for networks
        that normalise observations the observations it acted on, which seeds stepped, and with reward
        scaling every copy's discounted return after the step. A seed that waits for its round's updates
        (``waiting`` [S]) keeps its environment and stores nothing."""
        state, waiting = carry
        stepping = ~waiting
        seeds = axes.over_seeds(waiting.shape[0])
        rng, act_key = split_seed_keys(state.rng)
        action, policy = seeds(self.explore, in_axes=(0, 0, 0 if self.config.rounds else None, 0))(
            state.learner.actor_params, state.env.observation, self.random_phase(state), act_key
        )
        env_state, result = self.env.step(state.env, action)
        transitions = self.transitions(state.env.observation, action, result, env_state)
        counted = jnp.sum(result.counted, axis=(-2, -1), dtype=jnp.int32)
        returns, running = self.discounted_returns(state, result, stepping)
        acted = self.acted(state, policy, action, result) if self.config.diagnostics else None
        if self.config.waits:
            env_state = self.env.where_seeds(stepping, env_state, state.env)
            counted = jnp.where(stepping, counted, 0)
            waiting = waiting | result.round_over
        buffer_axes = axes.seed_axes(state.buffer)
        inserted = seeds(
            insert, in_axes=(buffer_axes, 0, 0 if self.config.waits else None), out_axes=buffer_axes
        )
        next_state = state.replace(
            buffer=inserted(state.buffer, transitions, stepping if self.config.waits else None),
            env=env_state,
            rng=rng,
            steps_per_task=state.steps_per_task + self.env.copies,
            counted=state.counted + counted,
            discounted_return=running,
        )
        observed = state.env.observation if self.learner.normalises_observations else None
        reward = jnp.where(stepping[:, None, None], result.reward, 0.0)
        return (next_state, waiting), (reward, observed, stepping, returns, acted)

    def transitions(
        self, observation: jax.Array, action: jax.Array, result: StepResult, env_state: MultiTaskState
    ) -> Transitions:
        """The step's transitions [S, K, n, ...] as the replay stores them, from the ``observation`` acted
        on, the ``action`` taken, the step's ``result`` and the environments' state after it."""
        next_observation = result.next_observation
        if self.config.reset_next_state:
            # The copies that hit the time limit have restarted: env_state holds their new episode's.
            truncated = result.truncated[..., None, None]
            next_observation = jnp.where(truncated, env_state.observation, next_observation)
        return Transitions(
            observation=observation,
            action=action,
            reward=result.reward,
            next_observation=next_observation,
            terminated=result.terminated,
            ended=result.terminated | result.truncated if self.learner.config.episode_ends else None,
        )

    def discounted_returns(
        self, state: TrainState, result: StepResult, stepping: jax.Array
    ) -> tuple[jax.Array | None, jax.Array | None]:
        """With reward scaling, every copy's discounted return [S, K, n] after the step and the one the next
        step starts from (:func:`~swat_jax.td3.reward_scaling.discounted_returns`); else None, None."""
        if not self.learner.config.reward_scaling:
            return None, None
        return discounted_returns(
            state.discounted_return,
            result.reward,
            result.terminated | result.truncated,
            stepping,
            self.learner.config.discount,
        )

    def acted(self, state: TrainState, policy: jax.Array, action: jax.Array, result: StepResult) -> Acted:
        """What the step acted on, for the diagnostics: the observation, pi(s) ``policy`` and the ``action``
        taken [S, K, n, L(, M)], the episodes it ended and whether the policy acted."""
        policy_phase = jnp.broadcast_to(~self.random_phase(state), (state.rng.shape[0],))
        ended = result.terminated | result.truncated
        return Acted(state.env.observation, policy, action, ended, policy_phase)

    def wait(self, carry: Carry) -> tuple[Carry, Collected]:
        """No step at all, for a chunk's steps after every seed has come to wait for its round's updates:
        what :meth:`step` gives a seed that waits, without the physics."""
        state, waiting = carry
        seeds, num_tasks = waiting.shape[0], self.env.num_bodies
        observed = state.env.observation if self.learner.normalises_observations else None
        reward = jnp.zeros(state.env.round_ended.shape, jnp.float32)
        waited = state.replace(steps_per_task=state.steps_per_task + self.env.copies)
        returns = state.discounted_return if self.learner.config.reward_scaling else None
        idle = None
        if self.config.diagnostics:
            action = jnp.zeros((seeds, num_tasks, *self.env.action_shape), jnp.float32)
            ended = jnp.zeros(reward.shape, bool)
            idle = Acted(state.env.observation, action, action, ended, jnp.zeros(seeds, bool))
        return (waited, waiting), (reward, observed, jnp.zeros(seeds, bool), returns, idle)

    def step_or_wait(self, carry: Carry, _: None = None) -> tuple[Carry, Collected]:
        """:meth:`step`, or :meth:`wait` once every seed waits (the rest of the chunk takes no physics)."""
        return jax.lax.cond(jnp.all(carry[1]), self.wait, self.step, carry)

    def chunk(self, state: TrainState) -> tuple[Carry, Collected]:
        """``config.chunk`` steps of every copy from ``state``, its episode statistics cleared first: the
        state after them, [S] bool the seeds whose round ended (with round updates), and what each step
        gave, stacked in front of the seed axis ([chunk, S, ...])."""
        seeds = state.rng.shape[0]
        state = state.replace(
            env=state.env.replace(episodes=EpisodeStats.zeros(self.env.num_bodies, (seeds,)))
        )
        step = self.step_or_wait if self.config.waits else self.step
        return jax.lax.scan(step, (state, jnp.zeros(seeds, bool)), None, length=self.config.chunk)


@dataclasses.dataclass(frozen=True, eq=False)
class TrainIteration:
    """The steps of one iteration of every seed (:func:`make_train_iteration`): the chunk's collection,
    the observations' and returns' statistics, the schedule's updates, the metrics and the diagnostics."""

    collection: Collection
    slots: int
    """Update slots of each task's run: with rounds a chunk's counted steps, or with round updates a whole
    round's; without, the iteration's updates."""
    motors: jax.Array
    """[K, 1, L(, M)] the real motors of each task (the structure's motor mask), for the diagnostics."""

    @classmethod
    def build(
        cls, env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
    ) -> TrainIteration:
        """The iteration of ``env``'s tasks (structure ``structure``) by ``learner``, sized by ``config``."""
        collection = Collection.build(env, structure, learner, config)
        longest = env.longest_episode if collection.config.waits else config.chunk
        motor_mask = collection.structure.motor_mask
        motors = jnp.expand_dims(motor_mask if env.motors_per_limb > 1 else motor_mask[..., 0], 1)
        return cls(collection, longest * env.copies if config.rounds else config.updates, motors)

    def iteration(self, state: TrainState) -> tuple[TrainState, dict[str, jax.Array]]:
        """Collect a chunk, let the learner observe it, run the schedule's updates; the state after them and
        the metrics of :func:`make_train_iteration`."""
        counted_before = state.counted
        (state, round_over), (rewards, observations, stepped, returns, acted) = self.collection.chunk(state)
        rng, update_key = split_seed_keys(state.rng)
        learner_state = self.observe(state.learner, observations, returns, stepped)
        state, learner_state, losses = self.update(
            state, learner_state, update_key, counted_before, round_over
        )
        metrics = self.metrics(state, losses, rewards, stepped)
        if self.collection.config.diagnostics:
            episode_values, metrics["diagnostics"] = self.diagnose(
                state, acted, rewards, stepped, losses["updated"]
            )
            state = state.replace(episode_values=episode_values)
        return state.replace(learner=learner_state, rng=rng), metrics

    def observe(
        self,
        learner_state: LearnerState,
        observations: jax.Array | None,
        returns: jax.Array | None,
        stepped: jax.Array,
    ) -> LearnerState:
        """``learner_state`` having observed the chunk: with observation normalisation its observations
        [chunk, S, K, n, L, F], with reward scaling its discounted returns [chunk, S, K, n]; ``stepped``
        [chunk, S] the seeds that stepped (the steps a seed waited hold nothing new)."""
        learner, structure = self.collection.learner, self.collection.structure
        seeds = axes.over_seeds(stepped.shape[1])
        learner_axes = axes.seed_axes(learner_state)
        if learner.normalises_observations:
            # The scan stacks the chunk in front of the seed axis: the seed axis goes first for the seeds' map.
            mask = structure.limb_mask[None, None, :, None, :] & stepped[:, :, None, None, None]
            observed = seeds(learner.observe, in_axes=(learner_axes, 0, 0), out_axes=learner_axes)
            learner_state = observed(
                learner_state, jnp.moveaxis(observations, 0, 1), jnp.moveaxis(mask, 0, 1)
            )
        if learner.config.reward_scaling:
            observed = seeds(learner.observe_returns, in_axes=(learner_axes, 0, 0), out_axes=learner_axes)
            learner_state = observed(learner_state, jnp.moveaxis(returns, 0, 1), jnp.moveaxis(stepped, 0, 1))
        return learner_state

    def update(
        self,
        state: TrainState,
        learner_state: LearnerState,
        key: jax.Array,
        counted_before: jax.Array,
        round_over: jax.Array,
    ) -> tuple[TrainState, LearnerState, dict[str, jax.Array]]:
        """The schedule's updates of ``learner_state`` on the replay of ``state``, keys ``key`` [S]: with round
        updates, each task of a seed whose round ended (``round_over`` [S]) takes the round's share
        (:func:`round_update_counts`); with rounds alone, the share of the steps counted since
        ``counted_before`` [S]; else ``config.updates``. The state with its rounds' start, the learner and
        the updates' losses."""
        collection = self.collection
        config, num_tasks = collection.config, collection.env.num_bodies
        update_phase = make_update_phase(
            collection.structure,
            collection.learner,
            config.schedule,
            self.slots,
            state.rng.shape[0],
            config.rounds,
            not collection.config.waits,
            collection.env.copies,
        )
        if collection.config.waits:
            counts, round_start = round_update_counts(state.counted, state.round_start, round_over, num_tasks)
            state = state.replace(round_start=round_start)
        elif config.rounds:
            # Each task takes (counted steps summed over tasks) // tasks updates; counting from the run's
            # start carries the remainder to the next iteration.
            counts = state.counted // num_tasks - counted_before // num_tasks
        else:
            return state, *update_phase(learner_state, state.buffer, key)
        return state, *update_phase(learner_state, state.buffer, key, counts)

    def metrics(
        self, state: TrainState, losses: dict[str, jax.Array], rewards: jax.Array, stepped: jax.Array
    ) -> dict[str, jax.Array]:
        """The iteration's metrics (:func:`make_train_iteration`) from the updates' ``losses``, the chunk's
        ``rewards`` [chunk, S, K, n] and ``stepped`` [chunk, S], and the state after it."""
        env = self.collection.env
        return {
            **losses,
            "reward": jnp.moveaxis(rewards, 0, 1),  # the scan stacks the chunk in front of the seed axis
            "episodes": state.env.episodes,
            "counted_steps": state.counted,
            "stored_steps": jnp.sum(stepped, axis=0, dtype=jnp.int32) * env.num_bodies * env.copies,
        }

    def diagnose(
        self, state: TrainState, acted: Acted, rewards: jax.Array, stepped: jax.Array, updated: jax.Array
    ) -> tuple[EpisodeValues, dict[str, jax.Array]]:
        """The chunk's diagnostics (:mod:`swat_jax.td3.diagnostics`): its states valued by the critics that
        acted in it (``state.learner``'s), in one batch, every copy's episode carried through it, and the
        updates [S, K] that took a batch of each task (``updated`` [S, updates], the update phase's)."""
        learner, structure = self.collection.learner, self.collection.structure
        seeds, num_tasks = state.rng.shape[0], self.collection.env.num_bodies
        divisor = (
            state.learner.returns.divisor() if learner.config.reward_scaling else jnp.ones((seeds, num_tasks))
        )
        estimated = axes.over_seeds(seeds)(diagnostics.make_value_estimate(learner.body_values, structure))
        q1, q2 = diagnostics.chunk_estimates(estimated, state.learner.critic_params, divisor, acted)
        episode_values, sums = diagnostics.iteration_sums(
            state.episode_values, acted, q1, q2, rewards, stepped, self.motors, learner.config.discount
        )
        per_task = updated.reshape(
            seeds, num_tasks if self.collection.config.schedule == "original" else 1, -1
        )
        return episode_values, {
            **sums,
            "updates": jnp.broadcast_to(jnp.sum(per_task, axis=-1), (seeds, num_tasks)),
        }


def split_seed_keys(rng: jax.Array) -> tuple[jax.Array, jax.Array]:
    """Each seed's key [S] split in two: the seed's next key and one to use now, [S] each."""
    return axes.over_seeds(rng.shape[0])(lambda key: tuple(jax.random.split(key)))(rng)


def make_train_iteration(
    env: MultiTaskEnv, structure: StructureBatch, learner: Learner, config: IterationConfig
) -> Callable[[TrainState], tuple[TrainState, dict[str, jax.Array]]]:
    """The pure ``iteration(state) -> (state, metrics)`` of every seed of a :class:`TrainState`; jit it once:
    one compilation serves every seed.

    ``structure`` is the bodies' StructureBatch [K, ...] padded to ``env.max_limbs``, in ``env``'s body
    order (the task set's, :func:`swat_jax.networks.task_set`).

    The seed axis is not an outer ``vmap`` of the iteration: the seeds' environments step as seeds of one
    :class:`MultiTaskEnv` state (their copies folded into one physics batch), and only the per-seed pieces
    (acting, replay, the TD3 updates) map over seeds (:func:`swat_jax.axes.over_seeds`), inside the loops.
    An outer ``vmap`` batches every loop of the traced program once more (MJX's physics loops included),
    which doubled the tracing of a two-seed iteration.

    metrics, each with a leading seed axis [S]: per-update critic and actor losses in the order the updates
    ran ([K x updates] with the original schedule, [updates] with all_tasks; :mod:`swat_jax.td3.schedules`;
    with rounds, each task's run has chunk x copies slots, the first (counted steps summed over tasks) / K
    of them updating), per-task rewards of the chunk [chunk, K, n], ``episodes``, the sums over the
    episodes each task finished during this iteration (EpisodeStats, [K]), ``counted_steps``, the steps
    counted since the run's start (:attr:`TrainState.counted`), ``stored_steps``, the transitions this
    iteration stored (summed over tasks and copies; a seed waiting for its round's updates stores none),
    and with :attr:`IterationConfig.diagnostics` ``diagnostics``, their sums per task [K]
    (:func:`swat_jax.td3.diagnostics.summed`, and ``updates``: the updates that took a batch of the task).
    """
    return TrainIteration.build(env, structure, learner, config).iteration


def round_update_counts(
    counted: jax.Array, round_start: jax.Array, round_over: jax.Array, num_tasks: int
) -> tuple[jax.Array, jax.Array]:
    """The original's ``per_morph_iter`` (``TD3.py:206``): when a seed's round is over, each of its tasks takes
    (the round's counted steps summed over tasks) // tasks updates.

    Args:
        counted: [S] steps counted since the run's start.
        round_start: [S] ``counted`` when each seed's round began.
        round_over: [S] bool, the seeds whose round ended.

    Returns:
        ``(counts, round_start)``: [S] updates per task (0 where the round goes on), and where each seed's
        next round begins.
    """
    counts = jnp.where(round_over, (counted - round_start) // num_tasks, 0)
    return counts, jnp.where(round_over, counted, round_start)


def make_exploration(
    learner: Learner, structure: StructureBatch, scales: jax.Array
) -> Callable[[Params, jax.Array, jax.Array, jax.Array], tuple[jax.Array, jax.Array]]:
    """``explore(actor_params, observation [K, n, L, F], uniform_phase [], rng) -> (action, policy)`` [K, n, L]
    ([K, n, L, M] in 3D) of one seed (paper section 5.1): the action is uniform random in the random phase,
    else the policy plus Gaussian noise of std ``scales`` [n] per copy (:func:`exploration_scales`),
    clipped to [-1, 1]; 0 on padded limbs (and on the hinge slots a 3D limb does not have). ``policy`` is
    the policy's own action pi(s), for the diagnostics."""
    mask = jnp.expand_dims(action_mask(structure), 1)
    noise_scales = scales.reshape(1, -1, *[1] * (mask.ndim - 2))

    def explore(
        actor_params: Params, observation: jax.Array, uniform_phase: jax.Array, rng: jax.Array
    ) -> tuple[jax.Array, jax.Array]:
        policy_key, random_key = jax.random.split(rng)
        policy = jax.vmap(learner.actor.apply, in_axes=(None, 0, 0))(actor_params, observation, structure)
        noise = noise_scales * jax.random.normal(policy_key, policy.shape)
        uniform = jax.random.uniform(random_key, policy.shape, minval=-1.0, maxval=1.0)
        action = jnp.where(uniform_phase, uniform, jnp.clip(policy + noise, -1.0, 1.0))
        return jnp.where(mask, action, 0.0), policy

    return explore
