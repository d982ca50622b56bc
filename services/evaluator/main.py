"""Entry point: `cec evaluator [--config configs/evaluator.yaml] [key=value ...]` (also
`python -m services.evaluator`). Scores checkpoints as their events arrive until SIGTERM/SIGINT.

Prints `evaluator ready ...` with the metrics URL once it consumes the stream. On SIGTERM or SIGINT the
checkpoint being scored is abandoned at its next compiled call (its stored parts are kept, its event stays
pending, and a restart under the same `consumer_name` resumes it) and the process exits with status 0; a
second signal exits at once (status 130). Exit status 2: a bad config or zoo manifest; 1: Redis cannot be
reached or the metrics port is taken.
"""

from __future__ import annotations

import argparse
import logging

from cec.signals import GracefulStop
from services.entry import Service, config_arguments, load_service_config
from services.evaluator.config import EvaluatorConfig
from services.store import StoreError  # needs redis: without it `cec X` names the package

log = logging.getLogger("cec.evaluator")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    config_arguments(parser, "configs/evaluator.yaml", "store.url=redis://host:6379/0")


def run(args: argparse.Namespace) -> int:
    config = load_service_config(EvaluatorConfig, args)
    from services.evaluator.evaluator import Evaluator
    from services.metrics import MetricsEndpoint  # the evaluator imports JAX: keep `cec --help` fast

    evaluator = Evaluator(config)
    endpoint = None
    try:
        if config.metrics_port >= 0:
            endpoint = MetricsEndpoint(config.metrics_port, config.metrics_host, component="evaluator")
        try:
            newest = evaluator.restore_gauges()
            if newest is not None:
                log.info("gauges restored from the newest scored checkpoint, %s", newest)
        except StoreError as err:
            log.warning("gauges not restored: %s", err)
        stopping = GracefulStop("stopping after the current compiled call", abort_status=130)
        where = endpoint.url if endpoint is not None else "off"
        print(
            f"evaluator ready: consuming {evaluator.plane.stream_key} at {config.store.display_url} as "
            f"{config.consumer_group}/{config.consumer_name}; metrics {where}",
            flush=True,
        )
        with stopping:
            evaluator.serve(stopping.event)
    finally:
        if endpoint is not None:
            endpoint.close()
        evaluator.close()
    log.info("evaluator stopped")
    return 0


SERVICE = Service(
    "evaluator",
    "services.evaluator",
    "score checkpoints from the Redis event stream against the partner zoo until SIGTERM/Ctrl-C",
    add_arguments,
    run,
    failures=(OSError, StoreError),
)
