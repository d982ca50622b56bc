"""Who joins the study and who is in it: the bounds of `StudyConfig.limits` on new participants, the
participants by session, the ones in progress (least recently seen first) and their arrival indices.

A join is admitted (`admit`: an arrival index, or `JoinRefusedError` naming the bound) before its
participant is recorded, and is then either `enter`ed (it has a session) or `withdraw`n (its record was
refused: the index goes back, to the next join, so the counterbalancing has no hole). Thread-safe (one lock).
"""

from __future__ import annotations

import heapq
import logging
import math
import threading
import time
from collections.abc import Callable

from services.play.config import LimitsConfig
from services.play.limits import RateLimiter
from services.play.plan import Participant

log = logging.getLogger("cec.play")


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


class Admission:
    """The study's participants as admission sees them.

    Args:
        limits: the study's bounds.
        clock: seconds, monotonic (the join rate and idle times are measured with it).
    """

    def __init__(self, limits: LimitsConfig, clock: Callable[[], float] = time.monotonic) -> None:
        self.limits = limits
        self.clock = clock
        self._by_token: dict[str, Participant] = {}  # session token hash -> participant
        self._active: dict[str, Participant] = {}  # in progress, least recently seen first
        self._joining = 0  # admitted joins whose participant is being recorded
        self._joins = RateLimiter(
            limits.joins_per_address_per_minute, limits.joins_per_address_per_minute, clock=clock
        )
        self._refused = 0  # joins refused since the last log line about it
        self._refused_logged = -math.inf
        self._lock = threading.Lock()
        self._next_index = 0  # arrival index of the next participant (`restore` continues the count)
        self._free_indices: list[int] = []  # a heap: indices of refused joins, given to the next joins

    def admit(self, address: str) -> int:
        """The arrival index of a new participant from `address`; `JoinRefusedError` when a bound of the
        limits does not admit another one now. The join is then `enter`ed or `withdraw`n."""
        with self._lock:
            self._admit(address)
            self._joining += 1
            if self._free_indices:
                return heapq.heappop(self._free_indices)
            index, self._next_index = self._next_index, self._next_index + 1
            return index

    def enter(self, session: str, p: Participant) -> None:
        """The admitted join `p` is recorded: it has a session (`session`: its token's hash) now."""
        with self._lock:
            self._joining -= 1
            self._by_token[session] = p
            self._seen(p)

    def withdraw(self, index: int) -> None:
        """The admitted join of arrival index `index` was not recorded: its index goes to the next join."""
        with self._lock:
            self._joining -= 1
            heapq.heappush(self._free_indices, index)

    def counted(self, index: int) -> None:
        """An earlier run recorded a participant of arrival index `index`: new ones come after it."""
        with self._lock:
            self._next_index = max(self._next_index, index + 1)

    def restore(self, session: str, p: Participant) -> None:
        """An earlier run's participant `p` of session `session` continues in this one."""
        with self._lock:
            self._by_token[session] = p

    def participant(self, session: str) -> Participant | None:
        """The participant of a session token's hash (None: unknown), marked seen now."""
        with self._lock:
            p = self._by_token.get(session)
            if p is not None:
                self._seen(p)
            return p

    def seen(self, p: Participant) -> None:
        """Marks `p` active now; finished participants are not active."""
        with self._lock:
            self._seen(p)

    def finished(self, p: Participant) -> None:
        """`p` finished the study: it no longer counts as active."""
        with self._lock:
            self._active.pop(p.id, None)

    def active(self) -> int:
        """Participants counted against `limits.max_active_participants` (idle ones not yet dropped)."""
        with self._lock:
            return len(self._active)

    def _admit(self, address: str) -> None:
        """Raises `JoinRefusedError` unless the limits admit one more participant (lock held)."""
        limits = self.limits
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
