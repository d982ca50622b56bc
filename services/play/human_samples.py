"""Behaviour-cloning samples from `cec play` records (`cec humans bc --from-play`).

A study's records folder (`<storage dir>/<study name>`, one `<participant>.jsonl` per participant; see
`services.play.recording`) is read back with the same checks as the export (`finished_rounds`: aborted
attempts left out, step numbers and totals checked). Every recorded step of a finished round, practice
included, becomes one sample: the HUMAN seat's observation of the state before the step, as
`cec.humans.bc.seat_observations` computes it for the published games (the round's kitchen from its
`level_ascii`, its length `steps` as the episode length), and the participant's `human_action`. The
agent's seat and actions are never used.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import jax
import numpy as np

from cec.config import ConfigError
from cec.envs.overcooked.state import NUM_ACTIONS, NUM_CHANNELS
from cec.humans.bc import Samples, seat_observations
from cec.humans.data import KITCHENS
from cec.levels import GRID_SIZE, LevelError, from_ascii
from services.play.export import RoundRecord, finished_rounds
from services.play.game import expand_state
from services.play.recording import FileStore, RecordError


@dataclass(frozen=True)
class PlayRecords:
    """A study's finished rounds by participant (participants who finished none are left out).

    Attributes:
        folder: the records folder read.
        study: its name (the folder's).
        rounds: participant id -> finished rounds in the order played (practice included).
        participants_without_rounds: how many participants' records hold no finished round.
    """

    folder: Path
    study: str
    rounds: dict[str, list[RoundRecord]]
    participants_without_rounds: int

    @property
    def steps(self) -> int:
        """Recorded human steps over all finished rounds."""
        return sum(len(r.steps) for rounds in self.rounds.values() for r in rounds)


def read_play_records(folder: str | Path) -> PlayRecords:
    """Every participant's finished rounds of a study's records folder.

    Raises `ConfigError` for a missing folder or one without a finished round, `RecordError` (naming the
    participant, the round and the problem) for inconsistent records."""
    folder = Path(folder)
    if not folder.is_dir():
        raise ConfigError(
            f"{folder} is not a folder; give a study's records folder, <storage dir>/<study name>, as "
            "`cec play` writes it (one p<20 hex digits>.jsonl per participant)"
        )
    store = FileStore(folder.parent, folder.name, create=False)
    participants = store.participants()
    if not participants:
        raise ConfigError(
            f"{folder} holds no participant records (p<20 hex digits>.jsonl); give a study's records folder, "
            "<storage dir>/<study name>, as `cec play` writes it"
        )
    rounds: dict[str, list[RoundRecord]] = {}
    for participant in participants:
        done = finished_rounds(participant, store.events(participant))
        if done:
            rounds[participant] = done
    if not rounds:
        raise ConfigError(
            f"{folder}: none of its {len(participants)} participant(s) finished a round; nothing to clone"
        )
    return PlayRecords(folder, folder.name, rounds, len(participants) - len(rounds))


def human_samples(
    rounds: Sequence[RoundRecord], participants: Sequence[str], *, batch: int = 4096
) -> Samples:
    """The human seat's (observation, action) of every step of `rounds`, in order; a sample's
    `participant` is its participant's index in `participants`, its `kitchen` the classic kitchen's code
    (`cec.humans.data.KITCHENS`) or -1 for any other kitchen. `RecordError` for inconsistent records."""
    states: list[Any] = []
    seats: list[int] = []
    lengths: list[int] = []
    actions: list[int] = []
    kitchens: list[int] = []
    codes: list[int] = []
    for r in rounds:
        where = f"participant {r.participant}, round {r.round} attempt {r.start.get('attempt')}"
        try:
            level = from_ascii(str(r.start["level_ascii"]))
            seat = int(r.start["human_seat"])
            length = int(r.start["steps"])
            compact = [r.start["state"], *(s["state"] for s in r.steps)]
        except (KeyError, TypeError, ValueError, LevelError) as err:
            raise RecordError(f"{where}: the round_start event is incomplete or malformed ({err})") from err
        if seat not in (0, 1) or length < len(r.steps):
            raise RecordError(
                f"{where}: human_seat {seat} / steps {length} do not fit its {len(r.steps)} steps"
            )
        level_name = str(r.start.get("level", ""))
        for t, (before, step) in enumerate(zip(compact[:-1], r.steps, strict=True)):
            try:
                state = expand_state(before, level)
            except ValueError as err:
                raise RecordError(f"{where}, the state before step {t + 1}: {err}") from err
            human, joint = step.get("human_action"), step.get("actions")
            if (
                int(state.time) != t
                or not isinstance(human, int)
                or not 0 <= human < NUM_ACTIONS
                or not isinstance(joint, list)
                or len(joint) != 2
                or joint[seat] != human
            ):
                raise RecordError(
                    f"{where}, step {t + 1}: human_action {human!r}, actions {joint!r} and the "
                    f"state's t {int(state.time)} (expected {t}) do not agree for human seat {seat}"
                )
            states.append(state)
            seats.append(seat)
            lengths.append(length)
            actions.append(human)
        kitchens += [KITCHENS.index(level_name) if level_name in KITCHENS else -1] * len(r.steps)
        codes += [participants.index(r.participant)] * len(r.steps)
    obs = []
    for start in range(0, len(states), batch):
        stacked = jax.tree.map(lambda *xs: np.stack(xs), *states[start : start + batch])
        both = seat_observations(stacked, np.asarray(lengths[start : start + batch]))
        obs.append(both[np.arange(len(both)), seats[start : start + batch]])
    return Samples(
        obs=np.concatenate(obs) if obs else np.zeros((0, GRID_SIZE, GRID_SIZE, NUM_CHANNELS), np.uint8),
        actions=np.asarray(actions, np.int32),
        kitchen=np.asarray(kitchens, np.int32),
        participant=np.asarray(codes, np.int32),
    )
