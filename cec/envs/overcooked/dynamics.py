"""Overcooked dynamics as pure, jittable functions over `Level` and `EnvState`.

The rules follow JaxMARL's Overcooked (v1), which the paper's code forked; see docs/overcooked.md for the
rules in full and for every deliberate difference from the reference code.

All per-cell updates are written as elementwise selects over the 9x9 grid (no scatters), which XLA fuses
into a few loops; that is what makes `vmap(step)` fast on CPU and GPU alike.
"""

from __future__ import annotations

from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs.base import Transition
from cec.envs.checks import check_actions, is_concrete
from cec.envs.overcooked.observation import get_obs
from cec.envs.overcooked.state import (
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    Action,
    EnvParams,
    EnvState,
    StepOutput,
)
from cec.levels import DIR_VEC, GRID_SIZE, Item, Level, Tile, cell_mask, validate_level
from cec.levels.solvability import adjacent, usable_counters

_DIR_VEC = jnp.asarray(DIR_VEC)


def _check_level(level: Level) -> None:
    if is_concrete(level) and np.ndim(level.grid) == 2:
        validate_level(level)


def _check_actions(actions: jax.Array) -> None:
    check_actions(actions, [a.name.lower() for a in Action])


# ---------------------------------------------------------------------------------------------------
# RESET
# ---------------------------------------------------------------------------------------------------


def initial_state(key: jax.Array, level: Level, params: EnvParams) -> EnvState:
    """The first state of an episode on `level`, unchecked (what `reset` and the auto-reset share)."""
    # Two uniform facings from one 32-bit draw (cheaper than randint, which draws twice as many bits).
    bits = jax.random.bits(key, (), jnp.uint32)
    random_dir = (jnp.stack([bits, bits >> 2]) & 3).astype(jnp.int32)
    agent_dir = jnp.where(params.random_start_facing, random_dir, level.agent_dir.astype(jnp.int32))
    state = EnvState(
        level=level,
        agent_pos=level.agent_pos.astype(jnp.int32),
        agent_dir=agent_dir,
        agent_inv=jnp.zeros((2,), jnp.int32),
        items=jnp.zeros((GRID_SIZE, GRID_SIZE), jnp.uint8),
        pot=jnp.where(level.grid == Tile.POT, POT_EMPTY, 0).astype(jnp.uint8),
        time=jnp.zeros((), jnp.int32),
        episode=jnp.zeros((), jnp.int32),
    )
    # only a run with a random start pays for its draws (params are not batched: real branches), each lever
    # from a key of its own, so that one's draws do not move when the other is switched on
    levers = ((params.random_start_items, _scatter_items), (params.random_start_pot_onions, _fill_pots))
    for salt, (share, draw) in enumerate(levers, start=1):
        state = jax.lax.cond(share > 0, draw, lambda k, s, p: s, jax.random.fold_in(key, salt), state, params)
    return state


def _scatter_items(key: jax.Array, state: EnvState, params: EnvParams) -> EnvState:
    """`state` with, each with probability `params.random_start_items`, an onion on each counter beside the
    floor (where a seat may reach it) and an onion or a plate in each seat's hands."""
    k_put, k_held = jax.random.split(key)
    cells = GRID_SIZE * GRID_SIZE
    put = jax.random.uniform(k_put, (cells + 2,)) < params.random_start_items  # each cell, then each seat
    held = jax.random.randint(k_held, (2,), Item.ONION, Item.PLATE + 1)
    grid = state.level.grid
    reachable = (grid == Tile.COUNTER) & adjacent(grid == Tile.FLOOR)
    on_counter = put[:cells].reshape(GRID_SIZE, GRID_SIZE) & reachable
    return state.replace(
        items=jnp.where(on_counter, jnp.uint8(Item.ONION), state.items),
        agent_inv=jnp.where(put[cells:], held, state.agent_inv),
    )


