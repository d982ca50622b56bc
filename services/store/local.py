"""`LocalRedis`: a real `redis-server` on loopback in a directory of its own (tests, and `cec up` when no
Redis URL is given)."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from typing import Any

import redis

from services.processes import Child, NotReadyError, free_port
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
        self._child: Child | None = None

    @property
    def url(self) -> str:
        return f"redis://{self.host}:{self.port}/0"

    @property
    def running(self) -> bool:
        return self._child is not None and self._child.running

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
        # its own log lines and anything it prints before opening that file (stderr) go to redis.log
        # its own session: a terminal's Ctrl-C reaches only our process, which stops Redis last, in order
        child = Child("redis-server", [binary, str(conf)], log_path=log, new_session=True)
        self._child = child.start()
        client = redis.Redis(
            host=self.host, port=self.port, password=self.password or None, socket_connect_timeout=0.5
        )

        def answers() -> bool:
            try:
                return bool(client.ping())
            except redis.BusyLoadingError:
                return False  # replaying the append-only file
            except redis.ConnectionError:
                return False

        try:
            child.wait_ready(answers, self.start_timeout_s, poll_s=0.02)
        except NotReadyError as err:
            self.stop(kill=True)
            if err.exited:
                return err.output.strip()[-2000:] or f"exit status {err.returncode}"
            return f"it did not answer within {self.start_timeout_s} s (log: {log})"
        finally:
            client.close()
        return None

    @property
    def pid(self) -> int:
        """The running server's process id."""
        pid = self._child.pid if self._child is not None else None
        if pid is None:
            raise StoreError("the local redis-server is not running")
        return pid

    def stop(self, *, kill: bool = False) -> None:
        """Stops the server: SIGTERM (a clean shutdown) or, with `kill`, SIGKILL (a crash)."""
        child, self._child = self._child, None
        if child is not None:
            child.stop(kill=kill)

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
