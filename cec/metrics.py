"""Every Prometheus metric of the stack, named once (`cec_<component>_<what>_<unit>`, counters `_total`).

Services import the metric objects from here and never define their own, so dashboards and scrape tests
have one list to check against. Labels stay low-cardinality (an RPC name, a status code; never a level,
a seed or a client address). Metrics live in the default registry of the process that serves them.
"""

from __future__ import annotations

from prometheus_client import REGISTRY, Counter, Gauge, Histogram, start_http_server

# --- level server ------------------------------------------------------------------------------------------
LEVELS_GENERATED = Counter(
    "cec_level_server_levels_generated_total", "Levels produced by the generator (fresh, not replayed)"
)
LEVELS_SENT = Counter("cec_level_server_levels_sent_total", "Levels sent to clients, by RPC", ["rpc"])
HELDOUT_REJECTIONS = Counter(
    "cec_level_server_heldout_rejections_total",
    "Generator draws rejected because they matched a held-out evaluation kitchen (then redrawn)",
)
LEVELS_REPLAYED = Counter(
    "cec_level_server_levels_replayed_total", "Levels sent from the prioritized-level-replay buffer"
)
CURRICULUM_BUFFER = Gauge("cec_level_server_curriculum_buffer_levels", "Levels in the replay buffer")
ACTIVE_STREAMS = Gauge("cec_level_server_active_streams", "StreamLevels calls being served")
GENERATOR_CONFIGS = Gauge("cec_level_server_generator_configs", "Distinct generator configs compiled")
RPCS = Counter("cec_level_server_rpcs_total", "Finished RPCs by method and gRPC status code", ["rpc", "code"])
RPC_LATENCY = Histogram(
    "cec_level_server_rpc_duration_seconds",
    "Latency of unary RPCs, and time to the first batch of a stream",
    ["rpc"],
    buckets=(0.0005, 0.001, 0.0025, 0.005, 0.01, 0.025, 0.05, 0.1, 0.25, 0.5, 1.0, 2.5, 10.0, 60.0),
)


class MetricsEndpoint:
    """A running `/metrics` HTTP endpoint; `close()` stops it."""

    def __init__(self, port: int, host: str = "127.0.0.1") -> None:
        self._server, self._thread = start_http_server(port, addr=host, registry=REGISTRY)
        self.host = host
        self.port: int = self._server.server_port  # the bound port (port 0 picks a free one)

    @property
    def url(self) -> str:
        return f"http://{self.host}:{self.port}/metrics"

    def close(self) -> None:
        self._server.shutdown()
        self._server.server_close()
