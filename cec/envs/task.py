"""Training tasks: one environment plus the distribution its levels are drawn from, behind one interface.

A `Task` is static (hashable; pass it to `jit` as a static argument). It gives the rollout a uniform
view of both games: `reset`, `step` (with auto-reset from a per-env level buffer) returning an `EnvStep`,
and `sample_levels`, which fills the level buffers for one rollout:

    overcooked        generator              CEC: the procedural generator, held-out set excluded
                      cramped_room, ...      single-task IPPO on one classic kitchen
                      kitchens/, a.txt,b.txt your own ASCII kitchens (`cec.levels.named`): one file is a
                                             fixed level, several (or a folder) a distribution, uniform
    dual_destination  fixed | multi_task     the paper's fixed task (or its two-pair variant)
                      procedural[_multi_task] procedural tasks, both fixed tasks excluded
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cec.config import ConfigError
from cec.envs import dual_destination as dd
from cec.envs import overcooked as oc
from cec.envs.base import EnvStep, Game, step_autoreset
from cec.envs.registry import GAMES, game
from cec.levels.classic import CLASSIC_ASCII, classic_level
from cec.levels.generator import GeneratorConfig, generate_batch
from cec.levels.level import stack_levels
from cec.levels.named import absolute_paths, names_files, resolve_levels

ENV_NAMES = tuple(GAMES)
DD_LEVELS = dd.GAME.level_specs
PROCEDURAL_LEVELS = tuple(spec for g in GAMES.values() for spec in g.procedural_levels)
_LEVEL_SPECS = tuple(spec for g in GAMES.values() for spec in g.level_specs)  # never a file name


@dataclass(frozen=True)
class EnvConfig:
    """Which game, which levels, and the game's settings.

    Attributes:
        name: `overcooked` or `dual_destination`.
        levels: the level distribution (see the module docstring): `generator`, a classic kitchen name,
            or ASCII kitchen files / folders (comma-separated) for Overcooked; `fixed`, `multi_task`,
            `procedural` or `procedural_multi_task` for Dual Destination.
        overcooked: Overcooked settings (used when `name` is `overcooked`).
        dual_destination: Dual Destination settings (used when `name` is `dual_destination`).
        generator: what the procedural kitchen generator may produce (used when `levels` is `generator`).
    """

    name: str = "overcooked"
    levels: str = "generator"
    overcooked: oc.EnvParams = field(default_factory=lambda: oc.EnvParams(max_steps=400))
    dual_destination: dd.DDParams = field(default_factory=dd.DDParams)
    generator: GeneratorConfig = field(default_factory=GeneratorConfig)

    def __post_init__(self) -> None:
        if self.name not in ENV_NAMES:
            raise ConfigError(f"env.name {self.name!r} is unknown; choose one of {list(ENV_NAMES)}")
        valid = self.game.level_specs
        if self.game.level_files and self.levels not in valid and _names_files(self.levels):
            # Absolute paths, so that Ray workers and resumed runs read the same files wherever they run.
            object.__setattr__(self, "levels", absolute_paths(self.levels))
            kitchen_set(self.levels)  # read and checked now: a bad file is refused before any work
        elif self.levels not in valid:
            raise ConfigError(
                f"env.levels {self.levels!r} is not valid for {self.name}; choose one of {list(valid)}"
            )
        self.game.check_levels(self.levels, self.params)
        if self.params.max_steps <= 0:
            raise ConfigError(f"env.{self.name}.max_steps must be positive, got {self.params.max_steps}")

    @property
    def game(self) -> Game:
        """The chosen game (`cec.envs.registry`)."""
        return game(self.name)

    @property
    def procedural(self) -> bool:
        """The levels come from a distribution (a generator, several kitchen files), not one fixed level."""
        if self.game.level_files and _names_files(self.levels):
            return len(kitchen_set(self.levels).names) > 1
        return self.levels in PROCEDURAL_LEVELS

    @property
    def levels_label(self) -> str:
        """`levels` as a file-name part: kitchen files and folders by their stems."""
        if self.game.level_files and _names_files(self.levels):
            return "+".join(Path(t).stem for t in self.levels.split(","))
        return self.levels

    @property
    def params(self) -> Any:
        """The settings of the chosen game (a traced pytree: `EnvParams` or `DDParams`): the field named
        after the game."""
        return getattr(self, self.name)


@dataclass(frozen=True)
class Task:
    """A game and its level distribution, as the rollout needs them. Build with `Task.from_config`."""

    env: str
    levels: str
    generator: GeneratorConfig

    @staticmethod
    def from_config(config: EnvConfig) -> Task:
        return Task(config.name, config.levels, config.generator)

    @property
    def game(self) -> Game:
        """The game (`cec.envs.registry`)."""
        return game(self.env)

    @property
    def num_actions(self) -> int:
        return self.game.num_actions

    @property
    def obs_shape(self) -> tuple[int, ...]:
        """One seat's observation shape."""
        return self.game.obs_shape

    def reset(self, key: jax.Array, level: Any, params: Any) -> tuple[jax.Array, Any]:
        """(obs [2, ...], state) of a new episode on one level."""
        return self.game.reset(key, level, params)

    def step(self, key: jax.Array, state: Any, actions: jax.Array, levels: Any, params: Any) -> EnvStep:
        """One env's step with auto-reset onto `levels[(episode + 1) % K]` (a buffer with leading axis K)."""
        return step_autoreset(self.game, key, state, actions, levels, params)

    def sample_levels(self, key: jax.Array, env_ids: jax.Array, k: int) -> Any:
        """Level buffers for the envs `env_ids` (int32[E]), `k` levels each (leading axes [E, k]).

        Env i's levels come from `fold_in(key, i)` alone, so a slice of the envs (a Ray actor's share)
        gets the levels those envs get in the full batch. Fixed tasks are broadcast.

        One jitted function for every `Task` (static): called outside `jit` (a trainer's init, an actor's
        level buffers), a task's sampler is compiled once per process for each number of envs, whichever
        `Trainer` calls it; inside a traced function it is inlined as before.
        """
        return _sample_levels(self, key, env_ids, k)

    def without_level(self, state: Any) -> Any:
        """An env state without its level (what changes step to step; `observe` puts the level back)."""
        return state.replace(level=None)

    def observe(self, state: Any, level: Any, params: Any) -> jax.Array:
        """[2, ...] both seats' observations of a level-less `state` (`without_level`) on `level`."""
        return self.game.get_obs(state.replace(level=level), params)


