"""Child processes of the services: started so that they die with their parent, stopped in order, and
recorded so that a later start can name any that outlived it.

- `with_parent_death(argv)`: the command, run through util-linux's `setpriv --pdeathsig` where it exists,
  so the kernel signals the child when the process that started it dies, however it dies (a SIGKILLed
  `cec up` used to leave Redis, the level server, the evaluator and Ray's agents running). No Python
  runs between fork and exec (no `preexec_fn`), so starting a child from a process where JAX's threads
  already run is safe.
- `terminate(proc)`: SIGTERM, a grace period, then SIGKILL.
- `Child`: the one supervisor of the services' children (Redis, Prometheus, Grafana, the services of
  `cec up`): started through `with_parent_death` with its output appended to a log file, ready when the
  caller's check passes (`NotReadyError`, with its output, when it exits or times out first), stopped with
  `terminate`.
- `ChildRecord`: a JSON file listing the children of one `cec up` (pid and command line), so that the
  next `cec up` of the same run finds and names leftovers instead of colliding with them.
- `free_port(host)`: a port that was free a moment ago.
"""

from __future__ import annotations

import contextlib
import json
import os
import shutil
import signal
import socket
import subprocess
import time
import weakref
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import NamedTuple

from cec.config import ConfigError, read_user_json

#: The most of a run's child record (`logs/children.json`) read; a larger one is no record of ours.
RECORD_MAX_BYTES = 1 << 20


def free_port(host: str = "127.0.0.1") -> int:
    """A TCP port on `host` that nothing listened on when asked (IPv6 when `host` has a colon)."""
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind((host, 0))
        return int(s.getsockname()[1])


def with_parent_death(argv: list[str], sig: signal.Signals = signal.SIGTERM) -> list[str]:
    """`argv` prefixed so that the child receives `sig` when its parent thread exits (Linux, `setpriv`
    on PATH); unchanged elsewhere, where `ChildRecord` still names what was left behind.

    The kernel sends the signal when the *thread* that forked the child exits: start children from a
    thread that lives as long as they should (the main thread, in the services here).
    """
    setpriv = shutil.which("setpriv")
    if setpriv is None:
        return list(argv)
    return [setpriv, f"--pdeathsig={sig.name.removeprefix('SIG')}", "--", *argv]


def terminate(proc: subprocess.Popen, grace_s: float = 10.0) -> None:
    """Stops `proc`: SIGTERM, up to `grace_s` seconds to exit, then SIGKILL."""
    if proc.poll() is None:
        proc.terminate()
        try:
            proc.wait(grace_s)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()


class NotReadyError(Exception):
    """A child did not become ready: it exited first (`returncode`), or `timeout_s` ran out (`returncode`
    None, the child still runs). `output`: what it wrote to its log since it started."""

    def __init__(self, name: str, returncode: int | None, output: str, timeout_s: float) -> None:
        self.name = name
        self.returncode = returncode
        self.output = output
        self.timeout_s = timeout_s
        what = f"exited with status {returncode}" if returncode is not None else f"not ready in {timeout_s} s"
        super().__init__(f"{name} {what}")

    @property
    def exited(self) -> bool:
        return self.returncode is not None


