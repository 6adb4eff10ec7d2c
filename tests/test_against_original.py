"""experiments/against_original.py: both sides train with the same settings, their logs land on one grid, the
report tests the difference, and the swat_jax side runs end to end at a micro scale (the original side too,
where the original code's venv is installed)."""

import csv
import dataclasses
import json
import math
import os
import warnings
from pathlib import Path

import numpy as np
import pytest
from scipy import stats as scipy_stats

from experiments import against_original as against
from experiments import plateau
from experiments.original import curves, returns, runs
from swat_jax.morphology import get_set
from swat_jax.runs.config import TrainConfig
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
    seeds = runs.ours(tmp_path, MICRO, environment_set)
    assert len(seeds) == MICRO.seeds and len({run.run_dir for run in seeds}) == MICRO.seeds
    for seed, (run, mine) in enumerate(
        zip(runs.original_runs(tmp_path, MICRO, environment_set), seeds, strict=True)
    ):
        theirs, ours = flag_values(run.flags()), config_values(mine.config)
        assert int(theirs["--seed"]) == int(ours["--seed"]) == seed, "one process per seed on both sides"
        assert int(ours["--seeds"]) == 1
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
    assert ours["--preset"] == "paper"
    bodies = len(get_set(environment_set).train)
    cap = int(ours["--steps"])
    assert int(ours["--counted-steps"]) == MICRO.budget(environment_set), "it stops where the original does"
    assert cap == MICRO.steps_cap(environment_set) >= 4 * MICRO.budget(environment_set), (
        "a cap no seed reaches before it counts the original's budget"
    )
    assert cap % (bodies * runs.CHUNK) == 0 and int(ours["--log-interval"]) == bodies * runs.CHUNK, (
        "a row per chunk, for the curves to be binned by counted steps"
    )


def test_a_budget_off_the_curves_grid_is_refused_with_the_fix(tmp_path, capsys):
    status = against.main(
        ["--dry-run", "--scale", "micro", "--sets", "hopper", "--steps", "500", "--out", str(tmp_path)]
    )
    assert status == 2
    assert "must be a multiple of 300" in capsys.readouterr().err


