"""experiments/benchmarks/gpu_report.py: its copy sweeps and time budget, and --tiny end to end on the CPU.

The end-to-end test steps the hopper_3 folder set instead of --tiny's Hopper++ (one body to trace and
compile instead of three), at the same copies 1 and 2.
"""

import json
import subprocess
import sys
from pathlib import Path

import pytest
from subprocesses import python_path_environment

REPO = Path(__file__).resolve().parents[1]
ENVIRONMENT_FIELDS = {
    "set",
    "copies",
    "bodies",
    "max_limbs",
    "steps_per_second",
    "c_steps_per_second",
    "mjx_over_c",
    "trace_s",
    "compile_s",
    "rss_gib",
    "device_peak_gib",
}
UPDATE_FIELDS = {
    "set",
    "network",
    "tasks",
    "batch_per_body",
    "actor_parameters",
    "critic_parameters",
    "trace_s",
    "compile_s",
    "updates_per_second",
    "transitions_per_second",
    "rss_gib",
    "device_peak_gib",
}


@pytest.fixture
def gpu_report():
    from experiments.benchmarks import gpu_report

    return gpu_report


def fake_sweep(gpu_report, steps_per_second: dict[int, float], out_of_time_at: int | None = None):
    """Sweep copies 1, 16, 256, 2048 with made-up throughputs; the counts measured, rows and stop reason."""
    measured = []

    def measure(copies: int) -> dict:
        measured.append(copies)
        if copies == out_of_time_at:
            raise gpu_report.WorkerError("stopped", timed_out=True)
        return {"steps_per_second": steps_per_second[copies], "compile_s": 1.0}

    rows, stop = gpu_report.sweep_copies("hopper", (1, 16, 256, 2048), measure, gpu_report.MIN_GAIN, 0.0)
    return measured, [row["copies"] for row in rows], stop


def test_a_sweep_stops_when_throughput_stops_growing(gpu_report):
    speeds = {1: 100.0, 16: 1000.0, 256: 1040.0, 2048: 5000.0}  # 4% more at 256: stop there
    assert fake_sweep(gpu_report, speeds) == (
        [1, 16, 256],
        [1, 16, 256],
        "throughput stopped growing at 256 copies",
    )
    speeds[256] = 2000.0
    assert fake_sweep(gpu_report, speeds) == ([1, 16, 256, 2048], [1, 16, 256, 2048], "")


def test_a_sweep_stops_where_the_time_budget_ends(gpu_report):
    speeds = {1: 100.0, 16: 1000.0}
    assert fake_sweep(gpu_report, speeds, out_of_time_at=256) == (
        [1, 16, 256],
        [1, 16],
        "out of time at 256 copies",
    )


def test_the_budget_starts_no_run_that_cannot_fit(gpu_report):
    with pytest.raises(gpu_report.WorkerError) as spent:
        gpu_report.Budget(0.0).run(gpu_report.Job(gpu_report.info_worker), "info")
    budget = gpu_report.Budget(100.0)
    budget.last_seconds["cwhh"] = (
        150.0  # the previous, smaller count of this sweep took longer than what is left
    )
    with pytest.raises(gpu_report.WorkerError, match="s left of the budget, 150 s expected") as too_long:
        budget.run(gpu_report.Job(gpu_report.info_worker), "cwhh")
    assert spent.value.timed_out and too_long.value.timed_out
    assert not (spent.value.out_of_memory or too_long.value.out_of_memory)


ONE_SECOND = ("--train-seconds", "1")
"""The training row's wall clock: the run still goes on to its first metrics row, however long it starts."""
ONE_COUNT = ("--copies", "1")
"""One copy count: each count compiles its own program (16 s of the report's 67 here); the sweep over several
is tested above with fake measurements."""


@pytest.mark.slow
def test_tiny_report_writes_json_and_markdown(hopper_folder, tmp_path):
    out = tmp_path / "report"
    sets = [
        "--sets",
        str(hopper_folder),
        "--update-sets",
        str(hopper_folder),
        "--train-set",
        str(hopper_folder),
    ]
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "experiments.benchmarks.gpu_report",
            "--tiny",
            *sets,
            *ONE_SECOND,
            *ONE_COUNT,
            "--out",
            str(out),
        ],
        capture_output=True,
        text=True,
        cwd=REPO,
        env=python_path_environment(REPO),
        check=False,
        timeout=600,
    )
    assert result.returncode == 0, result.stderr[-3000:]
    report = json.loads((out / "report.json").read_text())
    assert report["machine"]["platform"] == "cpu" and report["machine"]["cores"] >= 1
    assert report["software"]["jax"] and report["software"]["mujoco"] == "3.17.0"
    assert report["settings"]["copies"] == [1]
    assert [row["copies"] for row in report["environment"]] == [1]
    for row in report["environment"]:
        assert row.keys() >= ENVIRONMENT_FIELDS
        assert row["bodies"] == 1 and row["max_limbs"] == 3
        assert row["steps_per_second"] > 0 and row["c_steps_per_second"] > 0
        assert row["mjx_over_c"] == pytest.approx(row["steps_per_second"] / row["c_steps_per_second"])
    (update,) = report["td3_update"]
    assert update.keys() >= UPDATE_FIELDS
    assert update["tasks"] == 1 and update["batch_per_body"] == 8 and update["transitions_per_second"] > 0
    (training,) = report["training"]
    assert (training["preset"], training["seeds"]) == ("fast", 2)
    assert training["curve"] and training["env_steps_per_second_per_seed"] > 0
    assert 0 < training["first_row_s"] <= training["curve"][-1]["seconds"] <= training["wall_s"] + 1e-6
    assert report["peak_device_memory_gib"] is None  # the CPU backend reports no device memory
    assert report["not_measured"] == [] and report["total_s"] > 0
    markdown = (out / "report.md").read_text()
    assert markdown.startswith("# GPU report\n")
    assert "| set | bodies x max limbs | copies | MJX steps/s |" in markdown
    assert f"| {hopper_folder} | 1x3 | 1 | " in markdown
    assert f"| {hopper_folder} | swat | 2,839 / 5,712 | 1x8 |" in markdown
    assert f"| {hopper_folder} | fast | 2 | " in markdown
    assert markdown in result.stdout
