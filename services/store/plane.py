"""`ControlPlane`: the run registry, checkpoint events (published once by a Lua script, queued in a local
outbox while Redis is unreachable), the partner zoo and evaluation results in one Redis (key schema in the
package docstring, `services.store`).

Size: one class, `ControlPlane`, every method one Redis operation under the same key schema and retry
wrapper; the consumer group and records are their own modules.
"""

from __future__ import annotations

import contextlib
import fcntl
import json
import os
import socket
import threading
import time
from collections.abc import Iterator, Mapping
from dataclasses import asdict
from functools import partial
from pathlib import Path
from typing import Any

from services.store.client import RedisClient
from services.store.config import (
    StoreConfig,
    StoreError,
    StoreUnavailableError,
)
from services.store.consumer import CheckpointConsumer
from services.store.records import (
    RUN_STATUSES,
    CheckpointEvent,
    EvalResult,
    FlushResult,
    PartnerRecord,
    PublishResult,
    RunRecord,
    _check_name,
)

DEFAULT_GROUP = "evaluator"
OUTBOX_FILE = "checkpoint_outbox.jsonl"


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
        self.client = RedisClient(self.config)
        self._r: Any = self.client.redis
        self._call = self.client.call
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
        self.client.close()

    def __enter__(self) -> ControlPlane:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    # --- keys ---------------------------------------------------------------------------------------------

    def key(self, *parts: str) -> str:
        """`<prefix>:<part>:<part>...`, the name of a key of this control plane."""
        return self.client.key(*parts)

    @property
    def stream_key(self) -> str:
        return self.key("checkpoints")

    # --- health -------------------------------------------------------------------------------------------

    def check(self) -> str:
        """Pings Redis and checks its version; returns the version. StoreError (naming the fix) otherwise."""
        return self.client.check()

    def ping(self) -> bool:
        """True if Redis answers now (never raises)."""
        return self.client.ping()

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
        name = name or f"{socket.gethostname()}-{os.getpid()}"
        return CheckpointConsumer(self.client, self.stream_key, group, name, from_start)

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
