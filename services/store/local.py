"""`LocalRedis`: a real `redis-server` on loopback in a directory of its own (tests, and `cec up` when no
Redis URL is given)."""

from __future__ import annotations

import shutil
import signal
import subprocess
import tempfile
import time
import weakref
from pathlib import Path
from typing import Any

import redis

from services.processes import free_port, terminate, with_parent_death
from services.store.config import ENV_URL, INSTALL_HINT, StoreConfig, StoreError


class LocalRedis:
    """A real `redis-server` on loopback, in a directory of its own, with append-only persistence.

    Every write is fsynced to the append-only file, so `restart()` (even after `stop(kill=True)`) brings
    back all data, on the same port. Used by tests and by `cec up` when no Redis URL is given.

        with LocalRedis() as server:
            plane = ControlPlane.connect(server.config())

    Args:
        data_dir: where the server keeps its files (None: a temporary directory, removed on exit).
        port: TCP port (0: a free one, kept across restarts).
        password: `requirepass` ('' = none); written to a 0600 config file, not the command line.
        host: bind address.
        executable: the redis-server binary (name on PATH or path).
        start_timeout_s: time allowed for the server to answer PING.
    """

    def __init__(
        self,
        data_dir: str | Path | None = None,
        *,
        port: int = 0,
        password: str = "",
        host: str = "127.0.0.1",
        executable: str = "redis-server",
        start_timeout_s: float = 10.0,
    ) -> None:
        self._own_dir = data_dir is None
        self.data_dir = (
            Path(data_dir) if data_dir is not None else Path(tempfile.mkdtemp(prefix="cec-redis-"))
        )
        self.port = port
        self.password = password
        self.host = host
        self.executable = executable
        self.start_timeout_s = start_timeout_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._finalizer: weakref.finalize | None = None

    @property
    def url(self) -> str:
        return f"redis://{self.host}:{self.port}/0"

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def config(self, **overrides: Any) -> StoreConfig:
        """A StoreConfig pointing at this server (fields overridable)."""
        return StoreConfig(**{"url": self.url, "password": self.password, **overrides})

    def start(self) -> LocalRedis:
        """Starts the server and waits until it answers. StoreError if it cannot start."""
        if self.running:
            return self
        binary = shutil.which(self.executable)
        if binary is None:
            raise StoreError(
                f"`{self.executable}` was not found on PATH, so no local Redis can be started; "
                f"{INSTALL_HINT}. Or give the URL of a running Redis (store url or {ENV_URL})"
            )
        self.data_dir.mkdir(parents=True, exist_ok=True)
        attempts = 3 if self.port == 0 else 1
        for attempt in range(attempts):
            if self.port == 0 or attempt > 0:
                self.port = free_port(self.host)
            error = self._start_once(binary)
            if error is None:
                return self
            if "in use" not in error or attempt == attempts - 1:
                raise StoreError(f"redis-server failed to start on {self.host}:{self.port}: {error}")
        raise AssertionError("unreachable")

    def _start_once(self, binary: str) -> str | None:
        conf = self.data_dir / "redis.conf"
        lines = [
            f"bind {self.host}",
            f"port {self.port}",
            f"dir {self.data_dir.resolve()}",
            f"logfile {(self.data_dir / 'redis.log').resolve()}",
            "daemonize no",
            'save ""',
            "appendonly yes",
            "appendfsync always",
        ]
        if self.password:
            lines.append(f"requirepass {self.password}")
        conf.touch(mode=0o600)
        conf.write_text("\n".join(lines) + "\n")
        log = self.data_dir / "redis.log"
        offset = log.stat().st_size if log.exists() else 0
        proc = subprocess.Popen(
            with_parent_death([binary, str(conf)]),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        self._proc = proc
        self._finalizer = weakref.finalize(self, terminate, proc, 0.0)  # never leave a stray server behind
        client = redis.Redis(
            host=self.host, port=self.port, password=self.password or None, socket_connect_timeout=0.5
        )
        deadline = time.monotonic() + self.start_timeout_s
        try:
            while time.monotonic() < deadline:
                if proc.poll() is not None:
                    stderr = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                    tail = log.read_text(errors="replace")[offset:] if log.exists() else ""
                    self._proc = None
                    return (stderr + tail).strip()[-2000:] or f"exit status {proc.returncode}"
                try:
                    if client.ping():
                        return None
                except redis.BusyLoadingError:
                    pass  # replaying the append-only file
                except redis.ConnectionError:
                    pass
                time.sleep(0.02)
        finally:
            client.close()
        self.stop(kill=True)
        return f"it did not answer within {self.start_timeout_s} s (log: {log})"

    @property
    def pid(self) -> int:
        """The running server's process id."""
        if self._proc is None:
            raise StoreError("the local redis-server is not running")
        return self._proc.pid

    def stop(self, *, kill: bool = False) -> None:
        """Stops the server: SIGTERM (a clean shutdown) or, with `kill`, SIGKILL (a crash)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None

    def restart(self, *, kill: bool = False) -> None:
        """Stops and starts the server on the same port and directory (its data survives)."""
        self.stop(kill=kill)
        self.start()

    def close(self) -> None:
        """Stops the server and removes its temporary directory (a given `data_dir` is kept)."""
        self.stop()
        if self._own_dir:
            shutil.rmtree(self.data_dir, ignore_errors=True)

    def __enter__(self) -> LocalRedis:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
