"""The `Level` type: a kitchen as fixed-shape data.

A level is a 9x9 grid of static tile codes plus the two agents' start cells and facings. Every kitchen,
classic or generated, has this shape, so one compiled `reset`/`step` serves them all and a batch of
envs can mix kitchens freely (DESIGN.md rule 1). Smaller kitchens sit in the top-left corner of the
frame and the rest of the frame is counters, as in the paper's code.

Coordinates are `(row, col)` with row 0 at the top. Facing indices are the movement action indices:
0 north (row - 1), 1 south (row + 1), 2 east (col + 1), 3 west (col - 1).
"""

from __future__ import annotations

from collections.abc import Sequence
from enum import IntEnum

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

GRID_SIZE = 9
NUM_AGENTS = 2


class Tile(IntEnum):
    """Static content of a cell. Agents walk only on FLOOR; every other tile is a counter-like surface."""

    FLOOR = 0
    COUNTER = 1
    ONION_PILE = 2
    PLATE_PILE = 3
    POT = 4
    GOAL = 5  # delivery window


class Item(IntEnum):
    """What an agent holds, or what lies on a counter."""

    NONE = 0
    ONION = 1
    PLATE = 2
    DISH = 3  # a plated soup


class Direction(IntEnum):
    """Facing / movement direction; equal to the movement action with the same name."""

    NORTH = 0
    SOUTH = 1
    EAST = 2
    WEST = 3


# (d_row, d_col) per Direction, in Direction order.
DIR_VEC = np.array([(-1, 0), (1, 0), (0, 1), (0, -1)], dtype=np.int32)

_ROWS = np.arange(GRID_SIZE, dtype=np.int32)[:, None]
_COLS = np.arange(GRID_SIZE, dtype=np.int32)[None, :]


def cell_mask(cell: jax.Array) -> jax.Array:
    """bool[..., 9, 9]: True at `cell` = (row, col) in the last axis; all False outside the frame."""
    cell = jnp.asarray(cell)
    return (cell[..., 0, None, None] == _ROWS) & (cell[..., 1, None, None] == _COLS)


#: Tiles every solvable kitchen needs at least one of.
REQUIRED_TILES = (Tile.ONION_PILE, Tile.PLATE_PILE, Tile.POT, Tile.GOAL)


class LevelError(ValueError):
    """A level (or its ASCII source) is malformed. The message names the cause and the fix."""


@struct.dataclass
class Level:
    """A kitchen. All fields are arrays so that levels stack into batches and pass through `jit`.

    Attributes:
        grid: uint8[9, 9] `Tile` codes.
        agent_pos: int32[2, 2] start cell `(row, col)` of seat 0 and seat 1.
        agent_dir: int32[2] start facing (`Direction`) of each seat; used when the env does not
            randomise start facings.
        size: int32[2] `(height, width)` of the kitchen inside the frame (its top-left corner);
            the rest of the frame is counters. Used for rendering and for mapping to native layouts.
    """

    grid: jax.Array
    agent_pos: jax.Array
    agent_dir: jax.Array
    size: jax.Array

    @classmethod
    def create(
        cls,
        grid: np.ndarray | Sequence[Sequence[int]],
        agent_pos: np.ndarray | Sequence[Sequence[int]],
        agent_dir: np.ndarray | Sequence[int] = (Direction.NORTH, Direction.NORTH),
        size: tuple[int, int] | None = None,
    ) -> Level:
        """Builds a level from Python/NumPy data, validating it (raises `LevelError`).

        `grid` may be smaller than 9x9; it is then placed in the top-left corner and padded with counters.
        """
        g = np.asarray(grid)
        if g.ndim != 2 or g.shape[0] > GRID_SIZE or g.shape[1] > GRID_SIZE or g.size == 0:
            raise LevelError(
                f"grid must be a 2-D array of at most {GRID_SIZE}x{GRID_SIZE} tiles, got shape "
                f"{g.shape}; crop or split the kitchen so it fits the {GRID_SIZE}x{GRID_SIZE} frame"
            )
        h, w = g.shape
        frame = np.full((GRID_SIZE, GRID_SIZE), Tile.COUNTER, dtype=np.int64)
        frame[:h, :w] = g
        raw = cls(
            grid=frame,  # type: ignore[arg-type]
            agent_pos=np.asarray(agent_pos),  # type: ignore[arg-type]
            agent_dir=np.asarray(agent_dir),  # type: ignore[arg-type]
            size=np.asarray(size if size is not None else (h, w)),  # type: ignore[arg-type]
        )
        # Validate the raw inputs (before any dtype cast could wrap out-of-range values).
        validate_level(raw)
        return cls(
            grid=jnp.asarray(frame, dtype=jnp.uint8),
            agent_pos=jnp.asarray(raw.agent_pos, dtype=jnp.int32),
            agent_dir=jnp.asarray(raw.agent_dir, dtype=jnp.int32),
            size=jnp.asarray(raw.size, dtype=jnp.int32),
        )

    def kitchen(self) -> np.ndarray:
        """The kitchen's own tiles (without the counter padding), as a NumPy array."""
        h, w = (int(v) for v in np.asarray(self.size))
        return np.asarray(self.grid)[:h, :w]


