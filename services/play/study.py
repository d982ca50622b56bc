"""The study flow, independent of the web: a participant's actions, from joining to the last round.

The parts it composes: `services.play.admission` (who may join, the participants by session, arrival
indices), `services.play.plan` (a participant's rounds and stages, drawn from the config and the arrival
index), `services.play.pages` (what a page shows, input validation), `services.play.recording` (the
records) and `services.play.game` (a round being played).

`Study` holds the participants of one server process; every method validates its input and raises
`InputError` (the web layer answers 400 with its message) for anything a client could send wrong. Every
state change is recorded (`services.play.recording`) before the method returns, the events of one action
together. When a store cannot record them, the method raises `RecordUnavailableError` and leaves the
participant's stage as it was (a round being played is ended: its connection closes and the round is played
again), so the action can be retried without being recorded twice; a join refused so leaves no record, and
its counterbalancing index goes to the next join.
"""

from __future__ import annotations

import dataclasses
import logging
import secrets
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import jax
import numpy as np

from cec.levels import to_ascii
from cec.levels.named import resolve_level
from services.play import free_play, metrics, pages
from services.play.admission import Admission, JoinRefusedError
from services.play.caps import CapReachedError, Caps
from services.play.config import StudyConfig
from services.play.free_play import Candidate
from services.play.game import PartnerPool, Round, RoundSetup, StepResult, level_json
from services.play.limits import brief
from services.play.pages import InputError, validate_action, validate_rt
from services.play.plan import (
    Participant,
    RoundPlan,
    config_digest,
    free_round,
    new_participant,
    plan_of,
    token_hash,
)
from services.play.recording import Recorder

__all__ = [
    "CapReachedError",
    "InputError",
    "JoinRefusedError",
    "Participant",
    "Study",
    "validate_action",
    "validate_rt",
]

log = logging.getLogger("cec.play")


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
        self.digest = config_digest(config)
        self.clock = clock
        self.admission = Admission(config.limits, clock)
        self.caps = Caps(config.limits, config.free_play)  # rounds, reconnects, bytes recorded

    # --- participants ---------------------------------------------------------------------------------

    def join(self, address: str = "") -> tuple[str, Participant]:
        """A new participant: (session token for the cookie, participant). The id is random and opaque.

        `address`: the client's address, for `limits.joins_per_address_per_minute`. `JoinRefusedError` when a
        bound of `config.limits` does not admit another participant now.
        """
        self.caps.check_join()
        index = self.admission.admit(address)
        pid = "p" + secrets.token_hex(10)
        try:
            token = secrets.token_urlsafe(24)
            code = self.config.completion_code or "C" + secrets.token_hex(4).upper()
            p = self._participant(pid, index, code)
            self._record(
                p,
                "participant",
                study=self.config.name,
                index=index,
                level=p.level_spec,
                plan=[r.partner for r in p.rounds if not r.practice],
                config_digest=self.digest,
                session=token_hash(token),
                code=code,
            )
        except BaseException:  # not admitted (no cookie, no file): its index goes to the next join
            self.recorder.discard(pid)
            self.admission.withdraw(index)
            raise
        self.admission.enter(token_hash(token), p)
        metrics.PARTICIPANTS.inc()
        log.info("participant %s joined (index %d, level %s)", p.id, index, p.level_spec)
        return token, p

    def active_participants(self) -> int:
        """Participants counted against `limits.max_active_participants` (idle ones not yet dropped)."""
        return self.admission.active()

    def _participant(self, pid: str, index: int, code: str) -> Participant:
        """Participant `index`'s plan and stages (a function of the study config and the index only)."""
        return new_participant(self.config, self.pools, pid, index, code)

    def _free_round_ended(self, p: Participant, plan: RoundPlan, end: dict[str, Any]) -> None:
        """Free play: `plan`'s round is summed up and the next is planned, with the same partner."""
        partner = Candidate(plan.partner, plan.policy)
        p.played.append(free_play.summary_row(plan.index, free_play.describe(self.pools, partner), end))
        p.rounds.append(free_round(self.config, self.pools, p.index, plan.index + 1, p.level_spec, partner))
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
        return self.admission.participant(token_hash(token))

    def restore(self, records: dict[str, list[dict[str, Any]]]) -> int:
        """Takes back the participants of earlier runs of this server from their records, so that a
        participant whose server restarted continues where they were (with the same cookie). A round that
        was being played is recorded as aborted and is played again. Participants recorded under another
        study config, or whose participant event is missing, cannot continue (their records stay as they
        are). `records`: as the stores read them back (validated, `services.play.recording`). Returns how
        many were restored."""
        restored = 0
        for pid, events in records.items():
            self.caps.add(pid, events)  # every record counts against `limits.max_record_bytes`
            head = events[0] if events else {}
            index = int(head.get("index", -1))
            self.admission.counted(index)
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
            self.admission.restore(str(head["session"]), p)
            restored += 1
        return restored

    def _event(self, p: Participant, kind: str, **fields: Any) -> dict[str, Any]:
        return {"type": kind, "at": round(time.time(), 6), "participant": p.id, **fields}

    def _record(self, p: Participant, kind: str, **fields: Any) -> None:
        self._record_all(p, [self._event(p, kind, **fields)])

    def _record_all(self, p: Participant, events: list[dict[str, Any]]) -> None:
        """Records the events of one action together (`RecordUnavailableError`: none is taken as
        recorded, and the participant's state is left as it was, so the action can be retried)."""
        self.caps.add(p.id, self.recorder.append(p.id, *events))

    # --- views ----------------------------------------------------------------------------------------

    def _plan_of(self, p: Participant, index: int) -> RoundPlan:
        return plan_of(p, index)

    def view(self, p: Participant) -> dict[str, Any]:
        """What the participant's page shows now (never a partner's identity); past a cap of `limits`, a page
        that says so (`Caps.view`)."""
        base = {"title": self.config.title, "participant": p.id}
        return self.caps.view(p, base) or pages.view(self.config, self.pools, p)

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
                info = self._event(p, "info", fields=pages.validate_info(self.config, payload.get("fields")))
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
                answers = pages.validate_answers(self.config, payload.get("answers"))
                survey = self._event(
                    p, "survey", round=index, partner=self._plan_of(p, index).partner, answers=answers
                )
                self._record_all(p, [survey, *self._completion(p)])
                metrics.SURVEYS.inc()
                self._advance(p)
            else:
                raise InputError(f"stage {kind!r} takes no form submission")
            return self.view(p)

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
            self.admission.finished(p)
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
            self.caps.check_round(p, index)  # before a running round is ended: a capped tab changes nothing
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
                agent_gives_way_after=self.config.agent_gives_way_after,
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
            self.admission.seen(p)
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
                    agent_gave_way=result.agent_gave_way,
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
            if result.agent_gave_way:
                metrics.AGENT_GAVE_WAY.inc()
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
