"""The region channels (a lever, not the paper's observation): what each seat can walk to and use, read
off the 26-channel view alone, equal the flood fill of the kitchen's own grid, whatever lies on the
counters and whoever holds what."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.observation import get_obs, region_channels
from cec.envs.overcooked.state import EnvParams
from cec.levels import Tile
from cec.levels.classic import classic_level
from cec.levels.generator import generate_batch
from cec.levels.solvability import adjacent, flood


def _expected(state) -> np.ndarray:
    """uint8[2, 9, 9, 4]: each seat's own floor, the other's, and the cells next to each (from the grid)."""
    grid = state.level.grid
    floor = grid == Tile.FLOOR
    regions = [flood(floor, state.agent_pos[s]) for s in (0, 1)]
    usable = [adjacent(r) & ~floor for r in regions]
    views = [jnp.stack([regions[me], regions[1 - me], usable[me], usable[1 - me]], -1) for me in (0, 1)]
    return np.asarray(jnp.stack(views)).astype(np.uint8)


def test_region_channels_equal_the_flood_fill_of_the_grid_in_generated_kitchens_mid_episode() -> None:
    params = EnvParams()
    levels = generate_batch(jax.random.PRNGKey(3), 24)
    play = jax.jit(
        lambda key, level: jax.lax.scan(
            lambda st, k: (step(k, st, jax.random.randint(k, (2,), 0, 6), params).state, None),
            reset(key, level, params)[1],
            jax.random.split(key, 60),
        )[0]
    )
    checked_items = 0
    for i in range(24):
        level = jax.tree.map(lambda x, i=i: x[i], levels)
        state = play(jax.random.PRNGKey(i), level)
        obs = get_obs(state, params)
        got = np.asarray(jax.jit(region_channels)(obs))
        np.testing.assert_array_equal(got, _expected(state))
        checked_items += int(np.count_nonzero(np.asarray(state.items)) + np.count_nonzero(state.agent_inv))
    assert checked_items > 0  # random play left items on counters or in hands: those cells were tested


def test_in_forced_coordination_the_middle_counter_is_the_only_cell_both_seats_use() -> None:
    params = EnvParams()
    obs, _ = reset(jax.random.PRNGKey(0), classic_level("forced_coord"), params)
    ch = np.asarray(region_channels(obs))  # [2 seats, 9, 9, 4]
    both = (ch[0, ..., 2] & ch[0, ..., 3]).astype(bool)
    grid = np.asarray(classic_level("forced_coord").grid)
    assert both.any() and (grid[both] == Tile.COUNTER).all()  # hand-overs go across bare counters
    assert not (ch[0, ..., 0] & ch[0, ..., 1]).any()  # two floors that never meet
    np.testing.assert_array_equal(ch[0, ..., [0, 2]], ch[1, ..., [1, 3]])  # the other seat's view, swapped
    assert ch[0, ..., 0].sum() and ch[0, ..., 1].sum()
