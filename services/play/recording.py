"""Durable records of a study: one append-only event log per participant, in files and/or Redis, validated
when read back (their export to result and survey tables: `services.play.export`).

Every event is a JSON object with `type`, `at` (Unix time on the server), the participant's opaque id and
`seq`, its number in the participant's log (0, 1, ...: the event id). `append` returns only after the event
is on disk (file written and fsynced) and/or acknowledged by Redis (whose own durability is its
`appendfsync` setting; `LocalRedis` fsyncs every write), and the server answers the action that caused an
event only after that, so a crash loses at most the step being played.

Store faults (`Recorder`): an event goes to the primary store (files when configured, else Redis) first,
then to the others. When a store fails, the stores that took the events give them back (the file is cut
back to its length before them; a file a join created is removed), `RecordUnavailableError` names the store
and the action fails (the web layer answers 503: nothing was changed). The participant's next event keeps
the same `seq`, and readers keep the last event of a `seq`: an event that reached a store anyway (a write to
a frozen Redis that timed out and was applied later, a cut that failed) is replaced by the next one, so a
retry is never counted twice and every store reads back the same log. A server that starts replays the
primary's records into Redis where Redis lacks them (`Recorder.replay`: Redis restarted empty, say).

Reading back validates every event (`check_event`: a JSON object of a known `type` with the fields the
readers use, of their types, nested at most `MAX_RECORD_DEPTH` levels). A bad line (or Redis entry) is
quarantined: left out, with a warning naming the file and line, and listed in the store's `quarantined`
(which `cec play export` reports), so a damaged record never stops a restart or an export.

Event types, in the order a participant produces them:

    participant   study, index (arrival order), level (assigned level spec), plan (partner names in
                  order), config_digest, session (SHA-256 of the session cookie, so that a restarted
                  server can take the participant back), code (their completion code)
    consent       accepted (true or false)
    info          fields: the answers to the study's `ask` questions (nothing else about the person)
    instructions  (read; the participant went on)
    round_start   round (-1: practice), attempt, practice, partner (name), policy, algorithm, seed,
                  level (name), level_ascii, human_seat, mode, steps, ticks_per_second, agent_actions,
                  agent_gives_way_after (absent in records before it existed: 0),
                  state (compact start state, see services.play.game)
    step          round, attempt, t (1-based), actions [seat 0, seat 1], human_action, rt_ms (the
                  participant's reaction time as the browser measured it; null if not given), reward,
                  shaped [seat 0, seat 1], collision, agent_gave_way (the agent's action was the
                  give-way rule's step aside; absent in records before it existed), done, state (compact
                  state after the step), compute_ms (server time of the step)
    round_end     round, attempt, steps, return, shaped_return, collisions, deliveries
    round_abort   round, attempt, steps (the connection closed, or the server stopped (steps -1), before
                  the round ended; it is played again from the start)
    survey        round, partner, answers {item id: 1..len(scale)}
    complete      code (the completion code shown)
    choice        round, choice (`same` or `next`), partner, policy: free play's partner of a coming round

Files: `<dir>/<study>/<participant>.jsonl`, one event per line. Redis: a stream per participant,
`<prefix>:play:<study>:<participant>` (field `event`: the JSON), and the set of participants,
`<prefix>:play:<study>:participants`.

Size: the event format's validation, the two stores that read it back through it and the `Recorder` that
keeps them consistent under faults change together (a new event field touches all three), so they stay one
module; reading the records back into tables is `services.play.export`.
"""

from __future__ import annotations

import json
import logging
import os
import re
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Protocol

from cec.paths import safe_name
from services.play.limits import json_depth
from services.store import RedisClient, StoreConfig, StoreError, StoreKeyTypeError, StoreUnavailableError

log = logging.getLogger("cec.play")

PARTICIPANT_ID = re.compile(r"^p[0-9a-f]{20}$")


