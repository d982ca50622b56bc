"""The study flow, independent of the web: participants, their stages, input validation, rounds, records.

A participant walks through stages: consent (if the study has consent text), info (if it asks anything),
instructions, the practice round (if any), then for each study round the round and its survey (if the
survey has items), and finally the completion code. In free play (`StudyConfig.free_play`) the rounds never
end: each finished round plans the next, whose partner the person may change (`services.play.free_play`).
`Study` holds the participants of one server process; every method validates its input and raises
`InputError` (the web layer answers 400 with its message) for anything a client could send wrong. Every
state change is recorded (`services.play.recording`) before the method returns, the events of one action
together. When a store cannot record them, the method raises `RecordUnavailableError` and leaves the
participant's stage as it was (a round being played is ended: its connection closes and the round is played
again), so the action can be retried without being recorded
twice; a join refused so leaves no record, and its counterbalancing index goes to the next join.

The round plan of participant i (their partners in order, the human's seat, the zoo draws, the kitchen and
the round seeds) comes from `numpy.random.default_rng([study.seed, i])`, so a study is reproducible; a
round replayed after a dropped connection is the same round again.

Size: one class, `Study`, whose methods share one lock and one participant table (join, plan, record,
survey, export); splitting it would spread that invariant over files.
"""

from __future__ import annotations

import dataclasses
import hashlib
import heapq
import json
import logging
import math
import re
import secrets
import threading
import time
from collections.abc import Callable
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import jax
import numpy as np

from cec.levels import to_ascii
from cec.levels.named import resolve_level
from services.play import free_play, metrics
from services.play.config import PracticeConfig, StudyConfig
from services.play.free_play import Candidate
from services.play.game import (
    NUM_ACTIONS,
    PartnerPool,
    Round,
    RoundSetup,
    StepResult,
    level_json,
)
from services.play.limits import RateLimiter, brief
from services.play.recording import Recorder

log = logging.getLogger("cec.play")

MAX_RT_MS = 3_600_000.0
PRACTICE = -1  # the practice round's index in the records
FINAL_STAGES = ("done", "declined")


class InputError(ValueError):
    """A client sent something the study does not accept; the message says what and what is expected."""


class JoinRefusedError(Exception):
    """A new participant is refused by one of the study's `limits` (the existing ones go on).

    Attributes:
        limit: the config key of the bound (`limits.max_active_participants`, ...).
        rate: True for a rate bound (HTTP 429), False when the server is full (HTTP 503).
        retry_after: seconds after which a join may succeed (None: not foreseeable).
    """

    def __init__(self, message: str, limit: str, *, rate: bool, retry_after: float | None) -> None:
        super().__init__(message)
        self.limit = limit
        self.rate = rate
        self.retry_after = retry_after


@dataclass(frozen=True)
class RoundPlan:
    """One round as planned for a participant.

    Attributes:
        index: round index (0..N-1; `PRACTICE` for the practice round).
        partner: partner condition name.
        policy: index of the policy drawn from the partner's pool.
        level_spec: the level spec to play.
        human_seat: the human's seat.
        steps: round length.
        mode: `turn_based` or `real_time`.
        seed: the round's PRNG seed (env reset, sampled agent actions) and `generated:random` draw.
    """

    index: int
    partner: str
    policy: int
    level_spec: str
    human_seat: int
    steps: int
    mode: str
    seed: int

    @property
    def practice(self) -> bool:
        return self.index == PRACTICE


@dataclass
class Participant:
    """One participant's progress (in memory; everything that matters is also in the records)."""

    id: str
    index: int
    level_spec: str
    rounds: list[RoundPlan]
    stages: list[tuple[str, int]]
    code: str
    stage: int = 0
    attempts: dict[int, int] = field(default_factory=dict)
    round: Round | None = None
    lock: threading.Lock = field(default_factory=threading.Lock)
    seen: float = 0.0  # the study clock at the participant's last request
    played: list[dict[str, Any]] = field(default_factory=list)  # free play: the rounds so far, summed up

    @property
    def current(self) -> tuple[str, int]:
        return self.stages[self.stage]

    @property
    def finished(self) -> bool:
        return self.current[0] in FINAL_STAGES