class Child:
    """One child process of a service: output appended to a log file, killed with its parent
    (`with_parent_death`), ready when a check passes, stopped with a grace period (`terminate`).

        child = Child("prometheus", argv, log_path=run_dir / "prometheus.log").start()
        try:
            child.wait_ready(lambda: http_ok(ready_url), timeout_s=60)
        except NotReadyError as err:  # exited (err.returncode) or timed out; err.output: its log since start
            child.stop()
            ...

    A child still running when its `Child` is garbage-collected, or at interpreter exit, is stopped too.
    `start()` again after it stopped (or died) starts a new process with the same command.

    Args:
        name: what it is, for messages.
        argv: the command.
        log_path: file its stdout and stderr are appended to (its parent directory is created); None: both
            are discarded.
        env: its whole environment (None: this process's).
        cwd: its working directory (None: this process's).
        new_session: start it in a session of its own, so that a Ctrl-C in the terminal reaches only this
            process, which then stops it in order.
        grace_s: time `stop()` allows between SIGTERM and SIGKILL.
    """

    def __init__(
        self,
        name: str,
        argv: Sequence[str],
        *,
        log_path: Path | None = None,
        env: Mapping[str, str] | None = None,
        cwd: Path | None = None,
        new_session: bool = False,
        grace_s: float = 10.0,
    ) -> None:
        self.name = name
        self.argv = list(argv)
        self.log_path = log_path
        self.env = dict(env) if env is not None else None
        self.cwd = cwd
        self.new_session = new_session
        self.grace_s = grace_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._finalizer: weakref.finalize | None = None
        self._offset = 0  # size of the log when the process started

    @property
    def proc(self) -> subprocess.Popen[bytes]:
        """The process of the last `start()` (also after it ended)."""
        if self._proc is None:
            raise RuntimeError(f"{self.name} was never started")
        return self._proc

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        """The process id while it runs."""
        return self._proc.pid if self._proc is not None and self.running else None

    def start(self) -> Child:
        """Starts the process (nothing if it runs); returns at once: `wait_ready` waits for it."""
        if self.running:
            return self
        self.stop()  # an earlier process that ended: reaped, its finalizer dropped
        log_file = None
        if self.log_path is not None:
            self.log_path.parent.mkdir(parents=True, exist_ok=True)
            self._offset = self.log_path.stat().st_size if self.log_path.exists() else 0
            log_file = self.log_path.open("ab")
        try:
            self._proc = subprocess.Popen(
                with_parent_death(self.argv),
                stdin=subprocess.DEVNULL,
                stdout=log_file if log_file is not None else subprocess.DEVNULL,
                stderr=subprocess.STDOUT,
                env=self.env,
                cwd=self.cwd,
                start_new_session=self.new_session,
            )
        finally:
            if log_file is not None:
                log_file.close()  # the child holds its own descriptor
        # never leave a stray process behind
        self._finalizer = weakref.finalize(self, terminate, self._proc, self.grace_s)
        return self

    def output(self) -> str:
        """What the process wrote to its log since it started ('' without a log)."""
        if self.log_path is None or not self.log_path.exists():
            return ""
        with self.log_path.open("rb") as f:
            f.seek(self._offset)
            return f.read().decode(errors="replace")

    def wait_ready(self, ready: Callable[[], bool], timeout_s: float, poll_s: float = 0.1) -> None:
        """Returns once `ready()` is true while the process runs (checked every `poll_s`). NotReadyError if
        the process exits first or `timeout_s` runs out; the process is left as it is (`stop()` it)."""
        proc = self.proc
        deadline = time.monotonic() + timeout_s
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                raise NotReadyError(self.name, proc.returncode, self.output(), timeout_s)
            if ready():
                return
            time.sleep(poll_s)
        raise NotReadyError(self.name, None, self.output(), timeout_s)

    def stop(self, *, kill: bool = False, grace_s: float | None = None) -> None:
        """Stops the process: SIGTERM, up to `grace_s` (default: the child's) to exit, then SIGKILL; with
        `kill`, SIGKILL at once (a crash). Idempotent."""
        if self._proc is not None:
            if kill:
                if self._proc.poll() is None:
                    self._proc.kill()
                self._proc.wait()
            else:
                terminate(self._proc, self.grace_s if grace_s is None else grace_s)
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None


