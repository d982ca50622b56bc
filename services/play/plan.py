"""A participant's plan: the rounds they play (`RoundPlan`), their stages, and `Participant`, their progress.

A participant walks through stages: consent (if the study has consent text), info (if it asks anything),
instructions, the practice round (if any), then for each study round the round and its survey (if the
survey has items), and finally the completion code. In free play (`StudyConfig.free_play`) the rounds never
end: each finished round plans the next, whose partner the person may change (`services.play.free_play`).

The round plan of participant i (their partners in order, the human's seat, the zoo draws, the kitchen and
the round seeds) comes from `numpy.random.default_rng([study.seed, i])`, so a study is reproducible; a
round replayed after a dropped connection is the same round again.
"""

from __future__ import annotations

import hashlib
import json
import threading
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from services.play import free_play
from services.play.config import PracticeConfig, StudyConfig
from services.play.free_play import Candidate
from services.play.game import PartnerPool, Round

PRACTICE = -1  # the practice round's index in the records
FINAL_STAGES = ("done", "declined")


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


def config_digest(config: StudyConfig) -> str:
    """A digest of everything that shapes a participant's study (where records go and the server's limits
    do not)."""
    data = {k: v for k, v in asdict(config).items() if k not in ("storage", "limits")}
    return hashlib.sha256(json.dumps(data, sort_keys=True, default=str).encode()).hexdigest()[:16]


def token_hash(token: str) -> str:
    """What the server keeps of a session token: its SHA-256 (the token itself is only in the cookie)."""
    return hashlib.sha256(token.encode()).hexdigest()


def new_participant(
    config: StudyConfig, pools: dict[str, PartnerPool], pid: str, index: int, code: str
) -> Participant:
    """Participant `index`'s plan and stages (a function of the study config and the index only)."""
    rng = np.random.default_rng([config.seed, index])
    level_spec = config.levels[index % len(config.levels)]
    free = config.free_play  # one round planned now, the next when it ends (`free_play`)
    rounds = (
        [free_round(config, pools, index, 0, level_spec, None)]
        if free
        else _plan(config, pools, rng, level_spec)
    )
    stages: list[tuple[str, int]] = []
    if config.consent.strip():
        stages.append(("consent", 0))
    if config.ask:
        stages.append(("info", 0))
    stages.append(("instructions", 0))
    for plan in rounds:
        stages.append(("round", plan.index))
        if not plan.practice and config.survey.items:
            stages.append(("survey", plan.index))
    if not free:
        stages.append(("done", 0))
    return Participant(pid, index, level_spec, rounds, stages, code)


def free_round(
    config: StudyConfig,
    pools: dict[str, PartnerPool],
    index: int,
    number: int,
    level_spec: str,
    partner: Candidate | None,
) -> RoundPlan:
    """Free-play round `number` of participant `index`, with `partner` (None: the drawn one)."""
    drawn = free_play.draw(config, free_play.candidates(config, pools, level_spec), index, number)
    partner = partner or drawn.partner
    steps, mode = int(config.env.max_steps), config.mode
    return RoundPlan(number, *partner, level_spec, drawn.human_seat, steps, mode, drawn.seed)


def plan_of(p: Participant, index: int) -> RoundPlan:
    """The participant's plan of round `index`."""
    return next(r for r in p.rounds if r.index == index)


def _plan(
    config: StudyConfig, pools: dict[str, PartnerPool], rng: np.random.Generator, level_spec: str
) -> list[RoundPlan]:
    c = config
    order = [name for name in (p.name for p in c.partners) for _ in range(c.rounds_per_partner)]
    if c.shuffle_rounds:
        order = [order[i] for i in rng.permutation(len(order))]
    plans: list[RoundPlan] = []
    if c.practice is not None:
        plans.append(_round_plan(c, pools, rng, PRACTICE, c.practice, level_spec))
    for i, name in enumerate(order):
        plans.append(_round_plan(c, pools, rng, i, name, level_spec))
    return plans


def _round_plan(
    c: StudyConfig,
    pools: dict[str, PartnerPool],
    rng: np.random.Generator,
    index: int,
    what: str | PracticeConfig,
    level_spec: str,
) -> RoundPlan:
    if isinstance(what, PracticeConfig):
        partner = what.partner or c.partners[0].name
        level_spec, steps, mode = what.level, what.steps, what.mode or c.mode
    else:
        partner, steps, mode = what, int(c.env.max_steps), c.mode
    seat = int(rng.integers(2)) if c.human_seat < 0 else c.human_seat
    eligible = pools[partner].eligible(level_spec)
    policy = eligible[int(rng.integers(len(eligible)))]
    return RoundPlan(index, partner, policy, level_spec, seat, steps, mode, int(rng.integers(2**31 - 1)))