#: Deepest nesting of a recorded event (a step's state is 4 levels deep; more is damage, not a record).
MAX_RECORD_DEPTH = 32
#: Longest record line (or Redis entry) read (a step is ~1 kB; a line this long is not one of ours).
MAX_RECORD_BYTES = 1 << 20


class RecordError(ValueError):
    """Records are missing or inconsistent; the message names the participant, the round and the problem."""


class RecordUnavailableError(StoreUnavailableError):
    """A store could not record an event (Redis down, a full disk...): the action is refused (HTTP 503) and
    may be retried; `store` names the store for a participant (`Redis`, `the records folder`)."""

    def __init__(self, message: str, store: str) -> None:
        super().__init__(message)
        self.store = store


@dataclass(frozen=True)
class Quarantined:
    """A record line (or Redis entry) left out on reading: `where` (file and line, or key and entry id)
    and the cause."""

    where: str
    cause: str
    participant: str = ""  # whose records the line belongs to (when known)

    def __str__(self) -> str:
        return f"{self.where}: {self.cause}"


def _int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _nonneg(v: Any) -> bool:
    return _int(v) and v >= 0


def _num(v: Any) -> bool:
    return isinstance(v, int | float) and not isinstance(v, bool)


def _any(v: Any) -> bool:
    return True


_CHECKS: dict[str, tuple[str, Callable[[Any], bool]]] = {
    "int": ("an integer", _int),
    "nonneg": ("an integer >= 0", _nonneg),
    "num": ("a number", _num),
    "bool": ("true or false", lambda v: isinstance(v, bool)),
    "str": ("a string", lambda v: isinstance(v, str)),
    "list": ("a list", lambda v: isinstance(v, list)),
    "dict": ("an object", lambda v: isinstance(v, dict)),
    "any": ("present", _any),
}

#: The fields each event type must have for the readers (restore, export, `cec humans bc --from-play`),
#: and their kinds (`_CHECKS`).
EVENT_FIELDS: dict[str, dict[str, str]] = {
    "participant": {"index": "nonneg", "session": "str", "code": "str", "config_digest": "str"},
    "consent": {"accepted": "bool"},
    "info": {"fields": "dict"},
    "instructions": {},
    "round_start": {
        "round": "int", "attempt": "nonneg", "practice": "bool", "partner": "any", "policy": "any",
        "algorithm": "any", "seed": "any", "level": "str", "level_ascii": "str", "human_seat": "int",
        "steps": "nonneg", "agent_actions": "any", "state": "any",
    },
    "step": {
        "round": "int", "attempt": "nonneg", "t": "int", "actions": "list", "human_action": "any",
        "reward": "num", "collision": "bool", "done": "bool", "state": "any",
    },
    "round_end": {
        "round": "int", "attempt": "nonneg", "steps": "nonneg", "return": "num", "shaped_return": "num",
        "collisions": "nonneg", "deliveries": "int",
    },
    "round_abort": {"round": "int", "attempt": "nonneg", "steps": "int"},
    "survey": {"round": "int", "partner": "any", "answers": "dict"},
    "choice": {"round": "int", "choice": "str", "partner": "any", "policy": "any"},
    "complete": {"code": "str"},
}  # fmt: skip


def check_event(event: Any) -> str | None:
    """What is wrong with a recorded event (None: nothing): a JSON object whose `type` is one of
    `EVENT_FIELDS`, with that type's fields of their kinds, and `seq` (when given) an integer >= 0."""
    if not isinstance(event, dict):
        return f"not a JSON object but a {type(event).__name__}"
    kind = event.get("type")
    if not isinstance(kind, str) or kind not in EVENT_FIELDS:
        return f"`type` {_brief(kind)} is not an event type ({', '.join(EVENT_FIELDS)})"
    if "seq" in event and not _nonneg(event["seq"]):
        return f"an event of type {kind!r} whose `seq` {_brief(event['seq'])} is not an integer >= 0"
    for name, check in EVENT_FIELDS[kind].items():
        what, ok = _CHECKS[check]
        if name not in event:
            return f"an event of type {kind!r} without `{name}`"
        if not ok(event[name]):
            return f"an event of type {kind!r} whose `{name}` {_brief(event[name])} is not {what}"
    return None


