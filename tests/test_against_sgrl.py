"""experiments/against_sgrl.py: SGRL's 3D trainer beside swat_jax's paper preset with SGRL's settings."""

import csv
import importlib
import json
import os
import sys
from pathlib import Path

import numpy as np
import pytest

from experiments import against_sgrl as against
from experiments.original import returns
from experiments.sgrl import curves, runs
from swat_jax.morphology import get_set

MICRO = runs.SCALES["micro"]
SMALL = runs.SCALES["small"]
SGRL_PYTHON = Path(os.environ.get("SGRL_PYTHON", "/tmp/sgrl-venv/bin/python"))
ORIGINAL_TOOLS = Path(os.environ.get("ORIGINAL_TOOLS", "/nonexistent"))
SGRL_TOOLS = Path(os.environ.get("SGRL_TOOLS", "/nonexistent"))


def test_the_sgrl_config_is_its_3d_config_with_only_the_budget_changed(tmp_path, monkeypatch):
    """The written config imports SGRL's configs/3d.py (a stand-in here) and changes max_epoch alone, leaving
    the module it read untouched."""
    configs = tmp_path / "configs"
    configs.mkdir()
    (configs / "__init__.py").write_text("")
    (configs / "3d.py").write_text(
        'overwrite_args = {"trainer": {"max_epoch": 5000, "eval_interval": 123}}\n'
    )
    run = runs.SgrlRun(tmp_path / "out", MICRO, "3d_hopper", 0)
    (configs / "written.py").write_text(run.config_text())
    monkeypatch.syspath_prepend(str(tmp_path))
    for name in ("configs", "configs.3d", "configs.written"):
        monkeypatch.delitem(sys.modules, name, raising=False)
    written = importlib.import_module("configs.written").overwrite_args
    assert written == {"trainer": {"max_epoch": MICRO.epochs["3d_hopper"], "eval_interval": 123}}
    assert importlib.import_module("configs.3d").overwrite_args["trainer"]["max_epoch"] == 5000
    flags = run.flags()
    assert flags[flags.index("--config_path") + 1] == f"configs/{run.config_module.name}"
    assert flags[flags.index("--custom_xml") + 1] == "environments/3d_hoppers/"
    assert flags[flags.index("--attention_embedding_size") + 1] == str(MICRO.width)


def test_the_recorder_keeps_returns_and_timings_not_losses_and_nothing_without_its_file(
    tmp_path, monkeypatch
):
    monkeypatch.syspath_prepend(str(runs.RECORDER))
    monkeypatch.delitem(sys.modules, "wandb", raising=False)
    wandb = importlib.import_module("wandb")
    assert Path(wandb.__file__).parent.parent == runs.RECORDER
    log = tmp_path / "log.jsonl"
    monkeypatch.setenv("SWAT_JAX_SGRL_LOG", str(log))
    wandb.init(project="hopper")
    wandb.log({"performance/train_return": np.float32(3.5)}, step=5_200)
    wandb.log({"critic_loss": 1.0}, step=5_200)
    wandb.log({"times/epoch_duration": 30.0}, step=7_000)
    records = [json.loads(line) for line in log.read_text().splitlines()]
    assert [(r["step"], {k for k in r if "/" in k}) for r in records] == [
        (5_200, {"performance/train_return"}),
        (7_000, {"times/epoch_duration"}),
    ]
    assert records[0]["performance/train_return"] == 3.5 and records[1]["time"] >= records[0]["time"]
    monkeypatch.delenv("SWAT_JAX_SGRL_LOG")
    wandb.log({"performance/train_return": 1.0}, step=9_000)
    assert len(log.read_text().splitlines()) == 2
    assert len(wandb.util.generate_id()) == 8


@pytest.mark.parametrize("environment_set", ["3d_hopper", "3d_walker"])
def test_swat_jax_stops_where_sgrls_counter_reaches_the_budget(environment_set):
    """The counted budget is the first point of swat_jax's grid whose SGRL counter reaches SGRL's budget."""
    counted = SMALL.counted_budget(environment_set)
    grid = len(get_set(environment_set).train) * 100
    assert counted % grid == 0
    assert SMALL.counter(environment_set, counted) >= SMALL.budget(environment_set) == 150_000
    assert SMALL.counter(environment_set, counted - grid) < SMALL.budget(environment_set)
    assert SMALL.counter(environment_set, len(get_set(environment_set).train) * SMALL.random_steps) == 5_000


