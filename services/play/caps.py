"""What one participant, and the server in all, may make the play server record: the caps of
`StudyConfig.limits` on free-play rounds, reconnects (a round started again) and recorded bytes.

Rounds, reconnects and a participant's bytes are checked when a round would start: past a cap the round is not
started (`CapReachedError`, an `InputError`: the round's connection gets the message and closes) and the
participant's page says so (`Caps.view`). A round that has started is recorded to its end, so a participant
ends at most one round past their byte cap. The server's bytes, those of earlier runs' records included, are
also checked at each join (`JoinRefusedError`: HTTP 503). The bytes are counted as the records hold them (one
compact JSON line per event), from the records read back at start and every event recorded since.
"""

from __future__ import annotations

import json
import threading
from collections.abc import Iterable
from typing import Any, NamedTuple

from services.play.admission import JoinRefusedError
from services.play.config import LimitsConfig
from services.play.pages import InputError
from services.play.plan import Participant


class CapReachedError(InputError):
    """A round is not started: the participant (or the server) reached a cap of `limits` (`limit`)."""

    def __init__(self, message: str, limit: str) -> None:
        super().__init__(message)
        self.limit = limit


class Cap(NamedTuple):
    """A cap reached: its config key and what the participant is told."""

    limit: str
    message: str


def event_bytes(event: dict[str, Any]) -> int:
    """The bytes `event` takes in a participant's record (its JSON line, as `services.play.recording`
    writes it)."""
    return len(json.dumps(event, separators=(",", ":"), allow_nan=False).encode("utf-8")) + 1


def reconnects(p: Participant) -> int:
    """Rounds the participant started again (a reload, a dropped connection, a second tab)."""
    return sum(max(0, n - 1) for n in p.attempts.values())


class Caps:
    """The caps of `limits` on what is recorded; counts the bytes recorded per participant. Thread-safe."""

    def __init__(self, limits: LimitsConfig, free_play: bool) -> None:
        self.limits = limits
        self.free_play = free_play
        self.bytes: dict[str, int] = {}  # participant -> bytes recorded
        self.total = 0
        self._lock = threading.Lock()

    def add(self, participant: str, events: Iterable[dict[str, Any]]) -> None:
        """Counts `events` (as recorded, `seq` included) against the participant and the server."""
        size = sum(event_bytes(e) for e in events)
        with self._lock:
            self.bytes[participant] = self.bytes.get(participant, 0) + size
            self.total += size

    def reached(self, p: Participant, index: int) -> Cap | None:
        """The cap that keeps participant `p` from starting round `index` (again), or None."""
        limits, played = self.limits, len(p.played)
        if self.free_play and played >= limits.max_rounds_per_participant:
            return Cap(
                "limits.max_rounds_per_participant",
                f"You have played {played} rounds, the most this server offers one person. Thank you for "
                "playing!",
            )
        if p.attempts.get(index, 0) > 0 and reconnects(p) >= limits.max_reconnects_per_participant:
            return Cap(
                "limits.max_reconnects_per_participant",
                f"Your rounds were started again {reconnects(p)} times (reloads or dropped connections), the "
                "most this server allows one person, so it starts no more rounds for you. Thank you!",
            )
        if self.bytes.get(p.id, 0) >= limits.max_record_bytes_per_participant:
            return Cap(
                "limits.max_record_bytes_per_participant",
                "Your games fill as much of the server's records as one person may, so it starts no more "
                "rounds for you. Thank you for playing!",
            )
        if self.total >= limits.max_record_bytes:
            return Cap(
                "limits.max_record_bytes",
                "The server's records are full, so it starts no more rounds. Thank you for playing; please "
                "tell the person who runs it.",
            )
        return None

    def check_round(self, p: Participant, index: int) -> None:
        """`CapReachedError` when a cap keeps `p` from starting round `index`."""
        cap = self.reached(p, index)
        if cap is not None:
            raise CapReachedError(cap.message, cap.limit)

    def check_join(self) -> None:
        """`JoinRefusedError` (503) when the server's records are at `limits.max_record_bytes`."""
        if self.total >= self.limits.max_record_bytes:
            raise JoinRefusedError(
                f"the server's records hold {self.total:,} bytes, the most it records "
                f"(limits.max_record_bytes = {self.limits.max_record_bytes:,}); it takes no new participants",
                "limits.max_record_bytes",
                rate=False,
                retry_after=None,
            )

    def view(self, p: Participant, base: dict[str, Any]) -> dict[str, Any] | None:
        """The page of a participant a cap keeps from their next round (None: no cap reached): it says why,
        and, in free play, sums up their rounds."""
        kind, index = p.current
        if kind != "round" or p.round is not None:
            return None
        cap = self.reached(p, index)
        if cap is None:
            return None
        return {**base, "stage": "capped", "text": cap.message, "limit": cap.limit, "played": p.played[-50:]}


__all__ = ["Cap", "CapReachedError", "Caps", "event_bytes", "reconnects"]