def _config_digest(config: StudyConfig) -> str:
    """A digest of everything that shapes a participant's study (where records go and the server's limits
    do not)."""
    data = {k: v for k, v in asdict(config).items() if k not in ("storage", "limits")}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:16]


class Study:
    """The participants of one study served by this process (and, after `restore`, of earlier runs).

    Args:
        config: the study.
        base_dir: the folder the study's relative paths are relative to.
        pools: the loaded partner conditions, by name.
        recorder: where events go.
        clock: seconds, monotonic (the join rate and idle times are measured with it).
    """

    def __init__(
        self,
        config: StudyConfig,
        base_dir: Path,
        pools: dict[str, PartnerPool],
        recorder: Recorder,
        clock: Callable[[], float] = time.monotonic,
    ) -> None:
        self.config = config
        self.base_dir = base_dir
        self.pools = pools
        self.recorder = recorder
        self.digest = _config_digest(config)
        self.clock = clock
        self._by_token: dict[str, Participant] = {}
        self._active: dict[str, Participant] = {}  # in progress, least recently seen first
        self._joining = 0  # admitted joins whose participant is being recorded
        self._joins = RateLimiter(
            config.limits.joins_per_address_per_minute,
            config.limits.joins_per_address_per_minute,
            clock=clock,
        )
        self._refused = 0  # joins refused since the last log line about it
        self._refused_logged = -math.inf
        self._lock = threading.Lock()
        self._next_index = 0  # arrival index of the next participant (`restore` continues the count)
        self._free_indices: list[int] = []  # a heap: indices of refused joins, given to the next joins

    # --- participants ---------------------------------------------------------------------------------

    def join(self, address: str = "") -> tuple[str, Participant]:
        """A new participant: (session token for the cookie, participant). The id is random and opaque.

        `address`: the client's address, for `limits.joins_per_address_per_minute`. `JoinRefusedError` when a
        bound of `config.limits` does not admit another participant now.
        """
        with self._lock:
            self._admit(address)
            self._joining += 1
            if self._free_indices:
                index = heapq.heappop(self._free_indices)
            else:
                index, self._next_index = self._next_index, self._next_index + 1
        try:
            token = secrets.token_urlsafe(24)
            code = self.config.completion_code or "C" + secrets.token_hex(4).upper()
            p = self._participant("p" + secrets.token_hex(10), index, code)
            try:
                self._record(
                    p,
                    "participant",
                    study=self.config.name,
                    index=index,
                    level=p.level_spec,
                    plan=[r.partner for r in p.rounds if not r.practice],
                    config_digest=self.digest,
                    session=_token_hash(token),
                    code=code,
                )
            except Exception:  # not admitted (no cookie, no file): its index goes to the next join
                self.recorder.discard(p.id)
                with self._lock:
                    heapq.heappush(self._free_indices, index)
                raise
        finally:
            with self._lock:
                self._joining -= 1
        with self._lock:
            self._by_token[_token_hash(token)] = p
            self._seen(p)
        metrics.PARTICIPANTS.inc()
        log.info("participant %s joined (index %d, level %s)", p.id, index, p.level_spec)
        return token, p

    def _admit(self, address: str) -> None:
        """Raises `JoinRefusedError` unless the limits admit one more participant (lock held)."""
        limits = self.config.limits
        now = self.clock()
        idle = limits.idle_minutes * 60.0
        while self._active:  # least recently seen first: drop the idle ones
            pid, oldest = next(iter(self._active.items()))
            if now - oldest.seen <= idle:
                break
            del self._active[pid]
        refusal: JoinRefusedError | None = None
        if len(self._by_token) + self._joining >= limits.max_participants:
            refusal = JoinRefusedError(
                "this study takes no more participants "
                f"(limits.max_participants = {limits.max_participants})",
                "limits.max_participants",
                rate=False,
                retry_after=None,
            )
        elif len(self._active) + self._joining >= limits.max_active_participants:
            first = next(iter(self._active.values()), None)
            wait = idle - (now - first.seen) if first is not None else 60.0
            refusal = JoinRefusedError(
                "the study is full right now (limits.max_active_participants = "
                f"{limits.max_active_participants} in progress); please try again later",
                "limits.max_active_participants",
                rate=False,
                retry_after=max(1.0, min(wait, 60.0)),
            )
        else:
            wait = self._joins.take(address)
            if wait > 0:
                refusal = JoinRefusedError(
                    "too many new participants from your address (limits.joins_per_address_per_minute = "
                    f"{limits.joins_per_address_per_minute}); try again in {math.ceil(wait)} s",
                    "limits.joins_per_address_per_minute",
                    rate=True,
                    retry_after=wait,
                )
        if refusal is None:
            return
        self._refused += 1
        if now - self._refused_logged >= 60.0:  # one line a minute at most, however many are refused
            log.warning("refusing joins: %s (%d refused since the last such line)", refusal, self._refused)
            self._refused, self._refused_logged = 0, now
        raise refusal

    def _seen(self, p: Participant) -> None:
        """Marks `p` active now (the caller holds the lock); finished participants are not active."""
        self._active.pop(p.id, None)
        p.seen = self.clock()
        if not p.finished:
            self._active[p.id] = p

    def active_participants(self) -> int:
        """Participants counted against `limits.max_active_participants` (idle ones not yet dropped)."""
        with self._lock:
            return len(self._active)

    def _participant(self, pid: str, index: int, code: str) -> Participant:
        """Participant `index`'s plan and stages (a function of the study config and the index only)."""
        rng = np.random.default_rng([self.config.seed, index])
        level_spec = self.config.levels[index % len(self.config.levels)]
        free = self.config.free_play  # one round planned now, the next when it ends (`free_play`)
        rounds = [self._free_round(index, 0, level_spec, None)] if free else self._plan(rng, level_spec)
        stages: list[tuple[str, int]] = []
        if self.config.consent.strip():
            stages.append(("consent", 0))
        if self.config.ask:
            stages.append(("info", 0))
        stages.append(("instructions", 0))
        for plan in rounds:
            stages.append(("round", plan.index))
            if not plan.practice and self.config.survey.items:
                stages.append(("survey", plan.index))
        if not free:
            stages.append(("done", 0))
        return Participant(pid, index, level_spec, rounds, stages, code)

    def _free_round(self, index: int, number: int, level_spec: str, partner: Candidate | None) -> RoundPlan:
        """Free-play round `number` of participant `index`, with `partner` (None: the drawn one)."""
        drawn = free_play.draw(
            self.config, free_play.candidates(self.config, self.pools, level_spec), index, number
        )
        partner = partner or drawn.partner
        steps, mode = int(self.config.env.max_steps), self.config.mode
        return RoundPlan(number, *partner, level_spec, drawn.human_seat, steps, mode, drawn.seed)

    def _free_round_ended(self, p: Participant, plan: RoundPlan, end: dict[str, Any]) -> None:
        """Free play: `plan`'s round is summed up and the next is planned, with the same partner."""
        partner = Candidate(plan.partner, plan.policy)
        p.played.append(free_play.summary_row(plan.index, free_play.describe(self.pools, partner), end))
        p.rounds.append(self._free_round(p.index, plan.index + 1, p.level_spec, partner))
        p.stages.append(("round", plan.index + 1))

    def _choose(self, p: Participant, index: int, payload: dict[str, Any]) -> None:
        """Free play: the partner of the coming round `index`, the previous one's (`same`) or the next."""
        choice = payload.get("partner")
        if payload.get("round") != index:
            raise InputError(f"the coming round is round {index}, not {brief(payload.get('round'))}; reload")
        if choice not in free_play.CHOICES:
            raise InputError(f"partner must be one of {list(free_play.CHOICES)}, got {brief(choice)}")
        if index == 0:
            raise InputError("the first round's partner is drawn; choose the partner after it")
        if p.round is not None:
            raise InputError("this round is being played; choose the partner of the next one after it")
        previous = self._plan_of(p, index - 1)
        partner = Candidate(previous.partner, previous.policy)
        if choice == "next":
            cands = free_play.candidates(self.config, self.pools, p.level_spec)
            partner = free_play.following(cands, partner)
        name = free_play.describe(self.pools, partner)["name"]
        self._record(p, "choice", round=index, choice=choice, partner=partner.partner, policy=name)
        self._set_partner(p, index, partner)

    def _set_partner(self, p: Participant, index: int, partner: Candidate) -> None:
        p.rounds = [
            dataclasses.replace(r, partner=partner.partner, policy=partner.policy) if r.index == index else r
            for r in p.rounds
        ]

    def participant(self, token: str | None) -> Participant | None:
        """The participant of a session token (None for an unknown or missing one)."""
        if not token or len(token) > 128:
            return None
        with self._lock:
            p = self._by_token.get(_token_hash(token))
            if p is not None:
                self._seen(p)
            return p

    def restore(self, records: dict[str, list[dict[str, Any]]]) -> int:
        """Takes back the participants of earlier runs of this server from their records, so that a
        participant whose server restarted continues where they were (with the same cookie). A round that
        was being played is recorded as aborted and is played again. Participants recorded under another
        study config, or whose participant event is missing, cannot continue (their records stay as they
        are). `records`: as the stores read them back (validated, `services.play.recording`). Returns how
        many were restored."""
        restored = 0
        for pid, events in records.items():
            head = events[0] if events else {}
            index = int(head.get("index", -1))
            with self._lock:
                self._next_index = max(self._next_index, index + 1)
            if head.get("type") != "participant":
                log.warning("participant %s: the records do not start with the participant event (see the "
                            "quarantined lines); cannot continue", pid)  # fmt: skip
                continue
            if head.get("config_digest") != self.digest or "session" not in head:
                log.warning("participant %s: recorded under another study config; cannot continue", pid)
                continue
            self.recorder.resume(pid, events)
            p = self._participant(pid, index, str(head["code"]))
            running: int | None = None
            for ev in events[1:]:
                kind = ev.get("type")
                if kind == "consent" and not ev.get("accepted"):
                    p.stages = [*p.stages[: p.stage + 1], ("declined", 0)]
                if self.config.free_play and kind == "round_end":
                    self._free_round_ended(p, self._plan_of(p, int(ev["round"])), ev)
                if self.config.free_play and kind == "choice":
                    chosen = free_play.by_name(self.pools, ev.get("partner"), ev.get("policy"))
                    if chosen is not None:
                        self._set_partner(p, int(ev["round"]), chosen)
                if kind in ("consent", "info", "instructions", "round_end", "survey"):
                    p.stage = min(p.stage + 1, len(p.stages) - 1)
                if kind == "round_start":
                    running = int(ev["round"])
                    p.attempts[running] = int(ev["attempt"]) + 1
                elif kind in ("round_end", "round_abort"):
                    running = None
            if running is not None:  # the server stopped during this round
                self._record(p, "round_abort", round=running, attempt=p.attempts[running] - 1, steps=-1)
            with self._lock:
                self._by_token[str(head["session"])] = p
            restored += 1
        return restored

    def _plan(self, rng: np.random.Generator, level_spec: str) -> list[RoundPlan]:
        c = self.config
        order = [name for name in (p.name for p in c.partners) for _ in range(c.rounds_per_partner)]
        if c.shuffle_rounds:
            order = [order[i] for i in rng.permutation(len(order))]
        plans: list[RoundPlan] = []
        if c.practice is not None:
            plans.append(self._round_plan(rng, PRACTICE, c.practice, level_spec))
        for i, name in enumerate(order):
            plans.append(self._round_plan(rng, i, name, level_spec))
        return plans

    def _round_plan(
        self, rng: np.random.Generator, index: int, what: str | PracticeConfig, level_spec: str
    ) -> RoundPlan:
        c = self.config
        if isinstance(what, PracticeConfig):
            partner = what.partner or c.partners[0].name
            level_spec, steps, mode = what.level, what.steps, what.mode or c.mode
        else:
            partner, steps, mode = what, int(c.env.max_steps), c.mode
        seat = int(rng.integers(2)) if c.human_seat < 0 else c.human_seat
        eligible = self.pools[partner].eligible(level_spec)
        policy = eligible[int(rng.integers(len(eligible)))]
        return RoundPlan(index, partner, policy, level_spec, seat, steps, mode, int(rng.integers(2**31 - 1)))

    def _event(self, p: Participant, kind: str, **fields: Any) -> dict[str, Any]:
        return {"type": kind, "at": round(time.time(), 6), "participant": p.id, **fields}

    def _record(self, p: Participant, kind: str, **fields: Any) -> None:
        self._record_all(p, [self._event(p, kind, **fields)])

    def _record_all(self, p: Participant, events: list[dict[str, Any]]) -> None:
        """Records the events of one action together (`RecordUnavailableError`: none is taken as
        recorded, and the participant's state is left as it was, so the action can be retried)."""
        self.recorder.append(p.id, *events)

    # --- views ----------------------------------------------------------------------------------------

    def _plan_of(self, p: Participant, index: int) -> RoundPlan:
        return next(r for r in p.rounds if r.index == index)

    def view(self, p: Participant) -> dict[str, Any]:
        """What the participant's page shows now (never a partner's identity)."""
        c = self.config
        kind, index = p.current
        base = {"stage": kind, "title": c.title, "participant": p.id}
        if kind == "consent":
            return {**base, "text": c.consent}
        if kind == "info":
            fields = [
                {"id": f.id, "label": f.label, "max_length": f.max_length, "required": f.required}
                for f in c.ask
            ]
            return {**base, "fields": fields}
        if kind == "instructions":
            return {
                **base,
                "text": c.instructions,
                "practice": c.practice is not None,
                "rounds": c.num_rounds,
                "free_play": c.free_play,
            }
        if kind == "round" and c.free_play:
            return {**base, **free_play.view(c, self.pools, p, index)}
        if kind == "round":
            plan = self._plan_of(p, index)
            return {
                **base,
                "practice": plan.practice,
                "number": index + 1,
                "of": c.num_rounds,
                "partner_label": "Practice partner" if plan.practice else f"Partner {index + 1}",
                "mode": plan.mode,
                "steps": plan.steps,
                "ticks_per_second": c.ticks_per_second,
            }
        if kind == "survey":
            items = [{"id": i.id, "text": i.text} for i in c.survey.items]
            return {
                **base,
                "number": index + 1,
                "of": c.num_rounds,
                "prompt": c.survey.prompt,
                "scale": list(c.survey.scale),
                "items": items,
            }
        if kind == "done":
            return {**base, "code": p.code}
        return base  # declined

    # --- submissions ----------------------------------------------------------------------------------

    def submit(self, p: Participant, payload: Any) -> dict[str, Any]:
        """Applies a form submission for the current stage; returns the next view. `InputError` if invalid."""
        if not isinstance(payload, dict):
            raise InputError("the request body must be a JSON object")
        with p.lock:
            kind, index = p.current
            if payload.get("stage") != kind:
                raise InputError(
                    f"this participant is at stage {kind!r}, not {brief(payload.get('stage'))}; reload"
                )
            if kind == "consent":
                accept = payload.get("accept")
                if not isinstance(accept, bool):
                    raise InputError("consent needs `accept`: true or false")
                stages = p.stages if accept else [*p.stages[: p.stage + 1], ("declined", 0)]
                self._record_all(
                    p, [self._event(p, "consent", accepted=accept), *self._completion(p, stages)]
                )
                p.stages = stages
                self._advance(p)
            elif kind == "info":
                info = self._event(p, "info", fields=self.validate_info(payload.get("fields")))
                self._record_all(p, [info, *self._completion(p)])
                self._advance(p)
            elif kind == "instructions":
                self._record_all(p, [self._event(p, "instructions"), *self._completion(p)])
                self._advance(p)
            elif kind == "round" and self.config.free_play:
                self._choose(p, index, payload)
            elif kind == "survey":
                if payload.get("round") != index:
                    raise InputError(f"this survey is about round {index}, not {brief(payload.get('round'))}")
                answers = self.validate_answers(payload.get("answers"))
                survey = self._event(
                    p, "survey", round=index, partner=self._plan_of(p, index).partner, answers=answers
                )
                self._record_all(p, [survey, *self._completion(p)])
                metrics.SURVEYS.inc()
                self._advance(p)
            else:
                raise InputError(f"stage {kind!r} takes no form submission")
            return self.view(p)

    def validate_info(self, fields: Any) -> dict[str, str]:
        """The `ask` answers: exactly the configured ids, strings within length, matching their pattern."""
        expected = {f.id: f for f in self.config.ask}
        if not isinstance(fields, dict) or set(fields) != set(expected):
            raise InputError(f"info needs `fields` with exactly the keys {sorted(expected)}")
        out: dict[str, str] = {}
        for key, spec in expected.items():
            value = fields[key]
            if not isinstance(value, str):
                raise InputError(f"{spec.label}: expected text")
            value = value.strip()
            if len(value) > spec.max_length:
                raise InputError(f"{spec.label}: at most {spec.max_length} characters")
            if spec.required and not value:
                raise InputError(f"{spec.label}: please answer")
            if value and spec.pattern and not re.fullmatch(spec.pattern, value):
                raise InputError(f"{spec.label}: {brief(value)} is not in the expected format")
            out[key] = value
        return out

    def validate_answers(self, answers: Any) -> dict[str, int]:
        """Survey answers: every item exactly once, each an integer in 1..len(scale)."""
        items = [i.id for i in self.config.survey.items]
        top = len(self.config.survey.scale)
        if not isinstance(answers, dict) or set(answers) != set(items):
            raise InputError(f"please answer every statement (expected keys {items})")
        out: dict[str, int] = {}
        for key in items:
            value = answers[key]
            if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
                raise InputError(f"answer {key!r} must be an integer from 1 to {top}, got {brief(value)}")
            out[key] = value
        return out

    def _completion(
        self, p: Participant, stages: list[tuple[str, int]] | None = None
    ) -> list[dict[str, Any]]:
        """The `complete` event when going on from the current stage (of `stages`, default the
        participant's) reaches the end of the study, to be recorded with the event that goes on."""
        stages = p.stages if stages is None else stages
        if p.current[0] != "done" and stages[min(p.stage + 1, len(stages) - 1)][0] == "done":
            return [self._event(p, "complete", code=p.code)]
        return []

    def _advance(self, p: Participant) -> None:
        """Goes on to the next stage (its events are recorded: `_completion`)."""
        p.stage = min(p.stage + 1, len(p.stages) - 1)
        if p.finished:
            with self._lock:
                self._active.pop(p.id, None)
        if p.current[0] == "done":
            log.info("participant %s completed the study", p.id)

    # --- rounds ---------------------------------------------------------------------------------------

    def begin_round(self, p: Participant) -> tuple[Round, dict[str, Any]]:
        """Starts (or restarts, after a dropped connection) the participant's current round.

        Returns the round and the start message for the browser (kitchen, seat, start state, and in
        turn-based mode the six next states).
        """
        with p.lock:
            kind, index = p.current
            if kind != "round":
                raise InputError(f"this participant is at stage {kind!r}, not in a round")
            if p.round is not None:
                self._abort(p)
            plan = self._plan_of(p, index)
            attempt = p.attempts.get(index, 0)
            p.attempts[index] = attempt + 1
            pool = self.pools[plan.partner]
            policy = pool.policies[plan.policy]
            level_name, level = resolve_level(
                plan.level_spec, self.base_dir, np.random.default_rng(plan.seed)
            )
            level = jax.device_get(level)
            setup = RoundSetup(policy, level_name, level, plan.human_seat, plan.steps, plan.mode, plan.seed)
            rnd = Round(setup, self.config)
            state, branches = rnd.start()
            self._record(
                p,
                "round_start",
                round=index,
                attempt=attempt,
                practice=plan.practice,
                partner=plan.partner,
                policy=policy.name,
                algorithm=policy.algorithm,
                seed=policy.seed,
                level=level_name,
                level_ascii=to_ascii(level),
                human_seat=plan.human_seat,
                mode=plan.mode,
                steps=plan.steps,
                ticks_per_second=self.config.ticks_per_second,
                agent_actions=self.config.agent_actions,
                state=state,
            )
            p.round = rnd
            metrics.ACTIVE_ROUNDS.inc()
            log.info(
                "participant %s: round %d (attempt %d) with %s on %s, %s", p.id, index, attempt, plan.partner,
                level_name, plan.mode,
            )  # fmt: skip
            message = {
                "type": "start",
                "round": index,
                "practice": plan.practice,
                "level": level_json(level),
                "human_seat": plan.human_seat,
                "mode": plan.mode,
                "steps": plan.steps,
                "ticks_per_second": self.config.ticks_per_second,
                "state": state,
            }
            if plan.mode == "turn_based":
                message["branches"] = branches
            return rnd, message

    def step(self, p: Participant, rnd: Round, action: Any, rt_ms: Any) -> StepResult:
        """Plays one human action in the participant's running round `rnd`; records it (and the round's end).

        `InputError` for a bad action or reaction time, or when `rnd` is no longer the running round.
        """
        action = validate_action(action)
        rt = validate_rt(rt_ms)
        with p.lock:
            if p.round is not rnd or rnd.done:
                raise InputError("this round is no longer running (it was restarted or has ended)")
            plan = self._plan_of(p, p.current[1])
            with self._lock:
                self._seen(p)
            result = rnd.step(action, with_branches=plan.mode == "turn_based")
            attempt = p.attempts[plan.index] - 1
            events = [
                self._event(
                    p,
                    "step",
                    round=plan.index,
                    attempt=attempt,
                    t=result.t,
                    actions=result.actions,
                    human_action=action,
                    rt_ms=rt,
                    reward=result.reward,
                    shaped=result.shaped,
                    collision=result.collision,
                    done=result.done,
                    state=result.state,
                    compute_ms=round(result.compute_s * 1000, 3),
                )
            ]
            if result.done:  # the step, the round's end (and the study's) are recorded together
                delivery = float(self.config.env.delivery_reward)
                events.append(
                    self._event(
                        p,
                        "round_end",
                        round=plan.index,
                        attempt=attempt,
                        steps=rnd.t,
                        **{"return": rnd.team_return},
                        shaped_return=rnd.shaped_return,
                        collisions=rnd.collisions,
                        deliveries=round(rnd.team_return / delivery) if delivery > 0 else 0,
                    )
                )
                events += self._completion(p)
            self._record_all(p, events)
            metrics.STEPS.labels(plan.mode).inc()
            metrics.STEP_SECONDS.observe(result.compute_s)
            if result.done:
                if self.config.free_play:
                    self._free_round_ended(p, plan, events[1])
                p.round = None
                metrics.ACTIVE_ROUNDS.dec()
                metrics.ROUNDS.labels("completed").inc()
                log.info(
                    "participant %s: round %d done: return %.0f, %d collisions",
                    *(p.id, plan.index, rnd.team_return, rnd.collisions),
                )
                self._advance(p)
            return result

    def abort_round(self, p: Participant, rnd: Round) -> None:
        """Records that `rnd` was left unfinished (connection closed); the stage stays, a replay starts
        anew."""
        with p.lock:
            if p.round is rnd:
                self._abort(p)

    def _abort(self, p: Participant) -> None:
        assert p.round is not None
        index = p.current[1]
        self._record(p, "round_abort", round=index, attempt=p.attempts[index] - 1, steps=p.round.t)
        p.round = None
        metrics.ACTIVE_ROUNDS.dec()
        metrics.ROUNDS.labels("aborted").inc()
        log.info("participant %s: round %d aborted", p.id, index)


def _token_hash(token: str) -> str:
    """What the server keeps of a session token: its SHA-256 (the token itself is only in the cookie)."""
    return hashlib.sha256(token.encode()).hexdigest()


def validate_action(action: Any) -> int:
    """An action index 0..5 (an int, not a bool or a float); `InputError` otherwise."""
    if isinstance(action, bool) or not isinstance(action, int) or not 0 <= action < NUM_ACTIONS:
        raise InputError(f"action must be an integer from 0 to {NUM_ACTIONS - 1}, got {brief(action)}")
    return action


def validate_rt(rt_ms: Any) -> float | None:
    """A reaction time in milliseconds (finite, 0..1 hour), or None when not given; `InputError` otherwise."""
    if rt_ms is None:
        return None
    if isinstance(rt_ms, bool) or not isinstance(rt_ms, int | float) or not math.isfinite(rt_ms):
        raise InputError(f"rt_ms must be a number of milliseconds, got {brief(rt_ms)}")
    if not 0.0 <= rt_ms <= MAX_RT_MS:
        raise InputError(f"rt_ms must lie in [0, {MAX_RT_MS:.0f}], got {rt_ms}")
    return round(float(rt_ms), 3)
