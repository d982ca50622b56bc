"""Child processes of the services: started so that they die with their parent, stopped in order, and
recorded so that a later start can name any that outlived it.

- `with_parent_death(argv)`: the command, run through util-linux's `setpriv --pdeathsig` where it exists,
  so the kernel signals the child when the process that started it dies, however it dies (a SIGKILLed
  `cec up` used to leave Redis, the level server, the evaluator and Ray's agents running). No Python
  runs between fork and exec (no `preexec_fn`), so starting a child from a process where JAX's threads
  already run is safe.
- `terminate(proc)`: SIGTERM, a grace period, then SIGKILL.
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
from pathlib import Path

from cec.config import ConfigError


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


def _cmdline(pid: int) -> str | None:
    """The command line of a running process (NUL-separated, as /proc has it), or None if none runs."""
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes().decode(errors="replace")
    except OSError:
        return None


class ChildRecord:
    """The children one process started, in `path` (JSON: the owner's pid, each child's name, pid and
    command line); `check()` before starting any refuses while a recorded one still runs."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.children: list[dict] = []

    def recorded(self) -> tuple[int, list[dict]] | None:
        """(owner pid, the recorded children with `alive`: still the same pid and command line), or None
        when there is no readable record."""
        try:
            old = json.loads(self.path.read_text())
            owner = int(old["owner"])
            children = [
                {**c, "alive": bool(c.get("cmd")) and _cmdline(int(c["pid"])) == c["cmd"]}
                for c in old["children"]
            ]
        except (OSError, ValueError, KeyError, TypeError, AttributeError):
            return None
        return owner, children

    @staticmethod
    def running(pid: int) -> bool:
        """Whether a process with this pid runs."""
        return _cmdline(pid) is not None

    def check(self) -> None:
        """`ConfigError` naming the recorded processes that still run (same pid and command line)."""
        record = self.recorded()
        if record is None:
            return  # missing or unreadable: nothing to go by (`add` writes a new one)
        owner, children = record
        alive = [c for c in children if c["alive"]]
        if not alive:
            return
        names = ", ".join(f"{c.get('name')} (pid {c['pid']})" for c in alive)
        pids = " ".join(str(c["pid"]) for c in alive)
        who = (
            f"another `cec up` (pid {owner}) runs this run"
            if _cmdline(owner) is not None
            else f"an earlier `cec up` (pid {owner}) of this run ended without stopping its services"
        )
        raise ConfigError(f"{who}: {names} still run. Stop them (`kill {pids}`) and start again")

    def add(self, name: str, pid: int) -> None:
        """Records a started child (rewriting the file atomically)."""
        self.children.append({"name": name, "pid": pid, "cmd": _cmdline(pid)})
        self.path.parent.mkdir(parents=True, exist_ok=True)
        tmp = self.path.with_name(self.path.name + ".tmp")
        tmp.write_text(json.dumps({"owner": os.getpid(), "children": self.children}, indent=1))
        tmp.replace(self.path)

    def clear(self) -> None:
        """Forgets the children (all stopped)."""
        self.children = []
        with contextlib.suppress(FileNotFoundError):
            self.path.unlink()
