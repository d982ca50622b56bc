"""The procedural kitchen generator: one pure, vmappable JAX function `generate(key, config) -> Level`.

Recipe (the paper's Algorithm 1, extended; docs/generator.md has the details and the layout count):

1. pick a base wall structure (a classic kitchen stripped of objects and agents) and a dihedral transform,
   uniformly;
2. place a *witness*: one onion pile, plate pile, pot and goal on counters the agents can reach, chosen so
   that a soup can be made. In a kitchen split in two regions either a bare counter next to both regions is
   reserved for hand-overs, or the witness pot is one that one side fills and the other side serves;
3. draw the number of each object kind within the configured bounds and place the supplemental objects
   on the remaining reachable counters (or anywhere inside the kitchen, if decoys are allowed);
4. place the agents on distinct floor cells (one in each region of a split kitchen, seats in random order);
5. transform, place in the top-left of the 9x9 frame, and resample while the result is unsolvable
   (never, by construction; the check guards it) or equals a validation or test kitchen.

Coverage: with `handover_share` > 0 a kitchen is, with that probability, redrawn until neither seat can
finish a soup alone (`cec.levels.kinds`: a hand-over is needed; about 19% of the default draws), so that
training meets the skill the hard kitchens ask for more often. With `structure_weights` the base structures
are drawn in those proportions instead of uniformly (e.g. Counter Circuit's long loop more often). Neither
changes the set of possible kitchens.
"""

from __future__ import annotations

import dataclasses
import itertools
from dataclasses import dataclass
from functools import cache, partial
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.config import ConfigError
from cec.levels.fingerprint import fingerprint
from cec.levels.heldout import heldout_fingerprints
from cec.levels.kinds import Kind, classify
from cec.levels.level import Level, Tile
from cec.levels.solvability import check
from cec.levels.structures import CELLS, NUM_TRANSFORMS, StructureTables, base_structures, build_tables

#: Object kinds placed by the generator, in witness order.
OBJECT_TILES = (Tile.ONION_PILE, Tile.PLATE_PILE, Tile.POT, Tile.GOAL)
STRUCTURE_NAMES = ("asymm_advantages", "coord_ring", "counter_circuit", "cramped_room", "forced_coord")
WITNESS_TRIES = 4  # witness candidates drawn at once when no hand-over counter is reserved
_CANDIDATE_MASKS = np.concatenate(
    [
        np.zeros((1, 81), np.uint16),
        np.random.default_rng(7).integers(1, 2**16, (WITNESS_TRIES, 81), dtype=np.uint16),
    ]
)


