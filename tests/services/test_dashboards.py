"""The shipped monitoring files: Grafana dashboards and provisioning, Prometheus configs, the metric names.

Every metric a dashboard reads must be one that `services.metrics` defines (PromQL parsed for names); the
Prometheus configs and the default registry's exposition must pass `promtool` (Debian's `prometheus`).
"""

from __future__ import annotations

import json
import re
import shutil
import subprocess
import sys
import warnings
from pathlib import Path

import pytest
import yaml
from prometheus_client import CollectorRegistry, Counter, Gauge, Histogram, Summary

import services.metrics  # noqa: F401  (registers every metric of the stack in the default registry)
from cec.config import ConfigError, from_dict
from services.monitoring import (
    CLUSTER_DIR,
    DASHBOARDS_DIR,
    DEFAULT_TARGETS,
    ENV_DASHBOARDS,
    ENV_PROMETHEUS_URL,
    METRICS_PORTS,
    PROMETHEUS_PORT,
    PROMETHEUS_SYNTHETIC,
    PROVISIONING_DIR,
    Grafana,
    MonitoringConfig,
    MonitoringError,
    dashboard_metric_names,
    dashboard_queries,
    exported_metric_names,
    prometheus_config,
    promql_metric_names,
    query_metric_names,
    variable_metric_names,
    write_file_sd_targets,
)

DASHBOARDS = ("training", "levels", "evaluation", "cluster")
DATASOURCE = {"type": "prometheus", "uid": "${datasource}"}
PANEL_TYPES = {"row", "timeseries", "stat", "bargauge"}
RAW_TOTALS = {"Env steps trained", "PPO updates", "Checkpoints scored", "Failed evaluations"}  # stat panels
needs_promtool = pytest.mark.skipif(
    shutil.which("promtool") is None, reason="needs promtool (sudo apt-get install prometheus)"
)


def _load(name: str) -> dict:
    return json.loads((DASHBOARDS_DIR / f"{name}.json").read_text())


def _all_panels(panels: list[dict]) -> list[dict]:
    out = []
    for panel in panels:
        out.append(panel)
        out.extend(_all_panels(panel.get("panels", [])))
    return out


# --- the dashboards are Grafana dashboards ------------------------------------------------------------------
def test_the_four_dashboards_ship_and_nothing_else():
    assert sorted(p.stem for p in DASHBOARDS_DIR.glob("*.json")) == sorted(DASHBOARDS)


@pytest.mark.parametrize("name", DASHBOARDS)
def test_dashboard_is_valid_grafana_json(name):
    board = _load(name)
    assert board["uid"] == f"cec-{name}" and board["title"].startswith("CEC / ")
    assert isinstance(board["schemaVersion"], int) and board["schemaVersion"] >= 36
    assert board.get("id") is None  # provisioning assigns the database id
    assert "cec" in board["tags"]

    variables = {v["name"]: v for v in board["templating"]["list"]}
    source = variables["datasource"]
    assert source["type"] == "datasource" and source["query"] == "prometheus"

    panels = _all_panels(board["panels"])
    ids = [p["id"] for p in panels]
    assert all(isinstance(i, int) for i in ids) and len(ids) == len(set(ids)), f"duplicate panel ids: {ids}"

    occupied: dict[tuple[int, int], str] = {}
    for panel in panels:
        assert panel["type"] in PANEL_TYPES, panel["type"]
        pos = panel["gridPos"]
        assert {"h", "w", "x", "y"} <= pos.keys() and pos["x"] >= 0 and pos["x"] + pos["w"] <= 24
        for cell in (
            (x, y) for x in range(pos["x"], pos["x"] + pos["w"]) for y in range(pos["y"], pos["y"] + pos["h"])
        ):
            assert cell not in occupied, f"{panel['title']!r} overlaps {occupied[cell]!r}"
            occupied[cell] = panel["title"]
        if panel["type"] == "row":
            assert not panel.get("targets")
            continue
        assert panel["datasource"] == DATASOURCE, panel["title"]
        assert panel["title"] and panel.get("description"), "every panel says what it shows"
        targets = panel["targets"]
        assert targets and len({t["refId"] for t in targets}) == len(targets)
        for target in targets:
            assert target["datasource"] == DATASOURCE and target["expr"].strip()
        if "repeat" in panel:
            assert panel["repeat"] in variables

    # every $variable the queries use is defined (Grafana's own $__ variables aside)
    text = json.dumps([q.expr for q in dashboard_queries() if q.dashboard == f"{name}.json"])
    used = set(re.findall(r"\$\{?([A-Za-z]\w*)", text))
    assert used <= variables.keys(), f"undefined variables: {used - variables.keys()}"
    for variable in variables.values():
        if variable["type"] == "query":
            assert variable["datasource"] == DATASOURCE


