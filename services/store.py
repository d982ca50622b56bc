"""The control plane in Redis: run registry, checkpoint event stream, partner zoo, evaluation results.

One `ControlPlane` object wraps a `redis-py` client with plain methods that take and return named records;
the learner publishes checkpoints, the evaluator consumes them through a `CheckpointConsumer` (a Redis
Streams consumer group: at-least-once, acknowledged, pending work of a dead consumer reclaimed) and writes
results keyed by checkpoint, so a restarted evaluator never scores finished work again. `LocalRedis` runs a
real `redis-server` in a directory of its own (tests, and the single-machine `cec up`).

    plane = ControlPlane.connect(StoreConfig(), outbox_dir=run_dir)        # StoreError if unreachable
    plane.register_run("cec-s0", config=cfg_dict, algorithm="cec")
    plane.publish_checkpoint(CheckpointEvent(run_id="cec-s0", update=100, ...))  # never loses it
    consumer = plane.consumer(group="evaluator", name="evaluator-0")
    for msg in consumer.read(count=1, block_s=2.0):
        ...; plane.put_result(msg.event.checkpoint_id, "zoo", "classic", {"return_mean": 41.0})
        plane.mark_scored(msg.event.checkpoint_id); consumer.ack(msg)

Key schema (`P` is `StoreConfig.key_prefix`, `cec` by default; docs/control_plane.md has the long form):

    key                         type    contents                                       writer / readers
    P:runs                      zset    run id, scored by started_at                   learner / status, UI
    P:run:<run_id>              hash    run_id algorithm status started_at             learner / status,
                                        heartbeat_at config (YAML or JSON text)          evaluator
    P:checkpoints               stream  one entry per checkpoint: checkpoint_id run_id   learner / evaluator
                                        update env_steps path sha256 algorithm seed      (consumer groups)
                                        created_at
    P:checkpoint_ids            hash    checkpoint id -> stream entry id (dedupe)      learner (publish)
    P:consumed:<group>          set     checkpoint ids the group acknowledged          consumer
    P:dead:<group>              hash    stream entry id -> JSON {reason, consumer,     consumer / operators
                                        at, fields}: entries given up on
    P:zoo                       hash    partner name -> JSON PartnerRecord             zoo tools / evaluator
    P:result:<checkpoint_id>    hash    "<partner_group>|<level_set>" -> JSON          evaluator / report,
                                        EvalResult                                       dashboards
    P:results                   zset    checkpoint ids with results, by first write    evaluator / report
    P:scored                    hash    checkpoint id -> time its evaluation finished  evaluator

A checkpoint id is `<run_id>/update_<update, 9 digits>` (the checkpoint's directory under its run).
Publishing is one Lua script (index check + XADD + index write), so a retry or a re-publish of the same
checkpoint never adds a second stream entry. When Redis cannot be reached the event goes to a local
JSON-lines outbox (`<outbox_dir>/checkpoint_outbox.jsonl`, fsynced) and is written on the next successful
call, so a Redis restart loses no checkpoint event.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import shutil
import signal
import socket
import subprocess
import tempfile
import threading
import time
import weakref
from collections.abc import Callable, Iterator, Mapping
from dataclasses import asdict, dataclass, field, fields
from functools import partial
from pathlib import Path
from typing import Any, NamedTuple, TypeVar
from urllib.parse import urlsplit, urlunsplit

import redis
import yaml
from redis.backoff import ExponentialBackoff
from redis.retry import Retry

from cec.config import ConfigError
from services.processes import free_port, terminate, with_parent_death

T = TypeVar("T")

ENV_URL = "CEC_REDIS_URL"
ENV_PASSWORD = "CEC_REDIS_PASSWORD"
DEFAULT_URL = "redis://127.0.0.1:6379/0"
RUN_STATUSES = ("starting", "running", "interrupted", "finished", "failed")
DEFAULT_GROUP = "evaluator"
OUTBOX_FILE = "checkpoint_outbox.jsonl"
MIN_REDIS_VERSION = (6, 2)  # XPENDING IDLE, SMISMEMBER
INSTALL_HINT = (
    "to install it: `sudo apt-get install redis-server` (Debian/Ubuntu), `brew install redis` (macOS)"
)


class StoreError(RuntimeError):
    """The control plane cannot do what was asked; the message names the cause and the fix."""


class StoreUnavailableError(StoreError):
    """Redis cannot be reached (down, restarting, wrong address or a network failure)."""


# --- configuration -----------------------------------------------------------------------------------------


@dataclass(frozen=True)
class StoreConfig:
    """Where the control plane lives and how hard to try reaching it.

    Attributes:
        url: `redis://[:password@]host:port/db` (or `rediss://` for TLS, `unix:///path.sock`). Empty: the
            environment variable CEC_REDIS_URL, else redis://127.0.0.1:6379/0. (`cec up` starts its own
            Redis when neither is given.)
        password: Redis password (`requirepass`). Empty: a password in the URL, else the environment
            variable CEC_REDIS_PASSWORD, else none. Prefer the environment variable over a config file.
        key_prefix: prefix of every key (`<prefix>:runs`, ...); separate deployments may share one Redis.
        connect_timeout_s: time allowed to open a connection.
        socket_timeout_s: time allowed for one command's reply (blocking reads are kept below it).
        retries: retries of a command after a connection error or timeout, with exponential backoff.
        retry_backoff_s: first backoff between retries (doubled each retry).
        retry_backoff_max_s: longest backoff between retries.
        claim_idle_s: a checkpoint event delivered to a consumer and not acknowledged for this long is
            handed to another consumer of the group (its consumer is presumed dead). Consumers that work
            longer on one event call `CheckpointConsumer.touch` to keep it.
        max_deliveries: an event delivered this many times without an acknowledgement is given up on
            (moved to `<prefix>:dead:<group>`), so one poison event cannot stall a group forever.
    """

    url: str = ""
    password: str = ""
    key_prefix: str = "cec"
    connect_timeout_s: float = 2.0
    socket_timeout_s: float = 5.0
    retries: int = 3
    retry_backoff_s: float = 0.05
    retry_backoff_max_s: float = 1.0
    claim_idle_s: float = 600.0
    max_deliveries: int = 5

    def __post_init__(self) -> None:
        if self.url and urlsplit(self.url).scheme not in ("redis", "rediss", "unix"):
            raise ConfigError(
                f"store url {self.url!r} must start with redis://, rediss:// or unix:// (e.g. {DEFAULT_URL})"
            )
        if not self.key_prefix or any(c.isspace() for c in self.key_prefix) or self.key_prefix.endswith(":"):
            raise ConfigError(
                f"store key_prefix {self.key_prefix!r} must be non-empty, without spaces or a trailing ':'"
            )
        for name in ("connect_timeout_s", "socket_timeout_s", "claim_idle_s"):
            if getattr(self, name) <= 0:
                raise ConfigError(f"store {name} must be > 0, got {getattr(self, name)}")
        if self.retries < 0 or self.retry_backoff_s < 0 or self.retry_backoff_max_s < 0:
            raise ConfigError("store retries, retry_backoff_s and retry_backoff_max_s must be >= 0")
        if self.max_deliveries < 1:
            raise ConfigError(f"store max_deliveries must be >= 1, got {self.max_deliveries}")

    @property
    def url_given(self) -> bool:
        """Whether a URL was set (here or in CEC_REDIS_URL) rather than left to the default."""
        return bool(self.url or os.environ.get(ENV_URL))

    @property
    def resolved_url(self) -> str:
        """The URL used: `url`, else CEC_REDIS_URL, else the default."""
        return self.url or os.environ.get(ENV_URL) or DEFAULT_URL

    @property
    def resolved_password(self) -> str:
        """The password used ('' = none): `password`, else the URL's, else CEC_REDIS_PASSWORD."""
        return self.password or urlsplit(self.resolved_url).password or os.environ.get(ENV_PASSWORD, "")

    @property
    def display_url(self) -> str:
        """The URL with any password masked, for messages and logs."""
        return redact_url(self.resolved_url)


