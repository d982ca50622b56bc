"""One table of default ports (`services/ports.py`): every dataclass default, preset and Prometheus file that
names a service's port says the same (the standalone level server exported on 9101, the stack on 9401)."""

from __future__ import annotations

import re
from pathlib import Path

import yaml

from services.evaluator.config import EvaluatorConfig
from services.learner.config import DistributedConfig
from services.level_server.config import LevelServerConfig
from services.ports import LEVEL_SERVER_GRPC_PORT, METRICS_PORTS, PROMETHEUS_PORT
from services.stack import UpConfig

ROOT = Path(__file__).resolve().parents[2]


def _yaml(path: str) -> dict:
    data: dict = yaml.safe_load((ROOT / path).read_text())
    return data


def test_defaults_and_presets_use_the_one_table() -> None:
    up = UpConfig()
    assert (LevelServerConfig().port, LevelServerConfig().metrics_port) == (
        LEVEL_SERVER_GRPC_PORT,
        METRICS_PORTS["level_server"],
    )
    assert (up.level_server_port, up.level_server_metrics_port) == (
        LEVEL_SERVER_GRPC_PORT,
        METRICS_PORTS["level_server"],
    )
    assert DistributedConfig().metrics_port == METRICS_PORTS["learner"]
    assert EvaluatorConfig().metrics_port == up.evaluator_metrics_port == METRICS_PORTS["evaluator"]
    level_server = _yaml("configs/level_server.yaml")
    assert (level_server["port"], level_server["metrics_port"]) == (
        LEVEL_SERVER_GRPC_PORT,
        METRICS_PORTS["level_server"],
    )
    assert _yaml("configs/evaluator.yaml")["metrics_port"] == METRICS_PORTS["evaluator"]
    default = _yaml("configs/up/default.yaml")
    assert default["level_server_port"] == LEVEL_SERVER_GRPC_PORT
    assert default["level_server_metrics_port"] == METRICS_PORTS["level_server"]
    assert default["evaluator_metrics_port"] == METRICS_PORTS["evaluator"]
    assert default["distributed"]["metrics_port"] == METRICS_PORTS["learner"]


def test_the_prometheus_files_scrape_the_tables_ports() -> None:
    for name in ("cluster/prometheus.yml", "cluster/prometheus-ray.yml"):
        config = _yaml(name)
        targets = {
            job["job_name"]: [
                int(t.rsplit(":", 1)[1]) for g in job.get("static_configs", []) for t in g["targets"]
            ]
            for job in config["scrape_configs"]
        }
        for job, port in METRICS_PORTS.items():
            assert targets[job] == [port], (name, job)
        assert re.search(rf"127\.0\.0\.1:{PROMETHEUS_PORT}\b", (ROOT / name).read_text()), name
