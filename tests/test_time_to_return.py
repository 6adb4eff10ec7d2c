"""experiments/time_to_return.py: the smoothed crossing of R, machine seconds per seed, and the whole
benchmark at micro scale against original runs written as the original's tools leave them."""

import csv
import dataclasses
import json
import re
import sys
from pathlib import Path

import numpy as np
import pytest
from test_against_original import write_original_seed

from experiments import paper
from experiments import time_to_return as ttr
from experiments.original import curves, returns, runs
from swat_jax.morphology import SETS, get_set
from swat_jax.runs.config import PRESETS, load_config
from swat_jax.train import INTERRUPTED_STATUS

MICRO = runs.SETTINGS["micro"]
RESULTS = Path(__file__).parents[1] / "experiments" / "results"


def test_the_crossing_is_the_first_point_whose_trailing_mean_reaches_r():
    points = [(100, 10.0, 0.0, 0.0), (200, 20.0, 50.0, 0.0), (300, 30.0, 40.0, 0.0), (400, 40.0, 60.0, 0.0)]
    assert ttr.smoothed_crossing(points, 45.0, 1) == (200, 20.0), "unsmoothed: the first spike counts"
    assert ttr.smoothed_crossing(points, 45.0, 2) == (300, 30.0), "mean of 50 and 40"
    assert ttr.smoothed_crossing(points, 55.0, 2) is None, "never: the last two points average 50"


def test_machine_seconds_per_seed_charge_every_core_to_the_seeds_run_at_once():
    seeds = [
        curves.SeedCurves({"a": {300: 1.0}}, {300: 100.0}),
        curves.SeedCurves({"a": {300: 2.0}}, {300: 120.0}),
    ]
    assert ttr.machine_seconds(seeds, 2, 4) == ({300: 50.0}, {300: 60.0}), "4 seeds on 2 cores"
    assert ttr.machine_seconds(seeds, 1, 1) == ({300: 100.0}, {300: 120.0}), "one seed on one core"


def test_the_final_return_leaves_out_the_points_past_the_budget():
    curve = curves.SeedCurves({"hopper_3": {400: 1.0, 600: 3.0, 900: 100.0}}, {})
    assert returns.final_returns([curve], MICRO, "hopper").values.tolist() == [3.0], "600 is the budget"
    assert ttr.with_horizon(MICRO, "hopper", 1.6).budget("hopper") == 1200, "rounded up to a point (300)"
    assert ttr.with_horizon(MICRO, "hopper", 1.6).budget("walker") == MICRO.budget("walker")


class FixedCurve:
    """A curve with given points (steps, machine seconds, mean, standard error)."""

    def __init__(self, name, points):
        self.name, self._points = name, points

    def points(self):
        return self._points


def test_the_figure_draws_every_curve_against_steps_and_seconds_under_one_title(tmp_path, monkeypatch):
    drawn = []
    monkeypatch.setattr(ttr, "save", lambda figure, path: drawn.append(figure))
    curves_ = [
        FixedCurve("original (PyTorch)", [(1000, 50.0, 10.0, 1.0), (2000, 100.0, 30.0, 2.0)]),
        FixedCurve("fast-2dev", [(1000, 20.0, 12.0, 1.0), (2000, 40.0, 35.0, 3.0)]),
    ]
    title = "Animal-Walkers (NerveNet bodies, 21-value limb observation), 4 seeds"
    ttr.figure(curves_, 25.0, 2000, title, tmp_path / "set.png")
    (figure,) = drawn
    assert figure._suptitle.get_text() == title
    steps_axis, seconds_axis = figure.axes
    for ax, xs in ((steps_axis, ([1000, 2000], [1000, 2000])), (seconds_axis, ([50, 100], [20, 40]))):
        assert ax.get_title() == "", "one title over both panels, not one per panel"
        lines = {line.get_label(): line for line in ax.get_lines()}
        assert lines["original (PyTorch)"].get_xdata().tolist() == xs[0]
        assert lines["fast-2dev"].get_xdata().tolist() == xs[1]
        assert lines["fast-2dev"].get_ydata().tolist() == [12.0, 35.0]
        assert "R = 25.0" in [text.get_text() for text in ax.get_legend().get_texts()]


