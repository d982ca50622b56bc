"""The level server's logic as a plain in-process object (DESIGN rule 5): `LevelSource`.

It wraps the library generator (never reimplements it): level i of the sequence (seed, config) is level
i % chunk of `generate_batch(fold_in(PRNGKey(seed), i // chunk), chunk, config)`, so any slice of any
sequence is reproducible whatever batch sizes a client asks for, and a reconnecting client resumes at an
index. Chunks are generated on demand (one compiled program per config) and cached (LRU). The gRPC
servicer (`services.level_server.server`) is a thin adapter over this class; actors may also use it
directly, without a network, in the embedded single-machine setup.
"""

from __future__ import annotations

import logging
import threading
from collections import OrderedDict
from dataclasses import dataclass
from functools import cached_property

import jax
import numpy as np

from cec.levels.ascii import from_ascii
from cec.levels.counting import count_layouts
from cec.levels.generator import GeneratorConfig, generate_batch_with_info
from cec.levels.heldout import content_hash, heldout_levels
from cec.levels.level import Level, stack_levels, validate_level
from cec.levels.membership import in_space
from cec.levels.solvability import validate_solvable
from services import metrics
from services.level_server.config import LevelServerConfig
from services.level_server.curriculum import PrioritizedLevelReplay

log = logging.getLogger("cec.level_server")

SEED_RANGE = 2**63  # seeds are int64 on the wire; PRNGKey takes the low 64 bits


class InvalidRequestError(ValueError):
    """A request's values are invalid (gRPC INVALID_ARGUMENT); the message names the field and the fix."""


class LimitExceededError(RuntimeError):
    """A request exceeds a server limit (gRPC RESOURCE_EXHAUSTED); the message names the limit."""


@dataclass(frozen=True)
class Validation:
    """What the server says about a client's level."""

    level: Level
    solvable: bool
    reasons: tuple[str, ...]
    heldout_name: str  # '' if not held out
    in_generator_space: bool
    content_hash: str


def take_rows(levels: Level, idx: np.ndarray | slice | int) -> Level:
    """Rows `idx` of a NumPy-backed batch (an int drops the batch axis)."""
    return jax.tree.map(lambda x: np.asarray(x)[idx], levels)


def concat(batches: list[Level]) -> Level:
    if len(batches) == 1:
        return batches[0]
    return jax.tree.map(lambda *xs: np.concatenate(xs), *batches)