def _brief(value: Any, limit: int = 40) -> str:
    text = repr(value)
    return text if len(text) <= limit else text[: limit - 3] + "..."


def _constant(name: str) -> Any:
    raise ValueError(f"{name} is not a JSON number")


def parse_event(text: str | bytes) -> tuple[dict[str, Any] | None, str]:
    """(the event, '') from one record line or Redis entry, or (None, what is wrong with it): too long,
    not UTF-8 or JSON, nested deeper than `MAX_RECORD_DEPTH` (checked before parsing, without recursion),
    or not an event (`check_event`)."""
    if len(text) > MAX_RECORD_BYTES:
        return None, f"{len(text):,} bytes long (a record is at most {MAX_RECORD_BYTES:,})"
    try:
        line = text.decode("utf-8") if isinstance(text, bytes) else text
    except UnicodeDecodeError as err:
        return None, f"not UTF-8 text ({err.reason} at byte {err.start})"
    depth = json_depth(line)
    if depth > MAX_RECORD_DEPTH:
        return None, f"nested {depth} levels deep (a record is at most {MAX_RECORD_DEPTH})"
    try:
        event = json.loads(line, parse_constant=_constant)
    except json.JSONDecodeError as err:
        return None, f"not JSON ({err.msg} at column {err.colno})"
    except (ValueError, RecursionError) as err:
        return None, f"not JSON ({err})"
    problem = check_event(event)
    if problem is not None:
        return None, problem
    return event, ""


def _latest_per_seq(events: list[dict[str, Any]]) -> list[dict[str, Any]]:
    """`events` as the server acted on them: an event whose `seq` is not above the one before it was
    written again after a store fault (a retry, or what replaced it), so it replaces the events from that
    `seq` on; every event id is counted once."""
    out: list[dict[str, Any]] = []
    for ev in events:
        if "seq" in ev:
            while out and "seq" in out[-1] and out[-1]["seq"] >= ev["seq"]:
                out.pop()
        out.append(ev)
    return out


class EventStore(Protocol):
    """Where events are appended and read back; `quarantined`: what reading left out so far."""

    quarantined: list[Quarantined]

    def append(self, participant: str, *events: dict[str, Any]) -> Callable[[], None]:
        """Records `events`; returns what takes them back (`Recorder`: another store failed)."""
        ...

    def participants(self) -> list[str]: ...

    def events(self, participant: str) -> list[dict[str, Any]]: ...

    def close(self) -> None: ...


def _check_id(participant: str) -> None:
    if not PARTICIPANT_ID.match(participant):
        raise ValueError(f"{participant!r} is not a participant id (p + 20 hex digits)")


def _dumps(event: dict[str, Any]) -> str:
    return json.dumps(event, separators=(",", ":"), allow_nan=False)


