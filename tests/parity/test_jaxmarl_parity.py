"""Parity with JaxMARL 0.2.0's Overcooked: same dynamics, rewards and observations on the classic kitchens."""

from __future__ import annotations

import numpy as np
import pytest

pytest.importorskip("jaxmarl", reason="parity tests need the `peers` extra (pip install -e .[peers])")

from cec.envs import overcooked as oc  # noqa: E402
from tests.parity.jaxmarl_bridge import overcooked_layouts, run_parity  # noqa: E402

pytestmark = pytest.mark.parity

EPISODES_PER_LAYOUT = 256  # x 5 layouts x 400 steps = 512k joint steps (each kitchen: >1,000 deliveries)
MAX_STEPS = 400


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_classic_kitchen_matches_jaxmarl_layout(name: str) -> None:
    """Our ASCII kitchen has the same size, objects and start cells as JaxMARL's layout."""
    jm = overcooked_layouts[name]
    level = oc.classic_level(name)
    h, w = int(jm["height"]), int(jm["width"])
    assert tuple(np.asarray(level.size)) == (h, w)
    kitchen = level.kitchen()

    def cells(key: str) -> set[tuple[int, int]]:
        return {(int(i) // w, int(i) % w) for i in np.asarray(jm[key])}

    def ours(tile: int) -> set[tuple[int, int]]:
        return {(int(r), int(c)) for r, c in np.argwhere(kitchen == tile)}

    assert ours(oc_tile("POT")) == cells("pot_idx")
    assert ours(oc_tile("GOAL")) == cells("goal_idx")
    assert ours(oc_tile("ONION_PILE")) == cells("onion_pile_idx")
    assert ours(oc_tile("PLATE_PILE")) == cells("plate_pile_idx")
    assert {(r, c) for r, c in np.argwhere(kitchen != 0)} == cells("wall_idx")
    seats = [(int(i) // w, int(i) % w) for i in np.asarray(jm["agent_idx"])]
    assert [tuple(p) for p in np.asarray(level.agent_pos).tolist()] == seats


def oc_tile(name: str) -> int:
    from cec.levels import Tile

    return int(Tile[name])


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_random_and_scripted_play_matches_jaxmarl(name: str) -> None:
    result = run_parity(name, oc.classic_level(name), EPISODES_PER_LAYOUT, MAX_STEPS, seed=7)
    assert result.counts == dict.fromkeys(result.counts, 0), (
        f"{name}: steps with a disagreement per field {result.counts}, first at {result.first}"
    )
    # The action mix must exercise every rewarded interaction, or the comparison proves little.
    assert result.deliveries > 20
    assert result.onions_in_pot > 100
    assert result.soups_plated > 20
    assert result.plate_bonuses > 0


def test_parity_harness_detects_differences() -> None:
    """Guard against a harness that cannot fail: a different soup reward and episode length on our
    side must show up as shaped-reward, done and observation (urgency channel) disagreements."""
    level = oc.classic_level("cramped_room")
    from tests.parity import jaxmarl_bridge

    ours = oc.EnvParams(soup_pickup_reward=16.0)
    theirs = oc.EnvParams()
    jm_env = jaxmarl_bridge.make_jaxmarl_env("cramped_room", 100, theirs)
    result = run_parity("cramped_room", level, 16, 100, params=ours, jaxmarl_env=jm_env, our_max_steps=90)
    assert result.counts["shaped"] > 0
    assert result.counts["done"] > 0
    assert result.counts["obs"] > 0
    assert result.counts["pos"] == result.counts["pot"] == 0
