"""A study's records read back: finished rounds checked against their end events, and the export of every
participant's rounds to the evaluator's result table (`cec.evaluation.results`) and their answers to a
survey table (`cec play export`, `cec humans ... --from-play`). The records themselves, their stores and
their validation: `services.play.recording`."""

from __future__ import annotations

import logging
from collections.abc import Iterable, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cec.evaluation.results import ARRAY_FIELDS, EpisodeTable, make_table
from services.play.recording import EventStore, RecordError

log = logging.getLogger("cec.play")

HUMAN_ALGORITHM = "human"
SURVEY_COLUMNS = ("participant", "round", "partner", "policy", "algorithm", "seed", "level", "item", "answer")


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


def finished_rounds(
    participant: str, events: Iterable[dict[str, Any]], problems: list[str] | None = None
) -> list[RoundRecord]:
    """The rounds that ended (`round_end`), each checked: steps numbered 1..n without gaps, and the end
    event's totals equal to the sums over the steps. Aborted attempts are left out. An inconsistent round
    raises `RecordError`, or, given a `problems` list, is left out with its problem appended to it."""
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
            problem = _round_problem(steps, ev)
            if problem is None:
                rounds.append(RoundRecord(participant, current, tuple(steps), ev))
            elif problems is None:
                raise RecordError(f"{where}: {problem}")
            else:
                problems.append(f"{where}: {problem}; the round is left out")
                log.warning("%s: %s; the round is left out", where, problem)
            current, steps = None, []
    return rounds


def _round_problem(steps: list[dict[str, Any]], end: dict[str, Any]) -> str | None:
    """What makes a finished round's steps disagree with its end event (None: nothing)."""
    if [s["t"] for s in steps] != list(range(1, len(steps) + 1)):
        return f"step numbers are not 1..{len(steps)}"
    if end["steps"] != len(steps):
        return f"the end event counts {end['steps']} steps, {len(steps)} are recorded"
    total = sum(s["reward"] for s in steps)
    collisions = sum(bool(s["collision"]) for s in steps)
    if abs(total - end["return"]) > 1e-6 or collisions != end["collisions"]:
        return "the end event's return/collisions differ from the sum of its steps"
    return None


def log_problem(events: Sequence[dict[str, Any]]) -> str | None:
    """What is missing from a participant's log as read back (None: nothing): it must start with the
    participant event, its events numbered 0, 1, ... (`seq`) without a gap."""
    if not events:
        return "no event of it could be read"
    head = events[0]
    if head["type"] != "participant":
        return f"its records start at event {head.get('seq', '?')} ({head['type']}), not at its join"
    seqs = [e["seq"] for e in events if "seq" in e]
    if len(seqs) == len(events):  # records from before `seq` have none
        gap = next((i for i, seq in enumerate(seqs) if seq != i), None)
        if gap is not None:
            return f"its events {gap}..{seqs[gap] - 1} are missing"
    return None


#: What to do about a participant whose log misses events.
LOG_FIX = (
    "a store lost them (Redis restarted empty?): export from the records folder (--data), or restart `cec "
    "play serve` with both stores, which replays the records folder into Redis"
)


def _unplayed(events: Sequence[dict[str, Any]]) -> str:
    """Why a participant whose log is whole has no finished study round."""
    if any(e["type"] == "consent" and not e["accepted"] for e in events):
        return "declined consent"
    return f"the last event recorded is {events[-1]['type']!r}"


def read_all(store: EventStore, problems: list[str] | None = None) -> dict[str, list[dict[str, Any]]]:
    """Every participant's events (validated; bad lines quarantined by the store). A participant whose
    records cannot be read at all is left out with a warning (and its problem appended to `problems`)."""
    out: dict[str, list[dict[str, Any]]] = {}
    for participant in store.participants():
        try:
            out[participant] = store.events(participant)
        except RecordError as err:
            log.warning("%s; left out", err)
            if problems is not None:
                problems.append(f"{err}; left out")
    return out


def agent_actions(start: dict[str, Any]) -> str:
    """How the agent of a round chose its actions, as the result table's `actions` column says it:
    `greedy`/`sampled`, and `; gives way after N collisions` where the play server's rule was on."""
    gives_way = int(start.get("agent_gives_way_after", 0))
    rule = f"; gives way after {gives_way} collisions" if gives_way > 0 else ""
    return f"{start['agent_actions']}{rule}"


def export_tables(
    store: EventStore, problems: list[str] | None = None
) -> tuple[EpisodeTable, list[dict[str, Any]]]:
    """(result table of every finished study round, survey rows) from a store.

    Result rows: `policy_a` the participant id, `algorithm_a` `human`, `seed_a` 0; `policy_b` the partner's
    policy (zoo entry or partner name), its algorithm and seed; `seat` the human's seat; `episode` the round
    index; the outcome columns; `actions` how the agent chose (`agent_actions`). Practice rounds are
    left out. Survey rows: one per answered item (`SURVEY_COLUMNS`). Bad record lines are quarantined by the
    store (`store.quarantined`); a round whose records are inconsistent, or a participant whose records
    cannot be read or miss events (`log_problem`), is left out and named in `problems` (when given; else
    `RecordError`), and so is a participant with no finished study round (when `problems` is given).
    """
    cols: dict[str, list[Any]] = {f: [] for f in ARRAY_FIELDS}
    surveys: list[dict[str, Any]] = []
    if problems is None:
        records = {p: store.events(p) for p in store.participants()}
    else:
        records = read_all(store, problems)
    for participant, events in records.items():
        gap = log_problem(events)
        if gap is not None:
            if problems is None:
                raise RecordError(f"participant {participant}: {gap}; {LOG_FIX}")
            problems.append(f"participant {participant}: {gap}; left out ({LOG_FIX})")
            continue
        by_round: dict[int, RoundRecord] = {}
        for r in finished_rounds(participant, events, problems):
            if r.practice:
                continue
            by_round[r.round] = r  # a round is finished once; a later attempt would replace an earlier one
        if not by_round and problems is not None:
            problems.append(f"participant {participant}: no finished study round ({_unplayed(events)})")
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
            cols["actions"].append(agent_actions(s))
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
