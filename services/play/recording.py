"""Durable records of a study: one append-only event log per participant, in files and/or Redis; export to
the evaluator's result table (`cec.evaluation.results`) and a survey table.

Every event is a JSON object with `type`, `at` (Unix time on the server) and the participant's opaque id.
`append` returns only after the event is on disk (file written and fsynced) and/or acknowledged by Redis
(whose own durability is its `appendfsync` setting; `LocalRedis` fsyncs every write), and the server answers
the action that caused an event only after that, so a crash loses at most the step being played.

Event types, in the order a participant produces them:

    participant   study, index (arrival order), level (assigned level spec), plan (partner names in
                  order), config_digest, session (SHA-256 of the session cookie, so that a restarted
                  server can take the participant back), code (their completion code)
    consent       accepted (true or false)
    info          fields: the answers to the study's `ask` questions (nothing else about the person)
    instructions  (read; the participant went on)
    round_start   round (-1: practice), attempt, practice, partner (name), policy, algorithm, seed,
                  level (name), level_ascii, human_seat, mode, steps, ticks_per_second, agent_actions,
                  state (compact start state, see services.play.game)
    step          round, attempt, t (1-based), actions [seat 0, seat 1], human_action, rt_ms (the
                  participant's reaction time as the browser measured it; null if not given), reward,
                  shaped [seat 0, seat 1], collision, done, state (compact state after the step),
                  compute_ms (server time of the step)
    round_end     round, attempt, steps, return, shaped_return, collisions, deliveries
    round_abort   round, attempt, steps (the connection closed, or the server stopped (steps -1), before
                  the round ended; it is played again from the start)
    survey        round, partner, answers {item id: 1..len(scale)}
    complete      code (the completion code shown)

Files: `<dir>/<study>/<participant>.jsonl`, one event per line. Redis: a stream per participant,
`<prefix>:play:<study>:<participant>` (field `event`: the JSON), and the set of participants,
`<prefix>:play:<study>:participants`.
"""

from __future__ import annotations

import json
import logging
import os
import re
from collections.abc import Iterable, Sequence
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Protocol

import redis

from cec.evaluation.results import EpisodeTable, make_table
from services.store import StoreConfig, StoreError, StoreUnavailableError

log = logging.getLogger("cec.play")

PARTICIPANT_ID = re.compile(r"^p[0-9a-f]{20}$")
HUMAN_ALGORITHM = "human"
SURVEY_COLUMNS = ("participant", "round", "partner", "policy", "algorithm", "seed", "level", "item", "answer")


class RecordError(ValueError):
    """Records are missing or inconsistent; the message names the participant, the round and the problem."""


