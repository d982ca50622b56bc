"""What Prometheus scrapes: a generated config for a stack's `/metrics` endpoints (`prometheus_config`) and
file_sd target files for services off a Ray head node (`write_file_sd_targets`)."""

from __future__ import annotations

import json
import os
import re
from collections.abc import Mapping, Sequence
from pathlib import Path

import yaml

from services.monitoring.config import (
    MonitoringError,
)

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
