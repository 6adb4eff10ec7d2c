"""Training over several hosts, proven on one machine: two processes of ``python -m swat_jax.train`` joined
through ``jax.distributed`` (a localhost coordinator, JAX's CPU collectives, one CPU device each) train a
two-seed run, checkpoint, resume, and end with the state of the same run in one process on two devices.

Each process is one "host": its device is half of the 2-device mesh (seeds 2 x tasks 1), so each process
holds, steps (its own MuJoCo C calls) and updates one seed, process 0 writes
the metrics of both, and each writes its shards of every checkpoint into the shared run directory. The
one-process twin gets its 2 devices from XLA's fake host devices
(``--xla_force_host_platform_device_count=2``) and runs the same partitioned program. docs/gpus-and-hosts.md
("Several hosts") gives the same commands.
"""

from __future__ import annotations

import os
import re
import socket
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
from conftest import train_flags
from sharded_twins import config, final_state, largest_differences
from subprocesses import python_path_environment

from swat_jax.runs.checkpoint import flatten
from swat_jax.runs.config import ConfigError
from swat_jax.runs.metrics import read_metrics
from swat_jax.train import parse_command

REPO = Path(__file__).resolve().parents[1]
DOCS = REPO / "docs" / "gpus-and-hosts.md"
"""Its "Several hosts" section gives the commands this test runs."""
TIMEOUT = 240
"""Seconds the processes run together may take before they are killed and the test fails (15-35 s on 2
cores); twice that stays within pytest's 600 s."""
MESH = "mesh of 2 cpu devices: seeds 2 x tasks 1; 'seeds' splits the seed axis of the whole state (2 way)"


def free_port() -> int:
    """A TCP port of localhost that nothing listens on now (for the coordinator)."""
    with socket.socket() as probe:
        probe.bind(("localhost", 0))
        return probe.getsockname()[1]


def physics_calls(output: str) -> dict[int, int]:
    """{device id: MuJoCo C calls} of the "physics calls of process P in training" line of a run's output."""
    line = next(line for line in output.splitlines() if line.startswith("physics calls of process"))
    counts = line.split(": ", 1)[1].split(", ")
    return {int(device): int(count) for count, device in (item.split(" on device ") for item in counts)}


Command = tuple[list[str], Path, dict[str, str]]
"""``python -m swat_jax.train`` flags, the file its stdout and stderr go to, environment variables to set."""


def run_together(commands: list[Command]) -> list[str]:
    """Run the ``python -m swat_jax.train`` commands of this checkout at once; their logs once all succeeded.
    As soon as one fails, or TIMEOUT seconds have passed, the others are killed (a host whose partner is
    gone would wait in a collective) and the test fails with every log's end."""
    processes: list[subprocess.Popen] = []
    deadline = time.monotonic() + TIMEOUT
    try:
        for flags, log, variables in commands:
            with log.open("w") as output:
                processes.append(
                    subprocess.Popen(
                        [sys.executable, "-m", "swat_jax.train", *flags, "--no-progress"],
                        stdout=output,
                        stderr=subprocess.STDOUT,
                        cwd=REPO,
                        env=python_path_environment(REPO, PYTHONUNBUFFERED="1", **variables),
                    )
                )
        while any(process.poll() is None for process in processes) and time.monotonic() < deadline:
            if any(process.returncode not in (None, 0) for process in processes):
                break
            time.sleep(0.1)
    finally:
        for process in processes:
            if process.poll() is None:
                process.kill()
            process.wait()
    logs = [log.read_text() for _, log, _ in commands]
    statuses = [process.returncode for process in processes]
    late = f"killed after {TIMEOUT} s\n\n" if time.monotonic() >= deadline else ""
    assert statuses == [0] * len(commands), late + "\n\n".join(
        f"{log.name}: exit status {status}\n{text[-3000:]}"
        for (_, log, _), status, text in zip(commands, statuses, logs, strict=True)
    )
    return logs


def two_hosts(flags: list[str], name: str, folder: Path) -> list[Command]:
    """``python -m swat_jax.train FLAGS`` as processes 0 and 1 of a two-host run on this machine, logged to
    ``folder / NAME_process_0.log`` and ``..._1.log``."""
    joined = ["--coordinator-address", f"localhost:{free_port()}", "--num-processes", "2"]
    return [
        ([*flags, *joined, "--process-id", str(index)], folder / f"{name}_process_{index}.log", {})
        for index in range(2)
    ]


