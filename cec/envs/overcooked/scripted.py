"""A scripted greedy cook: a jittable, non-learning policy that fetches onions, fills pots, plates soups
and delivers them, walking shortest paths. Used to drive interact-heavy tests and demos, and as a simple
fixed partner.

Each seat picks the nearest useful target for what it holds (onion -> a pot that needs onions, plate ->
a cooking or ready pot, dish -> a goal, empty hand -> onions while a pot needs them, else plates while a
soup is coming, and loose dishes). A target it cannot reach is handed over by dropping the item on a
reachable empty counter. With probability `epsilon` a seat acts uniformly at random instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp

from cec.envs.overcooked.state import NUM_ACTIONS, POT_FULL, Action, EnvState
from cec.levels import DIR_VEC, GRID_SIZE, Item, Tile, cell_mask
from cec.levels.solvability import adjacent

_INF = 1_000
_DIR_VEC = jnp.asarray(DIR_VEC)


def _distances(floor: jax.Array, seeds: jax.Array) -> jax.Array:
    """Shortest walking distance over floor cells from each floor cell to the nearest seed cell."""
    big = jnp.full((GRID_SIZE + 2, GRID_SIZE + 2), _INF)

    def relax(_: int, d: jax.Array) -> jax.Array:
        padded = jax.lax.dynamic_update_slice(big, d, (1, 1))
        best = d
        for dr, dc in DIR_VEC.tolist():
            best = jnp.minimum(best, padded[1 + dr : 1 + dr + GRID_SIZE, 1 + dc : 1 + dc + GRID_SIZE] + 1)
        return jnp.where(floor, best, _INF)

    return jax.lax.fori_loop(0, 2 * GRID_SIZE + 6, relax, jnp.where(floor & seeds, 0, _INF))


def _distance_to_front(floor: jax.Array, target: jax.Array) -> jax.Array:
    """Steps from each floor cell to the nearest floor cell that has a `target` cell next to it."""
    return _distances(floor, adjacent(target))


def _seat_action(state: EnvState, seat: int) -> jax.Array:
    grid, items, pot = state.level.grid, state.items, state.pot.astype(jnp.int32)
    pos, facing, held = state.agent_pos[seat], state.agent_dir[seat], state.agent_inv[seat]
    is_pot = grid == Tile.POT
    needs_onion = is_pot & (pot > POT_FULL)
    soup_coming = is_pot & (pot <= POT_FULL)
    bare_counter = (grid == Tile.COUNTER) & (items == Item.NONE)
    floor = grid == Tile.FLOOR
    me = cell_mask(pos)
    within_reach = adjacent(_distances(floor, me) < _INF)  # cells this seat can interact with

    def loose(item: Item, destination: jax.Array) -> jax.Array:
        # A loose item is worth picking up only if this seat can take it where it is needed
        # (otherwise a seat would pick back up what it just handed over).
        return (grid == Tile.COUNTER) & (items == item) & jnp.any(destination & within_reach)

    want_onions = jnp.any(needs_onion)
    want_plates = jnp.any(soup_coming) & ~want_onions
    empty_hand_target = (
        (want_onions & ((grid == Tile.ONION_PILE) | loose(Item.ONION, needs_onion)))
        | (want_plates & ((grid == Tile.PLATE_PILE) | loose(Item.PLATE, soup_coming)))
        | loose(Item.DISH, grid == Tile.GOAL)
    )
    target = jnp.select(
        [held == Item.ONION, held == Item.PLATE, held == Item.DISH],
        [needs_onion, soup_coming, grid == Tile.GOAL],
        empty_hand_target,
    )
    dist = _distance_to_front(floor, target)
    here = dist[pos[0], pos[1]]
    # Unreachable with something in hand: hand it over on a bare counter the partner can reach.
    partner = state.agent_pos[1 - seat]
    partner_cell = cell_mask(partner)
    partner_side = adjacent(_distances(floor, partner_cell) < _INF)
    shared = bare_counter & partner_side
    drop_spot = jnp.where(jnp.any(shared), shared, bare_counter)
    fallback = _distance_to_front(floor, drop_spot)
    use_fallback = (here >= _INF) & (held != Item.NONE)
    dist = jnp.where(use_fallback, fallback, dist)
    target = jnp.where(use_fallback, drop_spot, target)
    here = dist[pos[0], pos[1]]

    nb = jnp.clip(pos + _DIR_VEC, 0, GRID_SIZE - 1)  # (4, 2) neighbour cells
    nb_target = target[nb[:, 0], nb[:, 1]]
    nb_dist = dist[nb[:, 0], nb[:, 1]]
    at_front = here == 0
    face_dir = jnp.argmax(nb_target)
    step_dir = jnp.argmin(nb_dist)
    action = jnp.where(
        at_front,
        jnp.where(facing == face_dir, Action.INTERACT, face_dir),
        step_dir,
    )
    return jnp.where(here >= _INF, Action.STAY, action).astype(jnp.int32)


def scripted_actions(key: jax.Array, state: EnvState, epsilon: float | jax.Array = 0.1) -> jax.Array:
    """Both seats' actions, int32[2]: greedy, or uniform random with probability `epsilon` per seat."""
    k_coin, k_rand = jax.random.split(key)
    greedy = jnp.stack([_seat_action(state, 0), _seat_action(state, 1)])
    random = jax.random.randint(k_rand, (2,), 0, NUM_ACTIONS, dtype=jnp.int32)
    return jnp.where(jax.random.uniform(k_coin, (2,)) < epsilon, random, greedy)
