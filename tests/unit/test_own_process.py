"""The `own_process` marker (tests/own_process.py): a test that crashes its process fails alone, with the
signal named, and what it started is killed; the run that holds it goes on to the next test."""

from __future__ import annotations

import os
import subprocess
import sys
import textwrap
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    with open(f"/proc/{pid}/stat") as stat:  # a zombie is gone for our purpose
        return stat.read().split(")")[-1].split()[0] != "Z"


def test_a_crash_in_its_own_process_fails_that_test_and_kills_what_it_started(tmp_path: Path) -> None:
    pid_file = tmp_path / "grandchild.pid"
    (tmp_path / "test_crash.py").write_text(
        textwrap.dedent(f"""
        import os, signal, subprocess
        import pytest

        @pytest.mark.own_process
        def test_crashes():
            sleeper = subprocess.Popen(["sleep", "300"])  # as Ray's raylet: same process group
            open({str(pid_file)!r}, "w").write(str(sleeper.pid))
            os.kill(os.getpid(), signal.SIGKILL)  # as Ray's core ending its driver

        @pytest.mark.own_process
        def test_passes():
            assert os.environ["CEC_TEST_OWN_PROCESS"] == "1"
        """)
    )
    env = {**os.environ, "PYTHONPATH": str(REPO)}
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider", "-p", "tests.own_process"]
    proc = subprocess.run(
        [*cmd, "test_crash.py"], cwd=tmp_path, env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 1, proc.stdout + proc.stderr
    assert "1 failed, 1 passed" in proc.stdout, proc.stdout
    assert "the test in its own process: ended by signal 9" in proc.stdout
    grandchild = int(pid_file.read_text())
    deadline = time.monotonic() + 10
    while _alive(grandchild) and time.monotonic() < deadline:
        time.sleep(0.1)
    assert not _alive(grandchild), "what the crashed test started was left running"
