"""experiments/three_d.py's report: curve points at the runs' common budget and at each run's own end,
beside the random-action return, per body and over the set."""

from __future__ import annotations

import json

import numpy as np

from experiments.three_d import ThreeDCommand, curve_point, report

BODIES = ("3d_hopper_3_shin", "3d_hopper_4_lower_shin", "3d_hopper_5_full")


def _run(directory, seeds: int, steps: int, returns: dict[int, list[float]]):
    """A run directory with config.json and a metrics.csv of one row per seed and curve point, every body
    at ``returns[step][seed]`` plus its index."""
    directory.mkdir(parents=True)
    (directory / "config.json").write_text(json.dumps({"seeds": seeds, "steps": steps}))
    header = ["env_steps", "seed"] + [f"return/{body}" for body in BODIES]
    rows = [
        [str(step), str(seed)] + [str(value + index) for index in range(len(BODIES))]
        for step, values in returns.items()
        for seed, value in enumerate(values)
    ]
    (directory / "metrics.csv").write_text("\n".join(",".join(row) for row in [header, *rows]) + "\n")
    return directory


def test_curve_points_and_the_report(tmp_path):
    long = _run(tmp_path / "swat", 2, 40_000, {20_000: [10.0, 20.0], 40_000: [30.0, 50.0]})
    short = _run(tmp_path / "smp", 1, 20_000, {10_000: [1.0], 20_160: [5.0]})
    assert curve_point(long, BODIES, 20_000)[BODIES[0]] == (15.0, 5.0)
    assert curve_point(long, BODIES)["set"] == (41.0, 10.0), "the last point, mean over the three bodies"
    assert curve_point(short, BODIES, 20_000)[BODIES[2]] == (3.0, 0.0), "the last point not beyond 20,000"
    random = {body: np.array([1.0, 3.0]) for body in BODIES}
    text = report(ThreeDCommand(), {"swat": long, "smp": short}, random)
    assert "| body | random actions | swat at 20,000 | smp at 20,000 | swat at 40,000 |" in text
    assert "| 3d_hopper_3_shin | 2.0 ± 1.0 | 15.0 ± 5.0 | 1.0 ± 0.0 | 40.0 ± 10.0 |" in text
    assert "| **mean over the bodies** | 2.0 | 16.0 ± 5.0 | 2.0 ± 0.0 | 41.0 ± 10.0 |" in text
    assert "swat: 2 seeds, 40,000 steps; smp: 1 seeds, 20,000 steps" in text