def redact_url(url: str) -> str:
    """`url` with the password (if any) replaced by `***`."""
    parts = urlsplit(url)
    if parts.password is None:
        return url
    netloc = parts.netloc.rsplit("@", 1)
    user = parts.username or ""
    return urlunsplit(parts._replace(netloc=f"{user}:***@{netloc[-1]}"))


# --- records -----------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RunRecord:
    """A training run in the registry.

    Attributes:
        run_id: the run's name (its directory under `run_dir`).
        algorithm: `cec`, `ippo`, ...
        status: one of RUN_STATUSES.
        started_at: Unix time of the first registration (a resumed run keeps it).
        heartbeat_at: Unix time of the last heartbeat (or registration).
        config: the run's configuration as YAML or JSON text (`config_dict()` parses it).
    """

    run_id: str
    algorithm: str
    status: str
    started_at: float
    heartbeat_at: float
    config: str

    def config_dict(self) -> dict[str, Any]:
        data = yaml.safe_load(self.config) if self.config else {}
        return dict(data) if isinstance(data, Mapping) else {}


def checkpoint_id(run_id: str, update: int) -> str:
    """The id of a run's checkpoint after `update` updates: `<run_id>/update_<9 digits>`."""
    return f"{run_id}/update_{update:09d}"


@dataclass(frozen=True)
class CheckpointEvent:
    """A checkpoint was written (the fields of `meta.json` a consumer needs before opening it).

    Attributes:
        run_id: the run that wrote it.
        update: PPO updates done when it was saved.
        env_steps: joint environment steps per seed when it was saved.
        path: checkpoint directory (as the learner's machine sees it).
        sha256: checksum of `state.msgpack` (from `meta.json`).
        algorithm: the run's algorithm.
        seed: the run's base seed (seed i of a multi-seed checkpoint is `seed + i`).
        created_at: Unix time it was written.
    """

    run_id: str
    update: int
    env_steps: int
    path: str
    sha256: str
    algorithm: str
    seed: int
    created_at: float

    @property
    def checkpoint_id(self) -> str:
        return checkpoint_id(self.run_id, self.update)

    @classmethod
    def from_checkpoint(cls, path: str | Path, run_id: str) -> CheckpointEvent:
        """The event of a checkpoint directory written by `cec.checkpoints.save` (from its `meta.json`)."""
        from cec import checkpoints  # imports JAX; only the learner needs this

        meta = checkpoints.read_meta(path)
        info, config = meta.get("metadata", {}), meta.get("config", {})
        seeds = info.get("seeds") or [config.get("seed", 0)]
        return cls(
            run_id=run_id,
            update=int(meta["update"]),
            env_steps=int(meta["env_steps"]),
            path=str(path),
            sha256=str(meta["sha256"]),
            algorithm=str(info.get("algorithm", config.get("algorithm", ""))),
            seed=int(seeds[0]),
            created_at=(Path(path) / checkpoints.META_FILE).stat().st_mtime,
        )

    def to_fields(self) -> dict[str, str]:
        """The stream entry: every field as text, plus `checkpoint_id`."""
        out = {"checkpoint_id": self.checkpoint_id}
        out.update({k: repr(v) if isinstance(v, float) else str(v) for k, v in asdict(self).items()})
        return out

    @classmethod
    def from_fields(cls, data: Mapping[str, Any]) -> CheckpointEvent:
        """Parses a stream entry or outbox record; ValueError names what is missing or malformed."""
        kinds = {f.name: f.type for f in fields(cls)}
        missing = [k for k in kinds if k not in data]
        if missing:
            raise ValueError(f"checkpoint event lacks {', '.join(missing)}")
        try:
            event = cls(
                run_id=str(data["run_id"]),
                update=int(data["update"]),
                env_steps=int(data["env_steps"]),
                path=str(data["path"]),
                sha256=str(data["sha256"]),
                algorithm=str(data["algorithm"]),
                seed=int(data["seed"]),
                created_at=float(data["created_at"]),
            )
        except (TypeError, ValueError) as err:
            raise ValueError(f"malformed checkpoint event: {err}") from err
        if "checkpoint_id" in data and data["checkpoint_id"] != event.checkpoint_id:
            raise ValueError(f"checkpoint_id {data['checkpoint_id']!r} does not match run_id and update")
        return event


