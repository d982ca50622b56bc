"""Prometheus started by `services.monitoring` scrapes a real `MetricsEndpoint` over loopback.

The endpoint runs in a child interpreter that has touched every labelled metric once, so that every series
the dashboards read exists; Prometheus (Debian's `prometheus` binary) scrapes it, and the test reads the
results back through Prometheus' HTTP API: the target is up, every metric the dashboards read arrived, and
every dashboard expression is PromQL that Prometheus itself parses and evaluates.
"""

from __future__ import annotations

import re
import shutil
import signal
import socket
import subprocess
import sys
import time
from collections.abc import Iterator

import pytest

from services.monitoring import (
    MonitoringConfig,
    MonitoringError,
    Prometheus,
    dashboard_metric_names,
    dashboard_queries,
    prometheus_config,
    start_monitoring,
)

needs_prometheus = pytest.mark.skipif(
    shutil.which("prometheus") is None, reason="needs prometheus (sudo apt-get install prometheus)"
)
SCRAPE_S = 0.5
WAIT_S = 60.0  # Prometheus applies new targets within ~5 s of starting; this only bounds a broken run

# A child serving every metric of the stack on a free port: prints the port, serves until stdin closes.
_EXPORTER = """
import sys
import services.metrics as m
from prometheus_client.metrics import MetricWrapperBase
for metric in vars(m).values():
    if isinstance(metric, MetricWrapperBase) and metric._labelnames:
        metric.labels(*["example"] * len(metric._labelnames))
m.LEARNER_UPDATES.inc(7)
endpoint = m.MetricsEndpoint(0)
print(endpoint.port, flush=True)
sys.stdin.read()
endpoint.close()
"""


@pytest.fixture(scope="module")
def exporter() -> Iterator[str]:
    proc = subprocess.Popen(
        [sys.executable, "-c", _EXPORTER], stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True
    )
    try:
        assert proc.stdout is not None
        port = int(proc.stdout.readline())
        yield f"127.0.0.1:{port}"
    finally:
        assert proc.stdin is not None
        proc.stdin.close()
        proc.wait(10)


def _wait_for(prom: Prometheus, expr: str, want: str) -> list[dict]:
    deadline = time.monotonic() + WAIT_S
    while True:
        result = prom.query(expr)
        if result and all(r["value"][1] == want for r in result):
            return result
        assert time.monotonic() < deadline, f"{expr} never became {want}: {result}"
        time.sleep(0.2)


@pytest.fixture(scope="module")
def prometheus(exporter, tmp_path_factory) -> Iterator[Prometheus]:
    run = tmp_path_factory.mktemp("prometheus")
    with Prometheus(run, targets={"learner": [exporter]}, port=0, scrape_interval_s=SCRAPE_S) as prom:
        _wait_for(prom, 'up{job="learner"}', "1")
        yield prom


@needs_prometheus
def test_prometheus_scrapes_the_metrics_endpoint(prometheus, exporter):
    (up,) = _wait_for(prometheus, 'up{job="learner"}', "1")
    assert up["metric"]["instance"] == exporter
    (updates,) = prometheus.query("cec_learner_updates_total")
    assert updates["metric"]["job"] == "learner" and float(updates["value"][1]) == 7.0
    assert (prometheus.run_dir / "prometheus.yml").is_file() and (prometheus.run_dir / "data").is_dir()


@needs_prometheus
def test_every_metric_the_dashboards_read_reaches_prometheus(prometheus):
    scraped = {r["metric"]["__name__"] for r in prometheus.query('count by (__name__) ({job="learner"})')}
    missing = dashboard_metric_names() - scraped
    assert not missing, f"dashboard metrics Prometheus did not get: {sorted(missing)}"


def _as_promql(expr: str) -> str:
    """A dashboard expression with Grafana's variables filled in as Grafana would."""
    expr = expr.replace("$__rate_interval", "1m").replace("$__range", "1h").replace("$__interval", "15s")
    return re.sub(r"\$\{?\w+\}?", ".*", expr)  # template variables: "All"


