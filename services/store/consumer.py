"""`CheckpointConsumer`: one consumer of the checkpoint stream in a Redis consumer group (at-least-once
delivery, acknowledged, pending work of a dead consumer reclaimed, poison events moved to dead letters)."""

from __future__ import annotations

import json
import time
from functools import partial
from typing import TYPE_CHECKING, Any

from services.store.config import StoreError
from services.store.records import CheckpointEvent, CheckpointMessage, _check_name

if TYPE_CHECKING:
    from services.store.client import RedisClient


class CheckpointConsumer:
    """One consumer of the checkpoint stream in a Redis consumer group: at-least-once delivery.

    `read()` returns, in this order: events delivered to this consumer name before (a restart), events
    another consumer left unacknowledged for `claim_idle_s` (it died), then new events. Acknowledge each
    with `ack()` once its work is stored; an event is delivered again until then. Events the group already
    acknowledged under the same checkpoint id are skipped (and acknowledged), and events that are
    malformed or were delivered `max_deliveries` times are moved to `<prefix>:dead:<group>`.
    """

    def __init__(
        self, client: RedisClient, stream: str, group: str, name: str, from_start: bool = True
    ) -> None:
        self.client = client
        self.config = client.config
        self.group = _check_name(group, "consumer group")
        self.name = _check_name(name, "consumer name")
        self._r = client.redis
        self._stream = stream
        self._consumed = client.key("consumed", group)
        self._dead = client.key("dead", group)
        self._claim_idle_ms = int(self.config.claim_idle_s * 1000)
        self._replay_from: str | None = "0"  # own unacknowledged events, read once after start
        self.ensure_group(from_start)

    def ensure_group(self, from_start: bool = True) -> None:
        """Creates the consumer group (and the stream) if missing."""
        try:
            self.client.call(
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
        limit = 0.8 * self.config.socket_timeout_s
        block_ms = int(min(block_s, limit) * 1000) if block_s > 0 else None
        return self._accept(self._xreadgroup(">", count, block_ms), redelivered=False)

    def _xreadgroup(self, start: str, count: int, block_ms: int | None) -> list[tuple[str, Any]]:
        reply = self.client.call(
            "read checkpoint events",
            lambda: self._r.xreadgroup(
                self.group, self.name, {self._stream: start}, count=count, block=block_ms
            ),
        )
        return [(entry_id, data) for _stream, entries in reply or [] for entry_id, data in entries]

    def _reclaim(self, count: int) -> list[tuple[str, Any]]:
        stale = self.client.call(
            "list pending checkpoint events",
            lambda: self._r.xpending_range(
                self._stream, self.group, "-", "+", count, idle=self._claim_idle_ms
            ),
        )
        if not stale:
            return []
        limit = self.config.max_deliveries
        for p in stale:
            if p["times_delivered"] >= limit:
                self._bury(p["message_id"], f"delivered {p['times_delivered']} times without an ack", None)
        ids = [p["message_id"] for p in stale if p["times_delivered"] < limit]
        if not ids:
            return []
        claimed = self.client.call(
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
        seen = self.client.call("read consumed checkpoints", lambda: self._r.smismember(self._consumed, ids))
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
            self.client.call(
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

        self.client.call("move an event to the dead letters", write)

    def ack(self, message: CheckpointMessage) -> None:
        """Marks the event done for this group (its checkpoint id too, so duplicates are skipped)."""

        def write() -> None:
            with self._r.pipeline(transaction=True) as p:
                p.xack(self._stream, self.group, message.entry_id)
                p.sadd(self._consumed, message.event.checkpoint_id)
                p.execute()

        self.client.call("acknowledge an event", write)

    def touch(self, message: CheckpointMessage) -> None:
        """Keeps an event being worked on from being reclaimed by another consumer (resets its idle time)."""
        self.client.call(
            "keep a pending event",
            lambda: self._r.xclaim(self._stream, self.group, self.name, 0, [message.entry_id], justid=True),
        )

    def pending_count(self) -> int:
        """Events of the group delivered and not acknowledged (all consumers)."""
        summary = self.client.call("count pending events", lambda: self._r.xpending(self._stream, self.group))
        return int(summary["pending"])

    def dead_letters(self) -> dict[str, dict[str, Any]]:
        """Events the group gave up on, by stream entry id: {reason, consumer, at, fields}."""
        data = self.client.call("read dead letters", lambda: self._r.hgetall(self._dead))
        return {k: json.loads(v) for k, v in data.items()}
