"""The tests' subprocess environment keeps what PYTHONPATH held (a ``pip install --target`` folder)."""

import os
import subprocess
import sys

from subprocesses import python_path_environment


def test_folders_go_in_front_of_the_existing_python_path(tmp_path, monkeypatch):
    installed, checkout = tmp_path / "site", tmp_path / "checkout"
    for folder, module in ((installed, "only_installed"), (checkout, "only_in_checkout")):
        folder.mkdir()
        (folder / f"{module}.py").write_text(f"WHERE = {folder.name!r}\n")
    monkeypatch.setenv("PYTHONPATH", str(installed))
    environment = python_path_environment(checkout, EXTRA="1")
    script = "import os, only_installed, only_in_checkout; print(only_installed.WHERE, only_in_checkout.WHERE, os.environ['EXTRA'])"
    result = subprocess.run(
        [sys.executable, "-c", script],
        capture_output=True,
        text=True,
        env=environment,
        check=False,
        timeout=60,
    )
    assert result.returncode == 0, result.stderr
    assert result.stdout.split() == ["site", "checkout", "1"]
    assert environment["PYTHONPATH"].split(os.pathsep) == [str(checkout), str(installed)]


def test_without_a_python_path_only_the_folders(tmp_path, monkeypatch):
    monkeypatch.delenv("PYTHONPATH", raising=False)
    assert python_path_environment(tmp_path)["PYTHONPATH"] == str(tmp_path)
