"""Dual Destination as a `cec.envs.base.Game`, its evaluation level names, and its auto-reset step (the one
in `cec.envs.base`)."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from cec.config import ConfigError
from cec.envs import base
from cec.envs.dual_destination.env import (
    DEFAULT_PARAMS,
    NUM_ACTIONS,
    NUM_CHANNELS,
    DDParams,
    DDState,
    DDStepOutput,
    get_obs,
    initial_state,
    reset,
    transition,
)
from cec.envs.dual_destination.level import (
    DD_SIZE,
    DDLevel,
    fixed_level,
    heldout_generated_dd_levels,
    multi_task_level,
    stack_dd_levels,
)


def named_levels(spec: str) -> dict[str, DDLevel]:
    """{name: level} for an evaluation level spec: comma-separated `fixed`, `multi_task`, `generated` (the
    100 held-out generated tasks), `heldout` (fixed + generated) or `generated_000..generated_099`, in the
    order named; `ConfigError` naming an unknown token."""
    tokens = [t.strip() for t in spec.split(",") if t.strip()]
    if not tokens:
        raise ConfigError("levels is empty; give e.g. `heldout`, `generated` or level names")
    out: dict[str, Any] = {}
    generated = dict(heldout_generated_dd_levels())
    known = {"fixed": fixed_level(), "multi_task": multi_task_level(), **generated}
    for tok in tokens:
        if tok in ("generated", "heldout"):
            out.update({"fixed": known["fixed"]} if tok == "heldout" else {})
            out.update(generated)
        elif tok in known:
            out[tok] = known[tok]
        else:
            raise ConfigError(
                f"unknown Dual Destination level {tok!r}; choose from fixed, multi_task, generated (the "
                "100 held-out generated tasks), heldout (fixed + generated) or "
                "generated_000..generated_099"
            )
    return out


def _check_levels(levels: str, params: Any) -> None:
    """The pink goals pay only in the multi-task game: `multi_task` levels need `params.multi_task`, the
    others need it off."""
    if params.multi_task != ("multi_task" in levels):
        raise ConfigError(
            f"env.levels {levels!r} needs env.dual_destination.multi_task="
            f"{str('multi_task' in levels).lower()} (the pink goals pay only in the multi-task game)"
        )


def _obs_settings(params: Any) -> tuple:
    return (bool(params.partial_obs), bool(params.multi_task))


def _deliveries(returns: np.ndarray, steps: int, params: Any) -> np.ndarray:
    """Steps on a goal pair: return = steps * step_cost + goal_steps * goal_bonus (NaN without a bonus)."""
    bonus = float(params.goal_bonus)
    goal = (returns - steps * float(params.step_cost)) / bonus if bonus else np.nan * returns
    return np.round(goal)


GAME = base.Game(
    name="dual_destination",
    num_actions=NUM_ACTIONS,
    obs_shape=(DD_SIZE, DD_SIZE, NUM_CHANNELS),
    reset=reset,
    initial_state=initial_state,
    transition=transition,
    get_obs=get_obs,
    level_specs=("fixed", "multi_task", "procedural", "procedural_multi_task"),
    default_levels="fixed",
    procedural_levels=("procedural", "procedural_multi_task"),
    level_files=False,
    check_levels=_check_levels,
    named_levels=named_levels,
    stack_levels=stack_dd_levels,
    egocentric=False,
    normalised_score=True,
    obs_settings=_obs_settings,
    deliveries=_deliveries,
    single_task_own_level=False,
)


def step_autoreset(
    key: jax.Array,
    state: DDState,
    actions: jax.Array,
    levels: DDLevel,
    params: DDParams = DEFAULT_PARAMS,
) -> DDStepOutput:
    """`step`, then, if the episode ended, starts the next one on `levels[(episode + 1) % K]`
    (`cec.envs.base.step_autoreset` on Dual Destination).

    The reset is a select between two cheap states (no generator work on the step path); the returned
    observation is that of the new episode's first state when `done`, while `reward` and `done` are
    those of the step that ended the old one.

    Args:
        key: PRNG key (unused; kept for API symmetry).
        state: current `DDState`.
        actions: int[2] actions of seat 0 and seat 1.
        levels: a batched `DDLevel` with leading axis K, this env's buffer of upcoming levels. Give each
            env its own buffer (vmap over it) or share one (`in_axes=None`).
        params: game settings.

    Returns:
        `DDStepOutput`.
    """
    out = base.step_autoreset(GAME, key, state, actions, levels, params)
    return DDStepOutput(out.obs, out.state, out.reward, out.done)
