"""The 9x9x26 per-seat observation of the paper's code (JaxMARL Overcooked v1 channel list).

Channels (seat i's view; "self" = i, "other" = 1 - i):
    0 self position            1 other position
    2-5 self facing (N, S, E, W), one-hot at the self cell        6-9 other facing
    10 pots   11 bare counters   12 onion piles   13 tomato piles (0)   14 plate piles   15 goals
    16 onions in a pot that is not cooking (0-3)                  17 tomatoes in pot (0)
    18 onions in soup: 3 on cooking/ready pots, loose dishes and a seat holding a dish
    19 tomatoes in soup (0)
    20 cooking time left (19..1 while cooking, else 0)
    21 soup ready: ready pots, loose dishes, a seat holding a dish
    22 plates (loose or held)   23 onions (loose or held)   24 tomatoes (0)
    25 urgency: all ones when fewer than 40 steps remain
Held items count at the holder's cell. Only channels 0-9 differ between the two seats.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from cec.envs.overcooked.state import (
    MAX_ONIONS,
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    URGENCY_STEPS,
    EnvParams,
    EnvState,
)
from cec.levels import GRID_SIZE, Item, Tile

_ROWS = jnp.arange(GRID_SIZE, dtype=jnp.int32)[:, None]
_COLS = jnp.arange(GRID_SIZE, dtype=jnp.int32)[None, :]
_DIRS = jnp.arange(4, dtype=jnp.int32)


def get_obs(state: EnvState, params: EnvParams) -> jax.Array:
    """Both seats' observations.

    Returns:
        uint8[2, 9, 9, 26]: index 0 is seat 0's view, index 1 seat 1's.
    """
    grid = state.level.grid
    pos = state.agent_pos
    # (2, 9, 9) one-hot cell of each seat
    at_agent = (_ROWS[None] == pos[:, 0, None, None]) & (_COLS[None] == pos[:, 1, None, None])
    # (2, 9, 9, 4) facing one-hot at each seat's cell
    facing = at_agent[..., None] & (state.agent_dir[:, None, None, None] == _DIRS)

    # Items per cell: loose items on counters, held items at the holder's cell.
    held = jnp.where(at_agent[0], state.agent_inv[0], jnp.where(at_agent[1], state.agent_inv[1], 0))
    item = jnp.where(at_agent[0] | at_agent[1], held, state.items.astype(jnp.int32))
    dish = item == Item.DISH

    is_pot = grid == Tile.POT
    status = jnp.where(is_pot, state.pot.astype(jnp.int32), POT_EMPTY)
    cooking_or_ready = is_pot & (status < POT_FULL)
    urgent = (params.max_steps - state.time) < URGENCY_STEPS
    zeros = jnp.zeros((GRID_SIZE, GRID_SIZE), jnp.int32)

    env_layers = jnp.stack(
        [
            is_pot,  # 10
            (grid == Tile.COUNTER) & (item == Item.NONE),  # 11
            grid == Tile.ONION_PILE,  # 12
            zeros,  # 13
            grid == Tile.PLATE_PILE,  # 14
            grid == Tile.GOAL,  # 15
            jnp.where(status >= POT_FULL, jnp.minimum(POT_EMPTY - status, MAX_ONIONS), 0),  # 16
            zeros,  # 17
            MAX_ONIONS * (cooking_or_ready | dish),  # 18
            zeros,  # 19
            jnp.where(cooking_or_ready, status, 0),  # 20
            (is_pot & (status == POT_READY)) | dish,  # 21
            item == Item.PLATE,  # 22
            item == Item.ONION,  # 23
            zeros,  # 24
            jnp.broadcast_to(urgent, (GRID_SIZE, GRID_SIZE)),  # 25
        ],
        axis=-1,
    ).astype(jnp.uint8)

    def view(me: int) -> jax.Array:
        other = 1 - me
        agent_layers = jnp.concatenate(
            [at_agent[me, ..., None], at_agent[other, ..., None], facing[me], facing[other]], axis=-1
        ).astype(jnp.uint8)
        return jnp.concatenate([agent_layers, env_layers], axis=-1)

    return jnp.stack([view(0), view(1)])
