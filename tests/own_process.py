"""The `own_process` marker: a test that runs in a child pytest of its own process group.

For tests that host Ray's driver: Ray's C++ core ends the process that hosts it when its cluster fails it,
and in an xdist worker that takes the worker down, which reschedules the worker's whole group (the
crashed test included) and leaves the crashed test's raylets and Ray workers running. In a child, a
crash fails that one test with the child's output, and whatever the child leaves in its process group
(raylets, Ray workers, Redis) is killed when it ends. Loaded by tests/conftest.py (`pytest_plugins`), or
`-p tests.own_process`.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import sys
import tempfile
from pathlib import Path

import pytest


def pytest_configure(config: pytest.Config) -> None:
    config.addinivalue_line(
        "markers", "own_process: runs in a child pytest of its own process group (tests/own_process.py)"
    )


_CHILD = "CEC_TEST_OWN_PROCESS"


@pytest.hookimpl(tryfirst=True)
def pytest_pyfunc_call(pyfuncitem: pytest.Function) -> bool | None:
    """In the parent (not the child, which `CEC_TEST_OWN_PROCESS` marks), a test marked `own_process` runs
    as `pytest NODEID` in a new session, waited for at most its timeout marker less 30 s (so that this
    failure, not pytest-timeout's, says what happened); then its process group is killed."""
    marker = pyfuncitem.get_closest_marker("own_process")
    if marker is None or os.environ.get(_CHILD):
        return None
    limit = pyfuncitem.get_closest_marker("timeout")
    wait = (float(limit.args[0]) if limit and limit.args else 600.0) - 30.0
    root = pyfuncitem.config.rootpath
    log_path = Path(tempfile.mkdtemp(prefix="cec-own-process-")) / "pytest.log"
    cmd = [sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
           "--basetemp", str(log_path.parent / "tmp"), pyfuncitem.nodeid]  # fmt: skip
    with open(log_path, "w") as log:
        child = subprocess.Popen(
            cmd, cwd=root, env={**os.environ, _CHILD: "1"}, stdout=log, stderr=subprocess.STDOUT,
            start_new_session=True,
        )  # fmt: skip
        try:
            code: int | str = child.wait(timeout=wait)
        except subprocess.TimeoutExpired:
            code = f"still running after {wait:.0f} s"
        finally:
            with contextlib.suppress(ProcessLookupError):  # the child, if still there, and all it started
                os.killpg(child.pid, signal.SIGKILL)
            child.wait()
    output = log_path.read_text(errors="replace")
    shutil.rmtree(log_path.parent, ignore_errors=True)
    if code != 0:
        if isinstance(code, int):
            code = f"ended by signal {-code}" if code < 0 else f"exit status {code}"
        pytest.fail(f"the test in its own process: {code}\n{output[-12000:]}", pytrace=False)
    summary = output.strip().splitlines()[-1] if output.strip() else ""
    if "skipped" in summary and "passed" not in summary:
        pytest.skip(f"in its own process: {summary}")
    return True
