"""`cec up`: the whole service on one machine, started in order and shut down cleanly.

    cec up [--config configs/up/default.yaml] [--monitoring] [key=value ...] [train.key=value ...]

Start-up (each step checked before the next; a failure stops everything started so far and names the fix):
1. Redis: `store.url` (or CEC_REDIS_URL) when given, else a local `redis-server` on a free port in the run
   directory (`services.store.LocalRedis`).
2. The level server (`python -m services.level_server`) unless `level_server_address` points at one, or the
   preset trains on fixed kitchens (`env.levels` other than `generator`: nothing would stream from it, and
   it would compile the kitchen generator for a minute or more first).
3. Ray (local, or `distributed.ray_address`), then the learner and its rollout actors
   (`services.learner.driver`), streaming kitchens from the level server for procedural Overcooked runs.
4. The evaluator (`python -m services.evaluator`), scoring each checkpoint the learner publishes.
5. With `monitoring`: Prometheus (and Grafana when installed) scraping all of the above.

The URLs of everything are printed; Ctrl-C (or SIGTERM) makes the learner checkpoint, then the evaluator,
level server, Ray, Redis and Prometheus are stopped in reverse order. The learner's last line names the
command that continues the run (`cec up --resume ...`, or `make up ARGS=--resume ...` under `make up`), also
recorded in the run (`logs/resume_command`) for `cec status` and for the refusal of a second start. Runs
are named `up-<preset's run name>` unless `train.name=` is given, apart from `cec train`'s.

No wait is silent: a service that is slow to start gets a line every few seconds with its latest log line
(`ServiceProcess` progress), and the learner a line every few seconds until its first update (`Heartbeat`),
unless it printed one itself.

Size: one stack's checks, start-up and shutdown, which all read the same state (the children started so
far, their ports and logs); split, each part would take that whole state as arguments.
"""

from __future__ import annotations

import argparse
import dataclasses
import logging
import os
import shlex
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO, cast

from cec.config import ConfigError, load_config
from cec.training.config import TrainConfig
from services.entry import override_arguments
from services.learner.config import DistributedConfig
from services.monitoring import MonitoringConfig
from services.ports import LEVEL_SERVER_GRPC_PORT, METRICS_PORTS, check_distinct, check_port
from services.processes import ChildRecord, free_port
from services.progress import Heartbeat, Stamped
from services.service_process import (
    ServiceProcess,
    ensure_ray_token,
    forget_ray_address,
    start_ray_head,
)
from services.status import last_row, write_stack_file
from services.store import StoreConfig
from services.terminal import foreground_group

log = logging.getLogger("cec.up")
DEFAULT_CONFIG = "configs/up/default.yaml"
CACHE_DIR = "JAX_COMPILATION_CACHE_DIR"  # the evaluator's compilation cache (`Stack.start`)
PROGRESS_S = 7.0  # the longest silence while a person waits for the stack (the learner's first update)


