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

Modules (the public names are re-exported here):

    config.py      paths, default ports, MonitoringConfig, MonitoringError
    dashboards.py  the dashboards' PromQL and the metric names it reads
    scrape.py      Prometheus scrape configs and file_sd target files
    servers.py     Prometheus, Grafana (local subprocesses), Monitoring, start_monitoring
    main.py        `python -m services.monitoring` (with __main__.py)
"""

from services.monitoring.config import (
    CLUSTER_DIR,
    DASHBOARDS_DIR,
    DEFAULT_TARGETS,
    ENV_DASHBOARDS,
    ENV_PROMETHEUS_URL,
    GRAFANA_INSTALL_HINT,
    GRAFANA_PORT,
    LEVEL_SERVER_GRPC_PORT,
    METRICS_PORTS,
    PROMETHEUS_INSTALL_HINT,
    PROMETHEUS_PORT,
    PROVISIONING_DIR,
    MonitoringConfig,
    MonitoringError,
)
from services.monitoring.dashboards import (
    PROMETHEUS_SYNTHETIC,
    DashboardQuery,
    dashboard_metric_names,
    dashboard_queries,
    exported_metric_names,
    promql_metric_names,
    query_metric_names,
    variable_metric_names,
)
from services.monitoring.scrape import (
    prometheus_config,
    write_file_sd_targets,
)
from services.monitoring.servers import (
    Grafana,
    Monitoring,
    Prometheus,
    find_binary,
    start_monitoring,
)

__all__ = [
    "CLUSTER_DIR",
    "DASHBOARDS_DIR",
    "DEFAULT_TARGETS",
    "DashboardQuery",
    "ENV_DASHBOARDS",
    "ENV_PROMETHEUS_URL",
    "GRAFANA_INSTALL_HINT",
    "GRAFANA_PORT",
    "Grafana",
    "LEVEL_SERVER_GRPC_PORT",
    "METRICS_PORTS",
    "Monitoring",
    "MonitoringConfig",
    "MonitoringError",
    "PROMETHEUS_INSTALL_HINT",
    "PROMETHEUS_PORT",
    "PROMETHEUS_SYNTHETIC",
    "PROVISIONING_DIR",
    "Prometheus",
    "dashboard_metric_names",
    "dashboard_queries",
    "exported_metric_names",
    "find_binary",
    "prometheus_config",
    "promql_metric_names",
    "query_metric_names",
    "start_monitoring",
    "variable_metric_names",
    "write_file_sd_targets",
]
