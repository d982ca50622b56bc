"""Overcooked as a `cec.envs.base.Game`, and its auto-reset step (the one in `cec.envs.base`)."""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from cec.config import ConfigError
from cec.envs import base
from cec.envs.overcooked.dynamics import initial_state, needs_handover, reset, transition
from cec.envs.overcooked.observation import get_obs
from cec.envs.overcooked.scripted import scripted_actions
from cec.envs.overcooked.state import NUM_ACTIONS, NUM_CHANNELS, EnvParams, EnvState, StepOutput
from cec.levels import GRID_SIZE, Level
from cec.levels.classic import CLASSIC_ASCII
from cec.levels.level import stack_levels
from cec.levels.named import resolve_levels


def _check_levels(levels: str, params: Any) -> None:
    del levels  # every Overcooked setting plays every kitchen
    for name in ("random_start_items", "random_start_pot_onions"):
        share = float(getattr(params, name))
        if not 0.0 <= share <= 1.0:
            raise ConfigError(
                f"env.overcooked.{name} is a probability, got {share}; give a value in [0, 1] (0: off)"
            )


def _obs_settings(params: Any) -> tuple:
    del params  # the observation is the same under every setting
    return ()


def _deliveries(returns: np.ndarray, steps: int, params: Any) -> np.ndarray:
    """Soups delivered: the sparse return in units of the delivery reward (NaN when it is not positive)."""
    del steps
    per_soup = float(params.delivery_reward)
    return np.round(returns / per_soup) if per_soup > 0 else np.full_like(returns, np.nan)


GAME = base.Game(
    name="overcooked",
    num_actions=NUM_ACTIONS,
    obs_shape=(GRID_SIZE, GRID_SIZE, NUM_CHANNELS),
    reset=reset,
    initial_state=initial_state,
    transition=transition,
    get_obs=get_obs,
    level_specs=("generator", *CLASSIC_ASCII),
    default_levels="generator",
    procedural_levels=("generator",),
    level_files=True,
    check_levels=_check_levels,
    named_levels=resolve_levels,
    stack_levels=stack_levels,
    egocentric=True,
    normalised_score=False,
    obs_settings=_obs_settings,
    deliveries=_deliveries,
    single_task_own_level=True,
    scripted=scripted_actions,
    needs_partner=needs_handover,
    evaluation_params=EnvParams.without_training_levers,
)


def step_autoreset(
    key: jax.Array,
    state: EnvState,
    actions: jax.Array,
    levels: Level,
    params: EnvParams = EnvParams(),
) -> StepOutput:
    """`step`, then, if the episode ended, starts the next one on `levels[(episode + 1) % K]`
    (`cec.envs.base.step_autoreset` on Overcooked).

    The reset is a select between two cheap states (no generator work on the step path); the returned
    observation is that of the new episode's first state when `done`.

    Args:
        levels: a batched `Level` with leading axis K, this env's buffer of upcoming levels. Give each
            env its own buffer (vmap over it) or share one (`in_axes=None`).
    """
    out = base.step_autoreset(GAME, key, state, actions, levels, params)
    return StepOutput(out.obs, out.state, out.reward, out.shaped, out.done, out.collision)
