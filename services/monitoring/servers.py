"""Prometheus and Grafana as local subprocesses bound to loopback (`Prometheus`, `Grafana`), and
`start_monitoring`, which starts both for a stack and returns their `Monitoring` handle."""

from __future__ import annotations

import json
import logging
import os
import shutil
import socket
import urllib.error
import urllib.parse
import urllib.request
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any

from services.monitoring.config import (
    DASHBOARDS_DIR,
    DEFAULT_TARGETS,
    ENV_DASHBOARDS,
    ENV_PROMETHEUS_URL,
    GRAFANA_INSTALL_HINT,
    GRAFANA_PORT,
    PROMETHEUS_INSTALL_HINT,
    PROMETHEUS_PORT,
    PROVISIONING_DIR,
    MonitoringConfig,
    MonitoringError,
    _is_loopback,
)
from services.monitoring.scrape import _check_targets, prometheus_config
from services.processes import Child, NotReadyError, free_port

log = logging.getLogger("services.monitoring")


# --- running the servers ------------------------------------------------------------------------------------
def find_binary(*names: str) -> str | None:
    """Full path of the first of `names` found (on PATH, or as a path); None if none is."""
    for name in names:
        if name and (found := shutil.which(name)):
            return found
    return None


def _port_taken(host: str, port: int) -> bool:
    with socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM) as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind((host, port))
        except OSError:
            return True
    return False


def _http_get(url: str, timeout_s: float = 2.0) -> tuple[int, bytes]:
    """(status, body) of a GET; status 0 when nothing answers."""
    try:
        with urllib.request.urlopen(url, timeout=timeout_s) as response:
            return int(response.status), response.read()
    except urllib.error.HTTPError as err:
        return int(err.code), err.read()
    except (urllib.error.URLError, OSError):
        return 0, b""


class _Server:
    """A loopback HTTP server run as a subprocess: start, wait until `ready_path` answers 200, stop."""

    name = ""
    ready_path = ""

    def __init__(self, run_dir: Path, host: str, port: int, start_timeout_s: float) -> None:
        self.run_dir = run_dir
        self.host = host
        self.requested_port = port
        self.port = port
        self.start_timeout_s = start_timeout_s
        self._child: Child | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    @property
    def running(self) -> bool:
        return self._child is not None and self._child.running

    @property
    def pid(self) -> int | None:
        """The server's process id while it runs."""
        return self._child.pid if self._child is not None else None

    @property
    def log_path(self) -> Path:
        return self.run_dir / f"{self.name}.log"

    def _command(self) -> tuple[list[str], dict[str, str]]:
        raise NotImplementedError

    def start(self) -> _Server:
        """Starts the server and waits until it is ready. MonitoringError if it cannot start."""
        if self.running:
            return self
        self.run_dir.mkdir(parents=True, exist_ok=True)
        attempts = 3 if self.requested_port == 0 else 1
        for attempt in range(attempts):
            if self.requested_port == 0:
                self.port = free_port(self.host)
            elif _port_taken(self.host, self.port):
                raise MonitoringError(
                    f"{self.name} cannot listen on {self.host}:{self.port}: the port is in use (another "
                    f"{self.name}, or a stack already running?). Stop that process or choose another port "
                    f"(0: a free one)"
                )
            error = self._start_once()
            if error is None:
                log.info("%s ready at %s (log: %s)", self.name, self.url, self.log_path)
                return self
            if "address already in use" not in error or attempt == attempts - 1:
                raise MonitoringError(f"{self.name} failed to start on {self.host}:{self.port}: {error}")
        raise AssertionError("unreachable")

    def _start_once(self) -> str | None:
        command, env = self._command()
        child = Child(
            self.name,
            command,
            log_path=self.log_path,
            env={**os.environ, **env},
            cwd=self.run_dir,
            new_session=True,  # a Ctrl-C in the terminal reaches us; we stop it in order
        )
        self._child = child.start()
        try:
            child.wait_ready(
                lambda: _http_get(self.url + self.ready_path, timeout_s=1.0)[0] == 200, self.start_timeout_s
            )
        except NotReadyError as err:
            self.stop()
            if err.exited:
                tail = err.output.strip()[-1500:]
                return f"exit status {err.returncode}: {tail or '(no output)'} (log: {self.log_path})"
            return f"not ready within {self.start_timeout_s} s (log: {self.log_path})"
        return None

    def stop(self) -> None:
        """Stops the server (SIGTERM, then SIGKILL after 10 s). Idempotent."""
        child, self._child = self._child, None
        if child is not None:
            child.stop()

    def __enter__(self) -> _Server:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.stop()


