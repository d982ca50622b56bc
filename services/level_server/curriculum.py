"""Prioritized level replay (Jiang et al., 2021) over levels whose learning scores consumers report.

Levels are identified by content (`cec.levels.fingerprint.fingerprint_host`); a reported level's score
replaces its previous one. Sampling mixes rank prioritisation of the scores with a staleness term:

    P(i) = (1 - rho) * h_i^(1/T) / sum_j h_j^(1/T) + rho * (t - t_i) / sum_j (t - t_j),   h_i = 1 / rank_i

where t counts sampled batches and t_i is when level i was last sampled (or added).

Only levels the server itself served may enter the buffer: `ServedWindow` remembers keyed digests of the
levels most recently served, and the source refuses scores for any other level (a held-out kitchen, an
unsolvable one, anything hand-made), so what the server streams stays what its generator produces.
"""

from __future__ import annotations

import hashlib
import os
import threading
from collections import deque

import numpy as np

from cec.levels.fingerprint import fingerprint_host
from cec.levels.level import GRID_SIZE, NUM_AGENTS, Level
from services.level_server.config import CurriculumConfig


class PrioritizedLevelReplay:
    """A fixed-capacity replay buffer of levels with scores. Thread-safe."""

    def __init__(self, config: CurriculumConfig) -> None:
        c = config.capacity
        self.config = config
        self._rng = np.random.default_rng(config.seed)
        self._lock = threading.Lock()
        self._grid = np.zeros((c, GRID_SIZE, GRID_SIZE), np.uint8)
        self._pos = np.zeros((c, NUM_AGENTS, 2), np.int32)
        self._dir = np.zeros((c, NUM_AGENTS), np.int32)
        self._size = np.zeros((c, 2), np.int32)
        self._score = np.zeros(c, np.float64)
        self._last = np.zeros(c, np.int64)
        self._slot: dict[bytes, int] = {}
        self._keys: list[bytes] = []
        self._tick = 0

    def __len__(self) -> int:
        return len(self._keys)

    @property
    def ready(self) -> bool:
        return len(self) >= self.config.min_fill

    def update(self, levels: Level, scores: np.ndarray) -> int:
        """Records scores (float[N]) for a batch of levels; returns how many were stored or updated."""
        scores = np.asarray(scores, np.float64)
        keys = [fp.tobytes() for fp in fingerprint_host(levels)]
        stored = 0
        with self._lock:
            for i, (key, score) in enumerate(zip(keys, scores, strict=True)):
                if not np.isfinite(score):
                    continue
                slot = self._slot.get(key)
                if slot is None:
                    if len(self._keys) < self.config.capacity:
                        slot = len(self._keys)
                        self._keys.append(key)
                    else:
                        slot = int(np.argmin(self._score))
                        if self._score[slot] >= score:
                            continue
                        del self._slot[self._keys[slot]]
                        self._keys[slot] = key
                    self._slot[key] = slot
                    self._grid[slot] = np.asarray(levels.grid[i])
                    self._pos[slot] = np.asarray(levels.agent_pos[i])
                    self._dir[slot] = np.asarray(levels.agent_dir[i])
                    self._size[slot] = np.asarray(levels.size[i])
                    self._last[slot] = self._tick
                self._score[slot] = score
                stored += 1
        return stored

    def probabilities(self) -> np.ndarray:
        """float[len(self)]: the sampling distribution over the stored levels."""
        n = len(self)
        score = self._score[:n]
        ranks = np.empty(n)
        ranks[np.argsort(-score, kind="stable")] = np.arange(1, n + 1)
        prio = (1.0 / ranks) ** (1.0 / self.config.temperature)
        prio /= prio.sum()
        stale = (self._tick - self._last[:n]).astype(np.float64)
        stale = stale / stale.sum() if stale.sum() > 0 else np.full(n, 1.0 / n)
        rho = self.config.staleness_coef
        return (1.0 - rho) * prio + rho * stale

    def sample(self, n: int) -> Level:
        """`n` levels drawn (with replacement) from the buffer; call only when `ready`."""
        with self._lock:
            self._tick += 1
            idx = self._rng.choice(len(self), size=n, p=self.probabilities())
            self._last[idx] = self._tick
            return Level(
                grid=self._grid[idx],  # type: ignore[arg-type]
                agent_pos=self._pos[idx],  # type: ignore[arg-type]
                agent_dir=self._dir[idx],  # type: ignore[arg-type]
                size=self._size[idx],  # type: ignore[arg-type]
            )


def wire_rows(levels: Level) -> np.ndarray:
    """uint8[N, 89]: each level of a batch as the bytes `cec.levels.wire.encode` sends for it."""
    grid = np.asarray(levels.grid)
    n = grid.shape[0]
    parts = (grid, levels.agent_pos, levels.agent_dir, levels.size)
    return np.concatenate([np.asarray(x).astype(np.uint8).reshape(n, -1) for x in parts], axis=1)


class ServedWindow:
    """Digests of the last `capacity` (or a few thousand more) levels served, for membership tests.

    A digest is a keyed 64-bit BLAKE2b of a level's exact wire bytes (tiles, start cells and seats,
    facings, size), under a key drawn at start-up: a client cannot compute digests, let alone craft a level
    that collides with a served one. Digests are kept in sorted blocks (8 bytes a level), the oldest block
    dropped once the newer ones hold `capacity`. Thread-safe.
    """

    BLOCK = 16384

    def __init__(self, capacity: int) -> None:
        self.capacity = capacity
        self._key = os.urandom(16)
        self._block = max(1, min(self.BLOCK, capacity))
        self._blocks: deque[np.ndarray] = deque()  # sorted unique digests, oldest first
        self._pending: list[np.ndarray] = []
        self._pending_n = 0
        self._size = 0  # digests in `_blocks`
        self._lock = threading.Lock()

    def __len__(self) -> int:
        return self._size + self._pending_n

    def digests(self, levels: Level) -> np.ndarray:
        """uint64[N]: the digest of each level of a batch."""
        rows = wire_rows(levels)
        width = rows.shape[1]
        buf = memoryview(rows.tobytes())
        key = self._key
        return np.fromiter(
            (int.from_bytes(hashlib.blake2b(buf[i : i + width], digest_size=8, key=key).digest(), "little")
             for i in range(0, len(buf), width)),
            dtype=np.uint64, count=rows.shape[0],
        )  # fmt: skip

    def add(self, digests: np.ndarray) -> None:
        """Records digests of levels just served."""
        if not len(digests):
            return
        with self._lock:
            self._pending.append(np.asarray(digests, np.uint64))
            self._pending_n += len(digests)
            if self._pending_n >= self._block:
                block = np.unique(np.concatenate(self._pending))
                self._pending, self._pending_n = [], 0
                self._blocks.append(block)
                self._size += len(block)
                while self._blocks and self._size - len(self._blocks[0]) >= self.capacity:
                    self._size -= len(self._blocks.popleft())

    def contains(self, digests: np.ndarray) -> np.ndarray:
        """bool[N]: which of these digests belong to recently served levels."""
        digests = np.asarray(digests, np.uint64)
        hit = np.zeros(len(digests), bool)
        if not len(digests):
            return hit
        with self._lock:
            if self._pending:
                hit |= np.isin(digests, np.concatenate(self._pending))
            for block in self._blocks:
                idx = np.minimum(np.searchsorted(block, digests), len(block) - 1)
                hit |= block[idx] == digests
        return hit