class PublishResult(NamedTuple):
    """What `publish_checkpoint` did.

    outcome: `published` (a new stream entry), `duplicate` (that checkpoint id was published before;
    `entry_id` is the first entry) or `queued` (Redis unreachable; the event waits in the outbox).
    """

    checkpoint_id: str
    outcome: str
    entry_id: str | None


class FlushResult(NamedTuple):
    """What `flush_outbox` did: events now in Redis (`published` or found `duplicate`), events left."""

    delivered: int
    remaining: int


@dataclass(frozen=True)
class CheckpointMessage:
    """A checkpoint event delivered to a consumer; acknowledge it with `CheckpointConsumer.ack`.

    Attributes:
        entry_id: the stream entry id.
        event: the checkpoint event.
        redelivered: it was delivered before (to this consumer before a restart, or to a dead one).
    """

    entry_id: str
    event: CheckpointEvent
    redelivered: bool = False


@dataclass(frozen=True)
class PartnerRecord:
    """One partner of the zoo.

    Attributes:
        name: unique label (`ippo_cramped_room_s0`, `fcp_s1`, ...).
        algorithm: how it was trained (`ippo`, `fcp`, `e3t`, `cec`, `cec_finetune`, ...).
        seed: its training seed.
        env: the environment and levels it was trained on (`overcooked:cramped_room`,
            `overcooked:procedural`, `dual_destination:fixed`, ...).
        env_steps: environment steps it was trained for.
        path: its checkpoint directory.
        sha256: checksum of the checkpoint's `state.msgpack`.
        added_at: Unix time it was added (set by `add_partner` when 0).
    """

    name: str
    algorithm: str
    seed: int
    env: str
    env_steps: int
    path: str
    sha256: str
    added_at: float = 0.0


@dataclass(frozen=True)
class EvalResult:
    """Scores of one checkpoint against one partner group on one level set.

    Attributes:
        checkpoint_id: the scored checkpoint.
        partner_group: which partners (`zoo`, `self`, `ippo`, a partner name, ...).
        level_set: which levels (`classic`, `heldout`, `cramped_room`, ...).
        metrics: JSON values by name (`return_mean`, `return_iqm`, `episodes`, ...).
        written_at: Unix time of the (last) write.
    """

    checkpoint_id: str
    partner_group: str
    level_set: str
    metrics: dict[str, Any] = field(default_factory=dict)
    written_at: float = 0.0


# --- the control plane -------------------------------------------------------------------------------------

# Publishes a checkpoint event once: KEYS = (index hash, stream); ARGV = (checkpoint id, field, value, ...).
_PUBLISH_LUA = """
local existing = redis.call('HGET', KEYS[1], ARGV[1])
if existing then return {0, existing} end
local entry = {}
for i = 2, #ARGV do entry[#entry + 1] = ARGV[i] end
local id = redis.call('XADD', KEYS[2], '*', unpack(entry))
redis.call('HSET', KEYS[1], ARGV[1], id)
return {1, id}
"""

# Sets hash fields only if the hash exists: KEYS = (hash,); ARGV = (field, value, ...). Returns 0 or 1.
_UPDATE_LUA = """
if redis.call('EXISTS', KEYS[1]) == 0 then return 0 end
redis.call('HSET', KEYS[1], unpack(ARGV))
return 1
"""


def _check_name(value: str, what: str) -> str:
    if not isinstance(value, str) or not value or len(value) > 200:
        raise ValueError(f"{what} must be a non-empty string of at most 200 characters, got {value!r}")
    if any(c.isspace() or not c.isprintable() or c == "|" for c in value):
        raise ValueError(f"{what} {value!r} must not contain spaces, control characters or '|'")
    return value


def _redis_version(info: Mapping[str, Any]) -> tuple[int, ...]:
    try:
        return tuple(int(p) for p in str(info.get("redis_version", "0")).split(".")[:2])
    except ValueError:
        return (0,)