class Prometheus(_Server):
    """A `prometheus` subprocess storing its data in `run_dir`, scraping `targets` or using `config_file`.

    Args:
        run_dir: directory for the generated config, the TSDB (`data/`) and `prometheus.log`.
        targets: {job: ['host:port', ...]} to scrape (a config is written into run_dir); or
        config_file: an existing Prometheus config to use as it is (e.g. cluster/prometheus-ray.yml).
        port: web/API port on `host` (0: a free one).
        scrape_interval_s: scrape interval of the generated config.
        executable: the binary (name on PATH or path).
    """

    name = "prometheus"
    ready_path = "/-/ready"

    def __init__(
        self,
        run_dir: str | Path,
        *,
        targets: Mapping[str, Sequence[str]] | None = None,
        config_file: str | Path | None = None,
        host: str = "127.0.0.1",
        port: int = PROMETHEUS_PORT,
        scrape_interval_s: float = 5.0,
        executable: str = "prometheus",
        start_timeout_s: float = 60.0,
    ) -> None:
        super().__init__(Path(run_dir), host, port, start_timeout_s)
        if (targets is None) == (config_file is None):
            raise MonitoringError("give Prometheus either scrape targets or a config file, not both/neither")
        if targets is not None:
            _check_targets(targets)
        if config_file is not None and not Path(config_file).is_file():
            raise MonitoringError(f"Prometheus config file {str(config_file)!r} does not exist")
        self.targets = targets
        self.config_file = Path(config_file).resolve() if config_file is not None else None
        self.scrape_interval_s = scrape_interval_s
        self.executable = executable

    def start(self) -> Prometheus:
        super().start()
        return self

    def __enter__(self) -> Prometheus:
        return self.start()

    def _command(self) -> tuple[list[str], dict[str, str]]:
        binary = find_binary(self.executable)
        if binary is None:
            raise MonitoringError(f"`{self.executable}` was not found on PATH; {PROMETHEUS_INSTALL_HINT}")
        config = self.config_file
        if config is None:
            assert self.targets is not None
            config = (self.run_dir / "prometheus.yml").resolve()
            config.write_text(
                prometheus_config(
                    self.targets,
                    scrape_interval_s=self.scrape_interval_s,
                    self_address=f"{self.host}:{self.port}",
                )
            )
        command = [
            binary,
            f"--config.file={config}",
            f"--storage.tsdb.path={(self.run_dir / 'data').resolve()}",
            f"--web.listen-address={self.host}:{self.port}",
        ]
        return command, {}

    def query(self, expr: str, timeout_s: float = 5.0) -> list[dict[str, Any]]:
        """Evaluates a PromQL expression now: the API's `data.result`. MonitoringError on a bad query."""
        url = f"{self.url}/api/v1/query?{urllib.parse.urlencode({'query': expr})}"
        status, body = _http_get(url, timeout_s=timeout_s)
        try:
            reply = json.loads(body) if body else {}
        except json.JSONDecodeError:
            reply = {}
        if status != 200 or reply.get("status") != "success":
            reason = reply.get("error") or f"HTTP status {status or 'none (not running?)'}"
            raise MonitoringError(f"Prometheus query {expr!r} failed: {reason}")
        return list(reply["data"]["result"])


