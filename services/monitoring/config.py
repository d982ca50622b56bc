"""Where the monitoring files are, the default ports of the embedded stack, `MonitoringConfig` (local
Prometheus and Grafana) and `MonitoringError`."""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path

from cec.config import ConfigError
from services.ports import GRAFANA_PORT, LEVEL_SERVER_GRPC_PORT, METRICS_PORTS, PROMETHEUS_PORT  # noqa: F401 (re-exported)

# --- where things are ---------------------------------------------------------------------------------------
CLUSTER_DIR = Path(__file__).resolve().parent.parent.parent / "cluster"
DASHBOARDS_DIR = CLUSTER_DIR / "grafana" / "dashboards"
PROVISIONING_DIR = CLUSTER_DIR / "grafana" / "provisioning"

DEFAULT_TARGETS: Mapping[str, tuple[str, ...]] = {
    job: (f"127.0.0.1:{port}",) for job, port in METRICS_PORTS.items()
}

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