@dataclass(frozen=True)
class UpConfig:
    """The embedded stack (`cec up`).

    Attributes:
        train: the training preset (a `TrainConfig` YAML, e.g. configs/train/cramped_room_ci.yaml).
        train_overrides: `key=value` overrides of the preset (also `train.key=value` on the command line).
        distributed: actors, sync/async, the learner's metrics port (`DistributedConfig`).
        store: Redis; empty `url` and no CEC_REDIS_URL: a local redis-server is started for the run.
        level_server_address: an existing level server (`host:port`); empty: start one.
        level_server_port: gRPC port of the level server started here (0: a free one).
        level_server_metrics_port: its Prometheus port (0: a free one, -1: off).
        evaluator: start the evaluator service.
        evaluator_config: its preset (`EvaluatorConfig` YAML); the stack sets its Redis URL, results
            directory and metrics port.
        evaluator_metrics_port: the evaluator's Prometheus port (0: a free one, -1: off).
        monitoring: start Prometheus (and Grafana when installed) against the stack.
        monitoring_config: their ports and settings (`services.monitoring.MonitoringConfig`).
        ray_dashboard: start Ray's dashboard with the local Ray.
        start_timeout_s: how long each service may take to report ready.
        evaluator_drain_s: after the run finishes, how long `cec up` waits for the evaluator to score the
            checkpoints it has not scored yet (the run's last ones), so that its record ends with the run.
    """

    train: str = "configs/train/cramped_room_ci.yaml"
    train_overrides: tuple[str, ...] = ()
    distributed: DistributedConfig = field(default_factory=DistributedConfig)
    store: StoreConfig = field(default_factory=StoreConfig)
    level_server_address: str = ""
    level_server_port: int = LEVEL_SERVER_GRPC_PORT
    level_server_metrics_port: int = METRICS_PORTS["level_server"]
    evaluator: bool = True
    evaluator_config: str = "configs/evaluator.yaml"
    evaluator_metrics_port: int = METRICS_PORTS["evaluator"]
    monitoring: bool = False
    monitoring_config: MonitoringConfig = field(default_factory=MonitoringConfig)
    ray_dashboard: bool = True
    start_timeout_s: float = 120.0
    evaluator_drain_s: float = 3600.0

    def __post_init__(self) -> None:
        check_port("level_server_port", self.level_server_port)
        check_port("level_server_metrics_port", self.level_server_metrics_port, off=True)
        check_port("evaluator_metrics_port", self.evaluator_metrics_port, off=True)

    def train_config(self, extra: tuple[str, ...] = ()) -> TrainConfig:
        """The training preset with its overrides; unless it is named (`train.name=...`), the run is named
        `up-<the preset's run name>`, so that `cec train` of the same preset never meets a `cec up` run."""
        train = load_config(TrainConfig, preset_path(self.train), [*self.train_overrides, *extra])
        return train if train.name else dataclasses.replace(train, name=f"up-{train.run_name}")


def preset_path(path: str) -> Path:
    """`path` as given, or else relative to the repository (presets ship in its `configs/`)."""
    p = Path(path)
    repo = Path(__file__).resolve().parent.parent
    return p if p.exists() or p.is_absolute() or not (repo / p).exists() else repo / p


def _port(requested: int) -> int:
    return free_port() if requested == 0 else requested


