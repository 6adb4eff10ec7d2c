"""experiments/against_original.py: both sides train with the same settings, their logs land on one grid, the
report tests the difference, and the swat_jax side runs end to end at a micro scale (the original side too,
where the original code's venv is installed)."""

import csv
import json
import math
import os
from pathlib import Path

import numpy as np
import pytest

from experiments import against_original as against
from experiments.original import curves, returns, runs
from swat_jax.morphology import get_set
from swat_jax.runs.config import flag_values as config_values

REPO = Path(__file__).resolve().parents[1]

MICRO = runs.SETTINGS["micro"]
ORIGINAL_PYTHON = Path(os.environ.get("ORIGINAL_PYTHON", "/tmp/orig-venv/bin/python"))
ORIGINAL_TOOLS = Path(os.environ.get("ORIGINAL_TOOLS", REPO.parent / "shared" / "tools" / "original"))


def flag_values(flags) -> dict[str, str]:
    flags = list(flags)
    return {flag: flags[index + 1] for index, flag in enumerate(flags[:-1]) if flag.startswith("--")}


@pytest.mark.parametrize("environment_set", ["hopper", "walker"])
def test_both_sides_train_with_the_same_sizes_hyperparameters_and_budget(tmp_path, environment_set):
    ours = config_values(runs.ours(tmp_path, MICRO, environment_set).config)
    for seed, run in enumerate(runs.original_runs(tmp_path, MICRO, environment_set)):
        theirs = flag_values(run.flags())
        assert theirs["--seed"] == str(seed)
        same = {
            "--network.width": "--attention_embedding_size",
            "--network.heads": "--attention_heads",
            "--network.layers": "--attention_layers",
            "--network.feedforward": "--attention_hidden_size",
            "--iteration.random-steps": "--start_timesteps",
            "--iteration.capacity": "--rb_per_env",
            "--td3.learning-rate": "--lr",
            "--td3.batch-size": "--batch_size",
        }
        for our_flag, their_flag in same.items():
            assert float(ours[our_flag]) == float(theirs[their_flag]), (our_flag, their_flag)
        assert (
            theirs["--custom_xml"]
            == {"hopper": "environments/hoppers", "walker": "environments/walkers"}[environment_set]
        )
        assert int(theirs["--max_timesteps"]) == MICRO.budget(environment_set)
    assert (ours["--preset"], ours["--seeds"]) == ("paper", MICRO.seeds)
    bodies = len(get_set(environment_set).train)
    stored = int(ours["--steps"])
    assert stored == MICRO.stored_budget(environment_set) >= 1.75 * MICRO.budget(environment_set), (
        "swat_jax's budget stores enough steps for every seed to count the original's budget"
    )
    assert stored % (bodies * runs.CHUNK) == 0 and int(ours["--log-interval"]) == bodies * runs.CHUNK, (
        "a row per chunk, for the curves to be binned by counted steps"
    )


def test_a_budget_off_the_curves_grid_is_refused_with_the_fix(tmp_path, capsys):
    status = against.main(
        ["--dry-run", "--scale", "micro", "--sets", "hopper", "--steps", "500", "--out", str(tmp_path)]
    )
    assert status == 2
    assert "must be a multiple of 300" in capsys.readouterr().err


