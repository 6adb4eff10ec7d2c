"""The frozen, typed configuration of a training run, its presets and its JSON form (``config.json``).

``python -m swat_jax.train`` parses a :class:`TrainConfig` with tyro, so every field's docstring is its
``--help`` line; the network sizes and the environments' switches are groups of their own
(``--network.*``, ``--envs.*``), as the iteration's and TD3's are. A preset is a whole :class:`TrainConfig`
used as the defaults that flags override, written as its differences from the ``paper`` preset, which is
TrainConfig's defaults:

- ``paper``: the paper's and the reference code's: one environment copy per task and the reference code's
  training loop (:attr:`~swat_jax.td3.iteration.IterationConfig.loop` ``rounds``): lock-step rounds; when
  a round ends, task after task takes (counted steps of the round summed over tasks) / tasks updates on
  batches of 100 from its own replay, one Adam step per counted environment step, and the next round is
  collected by the policy they left.
- ``intended``: the ``paper`` preset with every quirk of the original code fixed (:func:`fixed`): the
  paper's intended method in the original's rounds, updated after every chunk (loop ``rounds_chunked``).
- ``fast``: the recipe measured fastest to the original trainer's final return on a 2-core CPU
  (docs/training.md): four copies per task and the ``all_tasks`` loop (after every chunk, each update one
  Adam step on a small batch from every task), 3-step returns, each body's rewards scaled by the spread of its returns,
  TD targets halfway between the twin target critics' minimum and mean, and the sizes and hyperparameters it
  was measured at (a width-32 one-layer network, learning rate 1e-3, 1,000 random steps and 50,000 replay
  rows per body).

Budget convention (the benchmark's): ``steps`` counts environment steps summed over all bodies of the set,
so Animal-Walkers' 10M steps give each of its 5 bodies 2M.
"""

from __future__ import annotations

import dataclasses
import functools
import json
import math
import typing
from pathlib import Path
from typing import Any, Literal

import numpy as np

from swat_jax.envs.config import EnvConfig
from swat_jax.errors import ConfigError, require_positive
from swat_jax.morphology import SETS, get_set, load
from swat_jax.networks import NAMED_VARIANTS, NetworkConfig, StructureMismatch, network_config
from swat_jax.networks.config import NETWORK_SIZES, NetworkSizes
from swat_jax.networks.smp import most_children
from swat_jax.runs import formats
from swat_jax.td3.iteration import LOOPS, IterationConfig
from swat_jax.td3.learner import TD3Config

Algorithm = Literal["swat", "amorpheus", "smp", "swat_no_pe", "swat_no_re", "swat_no_pe_re", "set"]
Preset = Literal["paper", "intended", "fast"]
Split = Literal["train", "test", "all"]


CONFIG_FILE = "config.json"
"""The resolved config in every run directory."""


PRESET_NAMES: tuple[str, ...] = typing.get_args(Preset)


HOST_ONLY = "host_only"
"""The metadata key of the TrainConfig fields that only the host loop reads (:func:`host_only`)."""


def host_only(default: Any) -> Any:
    """A TrainConfig field that no compiled program depends on: where and how long the run goes, how often
    it logs, evaluates and checkpoints, its first seed and transfer source, and how its bodies are named
    (the programs see them as models); :func:`swat_jax.runs.programs.recipe` leaves it out."""
    return dataclasses.field(default=default, metadata={HOST_ONLY: True})