class EventStore(Protocol):
    """Where events are appended and read back."""

    def append(self, participant: str, event: dict[str, Any]) -> None: ...

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
    so the server holds no descriptor per participant, however many join.
    """

    def __init__(self, root: str | Path, study: str, *, create: bool = True) -> None:
        self.dir = Path(root) / study
        if create:
            self.dir.mkdir(parents=True, exist_ok=True)

    def path(self, participant: str) -> Path:
        _check_id(participant)
        return self.dir / f"{participant}.jsonl"

    def append(self, participant: str, event: dict[str, Any]) -> None:
        data = (_dumps(event) + "\n").encode("utf-8")
        fd = os.open(self.path(participant), os.O_WRONLY | os.O_APPEND | os.O_CREAT | os.O_CLOEXEC, 0o666)
        try:
            view = memoryview(data)
            while view:  # one write() for a line in practice; O_APPEND keeps lines whole at the end
                view = view[os.write(fd, view) :]
            os.fsync(fd)
        finally:
            os.close(fd)

    def participants(self) -> list[str]:
        return sorted(p.stem for p in self.dir.glob("p*.jsonl") if PARTICIPANT_ID.match(p.stem))

    def events(self, participant: str) -> list[dict[str, Any]]:
        path = self.path(participant)
        if not path.is_file():
            raise RecordError(f"no records of participant {participant} in {self.dir}")
        lines = path.read_text(encoding="utf-8").splitlines()
        out = []
        for n, line in enumerate(lines, start=1):
            if not line.strip():
                continue
            try:
                out.append(json.loads(line))
            except json.JSONDecodeError as err:
                if n == len(lines):  # a crash while the last event was being written
                    log.warning("%s: the last line is cut off; ignored", path)
                    break
                raise RecordError(f"{path}, line {n}: not JSON ({err})") from err
        return out

    def close(self) -> None:
        """Nothing to close: no file stays open between events."""


class RedisStore:
    """One Redis stream per participant plus the set of participants."""

    def __init__(self, config: StoreConfig, study: str) -> None:
        self.config = config
        self.study = study
        try:
            self._r: Any = redis.Redis.from_url(
                config.resolved_url,
                password=config.resolved_password or None,
                decode_responses=True,
                socket_connect_timeout=config.connect_timeout_s,
                socket_timeout=config.socket_timeout_s,
            )
            self._r.ping()
        except ValueError as err:
            raise StoreError(
                f"Redis URL {config.display_url!r} is malformed ({err}); use redis://host:port/db"
            ) from err
        except redis.RedisError as err:
            raise StoreUnavailableError(
                f"cannot reach Redis at {config.display_url} ({err}); start it or fix storage.redis_url"
            ) from err

    def _key(self, *parts: str) -> str:
        return ":".join((self.config.key_prefix, "play", self.study, *parts))

    def append(self, participant: str, event: dict[str, Any]) -> None:
        _check_id(participant)
        try:
            pipe = self._r.pipeline(transaction=True)
            pipe.sadd(self._key("participants"), participant)
            pipe.xadd(self._key(participant), {"event": _dumps(event)})
            pipe.execute()
        except redis.RedisError as err:
            raise StoreUnavailableError(
                f"Redis at {self.config.display_url} failed to record an event: {err}"
            ) from err

    def participants(self) -> list[str]:
        return sorted(str(p) for p in self._r.smembers(self._key("participants")))

    def events(self, participant: str) -> list[dict[str, Any]]:
        _check_id(participant)
        entries = self._r.xrange(self._key(participant))
        if not entries:
            raise RecordError(
                f"no records of participant {participant} in Redis at {self.config.display_url}"
            )
        return [json.loads(fields["event"]) for _, fields in entries]

    def close(self) -> None:
        self._r.close()


class Recorder:
    """Appends every event to all configured stores (files first, then Redis)."""

    def __init__(self, stores: Sequence[EventStore]) -> None:
        if not stores:
            raise ValueError("a recorder needs at least one store")
        self.stores = list(stores)

    def append(self, participant: str, event: dict[str, Any]) -> None:
        for store in self.stores:
            store.append(participant, event)

    def close(self) -> None:
        for store in self.stores:
            store.close()


def open_stores(
    study: str, directory: str, redis_url: str, key_prefix: str = "cec", *, create: bool = True
) -> list[EventStore]:
    """The stores a study's storage config names (files and/or Redis); `create`: make the folder."""
    stores: list[EventStore] = []
    if directory:
        stores.append(FileStore(directory, study, create=create))
    if redis_url:
        stores.append(RedisStore(StoreConfig(url=redis_url, key_prefix=key_prefix), study))
    return stores


# ---------------------------------------------------------------------------------------------------------
# READING BACK
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class RoundRecord:
    """A finished round as recorded: its start event, its steps, and its end event (checked consistent)."""

    participant: str
    start: dict[str, Any]
    steps: tuple[dict[str, Any], ...]
    end: dict[str, Any]

    @property
    def round(self) -> int:
        return int(self.start["round"])

    @property
    def practice(self) -> bool:
        return bool(self.start["practice"])


