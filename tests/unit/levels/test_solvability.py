"""The jittable solvability check and its reasons, on hand-made kitchens."""

from __future__ import annotations

import jax
import numpy as np
import pytest

from cec.envs import overcooked as oc
from cec.levels import from_ascii, stack_levels
from cec.levels.solvability import Unsolvable, check, validate_solvable


def reasons(text: str, allow_decoys: bool = False) -> Unsolvable:
    return Unsolvable(int(check(from_ascii(text), allow_decoys).reasons))


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_classic_kitchens_are_solvable_with_their_decoy_free_objects(name: str) -> None:
    assert validate_solvable(oc.classic_level(name)) == []


def test_batched_check_matches_single() -> None:
    levels = list(oc.classic_levels().values())
    report = jax.jit(jax.vmap(check))(stack_levels(levels))
    assert np.asarray(report.solvable).all()


def test_missing_kinds_are_named() -> None:
    # the only onion pile sits in a corner no floor cell touches
    kitchen = "OWWWW\nWPWWW\nW0 1W\nWWBXW"
    assert reasons(kitchen) == Unsolvable.NO_ONION_PILE | Unsolvable.DECOY
    assert reasons(kitchen, allow_decoys=True) == Unsolvable.NO_ONION_PILE


def test_split_kitchen_with_a_bare_shared_counter_hands_over() -> None:
    # left: onion, plate; right: pot, goal; middle column counter (1,2) is bare and shared
    assert reasons("WWWWW\nO0W1P\nB W X\nWWWWW") == 0


def test_split_kitchen_without_handover_or_route_is_unsolvable() -> None:
    # onions only on the left, the only pot on the right; the shared counters hold a plate pile and a
    # goal, so no onion can cross
    kitchen = "WWWWW\nO0B1P\nW X W\nWWWWW"
    assert reasons(kitchen) == Unsolvable.NO_HANDOVER
    assert "hand-over" in validate_solvable(from_ascii(kitchen))[0]


def test_shared_pot_is_a_handover_route() -> None:
    # left fills the shared pot with onions; right brings plates, takes the soup and delivers
    assert reasons("WWWWW\nO0P1B\nW X W\nWWWWW") == 0
    # ... but not if no side reaches both a plate pile and a goal
    assert reasons("WWWWW\nO0P1B\nX O W\nWWWWW") == Unsolvable.NO_HANDOVER


def test_agents_in_one_region_need_no_handover() -> None:
    assert reasons("WWOWW\nW0 1W\nWPBXW") == 0