def _fill_pots(key: jax.Array, state: EnvState, params: EnvParams) -> EnvState:
    """`state` with each pot holding, with probability `params.random_start_pot_onions`, one or two onions
    (equally likely), not cooking."""
    k_put, k_count = jax.random.split(key)
    shape = (GRID_SIZE, GRID_SIZE)
    put = (jax.random.uniform(k_put, shape) < params.random_start_pot_onions) & (state.level.grid == Tile.POT)
    onions = jax.random.randint(k_count, shape, 1, 3).astype(jnp.uint8)
    return state.replace(pot=jnp.where(put, jnp.uint8(POT_EMPTY) - onions, state.pot))


def reset(key: jax.Array, level: Level, params: EnvParams = EnvParams()) -> tuple[jax.Array, EnvState]:
    """Starts an episode on `level`: agents at the level's start cells, empty hands, pots and counters
    (unless `params.random_start_items` or `params.random_start_pot_onions`).

    Args:
        key: PRNG key (used for the start facings when `params.random_start_facing`).
        level: a single `Level` (vmap for batches).
        params: dynamics settings.

    Returns:
        obs: uint8[2, 9, 9, 26]; state: the initial `EnvState`.
    """
    _check_level(level)
    state = initial_state(key, jax.tree.map(jnp.asarray, level), params)
    return get_obs(state, params), state


# ---------------------------------------------------------------------------------------------------
# STEP
# ---------------------------------------------------------------------------------------------------


def _at(grid: jax.Array, cell: jax.Array) -> jax.Array:
    """Value of a 9x9 grid at `cell` (row, col); `cell` must be inside the frame."""
    return grid[cell[0], cell[1]]


def _interact(
    seat: int,
    state: EnvState,
    items: jax.Array,
    pot: jax.Array,
    inv: jax.Array,
    front: jax.Array,
    acts: jax.Array,
    params: EnvParams,
    sides: Sides,
) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array, jax.Array, jax.Array, jax.Array]:
    """Resolves one seat's interact on the grids left by the seats before it.

    `sides`: what each seat's region can use (`sides_of`; everything when the hand-over levers are off).
    Returns the updated (items, pot, inventories, sparse reward, shaped reward) of this seat, and whether
    it used an item it could not have fetched (`handover_reward`) and took up a pass of its partner's
    (`pass_taken_reward`, paid to the partner; `pass_received_reward`, paid to this seat, is in its shaped
    reward).
    """
    grid = state.level.grid
    cell = front[seat]
    inside = jnp.all((cell >= 0) & (cell < GRID_SIZE))
    safe = jnp.clip(cell, 0, GRID_SIZE - 1)
    active = (acts[seat] == Action.INTERACT) & inside
    tile = _at(grid, safe)
    item = _at(items, safe)
    status = _at(pot, safe).astype(jnp.int32)
    held = inv[seat]
    empty_hand = held == Item.NONE

    # WHAT HAPPENS (exactly one of these, or nothing)
    add_onion = active & (tile == Tile.POT) & (status > POT_FULL) & (held == Item.ONION)
    take_soup = active & (tile == Tile.POT) & (status == POT_READY) & (held == Item.PLATE)
    from_pile = active & empty_hand & ((tile == Tile.ONION_PILE) | (tile == Tile.PLATE_PILE))
    from_counter = active & empty_hand & (tile == Tile.COUNTER) & (item != Item.NONE)
    drop = active & ~empty_hand & (tile == Tile.COUNTER) & (item == Item.NONE)
    deliver = active & (tile == Tile.GOAL) & (held == Item.DISH)

    pile_item = jnp.where(tile == Tile.ONION_PILE, Item.ONION, Item.PLATE)
    new_held = jnp.select(
        [add_onion | drop | deliver, take_soup, from_pile, from_counter],
        [jnp.int32(Item.NONE), jnp.int32(Item.DISH), pile_item, item.astype(jnp.int32)],
        held,
    )

    # Plate-pickup shaping (as JaxMARL 0.2.0): only when no loose plate lies on a counter and fewer
    # plates are in hands than pots are non-empty; counted on the grids before this seat acts.
    picked_plate = (from_pile | from_counter) & (new_held == Item.PLATE)
    no_loose_plates = ~jnp.any(items == Item.PLATE)
    nonempty_pots = jnp.sum((grid == Tile.POT) & (pot != POT_EMPTY))
    plates_in_hands = jnp.sum(inv == Item.PLATE)
    plate_bonus = picked_plate & no_loose_plates & (plates_in_hands < nonempty_pots)

    # GRID UPDATES at the cell in front
    here = cell_mask(cell)
    items = jnp.where(here & from_counter, jnp.uint8(Item.NONE), items)
    items = jnp.where(here & drop, held.astype(jnp.uint8), items)
    pot = jnp.where(here & add_onion, (status - 1).astype(jnp.uint8), pot)
    pot = jnp.where(here & take_soup, jnp.uint8(POT_EMPTY), pot)

    reward = deliver * params.delivery_reward
    shaped = (
        add_onion * params.onion_in_pot_reward
        + take_soup * params.soup_pickup_reward
        + plate_bonus * params.plate_pickup_reward
    )
    own = sides.reach[seat]
    handed = (add_onion & ~own[0]) | (take_soup & ~(own[0] & own[1])) | (deliver & ~own[2])

    # Pass reward: an item this seat cannot use and its partner can, on a counter the partner reaches
    partner_side = _at(sides.counters[1 - seat], safe)
    mine, theirs = sides.uses[seat], sides.uses[1 - seat]
    passed = drop & ~mine[held] & theirs[held] & partner_side
    taken_back = from_counter & ~mine[item] & theirs[item] & partner_side
    shaped = shaped + passed.astype(jnp.float32) * params.pass_reward
    shaped = shaped - taken_back.astype(jnp.float32) * (params.pass_reward + params.pass_take_back_cost)
    # ... and the other way round: this seat took up an item only it can use, from the partner's side
    received = from_counter & mine[item] & ~theirs[item] & partner_side
    put_back = drop & mine[held] & ~theirs[held] & partner_side
    receipt = received.astype(jnp.float32) - put_back.astype(jnp.float32)
    shaped = shaped + receipt * params.pass_received_reward
    return items, pot, inv.at[seat].set(new_held), reward, shaped, handed, received