@dataclass(frozen=True)
class GeneratorConfig:
    """What the generator may produce. Hashable: pass it as a static argument.

    Attributes:
        structures: base wall structures to draw from, uniformly (names of the classic kitchens).
        onion_piles: (min, max) number of onion piles per kitchen.
        plate_piles: (min, max) number of plate piles.
        pots: (min, max) number of pots.
        goals: (min, max) number of goals (delivery windows).
        count_decay: each object beyond a kind's minimum multiplies a count vector's probability by this
            (0.5: on average ~1.8 of each kind, near the paper's two; 1.0: uniform over the count vectors
            that fit the kitchen). The set of possible kitchens does not depend on it.
        allow_decoys: let supplemental objects stand on counters no agent can reach.
        exclude_heldout: never emit a kitchen of the validation or test sets (`cec.levels.heldout`).
        handover_share: the probability that a kitchen is drawn among those that need a hand-over (neither
            seat can finish a soup alone; `cec.levels.kinds`); 0 draws kitchens as they come (about 19%
            need one), 1 draws only such kitchens.
        structure_weights: how often each of `structures` is drawn, in its order (positive; normalised);
            empty: uniformly.
    """

    structures: tuple[str, ...] = STRUCTURE_NAMES
    onion_piles: tuple[int, int] = (1, 5)
    plate_piles: tuple[int, int] = (1, 5)
    pots: tuple[int, int] = (1, 5)
    goals: tuple[int, int] = (1, 5)
    count_decay: float = 0.5
    allow_decoys: bool = False
    exclude_heldout: bool = True
    handover_share: float = 0.0
    structure_weights: tuple[float, ...] = ()

    def __post_init__(self) -> None:
        if not self.structures:
            raise ConfigError("structures is empty; choose at least one of " + ", ".join(STRUCTURE_NAMES))
        unknown = [s for s in self.structures if s not in STRUCTURE_NAMES]
        if unknown:
            raise ConfigError(f"unknown structures {unknown}; choose from {', '.join(STRUCTURE_NAMES)}")
        if len(set(self.structures)) != len(self.structures):
            raise ConfigError(f"structures lists a name twice: {list(self.structures)}")
        by_name = {st.name: st for st in base_structures()}
        if not 0.0 <= self.handover_share <= 1.0:
            raise ConfigError(f"handover_share is a probability in [0, 1], got {self.handover_share}")
        if self.handover_share > 0 and not any(by_name[n].n_regions == 2 for n in self.structures):
            raise ConfigError(
                f"handover_share={self.handover_share} asks for kitchens that need a hand-over, but none of "
                f"the structures {list(self.structures)} is split in two; add forced_coord or "
                "asymm_advantages"
            )
        most_weight = 1e6  # weights are normalised: a larger one only risks overflowing their sum
        if self.structure_weights and (
            len(self.structure_weights) != len(self.structures)
            or not all(0 < w <= most_weight for w in self.structure_weights)
        ):
            raise ConfigError(
                f"structure_weights {list(self.structure_weights)} must give a positive weight to each of "
                f"the {len(self.structures)} structures {list(self.structures)}, in that order, each at most "
                f"{most_weight:g} (to leave a structure out, drop it from structures)"
            )
        if not 0.0 < self.count_decay <= 1.0:
            raise ConfigError(f"count_decay must lie in (0, 1], got {self.count_decay}")
        for name in ("onion_piles", "plate_piles", "pots", "goals"):
            lo, hi = getattr(self, name)
            if not 1 <= lo <= hi:
                raise ConfigError(
                    f"{name} bounds must satisfy 1 <= min <= max (every kitchen needs one of each "
                    f"object for a soup), got ({lo}, {hi})"
                )
        # No kitchen holds more of a kind than its structure has counters for objects (count vectors past
        # that never fit), nor more objects than the 9x9 frame has cells.
        most = max(int(by_name[n].reachable.sum() + (by_name[n].decoy.sum() if self.allow_decoys else 0))
                   for n in self.structures)  # fmt: skip
        for name in ("onion_piles", "plate_piles", "pots", "goals"):
            if getattr(self, name)[1] > most:
                raise ConfigError(
                    f"{name} max {getattr(self, name)[1]} is more than any of the structures "
                    f"{list(self.structures)} has counters for ({most}); lower it to at most {most}"
                )
        if sum(hi for _, hi in self.bounds) > CELLS:
            raise ConfigError(
                f"the maxima of onion_piles, plate_piles, pots and goals add up to "
                f"{sum(hi for _, hi in self.bounds)}, more than the {CELLS} cells of a kitchen; lower them"
            )
        need = sum(lo for lo, _ in self.bounds)
        for name in self.structures:
            st = by_name[name]
            room = int(st.reachable.sum()) - (1 if st.n_regions == 2 else 0)
            if need > room:
                raise ConfigError(
                    f"structure {name!r} has {room} counters for objects"
                    + (" (one is kept bare for hand-overs)" if st.n_regions == 2 else "")
                    + f" but the minimum counts need {need}; lower the minimums or drop {name!r}"
                )

    @property
    def bounds(self) -> tuple[tuple[int, int], ...]:
        """(min, max) per object kind, in `OBJECT_TILES` order."""
        return (self.onion_piles, self.plate_piles, self.pots, self.goals)

    def replace(self, **changes: object) -> GeneratorConfig:
        return dataclasses.replace(self, **changes)  # type: ignore[arg-type]


