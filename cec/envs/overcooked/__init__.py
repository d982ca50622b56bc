"""Overcooked (JaxMARL v1 dynamics) as pure functions over levels: `reset`, `step`, `step_autoreset`;
`GAME` is the game as a `cec.envs.base.Game`."""

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.game import GAME, step_autoreset
from cec.envs.overcooked.observation import get_obs
from cec.envs.overcooked.state import (
    NUM_ACTIONS,
    NUM_CHANNELS,
    POT_EMPTY,
    POT_FULL,
    POT_READY,
    Action,
    EnvParams,
    EnvState,
    StepOutput,
)
from cec.levels.classic import CLASSIC_ASCII, CLASSIC_NAMES, classic_level, classic_levels

__all__ = [
    "CLASSIC_ASCII",
    "CLASSIC_NAMES",
    "GAME",
    "NUM_ACTIONS",
    "NUM_CHANNELS",
    "POT_EMPTY",
    "POT_FULL",
    "POT_READY",
    "Action",
    "EnvParams",
    "EnvState",
    "StepOutput",
    "classic_level",
    "classic_levels",
    "get_obs",
    "reset",
    "step",
    "step_autoreset",
]