class FileStore:
    """Append-only JSON lines, one file per participant, fsynced after every event.

    A file is open only while an event is written to it (opened for appending, written, fsynced, closed),
    so the server holds no descriptor per participant, however many join. A file whose last line was cut
    off (a crash while it was written) gets a line break before the next event, so that event stays whole.
    """

    name = "the records folder"

    def __init__(self, root: str | Path, study: str, *, create: bool = True) -> None:
        self.dir = Path(root) / study
        self.quarantined: list[Quarantined] = []
        if create:
            self.dir.mkdir(parents=True, exist_ok=True)

    def path(self, participant: str) -> Path:
        _check_id(participant)
        return self.dir / f"{participant}.jsonl"

    def append(self, participant: str, *events: dict[str, Any]) -> Callable[[], None]:
        """Appends `events` (one write, one fsync) to the participant's file; returns what cuts the file back
        to its length before them (removes it when they were its first events)."""
        data = "".join(_dumps(event) + "\n" for event in events).encode("utf-8")
        path = self.path(participant)
        fd = os.open(path, os.O_RDWR | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            size = os.fstat(fd).st_size
            if size and os.pread(fd, 1, size - 1) != b"\n":  # a cut-off last line: end it first
                data = b"\n" + data
            view = memoryview(data)
            while view:  # one write() for a line in practice; O_APPEND keeps lines whole at the end
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)

        def undo() -> None:
            if size == 0:
                path.unlink(missing_ok=True)
            else:
                os.truncate(path, size)

        return undo

    def participants(self) -> list[str]:
        return sorted(p.stem for p in self.dir.glob("p*.jsonl") if PARTICIPANT_ID.match(p.stem))

    def events(self, participant: str) -> list[dict[str, Any]]:
        """The participant's events in order; a bad line is quarantined (`Quarantined`, with a warning
        naming the file and line), never an error. `RecordError` when the participant has no file."""
        path = self.path(participant)
        if not path.is_file():
            raise RecordError(f"no records of participant {participant} in {self.dir}")
        out = []
        with path.open("rb") as f:  # line by line: an overlong line costs at most MAX_RECORD_BYTES
            n = 0
            while True:
                raw = f.readline(MAX_RECORD_BYTES + 1)
                if not raw:
                    break
                n += 1
                cut = not raw.endswith(b"\n")
                if len(raw) > MAX_RECORD_BYTES:
                    while raw and not raw.endswith(b"\n"):  # skip the rest of the line
                        raw = f.readline(MAX_RECORD_BYTES + 1)
                    self._quarantine(path, n, f"longer than {MAX_RECORD_BYTES:,} bytes")
                    continue
                if not raw.strip():
                    continue
                event, problem = parse_event(raw.rstrip(b"\n"))
                if event is None:
                    if cut:  # only the last line lacks its line break
                        problem += " (the last line, cut off: a crash while it was written)"
                    self._quarantine(path, n, problem)
                    continue
                out.append(event)
        return _latest_per_seq(out)

    def _quarantine(self, path: Path, line: int, cause: str) -> None:
        entry = Quarantined(f"{path}, line {line}", cause, path.stem)
        if entry not in self.quarantined:
            self.quarantined.append(entry)
            log.warning("%s; quarantined (left out of the records read)", entry)

    def close(self) -> None:
        """Nothing to close: no file stays open between events."""


