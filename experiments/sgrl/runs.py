"""The two sides of the 3D comparison at one scale, each seed its own process on one core: SGRL's own trainer
(its unmodified ``main.py`` with its ``configs/3d.py``, in its own virtual environment) and swat_jax's paper
preset with SGRL's settings where swat_jax has a switch for them (docs/fidelity.md, rows S1-S15).

SGRL counts its budget in a counter of its own (fidelity row S4): 5,000 after its warm-up, then one per stored
transition and one per update, and it stops at the first epoch end (every 1,000 lock-step steps) past
``max_epoch`` x 1,000. Both sides' curves are drawn against that counter: a swat_jax row's is
:meth:`SgrlScale.counter`, the warm-up's 5,000 plus two per step it counted after its random phase.
"""

from __future__ import annotations

import dataclasses
import hashlib
import json
import os
import shlex
import shutil
import subprocess
import sys
from collections.abc import Mapping, Sequence
from pathlib import Path

from experiments.original.runs import CHUNK, Settings, paper_config, train_foreign
from experiments.paper import GridError, RunSpec
from swat_jax.morphology import get_set

SGRL = "SGRL (PyTorch)"
OURS = "swat_jax (paper preset, SGRL's settings)"
SGRL_FOLDERS = {
    "3d_hopper": "3d_hoppers",
    "3d_walker": "3d_walkers",
    "3d_humanoid": "3d_humanoids",
    "3d_cheetah": "3d_cheetahs",
    "3d_whh": "3d_whh",
    "3d_cwhh": "3d_cwhh",
}
"""SGRL's ``--custom_xml`` folder (under its ``environments/``) of each 3D set that it trains."""
WARMUP = 5_000
"""SGRL's warm-up, in lock-step steps (its ``warmup_timesteps``); its counter is set to this after it."""
EPOCH = 1_000
"""Lock-step steps of one SGRL epoch (its ``num_env_steps_per_epoch``): it checks its budget at epoch ends."""
SGRL_BATCH = 256
"""SGRL's batch of every update (its ``agent_batch_size``; fidelity row S5)."""
SGRL_TAU = 0.005
"""SGRL's target-network rate (its ``target_smoothing_tau``; fidelity row S7)."""
ALGORITHMS = ("swat", "set")
"""The networks both sides train: SWAT (SGRL's baseline) and SET (its own)."""
SGRL_WORK = Path(os.environ.get("SGRL_DIR", "/tmp/sgrl-work"))
"""SGRL's working copy (made by its tools' ``record_sgrl.py``); its ``main.py`` runs in ``src/``."""
RECORDER = Path(__file__).resolve().parent / "recorder"
"""The folder whose ``wandb`` stand-in records what SGRL's logger sends, first on the trainer's path."""
LOG_FILE = "wandb.jsonl"
"""The recorded log of an SGRL seed, in its folder."""
WALL_FILE = "wall.json"
"""Written when an SGRL seed has finished: its wall clock."""


