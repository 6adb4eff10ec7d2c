"""The Makefile's training targets: the CPU's cores as JAX devices, the user's XLA flags kept."""

import subprocess
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def dry_run(*arguments: str) -> str:
    return subprocess.run(
        ["make", "--no-print-directory", "-n", *arguments],
        cwd=REPO,
        capture_output=True,
        text=True,
        check=True,
    ).stdout


def test_train_and_resume_run_with_the_cores_as_devices_and_keep_the_users_xla_flags():
    train = dry_run("train", "ENV=hopper", "CPU_DEVICES=3", "XLA_FLAGS=--xla_cpu_enable_fast_math=false")
    assert 'XLA_FLAGS="--xla_cpu_enable_fast_math=false --xla_force_host_platform_device_count=3"' in train
    assert "-m swat_jax.train --preset paper --env hopper" in train
    resume = dry_run("resume", "RUN=runs/x", "CPU_DEVICES=3")
    assert resume.rstrip().endswith("-m swat_jax.train --resume runs/x")
    assert "--xla_force_host_platform_device_count=3" in resume
    assert dry_run("resume", "RUN=runs/x", "STEPS=500").rstrip().endswith("--resume runs/x --steps 500")
