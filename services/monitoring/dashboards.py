"""What the dashboards query: every PromQL expression of cluster/grafana/dashboards, the metric names they
read (`dashboard_metric_names`), and the series names a registry can expose (`exported_metric_names`)."""

from __future__ import annotations

import json
import re
from collections.abc import Iterator, Mapping, Sequence
from pathlib import Path
from typing import Any, NamedTuple

from prometheus_client import REGISTRY, CollectorRegistry

from services.monitoring.config import (
    DASHBOARDS_DIR,
    MonitoringError,
)

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
