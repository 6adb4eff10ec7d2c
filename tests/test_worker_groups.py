"""``make test``'s scheduling (conftest.WORKER_GROUPS): a group's tests share one xdist worker, so the
fixtures they share are built once, while the other tests spread over every worker."""

import os
import shutil
import subprocess
import sys
from pathlib import Path

TESTS = Path(__file__).resolve().parent

RECORDING_TESTS = """
import os
import pytest

@pytest.mark.parametrize("index", range({count}))
def test_records_its_worker(index):
    with open(os.path.join(os.environ["PIDS"], "{module}-{{}}".format(index)), "w") as pid:
        pid.write(str(os.getpid()))
"""


def test_a_groups_tests_run_on_one_worker_and_the_others_on_every_worker(tmp_path):
    shutil.copy(TESTS / "conftest.py", tmp_path)
    (tmp_path / "pids").mkdir()
    (tmp_path / "test_render.py").write_text(RECORDING_TESTS.format(count=4, module="grouped"))
    (tmp_path / "test_unlisted.py").write_text(RECORDING_TESTS.format(count=8, module="single"))
    completed = subprocess.run(
        [sys.executable, "-m", "pytest", "-q", "-n", "2", "--dist", "loadgroup", "-p", "no:cacheprovider"],
        cwd=tmp_path,
        capture_output=True,
        text=True,
        env={**os.environ, "PIDS": str(tmp_path / "pids")},
        check=False,
    )
    assert completed.returncode == 0, completed.stdout[-3000:]
    pids = {path.name: path.read_text() for path in (tmp_path / "pids").iterdir()}
    assert len(pids) == 12
    assert len({pid for name, pid in pids.items() if name.startswith("grouped")}) == 1
    assert len(set(pids.values())) == 2, "the ungrouped tests keep the other worker busy"