class RedisStore:
    """One Redis stream per participant plus the set of participants."""

    name = "Redis"

    def __init__(self, config: StoreConfig, study: str) -> None:
        self.config = config
        self.study = study
        self.quarantined: list[Quarantined] = []
        self.client = RedisClient(config, decode_responses=False, fix="fix storage.redis_url")
        self._r: Any = self.client.redis
        self.client.call("answer PING", self._r.ping)

    def _key(self, *parts: str) -> str:
        return self.client.key("play", self.study, *parts)

    def append(self, participant: str, *events: dict[str, Any]) -> Callable[[], None]:
        """Appends `events` to the participant's stream (one transaction); returns what deletes them again
        (and the participant, when they were its first events)."""
        _check_id(participant)
        key, members = self._key(participant), self._key("participants")
        pipe = self._r.pipeline(transaction=True)
        pipe.sadd(members, participant)
        for event in events:
            pipe.xadd(key, {"event": _dumps(event)})
        new, *ids = self._write("record an event", pipe)

        def undo() -> None:
            pipe = self._r.pipeline(transaction=True)
            pipe.xdel(key, *ids)
            if new:
                pipe.delete(key)
                pipe.srem(members, participant)
            self._write("take events back", pipe)

        return undo

    def replace(self, participant: str, events: Sequence[dict[str, Any]]) -> None:
        """Makes the participant's stream hold exactly `events` (one transaction; none: the participant is
        removed)."""
        _check_id(participant)
        key, members = self._key(participant), self._key("participants")
        pipe = self._r.pipeline(transaction=True)
        pipe.delete(key)
        if events:
            pipe.sadd(members, participant)
        else:
            pipe.srem(members, participant)
        for event in events:
            pipe.xadd(key, {"event": _dumps(event)})
        self._write("replay the records", pipe)

    def _write(self, what: str, pipe: Any) -> list[Any]:
        try:
            return list(self.client.call(what, pipe.execute))
        except StoreError as err:  # any failure to record is the store's unavailability to the study
            raise StoreUnavailableError(str(err)) from err

    def _call(self, key: str, what: str, call: Callable[[], Any]) -> Any:
        """`call()` through the store's client, with a key of the wrong type named: `RecordError` (someone
        else's data); `StoreUnavailableError` when Redis cannot answer."""
        try:
            return self.client.call(f"read {what}", call)
        except StoreKeyTypeError as err:
            raise RecordError(
                f"Redis key {key!r} at {self.config.display_url} is not {what} ({err.__cause__}); it is not "
                "this study's record: remove it, or choose another storage.key_prefix"
            ) from err
        except StoreUnavailableError:
            raise
        except StoreError as err:  # any other failure to read is the store's unavailability to the study
            raise StoreUnavailableError(f"cannot read the records from Redis: {err}") from err

    def participants(self) -> list[str]:
        key = self._key("participants")
        members = self._call(key, "a set of participant ids", lambda: self._r.smembers(key))
        out = []
        for m in members:
            pid = m.decode("utf-8", "replace") if isinstance(m, bytes) else str(m)
            if PARTICIPANT_ID.match(pid):
                out.append(pid)
            else:
                self._quarantine(f"Redis key {key!r}, member {_brief(pid)}", "not a participant id")
        return sorted(out)

    def events(self, participant: str, *, missing_ok: bool = False) -> list[dict[str, Any]]:
        """The participant's events in order; a bad entry is quarantined (`Quarantined`, with a warning
        naming the key and entry), never an error. `RecordError` when the participant has no stream (none:
        `[]` with `missing_ok`)."""
        _check_id(participant)
        key = self._key(participant)
        entries = self._call(key, "a stream of events", lambda: self._r.xrange(key))
        if not entries and not missing_ok:
            raise RecordError(
                f"no records of participant {participant} in Redis at {self.config.display_url}"
            )
        out = []
        for entry_id, data in entries:
            ident = entry_id.decode() if isinstance(entry_id, bytes) else str(entry_id)
            where = f"Redis key {key!r}, entry {ident}"
            raw = data.get(b"event")
            if raw is None:
                self._quarantine(where, "no `event` field", participant)
                continue
            event, problem = parse_event(raw)
            if event is None:
                self._quarantine(where, problem, participant)
                continue
            out.append(event)
        return _latest_per_seq(out)

    def _quarantine(self, where: str, cause: str, participant: str = "") -> None:
        entry = Quarantined(where, cause, participant)
        if entry not in self.quarantined:
            self.quarantined.append(entry)
            log.warning("%s; quarantined (left out of the records read)", entry)

    def close(self) -> None:
        self.client.close()


def _store_name(store: EventStore) -> str:
    return str(getattr(store, "name", type(store).__name__))