def test_dashboards_have_distinct_uids_and_titles():
    boards = [_load(n) for n in DASHBOARDS]
    assert len({b["uid"] for b in boards}) == len({b["title"] for b in boards}) == len(DASHBOARDS)


def test_panels_use_rate_on_counters_and_quantiles_on_buckets():
    for query in dashboard_queries():
        if query.kind != "panel":
            continue
        flat = re.sub(r"\s+", "", query.expr)
        for name in promql_metric_names(query.expr):
            if name.endswith("_bucket"):
                assert "histogram_quantile(" in flat, f"{query.where}: buckets need histogram_quantile"
            is_counter = name.endswith(("_total", "_bucket", "_sum", "_count"))
            if is_counter and not re.search(rf"(rate|increase)\({name}[{{\[]", flat):
                # a counter is read through rate/increase, except as a single-stat total
                assert query.where in RAW_TOTALS, f"{query.where}: raw counter {name}"


def test_the_required_views_are_there():
    exprs = {q.dashboard: [] for q in dashboard_queries()}
    for q in dashboard_queries():
        exprs[q.dashboard].append(re.sub(r"\s+", " ", q.expr))
    training, cluster = " | ".join(exprs["training.json"]), " | ".join(exprs["cluster.json"])
    assert (
        "rate(cec_learner_trajectory_bytes_total[$__rate_interval]) / rate(cec_learner_agent_steps_total"
        in training
    )
    assert "histogram_quantile(0.99, sum by (le) (rate(cec_learner_policy_lag_versions_bucket" in training
    assert 'cec_learner_batches_total{outcome!="accepted"}' in training and "cec_learner_loss{" in training
    assert "time() - cec_learner_last_checkpoint_timestamp_seconds" in cluster
    assert "cec_learner_redis_up" in cluster and "cec_actor_restarts_total" in cluster
    evaluation = " | ".join(exprs["evaluation.json"])
    assert 'partner_group="self_play"' in evaluation and 'partner_group!="self_play"' in evaluation
    assert "{{partner_group}} / {{level_set}}" in (DASHBOARDS_DIR / "evaluation.json").read_text()


# --- the dashboards read only metrics the stack exports -----------------------------------------------------
def test_promql_metric_names():
    cases = {
        'histogram_quantile(0.9, sum by (le, rpc) (rate(a_bucket{x="y"}[$__rate_interval])))': {"a_bucket"},
        "rate(a_total[5m] offset 1h) / ignoring(stage) group_left sum(b)": {"a_total", "b"},
        "time() - c_timestamp_seconds": {"c_timestamp_seconds"},
        'x{l=~"a|b", m!="{c}"} and on() vector(1)': {"x"},
        "max_over_time(rate(d_total[5m])[1h:1m])": {"d_total"},
        "e > bool 1e3 or f < -Inf unless g == NaN": {"e", "f", "g"},
        "sum without (instance) (h) @ end() * 0x1F": {"h"},
        'label_replace(i, "dst", "$1 {x} [y]", "src", "(.*)")': {"i"},
        "sum(rate(j[$__range])) by (job) / scalar(sum(k:recorded:rate5m))": {"j", "k:recorded:rate5m"},
        "topk(3, l) + on (a, b) group_right (c) m offset -5m": {"l", "m"},
        "vector(1)": set(),
    }
    for expr, names in cases.items():
        assert promql_metric_names(expr) == names, expr
    with pytest.raises(ValueError, match="__name__"):
        promql_metric_names('{__name__=~"cec_.*"}')
    assert variable_metric_names("label_values(cec_evaluator_return{a='b'}, level_set)") == {
        "cec_evaluator_return"
    }
    assert variable_metric_names("label_values(job)") == set()
    assert variable_metric_names("query_result(topk(3, n))") == {"n"}


def test_exported_metric_names_follow_the_exposition_format():
    registry = CollectorRegistry()
    Counter("t_things_total", "doc", registry=registry)
    Gauge("t_level", "doc", ["who"], registry=registry)  # labelled, no children yet: still listed
    Histogram("t_seconds", "doc", ["rpc"], registry=registry)
    Summary("t_size_bytes", "doc", registry=registry)
    assert exported_metric_names(registry) == {
        "t_things_total", "t_things_created", "t_level",
        "t_seconds_bucket", "t_seconds_sum", "t_seconds_count", "t_seconds_created",
        "t_size_bytes", "t_size_bytes_sum", "t_size_bytes_count", "t_size_bytes_created",
    }  # fmt: skip