@dataclasses.dataclass(frozen=True)
class SgrlScale:
    """What both sides train with: the same network sizes and learning rate, and budgets in SGRL's counter."""

    name: str
    seeds: int
    epochs: Mapping[str, int]
    """SGRL's ``max_epoch`` by set: the budget is this x 1,000 in its counter."""
    algorithm: str = "swat"
    """The actor's and critic's network on both sides: swat or set."""
    width: int = 32
    heads: int = 2
    layers: int = 1
    feedforward: int = 64
    learning_rate: float = 1e-3
    random_steps: int = 1_000
    """swat_jax's random-action steps per body, counted as the original counts them (SGRL's warm-up, 5,000
    lock-step steps storing first episodes only, has no switch: fidelity row S1)."""
    capacity: int = 100_000
    """swat_jax's replay rows per body; no ring fills at these budgets on either side (fidelity row S8)."""
    point: int = 5_000
    """SGRL counter units between two curve points."""
    final_fraction: float = 0.2
    """A seed's final return: its mean over the curve points in this last fraction of the budget."""

    def budget(self, environment_set: str) -> int:
        """The budget on ``environment_set`` in SGRL's counter; GridError if this scale has none."""
        if environment_set not in SGRL_FOLDERS:
            raise GridError(
                f"SGRL's trainer has no folder for {environment_set}; sets it trains: {', '.join(SGRL_FOLDERS)}"
            )
        if environment_set not in self.epochs:
            raise GridError(f"scale {self.name} has no budget for {environment_set}; give --epochs")
        return self.epochs[environment_set] * EPOCH

    def log_interval(self, environment_set: str) -> int:
        """SGRL counter units between two curve points (the grid of experiments/original/curves.py)."""
        return self.point

    def counter(self, environment_set: str, counted: float) -> float:
        """SGRL's counter at a swat_jax row that has counted ``counted`` steps: its warm-up, then one per
        stored transition and one per update, two per step counted after the random phase."""
        random_phase = len(get_set(environment_set).train) * self.random_steps
        return WARMUP + 2 * max(0.0, counted - random_phase)

    def counted_budget(self, environment_set: str) -> int:
        """swat_jax's ``--counted-steps`` that reaches :meth:`budget` in SGRL's counter, rounded up to its curve
        grid (bodies x 100 steps)."""
        random_phase = len(get_set(environment_set).train) * self.random_steps
        grid = len(get_set(environment_set).train) * CHUNK
        counted = random_phase + (self.budget(environment_set) - WARMUP) / 2
        return -(-int(counted) // grid) * grid

    def ours(self, environment_set: str) -> Settings:
        """swat_jax's side as an original-comparison scale: these sizes, SGRL's batch, the counted budget."""
        return Settings(
            name=f"sgrl-{self.name}",
            seeds=self.seeds,
            steps={environment_set: self.counted_budget(environment_set)},
            width=self.width,
            heads=self.heads,
            layers=self.layers,
            feedforward=self.feedforward,
            random_steps=self.random_steps,
            learning_rate=self.learning_rate,
            batch_size=SGRL_BATCH,
            capacity=self.capacity,
            log_iterations=1,
            final_fraction=self.final_fraction,
        )

    def given(
        self, seeds: int | None, epochs: int | None, sets: Sequence[str], algorithm: str = "swat"
    ) -> SgrlScale:
        """This scale with a command's ``--seeds`` and ``--epochs`` (on every one of ``sets``), where given,
        and its ``--algo``."""
        if algorithm not in ALGORITHMS:
            raise GridError(f"--algo must be one of {', '.join(ALGORITHMS)}, got {algorithm!r}")
        scale = dataclasses.replace(self, algorithm=algorithm)
        if seeds is not None:
            if seeds < 1:
                raise GridError(f"--seeds must be 1 or more, got {seeds}")
            scale = dataclasses.replace(scale, seeds=seeds)
        if epochs is not None:
            if epochs * EPOCH <= WARMUP:
                raise GridError(
                    f"--epochs must be more than {WARMUP // EPOCH} (SGRL's warm-up), got {epochs}"
                )
            scale = dataclasses.replace(scale, epochs={name: epochs for name in sets})
        return scale


SCALES = {
    "micro": SgrlScale(
        name="micro", seeds=2, epochs={"3d_hopper": 7, "3d_walker": 7}, width=8, feedforward=16, point=1_000
    ),
    "small": SgrlScale(name="small", seeds=4, epochs={"3d_hopper": 150, "3d_walker": 150}),
}
"""``micro``: a smoke test of the pipeline (SGRL's warm-up and an epoch or two); ``small``: width-32 one-layer SWAT
at SGRL's counter 150,000 (about 72,500 transitions stored by its policy)."""


def ours(out: Path, scale: SgrlScale, environment_set: str) -> list[RunSpec]:
    """swat_jax's run of each seed: the paper preset at :meth:`SgrlScale.ours` with SGRL's τ and the scale's
    network, one process per seed, in ``OUT/runs/<set>-<algorithm>-swat_jax-seed<k>``."""
    settings = scale.ours(environment_set)
    runs = []
    for seed in range(scale.seeds):
        config = paper_config(
            settings,
            environment_set,
            out / "runs" / f"{environment_set}-{scale.algorithm}-swat_jax-seed{seed}",
            seeds=1,
            seed=seed,
        )
        td3 = dataclasses.replace(config.td3, tau=SGRL_TAU)
        runs.append(RunSpec(dataclasses.replace(config, algo=scale.algorithm, td3=td3)))
    return runs


@dataclasses.dataclass(frozen=True)
class Sgrl:
    """Where SGRL's trainer runs: its venv's python, the original's tools (their ``shim/``) and SGRL's tools
    (``record_sgrl.py``, which makes its working copy)."""

    python: Path
    original_tools: Path
    sgrl_tools: Path
    parallel: int
    timeout: float

    def missing(self) -> str | None:
        """Why it cannot run here, or None."""
        if not self.python.is_file():
            return f"no SGRL venv at {self.python} (give --sgrl-python; its tools' README has the set-up)"
        if not (self.original_tools / "shim").is_dir():
            return f"no shim/ in {self.original_tools} (give --original-tools or set $ORIGINAL_TOOLS)"
        if not (SGRL_WORK / "src").is_dir() and not (self.sgrl_tools / "record_sgrl.py").is_file():
            return (
                f"no SGRL working copy at {SGRL_WORK}/src and no record_sgrl.py in {self.sgrl_tools} to make "
                "it (give --sgrl-tools or set $SGRL_TOOLS)"
            )
        return None

    def prepare(self) -> None:
        """Have SGRL's tools make its working copy once (recording one body), before seeds start."""
        if (SGRL_WORK / "src" / "main.py").is_file():
            return
        environment = {
            **os.environ,
            "SGRL_DIR": str(SGRL_WORK),
            "OUT": str(SGRL_WORK / "recorded"),
            "STEPS": "2",
        }
        command = [str(self.python), str(self.sgrl_tools / "record_sgrl.py"), "3d_hopper_3_shin"]
        subprocess.run(command, env=environment, cwd="/tmp", check=True, capture_output=True)


@dataclasses.dataclass(frozen=True)
class SgrlRun:
    """One seed of SGRL's trainer on one set."""

    out: Path
    scale: SgrlScale
    environment_set: str
    seed: int

    @property
    def name(self) -> str:
        return f"{self.environment_set}-{self.scale.algorithm}-seed{self.seed}"

    @property
    def folder(self) -> Path:
        """Where its recorded log, SGRL's own log and parameters, and its wall clock are kept in OUT."""
        return self.out / "sgrl" / self.name

    @property
    def experiment_id(self) -> str:
        """Its ``--expID``, and the name of its config module: unique per OUT folder and budget."""
        key = f"{self.out.resolve()}:{self.scale.budget(self.environment_set)}"
        return f"swat_jax_{hashlib.sha1(key.encode()).hexdigest()[:8]}_{self.name.replace('-', '_')}"

    @property
    def config_module(self) -> Path:
        """Its config file in SGRL's ``configs/`` (SGRL imports it by its path there, beside ``default.py``)."""
        return SGRL_WORK / "src" / "configs" / f"{self.experiment_id}.py"

    def config_text(self) -> str:
        """SGRL's ``configs/3d.py`` overrides, its ``max_epoch`` set to this scale's."""
        return (
            '"""SGRL\'s configs/3d.py with the budget of a swat_jax comparison (written by '
            'experiments/sgrl/runs.py)."""\n'
            "import copy\nimport importlib\n\n"
            'overwrite_args = copy.deepcopy(importlib.import_module("configs.3d").overwrite_args)\n'
            f'overwrite_args["trainer"]["max_epoch"] = {self.scale.epochs[self.environment_set]}\n'
        )

    def flags(self) -> list[str]:
        """SGRL's main.py flags: SWAT actor and critic at this scale's sizes, its 3D config with the budget."""
        s = self.scale
        family = self.environment_set.removeprefix("3d_")
        return [
            "--env_name", family, "--morphologies", family, "--expID", self.experiment_id,
            "--exp_path", str(SGRL_WORK / "results"), "--config_path", f"configs/{self.config_module.name}",
            "--gpu", "-1", "--custom_xml", f"environments/{SGRL_FOLDERS[self.environment_set]}/",
            "--actor_type", s.algorithm, "--critic_type", s.algorithm, "--seed", str(self.seed),
            "--lr", str(s.learning_rate),
            "--attention_embedding_size", str(s.width), "--attention_heads", str(s.heads),
            "--attention_layers", str(s.layers), "--attention_hidden_size", str(s.feedforward),
        ]  # fmt: skip

    def command(self, python: Path) -> list[str]:
        return [str(python), "main.py", *self.flags()]

    def environment(self, sgrl: Sgrl) -> dict[str, str]:
        """One torch thread, no progress bars, the recorder and the original's shim first on the path."""
        path = os.pathsep.join([str(RECORDER), str(sgrl.original_tools / "shim"), "."])
        return {
            **os.environ,
            "OMP_NUM_THREADS": "1",
            "TQDM_DISABLE": "1",
            "PYTHONPATH": path,
            "SWAT_JAX_SGRL_LOG": str((self.folder / LOG_FILE).resolve()),
        }

    def finished(self) -> bool:
        """Whether the seed ran to its end; GridError if it ran another budget than this scale's."""
        if not (self.folder / WALL_FILE).is_file():
            return False
        ran = json.loads((self.folder / WALL_FILE).read_text())["budget"]
        if ran != self.scale.budget(self.environment_set):
            raise GridError(
                f"{self.folder} holds a run of SGRL to its counter {ran:,}, not "
                f"{self.scale.budget(self.environment_set):,}: give --epochs {ran // EPOCH}, or another --out"
            )
        return True

    def logs(self) -> list[Path]:
        """SGRL's log folders of this seed (``results/<family>/<date>-<seed>-<pid>_<expID>``), oldest first."""
        return sorted((SGRL_WORK / "results").glob(f"*/*_{self.experiment_id}"))

    def wall(self) -> float:
        """Seconds its process ran, start-up included."""
        return float(json.loads((self.folder / WALL_FILE).read_text())["seconds"])

    def records(self) -> list[dict[str, float]]:
        """Its recorded log: a dict per logged call (``step``, ``time`` and the values)."""
        lines = (self.folder / LOG_FILE).read_text().splitlines()
        return [json.loads(line) for line in lines if line.strip()]


def sgrl_runs(out: Path, scale: SgrlScale, environment_set: str) -> list[SgrlRun]:
    return [SgrlRun(out, scale, environment_set, seed) for seed in range(scale.seeds)]


def train_sgrl(runs: Sequence[SgrlRun], sgrl: Sgrl, out: Path) -> None:
    """Run every unfinished seed from its start, ``sgrl.parallel`` at a time, each with one torch thread on no
    core in particular; keep its recorded log, SGRL's ``logs.txt`` and ``parameters.txt`` and its wall clock."""
    timing = (out, f"sgrl-{runs[0].name.rsplit('-', 1)[0]}")
    train_foreign(
        "SGRL", runs, lambda run, slot: _start(run, sgrl, slot), _collect, sgrl.prepare, sgrl.parallel, timing
    )


def _start(run: SgrlRun, sgrl: Sgrl, _slot: int) -> subprocess.Popen:
    shutil.rmtree(run.folder, ignore_errors=True)
    for stale in run.logs():
        shutil.rmtree(stale)
    run.folder.mkdir(parents=True)
    run.config_module.write_text(run.config_text())
    command = run.command(sgrl.python)
    print(f"SGRL {run.name}: {shlex.join(command)}", file=sys.stderr)
    log = (run.folder / "stdout.log").open("w")
    return subprocess.Popen(
        ["timeout", str(int(sgrl.timeout)), *command],
        stdout=log,
        stderr=subprocess.STDOUT,
        env=run.environment(sgrl),
        cwd=SGRL_WORK / "src",
    )


def _collect(run: SgrlRun, status: int, seconds: float) -> None:
    if status != 0:
        raise GridError(
            f"SGRL {run.name} exited with status {status}; its output: {run.folder / 'stdout.log'}"
        )
    logs = run.logs()
    if not logs:
        raise GridError(f"SGRL {run.name} wrote no log folder under {SGRL_WORK / 'results'}")
    for name in ("logs.txt", "parameters.txt"):
        shutil.copy(logs[-1] / name, run.folder / name)
    budget = run.scale.budget(run.environment_set)
    (run.folder / WALL_FILE).write_text(json.dumps({"seconds": seconds, "budget": budget}) + "\n")
    print(f"SGRL {run.name}: finished in {seconds / 60:.1f} min", file=sys.stderr)