def finished_rounds(participant: str, events: Iterable[dict[str, Any]]) -> list[RoundRecord]:
    """The rounds that ended (`round_end`), each checked: steps numbered 1..n without gaps, and the end
    event's totals equal to the sums over the steps. Aborted attempts are left out. `RecordError` if not."""
    rounds: list[RoundRecord] = []
    current: dict[str, Any] | None = None
    steps: list[dict[str, Any]] = []
    for ev in events:
        kind = ev.get("type")
        if kind == "round_start":
            current, steps = ev, []
        elif kind == "step" and current is not None:
            steps.append(ev)
        elif kind == "round_abort":
            current, steps = None, []
        elif kind == "round_end" and current is not None:
            where = f"participant {participant}, round {current['round']} attempt {current['attempt']}"
            if [s["t"] for s in steps] != list(range(1, len(steps) + 1)):
                raise RecordError(f"{where}: step numbers are not 1..{len(steps)}")
            if ev["steps"] != len(steps):
                raise RecordError(
                    f"{where}: the end event counts {ev['steps']} steps, {len(steps)} are recorded"
                )
            total = sum(s["reward"] for s in steps)
            collisions = sum(bool(s["collision"]) for s in steps)
            if abs(total - ev["return"]) > 1e-6 or collisions != ev["collisions"]:
                raise RecordError(
                    f"{where}: the end event's return/collisions differ from the sum of its steps"
                )
            rounds.append(RoundRecord(participant, current, tuple(steps), ev))
            current, steps = None, []
    return rounds


def export_tables(store: EventStore) -> tuple[EpisodeTable, list[dict[str, Any]]]:
    """(result table of every finished study round, survey rows) from a store.

    Result rows: `policy_a` the participant id, `algorithm_a` `human`, `seed_a` 0; `policy_b` the partner's
    policy (zoo entry or partner name), its algorithm and seed; `seat` the human's seat; `episode` the round
    index; the outcome columns; `actions` how the agent chose (`greedy`/`sampled`). Practice rounds are
    left out. Survey rows: one per answered item (`SURVEY_COLUMNS`).
    """
    cols: dict[str, list[Any]] = {f.name: [] for f in fields(EpisodeTable) if f.name != "skipped"}
    surveys: list[dict[str, Any]] = []
    for participant in store.participants():
        events = store.events(participant)
        by_round: dict[int, RoundRecord] = {}
        for r in finished_rounds(participant, events):
            if r.practice:
                continue
            by_round[r.round] = r  # a round is finished once; a later attempt would replace an earlier one
        for index in sorted(by_round):
            r = by_round[index]
            s, e = r.start, r.end
            cols["policy_a"].append(participant)
            cols["algorithm_a"].append(HUMAN_ALGORITHM)
            cols["seed_a"].append(0)
            cols["policy_b"].append(s["policy"])
            cols["algorithm_b"].append(s["algorithm"])
            cols["seed_b"].append(s["seed"])
            cols["level"].append(s["level"])
            cols["seat"].append(s["human_seat"])
            cols["episode"].append(index)
            cols["returns"].append(e["return"])
            cols["deliveries"].append(e["deliveries"])
            cols["collisions"].append(e["collisions"])
            cols["shaped_return"].append(e["shaped_return"])
            cols["env"].append("overcooked")
            cols["episode_steps"].append(e["steps"])
            cols["actions"].append(s["agent_actions"])
        for ev in events:
            if ev.get("type") != "survey":
                continue
            played = by_round.get(int(ev["round"]))
            for item, answer in ev["answers"].items():
                surveys.append(
                    {
                        "participant": participant,
                        "round": ev["round"],
                        "partner": ev["partner"],
                        "policy": played.start["policy"] if played else "",
                        "algorithm": played.start["algorithm"] if played else "",
                        "seed": played.start["seed"] if played else "",
                        "level": played.start["level"] if played else "",
                        "item": item,
                        "answer": answer,
                    }
                )
    return make_table(cols), surveys


def write_survey_csv(rows: Sequence[dict[str, Any]], path: str | Path) -> Path:
    """Writes survey rows (`SURVEY_COLUMNS`) as CSV."""
    import csv

    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", newline="") as f:
        writer = csv.DictWriter(f, fieldnames=SURVEY_COLUMNS)
        writer.writeheader()
        writer.writerows(rows)
    return path