@pytest.mark.slow
def test_two_hosts_train_checkpoint_resume_and_end_as_one_process_on_two_devices(tmp_path, hopper_folder):
    """2 iterations and a checkpoint at 40 steps, then a resume to 80, over two hosts; the twin trains 80."""
    hosts, twin = config(tmp_path, hopper_folder, "hosts", 80), config(tmp_path, hopper_folder, "twin", 80)
    # The twin trains while the hosts train their first 40 steps: each run compiles on one core.
    first_hosts = two_hosts(train_flags(config(tmp_path, hopper_folder, "hosts", 40)), "first", tmp_path)
    twin_devices = f"{os.environ['XLA_FLAGS']} --xla_force_host_platform_device_count=2"
    *first, twin_output = run_together(
        [*first_hosts, (train_flags(twin), tmp_path / "twin.log", {"XLA_FLAGS": twin_devices})]
    )
    resumed = run_together(two_hosts(["--resume", hosts.run_dir, "--steps", "80"], "resumed", tmp_path))

    for output in (*first, *resumed, twin_output):
        assert MESH in output.splitlines(), output[-3000:]
    for output in resumed:
        assert f"resumed from {hosts.directory() / 'checkpoints' / '40'}" in output
    for outputs in (first, resumed):
        calls = [physics_calls(output) for output in outputs]
        assert [len(process_calls) for process_calls in calls] == [1, 1], f"one device each: {calls}"
        assert calls[0].keys() != calls[1].keys(), f"each host calls from its own device: {calls}"
        counts = [count for process_calls in calls for count in process_calls.values()]
        assert counts[0] == counts[1] > 0, f"both hosts step their seed's copies alike: {calls}"
    twin_calls = physics_calls(twin_output)
    per_host = sum(count for output in (first[0], resumed[0]) for count in physics_calls(output).values())
    assert list(twin_calls.values()) == [per_host, per_host], "the twin's devices split the same calls"
    for output in (*first, *resumed, twin_output):
        assert "[SPMD]" not in output, "no physics result is replicated and re-split"
    steps = sorted(
        int(path.name) for path in (hosts.directory() / "checkpoints").iterdir() if path.name.isdigit()
    )
    assert steps == [40, 80]
    assert sorted(path.name for path in (hosts.directory() / "tensorboard").iterdir()) == ["seed0", "seed1"]

    two_hosts_state, twin_state = final_state(hosts), final_state(twin)
    assert two_hosts_state.steps_per_task.item() == 80, "per body: 4 iterations of 2 copies x 10 steps"
    a, b = flatten(two_hosts_state), flatten(twin_state)
    assert a.keys() == b.keys()
    differing = [key for key in a if np.asarray(a[key]).tobytes() != np.asarray(b[key]).tobytes()]
    largest = largest_differences(two_hosts_state, twin_state)
    assert not differing, f"the two hosts' run differs from its twin in {differing[:5]}: {largest}"

    rows, twin_rows = read_metrics(hosts.directory()), read_metrics(twin.directory())
    assert [(row["env_steps"], row["seed"]) for row in rows] == [(40, 0), (40, 1), (80, 0), (80, 1)], (
        "process 0 alone writes the metrics, of both hosts' seeds, once"
    )
    for row, expected in zip(rows, twin_rows, strict=True):
        del row["steps_per_second"], expected["steps_per_second"]
        assert row == pytest.approx(expected, rel=0, abs=0, nan_ok=True)


@pytest.mark.parametrize(
    ("flags", "message"),
    [
        (["--num-processes", "2", "--process-id", "1"], "go with --coordinator-address HOST:PORT"),
        (
            ["--coordinator-address", "localhost:1234", "--num-processes", "2", "--process-id", "2"],
            "2 --process-id 2",
        ),
        (["--coordinator-address", "localhost:1234"], "got --num-processes 0 --process-id 0"),
    ],
)
def test_host_flags_that_make_no_run_over_hosts_are_refused_before_joining(flags, message):
    """Without --coordinator-address the process would train alone; the errors come before jax.distributed."""
    command, _ = parse_command(flags)
    with pytest.raises(ConfigError, match=message):
        command.start_distributed()


def test_the_docs_give_the_commands_of_the_two_hosts_test(tmp_path, hopper_folder):
    """docs/gpus-and-hosts.md's TINY flags train the run the test above trains (but --steps and --run-dir)."""
    documented = re.search(r'TINY="(.*?)"', DOCS.read_text(), re.DOTALL)
    assert documented, f"{DOCS} no longer sets TINY"
    *flags, progress = documented.group(1).split()
    tested = train_flags(config(tmp_path, hopper_folder, "hosts", 40))
    expected = dict(zip(tested[::2], tested[1::2], strict=True)) | {"--env": "/tmp/hopper_3"}
    for own in ("--preset", "--steps", "--run-dir"):
        del expected[own]
    assert dict(zip(flags[::2], flags[1::2], strict=True)) == expected and progress == "--no-progress"
