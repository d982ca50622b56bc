"""The one interface every game offers, and the one auto-reset written over it.

A `Game` is a frozen bundle of a game's pure functions and the facts its callers need (training, evaluation,
reports), so that nothing outside a game's own package asks for the game by name. The games are
`cec.envs.overcooked.GAME` and `cec.envs.dual_destination.GAME`; `cec.envs.registry` finds one by name.

`step_autoreset(game, ...)` is the only auto-reset: both games' `step_autoreset` call it.
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np


class Transition(NamedTuple):
    """One joint step's dynamics, before observations and auto-reset.

    Attributes:
        state: the next state (not reset).
        reward: float32[] team reward of the step (sparse; the same for both seats).
        shaped: float32[2] per-seat shaped reward (zeros for a game without shaping).
        done: bool[] the episode ended with this step.
        collision: bool[] a move was cancelled by the other agent (always False in a game without them).
    """

    state: Any
    reward: jax.Array
    shaped: jax.Array
    done: jax.Array
    collision: jax.Array


class EnvStep(NamedTuple):
    """One env's step, the same for every game.

    Attributes:
        obs: [2, ...] each seat's observation (uint8 for Overcooked, float32 for Dual Destination).
        state: the next env state (after auto-reset when `done`, for `step_autoreset`).
        reward: float32[] team reward of the step (sparse; the same for both seats).
        shaped: float32[2] per-seat shaped reward (zeros for Dual Destination).
        done: bool[] the episode ended with this step.
        collision: bool[] a move was cancelled by the other agent (always False in Dual Destination).
    """

    obs: jax.Array
    state: Any
    reward: jax.Array
    shaped: jax.Array
    done: jax.Array
    collision: jax.Array


@dataclass(frozen=True)
class Game:
    """A game: its pure functions (jittable, vmappable) and the facts its callers need.

    Dynamics (`state`, `level`, `params` are the game's own pytrees; `obs` is [2, ...], one per seat):
        reset(key, level, params) -> (obs, state): a new episode on one level; checks eager inputs.
        initial_state(key, level, params) -> state: the first state of an episode, unchecked (what
            `reset` and the auto-reset share; `episode` is 0).
        transition(key, state, actions, params) -> `Transition`: one joint step without observations or
            auto-reset; eager actions out of range raise `ValueError`.
        get_obs(state, params) -> obs.

    Levels:
        level_specs: the valid `env.levels` of training (`EnvConfig.levels`) apart from level files.
        default_levels: the level spec a policy plays when nothing else is said (a scripted policy).
        procedural_levels: those of `level_specs` that are distributions (generators), not one level.
        level_files: `env.levels` may also name the user's level files or folders (`cec.levels.named`).
        check_levels(levels, params): raises `ConfigError` when the game's settings cannot play `levels`.
        named_levels(spec) -> {name: level}: the evaluation levels named by `spec`, in a stable order;
            `ConfigError` for an unknown name.
        stack_levels(levels) -> a batched level (leading axis len(levels)).

    Observations, scores, evaluation:
        egocentric: channel 0 marks the seat's own cell, so a network may centre the view on it.
        normalised_score: reported scores are return / (2 x episode length) (not the team return).
        obs_settings(params) -> tuple: the settings the observations depend on (equal for cross-play).
        deliveries(returns, steps, params) -> float64[N]: the goal events (Overcooked's soups, Dual
            Destination's steps on a goal pair) behind `returns` of episodes of `steps` steps.
        single_task_own_level: an agent trained on one fixed level meets other agents only on that level
            (Overcooked: a kitchen's agent knows only its kitchen); otherwise it plays every level.

    Partners:
        scripted(key, state, epsilon, yields) -> int32[2]: both seats' actions of the game's hand-written
            policy, read from the full state (a training partner, `cec.training.partners`): uniformly
            random with probability `epsilon` per seat; `yields` (static) whether it gives way where its
            route and its partner's collide. None: the game has none.
        needs_partner(state) -> bool[]: whether neither seat can reach the goal alone in this state's level
            (Overcooked: a kitchen that needs a hand-over across a counter), for a scripted partner kept to
            such levels (`partner.scripted_where_needed`). None: the game cannot tell.
        evaluation_params(params) -> params: the settings evaluation plays a policy under, given those it
            trained with: training-only levers (e.g. Overcooked's random start items) off.
    """

    name: str
    num_actions: int
    obs_shape: tuple[int, ...]
    reset: Callable[[jax.Array, Any, Any], tuple[jax.Array, Any]]
    initial_state: Callable[[jax.Array, Any, Any], Any]
    transition: Callable[[jax.Array, Any, jax.Array, Any], Transition]
    get_obs: Callable[[Any, Any], jax.Array]
    level_specs: tuple[str, ...]
    default_levels: str
    procedural_levels: tuple[str, ...]
    level_files: bool
    check_levels: Callable[[str, Any], None]
    named_levels: Callable[[str], Mapping[str, Any]]
    stack_levels: Callable[[Sequence[Any]], Any]
    egocentric: bool
    normalised_score: bool
    obs_settings: Callable[[Any], tuple]
    deliveries: Callable[[np.ndarray, int, Any], np.ndarray]
    single_task_own_level: bool
    scripted: Callable[[jax.Array, Any, Any, bool], jax.Array] | None = None
    needs_partner: Callable[[Any], jax.Array] | None = None
    evaluation_params: Callable[[Any], Any] = lambda params: params

    @property
    def fixed_levels(self) -> tuple[str, ...]:
        """The level specs that name one level (not a distribution), e.g. Overcooked's classic kitchens."""
        return tuple(spec for spec in self.level_specs if spec not in self.procedural_levels)

    def step(self, key: jax.Array, state: Any, actions: jax.Array, params: Any) -> EnvStep:
        """One joint step, without auto-reset."""
        t = self.transition(key, state, actions, params)
        return EnvStep(self.get_obs(t.state, params), t.state, t.reward, t.shaped, t.done, t.collision)


def step_autoreset(
    game: Game, key: jax.Array, state: Any, actions: jax.Array, levels: Any, params: Any
) -> EnvStep:
    """`game`'s step, then, if the episode ended, the next one starts on `levels[(episode + 1) % K]`.

    The reset is a select between two cheap states (no generator work on the step path); the returned
    observation is that of the new episode's first state when `done`, while `reward`, `shaped`, `done` and
    `collision` are those of the step that ended the old one. `key` goes to the step and to the new
    episode's first state.

    Args:
        levels: a batched level with leading axis K, this env's buffer of upcoming levels. Give each env its
            own buffer (vmap over it) or share one (`in_axes=None`).
    """
    t = game.transition(key, state, actions, params)
    n_levels = jax.tree.leaves(levels)[0].shape[0]
    episode = t.state.episode + 1
    next_level = jax.tree.map(lambda x: x[0] if n_levels == 1 else x[episode % n_levels], levels)
    fresh = game.initial_state(key, next_level, params).replace(episode=episode)
    new_state = jax.tree.map(lambda a, b: jnp.where(t.done, a, b), fresh, t.state)
    return EnvStep(game.get_obs(new_state, params), new_state, t.reward, t.shaped, t.done, t.collision)
