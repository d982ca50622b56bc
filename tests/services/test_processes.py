"""Child processes of the stack: they die with their parent, and leftovers are named, not collided with."""

from __future__ import annotations

import json
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from cec.config import ConfigError
from services.processes import Child, ChildRecord, NotReadyError

REPO = Path(__file__).resolve().parents[2]


def _alive(pid: int) -> bool:
    try:
        stat = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return False
    return stat.rsplit(")", 1)[1].split()[0] != "Z"  # a zombie has exited


def _wait_gone(pid: int, timeout: float = 10.0) -> bool:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if not _alive(pid):
            return True
        time.sleep(0.05)
    return False


def _parent_with_child(tmp_path: Path, *, parent_death: bool) -> tuple[subprocess.Popen, int]:
    """A Python process that starts `sleep 600` (recorded in `tmp_path/children.json`) and waits."""
    script = (
        "import subprocess, sys, time\n"
        "from pathlib import Path\n"
        "from services.processes import ChildRecord, with_parent_death\n"
        f"argv = ['sleep', '600']\n"
        f"child = subprocess.Popen(with_parent_death(argv) if {parent_death} else argv)\n"
        "time.sleep(0.3)  # exec'd past setpriv: the recorded command line is sleep's\n"
        f"ChildRecord(Path({str(tmp_path / 'children.json')!r})).add('sleeper', child.pid)\n"
        "print(child.pid, flush=True)\n"
        "time.sleep(600)\n"
    )
    argv = [sys.executable, "-c", script, "up"]  # a stand-in for a `cec up`: the advice names only those
    parent = subprocess.Popen(argv, cwd=REPO, stdout=subprocess.PIPE, text=True)
    assert parent.stdout is not None
    return parent, int(parent.stdout.readline())


@pytest.mark.skipif(shutil.which("setpriv") is None, reason="util-linux setpriv is not installed")
def test_a_child_dies_with_its_sigkilled_parent(tmp_path: Path) -> None:
    parent, child = _parent_with_child(tmp_path, parent_death=True)
    assert _alive(child)
    parent.send_signal(signal.SIGKILL)
    parent.wait()
    assert _wait_gone(child), "the child outlived its SIGKILLed parent"
    ChildRecord(tmp_path / "children.json").check()  # nothing left to report


def test_leftovers_of_a_dead_owner_are_named_with_the_command_to_stop_them(tmp_path: Path) -> None:
    parent, child = _parent_with_child(tmp_path, parent_death=False)
    record = ChildRecord(tmp_path / "children.json")
    try:
        live_run = rf"another `cec up` \(pid {parent.pid}\) runs this run"
        with pytest.raises(ConfigError, match=live_run) as live:
            record.check()
        # a live run's children are never to be killed: the advice stops its owner gracefully
        assert f"kill -INT {parent.pid}" in str(live.value) and f"kill {child}" not in str(live.value)
        parent.send_signal(signal.SIGKILL)
        parent.wait()
        gone = rf"ended without stopping .*sleeper \(pid {child}\).*kill {child}"
        with pytest.raises(ConfigError, match=gone):
            record.check()
    finally:
        subprocess.run(["kill", str(child)], check=False)
    assert _wait_gone(child)
    record.check()  # stopped: nothing to report
    # a recycled pid running something else is not a leftover
    other = subprocess.Popen(["sleep", "5"])
    try:
        data = json.loads((tmp_path / "children.json").read_text())
        data["children"][0]["pid"] = other.pid
        (tmp_path / "children.json").write_text(json.dumps(data))
        record.check()
    finally:
        other.kill()
        other.wait()


def test_cec_up_refuses_to_start_beside_leftovers_before_starting_anything(tmp_path: Path) -> None:
    sleeper = subprocess.Popen(["sleep", "600"])
    try:
        time.sleep(0.2)
        run_dir = tmp_path / "up"
        record = ChildRecord(run_dir / "logs" / "children.json")
        record.add("level server", sleeper.pid)  # as if a killed `cec up` had left it
        proc = subprocess.run(
            [sys.executable, "-m", "apps.cli", "up", f"train.run_dir={tmp_path}", "train.name=up"],
            cwd=REPO,
            capture_output=True,
            text=True,
            timeout=120,
        )
    finally:
        sleeper.kill()
        sleeper.wait()
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"level server (pid {sleeper.pid}) still run" in proc.stderr
    assert not (run_dir / "redis").exists(), "nothing was started"


def _script(code: str) -> list[str]:
    return [sys.executable, "-u", "-c", code]


