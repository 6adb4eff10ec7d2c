"""The evaluation command: deterministic per-body returns and lengths, splits, JSON, videos, errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from swat_jax.eval import evaluate_body, main
from swat_jax.runs.experiment import load_policy


def test_evaluation_is_deterministic_and_episodes_differ_by_their_resets(trained_run):
    policy = load_policy(trained_run)
    first = evaluate_body(policy, "hopper_3", episodes=3, seed=1)
    again = evaluate_body(policy, "hopper_3", episodes=3, seed=1)
    np.testing.assert_array_equal(first.returns, again.returns)
    assert first.returns.shape == first.lengths.shape == (3,)
    assert len(set(first.returns.tolist())) == 3, "each episode has its own reset noise"
    assert ((first.lengths > 0) & (first.lengths <= 1000)).all()
    assert first.qpos is None


def test_json_reports_every_body_and_zero_shot_bodies_by_name(trained_run, capsys):
    assert main([str(trained_run), "--episodes", "3", "--bodies", "hopper_3", "hopper_4", "--json"]) == 0
    report = json.loads(capsys.readouterr().out)
    assert report["env_steps"] == 600 and report["episodes"] == 3
    assert set(report["bodies"]) == {"hopper_3", "hopper_4"}
    for body in report["bodies"].values():
        assert len(body["returns"]) == 3
        assert body["return_mean"] == pytest.approx(np.mean(body["returns"]), rel=1e-5)
        assert body["length_std"] == pytest.approx(np.std(body["lengths"]), abs=1e-4)


def test_table_and_video_of_the_train_split(trained_run, tmp_path, capsys):
    assert main([str(trained_run), "--episodes", "3", "--video", str(tmp_path / "videos")]) == 0
    out = capsys.readouterr().out
    assert "after 600 environment steps" in out and "hopper_3" in out and "±" in out
    video = tmp_path / "videos" / "hopper_3.mp4"
    assert video.stat().st_size > 1000


def test_errors_name_the_problem(trained_run, tmp_path, capsys):
    assert main([str(trained_run), "--split", "test"]) == 2
    assert "has no test bodies" in capsys.readouterr().err
    assert main([str(tmp_path / "nowhere")]) == 2
    assert "no such run directory" in capsys.readouterr().err
    assert main([str(trained_run), "--bodies", "nervenet_hopper"]) == 2
    assert "21 observation features per limb, the policy was trained on 19" in capsys.readouterr().err
