"""Chores of a soup read from an episode: an onion taken from the pile and put in the pot, an item put on a
counter and taken back at once, and the scripted cook's episode, whose chain of chores must add up."""

from __future__ import annotations

import numpy as np
import pytest

from cec.agents.policy import load_policies
from cec.agents.zoo import ZooEntry
from cec.envs.overcooked.state import Action
from cec.evaluation.chores import Chores, count_chores
from cec.evaluation.crossplay import episode_states, eval_levels
from cec.levels import Item, Tile
from cec.levels.classic import classic_level
from cec.levels.level import unstack_levels
from tests.scripts import research
from tests.unit.evaluation.test_handovers import _episode as episode

A = Action


ONION = [(A.LEFT, A.STAY), (A.INTERACT, A.STAY)]  # face the pile, take an onion


def _episode(actions: list[tuple[Action, Action]]) -> object:
    """Cramped Room: seat 0 starts at (1, 1) beside the onion pile on its left, the pot above-right."""
    return episode(actions, "cramped_room")


def test_an_onion_from_the_pile_into_the_pot() -> None:
    chores = count_chores(_episode([*ONION, (A.RIGHT, A.STAY), (A.UP, A.STAY), (A.INTERACT, A.STAY)]))
    assert chores.onions_taken.tolist() == [1, 0] and chores.onions_in.tolist() == [1, 0]
    assert chores.put_down.tolist() == [0, 0] and chores.soups.tolist() == [0, 0]
    assert chores.carrying[0, Item.ONION] == 3  # held over the three steps after taking it
    assert chores.soups_ready == 0 and chores.ready_wait == 0


def test_an_item_put_on_a_counter_and_taken_again_at_once_is_dithering() -> None:
    walk = [(A.DOWN, A.STAY), (A.LEFT, A.STAY)]  # to (2, 1), then face the bare counter at (2, 0)
    chores = count_chores(_episode([*ONION, *walk, (A.INTERACT, A.STAY), (A.INTERACT, A.STAY)]))
    assert chores.put_down.tolist() == [1, 0] and chores.taken_back_soon.tolist() == [1, 0]
    assert chores.soups_put_down.tolist() == [0, 0]  # an onion, not a soup
    assert chores.onions_in.tolist() == [0, 0]
    assert chores.still[1] > 0  # the other seat stayed put throughout


def test_the_cooks_chain_of_chores_adds_up() -> None:
    """Two scripted cooks in Cramped Room: every delivered soup was plated, every plated soup cooked, every
    cooked soup took three onions, and the soups delivered are the team return's (20 each)."""
    [cook] = load_policies([ZooEntry("cook", "", scripted="cook")])[0]
    levels = eval_levels("overcooked", "cramped_room")
    states, team_return = episode_states(
        cook, cook, unstack_levels(levels.levels)[0], "cramped_room", max_steps=200
    )
    chores = count_chores(states)
    soups = int(chores.soups.sum())
    assert soups >= 3 and 20 * soups == team_return
    assert int(chores.soups_plated.sum()) >= soups and chores.soups_ready >= int(chores.soups_plated.sum())
    assert int(chores.onions_in.sum()) >= 3 * chores.soups_ready
    assert int(chores.plates_taken.sum()) >= int(chores.soups_plated.sum())
    assert chores.carrying.sum() == 2 * (len(states.agent_inv) - 1)  # both seats, every step taken
    per = chores.per_episode(1)
    assert abs(sum(per["carrying"].values()) - 1.0) < 1e-9 and per["soups"] == soups


def test_counter_circuits_variants_keep_its_floor_and_its_objects() -> None:
    """`research/analyses/chores.py`'s variants move one thing each: the floor (turned 180 degrees for the
    control)
    and the number of each object stay Counter Circuit's; an unknown part is refused with the choices."""
    chores = research("chores")
    base = np.asarray(classic_level("counter_circuit").grid)
    parts = chores._parts(list(chores.VARIANTS))
    for name, levels in parts.items():
        grid = np.asarray(levels[name].grid)
        floor = grid == Tile.FLOOR
        expected = (
            np.rot90(base[:5, :8] == Tile.FLOOR, 2)
            if name.endswith("rotated")
            else base[:5, :8] == Tile.FLOOR
        )
        assert (floor[:5, :8] == expected).all(), name
        for tile in (Tile.ONION_PILE, Tile.PLATE_PILE, Tile.POT, Tile.GOAL):
            assert (grid == tile).sum() == (base == tile).sum(), (name, tile)
    moved = np.argwhere(
        np.asarray(parts["counter_circuit/window_on_island"]["counter_circuit/window_on_island"].grid)
        == Tile.GOAL
    )
    assert moved.tolist() == [[2, 4]]
    with pytest.raises(SystemExit, match="window_top"):
        chores._parts(["counter_circuit/nowhere"])


def test_the_table_has_a_column_per_part_and_group() -> None:
    chores = research("chores")
    per = Chores.zero().per_episode(1)
    result = {"counter_circuit": {"levels": 1, "xp": {"episodes": 2, "return": 15.0, **per}}}
    text = chores.table(result)
    assert "| per 400-step episode | counter_circuit: xp |" in text
    assert "| team return per episode | 15.0 |" in text and "| soups delivered | 0.0 |" in text
