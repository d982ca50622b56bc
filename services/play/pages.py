"""What a participant's page shows at each stage (`view`, never a partner's identity) and what its forms and
a round's messages accept: every check of a client's input raises `InputError` (the web layer answers 400
with its message) naming what is wrong and what is expected.
"""

from __future__ import annotations

import math
import re
from typing import Any

from services.play import free_play
from services.play.config import StudyConfig
from services.play.game import NUM_ACTIONS, PartnerPool
from services.play.limits import brief
from services.play.plan import Participant, plan_of

MAX_RT_MS = 3_600_000.0


class InputError(ValueError):
    """A client sent something the study does not accept; the message says what and what is expected."""


def view(config: StudyConfig, pools: dict[str, PartnerPool], p: Participant) -> dict[str, Any]:
    """What the participant's page shows now (never a partner's identity)."""
    c = config
    kind, index = p.current
    base = {"stage": kind, "title": c.title, "participant": p.id}
    if kind == "consent":
        return {**base, "text": c.consent}
    if kind == "info":
        fields = [
            {"id": f.id, "label": f.label, "max_length": f.max_length, "required": f.required} for f in c.ask
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
        return {**base, **free_play_view(c, pools, p, index)}
    if kind == "round":
        plan = plan_of(p, index)
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


def free_play_view(
    config: StudyConfig, pools: dict[str, PartnerPool], p: Participant, index: int
) -> dict[str, Any]:
    """A free-play round's page: its partner by name and kind, the choice of partner (after the first round)
    and the person's rounds so far (the latest `free_play.SUMMARY_ROWS`)."""
    plans = {r.index: r for r in p.rounds}
    plan = plans[index]
    current = free_play.Candidate(plan.partner, plan.policy)
    partner = free_play.describe(pools, current)
    out: dict[str, Any] = {
        "free_play": True,
        "practice": False,
        "number": index + 1,
        "of": None,
        "partner": partner,
        "partner_label": f"{partner['name']} ({partner['kind']})",
        "partner_note": free_play.note(partner["kind"]),
        "mode": plan.mode,
        "steps": plan.steps,
        "ticks_per_second": config.ticks_per_second,
        "gives_way_after": config.agent_gives_way_after,
        "played": p.played[-free_play.SUMMARY_ROWS :],
        "rounds_played": len(p.played),
    }
    if index > 0:
        previous = plans[index - 1]
        same = free_play.Candidate(previous.partner, previous.policy)
        out["same"] = free_play.describe(pools, same)
        out["next"] = free_play.describe(
            pools, free_play.following(free_play.candidates(config, pools, p.level_spec), same)
        )
        out["choice"] = "same" if same == current else "next"
    return out


def validate_info(config: StudyConfig, fields: Any) -> dict[str, str]:
    """The `ask` answers: exactly the configured ids, strings within length, matching their pattern."""
    expected = {f.id: f for f in config.ask}
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


def validate_answers(config: StudyConfig, answers: Any) -> dict[str, int]:
    """Survey answers: every item exactly once, each an integer in 1..len(scale)."""
    items = [i.id for i in config.survey.items]
    top = len(config.survey.scale)
    if not isinstance(answers, dict) or set(answers) != set(items):
        raise InputError(f"please answer every statement (expected keys {items})")
    out: dict[str, int] = {}
    for key in items:
        value = answers[key]
        if isinstance(value, bool) or not isinstance(value, int) or not 1 <= value <= top:
            raise InputError(f"answer {key!r} must be an integer from 1 to {top}, got {brief(value)}")
        out[key] = value
    return out


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