def test_dry_run_prints_every_seed_of_both_sides_each_on_one_thread(tmp_path, capsys):
    assert against.main(["--dry-run", "--scale", "micro", "--sets", "hopper", "--out", str(tmp_path)]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert len(lines) == 2 * MICRO.seeds
    theirs, ours = lines[: MICRO.seeds], lines[MICRO.seeds :]
    assert all("run_trainer.py" in line and "OMP_NUM_THREADS=1" in line for line in theirs)
    assert all("swat_jax.train" in line and line.endswith("# new") for line in ours)
    assert all("intra_op_parallelism_threads=1" in line for line in ours)


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
    constant, other = returns.Final(np.ones(4)), returns.Final(np.full(4, 2.0))
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # scipy warns of catastrophic cancellation on constant samples
        assert returns.welch(constant, constant) == 1.0, "equal and constant: no difference to find"
        assert returns.welch(constant, other) == 0.0, "constant and apart: t is infinite"


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


@pytest.mark.slow
def test_swat_jax_side_at_micro_scale_trains_draws_and_reports(tmp_path, capsys):
    argv = [
        "--scale",
        "micro",
        "--sets",
        "hopper",
        "--only",
        "swat_jax",
        "--parallel",
        "1",
        "--out",
        str(tmp_path),
    ]
    assert against.main(argv) == 0
    lines = plotted(tmp_path / "hopper.csv")
    panels = ["Hopper++: mean over bodies", "Hopper++: hopper_3", "Hopper++: hopper_4", "Hopper++: hopper_5"]
    assert sorted(lines) == sorted((panel, runs.OURS) for panel in panels)
    mean_line = lines["Hopper++: mean over bodies", runs.OURS]
    assert [int(row["env_steps"]) for row in mean_line] == [300, 600]
    assert all(int(row["seeds"]) == MICRO.seeds for row in mean_line)
    assert (tmp_path / "hopper.png").stat().st_size > 10_000
    report = (tmp_path / "against_original.md").read_text()
    assert f"| {runs.OURS} | {MICRO.seeds} |" in report and "per seed (one core each)" in report
    assert "Welch" not in report, "no test without the original's side"
    timings = json.loads((tmp_path / "timings.json").read_text())
    assert sorted(timings) == [f"hopper-swat_jax-seed{k}" for k in range(MICRO.seeds)]
    # A second call keeps the finished runs instead of training them again.
    capsys.readouterr()
    assert against.main(argv) == 0
    assert capsys.readouterr().err.count("steps), kept") == MICRO.seeds


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


def test_the_seed_table_tells_seeds_on_a_plateau_from_those_that_break_out():
    def seed(hopper_3, length):
        flat = {300: 1.0, 600: 1.0}
        return curves.SeedCurves(
            {"hopper_3": dict(zip((300, 600), hopper_3, strict=True)), "hopper_4": flat, "hopper_5": flat},
            {300: 1.0, 600: 2.0},
            {"hopper_3": {300: length, 600: length}},
        )

    sides = {
        runs.ORIGINAL: [seed((50.0, 100.0), 40.0), seed((60.0, 120.0), 50.0)],
        runs.OURS: [seed((110.0, 20.0), 30.0), seed((40.0, 45.0), 20.0)],
    }
    finals = {side: returns.final_returns(seeds, MICRO, "hopper") for side, seeds in sides.items()}
    lines = against._difference_lines(sides, finals, MICRO, "hopper", ())
    assert any(line.startswith("hopper_3 seed by seed") and "110.0" in line for line in lines), (
        "by default the body whose finals differ (the others are equal) with the original's final on it"
    )
    rows = [line for line in lines if line.startswith(f"| {runs.OURS} |")]
    assert rows[0] == f"| {runs.OURS} | 0 | 20 | 30 | 110 at 300 | 300 |", "broke out at 300, fell back"
    assert rows[1] == f"| {runs.OURS} | 1 | 45 | 20 | 45 at 600 | never |", "never reached the original"
    chosen = against._difference_lines(sides, finals, MICRO, "hopper", ("hopper_4", "walker_7_main"))
    assert [line.split(" ")[0] for line in chosen if "seed by seed" in line] == ["hopper_4"]


def test_panel_titles_name_the_set_shortly_enough_to_fit_above_a_panel():
    bodies = get_set("animal_walkers").train
    seed = curves.SeedCurves({body: {2500: 1.0} for body in bodies}, {2500: 1.0})
    panels = {point.panel for point in curves.curve_points("animal_walkers", {runs.OURS: [seed]})}
    assert panels == {"Animal-Walkers: mean over bodies", *(f"Animal-Walkers: {body}" for body in bodies)}
    assert get_set("hopper").title == "Hopper++"


def _ours_rows(seed: int, counted: list[int], value: float) -> list[dict[str, float]]:
    """Metrics rows of one swat_jax seed of Hopper++ at these counted steps (2x as many slots, 1.5x stored)."""
    bodies = get_set("hopper").train
    return [
        {
            "seed": seed,
            "env_steps": 2.0 * n,
            "stored_steps": 1.5 * n,
            "counted_steps": n,
            "steps_per_second": 10.0,
        }
        | {f"return/{body}": value for body in bodies}
        | {f"length/{body}": 20.0 for body in bodies}
        for n in counted
    ]


def test_our_last_round_past_the_budget_is_binned_as_the_originals_and_a_short_run_is_named(tmp_path):
    """A seed's rows up to the first that counts the budget (650 > 600) land on the grid, as the original's
    last round does; a seed that ended at 300 has no final return: the report leaves it out and says where it
    ended, and prints no NaN; the stored and waited steps are told apart."""
    finished = _ours_rows(0, [150, 300, 450, 650, 800], 10.0)
    short = _ours_rows(1, [150, 300], 99.0)
    seeds = [curves.ours_curves(rows, MICRO, "hopper", None)[0] for rows in (finished, short)]
    assert seeds[0].returns["hopper_3"] == {300: 10.0, 600: 10.0}, "the row at 800 comes after the budget"
    final = returns.final_returns(seeds, MICRO, "hopper")
    assert list(final.finite().values) == [10.0] and final.cell() == "10.0 (1 of 2 seeds)"
    assert returns.Final(np.array([10.0, 12.0, np.nan])).cell() == "11.0 ± 1.0, 2 of 3 seeds"
    assert returns.Final(np.array([])).cell() == "no seed reached the budget"
    lines = "\n".join(against._short_lines({runs.OURS: seeds}, MICRO, "hopper"))
    assert f"{runs.OURS} seed 1 ended at the 300-step point, short of" in lines and "seed 0" not in lines
    surplus = "\n".join(against._surplus_lines([], finished + short))
    assert "stored 1.50-1.50x the transitions" in surplus and "2.00-2.00x collection slots" in surplus
    older = [{k: v for k, v in row.items() if k != "stored_steps"} for row in finished]
    surplus = "\n".join(against._surplus_lines([], older + short))
    assert "stored 1.50-1.50x the transitions they counted (1 of 2 seeds record what they stored)" in surplus
    assert "did not record" in "\n".join(against._surplus_lines([], older))


def test_the_pooled_test_combines_the_sets_one_sided_welch_tests():
    """Four sets whose two-sided Welch p are 0.76, 0.62, 0.32 and 0.29, all lower: one-sided p of half those,
    Stouffer's combination 0.077 (what the issue computed for the project's four parity sets), the sign test
    1/16; a set whose side is higher pulls the combination up."""
    rng = np.random.default_rng(1)
    spread = rng.normal(0.0, 1.0, 8)
    spread = (spread - spread.mean()) / spread.std(ddof=1) * 20.0
    pairs = []
    for two_sided in (0.764, 0.619, 0.318, 0.293):
        a = returns.Final(200.0 + spread)
        shift = scipy_stats.t.isf(two_sided / 2, 14) * 20.0 * math.sqrt(2 / 8)
        pairs.append((a, returns.Final(200.0 - shift + spread)))
    one_sided = [returns.below(a, b) for a, b in pairs]
    assert one_sided == pytest.approx([0.382, 0.3095, 0.159, 0.1465], abs=1e-6)
    assert returns.stouffer(one_sided) == pytest.approx(0.077, abs=0.001)
    assert returns.sign_test(4, 4) == 1 / 16 and returns.sign_test(0, 4) == 1.0
    assert returns.stouffer([*one_sided, 1 - one_sided[0]]) > returns.stouffer(one_sided)
    low, high = returns.difference_interval(*pairs[0])
    difference = pairs[0][1].mean - pairs[0][0].mean
    assert low < difference < high and high - difference == pytest.approx(difference - low)
    assert returns.difference_interval(*pairs[0], level=0.95)[0] < low
    pooled = "\n".join(against.pooled_lines({"hopper": pairs[0], "walker": pairs[1]}))
    assert "| Hopper++ | 8, 8 |" in pooled and "| 0.764 | 0.382 |" in pooled
    assert f"over the 2 sets: p = {returns.stouffer(one_sided[:2]):.3f}; swat_jax lower on 2 of 2" in pooled


def test_the_plateau_table_sets_each_seeds_diagnostics_beside_whether_it_is_stranded(tmp_path, capsys):
    """Two original seeds whose lowest final on hopper_3 is 15; a run of two seeds: seed 0 ends at 5 (below
    it: stranded) with saturated actions, seed 1 at 40; the early window averages the rows after the random
    phase (100 steps per body x 3) up to its share of the run, the late one the last 20%."""
    for seed, final in enumerate((15.0, 30.0)):
        run = runs.original_runs(tmp_path / "original_out", MICRO, "hopper")[seed]
        rewards = {body: [1.0, final] for body in ("hopper_3", "hopper_4", "hopper_5")}
        write_original_seed(run, [300, 600], rewards, [1.0, 2.0])
    run_dir = tmp_path / "run"
    run_dir.mkdir()
    config = TrainConfig(env="hopper", preset="fast", seeds=2, steps=1000, run_dir=str(run_dir))
    config = dataclasses.replace(config, iteration=dataclasses.replace(config.iteration, random_steps=100))
    (run_dir / "config.json").write_text(config.to_json())
    columns = [
        "env_steps",
        "seed",
        *(f"{c}/hopper_{n}" for c in ("return", *plateau.COLUMNS) for n in (3, 4, 5)),
    ]
    with (run_dir / "metrics.csv").open("w", newline="") as file:
        writer = csv.writer(file)
        writer.writerow(columns)
        for steps in (200, 400, 600, 800, 1000):
            for seed, (final, saturated) in enumerate(((5.0, 0.9), (40.0, 0.1))):
                values = {"return": final if steps == 1000 else 0.0, "diag/saturated": saturated}
                writer.writerow([steps, seed, *(values.get(c.rsplit("/", 1)[0], steps) for c in columns[2:])])
    argv = [
        str(run_dir),
        "--original-from",
        str(tmp_path / "original_out"),
        "--scale",
        "micro",
        "--early",
        "0.5",
    ]
    assert plateau.main(argv) == 0
    table = capsys.readouterr().out
    assert "run, hopper_3 (stranded: below the original's lowest seed, 15.0):" in table
    assert "| 0 | 5.0 | yes | 500, 1e+03 | 0.9, 0.9 |" in table, "length early: the rows at 400 and 600"
    assert "| 1 | 40.0 | no | 500, 1e+03 | 0.1, 0.1 |" in table
    assert plateau.main([str(tmp_path), "--original-from", str(tmp_path)]) == 2
