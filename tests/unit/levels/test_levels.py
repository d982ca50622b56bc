"""The Level type, its ASCII codec and structural validation."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.envs import overcooked as oc
from cec.levels import (
    Direction,
    Level,
    LevelError,
    Tile,
    from_ascii,
    stack_levels,
    to_ascii,
    unstack_levels,
)


def assert_same_level(a: Level, b: Level) -> None:
    for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True):
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_classic_ascii_round_trip(name: str) -> None:
    level = oc.classic_level(name)
    assert to_ascii(level) == oc.CLASSIC_ASCII[name].strip("\n")
    assert_same_level(from_ascii(to_ascii(level)), level)


def test_round_trip_keeps_facings() -> None:
    level = oc.classic_level("coord_ring").replace(
        agent_dir=jnp.asarray([Direction.EAST, Direction.SOUTH], jnp.int32)
    )
    text = to_ascii(level)
    assert text.endswith("facing: E S")
    assert_same_level(from_ascii(text), level)


def test_small_kitchen_is_padded_with_counters_in_the_top_left() -> None:
    level = oc.classic_level("cramped_room")
    grid = np.asarray(level.grid)
    assert grid.shape == (9, 9)
    assert tuple(np.asarray(level.size)) == (4, 5)
    assert (grid[4:, :] == Tile.COUNTER).all() and (grid[:, 5:] == Tile.COUNTER).all()
    assert grid[0, 2] == Tile.POT


def test_a_marks_give_reading_order_seats() -> None:
    level = from_ascii("WWPWW\nOA AO\nW   W\nWBWXW")
    assert np.asarray(level.agent_pos).tolist() == [[1, 1], [1, 3]]


@pytest.mark.parametrize(
    ("text", "message"),
    [
        ("", "empty"),
        ("WWPWW\nO0 1O\nW  W\nWBWXW", "row 2 has 4 characters"),
        ("WWPWW\nO0 1Q\nW   W\nWBWXW", "unknown character 'Q' at row 1, column 4"),
        ("WWPWW\nO0  O\nW   W\nWBWXW", "marks for seat 1"),
        ("WWPWW\nO0 0O\nW 1 W\nWBWXW", "2 marks for seat 0"),
        ("WWPWW\nOA  O\nW   W\nWBWXW", "found 1 'A'"),
        ("WWPWW\nOA 1O\nW   W\nWBWXW", "mix of 'A' and '0'/'1'"),
        ("WWWWW\nO0 1O\nW   W\nWBWXW", "no pot"),
        ("WWPWW\nW0 1W\nW   W\nWWWWW", "no onion_pile, plate_pile, goal"),
        ("WWPWW\nO0 1O\nW   W\nWBWXW\nfacing: N Q", "bad facing line"),
        ("W" * 10 + "\n" + "O0 1PBXWWW", "at most 9x9"),
    ],
)
def test_malformed_ascii_names_the_cause(text: str, message: str) -> None:
    with pytest.raises(LevelError, match=message):
        from_ascii(text)


def test_agent_on_a_wall_is_rejected() -> None:
    grid = np.asarray(oc.classic_level("cramped_room").kitchen())
    with pytest.raises(LevelError, match=r"agent 1 starts on a counter at \(row=0, col=0\)"):
        Level.create(grid, [(1, 1), (0, 0)])
    with pytest.raises(LevelError, match="same cell"):
        Level.create(grid, [(1, 1), (1, 1)])
    with pytest.raises(LevelError, match="outside the 4x5 kitchen"):
        Level.create(grid, [(1, 1), (6, 6)])
    with pytest.raises(LevelError, match="facings in 0..3"):
        Level.create(grid, [(1, 1), (1, 2)], agent_dir=[0, 4])
    with pytest.raises(LevelError, match="unknown tile codes"):
        Level.create(np.where(grid == Tile.POT, 9, grid), [(1, 1), (1, 2)])


def test_reset_validates_concrete_levels() -> None:
    level = oc.classic_level("cramped_room")
    broken = level.replace(agent_pos=jnp.asarray([[0, 0], [1, 1]], jnp.int32))
    with pytest.raises(LevelError, match="agent 0 starts on a counter"):
        oc.reset(jnp.zeros(2, jnp.uint32), broken)


def test_stack_and_unstack() -> None:
    levels = list(oc.classic_levels().values())
    batch = stack_levels(levels)
    assert batch.grid.shape == (5, 9, 9)
    for a, b in zip(unstack_levels(batch), levels, strict=True):
        assert_same_level(a, b)
    with pytest.raises(LevelError):
        stack_levels([])
