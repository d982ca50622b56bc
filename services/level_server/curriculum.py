"""Prioritized level replay (Jiang et al., 2021) over levels whose learning scores consumers report.

Levels are identified by content (`cec.levels.heldout.fingerprint_host`); a reported level's score
replaces its previous one. Sampling mixes rank prioritisation of the scores with a staleness term:

    P(i) = (1 - rho) * h_i^(1/T) / sum_j h_j^(1/T) + rho * (t - t_i) / sum_j (t - t_j),   h_i = 1 / rank_i

where t counts sampled batches and t_i is when level i was last sampled (or added).
"""

from __future__ import annotations

import threading

import numpy as np

from cec.levels.heldout import fingerprint_host
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
