"""The default ports of every service, in one table: the dataclass defaults, the presets under configs/,
`cluster/prometheus.yml` and docs/monitoring.md all use these (tests/services/test_ports.py checks them)."""

from __future__ import annotations

from collections.abc import Mapping

LEVEL_SERVER_GRPC_PORT = 50051
#: Each service's Prometheus `/metrics` port.
METRICS_PORTS: Mapping[str, int] = {"level_server": 9401, "learner": 9402, "evaluator": 9403}
PROMETHEUS_PORT = 9090
GRAFANA_PORT = 3000
#: The Redis of a cluster's head node (`cluster/config*.yaml`; a local `cec up` starts its own).
CLUSTER_REDIS_PORT = 6380