def test_dry_run_prints_every_seed_of_the_original_and_one_swat_jax_program(tmp_path, capsys):
    assert against.main(["--dry-run", "--scale", "micro", "--sets", "hopper", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == MICRO.seeds + 1
    assert all("run_trainer.py" in line and "OMP_NUM_THREADS=1" in line for line in lines[:-1])
    assert "swat_jax.train" in lines[-1] and lines[-1].endswith("# new")


def write_original_seed(run: runs.OriginalRun, timesteps, rewards_by_body, round_seconds) -> None:
    """A finished original seed's files as train_original leaves them."""
    run.folder.mkdir(parents=True)
    stat = {"timestep": timesteps, "episode_return": [0.0] * len(timesteps)}
    for body, rewards in rewards_by_body.items():
        stat[f"{body}_episode_reward"] = rewards
        stat[f"{body}_episode_len"] = [10.0] * len(timesteps)
    (run.folder / "stat.json").write_text(json.dumps(stat))
    log = [f"[harness] t={t:6.1f}s round={k + 1} env_steps(all envs)=0" for k, t in enumerate(round_seconds)]
    log.append(
        "[harness] totals: env_steps=900 (summed over envs) in 1.0s stepping, updates=600 in 8.0s updating"
    )
    log.append("[harness] training window 9.0s (rounds 2..4): 50.00 env steps/s, 40.00 updates/s overall;")
    (run.folder / "trainer.log").write_text("\n".join(log) + "\n")


def test_original_rounds_are_binned_on_the_curve_grid_with_their_wall_clock(tmp_path):
    run = runs.original_runs(tmp_path, MICRO, "hopper")[0]
    bodies = ("hopper_3", "hopper_4", "hopper_5")
    write_original_seed(
        run,
        [120, 290, 450, 610],
        {
            "hopper_3": [1.0, 3.0, 10.0, 20.0],
            "hopper_4": [2.0, 4.0, 6.0, 8.0],
            "hopper_5": [0.0, 0.0, 0.0, 0.0],
        },
        [1.0, 2.0, 3.5, 5.0],
    )
    seed = curves.original_curves(run)
    assert set(seed.returns) == set(bodies)
    # Grid of 300 steps, budget 600: rounds at 120 and 290 fall into 300; 450 and 610 (past the budget) into 600.
    assert seed.returns["hopper_3"] == {300: 2.0, 600: 15.0}
    assert seed.mean_over_bodies() == {300: pytest.approx(5.0 / 3), 600: pytest.approx(22.0 / 3)}
    assert seed.seconds == {300: 2.0, 600: 5.0}, "a point's time is that of its last round"
    assert curves.original_throughput(run) == (50.0, 40.0)
    assert curves.original_surplus(run) == 1.5, "900 steps taken for 600 counted"


def test_welch_test_tells_a_real_difference_from_noise():
    spread = np.array([-15.0, -5.0, 0.0, 5.0, 15.0])
    low, shifted_by_noise, far = (returns.Final(centre + spread) for centre in (100.0, 104.0, 300.0))
    assert returns.welch(low, shifted_by_noise) > 0.5
    assert returns.welch(low, far) < 1e-6
    assert math.isnan(returns.welch(returns.Final(np.array([1.0])), far)), "one seed has no variance"


def test_time_to_reach_is_the_first_point_where_the_mean_over_seeds_gets_there():
    seeds = [
        curves.SeedCurves({"a": {1: 0.0, 2: 10.0, 3: 30.0}}, {1: 10.0, 2: 20.0, 3: 30.0}),
        curves.SeedCurves({"a": {1: 0.0, 2: 20.0, 3: 30.0}}, {1: 12.0, 2: 22.0, 3: 32.0}),
    ]
    assert returns.time_to_reach(seeds, 15.0) == 21.0
    assert returns.time_to_reach(seeds, 31.0) is None


def plotted(csv_path: Path) -> dict[tuple[str, str], list[dict[str, str]]]:
    lines: dict[tuple[str, str], list[dict[str, str]]] = {}
    with csv_path.open() as file:
        for row in csv.DictReader(file):
            lines.setdefault((row["panel"], row["algorithm"]), []).append(row)
    return lines


def test_swat_jax_side_at_micro_scale_trains_draws_and_reports(tmp_path, capsys):
    argv = ["--scale", "micro", "--sets", "hopper", "--only", "swat_jax", "--out", str(tmp_path)]
    assert against.main(argv) == 0
    lines = plotted(tmp_path / "hopper.csv")
    panels = ["Hopper++: mean over bodies", "Hopper++: hopper_3", "Hopper++: hopper_4", "Hopper++: hopper_5"]
    assert sorted(lines) == sorted((panel, runs.OURS) for panel in panels)
    mean_line = lines["Hopper++: mean over bodies", runs.OURS]
    assert [int(row["env_steps"]) for row in mean_line] == [300, 600]
    assert all(int(row["seeds"]) == MICRO.seeds for row in mean_line)
    assert (tmp_path / "hopper.png").stat().st_size > 10_000
    report = (tmp_path / "against_original.md").read_text()
    assert f"| {runs.OURS} | {MICRO.seeds} |" in report
    assert "Welch" not in report, "no test without the original's side"
    # A second call keeps the finished run instead of training it again.
    capsys.readouterr()
    assert against.main(argv) == 0
    assert f"done ({MICRO.stored_budget('hopper'):,} steps), kept" in capsys.readouterr().err


@pytest.mark.skipif(
    not ORIGINAL_PYTHON.is_file() or not (ORIGINAL_TOOLS / "run_trainer.py").is_file(),
    reason=f"the original code's venv ({ORIGINAL_PYTHON}) or its tools ({ORIGINAL_TOOLS}) are not installed here; "
    "set ORIGINAL_PYTHON and ORIGINAL_TOOLS to run the original side",
)
def test_original_side_at_micro_scale_trains_every_seed_and_lands_on_the_grid(tmp_path, monkeypatch):
    monkeypatch.setattr(runs, "ORIGINAL_WORK", tmp_path / "original-tree")
    argv = [
        "--scale", "micro", "--sets", "hopper", "--only", "original", "--out", str(tmp_path),
        "--original-python", str(ORIGINAL_PYTHON), "--original-tools", str(ORIGINAL_TOOLS),
    ]  # fmt: skip
    assert against.main(argv) == 0
    for run in runs.original_runs(tmp_path, MICRO, "hopper"):
        assert run.finished()
        assert json.loads((run.folder / "args.txt").read_text())["max_timesteps"] == 600
        assert set(curves.original_curves(run).mean_over_bodies()) <= {300, 600}
    assert f"| {runs.ORIGINAL} | {MICRO.seeds} |" in (tmp_path / "against_original.md").read_text()


def test_the_body_table_shows_which_body_disagrees():
    def seeds(far_body_value):
        return [
            curves.SeedCurves(
                {
                    "hopper_3": {600: 100.0 + k},
                    "hopper_4": {600: 50.0 - k},
                    "hopper_5": {600: far_body_value + k},
                },
                {600: 1.0},
            )
            for k in (-2.0, 0.0, 1.0, 3.0)
        ]

    table = against.body_table({runs.ORIGINAL: seeds(300.0), runs.OURS: seeds(40.0)}, MICRO, "hopper")
    rows = {row.split("|")[1].strip(): row.split("|")[-2].strip() for row in table[2:]}
    assert float(rows["hopper_3"]) == pytest.approx(1.0) and float(rows["hopper_4"]) == pytest.approx(1.0)
    assert float(rows["hopper_5"]) < 1e-3
