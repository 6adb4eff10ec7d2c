"""experiments/paper.py: the grid each command trains, and one command end to end (train, resume, keep, draw).

The end-to-end test runs figure4 for AMORPHEUS on the hopper_3 folder set at the size of the shared tiny
run (conftest's tiny_train_config), so its training program is the one the compilation cache already
holds when that run was trained first.
"""

import csv
import dataclasses
from pathlib import Path

import pytest
from conftest import tiny_train_config

from experiments import paper
from swat_jax.runs.config import load_config


def test_figure4_and_figure6_train_every_set_with_every_algorithm_seeds_in_one_program(tmp_path):
    scale = paper.SCALES["tiny"]
    runs = paper.grid("figure4", scale, ["hopper", "walker"], paper.MAIN_ALGORITHMS, tmp_path)
    assert [run.name for run in runs] == [
        "hopper-swat", "hopper-amorpheus", "hopper-smp", "walker-swat", "walker-amorpheus", "walker-smp"
    ]  # fmt: skip
    for run in runs:
        config = run.config
        assert (config.seeds, config.steps, config.split, config.network.width) == (
            3,
            scale.steps,
            "train",
            32,
        )
        assert config.directory() == run.run_dir
    ablations = paper.grid("figure6", scale, ["hopper"], paper.ABLATIONS, tmp_path)
    assert [run.config.algo for run in ablations] == list(paper.ABLATIONS)
    assert ablations[0].run_dir == runs[0].run_dir, "figure6 reuses figure4's SWAT run"


def test_figure5_pretrains_then_fine_tunes_on_held_out_bodies_against_training_from_scratch(tmp_path):
    scale = paper.SCALES["tiny"]
    runs = paper.grid("figure5", scale, ["hopper", "walker"], paper.MAIN_ALGORITHMS, tmp_path)
    names = [run.name for run in runs]
    assert names == [
        "walker-swat", "walker-amorpheus", "walker-smp",
        "walker-test-swat-transfer", "walker-test-amorpheus-transfer", "walker-test-smp-transfer",
        "walker-test-swat-scratch",
    ], "hopper has no held-out bodies, so it is skipped"  # fmt: skip
    by_name = {run.name: run for run in runs}
    for algorithm in paper.MAIN_ALGORITHMS:
        transfer = by_name[f"walker-test-{algorithm}-transfer"].config
        assert transfer.init_from == str(by_name[f"walker-{algorithm}"].run_dir.resolve())
        assert (transfer.split, transfer.steps, transfer.algo) == ("test", scale.finetune_steps, algorithm)
    scratch = by_name["walker-test-swat-scratch"].config
    assert (scratch.init_from, scratch.split) == ("", "test")
    assert [run.name for run in paper.plotted_runs("figure5", runs)] == names[3:]


def test_tables_need_a_set_with_held_out_bodies(tmp_path, capsys):
    scale = paper.SCALES["tiny"]
    runs = paper.grid("tables", scale, ["hopper", "walker"], paper.MAIN_ALGORITHMS, tmp_path)
    assert [run.name for run in runs] == ["walker-swat", "walker-amorpheus", "walker-smp"]
    assert "skipping hopper" in capsys.readouterr().err
    assert paper.main(["tables", "--sets", "hopper", "--out", str(tmp_path)]) == 2
    assert "needs sets with held-out bodies" in capsys.readouterr().err


def test_dry_run_writes_the_runs_configs_and_prints_their_commands(tmp_path, capsys):
    """The grid is TrainConfig JSON that ``train --config`` reads, not flag strings parsed back."""
    assert (
        paper.main(["figure4", "--sets", "hopper", "--algos", "smp", "--out", str(tmp_path), "--dry-run"])
        == 0
    )
    (line,) = capsys.readouterr().out.splitlines()
    written = tmp_path / "runs" / "hopper-smp.json"
    assert line == f"python -m swat_jax.train --config {written}"
    config = load_config(written)
    assert (config.env, config.algo, config.seeds, config.network.smp_hidden) == ("hopper", "smp", 3, 32)
    assert config.run_dir == str(tmp_path / "runs" / "hopper-smp")
    assert not (tmp_path / "runs" / "hopper-smp").exists(), "nothing trained"


def micro_scale(hopper_folder: Path, steps: int) -> paper.Scale:
    """The shared tiny run's settings (2 seeds, evaluated during training) as a scale of ``steps`` steps."""
    return paper.Scale(
        name="micro",
        seeds=2,
        steps=steps,
        finetune_steps=steps,
        table_episodes=2,
        base=tiny_train_config(Path("unused"), hopper_folder),
        sets={},
    )


@pytest.mark.slow
def test_figure4_end_to_end_trains_resumes_keeps_and_draws(tmp_path, hopper_folder, capsys):
    out = tmp_path / "results"
    sets, algorithms = [str(hopper_folder)], ["amorpheus"]
    paper.produce("figure4", micro_scale(hopper_folder, 400), sets, algorithms, out, ["figure4"])
    assert "training" in capsys.readouterr().err
    full = micro_scale(hopper_folder, 600)
    report = paper.produce("figure4", full, sets, algorithms, out, ["figure4"])
    assert "resuming at 400 steps" in capsys.readouterr().err
    paper.produce("figure4", full, sets, algorithms, out, ["figure4"])
    assert "done (600 steps), kept" in capsys.readouterr().err

    for stem in ("figure4", "figure4_eval"):
        assert (out / f"{stem}.png").stat().st_size > 10_000
        with (out / f"{stem}.csv").open() as file:
            rows = list(csv.DictReader(file))
        assert {row["algorithm"] for row in rows} == {"amorpheus"}
        assert max(int(row["env_steps"]) for row in rows) == 600
        # A point averages the seeds that finished an episode in its window: both, or one where the
        # other's policy stood through the window.
        assert {row["seeds"] for row in rows} in ({"2"}, {"1", "2"})
    text = report.read_text()
    assert f"| {hopper_folder.name}-amorpheus | 600 |" in text, "wall clock row per run"
    final = paper.final_points(out / "figure4.csv")
    assert len(final) == 1 and int(final[0]["env_steps"]) == 600
    assert f"| {hopper_folder.name} | amorpheus | 600 |" in text, "final point of the curve"

    (run,) = paper.grid("figure4", full, sets, algorithms, out)
    wider_network = dataclasses.replace(full.base.network, width=32)
    wider = dataclasses.replace(full, base=dataclasses.replace(full.base, network=wider_network))
    (other,) = paper.grid("figure4", wider, sets, algorithms, out)
    assert paper.progress(run) == 600
    with pytest.raises(paper.GridError, match="width 16 \\(wanted 32\\)"):
        paper.progress(other)
