"""A worker that dies ends the run red, with its summary: it never hangs it
(``tests/xdist_scheduling.py``)."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parent.parent
HANG_S = 120  # bounds a hang only: the run below takes a few seconds

DIES = """
import os, signal

def test_dies():
    os.kill(os.getpid(), signal.SIGSEGV)

def test_after_the_death():
    pass
"""
PASSES = """
def test_one():
    pass
"""


def test_a_worker_killed_mid_file_fails_its_test_and_the_run_goes_on(tmp_path: Path) -> None:
    (tmp_path / "pytest.ini").write_text("[pytest]\n")
    (tmp_path / "test_a_dies.py").write_text(DIES)
    (tmp_path / "test_b_passes.py").write_text(PASSES)
    (tmp_path / "test_c_passes.py").write_text(PASSES)
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    env.pop("PYTEST_XDIST_WORKER", None)
    env.pop("PYTEST_ADDOPTS", None)
    # Without the plugin this run hangs (pytest-xdist 3.8: one worker, a file given out
    # again after it was finished): the timeout below then fails the test.
    result = subprocess.run(
        [
            sys.executable,
            "-m",
            "pytest",
            "-p",
            "no:django",
            "-p",
            "no:cacheprovider",
            "-p",
            "tests.xdist_scheduling",
            "-n",
            "1",
            "--dist",
            "loadfile",
            "--no-loadscope-reorder",
            "test_a_dies.py",
            "test_b_passes.py",
            "test_c_passes.py",
        ],
        cwd=tmp_path,
        env=env,
        capture_output=True,
        text=True,
        timeout=HANG_S,
        check=False,
    )
    summary = result.stdout.strip().splitlines()[-1]
    assert result.returncode == 1, result.stdout + result.stderr
    # The test the worker died on is reported once, and not run again; the rest all run.
    assert "1 failed, 3 passed" in summary, result.stdout
    assert "test_a_dies.py::test_dies" in result.stdout
