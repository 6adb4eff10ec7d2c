"""Both sides' learning curves on SGRL's counter: SGRL's recorded ``performance/train_return`` (the mean over
bodies of each lock-step round's first-episode returns), swat_jax's metrics rows per body."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from experiments.original.curves import SeedCurves, binned, grid_step, ours_curves
from experiments.sgrl.runs import SgrlRun, SgrlScale

MEAN = "mean over bodies"
"""SGRL's one curve: its logger records the mean over bodies only (fidelity row S11)."""
RETURN, LENGTH = "performance/train_return", "performance/train_length"


def sgrl_curves(run: SgrlRun) -> SeedCurves:
    """The seed's rounds binned on the grid up to the first that reaches the budget, with each point's
    machine seconds since its process started (start-up: the wall clock less the recorded span)."""
    records = run.records()
    budget, point = run.scale.budget(run.environment_set), run.scale.point
    rounds = list(_rounds(records).values())
    reaching = next((k for k, record in enumerate(rounds) if record["step"] >= budget), len(rounds) - 1)
    kept = rounds[: reaching + 1]
    bins = [grid_step(record["step"], point, budget) for record in kept]
    startup = run.wall() - (records[-1]["time"] - records[0]["time"])
    seconds = {
        step: startup + record["time"] - records[0]["time"] for step, record in zip(bins, kept, strict=True)
    }
    return SeedCurves(
        {MEAN: binned(bins, [record[RETURN] for record in kept])},
        seconds,
        {MEAN: binned(bins, [record[LENGTH] for record in kept])},
    )


def _rounds(records: Sequence[Mapping[str, float]]) -> dict[float, dict[str, float]]:
    """SGRL's rounds in order, by counter: its logger sends each value in a call of its own, so a round's
    return and length are two records at one counter value, merged here (the first one's time kept)."""
    rounds: dict[float, dict[str, float]] = {}
    for record in records:
        if RETURN in record or LENGTH in record:
            rounds.setdefault(record["step"], {"step": record["step"], "time": record["time"]}).update(
                {name: value for name, value in record.items() if name in (RETURN, LENGTH)}
            )
    return rounds


def ours_on_counter(
    rows: Sequence[Mapping[str, float]], scale: SgrlScale, environment_set: str, wall: float | None
) -> list[SeedCurves]:
    """swat_jax's seeds binned on the same grid, each row at :meth:`SgrlScale.counter` of its counted steps."""
    moved = [{**row, "counted_steps": scale.counter(environment_set, row["counted_steps"])} for row in rows]
    return ours_curves(moved, scale, environment_set, wall)