def test_every_metric_a_dashboard_reads_is_defined_in_cec_metrics():
    exported = exported_metric_names()
    missing = {
        f"{q.dashboard} / {q.where}: {name}"
        for q in dashboard_queries()
        for name in query_metric_names(q) - PROMETHEUS_SYNTHETIC
        if name not in exported
    }
    assert not missing, "dashboards read metrics no component exports:\n" + "\n".join(sorted(missing))
    # the synthetic series the dashboards use are the ones Prometheus makes for every target
    used = set().union(*(query_metric_names(q) for q in dashboard_queries()))
    assert used & PROMETHEUS_SYNTHETIC == {"up"}


def test_a_dashboard_reading_an_unknown_metric_is_caught(tmp_path):
    board = _load("training")
    board["panels"][1]["targets"][0]["expr"] = "rate(cec_learner_no_such_thing_total[$__rate_interval])"
    (tmp_path / "training.json").write_text(json.dumps(board))
    names = dashboard_metric_names(tmp_path)
    assert "cec_learner_no_such_thing_total" in names and names - exported_metric_names()


def test_metrics_that_no_dashboard_shows_are_listed():
    shown = dashboard_metric_names()
    families = {f.name: f.type for f in services.metrics.REGISTRY.collect() if f.name.startswith("cec_")}
    suffixes = {"counter": ("_total",), "histogram": ("_bucket", "_sum", "_count")}
    exported_by = {name: {name + s for s in suffixes.get(kind, ("",))} for name, kind in families.items()}
    unshown = sorted(name for name, samples in exported_by.items() if not samples & shown)
    if unshown:
        warnings.warn(f"metrics no dashboard shows: {', '.join(unshown)}", stacklevel=1)
    assert {"cec_learner_loss", "cec_evaluator_return"} <= families.keys()  # the registry was read
    assert len(unshown) < len(families)


# --- Grafana provisioning -----------------------------------------------------------------------------------
def test_provisioning_points_at_the_dashboards_and_prometheus(tmp_path):
    (source,) = yaml.safe_load((PROVISIONING_DIR / "datasources" / "cec.yaml").read_text())["datasources"]
    assert source["type"] == "prometheus" and source["isDefault"] is True
    (provider,) = yaml.safe_load((PROVISIONING_DIR / "dashboards" / "cec.yaml").read_text())["providers"]
    assert provider["type"] == "file"
    referenced = set(re.findall(r"\$\{?(\w+)\}?", json.dumps([source, provider])))
    assert referenced == {ENV_PROMETHEUS_URL, ENV_DASHBOARDS}

    env = Grafana(tmp_path, prometheus_url="http://127.0.0.1:9999", port=3001).environment()
    assert env[ENV_PROMETHEUS_URL] == "http://127.0.0.1:9999" and Path(env[ENV_DASHBOARDS]) == DASHBOARDS_DIR
    assert Path(env["GF_PATHS_PROVISIONING"]) == PROVISIONING_DIR and env["GF_SERVER_HTTP_PORT"] == "3001"
    assert env["GF_AUTH_ANONYMOUS_ENABLED"] == "true"  # loopback only
    remote = Grafana(tmp_path, prometheus_url="http://p:9090", host="0.0.0.0").environment()
    assert "GF_AUTH_ANONYMOUS_ENABLED" not in remote


def test_grafana_home_is_found_next_to_the_binary(tmp_path):
    home = tmp_path / "grafana-v11"
    (home / "bin").mkdir(parents=True)
    (home / "conf").mkdir()
    (home / "conf" / "defaults.ini").write_text("")
    binary = home / "bin" / "grafana"
    binary.write_text("#!/bin/sh\n")
    assert Grafana.find_home(str(binary)) == home
    with pytest.raises(MonitoringError, match="grafana_home"):
        Grafana.find_home(str(binary), home=str(tmp_path / "elsewhere"))


# --- Prometheus configs -------------------------------------------------------------------------------------
def _jobs(path: Path) -> dict[str, dict]:
    return {job["job_name"]: job for job in yaml.safe_load(path.read_text())["scrape_configs"]}