@dataclasses.dataclass(frozen=True)
class TrainConfig:
    """Train one policy on every body of an environment set with TD3 (SWAT, Hong et al. 2022)."""

    env: str = host_only("animal_walkers")
    """Environment set (hopper, walker, cheetah, humanoid, wh, whh, cwh, cwhh, animal_walkers; in 3D 3d_hopper, 3d_walker, 3d_humanoid, 3d_cheetah, 3d_whh, 3d_cwhh, 3d_*_v2: python -m swat_jax.morphology list) or a folder of MJCF files; trains on its train split."""
    split: Split = host_only("train")
    """Bodies of --env to train on: its train bodies, its held-out test bodies (fine-tuning on unseen bodies, paper section 5.3) or all."""
    bodies: tuple[str, ...] = host_only(())
    """Train on these bodies (benchmark names or MJCF paths) instead of a split of --env."""
    init_from: str = host_only("")
    """Start from the actor and critic (and their targets) of this run directory's newest checkpoint; optimizers and replay buffers start fresh (transfer, paper section 5.3)."""
    init_seed_index: int = host_only(0)
    """With --init-from: which seed of that run (an index into its seeds) every seed of this run starts from."""
    algo: Algorithm = "swat"
    """Network: swat, amorpheus, smp, a SWAT ablation (swat_no_pe, swat_no_re, swat_no_pe_re), or set (SGRL's subequivariant transformer, 3D sets only)."""
    preset: Preset = host_only("paper")
    """Preset that gave this run its defaults: paper (the original code's computation: 1 copy per body, its lock-step rounds with the updates at each round's end, 1 update per counted step, its observation quirks), intended (paper with every quirk fixed) or fast (the recipe measured fastest to the original's return on a CPU, docs/training.md: paper with the quirks fixed, 4 copies of chunk 16, 256 all_tasks updates of batch 25 per body per iteration, 3-step returns, per-body reward scaling, target pessimism 0.25, an action penalty 0.003, a width-32 one-layer network (feed-forward 64, Flax's initial weights) with learning rate 1e-3, 1,000 random steps and 50,000 replay rows per body)."""
    seed: int = host_only(0)
    """Seed of network initialisation, resets, exploration and replay sampling (the first seed, with --seeds)."""
    seeds: int = 1
    """Independent runs trained in one program, seeds seed .. seed+seeds-1 (a batch axis of the whole training state)."""
    steps: int = host_only(10_000_000)
    """Environment steps to train for, summed over all bodies of the set (the paper's budget convention)."""
    counted_steps: int = host_only(0)
    """Stop once every seed has counted this many environment steps, summed over the bodies (0: off, --steps alone ends the run). With the paper preset's lock-step rounds these are the steps the original counts, so the run stops where the original's --max_timesteps does: after the first round that reaches it, and its updates. --steps still caps the steps taken (and sizes the replay rings): a run that reaches that cap first stops there and says so."""
    envs: EnvConfig = dataclasses.field(default_factory=EnvConfig)
    """How the bodies are simulated and observed: copies, variants, physics, the original's observation quirks."""
    network: NetworkSizes = dataclasses.field(default_factory=NetworkSizes)
    """The sizes of --algo's networks and the traversal of its positional embedding."""
    iteration: IterationConfig = dataclasses.field(default_factory=IterationConfig)
    """One jitted iteration: the training loop, per-copy steps collected (chunk), updates, random steps, noise, replay capacity."""
    td3: TD3Config = dataclasses.field(default_factory=TD3Config)
    """TD3 hyperparameters (the paper's by default); batch_size is per body."""
    limb_buckets: int = 3
    """With --iteration.loop all_tasks: update tasks of similar size together at their own limb count, in at most this many groups (fewer FLOPs, a longer compile of the update; 1: every task padded to the largest body)."""
    log_interval: int = host_only(0)
    """Environment steps (all bodies) between metric rows (CSV, TensorBoard, progress bar); 0: a twentieth of --steps, at most 10,000 (20 points on a short run's curve, one per 10,000 steps on a long one)."""
    eval_interval: int = host_only(0)
    """Environment steps (all bodies) between deterministic evaluations of the policy on the train bodies, logged as eval/* columns at the next metrics row; 0 turns them off."""
    eval_episodes: int = 10
    """Deterministic episodes per body in each evaluation during training (from the same initial states every time)."""
    checkpoint_interval: int = host_only(200_000)
    """Environment steps (all bodies) between checkpoints; one is also written at the end and on Ctrl-C."""
    keep_checkpoints: int = host_only(2)
    """Most recent checkpoints kept on disk."""
    run_dir: str = host_only("")
    """Run directory; empty means runs/<env>-<algo>-seed<seed>."""

    def __post_init__(self) -> None:
        self._resolve_paths()
        self._check_run()
        self._check_iteration()
        self._check_replay()
        self._check_td3()
        try:
            self.network_config()
        except ValueError as error:
            raise ConfigError(f"network sizes: {error}") from error

    def _resolve_paths(self) -> None:
        """``env``, ``bodies`` and ``init_from`` as absolute paths where they are paths (benchmark names stay
        names), so the run resumes and evaluates from anywhere."""
        try:
            environment_set = get_set(self.env)
        except ValueError as error:
            raise ConfigError(f"--env: {error}") from error
        if SETS.get(environment_set.name) is not environment_set:
            object.__setattr__(self, "env", str(Path(self.env).expanduser().resolve()))
        object.__setattr__(self, "bodies", tuple(_absolute_if_path(body) for body in self.bodies))
        if self.init_from:
            object.__setattr__(self, "init_from", str(Path(self.init_from).expanduser().resolve()))
        if not self.bodies and not environment_set.split(self.split):
            raise ConfigError(
                f"--split {self.split}: {self.env} has no {self.split} bodies; use another --split or --bodies"
            )

    def _check_run(self) -> None:
        """The run's own fields: names, counts and intervals."""
        if self.init_seed_index < 0:
            raise ConfigError(f"--init-seed-index must be 0 or more, got {self.init_seed_index}")
        if self.algo not in NAMED_VARIANTS:
            raise ConfigError(f"algo must be one of {', '.join(NAMED_VARIANTS)}, got {self.algo!r}")
        if self.preset not in PRESET_NAMES:
            raise ConfigError(f"preset must be one of {', '.join(PRESET_NAMES)}, got {self.preset!r}")
        for name in ("steps", "seeds", "checkpoint_interval", "keep_checkpoints"):
            require_positive(f"--{name.replace('_', '-')}", getattr(self, name))
        if self.counted_steps < 0:
            raise ConfigError(f"--counted-steps must be 0 (off) or more, got {self.counted_steps}")
        if self.log_interval < 0:
            raise ConfigError(
                f"--log-interval must be 0 (a twentieth of --steps) or more, got {self.log_interval}"
            )
        require_positive("--eval-episodes", self.eval_episodes)
        require_positive("--limb-buckets", self.limb_buckets)
        if self.eval_interval < 0:
            raise ConfigError(f"--eval-interval must be 0 (off) or more, got {self.eval_interval}")

    def _check_iteration(self) -> None:
        """The iteration's sizes, loop, exploration noise and random steps (IterationConfig lives below this
        layer and raises no ConfigError)."""
        for name in ("chunk", "updates", "capacity"):
            require_positive(f"--iteration.{name}", getattr(self.iteration, name))
        if self.iteration.loop not in LOOPS:
            raise ConfigError(
                f"--iteration.loop must be one of {', '.join(LOOPS)}, got {self.iteration.loop!r}"
            )
        noise = (self.iteration.exploration_noise, self.iteration.exploration_noise_max)
        if min(value for value in noise if value is not None) < 0:
            raise ConfigError(
                f"--iteration.exploration-noise and --iteration.exploration-noise-max are standard deviations, "
                f"0 or more; got {noise[0]} and {noise[1]}"
            )
        if self.iteration.random_steps < 0:
            raise ConfigError(
                f"--iteration.random-steps must be 0 or more, got {self.iteration.random_steps}"
            )

    def _check_replay(self) -> None:
        """The replay rings hold at least one step of every copy."""
        if self.iteration.capacity < self.envs.copies:
            raise ConfigError(
                f"--iteration.capacity ({self.iteration.capacity}) must hold at least one step of every copy "
                f"(--envs.copies {self.envs.copies})"
            )
        if self.iteration.capacity_all is not None:
            bodies = len(self.training_bodies())
            if self.iteration.rows_per_task(bodies) < self.envs.copies:
                raise ConfigError(
                    f"--iteration.capacity-all ({self.iteration.capacity_all}) over {bodies} bodies must hold at "
                    f"least one step of every copy (--envs.copies {self.envs.copies}); raise it, or give "
                    "--iteration.capacity-all None"
                )

    def _check_td3(self) -> None:
        """The TD3 settings, and those that need a loop or a network (TD3Config lives below this layer and
        raises no ConfigError)."""
        require_positive("--td3.batch-size", self.td3.batch_size)
        require_positive("--td3.policy-delay", self.td3.policy_delay)
        require_positive("--td3.n-step", self.td3.n_step)
        if self.td3.n_step > 1 and self.iteration.loop != "all_tasks":
            raise ConfigError(
                f"--td3.n-step {self.td3.n_step} sums a copy's consecutive steps from its own replay rows, which "
                f"only the all_tasks loop keeps (--iteration.loop {self.iteration.loop}); add --iteration.loop "
                "all_tasks or give --td3.n-step 1"
            )
        if self.td3.reward_scaling and self.iteration.loop != "all_tasks":
            raise ConfigError(
                "--td3.reward-scaling scales each body's rewards in the all-task update's batch from every body; "
                "add --iteration.loop all_tasks or drop --td3.reward-scaling"
            )
        if self.td3.atoms and (self.td3.atoms < 2 or self.algo in ("smp", "set")):
            raise ConfigError(
                f"--td3.atoms must be 0 (a Q value per limb) or 2 or more, with SWAT or AMORPHEUS (SMP's critic "
                f"sums its limbs' values, SET's is one invariant value a limb); got {self.td3.atoms} with --algo "
                f"{self.algo}"
            )
        if not (self.td3.action_penalty >= 0.0 and self.td3.action_penalty_from >= 0.0):
            raise ConfigError(
                "--td3.action-penalty (0: TD3's actor loss) and --td3.action-penalty-from must be 0 or "
                f"positive; got {self.td3.action_penalty} and {self.td3.action_penalty_from}"
            )
        if not 0.0 <= self.td3.target_pessimism <= 1.0:
            raise ConfigError(
                f"--td3.target-pessimism must be in [0, 1] (1: the twin target critics' minimum, 0: their "
                f"mean); got {self.td3.target_pessimism}"
            )
        if self.td3.atoms and self.td3.target_pessimism not in (0.0, 1.0):
            raise ConfigError(
                f"--td3.atoms needs --td3.target-pessimism 0 or 1 (the distributional critic bootstraps from one "
                f"critic's distribution or the twins' mixture); got {self.td3.target_pessimism} (the fast "
                f"preset's is between): add --td3.target-pessimism 1"
            )
        if self.td3.atoms and not self.td3.value_min < self.td3.value_max:
            raise ConfigError(
                f"--td3.value-min ({self.td3.value_min}) must be below --td3.value-max ({self.td3.value_max})"
            )

    def network_config(self) -> NetworkConfig:
        """The network of ``algo`` with the sizes of ``network``."""
        sizes = {
            name: getattr(self.network, name)
            for name in NETWORK_SIZES
            if getattr(self.network, name) is not None
        }
        if self.algo == "smp" and self.network.max_children is None:
            sizes["max_children"] = _most_children(self.training_bodies())
        sizes["initialisation"] = self.network.initialisation
        sizes["observation_normalisation"] = self.network.observation_normalisation
        if self.network.smp_hidden is not None:
            sizes.update(up_hidden=(self.network.smp_hidden,) * 2, down_hidden=(self.network.smp_hidden,) * 2)
        return network_config(self.algo, **sizes)

    def training_bodies(self) -> tuple[str, ...]:
        """The bodies this run trains on: ``bodies`` if given, else ``split`` of ``env`` (names, or MJCF
        paths for a folder)."""
        return self.bodies or get_set(self.env).split(self.split)

    def directory(self) -> Path:
        """The run directory."""
        return Path(self.run_dir or f"runs/{Path(self.env).name}-{self.algo}-{self.seed_label()}")

    def seed_values(self) -> tuple[int, ...]:
        """The seeds of the run's independent runs, in the order of the state's seed axis."""
        return tuple(range(self.seed, self.seed + self.seeds))

    def seed_label(self) -> str:
        """``seed3`` for one seed, ``seeds0-4`` for several."""
        return f"seed{self.seed}" if self.seeds == 1 else f"seeds{self.seed}-{self.seed + self.seeds - 1}"

    def structure_fix(self, mismatch: StructureMismatch) -> str:
        """The flag that lets this run's network take bodies it refused, and the value it needs."""
        flag = f"--network.{mismatch.setting.replace('_', '-')}"
        return f"train with {flag} {mismatch.needed} or more (this run has {getattr(self.network_config(), mismatch.setting)})"

    def steps_per_iteration(self, num_bodies: int) -> int:
        """Environment steps, summed over bodies, of one iteration."""
        return num_bodies * self.envs.copies * self.iteration.chunk

    def metrics_interval(self) -> int:
        """Environment steps between metric rows: ``log_interval``, or with 0 a twentieth of ``steps``, at
        most 10,000."""
        return self.log_interval or min(10_000, max(1, self.steps // 20))

    def iterations(self, num_bodies: int) -> int:
        """Iterations of the whole run: ``steps`` rounded up to whole iterations (at least one)."""
        return max(1, math.ceil(self.steps / self.steps_per_iteration(num_bodies)))

    def replay_rows(self, num_bodies: int) -> int:
        """Rows of each task's replay ring: the transitions the run stores per task (every copy's steps of
        every iteration) rounded up to a power of two, or the capacity of its rings
        (:meth:`~swat_jax.td3.iteration.IterationConfig.rows_per_task`) when that is smaller.

        A ring that the run cannot overfill holds what the full-size one would: it is never overwritten, so
        it samples the same rows. The rounding lets budgets within a factor of two of each other share one
        compiled program (the ring's size is one of its shapes), for at most twice the rows filled."""
        stored = self.iterations(num_bodies) * self.iteration.chunk * self.envs.copies
        return min(self.iteration.rows_per_task(num_bodies), 1 << (stored - 1).bit_length())

    def to_json(self) -> str:
        """The config.json of this config (:data:`~swat_jax.runs.formats.CONFIG_VERSION`'s layout)."""
        fields = formats.versioned(dataclasses.asdict(self), formats.CONFIG_VERSION)
        return json.dumps(fields, indent=2) + "\n"


def fixed(config: TrainConfig) -> TrainConfig:
    """``config`` with every quirk of the original code fixed: what the paper intends (docs/fidelity.md).
    Its training loop's quirks too: updates after every chunk instead of at the rounds' ends, time-limit
    transitions bootstrapped from the state they reached, replay rows per body whatever the set's size."""
    return dataclasses.replace(
        config,
        envs=dataclasses.replace(config.envs, torso_relative_x=True, stale_kinematics=False),
        network=dataclasses.replace(config.network, reference_inorder=False),
        iteration=dataclasses.replace(
            config.iteration,
            loop="rounds_chunked" if config.iteration.loop == "rounds" else config.iteration.loop,
            reset_next_state=False,
            capacity_all=None,
        ),
    )


PAPER = TrainConfig()
"""The base every preset differs from: the paper's and the reference code's computation (TrainConfig's defaults)."""
PRESETS: dict[str, TrainConfig] = {
    "paper": PAPER,
    "intended": dataclasses.replace(fixed(PAPER), preset="intended"),
    "fast": dataclasses.replace(
        fixed(PAPER),
        preset="fast",
        envs=dataclasses.replace(fixed(PAPER).envs, copies=4),
        network=dataclasses.replace(
            fixed(PAPER).network, width=32, heads=2, layers=1, feedforward=64, initialisation="flax"
        ),
        iteration=dataclasses.replace(
            fixed(PAPER).iteration,
            chunk=16,
            updates=256,
            loop="all_tasks",
            random_steps=1_000,
            capacity=50_000,
        ),
        td3=dataclasses.replace(
            PAPER.td3,
            batch_size=25,
            learning_rate=1e-3,
            n_step=3,
            reward_scaling=True,
            target_pessimism=0.25,
            action_penalty=0.003,
        ),
    ),
}
"""The defaults each preset gives every flag: the paper's, and each other preset's differences from it."""


@functools.cache
def _most_children(bodies: tuple[str, ...]) -> int:
    """The most children of any limb of these bodies (at least 1): SMP's child slots for them."""
    return max(1, *(most_children(np.asarray(load(body).parents)) for body in bodies))


def _absolute_if_path(body: str) -> str:
    """An MJCF path made absolute; a benchmark body name unchanged."""
    path = Path(body).expanduser()
    return str(path.resolve()) if path.suffix.lower() == ".xml" or path.exists() else body


def flag_values(config: Any, prefix: str = "--") -> dict[str, Any]:
    """Every value of a config (a dataclass) by its flag (``--envs.copies``), nested groups included."""
    values = {}
    for field in dataclasses.fields(config):
        value, flag = getattr(config, field.name), prefix + field.name.replace("_", "-")
        values.update(flag_values(value, flag + ".") if dataclasses.is_dataclass(value) else {flag: value})
    return values


def config_flags(config: TrainConfig) -> list[str]:
    """``python -m swat_jax.train`` flags that build ``config``: its preset, then every value that differs
    from the preset's (the short form of a config for reports and printed commands)."""
    preset = flag_values(PRESETS[config.preset])
    flags = ["--preset", config.preset]
    for flag, value in flag_values(config).items():
        if value == preset[flag]:
            continue
        if isinstance(value, bool):
            group, _, name = flag[2:].rpartition(".")
            flags.append(f"--{group + '.' if group else ''}{'' if value else 'no-'}{name}")
        elif isinstance(value, tuple):
            flags += [flag, *map(str, value)]
        else:
            flags += [flag, str(value)]
    return flags


def load_config(path: str | Path) -> TrainConfig:
    """Read a run's ``config.json``; ConfigError names the file and the field when it does not fit."""
    path = Path(path)
    try:
        fields = json.loads(path.read_text())
    except FileNotFoundError as error:
        raise ConfigError(f"{path}: no such file; is this a swat_jax run directory?") from error
    except (OSError, json.JSONDecodeError) as error:
        raise ConfigError(f"{path}: not readable JSON ({error}); restore it or start a new run") from error
    try:
        current = formats.current_config(fields)
    except formats.FormatError as error:
        raise ConfigError(f"{path}: {error}") from error
    return _build(TrainConfig, current, path)


def _build(cls: type, fields: Any, path: Path) -> Any:
    """``cls(**fields)`` with nested dataclasses rebuilt and every field name checked."""
    if not isinstance(fields, dict):
        raise ConfigError(f"{path}: expected an object for {cls.__name__}, got {fields!r}")
    known = {field.name: field for field in dataclasses.fields(cls)}
    unknown = sorted(set(fields) - set(known))
    if unknown:
        raise ConfigError(f"{path}: unknown {cls.__name__} fields {unknown}; valid: {', '.join(known)}")
    hints = typing.get_type_hints(cls)
    values = {}
    for name, value in fields.items():
        kind = hints[name]
        if dataclasses.is_dataclass(kind):
            value = _build(kind, value, path)
        elif isinstance(value, list):
            value = tuple(value)
        values[name] = value
    try:
        return cls(**values)
    except (TypeError, ValueError) as error:
        raise ConfigError(f"{path}: {error}") from error