class LevelSource:
    """Generated levels by (seed, config, index), the held-out set, validation, and the curriculum."""

    def __init__(self, config: LevelServerConfig) -> None:
        self.config = config
        self.server_seed = (
            config.seed if config.seed >= 0 else int(np.random.default_rng().integers(0, 2**62))
        )
        self._lock = threading.Lock()
        self._cache: OrderedDict[tuple[GeneratorConfig, int, int], Level] = OrderedDict()
        self._configs: set[GeneratorConfig] = {config.generator}
        self._next_fresh = 0
        self.replay = PrioritizedLevelReplay(config.curriculum) if config.curriculum.enabled else None
        metrics.GENERATOR_CONFIGS.set(len(self._configs))

    # --- generated levels --------------------------------------------------------------------------------

    def check_config(self, gen: GeneratorConfig) -> None:
        """Admits a generator config; raises `LimitExceededError` when too many distinct ones are in use."""
        with self._lock:
            if gen in self._configs:
                return
            if len(self._configs) >= self.config.max_distinct_configs:
                raise LimitExceededError(
                    f"this server already serves {len(self._configs)} distinct generator configs "
                    f"(max_distinct_configs={self.config.max_distinct_configs}); use the server's default "
                    "config (leave config unset) or ask the operator to raise the limit"
                )
            self._configs.add(gen)
            metrics.GENERATOR_CONFIGS.set(len(self._configs))
            log.info("compiling the generator for a new config (%d in use): %s", len(self._configs), gen)

    def _chunk(self, gen: GeneratorConfig, seed: int, c: int) -> Level:
        key = (gen, seed, c)
        with self._lock:
            hit = self._cache.get(key)
            if hit is not None:
                self._cache.move_to_end(key)
                return hit
        n = self.config.chunk_levels
        rng = jax.random.fold_in(jax.random.PRNGKey(seed % SEED_RANGE), c)
        levels, resamples = jax.device_get(generate_batch_with_info(rng, n, gen))
        metrics.LEVELS_GENERATED.inc(n)
        if rejected := int(np.sum(resamples)):
            metrics.HELDOUT_REJECTIONS.inc(rejected)
        with self._lock:
            self._cache[key] = levels
            while len(self._cache) > self.config.cache_chunks:
                self._cache.popitem(last=False)
        return levels

    def levels(self, seed: int, start: int, n: int, gen: GeneratorConfig | None = None) -> Level:
        """Levels [start, start + n) of the sequence `seed` as a NumPy-backed batch (leading axis n)."""
        gen = gen or self.config.generator
        self._check_count(start, n)
        self.check_config(gen)
        chunk = self.config.chunk_levels
        parts = []
        i = start
        while i < start + n:
            c, off = divmod(i, chunk)
            take = min(chunk - off, start + n - i)
            parts.append(take_rows(self._chunk(gen, seed, c), slice(off, off + take)))
            i += take
        return concat(parts)

    def fresh(self, n: int, gen: GeneratorConfig | None = None) -> tuple[int, Level]:
        """`n` levels from the server's own sequence (never the same twice); returns (first index, levels)."""
        self._check_count(0, n)
        with self._lock:
            start = self._next_fresh
            self._next_fresh += n
        return start, self.levels(self.server_seed, start, n, gen)

    def with_replay(self, levels: Level) -> Level:
        """The curriculum's mix: a `replay_prob` share of the batch replaced by replayed levels (if ready)."""
        if self.replay is None or not self.replay.ready:
            return levels
        n = int(np.asarray(levels.grid).shape[0])
        k = int(round(self.config.curriculum.replay_prob * n))
        if k == 0:
            return levels
        metrics.LEVELS_REPLAYED.inc(k)
        return concat([self.replay.sample(k), take_rows(levels, slice(k, n))])

    def _check_count(self, start: int, n: int) -> None:
        if n < 1:
            raise InvalidRequestError(f"the number of levels must be >= 1, got {n}")
        if start < 0:
            raise InvalidRequestError(f"start_index must be >= 0, got {start}")
        if n > self.config.max_levels_per_request:
            raise LimitExceededError(
                f"{n} levels exceed max_levels_per_request={self.config.max_levels_per_request}; "
                "ask in several requests or stream them with StreamLevels"
            )

    # --- held-out set, validation, curriculum, info ---------------------------------------------------------

    @cached_property
    def heldout(self) -> tuple[tuple[str, ...], Level]:
        names, levels = zip(*heldout_levels(), strict=True)
        return tuple(names), jax.device_get(stack_levels(list(levels)))

    @cached_property
    def _heldout_by_hash(self) -> dict[str, str]:
        return {content_hash(lv): name for name, lv in heldout_levels()}

    def validate(self, level: Level | str, gen: GeneratorConfig | None = None) -> Validation:
        """Checks a client's level (a single `Level` or ASCII text). Raises `LevelError` if malformed."""
        gen = gen or self.config.generator
        if isinstance(level, str):
            level = from_ascii(level)
        else:
            validate_level(level)
        reasons = validate_solvable(level, gen.allow_decoys)
        digest = content_hash(level)
        return Validation(
            level=jax.device_get(level),
            solvable=not reasons,
            reasons=tuple(reasons),
            heldout_name=self._heldout_by_hash.get(digest, ""),
            in_generator_space=in_space(level, gen),
            content_hash=digest,
        )

    def report_scores(self, levels: Level, scores: np.ndarray) -> int:
        """Feeds the curriculum; returns how many scores were taken (0 when the curriculum is off)."""
        n = int(np.asarray(levels.grid).shape[0])
        if len(scores) != n:
            raise InvalidRequestError(f"{len(scores)} scores for {n} levels; send one score per level")
        if self.replay is None:
            return 0
        taken = self.replay.update(levels, np.asarray(scores))
        metrics.CURRICULUM_BUFFER.set(len(self.replay))
        return taken

    @cached_property
    def layout_space_size(self) -> int:
        """Distinct kitchens the default config can emit (its space minus the held-out set)."""
        return count_layouts(self.config.generator).emittable

    def warm_up(self) -> None:
        """Compiles the default config's generator and computes the info fields (before serving)."""
        self.levels(self.server_seed, 0, 1)
        _ = self.heldout, self._heldout_by_hash, self.layout_space_size
