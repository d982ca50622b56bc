"""Entry point: `cec level-server [--config configs/level_server.yaml] [key=value ...]`
(also `python -m services.level_server`). Serves until SIGTERM/SIGINT, then shuts down gracefully."""

from __future__ import annotations

import argparse
import asyncio
import logging
import signal

from services.entry import Service, config_arguments, load_service_config
from services.level_server.config import LevelServerConfig
from services.level_server.server import LevelServer
from services.metrics import MetricsEndpoint

log = logging.getLogger("cec.level_server")


def add_arguments(parser: argparse.ArgumentParser) -> None:
    config_arguments(parser, "configs/level_server.yaml", "port=50052")


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
    asyncio.run(serve(load_service_config(LevelServerConfig, args)))
    return 0


SERVICE = Service(
    "level-server",
    "services.level_server",
    "serve kitchens over gRPC until SIGTERM/Ctrl-C",
    add_arguments,
    run,
)
