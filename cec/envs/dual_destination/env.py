"""Dual Destination dynamics and observation as pure, jittable functions over `DDLevel` and `DDState`.

The rules follow the paper's ToyCoop env; see docs/dual_destination.md for the rules in full and for
every deliberate difference from the reference code.
"""

from __future__ import annotations

from enum import IntEnum
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import struct

from cec.envs.base import Transition
from cec.envs.checks import check_actions, is_concrete
from cec.envs.dual_destination.level import DD_SIZE, DDLevel, validate_dd_level
from cec.levels import LevelError

NUM_ACTIONS = 5
NUM_CHANNELS = 4
OUTSIDE_WINDOW = -1.0  # every channel of a cell outside the partial-observation window


class Action(IntEnum):
    """Per-seat actions, in the order of Overcooked's `Action` (names match the movement)."""

    UP = 0  # row - 1
    DOWN = 1  # row + 1
    RIGHT = 2  # col + 1
    LEFT = 3  # col - 1
    STAY = 4


#: `FROM_REFERENCE_ACTION[a]` is our action for the reference ToyCoop action `a`
#: (reference order: 0 right, 1 down, 2 left, 3 up, 4 stay).
FROM_REFERENCE_ACTION = np.array([Action.RIGHT, Action.DOWN, Action.LEFT, Action.UP, Action.STAY], np.int32)

# (d_row, d_col) per action, in Action order (STAY last).
_MOVE_VEC = jnp.asarray([(-1, 0), (1, 0), (0, 1), (0, -1), (0, 0)], dtype=jnp.int32)
_ROWS = jnp.arange(DD_SIZE, dtype=jnp.int32)[:, None]
_COLS = jnp.arange(DD_SIZE, dtype=jnp.int32)[None, :]


@struct.dataclass
class DDParams:
    """Traced (vmappable) game settings. Defaults are those of the paper and its code.

    Attributes:
        max_steps: episode length; `done` when `time >= max_steps`.
        step_cost: team reward added on every step (negative).
        goal_bonus: team reward added on a step after which the two agents stand on the two different
            green goals (or, in the multi-task variant, on the two different pink goals).
        partial_obs: if true, each seat sees only the 3x3 window around its own agent; every channel of
            the cells outside reads `OUTSIDE_WINDOW` (-1), as in the reference code.
        multi_task: if true, the pink goals of levels that have them also pay `goal_bonus` and appear in
            observation channel 3; otherwise pink goals are ignored (channel 3 is all zeros).
    """

    max_steps: int = 100
    step_cost: float = -1.0
    goal_bonus: float = 3.0
    partial_obs: bool = False
    multi_task: bool = False


DEFAULT_PARAMS = DDParams()


class DDState(struct.PyTreeNode):
    """Everything that changes during an episode, plus the level being played.

    Attributes:
        level: the task (static during the episode).
        agent_pos: int32[2, 2] `(row, col)` per seat.
        time: int32[] steps taken in this episode.
        episode: int32[] index of this episode in the env's life (auto-reset plays levels[episode % K]).
    """

    level: DDLevel
    agent_pos: jax.Array
    time: jax.Array
    episode: jax.Array


class DDStepOutput(NamedTuple):
    """What `step` returns.

    Attributes:
        obs: float32[2, 5, 5, 4] each seat's observation from its own perspective.
        state: the next `DDState` (after auto-reset, for `step_autoreset`).
        reward: float32[] team reward of this step (the same for both seats).
        done: bool[] the episode ended with this step.
    """

    obs: jax.Array
    state: DDState
    reward: jax.Array
    done: jax.Array


# ---------------------------------------------------------------------------------------------------
# INPUT CHECKS (eager calls only; inside jit nothing can raise)
# ---------------------------------------------------------------------------------------------------


def _check_level(level: DDLevel, params: DDParams) -> None:
    if not is_concrete(level) or np.ndim(level.agent_pos) != 2:
        return
    validate_dd_level(level)
    if is_concrete(params.multi_task) and bool(params.multi_task) and not bool(level.has_pink):
        raise LevelError(
            "DDParams(multi_task=True) needs a level with pink goals, but this level has none "
            "(has_pink=False); use multi_task_level(), fixed_level(), DDLevel.create(..., pink_goals=...) "
            "or generate_dd_level(key, multi_task=True, ...)"
        )


def _check_actions(actions: jax.Array) -> None:
    check_actions(actions, [a.name.lower() for a in Action])


# ---------------------------------------------------------------------------------------------------
# OBSERVATION
# ---------------------------------------------------------------------------------------------------


def _mask(cell: jax.Array) -> jax.Array:
    """bool[..., 5, 5]: True at `cell` = (row, col) in the last axis; all False outside the grid."""
    return (cell[..., 0, None, None] == _ROWS) & (cell[..., 1, None, None] == _COLS)


def _pink_active(level: DDLevel, params: DDParams) -> jax.Array:
    return jnp.asarray(params.multi_task, bool) & level.has_pink


