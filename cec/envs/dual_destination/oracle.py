"""The oracle: the best possible team play on a Dual Destination level, and the paper's normalised score.

The oracle controls both seats. It finds the fewest joint steps `T` after which the two agents stand on
the two different green goals (or, in the multi-task variant, the two different pink goals), by a
breadth-first search over the 625 joint positions with the env's own movement rule, then stays there.
Each step pays `step_cost`, and steps `T..max_steps` also pay `goal_bonus`, so (for `goal_bonus >= 0`)
no plan does better:

    return = max_steps * step_cost + goal_bonus * (max_steps - T + 1)

In the open 5x5 grid `T` equals the minimum over the assignments of agents to goal cells of the longer
of the two Manhattan distances (agents walk shortest paths; swapping cells is allowed); the search also
schedules around the one blocking case, both agents wanting the same cell. On the paper's fixed task
`T = 4` and the return is -100 + 3 * 97 = 191, a normalised score of 0.955.

This is an evaluation tool on concrete levels (NumPy, not jittable).
"""

from __future__ import annotations

import functools
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs.dual_destination.env import DEFAULT_PARAMS, NUM_ACTIONS, Action, DDParams, move
from cec.envs.dual_destination.level import DD_SIZE, DDLevel, validate_dd_level
from cec.levels import LevelError

_CELLS = DD_SIZE * DD_SIZE
_JOINT = _CELLS * _CELLS  # joint position index: cell(seat 0) * 25 + cell(seat 1), cell = row * 5 + col
_JOINT_ACTIONS = NUM_ACTIONS * NUM_ACTIONS  # joint action index: a0 * 5 + a1


class OraclePlan(NamedTuple):
    """The oracle's plan for one episode.

    Attributes:
        actions: int32[max_steps, 2] joint actions of seat 0 and seat 1, step by step.
        steps_to_goal: fewest steps after which both agents stand on a goal pair (-1 if no plan reaches
            one within `max_steps`).
        return_: the team return of the plan over `max_steps` steps.
    """

    actions: np.ndarray
    steps_to_goal: int
    return_: float


@functools.cache
def _joint_transitions() -> np.ndarray:
    """int64[625, 25]: the next joint position for every joint position and joint action (env rule)."""
    s = np.arange(_JOINT)
    pos = np.stack(
        [
            np.stack([(s // _CELLS) // DD_SIZE, (s // _CELLS) % DD_SIZE], -1),
            np.stack([(s % _CELLS) // DD_SIZE, (s % _CELLS) % DD_SIZE], -1),
        ],
        axis=1,
    )  # (625, 2, 2)
    a = np.arange(_JOINT_ACTIONS)
    acts = np.stack([a // NUM_ACTIONS, a % NUM_ACTIONS], -1)  # (25, 2)
    per_action = jax.vmap(move, in_axes=(None, 0))
    new = np.asarray(jax.jit(jax.vmap(per_action, in_axes=(0, None)))(jnp.asarray(pos), jnp.asarray(acts)))
    code = new[..., 0] * DD_SIZE + new[..., 1]  # (625, 25, 2)
    return code[..., 0] * _CELLS + code[..., 1]


def _pair_states(goals: np.ndarray) -> np.ndarray:
    """bool[625]: joint positions with the two agents on the two different cells of `goals` (2, 2)."""
    g = goals[:, 0] * DD_SIZE + goals[:, 1]
    out = np.zeros(_JOINT, bool)
    out[[g[0] * _CELLS + g[1], g[1] * _CELLS + g[0]]] = True
    return out


def oracle_plan(level: DDLevel, params: DDParams = DEFAULT_PARAMS) -> OraclePlan:
    """Plans the best joint play on a single concrete level.

    Args:
        level: a single, concrete `DDLevel` (raises `LevelError` if invalid).
        params: game settings (concrete); `multi_task` decides whether pink goal pairs count.

    Returns:
        `OraclePlan` with actions int32[max_steps, 2].
    """
    if np.ndim(level.agent_pos) != 2:
        raise LevelError(
            f"oracle_plan takes a single level, got agent_pos of shape {np.shape(level.agent_pos)}"
        )
    validate_dd_level(level)
    max_steps = int(params.max_steps)
    goal = _pair_states(np.asarray(level.green_goals))
    if bool(params.multi_task) and bool(level.has_pink):
        goal |= _pair_states(np.asarray(level.pink_goals))
    agents = np.asarray(level.agent_pos)
    start = int((agents[0, 0] * DD_SIZE + agents[0, 1]) * _CELLS + agents[1, 0] * DD_SIZE + agents[1, 1])

    # BREADTH-FIRST SEARCH over joint positions; parent links hold the joint action taken.
    nxt = _joint_transitions()
    parent = np.full(_JOINT, -1, np.int64)
    parent_action = np.full(_JOINT, -1, np.int64)
    seen = np.zeros(_JOINT, bool)
    seen[start] = True
    frontier = np.array([start])
    depth = 0
    while not goal[frontier].any() and depth < max_steps and frontier.size:
        succ = nxt[frontier].reshape(-1)  # (F * 25,), grouped by frontier state then joint action
        uniq, first = np.unique(succ, return_index=True)
        fresh = ~seen[uniq]
        uniq, first = uniq[fresh], first[fresh]
        parent[uniq] = frontier[first // _JOINT_ACTIONS]
        parent_action[uniq] = first % _JOINT_ACTIONS
        seen[uniq] = True
        frontier = uniq
        depth += 1

    actions = np.full((max_steps, 2), Action.STAY, np.int32)
    reached = frontier[goal[frontier]]
    if reached.size == 0:
        return OraclePlan(actions, -1, float(max_steps * params.step_cost))
    s = int(reached[0])
    for t in range(depth - 1, -1, -1):
        a = int(parent_action[s])
        actions[t] = (a // NUM_ACTIONS, a % NUM_ACTIONS)
        s = int(parent[s])
    ret = max_steps * float(params.step_cost) + float(params.goal_bonus) * (max_steps - depth + 1)
    return OraclePlan(actions, depth, ret)


def oracle_return(level: DDLevel, params: DDParams = DEFAULT_PARAMS) -> float:
    """The oracle's team return on a single concrete level over `params.max_steps` steps."""
    return oracle_plan(level, params).return_


def normalised_score(
    return_: float | jax.Array | np.ndarray, max_steps: int
) -> float | jax.Array | np.ndarray:
    """The paper's normalised score: `return_ / (2 * max_steps)`.

    `2 * max_steps` is the return of standing on a goal pair on every step with the default rewards
    (-1 + 3 = +2 per step); the oracle scores 0.955 on the fixed task. Works on floats and arrays.
    """
    return return_ / (2 * max_steps)