@needs_prometheus
def test_every_dashboard_expression_is_valid_promql(prometheus):
    queries = dashboard_queries()
    assert len(queries) > 40
    for query in queries:
        expr = _as_promql(query.expr)
        if query.kind == "variable":
            match = re.fullmatch(r"label_values\((.*),\s*(\w+)\)", expr)
            assert match, f"{query.dashboard} / {query.where}: unexpected variable query {query.expr}"
            expr = f"count by ({match.group(2)}) ({match.group(1)})"
        try:
            prometheus.query(expr)
        except MonitoringError as err:
            pytest.fail(f"{query.dashboard} / {query.where}: {err}")
    with pytest.raises(MonitoringError, match="parse error"):  # and a broken one is caught
        prometheus.query("rate(cec_learner_updates_total[5m)")


@needs_prometheus
def test_a_taken_port_is_refused_clearly(tmp_path):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        prom = Prometheus(tmp_path, targets={"learner": ["127.0.0.1:1"]}, port=port)
        with pytest.raises(MonitoringError, match=f"127.0.0.1:{port}: the port is in use"):
            prom.start()
        assert not prom.running


def test_a_missing_binary_is_named_with_the_fix(tmp_path):
    config = MonitoringConfig(prometheus_executable="no-such-prometheus-binary")
    with pytest.raises(MonitoringError, match=r"no-such-prometheus-binary.*apt-get install prometheus"):
        start_monitoring(tmp_path, {"learner": ["127.0.0.1:9402"]}, config)
    with pytest.raises(MonitoringError, match="does not exist"):
        Prometheus(tmp_path, config_file=tmp_path / "nope.yml")
    with pytest.raises(MonitoringError, match="not both"):
        start_monitoring(tmp_path, {"learner": ["127.0.0.1:9402"]}, config_file=tmp_path / "p.yml")


@needs_prometheus
def test_start_monitoring_prints_urls_and_stops(tmp_path, exporter):
    config_file = tmp_path / "given.yml"
    config_file.write_text(prometheus_config({"learner": [exporter]}, scrape_interval_s=SCRAPE_S))
    config = MonitoringConfig(prometheus_port=0, grafana_port=0, grafana=False)
    with start_monitoring(tmp_path / "run", config=config, config_file=config_file) as mon:
        assert mon.prometheus.running and mon.grafana is None
        assert mon.urls == {"prometheus": mon.prometheus.url}
        assert mon.prometheus.url in mon.describe() and "grafana=false" in mon.describe()
        assert mon.prometheus.query("vector(1)")[0]["value"][1] == "1"
    assert not mon.prometheus.running
    with pytest.raises(MonitoringError, match="not running"):
        mon.prometheus.query("vector(1)")


@needs_prometheus
def test_python_m_cec_monitoring_serves_until_interrupted(tmp_path, exporter):
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "services.monitoring",
            "--target",
            f"learner={exporter}",
            "--run-dir",
            str(tmp_path),
        ]
        + ["prometheus_port=0", "grafana=false", f"scrape_interval_s={SCRAPE_S}"],
        stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT,
        text=True,
    )
    try:
        assert proc.stdout is not None
        lines = []
        for line in proc.stdout:
            lines.append(line)
            if "monitoring ready" in line:
                break
        url = next(line.split()[1] for line in lines if line.startswith("prometheus "))
        assert url.startswith("http://127.0.0.1:")
        proc.send_signal(signal.SIGINT)
        assert proc.wait(30) == 0, "".join(lines) + proc.stdout.read()
    finally:
        if proc.poll() is None:
            proc.kill()
            proc.wait()
    port = int(url.rsplit(":", 1)[1])
    with socket.socket() as s:  # Prometheus has gone and released its port (as a restarted server binds)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        s.bind(("127.0.0.1", port))