class Sides(NamedTuple):
    """What each seat's floor region (from where it stands) can use.

    Attributes:
        reach: bool[2, 3], whether it reaches an onion pile, a plate pile, a pot.
        uses: bool[2, 4], by `Item`, whether it can use that item: an onion or a plate at a pot, a plated
            soup at a goal (`NONE` never).
        counters: bool[2, 9, 9], the non-floor cells next to the region (what it can interact with).
    """

    reach: jax.Array
    uses: jax.Array
    counters: jax.Array


def sides_of(grid: jax.Array, agent_pos: jax.Array) -> Sides:
    """What each seat's region can use in the kitchen `grid`, the seats at `agent_pos` (two flood fills)."""
    counters = jnp.stack([usable_counters(grid, agent_pos[seat]) for seat in (0, 1)])

    def has(tile: Tile) -> jax.Array:
        return jnp.any(counters & (grid == tile), axis=(1, 2))

    pot, goal = has(Tile.POT), has(Tile.GOAL)
    uses = jnp.stack([jnp.zeros_like(pot), pot, pot, goal], axis=1)
    return Sides(jnp.stack([has(Tile.ONION_PILE), has(Tile.PLATE_PILE), pot], axis=1), uses, counters)


def needs_handover(state: EnvState) -> jax.Array:
    """bool[]: whether neither seat can finish a soup alone from where it stands (its region misses an onion
    pile, a plate pile, a pot or a goal), so a soup needs a hand-over (`cec.levels.kinds`' kind)."""
    sides = sides_of(state.level.grid, state.agent_pos)
    alone = jnp.all(sides.reach, axis=1) & sides.uses[:, 3]
    return ~jnp.any(alone)


def _everything(grid: jax.Array, agent_pos: jax.Array) -> Sides:
    """`Sides` that make no hand-over lever fire (what a run without them gets, at no cost)."""
    del grid, agent_pos
    return Sides(jnp.ones((2, 3), bool), jnp.ones((2, 4), bool), jnp.ones((2, GRID_SIZE, GRID_SIZE), bool))