class Stack:
    """The services of `cec up` (see the module docstring); `start()` then `train()`, `stop()` always."""

    def __init__(
        self, config: UpConfig, train: TrainConfig, out: TextIO = sys.stderr, resume_hint: str = ""
    ) -> None:
        self.config = config
        self.train_config = train
        self.out = out
        self.resume_hint = resume_hint  # the command that continues this run (`resume_hint`)
        self.run_dir = Path(train.run_dir) / train.run_name
        self.services: list[ServiceProcess] = []
        self.redis: Any = None
        self.monitoring: Any = None
        self.store = config.store
        self.dist = config.distributed
        self.urls: dict[str, str] = {}
        self.ray_started = False
        self.ray_head_port: int | None = None  # of the Ray head started here
        self.stack_file: Path | None = None  # `cec status` reads it while the stack runs
        self.children = ChildRecord(self.run_dir / "logs" / "children.json")

    def say(self, text: str) -> None:
        print(text, file=self.out, flush=True)

    @property
    def starts_level_server(self) -> bool:
        """A level server is started here: none is given and the preset streams its kitchens."""
        return not self.config.level_server_address and self.train_config.env.levels == "generator"

    def start(self, resume: bool = False) -> None:
        """Long because it is the module docstring's start-up, step by step; `stop` undoes it in reverse."""
        from services.learner.config import check_streamed
        from services.learner.driver import check_run

        cfg = self.config
        self.dist.check(self.train_config)
        if self.starts_level_server or cfg.level_server_address:
            check_streamed(self.train_config)
        check_run(self.train_config, resume, self.resume_hint)  # before anything starts
        self.children.check()  # leftovers of an earlier `cec up` of this run: named, not collided with
        self.check_ports()
        if self.starts_level_server or cfg.level_server_address:  # before Redis, as `auth_token=` would be
            from services.level_server.config import TOKEN_ENV, check_token

            check_token(os.environ.get(TOKEN_ENV, ""), f"the {TOKEN_ENV} environment variable")
        logs = self.run_dir / "logs"
        # 1. Redis
        if self.store.url_given:
            from services.store import ControlPlane, StoreError

            try:
                ControlPlane.connect(self.store).close()
            except StoreError as err:
                raise ConfigError(str(err)) from err
            self.say(f"redis                  {self.store.display_url} (given)")
        else:
            from services.store import LocalRedis

            self.redis = LocalRedis(self.run_dir / "redis").start()
            self.children.add("redis-server", self.redis.pid)
            self.store = self.redis.config()
            self.say(
                f"redis                  {self.redis.url} (started here; data in {self.run_dir / 'redis'})"
            )
        self.urls["redis"] = self.store.display_url
        # 2. level server
        address = cfg.level_server_address
        if not address and not self.starts_level_server:
            self.say(
                f"level server           not started: the preset's kitchens (env.levels="
                f"{self.train_config.env.levels}) are not streamed; env.levels=generator starts it"
            )
        elif not address:
            port, mport = _port(cfg.level_server_port), cfg.level_server_metrics_port
            mport = mport if mport < 0 else _port(mport)
            self.say(
                "level server           starting: it compiles the kitchen generator first (a minute or two)"
            )
            server = ServiceProcess(
                "level server",
                [
                    "-m",
                    "services.level_server",
                    f"port={port}",
                    f"metrics_port={mport}",
                    f"seed={self.train_config.seed}",
                ],
                logs / "level_server.log",
                "level server ready on",
                cfg.start_timeout_s,
                progress=self.say,
            )
            self._started(server)
            address = server.ready_line.rsplit(" ", 1)[-1]
            self.say(f"level server           grpc://{address}  (log: {server.log_path})")
            if mport >= 0:
                self.urls["level server metrics"] = f"http://127.0.0.1:{mport}/metrics"
        else:
            from services.learner.driver import check_level_server

            check_level_server(address, self.dist.level_token)
            self.say(f"level server           grpc://{address} (given)")
        if self.train_config.env.levels == "generator" and not self.dist.level_server:
            self.dist = dataclasses.replace(self.dist, level_server=address)
        if self.dist.metrics_port == 0:
            self.dist = dataclasses.replace(self.dist, metrics_port=free_port())
        if self.dist.metrics_port >= 0:
            self.urls["learner metrics"] = f"http://{self.dist.metrics_host}:{self.dist.metrics_port}/metrics"
        # 3. evaluator
        if cfg.evaluator:
            eport = (
                cfg.evaluator_metrics_port
                if cfg.evaluator_metrics_port < 0
                else _port(cfg.evaluator_metrics_port)
            )
            evaluator = ServiceProcess(
                "evaluator",
                [
                    "-m",
                    "services.evaluator",
                    "--config",
                    str(preset_path(cfg.evaluator_config)),
                    f"store.url={self.store.resolved_url}",
                    f"results_dir={self.train_config.run_dir}",
                    f"metrics_port={eport}",
                ],
                logs / "evaluator.log",
                "evaluator ready",
                cfg.start_timeout_s,
                progress=self.say,
                # fast restarts: JAX's compilation cache, the user's own if set, else one in the run
                env={CACHE_DIR: os.environ.get(CACHE_DIR) or str(self.run_dir / "jax_cache")},
            )
            self._started(evaluator)
            self.say(f"evaluator              consuming checkpoint events  (log: {evaluator.log_path})")
            if eport >= 0:
                self.urls["evaluator metrics"] = f"http://127.0.0.1:{eport}/metrics"
        # 4. Ray (none when the learner and its actors run in this process: distributed.pool=local)
        if self.dist.pool == "ray":
            self._start_ray(logs)
        # 5. monitoring
        if cfg.monitoring:
            from services.monitoring import MonitoringError, start_monitoring

            targets = {
                job: [url.split("//", 1)[1].split("/", 1)[0]]
                for job, url in (
                    ("level_server", self.urls.get("level server metrics", "")),
                    ("learner", self.urls.get("learner metrics", "")),
                    ("evaluator", self.urls.get("evaluator metrics", "")),
                )
                if url
            }
            try:
                self.monitoring = start_monitoring(
                    self.run_dir / "monitoring", targets, cfg.monitoring_config
                )
                self.say(self.monitoring.describe())
                for server in (self.monitoring.prometheus, self.monitoring.grafana):
                    if server is not None and server.pid is not None:
                        self.children.add(server.name, server.pid)
            except MonitoringError as err:
                self.say(f"monitoring not started: {err}")
        for name, url in self.urls.items():
            self.say(f"{name:<22} {url}")
        self.stack_file = write_stack_file(self.run_dir, self.urls, bool(self.store.resolved_password))
        self.say(f"status                 cec status {self.run_dir}  [--watch]")

    def _start_ray(self, logs: Path) -> None:
        """Connects to `distributed.ray_address`, or starts a local Ray head (its own CLI, its own session)
        and connects to it."""
        cfg = self.config
        if not self.dist.ray_address:
            # Ray's token authentication (its default for a new local cluster; the token is Ray's own,
            # ~/.ray/auth_token): the head and this driver must agree, and Ray reads the mode when imported.
            os.environ.setdefault("RAY_AUTH_MODE", "token")
        from services.learner.driver import connect_ray

        address = self.dist.ray_address
        if not address:  # a local Ray started by its own CLI: no fork of this (JAX-threaded) process
            ensure_ray_token()
            port = free_port()
            head = start_ray_head(
                [
                    "-m",
                    "ray.scripts.scripts",
                    "start",
                    "--head",
                    "--block",  # until SIGTERM, then it stops every Ray process it started
                    "--node-ip-address=127.0.0.1",
                    f"--port={port}",
                    f"--include-dashboard={str(cfg.ray_dashboard).lower()}",
                    "--disable-usage-stats",
                    *([f"--num-cpus={self.dist.ray_num_cpus}"] if self.dist.ray_num_cpus else []),
                ],
                logs / "ray.log",
                cfg.start_timeout_s,
            )
            self._started(head)
            address = f"127.0.0.1:{port}"
            self.ray_head_port = port
        info = connect_ray(address, logging_level=logging.WARNING)
        self.ray_started = True
        dash = getattr(info, "dashboard_url", "") or ""
        if dash:
            self.urls["ray dashboard"] = dash if dash.startswith("http") else f"http://{dash}"

    def _started(self, service: ServiceProcess) -> None:
        self.services.append(service)
        self.children.add(service.name, service.proc.pid)

    def fixed_ports(self) -> list[tuple[str, str, int]]:
        """(key, service, port) of every fixed port this stack will bind (0: a free one, -1: off)."""
        cfg, out = self.config, []
        if not cfg.level_server_address:  # checked even when not started: the preset's ports stay usable
            out.append(("level_server_port", "the level server's gRPC", cfg.level_server_port))
            metrics = cfg.level_server_metrics_port
            out.append(("level_server_metrics_port", "the level server's metrics", metrics))
        if cfg.evaluator:
            out.append(("evaluator_metrics_port", "the evaluator's metrics", cfg.evaluator_metrics_port))
        out.append(("distributed.metrics_port", "the learner's metrics", self.dist.metrics_port))
        return [(k, s, p) for k, s, p in out if p > 0]

    def check_ports(self) -> None:
        """`ConfigError` naming the port, the service that wants it and the key that moves it, for the first
        fixed port another process holds, or for two of the stack's services given one port: found before
        anything starts, not after a service's slow start."""
        import socket

        mon = self.config.monitoring_config
        ours = [("monitoring_config.prometheus_port", "Prometheus", mon.prometheus_port)]
        ours += [("monitoring_config.grafana_port", "Grafana", mon.grafana_port)] if mon.grafana else []
        check_distinct(self.fixed_ports() + (ours if self.config.monitoring else []))
        for key, service, port in self.fixed_ports():
            with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as sock:
                sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
                try:
                    sock.bind(("127.0.0.1", port))
                except OSError as err:
                    raise ConfigError(
                        f"port {port} ({service}) is in use by another process ({err.strerror}); move it "
                        f"with {key}=PORT ({key}=0: a free one), or stop what holds it"
                    ) from None

    def train(self, resume: bool, max_updates: int | None = None) -> int:
        from services.learner.driver import run_distributed

        t = self.train_config
        seeds = (
            f"{t.num_seeds} seeds ({t.seed}..{t.seed + t.num_seeds - 1})"
            if t.num_seeds > 1
            else f"seed {t.seed}"
        )
        self.say(
            f"training {t.run_name}: {t.algorithm} on {t.env.name}/{t.env.levels}, {seeds}, "
            f"{self.dist.num_actors} actors ({self.dist.mode}); Ctrl-C stops with a checkpoint"
        )
        for departure in t.not_the_papers:
            self.say(f"not the paper's method: this run {departure}")
        out = Stamped(self.out)
        metrics = self.run_dir / "metrics.jsonl"
        # the first update's row is one past the checkpoint resumed from (a resume first drops the rows after
        # it, so the file's size says nothing until the run has re-made them)
        start = self._resumed_update() if resume else 0
        heartbeat = Heartbeat(
            out.say,
            lambda s: (
                f"learner                no update yet ({s:.0f} s): compiling and collecting the first batch"
            ),
            every_s=PROGRESS_S,
            quiet_since=lambda: out.last,
            done=lambda: wrote_past(metrics, start),
        )
        with heartbeat:
            return run_distributed(
                self.train_config,
                self.dist,
                self.store,
                resume=resume,
                max_updates=max_updates,
                log_to=cast(TextIO, out),
                resume_hint=self.resume_hint,
            )

    def _resumed_update(self) -> int:
        """The update of the checkpoint a resume continues from (0 when there is none)."""
        from cec.checkpoints import CheckpointStore

        latest = CheckpointStore(self.run_dir, keep_last=1).latest()
        return latest.update if latest else 0

    def drain_evaluator(self) -> None:
        """After a finished run: waits (with a line every few seconds) until the evaluator has scored or
        given up on every checkpoint event of the run, at most `evaluator_drain_s`; a Ctrl-C stops the wait
        (the events stay in Redis for an evaluator started later)."""
        evaluator = next((s for s in self.services if s.name == "evaluator"), None)
        if evaluator is None:
            return
        from services.evaluator.config import FAILED_GROUP, FAILED_LEVEL_SET
        from services.store import ControlPlane, StoreError

        run_id, said = self.train_config.run_name, 0.0
        deadline = time.monotonic() + self.config.evaluator_drain_s
        try:
            with ControlPlane.connect(self.store) as plane:
                while True:
                    left = [
                        e.update
                        for e in plane.list_checkpoints(run_id)
                        if not plane.is_scored(e.checkpoint_id)
                        and not plane.has_result(e.checkpoint_id, FAILED_GROUP, FAILED_LEVEL_SET)
                    ]
                    why = ("" if left else "it has scored every checkpoint of the run") or (
                        "it stopped" if evaluator.proc.poll() is not None else ""
                    )
                    if not why and time.monotonic() > deadline:
                        why = f"stopped waiting after evaluator_drain_s={self.config.evaluator_drain_s:g} s"
                    if why:
                        self.say(
                            f"evaluator              {why}"
                            + (f"; not scored: updates {left}" if left else "")
                        )
                        return
                    if time.monotonic() - said >= PROGRESS_S:
                        self.say(
                            f"evaluator              scoring the run's last checkpoints: {len(left)} left "
                            f"(updates {left[0]}..{left[-1]}); Ctrl-C stops waiting"
                        )
                        said = time.monotonic()
                    time.sleep(1.0)
        except StoreError as err:
            self.say(f"evaluator              not waited for: Redis did not answer ({err})")
        except KeyboardInterrupt:
            self.say(
                "evaluator              stopped waiting: `cec evaluator` scores the rest later from Redis"
            )

    def stop(self) -> None:
        started = bool(self.services or self.ray_started or self.monitoring or self.redis)
        if self.ray_started:
            from services.learner.driver import disconnect_ray

            disconnect_ray()
        for service in reversed(self.services):
            service.stop()
        if self.ray_head_port is not None:
            forget_ray_address(self.ray_head_port)
            self.ray_head_port = None
        if self.monitoring is not None:
            self.monitoring.stop()
        if self.redis is not None:
            self.redis.stop()
        self.children.clear()
        if self.stack_file is not None:
            self.stack_file.unlink(missing_ok=True)
        if started:  # a start refused before anything started says only why
            self.say("stack stopped")