def validate_level(level: Level) -> None:
    """Checks a single (unbatched, concrete) level and raises `LevelError` naming the first problem.

    Checks: shapes, tile codes, the kitchen size, the padding being counters, at least one onion pile,
    plate pile, pot and goal, and both agents on distinct floor cells with valid facings. Reachability and
    solvability are the job of `cec.levels.solvability`, not of this structural check.
    """
    grid, pos, dirs, size = (
        np.asarray(x) for x in (level.grid, level.agent_pos, level.agent_dir, level.size)
    )

    if grid.shape != (GRID_SIZE, GRID_SIZE):
        raise LevelError(
            f"level grid must have shape ({GRID_SIZE}, {GRID_SIZE}), got {grid.shape}; build levels with "
            "Level.create or cec.levels.from_ascii, which pad smaller kitchens"
        )
    bad = sorted({int(v) for v in np.unique(grid)} - {int(t) for t in Tile})
    if bad:
        raise LevelError(
            f"level grid holds unknown tile codes {bad}; valid codes are "
            + ", ".join(f"{t.value}={t.name}" for t in Tile)
        )
    if size.shape != (2,) or not (1 <= size[0] <= GRID_SIZE and 1 <= size[1] <= GRID_SIZE):
        raise LevelError(f"level size must be (height, width) within 1..{GRID_SIZE}, got {size.tolist()}")
    h, w = int(size[0]), int(size[1])
    outside = np.ones_like(grid, dtype=bool)
    outside[:h, :w] = False
    if np.any(grid[outside] != Tile.COUNTER):
        raise LevelError(
            f"cells outside the {h}x{w} kitchen must be counters (the frame padding); enlarge `size` or "
            "move those tiles inside the kitchen"
        )
    counts = {t: int(np.sum(grid == t)) for t in REQUIRED_TILES}
    missing = [t.name.lower() for t, n in counts.items() if n == 0]
    if missing:
        raise LevelError(
            f"level has no {', '.join(missing)}; a kitchen needs at least one onion pile, plate pile, "
            "pot and goal"
        )
    if pos.shape != (NUM_AGENTS, 2):
        raise LevelError(f"agent_pos must have shape (2, 2) as (row, col) per seat, got {pos.shape}")
    for seat, (r, c) in enumerate(pos.tolist()):
        if not (0 <= r < h and 0 <= c < w):
            raise LevelError(f"agent {seat} start cell (row={r}, col={c}) lies outside the {h}x{w} kitchen")
        if grid[r, c] != Tile.FLOOR:
            raise LevelError(
                f"agent {seat} starts on a {Tile(int(grid[r, c])).name.lower()} at (row={r}, col={c}); "
                "agents must start on floor cells"
            )
    if tuple(pos[0]) == tuple(pos[1]):
        raise LevelError(f"both agents start on the same cell {tuple(pos[0].tolist())}")
    if dirs.shape != (NUM_AGENTS,) or np.any((dirs < 0) | (dirs > 3)):
        raise LevelError(
            f"agent_dir must be two facings in 0..3 (north, south, east, west), got {dirs.tolist()}"
        )


def stack_levels(levels: Sequence[Level]) -> Level:
    """Stacks levels into one batched `Level` (leading axis = level index)."""
    if not levels:
        raise LevelError("cannot stack an empty sequence of levels")
    return jax.tree.map(lambda *xs: jnp.stack(xs), *levels)


def unstack_levels(levels: Level) -> list[Level]:
    """Splits a batched `Level` into a list of single levels."""
    n = int(levels.grid.shape[0])
    return [jax.tree.map(lambda x, i=i: x[i], levels) for i in range(n)]
