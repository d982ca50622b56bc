"""What a kitchen asks of its two cooks: can each seat finish a soup alone, is there a loop to run round?

Every evaluation reads its scores by kitchen kind, because the skills differ: a kitchen where neither seat
can finish a soup alone needs a hand-over across a counter (Forced Coordination), one where a seat can
finish alone only needs the two to keep out of each other's way. A seat *can finish alone* when the
counters next to the floor region it starts in (`cec.levels.solvability.reaches`) hold an onion pile, a pot,
a plate pile and a goal.

    kind     HANDOVER    neither seat can finish alone (a hand-over is needed: an item put on a counter
                         or a pot that the other seat can reach)
             ONE_ALONE   exactly one seat can (the other can only help)
             BOTH_ALONE  both can (every kitchen whose seats share a floor region)
    loop     the floor runs round an island of counters (Counter Circuit, Coordination Ring): the cooks can
             pass each other by going the other way round

`classify` is pure and jittable (vmap it for batches; the generator uses it to draw kinds on demand);
`kind_of` / `kinds_of` are the host-side readings with names.
"""

from __future__ import annotations

from collections.abc import Mapping
from enum import IntEnum
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.classic import CLASSIC_ASCII
from cec.levels.heldout import DRAWN_PREFIX
from cec.levels.level import REQUIRED_TILES, Level, Tile, stack_levels
from cec.levels.solvability import reaches


class Kind(IntEnum):
    """How many seats can finish a soup alone."""

    HANDOVER = 0
    ONE_ALONE = 1
    BOTH_ALONE = 2

    @property
    def label(self) -> str:
        return {0: "hand-over needed", 1: "one seat alone", 2: "both seats alone"}[int(self)]


class KitchenKind(NamedTuple):
    """`kind`: int32[] (a `Kind`); `alone`: bool[2], whether each seat can finish alone; `loop`: bool[]."""

    kind: jax.Array
    alone: jax.Array
    loop: jax.Array


def _grow8(mask: jax.Array, within: jax.Array) -> jax.Array:
    """`mask` flooded through `within` with 8-neighbourhood steps."""

    def grow(state: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        region, _ = state
        p = jnp.pad(region, 1)
        near = jnp.zeros_like(region)
        for dr in (0, 1, 2):
            for dc in (0, 1, 2):
                near = near | p[dr : dr + region.shape[0], dc : dc + region.shape[1]]
        bigger = near & within
        return bigger, jnp.any(bigger != region)

    return jax.lax.while_loop(lambda s: s[1], grow, (mask & within, jnp.bool_(True)))[0]


def classify(level: Level) -> KitchenKind:
    """The kind of one level (jittable; vmap for batches)."""
    grid = level.grid
    floor = grid == Tile.FLOOR
    both = jnp.stack([jnp.all(reaches(grid, level.agent_pos[seat], REQUIRED_TILES)) for seat in (0, 1)])
    # An island: counters that no chain of counters (8-neighbours: walking needs a 4-connected gap) joins
    # to the frame's edge. The floor round it is a loop.
    edge = jnp.zeros_like(floor).at[0, :].set(True).at[-1, :].set(True).at[:, 0].set(True).at[:, -1].set(True)
    attached = _grow8(edge & ~floor, ~floor)
    loop = jnp.any(~floor & ~attached)
    return KitchenKind(kind=jnp.sum(both).astype(jnp.int32), alone=both, loop=loop)


_classify_batch = jax.jit(jax.vmap(classify))


def kinds_of(levels: Mapping[str, Level]) -> dict[str, tuple[Kind, bool]]:
    """{name: (kind, loop)} for named single levels (host-side)."""
    if not levels:
        return {}
    names = list(levels)
    out = _classify_batch(stack_levels([levels[n] for n in names]))
    kinds, loops = np.asarray(out.kind), np.asarray(out.loop)
    return {n: (Kind(int(k)), bool(lp)) for n, k, lp in zip(names, kinds, loops, strict=True)}


LOOP = "loop"


def subsets(levels: Mapping[str, Level]) -> dict[str, list[str]]:
    """{subset: level names} of every kind that `levels` hold, in `Kind` order, then those with a loop
    (`LOOP`); the names keep the order of `levels`. How every evaluation splits its scores by kind."""
    kinds = kinds_of(levels)
    out = {k.label: [n for n, (kind, _) in kinds.items() if kind == k] for k in Kind}
    out[LOOP] = [n for n, (_, loop) in kinds.items() if loop]
    return {name: names for name, names in out.items() if names}


def validation_parts(levels: Mapping[str, Level]) -> dict[str, list[str]]:
    """{part: level names} of an evaluation set as every report splits it: its generated kitchens (named
    `generated_*`, `test_*` or `test2_*`; the headline), those by kind (`subsets`), the rest (the classic or
    drawn kitchens) together and each on its own."""
    generated = {n: lv for n, lv in levels.items() if n.startswith(("generated_", "test_", "test2_"))}
    rest = [n for n in levels if n not in generated]
    label = (
        "classic"
        if set(rest) <= set(CLASSIC_ASCII)
        else "drawn"
        if all(n.startswith(DRAWN_PREFIX) for n in rest)
        else "named"
    )
    return {"generated": list(generated), **subsets(generated), label: rest, **{n: [n] for n in rest}}


def kind_of(level: Level) -> tuple[Kind, bool]:
    """(kind, loop) of one level (host-side)."""
    return kinds_of({"level": level})["level"]