class ControlPlane:
    """Run registry, checkpoint events, partner zoo and evaluation results in one Redis.

    Every method raises `StoreError` (`StoreUnavailableError` when Redis cannot be reached) with a message
    that names the URL and the fix; `publish_checkpoint` instead queues the event in the outbox when Redis
    is unreachable. Thread-safe (one connection pool per object).

    Args:
        config: where Redis is and how to reach it.
        outbox_dir: directory for checkpoint events that could not be written yet (the run directory);
            None: `publish_checkpoint` raises when Redis is unreachable.
    """

    def __init__(self, config: StoreConfig | None = None, *, outbox_dir: str | Path | None = None) -> None:
        self.config = config or StoreConfig()
        self.outbox_dir = Path(outbox_dir) if outbox_dir is not None else None
        c = self.config
        try:
            pool = redis.ConnectionPool.from_url(
                c.resolved_url,
                decode_responses=True,
                protocol=2,
                socket_connect_timeout=c.connect_timeout_s,
                socket_timeout=c.socket_timeout_s,
                retry=Retry(ExponentialBackoff(cap=c.retry_backoff_max_s, base=c.retry_backoff_s), c.retries),
                retry_on_error=[redis.ConnectionError, redis.TimeoutError],
            )
        except ValueError as err:
            raise StoreError(
                f"Redis URL {c.display_url!r} is malformed ({err}); use redis://host:port/db "
                f"(set it with the store url or {ENV_URL})"
            ) from err
        # The URL's own password wins inside redis-py; the documented order is config, URL, environment.
        pool.connection_kwargs["password"] = c.resolved_password or None
        # redis-py annotates results as `T | Awaitable[T]` (one API for sync and async); this client is sync.
        self._r: Any = redis.Redis(connection_pool=pool)
        self._publish = self._r.register_script(_PUBLISH_LUA)
        self._update = self._r.register_script(_UPDATE_LUA)
        self._outbox_lock = threading.Lock()

    @classmethod
    def connect(
        cls, config: StoreConfig | None = None, *, outbox_dir: str | Path | None = None
    ) -> ControlPlane:
        """A control plane whose Redis answered (`check()`): the start-up path of every service."""
        plane = cls(config, outbox_dir=outbox_dir)
        try:
            plane.check()
        except BaseException:
            plane.close()
            raise
        return plane

    def close(self) -> None:
        self._r.close()
        self._r.connection_pool.disconnect()

    def __enter__(self) -> ControlPlane:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- keys ---------------------------------------------------------------------------------------------

    def key(self, *parts: str) -> str:
        """`<prefix>:<part>:<part>...`, the name of a key of this control plane."""
        return ":".join((self.config.key_prefix, *parts))

    @property
    def stream_key(self) -> str:
        return self.key("checkpoints")

    # --- errors -------------------------------------------------------------------------------------------

    def _unreachable(self, err: BaseException) -> StoreUnavailableError:
        return StoreUnavailableError(
            f"cannot reach Redis at {self.config.display_url} ({err}). Start a Redis server there "
            f"(`redis-server`; {INSTALL_HINT}), or point the control plane at a running one: set the "
            f"store url or {ENV_URL}=redis://host:port/db"
        )

    def _auth_failed(self, err: BaseException) -> StoreError:
        return StoreError(
            f"Redis at {self.config.display_url} refused the credentials ({err}). Set the password that "
            f"matches its `requirepass` with the store password or {ENV_PASSWORD} (or none if it has none)"
        )

    def _call(self, what: str, fn: Callable[[], T]) -> T:
        """Runs `fn` (Redis commands), translating redis-py errors into StoreError."""
        try:
            return fn()
        except (redis.AuthenticationError, redis.exceptions.NoPermissionError) as err:
            raise self._auth_failed(err) from err
        except (redis.ConnectionError, redis.TimeoutError) as err:
            raise self._unreachable(err) from err
        except redis.ResponseError as err:
            if str(err).startswith(("NOAUTH", "WRONGPASS")):
                raise self._auth_failed(err) from err
            raise StoreError(f"Redis at {self.config.display_url} failed to {what}: {err}") from err
        except redis.RedisError as err:
            raise StoreError(f"Redis at {self.config.display_url} failed to {what}: {err}") from err

    # --- health -------------------------------------------------------------------------------------------

    def check(self) -> str:
        """Pings Redis and checks its version; returns the version. StoreError (naming the fix) otherwise."""
        self._call("answer PING", self._r.ping)
        info = self._call("report its version", lambda: self._r.info("server"))
        version = _redis_version(info)
        if version < MIN_REDIS_VERSION:
            raise StoreError(
                f"Redis at {self.config.display_url} is version {info.get('redis_version')}; the control "
                f"plane needs >= {'.'.join(map(str, MIN_REDIS_VERSION))} (streams with XPENDING IDLE). "
                f"Upgrade it; {INSTALL_HINT}"
            )
        return str(info.get("redis_version", ""))

    def ping(self) -> bool:
        """True if Redis answers now (never raises)."""
        try:
            return bool(self._r.ping())
        except redis.RedisError:
            return False

    # --- run registry -------------------------------------------------------------------------------------

    def register_run(
        self,
        run_id: str,
        *,
        config: Mapping[str, Any] | str,
        algorithm: str,
        started_at: float | None = None,
        status: str = "running",
    ) -> RunRecord:
        """Adds (or, for a resumed run, updates) a run. A re-registration keeps the first `started_at`."""
        _check_name(run_id, "run_id")
        self._check_status(status)
        text = config if isinstance(config, str) else json.dumps(dict(config), sort_keys=True, default=str)
        now = time.time()
        start = now if started_at is None else float(started_at)
        key = self.key("run", run_id)

        def write() -> None:
            with self._r.pipeline(transaction=True) as p:
                p.hsetnx(key, "started_at", repr(start))
                p.hset(
                    key,
                    mapping={
                        "run_id": run_id,
                        "algorithm": algorithm,
                        "status": status,
                        "heartbeat_at": repr(now),
                        "config": text,
                    },
                )
                p.zadd(self.key("runs"), {run_id: start}, nx=True)
                p.execute()

        self._call("register a run", write)
        record = self.get_run(run_id)
        assert record is not None
        return record

    def set_run_status(self, run_id: str, status: str) -> None:
        """Sets a registered run's status (one of RUN_STATUSES); also a heartbeat."""
        self._check_status(status)
        self._update_run(run_id, "status", status, "heartbeat_at", repr(time.time()))

    def heartbeat(self, run_id: str, at: float | None = None) -> None:
        """Records that a registered run is alive (at `at`, default now)."""
        self._update_run(run_id, "heartbeat_at", repr(time.time() if at is None else float(at)))

    def get_run(self, run_id: str) -> RunRecord | None:
        data = self._call("read a run", lambda: self._r.hgetall(self.key("run", run_id)))
        return self._run_record(data) if data else None

    def list_runs(self) -> list[RunRecord]:
        """Every registered run, oldest start first."""
        ids = self._call("list runs", lambda: self._r.zrange(self.key("runs"), 0, -1))

        def read() -> list[dict[str, str]]:
            with self._r.pipeline(transaction=False) as p:
                for run_id in ids:
                    p.hgetall(self.key("run", run_id))
                return list(p.execute())

        return [self._run_record(d) for d in self._call("read runs", read) if d]

    def _update_run(self, run_id: str, *pairs: str) -> None:
        _check_name(run_id, "run_id")
        if not self._call(
            "update a run", lambda: self._update(keys=[self.key("run", run_id)], args=list(pairs))
        ):
            raise StoreError(f"run {run_id!r} is not registered; call register_run first")

    @staticmethod
    def _check_status(status: str) -> None:
        if status not in RUN_STATUSES:
            raise ValueError(f"run status {status!r} is unknown; use one of {list(RUN_STATUSES)}")

    @staticmethod
    def _run_record(data: Mapping[str, str]) -> RunRecord:
        return RunRecord(
            run_id=data.get("run_id", ""),
            algorithm=data.get("algorithm", ""),
            status=data.get("status", ""),
            started_at=float(data.get("started_at", 0.0)),
            heartbeat_at=float(data.get("heartbeat_at", 0.0)),
            config=data.get("config", ""),
        )

    # --- checkpoint events: publishing --------------------------------------------------------------------

    def publish_checkpoint(self, event: CheckpointEvent) -> PublishResult:
        """Adds a checkpoint event to the stream once per checkpoint id; never loses it.

        Events waiting in the outbox go first (their order is kept). If Redis cannot be reached, the event
        is appended to the outbox (`outcome == "queued"`); if Redis refuses (credentials, errors), it is
        queued too and StoreError is raised. Without an outbox directory, StoreError is raised.
        """
        _check_name(event.run_id, "run_id")
        try:
            self.flush_outbox(raise_errors=True)
            return self._publish_now(event)
        except StoreUnavailableError:
            if self.outbox_dir is None:
                raise
            self._append_outbox(event)
            return PublishResult(event.checkpoint_id, "queued", None)
        except StoreError:
            if self.outbox_dir is not None:
                self._append_outbox(event)
            raise

    def _publish_now(self, event: CheckpointEvent) -> PublishResult:
        args: list[str] = [event.checkpoint_id]
        for k, v in event.to_fields().items():
            args += [k, v]
        keys = [self.key("checkpoint_ids"), self.stream_key]
        created, entry_id = self._call("publish a checkpoint", lambda: self._publish(keys=keys, args=args))
        return PublishResult(event.checkpoint_id, "published" if created else "duplicate", str(entry_id))

    def get_checkpoint(self, checkpoint_id: str) -> CheckpointEvent | None:
        """The published event of a checkpoint id (None if it was never published)."""
        entry_id = self._call(
            "read the checkpoint index", lambda: self._r.hget(self.key("checkpoint_ids"), checkpoint_id)
        )
        if entry_id is None:
            return None
        entries = self._call(
            "read a checkpoint event", lambda: self._r.xrange(self.stream_key, entry_id, entry_id)
        )
        return CheckpointEvent.from_fields(entries[0][1]) if entries else None

    def list_checkpoints(self, run_id: str | None = None) -> list[CheckpointEvent]:
        """Published checkpoint events in publication order (of one run, or all); skips malformed ones."""
        out: list[CheckpointEvent] = []
        start = "-"
        while True:
            page = self._call(
                "read checkpoint events", partial(self._r.xrange, self.stream_key, start, "+", count=500)
            )
            for _entry_id, data in page:
                with contextlib.suppress(ValueError):
                    event = CheckpointEvent.from_fields(data)
                    if run_id is None or event.run_id == run_id:
                        out.append(event)
            if len(page) < 500:
                return out
            start = "(" + page[-1][0]

    # --- checkpoint events: the outbox --------------------------------------------------------------------

    @property
    def outbox_path(self) -> Path | None:
        return self.outbox_dir / OUTBOX_FILE if self.outbox_dir is not None else None

    @contextlib.contextmanager
    def _locked_outbox(self) -> Iterator[Path]:
        path = self.outbox_path
        assert path is not None
        path.parent.mkdir(parents=True, exist_ok=True)
        with self._outbox_lock, open(path.with_name(path.name + ".lock"), "a") as lock:
            fcntl.flock(lock, fcntl.LOCK_EX)  # other processes writing to the same run directory
            try:
                yield path
            finally:
                fcntl.flock(lock, fcntl.LOCK_UN)

    def _append_outbox(self, event: CheckpointEvent) -> None:
        line = json.dumps(asdict(event), sort_keys=True) + "\n"
        with self._locked_outbox() as path, open(path, "a") as fh:
            fh.write(line)
            fh.flush()
            os.fsync(fh.fileno())

    def pending_outbox(self) -> list[CheckpointEvent]:
        """Events waiting in the outbox, oldest first (unreadable lines are skipped)."""
        if self.outbox_path is None or not self.outbox_path.exists():
            return []
        with self._locked_outbox() as path:
            return [e for e, _ in self._read_outbox(path) if e is not None]

    @staticmethod
    def _read_outbox(path: Path) -> list[tuple[CheckpointEvent | None, str]]:
        out: list[tuple[CheckpointEvent | None, str]] = []
        for line in path.read_text().splitlines():
            if not line.strip():
                continue
            try:
                out.append((CheckpointEvent.from_fields(json.loads(line)), line))
            except (ValueError, TypeError, AttributeError):
                out.append((None, line))  # e.g. a line cut short by a crash while appending
        return out

    def flush_outbox(self, *, raise_errors: bool = False) -> FlushResult:
        """Writes outbox events to Redis, oldest first; delivered ones leave the outbox.

        If Redis is unreachable, the rest stay queued (`remaining > 0`); StoreError is raised only for
        other failures, or for any failure with `raise_errors`. Unreadable lines move to
        `checkpoint_outbox.rejected.jsonl` next to the outbox.
        """
        path = self.outbox_path
        if path is None or not path.exists():
            return FlushResult(0, 0)
        with self._locked_outbox() as path:
            items = self._read_outbox(path)
            if not items:
                return FlushResult(0, 0)
            delivered, error = 0, None
            for event, _line in items:
                if event is None:
                    delivered += 1
                    continue
                try:
                    self._publish_now(event)
                except StoreError as err:
                    error = err
                    break
                delivered += 1
            rest = [line for _, line in items[delivered:]]
            bad = [line for event, line in items[:delivered] if event is None]
            if bad:
                with open(path.with_name("checkpoint_outbox.rejected.jsonl"), "a") as fh:
                    fh.write("\n".join(bad) + "\n")
            self._rewrite(path, rest)
        if error is not None and (raise_errors or not isinstance(error, StoreUnavailableError)):
            raise error
        return FlushResult(sum(1 for e, _ in items[:delivered] if e is not None), len(rest))

    @staticmethod
    def _rewrite(path: Path, lines: list[str]) -> None:
        if not lines:
            path.unlink(missing_ok=True)
            return
        tmp = path.with_name(path.name + ".tmp")
        with open(tmp, "w") as fh:
            fh.write("\n".join(lines) + "\n")
            fh.flush()
            os.fsync(fh.fileno())
        tmp.replace(path)

    # --- checkpoint events: consuming ---------------------------------------------------------------------

    def consumer(
        self, group: str = DEFAULT_GROUP, name: str | None = None, *, from_start: bool = True
    ) -> CheckpointConsumer:
        """A consumer of the checkpoint stream in consumer group `group` (created if missing).

        `name` identifies the consumer within the group; keep it stable across restarts of one process
        (e.g. `evaluator-0`) so that a restart resumes its own unacknowledged events at once (default:
        `<host>-<pid>`). A new group starts at the first event (`from_start`) or at new events only.
        """
        return CheckpointConsumer(self, group, name or f"{socket.gethostname()}-{os.getpid()}", from_start)

    # --- partner zoo --------------------------------------------------------------------------------------

    def add_partner(self, partner: PartnerRecord) -> bool:
        """Adds or replaces a zoo partner (by name); True if the name is new."""
        _check_name(partner.name, "partner name")
        if not partner.added_at:
            partner = PartnerRecord(**{**asdict(partner), "added_at": time.time()})
        text = json.dumps(asdict(partner), sort_keys=True)
        return bool(
            self._call("add a zoo partner", lambda: self._r.hset(self.key("zoo"), partner.name, text))
        )

    def get_partner(self, name: str) -> PartnerRecord | None:
        text = self._call("read a zoo partner", lambda: self._r.hget(self.key("zoo"), name))
        return PartnerRecord(**json.loads(text)) if text else None

    def list_partners(self) -> list[PartnerRecord]:
        """The zoo, sorted by name."""
        data = self._call("read the zoo", lambda: self._r.hgetall(self.key("zoo")))
        return [PartnerRecord(**json.loads(data[n])) for n in sorted(data)]

    def remove_partner(self, name: str) -> bool:
        """Removes a partner; True if it was there."""
        return bool(self._call("remove a zoo partner", lambda: self._r.hdel(self.key("zoo"), name)))

    # --- evaluation results -------------------------------------------------------------------------------

    def put_result(
        self, checkpoint_id: str, partner_group: str, level_set: str, metrics: Mapping[str, Any]
    ) -> bool:
        """Writes the result of (checkpoint, partner group, level set), replacing an earlier one.

        Idempotent: one record per key however often it is written. True if the key is new. `metrics`
        must be JSON-serialisable.
        """
        for value, what in ((partner_group, "partner_group"), (level_set, "level_set")):
            _check_name(value, what)
        now = time.time()
        record = EvalResult(checkpoint_id, partner_group, level_set, dict(metrics), now)
        try:
            text = json.dumps(asdict(record), sort_keys=True)
        except (TypeError, ValueError) as err:
            raise ValueError(f"metrics of {checkpoint_id} must be JSON-serialisable: {err}") from err

        def write() -> Any:
            with self._r.pipeline(transaction=True) as p:
                p.hset(self.key("result", checkpoint_id), f"{partner_group}|{level_set}", text)
                p.zadd(self.key("results"), {checkpoint_id: now}, nx=True)
                return p.execute()[0]

        return bool(self._call("write a result", write))

    def has_result(self, checkpoint_id: str, partner_group: str, level_set: str) -> bool:
        """Whether that result was written (a restarted evaluator skips it)."""
        key = self.key("result", checkpoint_id)
        return bool(self._call("read a result", lambda: self._r.hexists(key, f"{partner_group}|{level_set}")))

    def get_results(self, checkpoint_id: str) -> list[EvalResult]:
        """Every result of a checkpoint, sorted by partner group and level set."""
        data = self._call("read results", lambda: self._r.hgetall(self.key("result", checkpoint_id)))
        return [self._result(data[k]) for k in sorted(data)]

    def list_results(self) -> list[EvalResult]:
        """Every result, by checkpoint (in order of their first result), partner group and level set."""
        ids = self._call("list results", lambda: self._r.zrange(self.key("results"), 0, -1))

        def read() -> list[dict[str, str]]:
            with self._r.pipeline(transaction=False) as p:
                for cid in ids:
                    p.hgetall(self.key("result", cid))
                return list(p.execute())

        return [self._result(d[k]) for d in self._call("read results", read) for k in sorted(d)]

    def mark_scored(self, checkpoint_id: str) -> None:
        """Records that the evaluation of a checkpoint is complete (all its results are written)."""
        self._call(
            "mark a checkpoint scored",
            lambda: self._r.hset(self.key("scored"), checkpoint_id, repr(time.time())),
        )

    def is_scored(self, checkpoint_id: str) -> bool:
        """Whether `mark_scored` was called for this checkpoint."""
        return bool(
            self._call("read scored checkpoints", lambda: self._r.hexists(self.key("scored"), checkpoint_id))
        )

    def list_scored(self) -> dict[str, float]:
        """Scored checkpoint ids and when their evaluation finished."""
        data = self._call("read scored checkpoints", lambda: self._r.hgetall(self.key("scored")))
        return {k: float(v) for k, v in data.items()}

    @staticmethod
    def _result(text: str) -> EvalResult:
        return EvalResult(**json.loads(text))


