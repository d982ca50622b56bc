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
import sys
from typing import Any

from cec.config import ConfigError, load_config
from cec.signals import GracefulStop
from services.evaluator.config import EvaluatorConfig

log = logging.getLogger("cec.evaluator")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML preset (e.g. configs/evaluator.yaml); defaults if omitted")
    parser.add_argument(
        "set", nargs="*", metavar="key=value", help="config overrides, e.g. store.url=redis://host:6379/0"
    )


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        config = load_config(EvaluatorConfig, args.config, args.set)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return 2
    from services.evaluator.evaluator import Evaluator
    from services.metrics import MetricsEndpoint  # the evaluator imports JAX: keep `cec --help` fast
    from services.store import StoreError

    try:
        evaluator = Evaluator(config)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return 2
    except StoreError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    endpoint = None
    try:
        if config.metrics_port >= 0:
            try:
                endpoint = MetricsEndpoint(config.metrics_port, config.metrics_host, component="evaluator")
            except OSError as err:
                print(
                    f"error: cannot serve metrics on {config.metrics_host}:{config.metrics_port} ({err}); "
                    "choose another metrics_port (0: a free one, -1: off)",
                    file=sys.stderr,
                )
                return 1
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


def add_subcommands(sub: Any) -> None:
    """Adds `evaluator` to the `cec` command's subparsers."""
    parser = sub.add_parser(
        "evaluator",
        help="score checkpoints from the Redis event stream against the partner zoo until SIGTERM/Ctrl-C",
    )
    add_arguments(parser)
    parser.set_defaults(func=run)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="python -m services.evaluator", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
