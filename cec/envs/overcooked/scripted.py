"""A scripted greedy cook: a jittable, non-learning policy that fetches onions, fills pots, plates soups
and delivers them, walking shortest paths. It drives interact-heavy tests and demos, and is the zoo's
`cook` partner (`cook_step`, from one seat's observation): a competent partner no trained agent ever met.

Each seat picks the nearest useful target for what it holds (onion -> a pot that needs onions, plate ->
a cooking or ready pot, dish -> a goal, empty hand -> onions while a pot it can reach needs them, else
plates while a soup is coming, and loose dishes). A target it cannot reach is handed over by dropping the
item on a reachable empty counter. Routes go around the partner when that costs at most `DETOUR` extra
steps; where the two seats' next moves collide, the one further from its target steps aside. With
probability `epsilon` a seat acts uniformly at random instead.
"""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs.overcooked.state import (
    NUM_ACTIONS,
    NUM_CHANNELS,
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    Action,
    EnvState,
)
from cec.levels import DIR_VEC, GRID_SIZE, Item, Level, Tile, cell_mask
from cec.levels.solvability import adjacent

_INF = 1_000
DETOUR = 4  # extra steps a cook walks to get around its partner rather than through it
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


def _plan(state: EnvState, seat: int) -> tuple[jax.Array, jax.Array]:
    """The seat's greedy action toward its current target, ignoring what the partner is about to do, and
    its distance (steps) to the target's front."""
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

    # Onions for the pots this seat can reach, or for any pot if it reaches none (a hand-over side).
    reaches_pot = jnp.any(is_pot & within_reach)
    want_onions = jnp.any(needs_onion & (within_reach | ~reaches_pot))
    onion_source = (grid == Tile.ONION_PILE) | loose(Item.ONION, needs_onion)
    # Plates while a soup is coming and no onion is needed, or none this seat can fetch (in a split
    # kitchen the serving side must not wait for onions only the other side can get).
    want_plates = jnp.any(soup_coming) & ~(want_onions & jnp.any(onion_source & within_reach))
    empty_hand_target = (
        (want_onions & onion_source)
        | (want_plates & ((grid == Tile.PLATE_PILE) | loose(Item.PLATE, soup_coming)))
        | loose(Item.DISH, grid == Tile.GOAL)
    )
    target = jnp.select(
        [held == Item.ONION, held == Item.PLATE, held == Item.DISH],
        [needs_onion, soup_coming, grid == Tile.GOAL],
        empty_hand_target,
    )
    # Routes avoid the partner's cell when a way around it costs at most DETOUR extra steps; otherwise
    # they go through it and `_seat_action`'s yielding rule resolves the meeting (long detours that flip
    # back as soon as the partner moves make two cooks oscillate).
    partner = state.agent_pos[1 - seat]
    partner_cell = cell_mask(partner)
    free = floor & ~partner_cell

    def route(goal: jax.Array) -> jax.Array:
        around, direct = _distance_to_front(free, goal), _distance_to_front(floor, goal)
        return jnp.where(around[pos[0], pos[1]] <= direct[pos[0], pos[1]] + DETOUR, around, direct)

    dist = route(target)
    here = dist[pos[0], pos[1]]
    # Unreachable with something in hand: hand it over on a bare counter the partner can reach.
    partner_side = adjacent(_distances(floor, partner_cell) < _INF)
    shared = bare_counter & partner_side
    drop_spot = jnp.where(jnp.any(shared), shared, bare_counter)
    fallback = route(drop_spot)
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
    return jnp.where(here >= _INF, Action.STAY, action).astype(jnp.int32), here


def _next_cell(state: EnvState, seat: int, action: jax.Array) -> jax.Array:
    """int32[2] the cell the seat means to enter with `action` (its own cell unless it moves onto floor)."""
    pos = state.agent_pos[seat]
    to = jnp.clip(pos + _DIR_VEC[jnp.minimum(action, 3)], 0, GRID_SIZE - 1)
    moves = (action < 4) & (state.level.grid[to[0], to[1]] == Tile.FLOOR)
    return jnp.where(moves, to, pos)


def _seat_action(state: EnvState, seat: int) -> jax.Array:
    """The seat's greedy action, given its plan and the partner's (as this cook would play it)."""
    return _yielding(state, seat, _plan(state, seat), _plan(state, 1 - seat))


def _yielding(
    state: EnvState, seat: int, plan: tuple[jax.Array, jax.Array], partner_plan: tuple[jax.Array, jax.Array]
) -> jax.Array:
    """The seat's planned action, yielding where its plan and the partner's collide: both heading for one
    cell, swapping cells, or walking into a partner that stays. The seat further from its target (ties:
    the one further down/right; an order both seats see alike) gives way by stepping onto a free
    neighbour cell out of the partner's way, or waits if it has none; the other keeps its plan, and waits
    itself only when the partner stays put in its way."""
    (mine, my_dist), (theirs, their_dist) = plan, partner_plan
    pos, partner = state.agent_pos[seat], state.agent_pos[1 - seat]
    my_next, their_next = _next_cell(state, seat, mine), _next_cell(state, 1 - seat, theirs)
    moving = jnp.any(my_next != pos)
    into_partner = jnp.all(my_next == partner)
    partner_stays = jnp.all(their_next == partner)
    clash = moving & (jnp.all(my_next == their_next) | (into_partner & jnp.all(their_next == pos)))
    my_rank = my_dist * GRID_SIZE * GRID_SIZE + pos[0] * GRID_SIZE + pos[1]
    yields = my_rank > their_dist * GRID_SIZE * GRID_SIZE + partner[0] * GRID_SIZE + partner[1]
    nb = jnp.clip(pos + _DIR_VEC, 0, GRID_SIZE - 1)
    grid = state.level.grid
    out_of_way = (
        (grid[nb[:, 0], nb[:, 1]] == Tile.FLOOR)
        & jnp.any(nb != pos, axis=1)
        & jnp.any(nb != partner, axis=1)
        & jnp.any(nb != their_next, axis=1)
    )
    aside = jnp.where(jnp.any(out_of_way), jnp.argmax(out_of_way), Action.STAY)
    action = jnp.where(clash & yields, aside, mine)
    return jnp.where(moving & into_partner & partner_stays, Action.STAY, action).astype(jnp.int32)


