"""The Python blocks of docs/python.md run as written (the training block at a tiny size), and the README
keeps to its length."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
PAGE = ROOT / "docs" / "python.md"
SNIPPET = re.compile(r"<!-- snippet: (\w+) -->\n```python\n(.*?)```", re.DOTALL)

TINY_TRAINING = {
    'PRESETS["fast"]': (
        'dataclasses.replace(PRESETS["fast"], envs=dataclasses.replace(PRESETS["fast"].envs, copies=1), '
        'td3=TD3Config(batch_size=8), iteration=IterationConfig(chunk=16, updates=2, loop="all_tasks", '
        "random_steps=16, capacity=256))"
    ),
    "steps=20_000": (
        "steps=1008, network=NetworkSizes(width=16, layers=1, feedforward=32, max_traversal_positions=3)"
    ),
}
"""What the test changes in the training block so that it runs in seconds: a smaller network and one copy
of hopper_3 (a folder that holds it alone; the ``env=`` replacement is added with the folder) for 63
iterations, so that its first episode reaches the 1000-step time limit and the curve has a point."""


def snippets() -> dict[str, str]:
    """The page's marked Python blocks by name."""
    return dict(SNIPPET.findall(PAGE.read_text()))


def shrunk(code: str, replacements: dict[str, str]) -> str:
    """``code`` with each replacement made; fails if the page no longer holds a replaced text."""
    for old, new in replacements.items():
        assert old in code, f"docs/python.md's block no longer contains {old!r}; update tests/test_docs.py"
        code = code.replace(old, new)
    return code


def test_the_page_marks_a_block_per_command():
    assert list(snippets()) == ["train", "eval", "export", "plot", "bodies"]


@pytest.mark.slow
def test_every_block_runs_in_order(tmp_path, monkeypatch, hopper_folder, capsys):
    monkeypatch.chdir(tmp_path)
    blocks = snippets()
    training = shrunk(blocks["train"], {**TINY_TRAINING, 'env="hopper"': f'env="{hopper_folder}"'})
    namespace: dict = {}
    exec(
        "from swat_jax.runs import NetworkSizes\nfrom swat_jax.td3 import TD3Config\n"
        "from swat_jax.td3.iteration import IterationConfig\n" + training,
        namespace,
    )
    assert namespace["result"].env_steps == 1008 and not namespace["result"].interrupted
    for name in ("eval", "export", "plot", "bodies"):
        namespace = {}
        exec(blocks[name], namespace)
        if name == "eval":
            [body] = namespace["run"].results
            assert body.body == "hopper_3" and body.returns.shape == (1, 4)
        if name == "export":
            actions = np.asarray(namespace["actions"])
            assert actions.shape == (8, 3) and np.all(np.abs(actions) <= 1)
    for written in (
        "curves.png",
        "curves.csv",
        "embeddings.png",
        "relations.png",
        "hopper.mp4",
        "policy.npz",
    ):
        assert (tmp_path / written).stat().st_size > 0, written
    assert "('torso', 'thigh', 'foot') (-1, 0, 1)" in capsys.readouterr().out


def test_the_readme_is_at_most_100_lines():
    """The README keeps to one job (what swat_jax is, install, a first run, where to read more); the rest
    lives in docs/."""
    lines = (ROOT / "README.md").read_text().splitlines()
    assert len(lines) <= 100, f"README.md has {len(lines)} lines; move the longest section into docs/"