class GenerationInfo(NamedTuple):
    """How a level was drawn: structure index (into config.structures), transform (0..7), resamples."""

    structure: jax.Array
    transform: jax.Array
    resamples: jax.Array


class _Tables(NamedTuple):
    st: StructureTables
    counts: np.ndarray  # int32[V, 4] count vectors within bounds
    count_cdf: np.ndarray  # float32[S, 2, V]: cumulative probability of the vectors in structure s,
    # without (0) or with (1) a counter reserved for hand-overs (vectors that do not fit have none)


@cache
def _tables(config: GeneratorConfig) -> _Tables:
    by_name = {st.name: st for st in base_structures()}
    structures = tuple(by_name[n] for n in config.structures)
    st = build_tables(structures)
    counts = np.array(list(itertools.product(*(range(lo, hi + 1) for lo, hi in config.bounds))), np.int32)
    room = st.reachable.sum(-1) + (st.decoy.sum(-1) if config.allow_decoys else 0)  # (S,)
    total = counts.sum(-1)
    fits = np.stack([total[None] <= room[:, None], total[None] <= room[:, None] - 1], axis=1)
    lows = np.array([lo for lo, _ in config.bounds])
    weight = np.where(fits, config.count_decay ** (counts - lows).sum(-1), 0.0)
    return _Tables(st, counts, np.cumsum(weight / weight.sum(-1, keepdims=True), -1).astype(np.float32))


def _pick(priority: jax.Array, mask: jax.Array) -> jax.Array:
    """The `mask` cell of highest random priority."""
    return jnp.argmax(jnp.where(mask, priority, -1.0)).astype(jnp.int32)


def _top(priority: jax.Array, mask: jax.Array, k: int) -> jax.Array:
    """int32[..., k]: the `mask` cells of the k highest priorities, in order (a uniformly random ordered
    choice of k distinct cells); the mask must hold at least k cells."""
    return jax.lax.top_k(jnp.where(mask, priority, -1.0), k)[1].astype(jnp.int32)


