"""Prometheus and Grafana for the stack: scrape configs, local servers, and what the dashboards query.

`cec up --monitoring` calls `start_monitoring`: it writes a Prometheus config for the stack's `/metrics`
endpoints into the run directory, starts `prometheus` on it, and starts Grafana (when installed) with the
provisioning files and dashboards of `cluster/grafana/`. Both are plain subprocesses bound to loopback,
stopped with the returned handle. `python -m services.monitoring` does the same against any config (e.g.
`cluster/prometheus-ray.yml` on a Ray head node); docs/monitoring.md has the whole picture.

    with start_monitoring("runs/x/monitoring", DEFAULT_TARGETS) as mon:
        print(mon.describe())  # URLs of Prometheus and Grafana

`dashboard_metric_names()` parses every PromQL expression of the shipped dashboards and returns the metric
names they read, so tests can check them against `services.metrics` and against a live stack's `/metrics`.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import logging
import os
import re
import shutil
import signal
import socket
import subprocess
import threading
import time
import urllib.error
import urllib.parse
import urllib.request
import weakref
from collections.abc import Iterator, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, NamedTuple

import yaml
from prometheus_client import REGISTRY, CollectorRegistry

from cec.config import ConfigError, load_config
from services.processes import free_port, terminate, with_parent_death

log = logging.getLogger("services.monitoring")

# --- where things are ---------------------------------------------------------------------------------------
CLUSTER_DIR = Path(__file__).resolve().parent.parent / "cluster"
DASHBOARDS_DIR = CLUSTER_DIR / "grafana" / "dashboards"
PROVISIONING_DIR = CLUSTER_DIR / "grafana" / "provisioning"

# Default ports of the embedded stack (`cec up`); cluster/prometheus.yml and docs/monitoring.md use the same.
LEVEL_SERVER_GRPC_PORT = 50051
METRICS_PORTS: Mapping[str, int] = {"level_server": 9401, "learner": 9402, "evaluator": 9403}
PROMETHEUS_PORT = 9090
GRAFANA_PORT = 3000
DEFAULT_TARGETS: Mapping[str, tuple[str, ...]] = {
    job: (f"127.0.0.1:{port}",) for job, port in METRICS_PORTS.items()
}

# Series that Prometheus makes itself for every target; no component exports them.
PROMETHEUS_SYNTHETIC = frozenset(
    {
        "up",
        "scrape_duration_seconds",
        "scrape_samples_scraped",
        "scrape_samples_post_metric_relabeling",
        "scrape_series_added",
    }
)

# Environment variables read by the provisioning files in cluster/grafana/provisioning.
ENV_PROMETHEUS_URL = "CEC_PROMETHEUS_URL"
ENV_DASHBOARDS = "CEC_GRAFANA_DASHBOARDS"

PROMETHEUS_INSTALL_HINT = (
    "install it with `sudo apt-get install prometheus` (Debian/Ubuntu; provides prometheus and promtool), "
    "`brew install prometheus` (macOS), or put the binary from https://prometheus.io/download/ on PATH"
)
GRAFANA_INSTALL_HINT = (
    "install Grafana (https://grafana.com/docs/grafana/latest/setup-grafana/installation/) so that "
    "`grafana` or `grafana-server` is on PATH, or import cluster/grafana/dashboards/*.json into a Grafana "
    "you already run"
)


class MonitoringError(RuntimeError):
    """Prometheus or Grafana could not be configured or started; the message names the cause and the fix."""


# --- configuration ------------------------------------------------------------------------------------------
@dataclass(frozen=True)
class MonitoringConfig:
    """Local Prometheus (and Grafana) for a stack (`cec up --monitoring`, `python -m services.monitoring`).

    Attributes:
        host: bind address of Prometheus and Grafana. Loopback by default: neither has authentication as
            configured here (Grafana lets anonymous viewers in only on a loopback address).
        prometheus_port: Prometheus web/API port (0: pick a free one).
        grafana_port: Grafana web port (0: pick a free one).
        grafana: also start Grafana when its binary is installed (missing: a note, not an error).
        scrape_interval_s: how often Prometheus scrapes each target, in seconds (for generated configs).
        prometheus_executable: the Prometheus binary (name on PATH or path).
        grafana_executable: the Grafana binary ('' = `grafana` then `grafana-server` on PATH).
        grafana_home: Grafana's home directory, holding conf/defaults.ini and public/ ('' = found next to
            the binary or in the usual install locations).
        start_timeout_s: time allowed for each server to report ready.
    """

    host: str = "127.0.0.1"
    prometheus_port: int = PROMETHEUS_PORT
    grafana_port: int = GRAFANA_PORT
    grafana: bool = True
    scrape_interval_s: float = 5.0
    prometheus_executable: str = "prometheus"
    grafana_executable: str = ""
    grafana_home: str = ""
    start_timeout_s: float = 60.0

    def __post_init__(self) -> None:
        for name in ("prometheus_port", "grafana_port"):
            value = getattr(self, name)
            if not 0 <= value <= 65535:
                raise ConfigError(f"{name} must be a TCP port in 0..65535 (0: a free one), got {value}")
        if not self.scrape_interval_s >= 0.001:
            raise ConfigError(f"scrape_interval_s must be at least 0.001 s, got {self.scrape_interval_s}")
        if not self.start_timeout_s > 0:
            raise ConfigError(f"start_timeout_s must be > 0, got {self.start_timeout_s}")
        if not self.host:
            raise ConfigError("host must be an address to bind, e.g. 127.0.0.1")

    @property
    def is_loopback(self) -> bool:
        return _is_loopback(self.host)


def _is_loopback(host: str) -> bool:
    return host in ("localhost", "::1") or host.startswith("127.")


# --- what the dashboards query ------------------------------------------------------------------------------
class DashboardQuery(NamedTuple):
    """One PromQL expression of a dashboard: a panel's target or a template variable's query."""

    dashboard: str  # file name, e.g. "training.json"
    kind: str  # "panel" (a panel's target: PromQL) or "variable" (a template variable's query)
    where: str  # the panel's title or the variable's name
    expr: str  # as written, Grafana variables included


_STRING = re.compile(r'"(?:[^"\\]|\\.)*"|\'(?:[^\'\\]|\\.)*\'|`[^`]*`')
_GRAFANA_VARIABLE = re.compile(r"\$(?:\{[^}]*\}|\w+)")
_MATCHERS = re.compile(r"\{[^{}]*\}")
_RANGE = re.compile(r"\[[^\[\]]*\]")
_LABEL_LIST = re.compile(r"\b(?:by|without|on|ignoring|group_left|group_right)\s*\([^()]*\)", re.IGNORECASE)
_OFFSET = re.compile(r"\boffset\s+-?\w+", re.IGNORECASE)
_AT = re.compile(r"@\s*(?:start\s*\(\s*\)|end\s*\(\s*\)|[0-9.eE+-]+)")
_TOKEN = re.compile(
    r"(?P<number>0[xX][0-9a-fA-F]+|(?:\d+\.?\d*|\.\d+)(?:[eE][+-]?\d+)?)"
    r"|(?P<name>[A-Za-z_:][A-Za-z0-9_:]*)(?P<call>\s*\()?"
)
_KEYWORDS = frozenset(
    {"and", "or", "unless", "bool", "by", "without", "on", "ignoring", "group_left", "group_right"}
    | {"offset", "inf", "nan", "atan2"}
)


def promql_metric_names(expr: str) -> set[str]:
    """The metric names a PromQL expression reads (Grafana variables such as `$__rate_interval` allowed).

    Strips strings, label matchers, ranges and subqueries, `by`/`without`/`on`/`ignoring`/`group_*` label
    lists, `offset` and `@` modifiers, numbers and keywords; every remaining identifier that is not called
    as a function is a metric name. `{__name__=...}` selectors are refused (ValueError): name the metric.
    """
    if "__name__" in expr:
        raise ValueError(f"selects metrics by __name__, which no check can follow; name them instead: {expr}")
    text = _STRING.sub('""', expr)
    text = _GRAFANA_VARIABLE.sub(" 0 ", text)
    text = _MATCHERS.sub(" ", text)
    while True:  # subqueries may nest ranges
        stripped = _RANGE.sub(" ", text)
        if stripped == text:
            break
        text = stripped
    text = _LABEL_LIST.sub(" ", text)
    text = _OFFSET.sub(" ", text)
    text = _AT.sub(" ", text)
    names: set[str] = set()
    for token in _TOKEN.finditer(text):
        name = token.group("name")
        if name is None or token.group("call") is not None or name.lower() in _KEYWORDS:
            continue
        names.add(name)
    return names


def query_metric_names(query: DashboardQuery) -> set[str]:
    """Metric names a dashboard query reads (PromQL, or a variable's `label_values(...)` and the like)."""
    return variable_metric_names(query.expr) if query.kind == "variable" else promql_metric_names(query.expr)


def variable_metric_names(query: str) -> set[str]:
    """Metric names read by a Grafana Prometheus template-variable query."""
    q = query.strip()
    call = re.fullmatch(r"(\w+)\s*\((.*)\)", q, flags=re.DOTALL)
    if call is None:
        return promql_metric_names(q)
    function, body = call.group(1), call.group(2)
    if function == "label_values":  # label_values(label) or label_values(series_selector, label)
        return promql_metric_names(body.rsplit(",", 1)[0]) if "," in body else set()
    if function == "query_result":
        return promql_metric_names(body)
    if function == "label_names" or function == "metrics":
        return set()
    return promql_metric_names(q)


def _panels(panels: Sequence[Mapping[str, Any]]) -> Iterator[Mapping[str, Any]]:
    for panel in panels:
        yield panel
        yield from _panels(panel.get("panels", []))  # rows hold their panels while collapsed


def dashboard_queries(directory: str | Path = DASHBOARDS_DIR) -> list[DashboardQuery]:
    """Every PromQL expression of the dashboards (`*.json`) in `directory`: panel targets and variables."""
    files = sorted(Path(directory).glob("*.json"))
    if not files:
        raise MonitoringError(f"no dashboards (*.json) in {directory}")
    out: list[DashboardQuery] = []
    for path in files:
        board = json.loads(path.read_text())
        for panel in _panels(board.get("panels", [])):
            for target in panel.get("targets", []):
                if target.get("expr"):
                    title = str(panel.get("title", ""))
                    out.append(DashboardQuery(path.name, "panel", title, target["expr"]))
        for variable in board.get("templating", {}).get("list", []):
            if variable.get("type") != "query":
                continue
            query = variable.get("query")
            text = query.get("query", "") if isinstance(query, Mapping) else str(query or "")
            if text:
                out.append(DashboardQuery(path.name, "variable", str(variable.get("name")), text))
    return out


def dashboard_metric_names(directory: str | Path = DASHBOARDS_DIR) -> set[str]:
    """Names of the series the dashboards read that some component must export on its `/metrics`.

    Exposition names as Prometheus stores them (`..._total`, `..._bucket`, `..._sum`, `..._count`);
    series Prometheus makes itself (`up`, `scrape_*`) are left out.
    """
    names: set[str] = set()
    for query in dashboard_queries(directory):
        names |= query_metric_names(query)
    return names - PROMETHEUS_SYNTHETIC


_SAMPLE_SUFFIXES: Mapping[str, tuple[str, ...]] = {
    "counter": ("_total", "_created"),
    "gauge": ("",),
    "histogram": ("_bucket", "_sum", "_count", "_created"),
    "summary": ("", "_sum", "_count", "_created"),
    "gaugehistogram": ("_bucket", "_gsum", "_gcount"),
    "info": ("_info",),
    "stateset": ("",),
    "unknown": ("",),
}


def exported_metric_names(registry: CollectorRegistry = REGISTRY) -> set[str]:
    """Every series name `registry` can expose, labelled metrics included before they have children.

    A counter family `x` exposes `x_total` (and `x_created`), a histogram `x_bucket`, `x_sum`, `x_count`.
    """
    names: set[str] = set()
    for family in registry.collect():
        names.update(family.name + suffix for suffix in _SAMPLE_SUFFIXES.get(family.type, ("",)))
    return names


# --- Prometheus configuration -------------------------------------------------------------------------------
_JOB = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def _check_targets(targets: Mapping[str, Sequence[str]]) -> None:
    if not targets:
        raise MonitoringError("no scrape targets given: pass {job: ['host:port', ...]}")
    for job, addresses in targets.items():
        if not _JOB.fullmatch(job):
            raise MonitoringError(f"job name {job!r} must be letters, digits and underscores")
        if isinstance(addresses, str) or not addresses:
            raise MonitoringError(f"job {job!r}: give a list of 'host:port' addresses, got {addresses!r}")
        for address in addresses:
            host, _, port = address.rpartition(":")
            if not host or not port.isdigit() or not 0 < int(port) <= 65535:
                raise MonitoringError(f"job {job!r}: target {address!r} is not 'host:port'")


def _duration(seconds: float) -> str:
    ms = round(seconds * 1000)
    return f"{ms // 1000}s" if ms % 1000 == 0 else f"{ms}ms"


def prometheus_config(
    targets: Mapping[str, Sequence[str]], *, scrape_interval_s: float = 5.0, self_address: str = ""
) -> str:
    """Prometheus YAML scraping `targets` ({job: ['host:port', ...]}), plus itself at `self_address`."""
    _check_targets(targets)
    interval = _duration(scrape_interval_s)
    timeout = _duration(max(0.001, scrape_interval_s * 0.8))
    jobs = [{"job_name": job, "static_configs": [{"targets": list(addr)}]} for job, addr in targets.items()]
    if self_address and "prometheus" not in targets:
        jobs.append({"job_name": "prometheus", "static_configs": [{"targets": [self_address]}]})
    config = {
        "global": {"scrape_interval": interval, "scrape_timeout": timeout, "evaluation_interval": interval},
        "scrape_configs": jobs,
    }
    header = "# Written by services.monitoring for this run; cluster/prometheus.yml is its hand-run twin.\n"
    return header + yaml.safe_dump(config, sort_keys=False)


def write_file_sd_targets(path: str | Path, targets: Mapping[str, Sequence[str]]) -> Path:
    """Writes a Prometheus file_sd JSON file: one target group per job, labelled `job`.

    For services off the head node of a Ray cluster (cluster/prometheus-ray.yml watches
    /tmp/ray/cec_prometheus_targets/*.json). Replaced atomically, as Prometheus re-reads it on change.
    """
    _check_targets(targets)
    groups = [{"targets": list(addresses), "labels": {"job": job}} for job, addresses in targets.items()]
    out = Path(path)
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_name(f".{out.name}.tmp")
    tmp.write_text(json.dumps(groups, indent=2) + "\n")
    os.replace(tmp, out)
    return out


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


def _log_tail(path: Path, offset: int, chars: int = 1500) -> str:
    if not path.exists():
        return ""
    with path.open("rb") as f:
        f.seek(offset)
        return f.read().decode(errors="replace").strip()[-chars:]


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
        self._proc: subprocess.Popen[bytes] | None = None
        self._finalizer: weakref.finalize | None = None

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"http://{host}:{self.port}"

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    @property
    def pid(self) -> int | None:
        """The server's process id while it runs."""
        return self._proc.pid if self._proc is not None and self.running else None

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
        offset = self.log_path.stat().st_size if self.log_path.exists() else 0
        with self.log_path.open("ab") as log_file:
            proc = subprocess.Popen(
                with_parent_death(command),
                stdin=subprocess.DEVNULL,
                stdout=log_file,
                stderr=subprocess.STDOUT,
                env={**os.environ, **env},
                cwd=self.run_dir,
                start_new_session=True,  # a Ctrl-C in the terminal reaches us; we stop it in order
            )
        self._proc = proc
        self._finalizer = weakref.finalize(self, terminate, proc)  # never leave a stray server behind
        deadline = time.monotonic() + self.start_timeout_s
        while time.monotonic() < deadline:
            if proc.poll() is not None:
                self._proc = None
                tail = _log_tail(self.log_path, offset)
                return f"exit status {proc.returncode}: {tail or '(no output)'} (log: {self.log_path})"
            status, _ = _http_get(self.url + self.ready_path, timeout_s=1.0)
            if status == 200:
                return None
            time.sleep(0.1)
        self.stop()
        return f"not ready within {self.start_timeout_s} s (log: {self.log_path})"

    def stop(self) -> None:
        """Stops the server (SIGTERM, then SIGKILL after 10 s). Idempotent."""
        if self._proc is not None:
            terminate(self._proc)
            self._proc = None
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None

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


# --- python -m services.monitoring --------------------------------------------------------------------------
def _parse_target(text: str) -> tuple[str, str]:
    job, sep, address = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected job=host:port, got {text!r}")
    return job, address


def main(argv: Sequence[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m services.monitoring",
        description="Start Prometheus (and Grafana, when installed) for a CEC stack; Ctrl-C stops them.",
    )
    parser.add_argument(
        "--target",
        action="append",
        type=_parse_target,
        default=[],
        metavar="JOB=HOST:PORT",
        help="a /metrics endpoint to scrape (repeatable); default: the embedded stack's ports "
        + ", ".join(f"{job}=127.0.0.1:{port}" for job, port in METRICS_PORTS.items()),
    )
    parser.add_argument(
        "--prometheus-config", help="use this Prometheus config instead (e.g. cluster/prometheus-ray.yml)"
    )
    parser.add_argument("--run-dir", default="runs/monitoring", help="where data and logs go")
    parser.add_argument(
        "set", nargs="*", metavar="key=value", help="MonitoringConfig overrides, e.g. grafana=false"
    )
    args = parser.parse_args(argv)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    if args.target and args.prometheus_config:
        print("error: give --target or --prometheus-config, not both", flush=True)
        return 2
    try:
        config = load_config(MonitoringConfig, None, args.set)
    except ConfigError as err:
        print(f"config error: {err}", flush=True)
        return 2
    targets: dict[str, list[str]] | None = None
    if args.target:
        targets = {}
        for job, address in args.target:
            targets.setdefault(job, []).append(address)
    try:
        monitoring = start_monitoring(args.run_dir, targets, config, config_file=args.prometheus_config)
    except MonitoringError as err:
        print(f"error: {err}", flush=True)
        return 1
    stop = threading.Event()
    for sig in (signal.SIGTERM, signal.SIGINT):
        signal.signal(sig, lambda *_: stop.set())
    with monitoring:
        print(monitoring.describe(), flush=True)
        print("monitoring ready; Ctrl-C stops it", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            stop.wait()
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