def scripted_actions(
    key: jax.Array, state: EnvState, epsilon: float | jax.Array = 0.1, yields: bool = True
) -> jax.Array:
    """Both seats' actions, int32[2]: greedy, or uniform random with probability `epsilon` per seat.

    With `yields` False (static) each seat keeps its plan where it collides with its partner's: it never
    steps aside or waits, and walks into a partner in its way until the partner moves (a person who never
    gives way, as a training partner).
    """
    k_coin, k_rand = jax.random.split(key)
    plans = (_plan(state, 0), _plan(state, 1))  # each seat's plan once, for itself and its partner
    if yields:
        greedy = jnp.stack([_yielding(state, 0, plans[0], plans[1]), _yielding(state, 1, plans[1], plans[0])])
    else:
        greedy = jnp.stack([plans[0][0], plans[1][0]])
    random = jax.random.randint(k_rand, (2,), 0, NUM_ACTIONS, dtype=jnp.int32)
    return jnp.where(jax.random.uniform(k_coin, (2,)) < epsilon, random, greedy)


def state_from_obs(obs: jax.Array) -> EnvState:
    """The `EnvState` a seat's observation (uint8[9, 9, 26]) shows, with that seat as seat 0.

    Everything the cook reads is in the observation: tiles, loose items, pot contents and timers, both
    seats' cells, facings and held items. Not shown, and set to 0: the step count and the level's start
    cells.
    """
    o = obs.astype(jnp.int32)
    seat_here = (o[..., 0] + o[..., 1]) > 0
    counter = (o[..., 11] > 0) | (((o[..., 21] + o[..., 22] + o[..., 23]) > 0) & ~seat_here)  # bare or laden
    grid = jnp.select(
        [o[..., 10] > 0, o[..., 12] > 0, o[..., 14] > 0, o[..., 15] > 0, counter],
        [Tile.POT, Tile.ONION_PILE, Tile.PLATE_PILE, Tile.GOAL, Tile.COUNTER],
        Tile.FLOOR,
    ).astype(jnp.uint8)
    item = jnp.select(
        [o[..., 23] > 0, o[..., 22] > 0, o[..., 21] > 0], [Item.ONION, Item.PLATE, Item.DISH], Item.NONE
    )
    is_pot = grid == Tile.POT
    status = jnp.where(
        o[..., 21] > 0, POT_READY, jnp.where(o[..., 20] > 0, o[..., 20], POT_EMPTY - o[..., 16])
    )
    cells = jnp.stack([jnp.argmax(o[..., 0].reshape(-1)), jnp.argmax(o[..., 1].reshape(-1))])  # self, other
    pos = jnp.stack([cells // GRID_SIZE, cells % GRID_SIZE], axis=-1).astype(jnp.int32)
    facing = jnp.stack(
        [jnp.argmax(o[..., 2:6].reshape(-1, 4)[cells[0]]), jnp.argmax(o[..., 6:10].reshape(-1, 4)[cells[1]])]
    ).astype(jnp.int32)
    held = item.reshape(-1)[cells].astype(jnp.int32)
    level = Level(grid, pos, facing, jnp.array([GRID_SIZE, GRID_SIZE], jnp.int32))
    return EnvState(
        level=level,
        agent_pos=pos,
        agent_dir=facing,
        agent_inv=held,
        items=jnp.where(grid == Tile.COUNTER, item, Item.NONE).astype(jnp.uint8),
        pot=jnp.where(is_pot, status, 0).astype(jnp.uint8),
        time=jnp.zeros((), jnp.int32),
        episode=jnp.zeros((), jnp.int32),
    )


_OBS_MIX = jnp.asarray(
    (np.arange(GRID_SIZE * GRID_SIZE * NUM_CHANNELS) % 9973).reshape(GRID_SIZE, GRID_SIZE, NUM_CHANNELS),
    jnp.int32,
)  # spreads the observation into its key

#: Floats of memory the observation-driven cook keeps: its step count (the seed of its random actions).
COOK_MEMORY = 1
COOK_EPSILON = 0.05  # its share of uniformly random actions, which also breaks any remaining standoff


def cook_step(memory: jax.Array, obs: jax.Array) -> tuple[jax.Array, jax.Array]:
    """The scripted cook as a zoo partner: `(memory float32[1], one seat's obs) -> (memory, action)`.

    It plays `_seat_action` on the state its observation shows, with `COOK_EPSILON` random actions drawn
    from its step count and the observation (the same inputs give the same action).
    """
    state = state_from_obs(obs)
    count = memory[0].astype(jnp.int32)
    key = jax.random.fold_in(jax.random.PRNGKey(0), count * 7919 + jnp.sum(obs.astype(jnp.int32) * _OBS_MIX))
    k_coin, k_rand = jax.random.split(key)
    random = jax.random.randint(k_rand, (), 0, NUM_ACTIONS, dtype=jnp.int32)
    action = jnp.where(jax.random.uniform(k_coin) < COOK_EPSILON, random, _seat_action(state, 0))
    return memory.at[0].add(1.0), action