def test_the_body_table_shows_the_body_where_a_configuration_falls_short():
    def curve(name: str, walker_2: list[float], walker_7: list[float]) -> ttr.Curve:
        finals = {
            body: returns.Final(np.array(v))
            for body, v in (("walker_2_main", walker_2), ("walker_7_main", walker_7))
        }
        return ttr.Curve(
            name, (), (), returns.Final(np.mean([f.values for f in finals.values()], axis=0)), finals
        )

    original = curve(ttr.ORIGINAL, [200.0, 210.0, 190.0], [300.0, 310.0, 290.0])
    lines = ttr.body_finals_table(original, [curve("fast", [200.0, 212.0, 188.0], [100.0, 110.0, 90.0])])
    assert "| configuration | walker_2_main | walker_7_main |" in lines
    assert f"| {ttr.ORIGINAL} | 200.0 ± 5.8 | 300.0 ± 5.8 |" in lines
    assert "| fast | 200.0 ± 6.9 (1.00) | 100.0 ± 5.8 (0.00) |" in lines
    unfinished = curve("fast", [200.0, np.nan, 188.0], [np.nan, np.nan, np.nan])
    assert "| fast | 194.0 ± 6.0 (0.53), 2 of 3 seeds | no episode ended |" in ttr.body_finals_table(
        original, [unfinished]
    ), "a seed without an episode in the window is left out"


def test_the_stranded_table_counts_seeds_below_every_seed_of_the_original():
    def curve(name: str, walker_7: list[float]) -> ttr.Curve:
        finals = {"walker_7_main": returns.Final(np.array(walker_7))}
        return ttr.Curve(name, (), (), finals["walker_7_main"], finals)

    original = curve(ttr.ORIGINAL, [300.0, 260.0, 290.0, 310.0])
    lines = ttr.stranded_table(original, [curve("fast", [44.0, 50.0, 270.0, 320.0])])
    assert "| fast | 2 of 4 | 2 of 4 |" in lines, "the two seeds that never walk; 270 is above 260"
    assert "by chance alone about 1 in 5" in lines[0]
    eight = curve(ttr.ORIGINAL, [300.0, 260.0, 290.0, 310.0, 280.0, 240.0, 330.0, 250.0])
    lines = ttr.stranded_table(eight, [curve("fast", [44.0, 50.0, 270.0, 320.0])])
    assert "| fast | 2 of 4 | 2 of 4 |" in lines and "about 1 in 9" in lines[0], "against 8 seeds"


def test_every_candidate_builds_a_valid_run_whatever_the_preset_is_now(tmp_path):
    """Each candidate builds a valid run at the small scale (a candidate measured with an earlier preset is
    retired, its config kept in the results folder that reports it)."""
    settings = runs.SETTINGS["small"]
    for name in ttr.CANDIDATES:
        config = ttr.candidate_run(tmp_path, settings, "walker", name).config
        assert (config.env, Path(config.run_dir).name) == ("walker", f"walker-{name}")


def test_the_fast_candidate_at_the_small_scale_is_the_fast_preset_a_user_runs(tmp_path):
    """The preset's own sizes and hyperparameters are the ones its time to return was measured with."""
    settings = runs.SETTINGS["small"]
    measured = ttr.candidate_run(tmp_path, settings, "walker", "fast").config
    run_fields = ("env", "steps", "seeds", "run_dir", "log_interval", "checkpoint_interval")
    assert (
        dataclasses.replace(measured, **{f: getattr(PRESETS["fast"], f) for f in run_fields})
        == PRESETS["fast"]
    )


def test_an_unknown_candidate_is_refused(tmp_path, capsys):
    status = ttr.main(["--dry-run", "--scale", "micro", "--candidates", "fastest", "--out", str(tmp_path)])
    assert status == 2 and "unknown candidate 'fastest'" in capsys.readouterr().err