def test_embedded_config_scrapes_the_default_ports():
    jobs = _jobs(CLUSTER_DIR / "prometheus.yml")
    for job, port in METRICS_PORTS.items():
        assert jobs[job]["static_configs"] == [{"targets": [f"127.0.0.1:{port}"]}]
    assert jobs["prometheus"]["static_configs"] == [{"targets": [f"127.0.0.1:{PROMETHEUS_PORT}"]}]
    assert sorted(METRICS_PORTS) == ["evaluator", "learner", "level_server"]
    assert len(set(METRICS_PORTS.values())) == 3


def test_ray_config_discovers_ray_and_scrapes_the_services():
    jobs = _jobs(CLUSTER_DIR / "prometheus-ray.yml")
    assert jobs["ray"]["file_sd_configs"] == [{"files": ["/tmp/ray/prom_metrics_service_discovery.json"]}]
    for job, port in METRICS_PORTS.items():
        assert jobs[job]["static_configs"] == [{"targets": [f"127.0.0.1:{port}"]}]
    assert any("file_sd_configs" in j for name, j in jobs.items() if name != "ray")


@needs_promtool
@pytest.mark.parametrize("name", ["prometheus.yml", "prometheus-ray.yml"])
def test_promtool_accepts_the_cluster_configs(name):
    result = subprocess.run(
        ["promtool", "check", "config", str(CLUSTER_DIR / name)], capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 0, result.stdout + result.stderr


@needs_promtool
def test_promtool_accepts_generated_configs_and_file_sd_targets(tmp_path):
    config = tmp_path / "prometheus.yml"
    config.write_text(
        prometheus_config(DEFAULT_TARGETS, scrape_interval_s=0.5, self_address="127.0.0.1:9090")
    )
    targets = write_file_sd_targets(tmp_path / "sd" / "nodes.json", {"learner": ["10.0.0.7:9402"]})
    assert json.loads(targets.read_text()) == [{"targets": ["10.0.0.7:9402"], "labels": {"job": "learner"}}]
    sd = tmp_path / "sd.yml"
    sd.write_text(
        yaml.safe_dump(
            {"scrape_configs": [{"job_name": "x", "file_sd_configs": [{"files": [str(targets)]}]}]}
        )
    )
    for path in (config, sd):
        result = subprocess.run(
            ["promtool", "check", "config", str(path)], capture_output=True, text=True, timeout=30
        )
        assert result.returncode == 0 and "WARNING" not in result.stdout, result.stdout + result.stderr
    jobs = _jobs(config)
    assert jobs["learner"]["static_configs"] == [{"targets": ["127.0.0.1:9402"]}]
    assert yaml.safe_load(config.read_text())["global"]["scrape_interval"] == "500ms"


def test_bad_targets_and_configs_are_refused_clearly():
    with pytest.raises(MonitoringError, match="not 'host:port'"):
        prometheus_config({"learner": ["127.0.0.1"]})
    with pytest.raises(MonitoringError, match="list of 'host:port'"):
        prometheus_config({"learner": "127.0.0.1:9402"})
    with pytest.raises(MonitoringError, match="letters, digits"):
        prometheus_config({"my-learner": ["127.0.0.1:9402"]})
    with pytest.raises(ConfigError, match="unknown key 'prometheus_prot'"):
        from_dict(MonitoringConfig, {"prometheus_prot": 1})
    with pytest.raises(ConfigError, match="TCP port"):
        MonitoringConfig(grafana_port=70000)


# --- promtool on the exposition of every metric -------------------------------------------------------------
_EXPOSE_ALL = """
import services.metrics as m
from prometheus_client import REGISTRY, generate_latest
from prometheus_client.metrics import MetricWrapperBase
for metric in vars(m).values():
    if isinstance(metric, MetricWrapperBase) and metric._labelnames:
        metric.labels(*["example"] * len(metric._labelnames))  # a child, so that the series appears
print(generate_latest(REGISTRY).decode(), end="")
"""


@needs_promtool
def test_promtool_lints_the_exposition_of_every_metric():
    # A separate interpreter: touching the labelled metrics must not leave children in this one.
    text = subprocess.run(
        [sys.executable, "-c", _EXPOSE_ALL], capture_output=True, text=True, timeout=60, check=True
    ).stdout
    samples = set(re.findall(r"^([A-Za-z_:][\w:]*)[{ ]", text, flags=re.MULTILINE))
    ours = {name for name in exported_metric_names() if name.startswith("cec_")}
    assert {name for name in samples if name.startswith("cec_")} == ours  # every series, as predicted
    assert dashboard_metric_names() <= samples
    result = subprocess.run(
        ["promtool", "check", "metrics"], input=text, capture_output=True, text=True, timeout=30
    )
    assert result.returncode == 0, result.stdout + result.stderr