# ---- command line ---------------------------------------------------------------------------------------


def add_subcommands(sub: Any) -> None:
    up = sub.add_parser(
        "up", help="start the whole stack on this machine and train (Ctrl-C stops it cleanly)"
    )
    up.add_argument("--config", default=DEFAULT_CONFIG, help=f"stack preset (default {DEFAULT_CONFIG})")
    up.add_argument(
        "--monitoring", action="store_true", help="also start Prometheus (and Grafana if installed)"
    )
    up.add_argument("--resume", action="store_true", help="continue the run from its latest checkpoint")
    up.add_argument("--max-updates", type=int, help="stop (with a checkpoint) after this many more updates")
    override_arguments(up, "evaluator=false train.seed=3 (train.KEY=VALUE: the training preset's)", "stack")
    up.set_defaults(func=cmd_up)


def split_overrides(overrides: list[str]) -> tuple[list[str], tuple[str, ...]]:
    stack = [o for o in overrides if not o.startswith("train.")]
    train = tuple(o.removeprefix("train.") for o in overrides if o.startswith("train."))
    return stack, train


def resume_hint(args: argparse.Namespace) -> str:
    """The command that continues the run `cec up args` trains: `cec up --resume` with the same options, or
    `make up ARGS=--resume ...` when `make up` started it (which sets CEC_UP_VIA=make)."""
    options = ["--resume"]
    if args.config != DEFAULT_CONFIG:
        options += ["--config", args.config]
    if args.monitoring:
        options.append("--monitoring")
    options += args.overrides
    if os.environ.get("CEC_UP_VIA") == "make":
        return "make up ARGS=" + shlex.quote(shlex.join(options))
    return shlex.join(["cec", "up", *options])


def cmd_up(args: argparse.Namespace) -> int:
    stack_overrides, train_overrides = split_overrides(list(args.overrides))
    if args.monitoring:
        stack_overrides.append("monitoring=true")
    config = load_config(UpConfig, preset_path(args.config), stack_overrides)
    train = config.train_config(train_overrides)
    stack = Stack(config, train, resume_hint=resume_hint(args))
    with foreground_group():  # a no-op under `make up`, which took the terminal first (apps/make_up.py)
        try:
            stack.start(resume=args.resume)
            code = stack.train(resume=args.resume, max_updates=args.max_updates)
            if code == 0:
                stack.drain_evaluator()
            return code
        except KeyboardInterrupt:
            print(f"stopped; continue with: {stack.resume_hint}", file=sys.stderr)
            return 130
        finally:
            stack.stop()


def wrote_past(metrics: Path, update: int) -> bool:
    """Whether the last row of a run's `metrics.jsonl` is of an update after `update`."""
    last = last_row(metrics).get("update")
    return isinstance(last, int) and not isinstance(last, bool) and last > update