def _cmdline(pid: int) -> str | None:
    """The command line of a running process (NUL-separated, as /proc has it), or None if none runs."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return None


class Recorded(NamedTuple):
    """What a `ChildRecord` file says: its owner's pid, the children (each with `alive`), and whether the
    owner itself still runs (the same process, not a reused pid)."""

    owner: int
    children: list[dict]
    owner_alive: bool


class RecordError(ConfigError):
    """A child record that cannot be read or is not one `ChildRecord.add` writes."""


def _is_cec_up(cmdline: str) -> bool:
    """Whether a command line (NUL-separated, as /proc has it) is a `cec up` (`cec up ...`, `python -m
    apps.cli up ...`): the only kind of process the advice of `ChildRecord.check` may name."""
    return "up" in cmdline.split("\0")[1:]


def _pid(value: object) -> bool:
    return isinstance(value, int) and not isinstance(value, bool) and value > 0


class ChildRecord:
    """The children one process started, in `path` (JSON: the owner's pid and command line, each child's
    name, pid and command line); `check()` before starting any refuses while a recorded one still runs,
    and refuses too while the record cannot be read: a guard that cannot tell fails closed."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.children: list[dict] = []

    def read(self) -> Recorded | None:
        """The owner and the recorded children, each with whether it still runs (the same pid and command
        line), or None when there is no record. The owner counts as running only when its recorded command
        line is a `cec up` and the process with its pid still has it (a record without it names no one).
        `RecordError` naming the file and the cause when it is unreadable or malformed."""
        if not os.path.lexists(self.path):
            return None
        setting = f"{__name__}.RECORD_MAX_BYTES"
        old = read_user_json(self.path, "child record", RECORD_MAX_BYTES, setting, error=RecordError)
        problem = _record_problem(old)
        if problem is not None:
            raise RecordError(f"child record {str(self.path)!r} is malformed: {problem}")
        children = [
            {**c, "alive": bool(c.get("cmd")) and _cmdline(c["pid"]) == c["cmd"]} for c in old["children"]
        ]
        owner, owner_cmd = old["owner"], old.get("owner_cmd")
        owner_alive = (
            owner != os.getpid()
            and isinstance(owner_cmd, str)
            and _is_cec_up(owner_cmd)
            and _cmdline(owner) == owner_cmd
        )
        return Recorded(owner, children, owner_alive)

    def recorded(self) -> Recorded | None:
        """`read()`, or None when there is no readable record (for displays: `cec status`)."""
        try:
            return self.read()
        except RecordError:
            return None

    @staticmethod
    def running(pid: int) -> bool:
        """Whether a process with this pid runs."""
        return _cmdline(pid) is not None

    def check(self) -> None:
        """`ConfigError` naming the recorded processes that still run (same pid and command line), or the
        record itself when it cannot be read (the start is refused: it could be a live run's)."""
        try:
            record = self.read()
        except RecordError as err:
            raise ConfigError(
                f"{err}; it lists the processes of a `cec up` of this run, so nothing was started. If no "
                f"`cec up` of this run still runs (`cec status {self.path.parent.parent}`, or `ps -ef | grep "
                f"'cec up'`), delete {self.path} and start again"
            ) from None
        if record is None:
            return  # no record: no `cec up` of this run started children (`add` writes a new one)
        owner, children, owner_alive = record
        alive = [c for c in children if c["alive"]]
        names = ", ".join(f"{c.get('name')} (pid {c['pid']})" for c in alive)
        if owner_alive:  # a live run: never advise killing its children (its learner would lose its work)
            running = f" ({names} still run)" if alive else ""
            raise ConfigError(
                f"another `cec up` (pid {owner}) runs this run{running}. Stop it gracefully: Ctrl-C in its "
                f"terminal or `kill -INT {owner}` (its learner checkpoints, then it stops its services); "
                "then start again, with --resume to continue from that checkpoint"
            )
        if not alive:
            return
        pids = " ".join(str(c["pid"]) for c in alive)
        raise ConfigError(
            f"an earlier `cec up` (pid {owner}) of this run ended without stopping its services: {names} "
            f"still run. Stop them (`kill {pids}`) and start again"
        )

    def add(self, name: str, pid: int) -> None:
        """Records a started child (rewriting the file atomically)."""
        self.children.append({"name": name, "pid": pid, "cmd": _cmdline(pid)})
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        record = {"owner": os.getpid(), "owner_cmd": _cmdline(os.getpid()), "children": self.children}
        tmp.write_text(json.dumps(record, indent=1))
        tmp.replace(self.path)

    def clear(self) -> None:
        """Forgets the children (all stopped)."""
        self.children = []
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()


def _record_problem(record: object) -> str | None:
    """What makes `record` other than what `ChildRecord.add` writes, or None."""
    if not isinstance(record, dict):
        return f"it holds a JSON {type(record).__name__}, not an object"
    if not _pid(record.get("owner")):
        return f"owner must be a process id (an integer > 0), got {str(record.get('owner'))[:80]!r}"
    if not isinstance(record.get("owner_cmd"), str | None):
        return "owner_cmd must be a command line (a string)"
    children = record.get("children")
    if not isinstance(children, list):
        return f"children must be a list, got {type(children).__name__}"
    for i, child in enumerate(children):
        if not (isinstance(child, dict) and _pid(child.get("pid"))):
            return f"children[{i}] must be an object with a pid (an integer > 0), got {str(child)[:80]!r}"
        if not isinstance(child.get("cmd"), str | None) or not isinstance(child.get("name", ""), str):
            return f"children[{i}]'s name and cmd must be strings"
    return None