class Grafana(_Server):
    """A Grafana server with the provisioning of cluster/grafana (datasource + dashboards), data in run_dir.

    Args:
        run_dir: directory for Grafana's database, logs and plugins.
        prometheus_url: the Prometheus the provisioned datasource points at.
        port: web port on `host` (0: a free one).
        provisioning_dir: holds datasources/ and dashboards/ provisioning YAML.
        dashboards_dir: the dashboard JSON files the provisioning loads.
        executable: the binary ('' = `grafana`, then `grafana-server`, on PATH).
        home: Grafana's home directory (conf/defaults.ini, public/); '' = found from the binary.
    """

    name = "grafana"
    ready_path = "/api/health"

    def __init__(
        self,
        run_dir: str | Path,
        *,
        prometheus_url: str,
        host: str = "127.0.0.1",
        port: int = GRAFANA_PORT,
        provisioning_dir: str | Path = PROVISIONING_DIR,
        dashboards_dir: str | Path = DASHBOARDS_DIR,
        executable: str = "",
        home: str = "",
        start_timeout_s: float = 60.0,
    ) -> None:
        super().__init__(Path(run_dir), host, port, start_timeout_s)
        self.prometheus_url = prometheus_url
        self.provisioning_dir = Path(provisioning_dir).resolve()
        self.dashboards_dir = Path(dashboards_dir).resolve()
        self.executable = executable
        self.home = home
        for what, path in (("provisioning", self.provisioning_dir), ("dashboards", self.dashboards_dir)):
            if not path.is_dir():
                raise MonitoringError(f"Grafana {what} directory {str(path)!r} does not exist")

    def start(self) -> Grafana:
        super().start()
        return self

    def __enter__(self) -> Grafana:
        return self.start()

    @staticmethod
    def find(executable: str = "") -> str | None:
        """The Grafana binary: `executable`, else `grafana` (Grafana >= 10), else `grafana-server`."""
        return find_binary(executable) if executable else find_binary("grafana", "grafana-server")

    @staticmethod
    def find_home(binary: str, home: str = "") -> Path:
        """Grafana's home directory (the one holding conf/defaults.ini). MonitoringError if none is found."""
        candidates = [Path(home)] if home else []
        if not home:
            resolved = Path(binary).resolve()
            candidates += [resolved.parent.parent, resolved.parent]  # a tarball: <home>/bin/grafana
            candidates += [Path(p) for p in ("/usr/share/grafana", "/usr/local/share/grafana")]
            candidates += [Path(p) for p in ("/opt/homebrew/share/grafana", "/opt/grafana")]
        for candidate in candidates:
            if (candidate / "conf" / "defaults.ini").is_file():
                return candidate
        raise MonitoringError(
            f"Grafana's home directory (with conf/defaults.ini) was not found for {binary} (looked in "
            f"{', '.join(map(str, candidates))}); set grafana_home to it"
        )

    def environment(self) -> dict[str, str]:
        """The environment Grafana runs with: paths in run_dir, provisioning, port, no phoning home."""
        env = {
            "GF_PATHS_DATA": str((self.run_dir / "grafana" / "data").resolve()),
            "GF_PATHS_LOGS": str((self.run_dir / "grafana" / "logs").resolve()),
            "GF_PATHS_PLUGINS": str((self.run_dir / "grafana" / "plugins").resolve()),
            "GF_PATHS_PROVISIONING": str(self.provisioning_dir),
            "GF_SERVER_HTTP_ADDR": self.host,
            "GF_SERVER_HTTP_PORT": str(self.port),
            "GF_ANALYTICS_REPORTING_ENABLED": "false",
            "GF_ANALYTICS_CHECK_FOR_UPDATES": "false",
            "GF_ANALYTICS_CHECK_FOR_PLUGIN_UPDATES": "false",
            "GF_NEWS_NEWS_FEED_ENABLED": "false",
            "GF_DASHBOARDS_DEFAULT_HOME_DASHBOARD_PATH": str(self.dashboards_dir / "training.json"),
            ENV_PROMETHEUS_URL: self.prometheus_url,
            ENV_DASHBOARDS: str(self.dashboards_dir),
        }
        if _is_loopback(self.host):  # anonymous read-only access on this machine only
            env["GF_AUTH_ANONYMOUS_ENABLED"] = "true"
            env["GF_AUTH_ANONYMOUS_ORG_ROLE"] = "Viewer"
        return env

    def _command(self) -> tuple[list[str], dict[str, str]]:
        binary = self.find(self.executable)
        if binary is None:
            raise MonitoringError(f"Grafana was not found on PATH; {GRAFANA_INSTALL_HINT}")
        home = self.find_home(binary, self.home)
        server = [binary, "server"] if Path(binary).name == "grafana" else [binary]
        return [*server, f"--homepath={home}"], self.environment()