class Recorder:
    """Appends every event to all configured stores, the primary (the first: files when configured) first,
    numbering each participant's events (`seq`); an action's events are in every store or in none, so a
    retry after a store fault is recorded once in each store (module docstring)."""

    def __init__(self, stores: Sequence[EventStore]) -> None:
        if not stores:
            raise ValueError("a recorder needs at least one store")
        self.stores = list(stores)
        self._next: dict[str, int] = {}  # participant -> the seq of its next event

    def resume(self, participant: str, events: Sequence[dict[str, Any]]) -> None:
        """Continues the numbering of a participant recorded by an earlier run (`events`: as read back)."""
        seqs = [int(e["seq"]) for e in events if "seq" in e]
        self._next[participant] = max(len(events), max(seqs, default=-1) + 1)

    def append(self, participant: str, *events: dict[str, Any]) -> list[dict[str, Any]]:
        """Records `events` (the events of one action, each with its `seq` added) in every store; returns
        them. `RecordUnavailableError` naming the store that failed: the stores that took them give them
        back, and the next event of the participant (a retry, or what replaces it) takes the same `seq`s."""
        seq = self._next.get(participant, 0)
        batch = [{**event, "seq": seq + i} for i, event in enumerate(events)]
        taken: list[tuple[str, Callable[[], None]]] = []
        for store in self.stores:
            name = _store_name(store)
            try:
                taken.append((name, store.append(participant, *batch)))
            except (OSError, StoreError) as err:
                for held, undo in reversed(taken):
                    try:
                        undo()
                    except (OSError, StoreError) as cause:  # the next event replaces them (same seq)
                        log.error(
                            "participant %s: %s keeps events %d.. it could not give back (%s); the "
                            "participant's next event replaces them", participant, held, seq, cause,
                        )  # fmt: skip
                raise RecordUnavailableError(f"{name} cannot record events now: {err}", name) from err
        self._next[participant] = seq + len(batch)
        return batch

    def replay(self, records: dict[str, list[dict[str, Any]]]) -> int:
        """Makes Redis, where it follows the primary, hold the primary's `records` (as read back): a
        participant's stream that misses events (Redis restarted empty, say) or holds others (a write to a
        frozen Redis applied after it timed out) is written again from the primary's records; a participant
        Redis alone holds with nothing but its join (a join refused while Redis was frozen) is removed.
        Where the primary quarantined lines of a participant Redis holds more of, or Redis alone holds one
        that went on, Redis is left as it is, with a warning. Returns how many participants were replayed."""
        primary, replayed = self.stores[0], 0
        damaged = {q.participant for q in primary.quarantined}
        for store in self.stores[1:]:
            if not isinstance(store, RedisStore):
                continue
            held = set(store.participants())
            for pid, events in records.items():
                theirs = store.events(pid, missing_ok=True) if pid in held else []
                if theirs == events:
                    continue
                if pid in damaged and theirs != events[: len(theirs)]:
                    log.warning(
                        "participant %s: %s holds events the primary's records lack (some of their lines "
                        "are quarantined); Redis is left as it is", pid, store.name,
                    )  # fmt: skip
                    continue
                store.replace(pid, events)
                replayed += 1
                log.warning(
                    "participant %s: %s held %d of its events, %s %d; replayed from %s", pid, store.name,
                    len(theirs), _store_name(primary), len(events), _store_name(primary),
                )  # fmt: skip
            for pid in sorted(held - set(records)):
                if [e["type"] for e in store.events(pid, missing_ok=True)] == ["participant"]:
                    store.replace(pid, [])
                    log.warning("participant %s: only in %s, its join refused; removed", pid, store.name)
                else:
                    where = (pid, store.name, _store_name(primary))
                    log.warning("participant %s: in %s, not in %s; left as it is", *where)
        return replayed

    def discard(self, participant: str) -> None:
        """Forgets a participant whose join failed (nobody can continue it)."""
        self._next.pop(participant, None)

    def close(self) -> None:
        for store in self.stores:
            store.close()


def open_stores(
    study: str,
    directory: str,
    redis_url: str,
    key_prefix: str = "cec",
    *,
    create: bool = True,
    redis_timeout_s: float | None = None,
) -> list[EventStore]:
    """The stores a study's storage config names (files and/or Redis); `create`: make the folder.
    `redis_timeout_s`: the serving limit (`StorageConfig.redis_timeout_s`: that long per command, one
    retry); None: the store's defaults, for tools that read the records back."""
    stores: list[EventStore] = []
    if directory:  # the study's name is a folder of `directory`: one plain path component
        safe_name(study, "study name", fix="name the study with 1-64 letters, digits, '_' or '-'")
        stores.append(FileStore(directory, study, create=create))
    if redis_url:
        config = StoreConfig(url=redis_url, key_prefix=key_prefix)
        if redis_timeout_s is not None:
            t = redis_timeout_s
            config = replace(config, connect_timeout_s=t, socket_timeout_s=t, retries=1)
        stores.append(RedisStore(config, study))
    return stores