class CheckpointConsumer:
    """One consumer of the checkpoint stream in a Redis consumer group: at-least-once delivery.

    `read()` returns, in this order: events delivered to this consumer name before (a restart), events
    another consumer left unacknowledged for `claim_idle_s` (it died), then new events. Acknowledge each
    with `ack()` once its work is stored; an event is delivered again until then. Events the group already
    acknowledged under the same checkpoint id are skipped (and acknowledged), and events that are
    malformed or were delivered `max_deliveries` times are moved to `<prefix>:dead:<group>`.
    """

    def __init__(self, plane: ControlPlane, group: str, name: str, from_start: bool = True) -> None:
        self.plane = plane
        self.group = _check_name(group, "consumer group")
        self.name = _check_name(name, "consumer name")
        self._r = plane._r
        self._stream = plane.stream_key
        self._consumed = plane.key("consumed", group)
        self._dead = plane.key("dead", group)
        self._claim_idle_ms = int(plane.config.claim_idle_s * 1000)
        self._replay_from: str | None = "0"  # own unacknowledged events, read once after start
        self.ensure_group(from_start)

    def ensure_group(self, from_start: bool = True) -> None:
        """Creates the consumer group (and the stream) if missing."""
        try:
            self.plane._call(
                "create a consumer group",
                lambda: self._r.xgroup_create(
                    self._stream, self.group, id="0" if from_start else "$", mkstream=True
                ),
            )
        except StoreError as err:
            if "BUSYGROUP" not in str(err):
                raise

    def read(self, count: int = 1, block_s: float = 0.0) -> list[CheckpointMessage]:
        """Up to `count` events to work on; waits up to `block_s` for new ones (kept below the socket
        timeout). After a Redis restart that lost the group, the group is created again."""
        if count < 1:
            raise ValueError(f"count must be >= 1, got {count}")
        try:
            return self._read(count, block_s)
        except StoreError as err:
            if "NOGROUP" not in str(err):
                raise
            self.ensure_group()
            return self._read(count, block_s)

    def _read(self, count: int, block_s: float) -> list[CheckpointMessage]:
        if self._replay_from is not None:
            entries = self._xreadgroup(self._replay_from, count, None)
            if entries:
                self._replay_from = entries[-1][0]
                return self._accept(entries, redelivered=True)
            self._replay_from = None
        claimed = self._reclaim(count)
        if claimed:
            return self._accept(claimed, redelivered=True)
        limit = 0.8 * self.plane.config.socket_timeout_s
        block_ms = int(min(block_s, limit) * 1000) if block_s > 0 else None
        return self._accept(self._xreadgroup(">", count, block_ms), redelivered=False)

    def _xreadgroup(self, start: str, count: int, block_ms: int | None) -> list[tuple[str, Any]]:
        reply = self.plane._call(
            "read checkpoint events",
            lambda: self._r.xreadgroup(
                self.group, self.name, {self._stream: start}, count=count, block=block_ms
            ),
        )
        return [(entry_id, data) for _stream, entries in reply or [] for entry_id, data in entries]

    def _reclaim(self, count: int) -> list[tuple[str, Any]]:
        stale = self.plane._call(
            "list pending checkpoint events",
            lambda: self._r.xpending_range(
                self._stream, self.group, "-", "+", count, idle=self._claim_idle_ms
            ),
        )
        if not stale:
            return []
        limit = self.plane.config.max_deliveries
        for p in stale:
            if p["times_delivered"] >= limit:
                self._bury(p["message_id"], f"delivered {p['times_delivered']} times without an ack", None)
        ids = [p["message_id"] for p in stale if p["times_delivered"] < limit]
        if not ids:
            return []
        claimed = self.plane._call(
            "claim pending checkpoint events",
            lambda: self._r.xclaim(self._stream, self.group, self.name, self._claim_idle_ms, ids),
        )
        return [(entry_id, data) for entry_id, data in claimed]

    def _accept(self, entries: list[tuple[str, Any]], redelivered: bool) -> list[CheckpointMessage]:
        messages: list[CheckpointMessage] = []
        for entry_id, data in entries:
            try:
                if not data:
                    raise ValueError("the stream entry was deleted")
                messages.append(CheckpointMessage(entry_id, CheckpointEvent.from_fields(data), redelivered))
            except ValueError as err:
                self._bury(entry_id, str(err), data)
        if not messages:
            return []
        ids = [m.event.checkpoint_id for m in messages]
        seen = self.plane._call("read consumed checkpoints", lambda: self._r.smismember(self._consumed, ids))
        fresh: list[CheckpointMessage] = []
        skip: list[str] = []
        for message, done in zip(messages, seen, strict=True):
            # Another entry of the same checkpoint: already handled by the group, or earlier in this batch
            # (that one stays pending until acknowledged, so dropping this copy keeps at-least-once).
            if done or any(m.event.checkpoint_id == message.event.checkpoint_id for m in fresh):
                skip.append(message.entry_id)
            else:
                fresh.append(message)
        if skip:
            self.plane._call(
                "acknowledge duplicate events", partial(self._r.xack, self._stream, self.group, *skip)
            )
        return fresh

    def _bury(self, entry_id: str, reason: str, data: Any) -> None:
        record = json.dumps(
            {"reason": reason, "consumer": self.name, "at": time.time(), "fields": data or {}}
        )

        def write() -> None:
            with self._r.pipeline(transaction=True) as p:
                p.hset(self._dead, entry_id, record)
                p.xack(self._stream, self.group, entry_id)
                p.execute()

        self.plane._call("move an event to the dead letters", write)

    def ack(self, message: CheckpointMessage) -> None:
        """Marks the event done for this group (its checkpoint id too, so duplicates are skipped)."""

        def write() -> None:
            with self._r.pipeline(transaction=True) as p:
                p.xack(self._stream, self.group, message.entry_id)
                p.sadd(self._consumed, message.event.checkpoint_id)
                p.execute()

        self.plane._call("acknowledge an event", write)

    def touch(self, message: CheckpointMessage) -> None:
        """Keeps an event being worked on from being reclaimed by another consumer (resets its idle time)."""
        self.plane._call(
            "keep a pending event",
            lambda: self._r.xclaim(self._stream, self.group, self.name, 0, [message.entry_id], justid=True),
        )

    def pending_count(self) -> int:
        """Events of the group delivered and not acknowledged (all consumers)."""
        summary = self.plane._call("count pending events", lambda: self._r.xpending(self._stream, self.group))
        return int(summary["pending"])

    def dead_letters(self) -> dict[str, dict[str, Any]]:
        """Events the group gave up on, by stream entry id: {reason, consumer, at, fields}."""
        data = self.plane._call("read dead letters", lambda: self._r.hgetall(self._dead))
        return {k: json.loads(v) for k, v in data.items()}