def test_a_child_is_ready_when_its_check_passes_and_stops_with_a_grace_period(tmp_path: Path) -> None:
    log = tmp_path / "logs" / "child.log"
    log.parent.mkdir()
    log.write_text("an earlier run\n")
    code = "import time\nprint('ready', flush=True)\ntime.sleep(600)\n"
    child = Child("sleeper", _script(code), log_path=log, grace_s=5.0).start()
    try:
        child.wait_ready(lambda: "ready" in child.output(), timeout_s=30, poll_s=0.02)
        assert child.running and child.pid == child.proc.pid
        assert child.output() == "ready\n", "only what this start wrote"
        assert log.read_text() == "an earlier run\nready\n", "appended to the log"
    finally:
        child.stop()
    assert not child.running and child.pid is None and child.proc.returncode == -signal.SIGTERM
    child.stop()  # idempotent


def test_a_child_that_ignores_sigterm_is_killed_after_the_grace_period(tmp_path: Path) -> None:
    code = (
        "import signal, time\nsignal.signal(signal.SIGTERM, signal.SIG_IGN)\n"
        "print('up', flush=True)\ntime.sleep(600)\n"
    )
    child = Child("stubborn", _script(code), log_path=tmp_path / "c.log", grace_s=0.3).start()
    child.wait_ready(lambda: "up" in child.output(), timeout_s=30, poll_s=0.02)
    started = time.monotonic()
    child.stop()
    assert child.proc.returncode == -signal.SIGKILL and time.monotonic() - started < 10
    again = child.start()  # a new process, same command
    assert again is child and child.running
    child.stop(kill=True)
    assert child.proc.returncode == -signal.SIGKILL


def test_a_child_that_exits_or_is_too_slow_is_not_ready_with_its_output(tmp_path: Path) -> None:
    log = tmp_path / "c.log"
    dead = Child(
        "failing", _script("import sys\nprint('bad config', file=sys.stderr)\nsys.exit(3)"), log_path=log
    )
    with pytest.raises(NotReadyError, match="failing exited with status 3") as err:
        dead.start().wait_ready(lambda: False, timeout_s=30)
    assert err.value.exited and err.value.returncode == 3 and err.value.output == "bad config\n"
    slow = Child("slow", ["sleep", "600"]).start()
    try:
        with pytest.raises(NotReadyError, match="slow not ready in 0.2 s") as err:
            slow.wait_ready(lambda: False, timeout_s=0.2)
        assert not err.value.exited and slow.running, "left running: the caller stops it"
    finally:
        slow.stop()
    assert not slow.running


def test_cec_up_resume_refuses_a_live_run_naming_its_owner_and_the_graceful_stop(tmp_path: Path) -> None:
    """`cec up --resume` on a run another `cec up` still runs: exit 2 before starting anything (no second
    redis-server on the live run's data), and the advice stops the owner gracefully, never kills its
    children."""
    run_dir = tmp_path / "up"
    parent, child = _parent_with_child(run_dir / "logs", parent_death=False)
    try:
        cmd = [sys.executable, "-m", "apps.cli", "up", "--resume", f"train.run_dir={tmp_path}"]
        cmd.append("train.name=up")
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
    finally:
        parent.kill()
        parent.wait()
        subprocess.run(["kill", str(child)], check=False)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"another `cec up` (pid {parent.pid}) runs this run" in proc.stderr
    assert f"kill -INT {parent.pid}" in proc.stderr and f"kill {child}" not in proc.stderr
    assert not (run_dir / "redis").exists(), "nothing was started"


def test_a_busy_port_is_named_with_its_service_and_key_before_anything_starts(tmp_path: Path) -> None:
    """A port another process holds: `cec up` says which port, which service wanted it and the key that
    moves it, before starting any service (no run folder left behind for `cec status` to mistake)."""
    import socket

    from services.metrics import MetricsEndpoint

    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        cmd = [sys.executable, "-m", "apps.cli", "up", f"level_server_metrics_port={port}"]
        cmd += [f"train.run_dir={tmp_path}", "train.name=up"]
        proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=120)
        with pytest.raises(ConfigError, match=rf"on 127.0.0.1:{port} .*distributed.metrics_port=PORT"):
            MetricsEndpoint(port, component="learner", key="distributed.metrics_port")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"port {port} (the level server's metrics) is in use" in proc.stderr
    assert "level_server_metrics_port=PORT" in proc.stderr and "Traceback" not in proc.stderr
    assert not (tmp_path / "up").exists()