def _sample(key: jax.Array, config: GeneratorConfig) -> tuple[Level, jax.Array, jax.Array]:
    tb = _tables(config)
    st = {f.name: jnp.asarray(getattr(tb.st, f.name)) for f in dataclasses.fields(tb.st) if f.name != "names"}
    k_prio, k_scalar = jax.random.split(key)
    # Random 16-bit priorities order every choice (random bits are the main cost here). Row 0 is drawn;
    # the witness candidates reuse it XORed with fixed masks, which gives each candidate another uniformly
    # random order. As float32: XLA's CPU top-k is ten times faster on floats than on integers.
    bits = jax.random.bits(k_prio, (CELLS,), jnp.uint16)
    prio = (bits[None, :] ^ jnp.asarray(_CANDIDATE_MASKS)).astype(jnp.float32)  # (1 + tries, 81)
    u = jax.random.uniform(k_scalar, (8,))
    cell_ids = jnp.arange(CELLS)

    # 1. STRUCTURE AND TRANSFORM
    if config.structure_weights:
        weights = np.cumsum(config.structure_weights) / np.sum(config.structure_weights)
        s = jnp.minimum(jnp.sum(u[0] >= jnp.asarray(weights[:-1], jnp.float32)), len(config.structures) - 1)
        s = s.astype(jnp.int32)
    else:
        s = jnp.minimum((u[0] * len(config.structures)).astype(jnp.int32), len(config.structures) - 1)
    t = jnp.minimum((u[1] * NUM_TRANSFORMS).astype(jnp.int32), NUM_TRANSFORMS - 1)
    reachable, shared, access = st["reachable"][s], st["shared"][s], st["access"][s]
    divided = st["divided"][s]

    # 2. WITNESS: with a reserved hand-over counter anything works; without one, take the first candidate
    # whose pot one side can fill while a side that also reaches a plate pile and a goal serves it.
    handover = cell_ids == _pick(prio[0], shared)
    candidates = _top(prio[1:], reachable[None], 4)  # (tries, 4): onion pile, plate pile, pot, goal
    on = access[:, candidates]  # (2 sides, tries, 4 objects)
    works = jnp.any(on[..., 0] & on[..., 2], axis=0) & jnp.any(on[..., 1] & on[..., 3] & on[..., 2], axis=0)
    reserve = divided & ((u[2] < 0.5) | ~jnp.any(works))
    witness = jnp.where(reserve, _top(prio[0], reachable & ~handover, 4), candidates[jnp.argmax(works)])

    # 3. COUNTS AND SUPPLEMENTAL OBJECTS on the remaining counters
    cdf = jnp.asarray(tb.count_cdf)[s, reserve.astype(jnp.int32)]
    pick_count = jnp.sum(cdf <= u[3] * cdf[-1])
    counts = jnp.asarray(tb.counts)[jnp.minimum(pick_count, cdf.shape[0] - 1)]
    grid = jnp.where(st["floor"][s], jnp.uint8(Tile.FLOOR), jnp.uint8(Tile.COUNTER))
    grid = grid.at[witness].set(jnp.asarray(OBJECT_TILES, jnp.uint8))
    room = reachable | (st["decoy"][s] if config.allow_decoys else False)
    free = room & (grid == Tile.COUNTER) & ~(reserve & handover)
    ends = jnp.cumsum(counts - 1)
    max_extra = sum(hi - lo for lo, hi in config.bounds)
    if max_extra:
        spots = _top(prio[0], free, max_extra)  # supplemental objects go to these cells, in this order
        j = jnp.arange(max_extra)
        kind = jnp.asarray(OBJECT_TILES, jnp.uint8)[jnp.minimum(jnp.sum(j[:, None] >= ends[None, :], -1), 3)]
        grid = grid.at[spots].set(jnp.where((j < ends[3]) & free[spots], kind, grid[spots]))

    # 4. AGENTS: one per region in a split kitchen (seats in random order), else two distinct floor cells
    regions = st["region_floor"][s]
    first = _pick(prio[0], regions[0])
    second = _pick(prio[0], regions[1] & (cell_ids != first))
    swap = divided & (u[4] < 0.5)
    agents = jnp.where(swap, jnp.stack([second, first]), jnp.stack([first, second]))

    # 5. TRANSFORM INTO THE 9x9 FRAME
    src, dst = st["src"][s, t], st["dst"][s, t]
    out = jnp.where(src >= 0, grid[jnp.maximum(src, 0)], jnp.uint8(Tile.COUNTER)).reshape(9, 9)
    cells = dst[agents]
    level = Level(
        grid=out,
        agent_pos=jnp.stack([cells // 9, cells % 9], axis=-1).astype(jnp.int32),
        agent_dir=jnp.minimum((u[5:7] * 4).astype(jnp.int32), 3),
        size=st["size"][s, t].astype(jnp.int32),
    )
    return level, s, t


def _exclusions(config: GeneratorConfig, exclude: jax.Array | None) -> jax.Array:
    if exclude is not None:
        return exclude
    with jax.ensure_compile_time_eval():
        fps = heldout_fingerprints() if config.exclude_heldout else np.zeros((0, 2), np.uint32)
    return jnp.asarray(fps)


_WANT_SALT = 0x6B1D  # folded into a level's key for its coverage draw (distinct from the resample indices)


def _wants_handover(key: jax.Array, config: GeneratorConfig) -> jax.Array:
    """Whether the kitchen of `key` must need a hand-over (`config.handover_share`); False when it is 0."""
    if config.handover_share <= 0:
        return jnp.bool_(False)
    return jax.random.uniform(jax.random.fold_in(key, _WANT_SALT)) < config.handover_share


def _rejected(level: Level, config: GeneratorConfig, exclude: jax.Array, want: jax.Array) -> jax.Array:
    """Unsolvable (never, by construction), one of the excluded (evaluation) kitchens, or wanted to need a
    hand-over and does not."""
    excluded = jnp.any(jnp.all(fingerprint(level)[None, :] == exclude, axis=-1))
    rejected = excluded | ~check(level, config.allow_decoys).solvable
    if config.handover_share > 0:
        rejected = rejected | (want & (classify(level).kind != Kind.HANDOVER))
    return rejected


def _draw(key: jax.Array, config: GeneratorConfig, exclude: jax.Array) -> tuple[Level, GenerationInfo]:
    """Samples from `key`, then resamples from `fold_in(key, i)` while the level is rejected."""
    want = _wants_handover(key, config)

    def body(
        carry: tuple[Level, jax.Array, jax.Array, jax.Array],
    ) -> tuple[Level, jax.Array, jax.Array, jax.Array]:
        n = carry[3] + 1
        level, s, t = _sample(jax.random.fold_in(key, n), config)
        return level, s, t, n

    level, s, t = _sample(key, config)
    carry = (level, s, t, jnp.int32(0))
    level, s, t, n = jax.lax.while_loop(lambda c: _rejected(c[0], config, exclude, want), body, carry)
    return level, GenerationInfo(structure=s, transform=t, resamples=n)


@partial(jax.jit, static_argnames=("config",))
def generate_with_info(
    key: jax.Array, config: GeneratorConfig = GeneratorConfig(), exclude: jax.Array | None = None
) -> tuple[Level, GenerationInfo]:
    """`generate`, also returning how the level was drawn (for tests and statistics).

    Args:
        exclude: uint32[E, 2] fingerprints (`cec.levels.fingerprint.fingerprint`) never to emit; default: the
            held-out set when `config.exclude_heldout`, else nothing.
    """
    return _draw(key, config, _exclusions(config, exclude))


def generate(key: jax.Array, config: GeneratorConfig = GeneratorConfig()) -> Level:
    """One solvable kitchen, never a held-out one (unless `config.exclude_heldout` is off).

    Pure and vmappable: `jax.vmap(generate, in_axes=(0, None))(keys, config)` makes a batch.
    """
    return generate_with_info(key, config)[0]


@partial(jax.jit, static_argnames=("n", "config"))
def generate_batch_with_info(
    key: jax.Array, n: int, config: GeneratorConfig = GeneratorConfig()
) -> tuple[Level, jax.Array]:
    """`generate_batch`, also returning int32[n]: how many draws each level rejected (evaluation kitchens,
    and with `handover_share` kitchens of another kind)."""
    keys = jax.random.split(key, n)
    exclude = _exclusions(config, None)
    first = jax.vmap(lambda k: _sample(k, config)[0])(keys)
    wants = jax.vmap(lambda k: _wants_handover(k, config))(keys)
    any_rejected = jnp.any(jax.vmap(lambda lv, w: _rejected(lv, config, exclude, w))(first, wants))

    def redraw() -> tuple[Level, jax.Array]:
        levels, info = jax.vmap(lambda k: _draw(k, config, exclude))(keys)
        return levels, info.resamples

    return jax.lax.cond(any_rejected, redraw, lambda: (first, jnp.zeros(n, jnp.int32)))


def generate_batch(key: jax.Array, n: int, config: GeneratorConfig = GeneratorConfig()) -> Level:
    """`n` kitchens from one key (a batched `Level` with leading axis n); the same levels as vmapping
    `generate` over `split(key, n)`, but the resampling loop only runs when some level needs it (under
    vmap a while loop costs ~15% even when it never iterates)."""
    return generate_batch_with_info(key, n, config)[0]