# --- a local redis-server ----------------------------------------------------------------------------------


class LocalRedis:
    """A real `redis-server` on loopback, in a directory of its own, with append-only persistence.

    Every write is fsynced to the append-only file, so `restart()` (even after `stop(kill=True)`) brings
    back all data, on the same port. Used by tests and by `cec up` when no Redis URL is given.

        with LocalRedis() as server:
            plane = ControlPlane.connect(server.config())

    Args:
        data_dir: where the server keeps its files (None: a temporary directory, removed on exit).
        port: TCP port (0: a free one, kept across restarts).
        password: `requirepass` ('' = none); written to a 0600 config file, not the command line.
        host: bind address.
        executable: the redis-server binary (name on PATH or path).
        start_timeout_s: time allowed for the server to answer PING.
    """

    def __init__(
        self,
        data_dir: str | Path | None = None,
        *,
        port: int = 0,
        password: str = "",
        host: str = "127.0.0.1",
        executable: str = "redis-server",
        start_timeout_s: float = 10.0,
    ) -> None:
        self._own_dir = data_dir is None
        self.data_dir = (
            Path(data_dir) if data_dir is not None else Path(tempfile.mkdtemp(prefix="cec-redis-"))
        )
        self.port = port
        self.password = password
        self.host = host
        self.executable = executable
        self.start_timeout_s = start_timeout_s
        self._proc: subprocess.Popen[bytes] | None = None
        self._finalizer: weakref.finalize | None = None

    @property
    def url(self) -> str:
        return f"redis://{self.host}:{self.port}/0"

    @property
    def running(self) -> bool:
        return self._proc is not None and self._proc.poll() is None

    def config(self, **overrides: Any) -> StoreConfig:
        """A StoreConfig pointing at this server (fields overridable)."""
        return StoreConfig(**{"url": self.url, "password": self.password, **overrides})

    def start(self) -> LocalRedis:
        """Starts the server and waits until it answers. StoreError if it cannot start."""
        if self.running:
            return self
        binary = shutil.which(self.executable)
        if binary is None:
            raise StoreError(
                f"`{self.executable}` was not found on PATH, so no local Redis can be started; "
                f"{INSTALL_HINT}. Or give the URL of a running Redis (store url or {ENV_URL})"
            )
        self.data_dir.mkdir(parents=True, exist_ok=True)
        attempts = 3 if self.port == 0 else 1
        for attempt in range(attempts):
            if self.port == 0 or attempt > 0:
                self.port = free_port(self.host)
            error = self._start_once(binary)
            if error is None:
                return self
            if "in use" not in error or attempt == attempts - 1:
                raise StoreError(f"redis-server failed to start on {self.host}:{self.port}: {error}")
        raise AssertionError("unreachable")

    def _start_once(self, binary: str) -> str | None:
        conf = self.data_dir / "redis.conf"
        lines = [
            f"bind {self.host}",
            f"port {self.port}",
            f"dir {self.data_dir.resolve()}",
            f"logfile {(self.data_dir / 'redis.log').resolve()}",
            "daemonize no",
            'save ""',
            "appendonly yes",
            "appendfsync always",
        ]
        if self.password:
            lines.append(f"requirepass {self.password}")
        conf.touch(mode=0o600)
        conf.write_text("\n".join(lines) + "\n")
        log = self.data_dir / "redis.log"
        offset = log.stat().st_size if log.exists() else 0
        proc = subprocess.Popen(
            with_parent_death([binary, str(conf)]),
            stdin=subprocess.DEVNULL,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.PIPE,
        )
        self._proc = proc
        self._finalizer = weakref.finalize(self, terminate, proc, 0.0)  # never leave a stray server behind
        client = redis.Redis(
            host=self.host, port=self.port, password=self.password or None, socket_connect_timeout=0.5
        )
        deadline = time.monotonic() + self.start_timeout_s
        try:
            while time.monotonic() < deadline:
                if proc.poll() is not None:
                    stderr = proc.stderr.read().decode(errors="replace") if proc.stderr else ""
                    tail = log.read_text(errors="replace")[offset:] if log.exists() else ""
                    self._proc = None
                    return (stderr + tail).strip()[-2000:] or f"exit status {proc.returncode}"
                try:
                    if client.ping():
                        return None
                except redis.BusyLoadingError:
                    pass  # replaying the append-only file
                except redis.ConnectionError:
                    pass
                time.sleep(0.02)
        finally:
            client.close()
        self.stop(kill=True)
        return f"it did not answer within {self.start_timeout_s} s (log: {log})"

    @property
    def pid(self) -> int:
        """The running server's process id."""
        if self._proc is None:
            raise StoreError("the local redis-server is not running")
        return self._proc.pid

    def stop(self, *, kill: bool = False) -> None:
        """Stops the server: SIGTERM (a clean shutdown) or, with `kill`, SIGKILL (a crash)."""
        proc, self._proc = self._proc, None
        if proc is None:
            return
        if proc.poll() is None:
            proc.send_signal(signal.SIGKILL if kill else signal.SIGTERM)
            try:
                proc.wait(timeout=10)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
        if proc.stderr is not None:
            proc.stderr.close()
        if self._finalizer is not None:
            self._finalizer.detach()
            self._finalizer = None

    def restart(self, *, kill: bool = False) -> None:
        """Stops and starts the server on the same port and directory (its data survives)."""
        self.stop(kill=kill)
        self.start()

    def close(self) -> None:
        """Stops the server and removes its temporary directory (a given `data_dir` is kept)."""
        self.stop()
        if self._own_dir:
            shutil.rmtree(self.data_dir, ignore_errors=True)

    def __enter__(self) -> LocalRedis:
        return self.start()

    def __exit__(self, *exc: object) -> None:
        self.close()
