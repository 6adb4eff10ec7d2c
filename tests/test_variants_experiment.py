"""experiments/variants.py: its plan, and the summary and figure it draws from evaluation rows."""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest

from experiments import variants as experiment


def test_the_plan_trains_the_same_run_with_and_without_variants(tmp_path):
    options = experiment.Options(out=tmp_path, train_variants=8, variation=0.2, spreads=(0.2, 0.4))
    runs = experiment.runs(options)
    nominal, variants = runs["nominal"].config, runs["variants"].config
    assert (nominal.envs.variants, variants.envs.variants, variants.envs.variation) == (0, 8, 0.2)
    assert nominal == dataclasses.replace(variants, envs=nominal.envs, run_dir=nominal.run_dir)
    assert nominal.envs == dataclasses.replace(variants.envs, variants=0), "the variants are the only change"
    evaluations = experiment.conditions(options)
    assert list(evaluations) == ["bodies", "variants ±20%", "variants ±40%"]
    assert evaluations["variants ±40%"].variation == 0.4 and evaluations["variants ±40%"].variant_seed == 1


def test_the_summary_averages_bodies_then_seeds_and_the_figure_has_a_bar_per_run_and_condition():
    rows = [
        dict(run=run, condition=condition, body=body, seed=seed, mean_return=value)
        for run, offset in (("nominal", 0.0), ("variants", 100.0))
        for condition in ("bodies", "variants ±20%")
        for seed in (0, 1)
        for body, value in (("hopper_3", 10.0 * seed + offset), ("hopper_4", 30.0 * seed + offset))
    ]
    table = experiment.summary(rows)
    mean, error, seeds = table[("variants", "bodies")]
    assert (mean, seeds) == (110.0, 2)  # the seeds' means over bodies: 100 and 120
    assert error == pytest.approx(np.std([100.0, 120.0], ddof=1) / np.sqrt(2))
    axes = experiment.figure(table, "title").axes[0]
    assert [bar.get_height() for bar in axes.patches] == [10.0, 10.0, 110.0, 110.0]
    assert [text.get_text() for text in axes.get_legend().get_texts()] == [
        "trained on nominal",
        "trained on variants",
    ]
