"""The evaluation command: deterministic per-body returns and lengths, splits, JSON, videos, errors."""

from __future__ import annotations

import dataclasses
import json
import shutil

import numpy as np
import pytest

from swat_jax.cli import strict_json
from swat_jax.eval import EvalOptions, evaluate, evaluate_run, main
from swat_jax.runs.config import load_config
from swat_jax.runs.trained import load_policy


def test_evaluation_is_deterministic_and_episodes_differ_by_their_resets(trained_run):
    policy = load_policy(trained_run)
    [first] = evaluate(policy, ["hopper_3"], episodes=2, seed=1)
    [again] = evaluate(policy, ["hopper_3"], episodes=2, seed=1)
    np.testing.assert_array_equal(first.returns, again.returns)
    assert first.seeds == (0, 1) and first.returns.shape == first.lengths.shape == (2, 2)
    assert len(set(first.returns[0].tolist())) == 2, "each episode has its own reset noise"
    assert ((first.lengths > 0) & (first.lengths <= 1000)).all()
    assert first.qpos is None
    assert not np.array_equal(first.returns[0], first.returns[1]), "each seed has its own actor"
    [only_second] = evaluate(policy, ["hopper_3"], episodes=2, seed=1, seed_indices=[1])
    np.testing.assert_allclose(only_second.returns[0], first.returns[1], rtol=1e-5)
    summary = first.summary()
    seed_means = first.returns.mean(axis=1)
    assert summary["return_mean"] == pytest.approx(seed_means.mean(), rel=1e-5)
    assert summary["return_se"] == pytest.approx(np.std(seed_means, ddof=1) / np.sqrt(2), rel=1e-4)


def test_json_reports_every_body_and_zero_shot_bodies_by_name(trained_run, capsys):
    assert main([str(trained_run), "--episodes", "2", "--bodies", "hopper_3", "hopper_4", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["env_steps"] == 600 and report["episodes"] == 2 and report["seeds"] == [0, 1]
    assert set(report["bodies"]) == {"hopper_3", "hopper_4"}
    for body in report["bodies"].values():
        assert set(body["per_seed"]) == {"0", "1"}
        for seed in body["per_seed"].values():
            assert len(seed["returns"]) == 2
            assert seed["return_mean"] == pytest.approx(np.mean(seed["returns"]), rel=1e-5)
            assert seed["length_std"] == pytest.approx(np.std(seed["lengths"]), abs=1e-4)
        seed_means = [seed["return_mean"] for seed in body["per_seed"].values()]
        assert body["return_mean"] == pytest.approx(np.mean(seed_means), rel=1e-5)


def test_a_run_evaluates_from_python_with_typed_options(trained_run):
    run = evaluate_run(trained_run, EvalOptions(bodies=("hopper_3",), episodes=2, seed=1, seed_index=1))
    [expected] = evaluate(load_policy(trained_run), ["hopper_3"], episodes=2, seed=1, seed_indices=[1])
    assert run.run_dir == trained_run and run.results[0].seeds == (1,)
    np.testing.assert_array_equal(run.results[0].returns, expected.returns)


def strict_loads(text: str) -> object:
    """Parse as a strict JSON reader (jq, JavaScript) does: NaN and Infinity are not JSON."""

    def refuse(constant: str) -> None:
        raise ValueError(f"not standard JSON: {constant}")

    return json.loads(text, parse_constant=refuse)


def test_json_of_one_seed_is_standard_json_with_null_spread(trained_run, capsys):
    args = [str(trained_run), "--episodes", "2", "--bodies", "hopper_3", "--seed-index", "0", "--json"]
    assert main(args) == 0
    body = strict_loads(capsys.readouterr().out)["bodies"]["hopper_3"]
    assert body["return_se"] is None, "one seed has no standard error"
    assert body["return_mean"] == pytest.approx(body["per_seed"]["0"]["return_mean"])


def test_strict_json_writes_null_for_undefined_numbers():
    text = strict_json({"se": float("nan"), "up": [np.float32(np.inf), np.float64(1.5)], "n": np.int64(3)})
    assert strict_loads(text) == {"se": None, "up": [None, 1.5], "n": 3}


def test_table_and_video_of_the_train_split(trained_run, tmp_path, capsys):
    assert main([str(trained_run), "--episodes", "2", "--video", str(tmp_path / "videos")]) == 0
    out = capsys.readouterr().out
    assert "after 600 environment steps" in out and "hopper_3" in out and "± s.e." in out
    assert "seed 0" in out and "seed 1" in out
    video = tmp_path / "videos" / "hopper_3.mp4"
    assert video.stat().st_size > 1000


def test_errors_name_the_problem(trained_run, tmp_path, capsys):
    assert main([str(trained_run), "--split", "test"]) == 2
    assert "has no test bodies" in capsys.readouterr().err
    assert main([str(trained_run), "--seed-index", "2"]) == 2
    assert "holds 2 seeds (0, 1); use an index from 0 to 1" in capsys.readouterr().err
    assert main([str(tmp_path / "nowhere")]) == 2
    assert "no such run directory" in capsys.readouterr().err
    assert main([str(trained_run), "--bodies", "nervenet_hopper"]) == 2
    assert "nervenet_hopper: 21 observation features per limb, the policy was trained on 19" in (
        capsys.readouterr().err
    )


def test_markdown_table_has_a_column_per_run_and_mean_and_standard_error_over_seeds(
    trained_run, tmp_path, capsys
):
    twin = tmp_path / "twin"
    shutil.copytree(trained_run, twin)
    config = load_config(twin / "config.json")
    (twin / "config.json").write_text(dataclasses.replace(config, run_dir=str(twin)).to_json())
    assert main([str(trained_run), str(twin), "--episodes", "2", "--markdown"]) == 0
    lines = capsys.readouterr().out.strip().splitlines()
    assert lines[:2] == [f"| body | {trained_run.name} | twin |", "|---|---|---|"], "algorithms repeat"
    [evaluation] = evaluate(load_policy(trained_run), ["hopper_3"], episodes=2)
    summary = evaluation.summary()
    cell = f"{summary['return_mean']:.1f} ± {summary['return_se']:.1f}"
    assert lines[2] == f"| hopper_3 | {cell} | {cell} |"
    assert "over 2 seeds" in lines[-1]
    assert main([str(trained_run), str(twin), "--video", str(tmp_path / "v")]) == 2
    assert "--video takes one RUN_DIR" in capsys.readouterr().err