def test_both_sides_train_at_the_same_sizes_with_sgrls_batch_and_target_rate(tmp_path):
    run = against.ours(tmp_path, SMALL, "3d_hopper")[1]
    config = run.config
    assert (config.env, config.algo, config.preset, config.seed, config.seeds) == (
        "3d_hopper",
        "swat",
        "paper",
        1,
        1,
    )
    assert (config.network.width, config.network.heads, config.network.layers) == (32, 2, 1)
    assert (config.td3.batch_size, config.td3.tau, config.td3.learning_rate) == (256, 0.005, 1e-3)
    assert config.counted_steps == SMALL.counted_budget("3d_hopper")
    flags = runs.SgrlRun(tmp_path, SMALL, "3d_hopper", 1).flags()
    assert flags[flags.index("--lr") + 1] == "0.001" and flags[flags.index("--seed") + 1] == "1"
    assert flags[flags.index("--actor_type") + 1] == flags[flags.index("--critic_type") + 1] == "swat"
    with_set = SMALL.given(None, None, ["3d_hopper"], "set")
    assert against.ours(tmp_path, with_set, "3d_hopper")[0].config.algo == "set"
    set_flags = runs.SgrlRun(tmp_path, with_set, "3d_hopper", 0).flags()
    assert (
        set_flags[set_flags.index("--actor_type") + 1]
        == set_flags[set_flags.index("--critic_type") + 1]
        == "set"
    )
    assert (
        runs.SgrlRun(tmp_path, with_set, "3d_hopper", 0).experiment_id
        != runs.SgrlRun(tmp_path, SMALL, "3d_hopper", 0).experiment_id
    )


def write_sgrl_seed(run: runs.SgrlRun, steps, values, wall: float) -> None:
    """A finished SGRL seed: a record at the start (counter 0), then each round's return and length, as its
    logger sends them, one call each, the rounds a second apart."""
    run.folder.mkdir(parents=True, exist_ok=True)
    records = [{"step": 0, "time": 100.0, "performance/eval_return": 1.0}]
    for k, (step, value) in enumerate(zip(steps, values, strict=True)):
        records.append({"step": step, "time": 101.0 + k, curves.RETURN: value})
        records.append({"step": step, "time": 101.0 + k, curves.LENGTH: 10.0})
    (run.folder / runs.LOG_FILE).write_text("".join(json.dumps(r) + "\n" for r in records))
    budget = run.scale.budget(run.environment_set)
    (run.folder / runs.WALL_FILE).write_text(json.dumps({"seconds": wall, "budget": budget}))


def test_sgrl_rounds_are_binned_on_its_counter_with_machine_seconds(tmp_path):
    """Rounds up to the first that reaches the budget (7,000) land on the grid; the rest of the last epoch is
    left out; each point's seconds count the start-up (the wall clock less the recorded span)."""
    run = runs.SgrlRun(tmp_path, MICRO, "3d_hopper", 0)
    write_sgrl_seed(run, [5_100, 5_900, 6_400, 7_300, 7_900], [1.0, 3.0, 5.0, 7.0, 99.0], wall=30.0)
    seed = curves.sgrl_curves(run)
    assert seed.mean_over_bodies() == {6_000: 2.0, 7_000: 6.0}
    startup = 30.0 - 5.0
    assert seed.seconds == {6_000: startup + 2.0, 7_000: startup + 4.0}
    assert run.finished()
    with pytest.raises(runs.GridError, match="give --epochs 7"):
        runs.SgrlRun(tmp_path, MICRO.given(None, 9, ["3d_hopper"]), "3d_hopper", 0).finished()


def write_ours_seed(run, counted, value) -> None:
    """A swat_jax seed's metrics rows of 3D Hopper++ at these counted steps, every body at ``value``."""
    run.run_dir.mkdir(parents=True)
    bodies = get_set("3d_hopper").train
    rows = [
        {"env_steps": n, "seed": 0, "counted_steps": n, "steps_per_second": 100.0}
        | {f"return/{body}": value for body in bodies}
        | {f"length/{body}": 20 for body in bodies}
        for n in counted
    ]
    with (run.run_dir / "metrics.csv").open("w", newline="") as file:
        writer = csv.DictWriter(file, fieldnames=list(rows[0]))
        writer.writeheader()
        writer.writerows(rows)