def _transition(state: EnvState, actions: jax.Array, params: EnvParams) -> Transition:
    acts = actions.astype(jnp.int32)
    grid = state.level.grid
    pos = state.agent_pos
    is_move = (acts >= 0) & (acts < 4)  # under jit an out-of-range action acts as stay

    # MOVEMENT: a move succeeds if the target is floor, unless both seats want the same cell
    # ("no collision, no move") or would swap cells. Moves turn the agent even when blocked.
    step_vec = _DIR_VEC[jnp.where(is_move, acts, 0)]  # (2, 2)
    target = jnp.clip(pos + step_vec, 0, GRID_SIZE - 1)
    target_floor = grid[target[:, 0], target[:, 1]] == Tile.FLOOR
    wanted = jnp.where((is_move & target_floor)[:, None], target, pos)
    same_cell = jnp.all(wanted[0] == wanted[1])
    swap = jnp.all(wanted[0] == pos[1]) & jnp.all(wanted[1] == pos[0])
    collision = same_cell | swap
    new_pos = jnp.where(collision, pos, wanted)
    new_dir = jnp.where(is_move, acts, state.agent_dir)

    # INTERACT: the cell in front of the pre-step position and facing; seat 0 resolves first.
    front = pos + _DIR_VEC[state.agent_dir]
    items, pot, inv = state.items, state.pot, state.agent_inv
    # only a run that rewards hand-overs pays for the flood fills (params are not batched: a real branch)
    levers = (params.handover_reward != 0) | (params.pass_reward != 0) | (params.pass_take_back_cost != 0)
    levers = levers | (params.pass_taken_reward != 0) | (params.pass_received_reward != 0)
    sides = jax.lax.cond(levers, sides_of, _everything, grid, pos)
    items, pot, inv, r0, s0, h0, p0 = _interact(0, state, items, pot, inv, front, acts, params, sides)
    items, pot, inv, r1, s1, h1, p1 = _interact(1, state, items, pot, inv, front, acts, params, sides)

    # COOKING: full pots count down to ready, including on the step the third onion went in.
    cooking = (grid == Tile.POT) & (pot <= POT_FULL) & (pot > POT_READY)
    pot = jnp.where(cooking, pot - 1, pot).astype(jnp.uint8)

    time = state.time + 1
    next_state = state.replace(
        agent_pos=new_pos, agent_dir=new_dir, agent_inv=inv, items=items, pot=pot, time=time
    )
    reward = (r0 + r1).astype(jnp.float32)
    handover_bonus = (h0.astype(jnp.float32) + h1.astype(jnp.float32)) * params.handover_reward
    pass_bonus = jnp.stack([p1, p0]).astype(jnp.float32) * params.pass_taken_reward  # to the seat that passed
    shaped = (jnp.stack([s0, s1]) + handover_bonus + pass_bonus).astype(jnp.float32)
    return Transition(next_state, reward, shaped, time >= params.max_steps, collision)


def transition(
    key: jax.Array, state: EnvState, actions: jax.Array, params: EnvParams = EnvParams()
) -> Transition:
    """One joint step's dynamics, without observations or auto-reset (what `step` and `step_autoreset`
    share). Eager actions out of range raise `ValueError`."""
    del key
    _check_actions(actions)
    return _transition(state, actions, params)


def step(key: jax.Array, state: EnvState, actions: jax.Array, params: EnvParams = EnvParams()) -> StepOutput:
    """Advances one joint step, without auto-reset.

    Args:
        key: PRNG key (the dynamics are deterministic; kept for API symmetry with `step_autoreset`).
        state: current `EnvState`.
        actions: int[2] actions of seat 0 and seat 1 (`Action`). Out-of-range actions raise
            `ValueError` when called eagerly; inside `jit` they must be in range.
        params: dynamics settings.
    """
    t = transition(key, state, actions, params)
    return StepOutput(get_obs(t.state, params), t.state, t.reward, t.shaped, t.done, t.collision)
