"""Free play (`StudyConfig.free_play`): rounds without end, each with the partner the person chose.

A free-play participant's plan grows one round at a time. When round k ends, round k+1 is planned with the
partner (the policy) of round k; before starting it the person may take the next one instead (a `choice`
event). The partners are the (condition, policy) pairs that play the participant's kitchen, in the order of
the study's `partners` and their pools; "next" goes round them. Round k's seat and seed come from
`numpy.random.default_rng([study.seed, participant index, k])` whatever the choice, and its partner from the
records (round 0's is drawn from that generator), so a server that restarts rebuilds the plan from the
`round_start` and `choice` events.
What a free-play round's page shows is `services.play.pages.free_play_view`.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import numpy as np

from services.play.config import StudyConfig
from services.play.game import PartnerPool

CHOICES = ("same", "next")
SUMMARY_ROWS = 50  # the latest rounds the page sums up


class Candidate(NamedTuple):
    """A partner a free-play round can have: a condition's name and a policy index in its pool."""

    partner: str
    policy: int


class Draw(NamedTuple):
    """What a free-play round's generator fixes: the partner drawn (used by round 0 only), seat, seed."""

    partner: Candidate
    human_seat: int
    seed: int


def candidates(config: StudyConfig, pools: dict[str, PartnerPool], level_spec: str) -> list[Candidate]:
    """Every (condition, policy) pair that plays `level_spec`, in the study's order."""
    return [Candidate(p.name, i) for p in config.partners for i in pools[p.name].eligible(level_spec)]


def draw(config: StudyConfig, cands: list[Candidate], index: int, number: int) -> Draw:
    """Round `number` of participant `index`: its drawn partner, the human's seat and the round seed."""
    rng = np.random.default_rng([config.seed, index, number])
    partner = cands[int(rng.integers(len(cands)))]
    seat = int(rng.integers(2)) if config.human_seat < 0 else config.human_seat
    return Draw(partner, seat, int(rng.integers(2**31 - 1)))


def following(cands: list[Candidate], current: Candidate) -> Candidate:
    """The partner after `current` (the first again after the last)."""
    return cands[(cands.index(current) + 1) % len(cands)] if current in cands else cands[0]


def by_name(pools: dict[str, PartnerPool], partner: Any, policy: Any) -> Candidate | None:
    """The candidate a record names (condition name, policy name); None when this server has no such one."""
    pool = pools.get(partner) if isinstance(partner, str) else None
    if pool is None:
        return None
    names = [p.name for p in pool.policies]
    return Candidate(partner, names.index(policy)) if policy in names else None


#: What the page says beside a partner whose training borrowed from the hand-written scripted cook (DESIGN
#: rule 16: a difference from the paper's method is named where a user meets it), by its kind (algorithm).
TEACHER = "CEC with a scripted teacher (imitates a hand-written cook; not the paper's method)"
NOTES = {"cec_teacher": TEACHER, "cec_finetune_teacher": f"{TEACHER}, fine-tuned in this kitchen"}


def note(kind: str) -> str:
    """The page's words on a partner of this kind beyond its name ("" for none)."""
    return NOTES.get(kind, "")


def describe(pools: dict[str, PartnerPool], cand: Candidate) -> dict[str, str]:
    """What the page shows of a partner: its policy's name and kind (the algorithm that trained it)."""
    policy = pools[cand.partner].policies[cand.policy]
    return {"name": policy.name, "kind": policy.algorithm}


def summary_row(number: int, partner: dict[str, str], end: dict[str, Any]) -> dict[str, Any]:
    """One finished round in the person's summary (from its `round_end` event's fields)."""
    return {
        "number": number + 1,
        "partner": partner["name"],
        "kind": partner["kind"],
        "score": end["return"],
        "deliveries": end["deliveries"],
        "collisions": end["collisions"],
        "steps": end["steps"],
    }


__all__ = [
    "CHOICES",
    "Candidate",
    "Draw",
    "by_name",
    "candidates",
    "describe",
    "draw",
    "following",
    "note",
    "summary_row",
]
