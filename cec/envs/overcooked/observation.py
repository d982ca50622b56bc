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

How it is computed: everything a cell shows depends only on a small per-cell code (its tile, the item on
it or held there, the pot status, which seat stands there and its facing, and the urgency flag), 128
codes in all. `OBS_TABLE[code]` holds the 26 channel values of each code, built once below from the
channel definitions; `get_obs` computes the codes with a few elementwise ops and gathers the table rows.
This is several times faster than assembling 26 layers, and it is checked cell for cell against JaxMARL.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs.overcooked.state import (
    MAX_ONIONS,
    NUM_CHANNELS,
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    URGENCY_STEPS,
    EnvParams,
    EnvState,
)
from cec.levels import Item, Tile, cell_mask
from cec.levels.solvability import adjacent, flood_from

# CELL CODES: floor 0 (empty) or 1 + 16*is_other + 4*facing + held (a seat stands there), counters
# 33 + item, onion pile 37, plate pile 38, goal 39, pots 40 + status; +64 when urgent.
_AGENT_BASE = 1
_COUNTER_BASE = 33
_POT_BASE = 40
_URGENT = 64
NUM_CODES = 128
_TILE_BASE = np.zeros(len(Tile), np.int32)
_TILE_BASE[Tile.COUNTER] = _COUNTER_BASE
_TILE_BASE[Tile.ONION_PILE] = 37
_TILE_BASE[Tile.PLATE_PILE] = 38
_TILE_BASE[Tile.GOAL] = 39
_TILE_BASE[Tile.POT] = _POT_BASE


def _item_channels(row: np.ndarray, item: int) -> None:
    """Channels of a loose or held item."""
    if item == Item.ONION:
        row[23] = 1
    elif item == Item.PLATE:
        row[22] = 1
    elif item == Item.DISH:
        row[18] = MAX_ONIONS
        row[21] = 1


def _build_table() -> np.ndarray:
    table = np.zeros((NUM_CODES, NUM_CHANNELS), np.uint8)
    for is_other in (0, 1):
        for facing in range(4):
            for held in Item:
                row = table[_AGENT_BASE + 16 * is_other + 4 * facing + held]
                row[is_other] = 1  # 0 self / 1 other position
                row[2 + 4 * is_other + facing] = 1  # 2-5 self / 6-9 other facing
                _item_channels(row, held)
    for item in Item:
        row = table[_COUNTER_BASE + item]
        row[11] = item == Item.NONE  # bare counter
        _item_channels(row, item)
    table[_TILE_BASE[Tile.ONION_PILE], 12] = 1
    table[_TILE_BASE[Tile.PLATE_PILE], 14] = 1
    table[_TILE_BASE[Tile.GOAL], 15] = 1
    for status in range(POT_EMPTY + 1):
        row = table[_POT_BASE + status]
        row[10] = 1
        if status >= POT_FULL:
            row[16] = min(POT_EMPTY - status, MAX_ONIONS)  # onions in a pot not yet cooking
        else:
            row[18] = MAX_ONIONS  # onions in soup
            row[20] = status  # cooking time left (0 when ready)
        row[21] = status == POT_READY
    table[_URGENT:] = table[:_URGENT]
    table[_URGENT:, 25] = 1
    return table


OBS_TABLE = _build_table()

_OBS_TABLE = jnp.asarray(OBS_TABLE)


def cell_codes(state: EnvState, params: EnvParams) -> jax.Array:
    """uint8[2, 9, 9]: each cell's code as seen by seat 0 and by seat 1."""
    u8 = jnp.uint8
    grid = state.level.grid
    # Per-tile base code, as compares rather than a table lookup (XLA vectorises these).
    static = sum(
        (jnp.where(grid == tile, u8(base), u8(0)) for tile, base in enumerate(_TILE_BASE) if base),
        start=jnp.zeros_like(grid),
    )
    dynamic = jnp.where(grid == Tile.COUNTER, state.items, u8(0)) + jnp.where(
        grid == Tile.POT, state.pot, u8(0)
    )
    urgent = jnp.where((params.max_steps - state.time) < URGENCY_STEPS, u8(_URGENT), u8(0))
    base = static + dynamic + urgent
    pos = state.agent_pos
    at = cell_mask(pos)  # (2, 9, 9)
    seat_code = (_AGENT_BASE + 4 * state.agent_dir + state.agent_inv).astype(u8)  # (2,)

    def view(me: jax.Array) -> jax.Array:
        other = 1 - me
        return (
            base
            + jnp.where(at[me], seat_code[me], u8(0))
            + jnp.where(at[other], seat_code[other] + u8(16), u8(0))
        )

    # A two-trip loop rather than a stack: its result is a real buffer, which keeps XLA from fusing
    # this whole computation into every one of the 26 channels the observation gather writes.
    return jax.lax.map(view, jnp.arange(2))


# Channels that mark a cell nobody walks on (pots, bare counters, piles, goals), and those of an item: an
# item on a cell without a seat lies on a counter.
_TILE_CHANNELS = (10, 11, 12, 13, 14, 15)
_ITEM_CHANNELS = (18, 21, 22, 23, 24)


def region_channels(obs: jax.Array) -> jax.Array:
    """[..., H, W, 26] observations -> uint8[..., H, W, 4], what each seat can reach, read off the view
    alone: 0 the floor the viewing seat can walk to, 1 the other seat's, 2 the cells it can use (pots,
    counters, piles, goals next to its floor), 3 those the other seat can use. A counter marked in both 2
    and 3 is where the two can hand items over; a pile marked only in 3 is one the viewer must be handed.

    Not in the paper's observation: the network appends these with `NetworkConfig.region_channels` (a
    lever of docs/reproduce_overcooked.md). `cec.levels.solvability.flood_from` over the floor the view
    shows (a seat does not block the other's region), batched over the leading axes.
    """
    tiles = jnp.any(obs[..., _TILE_CHANNELS] > 0, axis=-1)
    seats = (obs[..., 0] > 0) | (obs[..., 1] > 0)
    floor = ~tiles & ~(jnp.any(obs[..., _ITEM_CHANNELS] > 0, axis=-1) & ~seats)
    floors = floor[..., None, :, :]  # against the two seats' regions
    region = flood_from(jnp.stack([obs[..., 0] > 0, obs[..., 1] > 0], axis=-3), floors)
    usable = adjacent(region) & ~floors
    out = jnp.concatenate([region, usable], axis=-3)  # [..., 4, H, W]
    return jnp.moveaxis(out, -3, -1).astype(jnp.uint8)


def get_obs(state: EnvState, params: EnvParams) -> jax.Array:
    """Both seats' observations.

    Returns:
        uint8[2, 9, 9, 26]: index 0 is seat 0's view, index 1 seat 1's.
    """
    obs = _OBS_TABLE.at[cell_codes(state, params)].get(mode="promise_in_bounds")
    # Write the observation out once: fused into a consumer (a float conversion, a sum) XLA:CPU would
    # re-run the gather per element, several times slower than reading the materialised 4 KB.
    return jax.lax.optimization_barrier(obs)
