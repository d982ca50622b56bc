"""`cec monitoring` (also `python -m services.monitoring`): Prometheus (and Grafana, when installed) for a
CEC stack until Ctrl-C."""

from __future__ import annotations

import argparse
import contextlib
import sys

from cec.config import ConfigError, load_config
from cec.signals import GracefulStop
from services.entry import Service
from services.monitoring.config import (
    METRICS_PORTS,
    MonitoringConfig,
    MonitoringError,
)
from services.monitoring.servers import start_monitoring


def _parse_target(text: str) -> tuple[str, str]:
    job, sep, address = text.partition("=")
    if not sep:
        raise argparse.ArgumentTypeError(f"expected job=host:port, got {text!r}")
    return job, address


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument(
        "--target",
        action="append",
        type=_parse_target,
        default=[],
        metavar="JOB=HOST:PORT",
        help="a /metrics endpoint to scrape (repeatable); default: the embedded stack's ports "
        + ", ".join(f"{job}=127.0.0.1:{port}" for job, port in METRICS_PORTS.items()),
    )
    parser.add_argument(
        "--prometheus-config", help="use this Prometheus config instead (e.g. cluster/prometheus-ray.yml)"
    )
    parser.add_argument("--run-dir", default="runs/monitoring", help="where data and logs go")
    parser.add_argument(
        "overrides", nargs="*", metavar="KEY=VALUE", help="MonitoringConfig overrides, e.g. grafana=false"
    )


def run(args: argparse.Namespace) -> int:
    if args.target and args.prometheus_config:
        raise ConfigError("give --target or --prometheus-config, not both")
    config = load_config(MonitoringConfig, None, args.overrides)
    targets: dict[str, list[str]] | None = None
    if args.target:
        targets = {}
        for job, address in args.target:
            targets.setdefault(job, []).append(address)
    monitoring = start_monitoring(args.run_dir, targets, config, config_file=args.prometheus_config)
    with monitoring, GracefulStop("stopping Prometheus and Grafana", out=sys.stdout) as stopping:
        print(monitoring.describe(), flush=True)
        print("monitoring ready; Ctrl-C stops it", flush=True)
        with contextlib.suppress(KeyboardInterrupt):
            stopping.event.wait()
    return 0


SERVICE = Service(
    "monitoring",
    "services.monitoring",
    "start Prometheus (and Grafana, when installed) for a CEC stack; Ctrl-C stops them",
    add_arguments,
    run,
    failures=(OSError, MonitoringError),
)
