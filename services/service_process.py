"""Services of `cec up` as child processes: `ServiceProcess` (a `python -m <module>` child whose output
goes to a log file, ready once it prints a marker line) and Ray's local head started, stopped and
forgotten.

Split from `services.stack`, which orders the services; this module starts one.
"""

from __future__ import annotations

import contextlib
import os
import re
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

from cec.config import ConfigError
from services.processes import Child, NotReadyError


def ensure_ray_token() -> None:
    """With Ray's token authentication, `ray start --head` needs a token and never makes one (`ray.init`
    does): on a machine where Ray never ran, `cec up` failed with Ray's AuthenticationError. Ray's own CLI
    creates it (~/.ray/auth_token, kept if present); the token it prints is discarded, never logged."""
    if os.environ.get("RAY_AUTH_MODE") != "token":
        return
    cmd = [sys.executable, "-m", "ray.scripts.scripts", "get-auth-token", "--generate"]
    done = subprocess.run(cmd, capture_output=True, text=True, check=False, timeout=60)
    if done.returncode != 0:
        raise ConfigError(f"Ray's authentication token could not be created: {done.stderr.strip()[-500:]}")


def start_ray_head(args: list[str], log_path: Path, timeout: float) -> ServiceProcess:
    """Ray's head as a service (`args`: after `python -u`, e.g. `-m ray.scripts.scripts start --head ...`),
    ready once it prints "Ray runtime started". `RayStartError` in this project's words, naming
    `start_timeout_s` (`timeout`), when it exits or is not ready in time (a heavily loaded machine)."""
    from services.learner.driver import RayStartError, first_line

    try:
        # Ray lowers its workers' priority by 15 by default: the learner and the actors would then yield to
        # the evaluator, the level server and anything else on the machine (on a busy 2-core one, training
        # crawled). They run at the stack's own priority instead.
        env = {"RAY_worker_niceness": "0"}
        return ServiceProcess("ray head", args, log_path, "Ray runtime started", timeout, env=env)
    except ServiceStartError as err:
        why = "it exited" if err.exited else f"it was not ready within start_timeout_s = {timeout:g} s"
        last = first_line("\n".join(reversed(err.tail)))
        raise RayStartError(
            f"Ray's head did not start: {why} (its last line: {last or 'none'}). On a heavily loaded machine "
            f"Ray starts slowly or times out in its own start-up: raise start_timeout_s (now {timeout:g} s; "
            "`cec up start_timeout_s=600 ...`) and try again when the load is lower, or start Ray yourself "
            f"(`ray start --head`) and give distributed.ray_address=HOST:PORT. Ray's output: {log_path}"
        ) from None


def forget_ray_address(port: int) -> None:
    """Remove the "last cluster" file (<Ray temp dir>/ray_current_cluster) if it names our stopped head, as
    `ray stop` does, so that no later `ray.init()` on this machine tries to join a cluster that is gone; a
    file naming another cluster is left alone."""
    from ray._common.utils import get_ray_address_file

    path = Path(get_ray_address_file(None))
    with contextlib.suppress(OSError):
        if path.read_text().strip().rpartition(":")[2] == str(port):
            path.unlink()


_LOG_PREFIX = re.compile(r"^\d{4}-\d\d-\d\d [\d:,.]+ [A-Z]+ [\w.]+: ")


class ServiceStartError(ConfigError):
    """A service did not become ready: it `exited` first, or the time ran out; `tail`: its last lines."""

    def __init__(self, message: str, exited: bool, tail: list[str]) -> None:
        super().__init__(message)
        self.exited = exited
        self.tail = tail


class ServiceProcess:
    """A service in a child process (`python -m <module> ...`, a `Child`), its output appended to a log
    file in the run directory: ready once it prints a line with `ready` (`ready_line`). With `progress`, a
    start that takes longer than `PROGRESS_S` seconds is reported that often, with the service's latest log
    line (a level server compiling its generator, an evaluator its agents)."""

    PROGRESS_S = 7.0

    def __init__(
        self,
        name: str,
        args: list[str],
        log_path: Path,
        ready: str,
        timeout: float,
        env: dict | None = None,
        progress: Callable[[str], None] | None = None,
    ) -> None:
        self.name = name
        self.progress = progress
        self.log_path = log_path
        self.child = Child(
            name,
            [sys.executable, "-u", *args],
            log_path=log_path,
            env={"JAX_PLATFORMS": "cpu", **os.environ, **(env or {})},
            grace_s=30.0,
            # A session of its own: a terminal's Ctrl-C (SIGINT to the foreground process group) reaches
            # only `cec up`, which stops the services in order, the learner's checkpoint first. Without
            # it Ray's head and the servers died at once under the learner.
            new_session=True,
        ).start()
        self.proc = self.child.proc
        self.ready_line = self._wait_for(ready, timeout)

    def _wait_for(self, marker: str, timeout: float) -> str:
        """The first whole line of the child's output holding `marker`; `ServiceStartError` (with the end of
        its output) if it exits or `timeout` runs out first."""
        found: list[str] = []
        start = last = time.monotonic()

        def printed() -> bool:
            nonlocal last
            lines = self.child.output().split("\n")[:-1]  # whole lines only: the last may be half written
            found.extend(line.rstrip() for line in lines if marker in line)
            now = time.monotonic()
            if not found and self.progress is not None and now - last >= self.PROGRESS_S:
                latest = next((line.strip() for line in reversed(lines) if line.strip()), "no output yet")
                latest = _LOG_PREFIX.sub("", latest)  # "2026-11-28 17:51:09,599 INFO cec.level_server: "
                self.progress(f"{self.name:<22} starting ({now - start:.0f} s): {latest[-120:]}")
                last = now
            return bool(found)

        try:
            self.child.wait_ready(printed, timeout, poll_s=0.05)
        except NotReadyError as err:
            self.stop()
            tail = [line.rstrip() for line in err.output.splitlines()[-15:]]
            raise ServiceStartError(
                f"the {self.name} did not start (no {marker!r} line within {timeout:g} s); its output:\n  "
                + "\n  ".join(tail),
                err.exited,
                tail,
            ) from None
        return found[0]

    def alive(self) -> bool:
        return self.child.running

    def stop(self, timeout: float = 30.0) -> None:
        self.child.stop(grace_s=timeout)
