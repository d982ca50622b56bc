"""Levels as data: the `Level` type, its ASCII codec and structural validation."""

from cec.levels.ascii import from_ascii, to_ascii
from cec.levels.level import (
    DIR_VEC,
    GRID_SIZE,
    NUM_AGENTS,
    Direction,
    Item,
    Level,
    LevelError,
    Tile,
    cell_mask,
    stack_levels,
    unstack_levels,
    validate_level,
)

__all__ = [
    "DIR_VEC",
    "GRID_SIZE",
    "NUM_AGENTS",
    "Direction",
    "Item",
    "Level",
    "LevelError",
    "Tile",
    "cell_mask",
    "from_ascii",
    "stack_levels",
    "to_ascii",
    "unstack_levels",
    "validate_level",
]