def get_obs(state: DDState, params: DDParams = DEFAULT_PARAMS) -> jax.Array:
    """Both seats' observations.

    Channels: 0 own agent, 1 the other agent, 2 green goals, 3 pink goals (zeros unless multi-task).
    With `params.partial_obs`, cells outside the 3x3 window around the seat's own agent read -1 in
    every channel.

    Returns:
        float32[2, 5, 5, 4]: index 0 is seat 0's view, index 1 seat 1's.
    """
    level = state.level
    at = _mask(state.agent_pos)  # (2, 5, 5)
    green = jnp.any(_mask(level.green_goals), axis=0)
    pink = jnp.any(_mask(level.pink_goals), axis=0) & _pink_active(level, params)
    goals = jnp.broadcast_to(jnp.stack([green, pink], axis=-1), (2, DD_SIZE, DD_SIZE, 2))
    obs = jnp.concatenate([jnp.stack([at, at[::-1]], axis=-1), goals], axis=-1).astype(jnp.float32)

    # PARTIAL OBSERVATION: the 3x3 window (clipped to the grid) around each seat's own agent.
    pos = state.agent_pos
    window = (jnp.abs(_ROWS - pos[:, 0, None, None]) <= 1) & (jnp.abs(_COLS - pos[:, 1, None, None]) <= 1)
    hidden = jnp.asarray(params.partial_obs, bool) & ~window  # (2, 5, 5)
    return jnp.where(hidden[..., None], jnp.float32(OUTSIDE_WINDOW), obs)


# ---------------------------------------------------------------------------------------------------
# RESET AND STEP
# ---------------------------------------------------------------------------------------------------


def initial_state(key: jax.Array, level: DDLevel, params: DDParams = DEFAULT_PARAMS) -> DDState:
    """The first state of an episode on `level`, unchecked (what `reset` and the auto-reset share; the key
    and the settings play no part)."""
    del key, params
    return DDState(
        level=level,
        agent_pos=level.agent_pos.astype(jnp.int32),
        time=jnp.zeros((), jnp.int32),
        episode=jnp.zeros((), jnp.int32),
    )


def reset(key: jax.Array, level: DDLevel, params: DDParams = DEFAULT_PARAMS) -> tuple[jax.Array, DDState]:
    """Starts an episode on `level` with the agents on its start cells.

    Args:
        key: PRNG key (the reset is deterministic; kept for API symmetry).
        level: a single `DDLevel` (vmap for batches). Invalid levels raise `LevelError` when called eagerly.
        params: game settings.

    Returns:
        obs: float32[2, 5, 5, 4]; state: the initial `DDState`.
    """
    _check_level(level, params)
    state = initial_state(key, level, params)
    return get_obs(state, params), state


def move(agent_pos: jax.Array, actions: jax.Array) -> jax.Array:
    """The movement rule: int32[2, 2] positions after joint `actions` int[2].

    Each seat's intended cell is its neighbour in the action's direction, clipped to the grid (stay and
    out-of-range actions: its own cell). If both intended cells are equal, neither moves; otherwise both
    move, so agents may swap cells or pass through each other.
    """
    acts = actions.astype(jnp.int32)
    vec = _MOVE_VEC[jnp.where((acts >= 0) & (acts < NUM_ACTIONS), acts, Action.STAY)]
    intended = jnp.clip(agent_pos + vec, 0, DD_SIZE - 1)
    same_cell = jnp.all(intended[0] == intended[1])
    return jnp.where(same_cell, agent_pos, intended)


def _on_pair(pos: jax.Array, goals: jax.Array) -> jax.Array:
    """bool[]: the two agents stand on the two different cells of `goals` (2, 2)."""
    on = jnp.all(pos[:, None, :] == goals[None, :, :], axis=-1)  # (agent, goal)
    return jnp.any(on[0]) & jnp.any(on[1]) & jnp.any(pos[0] != pos[1])


def _transition(state: DDState, actions: jax.Array, params: DDParams) -> tuple[DDState, jax.Array, jax.Array]:
    level = state.level
    new_pos = move(state.agent_pos, actions)
    on_goals = _on_pair(new_pos, level.green_goals) | (
        _on_pair(new_pos, level.pink_goals) & _pink_active(level, params)
    )
    reward = (params.step_cost + jnp.where(on_goals, params.goal_bonus, 0.0)).astype(jnp.float32)
    time = state.time + 1
    return state.replace(agent_pos=new_pos, time=time), reward, time >= params.max_steps


def transition(
    key: jax.Array, state: DDState, actions: jax.Array, params: DDParams = DEFAULT_PARAMS
) -> Transition:
    """One joint step's dynamics, without observations or auto-reset (what `step` and `step_autoreset`
    share): no shaped reward (zeros) and no collisions (False). Eager actions out of range raise
    `ValueError`."""
    del key
    _check_actions(actions)
    next_state, reward, done = _transition(state, actions, params)
    return Transition(next_state, reward, jnp.zeros(2, jnp.float32), done, jnp.zeros((), bool))


def step(
    key: jax.Array, state: DDState, actions: jax.Array, params: DDParams = DEFAULT_PARAMS
) -> DDStepOutput:
    """Advances one joint step, without auto-reset.

    Args:
        key: PRNG key (the dynamics are deterministic; kept for API symmetry with `step_autoreset`).
        state: current `DDState`.
        actions: int[2] actions of seat 0 and seat 1 (`Action`). Out-of-range actions raise `ValueError`
            when called eagerly; inside `jit` they act as stay.
        params: game settings.

    Returns:
        `DDStepOutput` with obs float32[2, 5, 5, 4], reward float32[] and done bool[].
    """
    t = transition(key, state, actions, params)
    return DDStepOutput(get_obs(t.state, params), t.state, t.reward, t.done)
