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
from cec.levels.fingerprint import content_hash, fingerprint_host
from cec.levels.generator import GeneratorConfig, generate_batch_with_info
from cec.levels.heldout import heldout_fingerprints, heldout_levels, test2_levels, test_levels
from cec.levels.level import Level, stack_levels, validate_level
from cec.levels.membership import in_space
from cec.levels.solvability import validate_solvable
from services import metrics
from services.level_server.config import LevelServerConfig
from services.level_server.curriculum import PrioritizedLevelReplay, ServedWindow

log = logging.getLogger("cec.level_server")

SEED_RANGE = 2**63  # seeds are int64 on the wire; PRNGKey takes the low 64 bits
CHUNKS_PER_SEQUENCE = 2**32  # `fold_in` takes a uint32 chunk index: a sequence has this many chunks


class InvalidRequestError(ValueError):
    """A request's values are invalid (gRPC INVALID_ARGUMENT); the message names the field and the fix."""


class LimitExceededError(RuntimeError):
    """A request exceeds a server limit (gRPC RESOURCE_EXHAUSTED); the message names the limit."""


class UnknownLevelError(LookupError):
    """A request names levels this server did not serve (gRPC NOT_FOUND); the message says which."""


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
        self._cache: OrderedDict[tuple[GeneratorConfig, int, int], tuple[Level, np.ndarray | None]] = (
            OrderedDict()
        )
        self._configs: set[GeneratorConfig] = {config.generator}
        self._next_fresh = 0
        self.replay = PrioritizedLevelReplay(config.curriculum) if config.curriculum.enabled else None
        # what was served, so that only those levels can be scored into the replay buffer (curriculum only)
        self.served = ServedWindow(config.curriculum.served_window) if self.replay is not None else None
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

    @property
    def sequence_length(self) -> int:
        """Levels in one seeded sequence: indices run from 0 to this minus 1."""
        return self.config.chunk_levels * CHUNKS_PER_SEQUENCE

    def _chunk(self, gen: GeneratorConfig, seed: int, c: int) -> tuple[Level, np.ndarray | None]:
        """Chunk `c` of a sequence, and its levels' digests when the curriculum needs them (cached)."""
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
        entry = (levels, None if self.served is None else self.served.digests(levels))
        with self._lock:
            self._cache[key] = entry
            while len(self._cache) > self.config.cache_chunks:
                self._cache.popitem(last=False)
        return entry

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
            levels, digests = self._chunk(gen, seed, c)
            parts.append(take_rows(levels, slice(off, off + take)))
            if self.served is not None and digests is not None:
                self.served.add(digests[off : off + take])
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
        replayed = self.replay.sample(k)
        if self.served is not None:
            self.served.add(self.served.digests(replayed))
        return concat([replayed, take_rows(levels, slice(k, n))])

    def check_range(self, start: int, n: int | None) -> None:
        """Raises `InvalidRequestError` unless levels [start, start + n) (n None: to the end) exist."""
        end = self.sequence_length
        if start < 0:
            raise InvalidRequestError(f"start_index must be >= 0, got {start}")
        if start >= end or (n is not None and start + n > end):
            raise InvalidRequestError(
                f"levels from start_index={start}" + ("" if n is None else f" to {start + n}")
                + f" pass the end of a sequence: a sequence has {end} levels (chunk_levels="
                f"{self.config.chunk_levels} x 2**32 chunks), so start_index + count must be <= {end}; "
                "use another seed for more levels"
            )  # fmt: skip

    def _check_count(self, start: int, n: int) -> None:
        if n < 1:
            raise InvalidRequestError(f"the number of levels must be >= 1, got {n}")
        if n > self.config.max_levels_per_request:
            raise LimitExceededError(
                f"{n} levels exceed max_levels_per_request={self.config.max_levels_per_request}; "
                "ask in several requests or stream them with StreamLevels"
            )
        self.check_range(start, n)

    # --- held-out set, validation, curriculum, info ---------------------------------------------------------

    @cached_property
    def heldout(self) -> tuple[tuple[str, ...], Level]:
        names, levels = zip(*heldout_levels(), strict=True)
        return tuple(names), jax.device_get(stack_levels(list(levels)))

    @cached_property
    def _heldout_by_hash(self) -> dict[str, str]:
        """Every kitchen kept out of training by content hash: the validation (held-out) and test sets."""
        kept = (*heldout_levels(), *test_levels(), *test2_levels())
        return {content_hash(lv): name for name, lv in kept}

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
        """Feeds the curriculum; returns how many scores were taken (0 when the curriculum is off).

        All or nothing: a batch holding any level this server did not serve recently is refused whole, with
        `InvalidRequestError` for a held-out or unsolvable kitchen and `UnknownLevelError` otherwise.
        """
        n = int(np.asarray(levels.grid).shape[0])
        if len(scores) != n:
            raise InvalidRequestError(f"{len(scores)} scores for {n} levels; send one score per level")
        if self.replay is None or self.served is None or n == 0:
            return 0
        self._refuse_foreign(levels)
        taken = self.replay.update(levels, np.asarray(scores))
        metrics.CURRICULUM_BUFFER.set(len(self.replay))
        return taken

    def _refuse_foreign(self, levels: Level) -> None:
        """Raises unless every level of the batch is one this server served recently (and none held out)."""
        assert self.served is not None
        n = int(np.asarray(levels.grid).shape[0])
        # held-out kitchens first, exactly (a fingerprint match is confirmed by the content hash): they are
        # never served, so the window below refuses them too; this names the cause and guards the guard
        known = {tuple(fp) for fp in heldout_fingerprints().tolist()}
        for i, fp in enumerate(fingerprint_host(levels).tolist()):
            if tuple(fp) in known and (name := self._heldout_by_hash.get(content_hash(take_rows(levels, i)))):
                raise InvalidRequestError(
                    f"level {i} of the {n} reported is the held-out evaluation kitchen {name!r}; the "
                    "held-out set is for evaluation only and never enters the curriculum: report scores "
                    "only for levels this server streamed"
                )
        unknown = np.flatnonzero(~self.served.contains(self.served.digests(levels)))
        if not unknown.size:
            return
        i = int(unknown[0])
        reasons = validate_solvable(take_rows(levels, i), True)
        if reasons:
            raise InvalidRequestError(
                f"level {i} of the {n} reported is unsolvable ({'; '.join(reasons)}); this server never "
                "serves such a level, and takes scores only for levels it streamed"
            )
        raise UnknownLevelError(
            f"{unknown.size} of the {n} reported levels (the first: level {i}) are not among the last "
            f"{self.config.curriculum.served_window} levels this server served (curriculum.served_window); "
            "report scores only for levels streamed from this server, unchanged, and soon after receiving "
            "them; no score of this batch was taken"
        )

    @cached_property
    def layout_space_size(self) -> int:
        """Distinct kitchens the default config can emit (its space minus the held-out set)."""
        return count_layouts(self.config.generator).emittable

    def warm_up(self) -> None:
        """Compiles the default config's generator and computes the info fields (before serving)."""
        self.levels(self.server_seed, 0, 1)
        _ = self.heldout, self._heldout_by_hash, self.layout_space_size