@pytest.mark.slow
def test_micro_scale_trains_reports_and_resumes(tmp_path, capsys, monkeypatch):
    """A fast-preset candidate sized for the micro budget (3 bodies x 2 copies x 50 steps per iteration)
    beside two original seeds whose final return R is 19.5 (their points at 600 steps): the report has
    both, the figure and the CSV their lines, a second call keeps the finished run, and a longer horizon
    resumes it (the resume's training is test_paper_experiments'; the final return at the budget whatever
    the curve's length, test_the_final_return_leaves_out_the_points_past_the_budget)."""
    monkeypatch.setitem(ttr.CANDIDATES, "fast", ttr.Candidate(copies=2, chunk=50, updates=4))
    original_out = tmp_path / "against"
    for seed, run in enumerate(runs.original_runs(original_out, MICRO, "hopper")):
        rewards = [10.0 + seed, 20.0 + seed, 20.0 - seed]
        write_original_seed(
            run,
            [150, 300, 600],
            dict.fromkeys(("hopper_3", "hopper_4", "hopper_5"), rewards),
            [30.0, 60.0, 90.0],
        )
    out = tmp_path / "out"
    argv = ["--scale", "micro", "--sets", "hopper", "--candidates", "fast", "--window", "1"]
    argv += ["--original-from", str(original_out), "--out", str(out)]
    assert ttr.main(argv) == 0
    report = (out / "time_to_return.md").read_text()
    assert "R = 19.5" in report
    # The original's own curve: 15.5 at 300 (each seed's two rounds there averaged), 19.5 at 600 (90 s).
    assert f"| {ttr.ORIGINAL} | 2 | 90 | 1.00 | 600 | 19.5 ± 0.5 | - |" in report
    assert "| fast | 2 |" in report
    assert f"| {ttr.ORIGINAL} | 19.5 ± 0.5 | 19.5 ± 0.5 | 19.5 ± 0.5 |" in report, "each body's final return"
    with (out / "hopper.csv").open() as file:
        rows = list(csv.DictReader(file))
    assert {row["configuration"] for row in rows} == {ttr.ORIGINAL, "fast"}
    fast = [row for row in rows if row["configuration"] == "fast"]
    assert [int(row["counted_steps"]) for row in fast] == [300, 600]
    assert float(fast[0]["machine_seconds_per_seed"]) > 0
    assert (out / "hopper.png").stat().st_size > 10_000
    capsys.readouterr()
    assert ttr.main(argv) == 0
    assert "done (600 steps), kept" in capsys.readouterr().err
    assert ttr.main([*argv, "--candidates", "fast", "paper", "--report-only"]) == 0
    assert "| paper |" not in (out / "time_to_return.md").read_text(), "no paper run: left out"
    third = runs.original_runs(original_out, dataclasses.replace(MICRO, seeds=3), "hopper")[2]
    write_original_seed(
        third,
        [150, 300, 600],
        {body: [12.0, 22.0, 18.0] for body in ("hopper_3", "hopper_4", "hopper_5")},
        [30.0, 60.0, 90.0],
    )
    assert ttr.main([*argv, "--report-only", "--original-seeds", "3"]) == 0
    with_third = (out / "time_to_return.md").read_text()
    assert "R = 19.0" in with_third and "(seeds 0 to 2)" in with_third, "R from the original's 3 seeds"
    assert f"| {ttr.ORIGINAL} | 3 |" in with_third and "| fast | 2 |" in with_third
    assert not (out / "runs" / "hopper-paper").exists()
    capsys.readouterr()
    started = []
    monkeypatch.setattr(paper, "run_child", lambda command: started.append(command) or INTERRUPTED_STATUS)
    assert ttr.main([*argv, "--horizon", "2"]) == INTERRUPTED_STATUS
    assert "resuming at 600 steps" in capsys.readouterr().err, "twice the budget: the run continues"
    run_dir = str(out / "runs" / "hopper-fast")
    assert started == [[sys.executable, "-m", "swat_jax.train", "--resume", run_dir, "--steps", "1200"]]


def test_a_two_device_candidate_runs_with_the_cpu_as_two_devices(tmp_path):
    run = ttr.candidate_run(tmp_path, MICRO, "hopper", "fast-2dev")
    for command in (run.command(), run.resume_command()):
        assert command[0] == "env" and command[1].endswith("--xla_force_host_platform_device_count=2")
        assert command[2:5] == [sys.executable, "-m", "swat_jax.train"]
    assert run.resume_command()[5:7] == ["--resume", str(run.run_dir)], "a resumed run keeps its devices"
    assert paper.shown(run.command()).startswith("env 'XLA_FLAGS=") and " python -m swat_jax.train " in (
        paper.shown(run.command())
    ), "printed as a line to copy"
    plain = ttr.candidate_run(tmp_path, MICRO, "hopper", "fast")
    assert dataclasses.replace(plain.config, run_dir="") == dataclasses.replace(run.config, run_dir="")
    assert "device_count" not in " ".join(plain.command())


