"""Entry point: `cec level-server [--config configs/level_server.yaml] [key=value ...]`
(also `python -m services.level_server`). Serves until SIGTERM/SIGINT, then shuts down gracefully."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal
import sys

from cec.config import ConfigError, load_config
from services.level_server.config import LevelServerConfig
from services.level_server.server import LevelServer
from services.metrics import MetricsEndpoint

log = logging.getLogger("cec.level_server")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--config", help="YAML preset (e.g. configs/level_server.yaml); defaults if omitted")
    parser.add_argument("set", nargs="*", metavar="key=value", help="config overrides, e.g. port=50052")


async def serve(config: LevelServerConfig) -> None:
    server = LevelServer(config)
    endpoint = None
    if config.metrics_port >= 0:
        endpoint = MetricsEndpoint(config.metrics_port, config.metrics_host, "level_server")
        log.info("metrics at %s", endpoint.url)
    await server.start()
    print(f"level server ready on {server.address}", flush=True)  # a line scripts and tests wait for
    stop = asyncio.Event()
    loop = asyncio.get_running_loop()
    for sig in (signal.SIGTERM, signal.SIGINT):
        loop.add_signal_handler(sig, stop.set)
    await stop.wait()
    log.info("shutting down: %.1f s grace for in-flight calls", config.grace_seconds)
    await server.stop()
    if endpoint is not None:
        endpoint.close()


def run(args: argparse.Namespace) -> int:
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(levelname)s %(message)s")
    try:
        config = load_config(LevelServerConfig, args.config, args.set)
    except ConfigError as err:
        print(f"config error: {err}", file=sys.stderr)
        return 2
    try:
        asyncio.run(serve(config))
    except OSError as err:
        print(f"error: {err}", file=sys.stderr)
        return 1
    return 0


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(prog="cec level-server", description=__doc__.split("\n")[0])
    add_arguments(parser)
    return run(parser.parse_args(argv))