def test_the_report_puts_both_sides_on_sgrls_counter_with_the_ratio_of_their_means(tmp_path):
    scale = MICRO.given(3, None, ["3d_hopper"])
    for seed, (mine, theirs) in enumerate([(10.0, 20.0), (12.0, 22.0), (14.0, 24.0)]):
        run = runs.SgrlRun(tmp_path, scale, "3d_hopper", seed)
        write_sgrl_seed(run, [5_500, 6_500, 7_100], [theirs] * 3, wall=60.0)
        write_ours_seed(against.ours(tmp_path, scale, "3d_hopper")[seed], [3_000, 3_600, 4_200], mine)
    lines = "\n".join(against.compare(tmp_path, scale, "3d_hopper"))
    assert f"| {runs.SGRL} | 3 | 22.0 | 22.0 ± 1.2 |" in lines
    assert f"| {runs.OURS} | 3 | 12.0 | 12.0 ± 1.2 |" in lines
    assert "swat_jax / SGRL: 0.55 (90% interval" in lines and "beyond the noise" in lines
    assert "| 3d_hopper_5_full | 12.0 ± 1.2 | 10, 12, 14 |" in lines
    with (tmp_path / "3d_hopper-swat.csv").open() as file:
        plotted = {(row["algorithm"], int(row["env_steps"])) for row in csv.DictReader(file)}
    assert plotted == {(runs.SGRL, 6_000), (runs.SGRL, 7_000), (runs.OURS, 5_000), (runs.OURS, 7_000)}


def test_the_ratio_interval_covers_the_true_ratio_as_often_as_it_says():
    """Over many draws of 8 seeds a side (true means 100 and 60, standard deviations 20 and 15), the 90%
    interval of the ratio of the means covers 0.6 in 87-93% of them."""
    rng = np.random.default_rng(0)
    covered = []
    for _ in range(2_000):
        a, b = returns.Final(rng.normal(100, 20, 8)), returns.Final(rng.normal(60, 15, 8))
        low, high = returns.ratio_interval(a, b)
        covered.append(low <= 0.6 <= high)
    assert 0.87 <= np.mean(covered) <= 0.93


def test_a_set_sgrl_does_not_train_is_refused_with_the_sets_it_does(capsys):
    assert against.main(["--sets", "hopper", "--dry-run"]) == 2
    assert "SGRL's trainer has no folder for hopper; sets it trains: 3d_hopper" in capsys.readouterr().err


@pytest.mark.slow
@pytest.mark.skipif(
    not SGRL_PYTHON.is_file() or not (ORIGINAL_TOOLS / "shim").is_dir() or not SGRL_TOOLS.is_dir(),
    reason=f"SGRL's venv ({SGRL_PYTHON}), the original's tools or SGRL's tools are not here; set SGRL_PYTHON, "
    "ORIGINAL_TOOLS and SGRL_TOOLS to run SGRL's side",
)
def test_sgrls_side_at_micro_scale_records_its_rounds_to_the_budget(tmp_path):
    argv = [
        "--scale", "micro", "--sets", "3d_hopper", "--seeds", "1", "--only", "sgrl", "--out", str(tmp_path),
        "--sgrl-python", str(SGRL_PYTHON), "--original-tools", str(ORIGINAL_TOOLS), "--sgrl-tools", str(SGRL_TOOLS),
    ]  # fmt: skip
    assert against.main(argv) == 0
    run = runs.SgrlRun(tmp_path, MICRO.given(1, None, ["3d_hopper"]), "3d_hopper", 0)
    assert run.finished() and (run.folder / "logs.txt").is_file()
    assert max(record["step"] for record in run.records()) > run.scale.budget("3d_hopper")
    assert set(curves.sgrl_curves(run).mean_over_bodies()) <= {6_000, 7_000}
    assert f"| {runs.SGRL} | 1 |" in (tmp_path / "against_sgrl-swat.md").read_text()