def test_every_candidate_is_its_preset_at_the_scale_with_its_changes(tmp_path):
    """The paper candidates are against_original's run with their changes; the fast preset keeps its batch's
    ratio to the paper's, so at the scale's batch (the original's) it is the preset's own recipe."""
    small = runs.SETTINGS["small"]

    def config(name: str):
        return ttr.candidate_run(tmp_path, small, "walker", name).config

    assert config("paper-2dev").network.initialisation == "original"
    assert config("paper-flax-2dev").network.initialisation == "flax"
    assert dataclasses.replace(
        config("paper-flax-2dev"), network=config("paper-2dev").network, run_dir=""
    ) == (dataclasses.replace(config("paper-2dev"), run_dir=""))
    assert config("paper-2dev").td3.batch_size == small.batch_size == 100
    fast = config("fast-2dev")
    assert fast.td3.batch_size == 25 and fast.iteration.updates == 256
    recipe = load_config(RESULTS / "fast_recipe/runs/walker-fast-c4-k16-u256-b25-2dev/config.json")
    longer = ttr.candidate_run(tmp_path, ttr.with_horizon(small, "walker", 1.5), "walker", "fast-2dev").config
    shape = dataclasses.replace(
        longer, run_dir="", td3=recipe.td3, iteration=dataclasses.replace(longer.iteration, diagnostics=False)
    )
    assert shape == dataclasses.replace(recipe, run_dir=""), "the preset's shape is the recipe's, as it ran"
    last = dataclasses.replace(config("fast-ap0.003-p0.25-2dev"), run_dir="")
    assert last == dataclasses.replace(fast, run_dir=""), "and its TD3 settings the last search's"
    before = config("fast-ap0.003-2dev").td3
    assert before.target_pessimism == 0.5, "the preset before pessimism 0.25, as it was measured"
    assert dataclasses.replace(before, target_pessimism=fast.td3.target_pessimism) == fast.td3
    earlier = config("fast-rscale-p0.5-2dev").td3
    assert earlier.action_penalty == 0.0, "the preset before the action penalty, as it was measured"
    assert dataclasses.replace(earlier, action_penalty=fast.td3.action_penalty) == before


def test_the_originals_budget_is_given_with_steps_and_a_run_of_another_is_refused(tmp_path, capsys):
    longer = MICRO.given(None, 1200, ["hopper"])
    original_out = tmp_path / "against"
    for seed, run in enumerate(runs.original_runs(original_out, longer, "hopper")):
        rewards = [10.0, 20.0, 30.0 + seed, 40.0 + seed]
        write_original_seed(
            run,
            [300, 600, 900, 1200],
            dict.fromkeys(("hopper_3", "hopper_4", "hopper_5"), rewards),
            [1, 2, 3, 4],
        )
        (run.folder / "args.txt").write_text(json.dumps({"max_timesteps": 1200}))
    argv = ["--scale", "micro", "--sets", "hopper", "--candidates", "fast", "--report-only"]
    argv += ["--original-from", str(original_out), "--out", str(tmp_path / "out")]
    assert ttr.main(argv) == 2
    assert "to 1,200 counted steps, not 600: give --steps 1200" in capsys.readouterr().err
    assert ttr.main([*argv, "--steps", "1200"]) == 0
    assert "R = 40.5" in (tmp_path / "out" / "time_to_return.md").read_text(), "the last 20% of 1,200 steps"
    assert ttr.main([*argv, "--steps", "0"]) == 2
    assert "--steps must be 1 or more, got 0" in capsys.readouterr().err


def reported_runs(report: Path) -> list[tuple[str, str]]:
    """(set, candidate) of every swat_jax row of a committed time-to-return report, in order."""
    sets = {get_set(name).description or name: name for name in SETS}
    rows, environment_set = [], None
    for line in report.read_text().splitlines():
        if section := re.match(r"## (.*), [\d,]+ steps$", line):
            environment_set = sets[section.group(1)]
        elif (row := re.match(r"\| ([a-z][^ |]*) \| \d+ \|", line)) and environment_set:
            rows.append((environment_set, row.group(1)))
    return list(dict.fromkeys(rows))


REPORTS = sorted(
    report
    for report in RESULTS.glob("*/*.md")
    if report.read_text().startswith("# Time to the original's final return")
)


@pytest.mark.parametrize("report", REPORTS, ids=lambda report: f"{report.parent.name}/{report.name}")
def test_every_run_a_committed_report_shows_has_its_config(report):
    """Any figure can be rerun: each swat_jax row of a time-to-return report has its run's config.json,
    ``runs/<set>-<candidate>/`` in the report's folder, retired candidates' included."""
    rows = reported_runs(report)
    assert rows, "the report has swat_jax rows"
    for environment_set, name in rows:
        path = report.parent / "runs" / f"{environment_set}-{name}" / "config.json"
        assert path.is_file(), f"{path}: the config of a reported run is missing"
        config = load_config(path)
        assert config.env == environment_set, f"{path}: a run of {config.env}"
