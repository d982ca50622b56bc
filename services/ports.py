"""The default ports of every service, in one table: the dataclass defaults, the presets under configs/,
`cluster/prometheus.yml` and docs/monitoring.md all use these (tests/services/test_ports.py checks them);
and the checks of a port setting (`check_port`) and of a stack's ports together (`check_distinct`)."""

from __future__ import annotations

from collections.abc import Mapping, Sequence

from cec.config import ConfigError

LEVEL_SERVER_GRPC_PORT = 50051
#: Each service's Prometheus `/metrics` port.
METRICS_PORTS: Mapping[str, int] = {"level_server": 9401, "learner": 9402, "evaluator": 9403}
PROMETHEUS_PORT = 9090
GRAFANA_PORT = 3000
#: The Redis of a cluster's head node (`cluster/config*.yaml`; a local `cec up` starts its own).
CLUSTER_REDIS_PORT = 6380


def check_port(key: str, port: object, *, off: bool = False) -> None:
    """`ConfigError` naming `key` unless `port` is a TCP port (1..65535), 0 (a free one) or, with `off`,
    -1 (none): checked when the config is read, before a socket call meets it (70000 was an
    OverflowError traceback)."""
    low = -1 if off else 0
    if isinstance(port, bool) or not isinstance(port, int) or not low <= port <= 65535:
        extra = ", -1 (off)" if off else ""
        raise ConfigError(f"{key} must be a TCP port in 1..65535, 0 (a free one){extra}; got {port!r}")


def check_distinct(ports: Sequence[tuple[str, str, int]]) -> None:
    """`ConfigError` naming both services and their keys when two of `ports` ((key, service, port); 0 and -1
    left out) are the same port: found before anything starts, not when the second service fails to bind."""
    seen: dict[int, tuple[str, str]] = {}
    for key, service, port in ports:
        if port <= 0:
            continue
        if port in seen:
            other_key, other = seen[port]
            raise ConfigError(
                f"port {port} is given to both {other} ({other_key}) and {service} ({key}); give one of them "
                f"another port ({key}=0: a free one)"
            )
        seen[port] = (key, service)
