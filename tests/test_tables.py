"""experiments.tables: the result tables of README.md and BENCHMARKS.md agree with the committed results, a
table that does not is caught and named, and writing puts back what the results give. Reads files only."""

from __future__ import annotations

import shutil
from pathlib import Path

import pytest

from experiments import tables


def copy(name: str, folder: Path) -> tuple[Path, list[str]]:
    """The repository's ``name`` copied into ``folder``, with its lines."""
    path = folder / name
    shutil.copy(tables.ROOT / name, path)
    return path, path.read_text().splitlines()


def test_every_table_agrees_with_the_committed_results(capsys):
    assert tables.main(["--check"]) == 0, capsys.readouterr().err


@pytest.mark.parametrize("name", ["README.md", "BENCHMARKS.md"])
def test_an_altered_table_is_named_and_written_back(name, tmp_path, capsys):
    path, lines = copy(name, tmp_path)
    table, start, _ = tables.regions(lines, path)[0]
    row = start + 2  # the first row under the header and its delimiter
    altered = [*lines[:row], lines[row].replace(".", "1", 1), *lines[row + 1 :]]
    path.write_text("\n".join(altered) + "\n")

    assert tables.main(["--check", "--files", str(path)]) == 1
    error = capsys.readouterr().err
    assert f"{path}:{row + 1}: table {table!r} disagrees with the results" in error
    assert altered[row] in error and lines[row] in error

    assert tables.main(["--files", str(path)]) == 0
    assert path.read_text().splitlines() == lines


def test_a_table_without_its_end_or_a_missing_table_is_refused(tmp_path, capsys):
    path, lines = copy("README.md", tmp_path)
    path.write_text("\n".join(line for line in lines if line != tables.END) + "\n")
    assert tables.main(["--check", "--files", str(path)]) == 2
    assert "has no <!-- end table -->" in capsys.readouterr().err

    path.write_text("\n".join(line for line in lines if not line.startswith("<!-- ")) + "\n")
    assert tables.main(["--check", "--files", str(path)]) == 2
    assert "no generated table 'parity', 'time-to-return'" in capsys.readouterr().err
