"""Jittable solvability check: can the two agents of a level cook and deliver a soup?

Flood fill from each agent gives the floor region it can walk; the counters next to a region are what that
agent can use. A soup needs an onion in a pot (x3), a plate at the ready pot and the dish at a goal. It is
deliverable when

* every object kind is usable by some agent and the agents share their region, or can hand items over
  on a bare counter next to both regions; or
* some pot is usable by an agent that can also reach an onion pile, and by an agent that can also reach
  a plate pile and a goal (one fills it, the other plates and delivers: the pot itself is the hand-over).

`check` returns the verdict and a bitmask of reasons (`Unsolvable`); `explain` turns that into sentences.
"""

from __future__ import annotations

from enum import IntFlag
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.level import GRID_SIZE, Level, Tile, cell_mask


class Unsolvable(IntFlag):
    """Why a level is not solvable (bits of `SolvabilityReport.reasons`)."""

    NO_ONION_PILE = 1
    NO_PLATE_PILE = 2
    NO_POT = 4
    NO_GOAL = 8
    NO_HANDOVER = 16
    DECOY = 32


_MESSAGES = {
    Unsolvable.NO_ONION_PILE: "no agent can reach an onion pile",
    Unsolvable.NO_PLATE_PILE: "no agent can reach a plate pile",
    Unsolvable.NO_POT: "no agent can reach a pot",
    Unsolvable.NO_GOAL: "no agent can reach a goal",
    Unsolvable.NO_HANDOVER: (
        "the agents are in separate regions and cannot combine their objects: no bare counter next to "
        "both regions for a hand-over, and no pot that one side can fill while the other plates and delivers"
    ),
    Unsolvable.DECOY: "an object stands where no agent can reach it (decoys are not allowed)",
}


class SolvabilityReport(NamedTuple):
    """`solvable`: bool[]; `reasons`: int32[] bitmask of `Unsolvable` (0 when solvable)."""

    solvable: jax.Array
    reasons: jax.Array


def adjacent(mask: jax.Array) -> jax.Array:
    """bool[..., 9, 9]: cells with a `mask` cell among their four neighbours (jittable; any leading axes)."""
    p = jnp.pad(mask, [(0, 0)] * (mask.ndim - 2) + [(1, 1), (1, 1)])
    return p[..., :-2, 1:-1] | p[..., 2:, 1:-1] | p[..., 1:-1, :-2] | p[..., 1:-1, 2:]


def flood_from(seeds: jax.Array, floor: jax.Array) -> jax.Array:
    """bool[..., 9, 9]: the floor cells reachable by walking from the `seeds` cells that are floor (jittable;
    any leading axes, `floor` broadcast against `seeds`: a batch grows until none of its regions does)."""

    def grow(state: tuple[jax.Array, jax.Array]) -> tuple[jax.Array, jax.Array]:
        region, _ = state
        bigger = (region | adjacent(region)) & floor
        return bigger, jnp.any(bigger != region)

    region, _ = jax.lax.while_loop(lambda s: s[1], grow, (seeds & floor, jnp.bool_(True)))
    return region


def flood(floor: jax.Array, start: jax.Array) -> jax.Array:
    """bool[9, 9]: floor cells reachable from `start` (a (row, col) cell) by walking."""
    return flood_from(cell_mask(start), floor)


def usable_counters(grid: jax.Array, start: jax.Array) -> jax.Array:
    """bool[9, 9]: the non-floor cells an agent starting at `start` can interact with (next to its region)."""
    floor = grid == Tile.FLOOR
    return adjacent(flood(floor, start)) & ~floor


def reaches(grid: jax.Array, start: jax.Array, tiles: tuple[Tile, ...]) -> jax.Array:
    """bool[len(tiles)]: whether an agent starting at `start` can use a tile of each kind."""
    usable = usable_counters(grid, start)
    return jnp.stack([jnp.any((grid == t) & usable) for t in tiles])


def check(level: Level, allow_decoys: bool | jax.Array = False) -> SolvabilityReport:
    """Solvability of one level (vmap for batches). Pure and jittable.

    Args:
        level: a single `Level` (structurally valid: agents on floor).
        allow_decoys: if false, an object no agent can reach makes the level unsolvable (`DECOY`).
    """
    grid = level.grid
    floor = grid == Tile.FLOOR
    reach = [flood(floor, level.agent_pos[i]) for i in (0, 1)]
    usable = [adjacent(r) & ~floor for r in reach]  # counters each agent can interact with
    connected = jnp.any(reach[0] & reach[1])

    def has(tile: Tile, side: int) -> jax.Array:
        return jnp.any((grid == tile) & usable[side])

    onion = [has(Tile.ONION_PILE, i) for i in (0, 1)]
    plate = [has(Tile.PLATE_PILE, i) for i in (0, 1)]
    goal = [has(Tile.GOAL, i) for i in (0, 1)]
    pots = grid == Tile.POT
    missing = [
        ~(onion[0] | onion[1]),
        ~(plate[0] | plate[1]),
        ~jnp.any(pots & (usable[0] | usable[1])),
        ~(goal[0] | goal[1]),
    ]
    everything = ~(missing[0] | missing[1] | missing[2] | missing[3])
    handover = jnp.any((grid == Tile.COUNTER) & usable[0] & usable[1])
    fill = (usable[0] & onion[0]) | (usable[1] & onion[1])
    serve = (usable[0] & plate[0] & goal[0]) | (usable[1] & plate[1] & goal[1])
    route = jnp.any(pots & fill & serve)
    cookable = (everything & (connected | handover)) | route

    objects = ~floor & (grid != Tile.COUNTER)
    decoy = jnp.any(objects & ~(usable[0] | usable[1])) & ~jnp.asarray(allow_decoys)

    bits = [*missing, everything & ~cookable, decoy]
    flags = [Unsolvable.NO_ONION_PILE, Unsolvable.NO_PLATE_PILE, Unsolvable.NO_POT, Unsolvable.NO_GOAL,
             Unsolvable.NO_HANDOVER, Unsolvable.DECOY]  # fmt: skip
    reasons = sum((jnp.where(b, int(f), 0) for b, f in zip(bits, flags, strict=True)), start=jnp.int32(0))
    return SolvabilityReport(solvable=cookable & ~decoy, reasons=reasons.astype(jnp.int32))


def explain(reasons: int | np.integer | jax.Array) -> list[str]:
    """The sentences behind a reasons bitmask (empty for a solvable level)."""
    value = Unsolvable(int(np.asarray(reasons)))
    return [msg for flag, msg in _MESSAGES.items() if flag in value]


_check_jit = jax.jit(check)


def validate_solvable(level: Level, allow_decoys: bool = False) -> list[str]:
    """Host-side: the reasons a single level is not solvable (an empty list if it is)."""
    if np.shape(level.grid) != (GRID_SIZE, GRID_SIZE):
        raise ValueError(f"validate_solvable takes one level, got grid of shape {np.shape(level.grid)}")
    report = _check_jit(level, allow_decoys)
    return explain(report.reasons)
