"""experiments.specialists at a micro scale: Brax SAC specialists of a one-body set beside a tiny swat_jax
run, evaluated, reported, drawn, and an interrupted command goes on where it stopped."""

from __future__ import annotations

import json

import numpy as np
import pytest

from experiments import specialists


@pytest.mark.slow
def test_specialists_train_report_and_resume(trained_run, hopper_folder, tmp_path):
    out = tmp_path / "specialists"
    argv = ["--env", str(hopper_folder), "--swat-run", str(trained_run), "--seeds", "1"]
    argv += ["--learn-steps", "800", "--episodes", "2", "--out", str(out)]
    assert specialists.main(argv) == 0
    stem = hopper_folder.name
    entries = json.loads((out / f"{stem}-sac.json").read_text())
    assert sorted(entry["budget"] for entry in entries) == [600, 800], (
        "the run's 600 steps over 1 body, then 800"
    )
    for entry in entries:
        assert entry["body"] == "hopper_3" and entry["seed"] == 0 and entry["train_seconds"] > 0
        assert len(entry["returns"]) == 2 and np.all(np.isfinite(entry["returns"]))
        assert all(1 <= length <= 1000 for length in entry["lengths"])
    generalist = json.loads((out / f"{stem}-swat.json").read_text())
    assert set(generalist["evaluation"]["bodies"]["hopper_3"]["per_seed"]) == {"0", "1"}
    result = specialists.read_results(out, str(hopper_folder), "sac")
    assert result.budgets == (600, 800) and set(result.rows["hopper_3"]) == {"swat", 600, 800}
    markdown = (out / f"{stem}-sac.md").read_text()
    assert markdown.startswith(specialists.TABLE_HEADER)
    assert "| hopper_3 | " in markdown and "| wall clock of training | " in markdown
    assert (out / f"{stem}-sac.png").stat().st_size > 10_000

    assert specialists.main(argv) == 0, "a second call finds every specialist trained"
    assert json.loads((out / f"{stem}-sac.json").read_text()) == entries