def _overcooked_levels(task: Task, key: jax.Array, env_ids: jax.Array, k: int) -> Any:
    if task.levels == "generator":
        return jax.vmap(lambda kk: generate_batch(kk, k, task.generator))(env_keys(key, env_ids))
    if task.levels in CLASSIC_ASCII:
        return _broadcast(classic_level(task.levels), (env_ids.shape[0], k))
    kitchens = kitchen_set(task.levels)  # the user's kitchen files, uniformly
    pick = jax.vmap(lambda kk: jax.random.randint(kk, (k,), 0, len(kitchens.names)))
    return jax.tree.map(lambda x: jnp.asarray(x)[pick(env_keys(key, env_ids))], kitchens.levels)


def _dual_destination_levels(task: Task, key: jax.Array, env_ids: jax.Array, k: int) -> Any:
    if task.levels in ("fixed", "multi_task"):
        level = dd.fixed_level() if task.levels == "fixed" else dd.multi_task_level()
        return _broadcast(level, (env_ids.shape[0], k))
    multi = task.levels == "procedural_multi_task"
    exclude = dd.held_out_dd_levels()
    one = lambda kk: dd.generate_dd_level(kk, multi, exclude)  # noqa: E731
    return jax.vmap(lambda kk: jax.vmap(one)(jax.random.split(kk, k)))(env_keys(key, env_ids))


@functools.partial(jax.jit, static_argnums=(0, 3))
def _sample_levels(task: Task, key: jax.Array, env_ids: jax.Array, k: int) -> Any:
    return _LEVEL_SAMPLERS[task.env](task, key, env_ids, k)


#: Each game's training level buffers (`Task.sample_levels`), by game name.
_LEVEL_SAMPLERS: dict[str, Callable[[Task, jax.Array, jax.Array, int], Any]] = {
    oc.GAME.name: _overcooked_levels,
    dd.GAME.name: _dual_destination_levels,
}


class KitchenSet(NamedTuple):
    """Kitchen files read for training: their names (file stems) and the levels stacked [N, ...]."""

    names: tuple[str, ...]
    levels: Any


def _names_files(levels: str) -> bool:
    if levels in _LEVEL_SPECS:
        return False
    return names_files(levels)


@functools.cache
def kitchen_set(levels: str) -> KitchenSet:
    """The kitchens of an `env.levels` that names files or folders (read once per process; relative paths
    from the working directory); `ConfigError` naming a missing, malformed or unsolvable file."""
    found = resolve_levels(levels)
    return KitchenSet(tuple(found), jax.device_get(stack_levels(list(found.values()))))


def env_keys(key: jax.Array, env_ids: jax.Array) -> jax.Array:
    """uint32[E, 2]: each env's own key, `fold_in(key, env_id)` (independent of which envs are batched)."""
    return jax.vmap(jax.random.fold_in, in_axes=(None, 0))(key, env_ids)


def _broadcast(level: Any, shape: tuple[int, ...]) -> Any:
    return jax.tree.map(lambda x: jnp.broadcast_to(jnp.asarray(x), (*shape, *jnp.shape(x))), level)