# --- the whole thing ----------------------------------------------------------------------------------------
@dataclass
class Monitoring:
    """Running Prometheus (and Grafana); `stop()` stops both. `notes`: what was not started, and why."""

    prometheus: Prometheus
    grafana: Grafana | None
    notes: tuple[str, ...] = ()

    @property
    def urls(self) -> dict[str, str]:
        urls = {"prometheus": self.prometheus.url}
        if self.grafana is not None:
            urls["grafana"] = self.grafana.url
            urls.update(
                {
                    f"dashboard {uid}": f"{self.grafana.url}/d/cec-{uid}"
                    for uid in ("training", "levels", "evaluation", "cluster")
                }
            )
        return urls

    def describe(self) -> str:
        """Lines to print at start-up: where each thing is, and what was left out."""
        lines = [f"{name:<22} {url}" for name, url in self.urls.items()]
        lines.append(f"{'prometheus targets':<22} {self.prometheus.url}/targets")
        return "\n".join(lines + [f"note: {note}" for note in self.notes])

    def stop(self) -> None:
        if self.grafana is not None:
            self.grafana.stop()
        self.prometheus.stop()

    def __enter__(self) -> Monitoring:
        return self

    def __exit__(
        self, kind: type[BaseException] | None, value: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.stop()


def start_monitoring(
    run_dir: str | Path,
    targets: Mapping[str, Sequence[str]] | None = None,
    config: MonitoringConfig = MonitoringConfig(),
    *,
    config_file: str | Path | None = None,
) -> Monitoring:
    """Starts Prometheus on `targets` ({job: ['host:port']}, default: the embedded stack's ports) or on
    `config_file`, then Grafana when installed and `config.grafana` is set.

    MonitoringError when Prometheus is missing or cannot start. A missing or failing Grafana does not
    stop Prometheus: `Monitoring.notes` says why it is not running.
    """
    run = Path(run_dir)
    if targets is not None and config_file is not None:
        raise MonitoringError("give start_monitoring scrape targets or a Prometheus config file, not both")
    if find_binary(config.prometheus_executable) is None:
        raise MonitoringError(
            f"`{config.prometheus_executable}` was not found on PATH, so monitoring cannot start; "
            f"{PROMETHEUS_INSTALL_HINT}"
        )
    if config_file is None and targets is None:
        targets = DEFAULT_TARGETS
    prometheus = Prometheus(
        run,
        targets=targets if config_file is None else None,
        config_file=config_file,
        host=config.host,
        port=config.prometheus_port,
        scrape_interval_s=config.scrape_interval_s,
        executable=config.prometheus_executable,
        start_timeout_s=config.start_timeout_s,
    ).start()
    notes: list[str] = []
    grafana: Grafana | None = None
    if not config.grafana:
        notes.append("Grafana not started (grafana=false)")
    elif Grafana.find(config.grafana_executable) is None:
        notes.append(f"Grafana is not installed, so only Prometheus runs; {GRAFANA_INSTALL_HINT}")
    else:
        try:
            grafana = Grafana(
                run,
                prometheus_url=prometheus.url,
                host=config.host,
                port=config.grafana_port,
                executable=config.grafana_executable,
                home=config.grafana_home,
                start_timeout_s=config.start_timeout_s,
            ).start()
        except MonitoringError as err:
            notes.append(f"Grafana did not start, Prometheus runs without it: {err}")
            grafana = None
    return Monitoring(prometheus, grafana, tuple(notes))
