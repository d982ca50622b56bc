"""A JaxMARL-shaped front for the one Overcooked env: `MultiAgentEnv`'s API over `reset` and `step`.

`OvercookedMultiAgentEnv` has the attributes and methods JaxMARL's training loops use (`agents`,
`num_agents`, `reset(key)`, `step(key, state, actions)` with auto-reset, `observation_space(agent)`,
`action_space(agent)`, the shaped reward in `info["shaped_reward"]`), so that a JaxMARL IPPO script runs on
it unchanged. It adds no dynamics of its own: `step_env` is `cec.envs.overcooked.step` with dicts keyed by
agent, and `reset` is `cec.envs.overcooked.reset` on a level drawn from the level source:

* a classic layout name (``"cramped_room"``, ...) or one fixed `Level`: every episode plays that kitchen;
* a batched `Level` (leading axis K): each episode plays one of the K, drawn uniformly;
* a `GeneratorConfig` (or ``"generator"`` for the default one): each episode plays a fresh procedural
  kitchen from `cec.levels.generator.generate`, as in CEC's training.

Observations are JaxMARL Overcooked's 26 channels (the same channel list, checked cell for cell by
tests/parity), uint8. For one fixed kitchen they are cropped to the kitchen, ``(height, width, 26)``, as
JaxMARL's own arrays are (its `observation_space` reports ``(width, height, 26)``; ours reports the
arrays' real shape). Kitchens of varying size need one shape, so a batch or the generator gives the whole
9x9 frame, ``(9, 9, 26)``, as CEC's agents see it; ``crop=False`` gives that for a fixed kitchen too.

JaxMARL itself is never imported: `Discrete` and `Box` below are minimal equivalents of its spaces.
"""

from __future__ import annotations

import dataclasses
from collections.abc import Mapping
from functools import partial
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from cec.config import ConfigError
from cec.envs.overcooked.dynamics import reset as oc_reset
from cec.envs.overcooked.dynamics import step as oc_step
from cec.envs.overcooked.observation import get_obs as oc_get_obs
from cec.envs.overcooked.state import NUM_ACTIONS, NUM_CHANNELS, EnvParams, EnvState
from cec.levels import GRID_SIZE, Level, LevelError, stack_levels, unstack_levels, validate_level
from cec.levels.classic import CLASSIC_ASCII, classic_level
from cec.levels.generator import GeneratorConfig, generate
from cec.levels.named import resolve_levels

AGENTS = ("agent_0", "agent_1")

#: What `OvercookedMultiAgentEnv` accepts as its kitchens.
LevelSource = str | Level | GeneratorConfig


class Discrete:
    """A jittable discrete space {0, ..., n - 1} (JaxMARL's `spaces.Discrete`: `.n`, `.shape`, `.sample`)."""

    def __init__(self, num_categories: int, dtype: Any = jnp.int32) -> None:
        if num_categories < 1:
            raise ValueError(f"a discrete space needs at least one category, got {num_categories}")
        self.n = num_categories
        self.shape: tuple[int, ...] = ()
        self.dtype = dtype

    def sample(self, rng: jax.Array) -> jax.Array:
        """A uniform draw."""
        return jax.random.randint(rng, self.shape, 0, self.n).astype(self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether `x` lies in the space."""
        return jnp.logical_and(x >= 0, x < self.n)

    def __repr__(self) -> str:
        return f"Discrete({self.n})"


class Box:
    """A jittable box of `shape` between `low` and `high` (JaxMARL's `spaces.Box`)."""

    def __init__(self, low: float, high: float, shape: tuple[int, ...], dtype: Any = jnp.float32) -> None:
        self.low = low
        self.high = high
        self.shape = shape
        self.dtype = dtype

    def sample(self, rng: jax.Array) -> jax.Array:
        """A uniform draw (rounded down for integer dtypes)."""
        return jax.random.uniform(rng, self.shape, minval=self.low, maxval=self.high).astype(self.dtype)

    def contains(self, x: jax.Array) -> jax.Array:
        """Whether every entry of `x` lies within the bounds."""
        return jnp.logical_and(jnp.all(x >= self.low), jnp.all(x <= self.high))

    def __repr__(self) -> str:
        return f"Box({self.low}, {self.high}, {self.shape}, {jnp.dtype(self.dtype).name})"


def _resolve(levels: LevelSource) -> Level | GeneratorConfig:
    """A classic name -> its `Level`; ``"generator"`` -> the default `GeneratorConfig`; levels validated."""
    if isinstance(levels, GeneratorConfig):
        return levels
    if isinstance(levels, str):
        if levels == "generator":
            return GeneratorConfig()
        if levels in CLASSIC_ASCII:
            return classic_level(levels)
        try:  # names, sets, kitchen files and folders, as everywhere (`cec.levels.named`)
            found = list(resolve_levels(levels).values())
        except ConfigError as err:
            raise ValueError(
                f"level source {levels!r}: {err}; or give 'generator', a Level or a GeneratorConfig"
            ) from None
        return found[0] if len(found) == 1 else stack_levels(found)
    if isinstance(levels, Level):
        level = jax.tree.map(jnp.asarray, levels)
        ndim = np.ndim(level.grid)
        if ndim not in (2, 3):
            raise LevelError(
                f"levels must be one Level or a batch of them, got grid of shape {level.grid.shape}"
            )
        for one in unstack_levels(level) if ndim == 3 else [level]:
            validate_level(one)
        return level
    raise TypeError(
        f"levels must be a classic layout name, 'generator', a Level or a GeneratorConfig, got "
        f"{type(levels).__name__}"
    )


class OvercookedMultiAgentEnv:
    """Overcooked with JaxMARL's `MultiAgentEnv` interface; the state is the project's `EnvState`.

    Args:
        levels: the kitchens (see the module docstring): a classic layout name, ``"generator"``, a `Level`
            (one, or a batch to draw from), a `GeneratorConfig`, or any level spec of `cec.levels.named`
            (held-out names and sets, ASCII kitchen files, folders of them).
        params: the dynamics settings (rewards, episode length, random start facings). The defaults are
            the paper's shaped rewards (10 / 15 / 3); JaxMARL 0.2.0's are
            ``EnvParams(onion_in_pot_reward=3, soup_pickup_reward=5, plate_pickup_reward=3)``.
        max_steps: episode length; overrides ``params.max_steps`` when given (JaxMARL's keyword).
        crop: observations cropped to the kitchen (``(h, w, 26)``); default: only for one fixed kitchen,
            which is the only case it is possible.

    `reset` and `step` are jitted with the env as a static argument, as in JaxMARL, and vmap over keys.
    """

    def __init__(
        self,
        levels: LevelSource = "cramped_room",
        *,
        params: EnvParams = EnvParams(),
        max_steps: int | None = None,
        crop: bool | None = None,
    ) -> None:
        self.levels = _resolve(levels)
        self.params = params if max_steps is None else dataclasses.replace(params, max_steps=max_steps)
        if int(self.params.max_steps) < 1:
            raise ValueError(f"max_steps must be at least 1, got {self.params.max_steps}")
        fixed = isinstance(self.levels, Level) and np.ndim(self.levels.grid) == 2
        if crop and not fixed:
            raise ValueError(
                "crop=True needs one fixed kitchen: a batch of levels or the generator has kitchens of "
                "different sizes, which share the 9x9 frame's observation shape"
            )
        self.crop = fixed if crop is None else crop
        if self.crop:
            assert isinstance(self.levels, Level)
            h, w = (int(v) for v in np.asarray(self.levels.size))
        else:
            h, w = GRID_SIZE, GRID_SIZE
        self._hw = (h, w)

        self.num_agents = len(AGENTS)
        self.agents = list(AGENTS)
        self.obs_shape = (h, w, NUM_CHANNELS)
        self.observation_spaces = {a: Box(0, 255, self.obs_shape, jnp.uint8) for a in self.agents}
        self.action_spaces = {a: Discrete(NUM_ACTIONS, jnp.int32) for a in self.agents}

    # -- level source ---------------------------------------------------------------------------------

    def _level_and_key(self, key: jax.Array) -> tuple[Level, jax.Array]:
        """The level of a new episode and the key left for `reset`'s own draws."""
        source = self.levels
        if isinstance(source, Level) and np.ndim(source.grid) == 2:
            return source, key  # the same key as a direct `reset(key, level)`
        k_level, k_reset = jax.random.split(key)
        if isinstance(source, GeneratorConfig):
            return generate(k_level, source), k_reset
        i = jax.random.randint(k_level, (), 0, source.grid.shape[0])
        return jax.tree.map(lambda x: x[i], source), k_reset

    # -- MultiAgentEnv API ----------------------------------------------------------------------------

    def _split(self, obs: jax.Array) -> dict[str, jax.Array]:
        h, w = self._hw
        if self.crop:
            obs = obs[:, :h, :w, :]
        return {a: obs[i] for i, a in enumerate(self.agents)}

    @partial(jax.jit, static_argnums=(0,))
    def reset(self, key: jax.Array) -> tuple[dict[str, jax.Array], EnvState]:
        """Starts an episode on a kitchen from the level source. Returns (observations by agent, state)."""
        level, key = self._level_and_key(key)
        obs, state = oc_reset(key, level, self.params)
        return self._split(obs), state

    def step_env(
        self, key: jax.Array, state: EnvState, actions: Mapping[str, jax.Array]
    ) -> tuple[dict[str, jax.Array], EnvState, dict[str, jax.Array], dict[str, jax.Array], dict[str, Any]]:
        """One joint step without auto-reset: `cec.envs.overcooked.step` with dicts keyed by agent.

        Actions are integers in 0..5 (up, down, right, left, stay, interact); inside `jit` an out-of-range
        action acts as stay. Any other dtype (a float, NaN, a bool) is refused with a `TypeError` naming the
        agent: a cast would turn NaN into `up`, not `stay`, and 2.7 into `right`.
        """
        joint = []
        for a in self.agents:
            act = jnp.asarray(actions[a])
            if not jnp.issubdtype(act.dtype, jnp.integer):  # static under jit: checked while tracing
                raise TypeError(
                    f"the action of {a} must be an integer in 0..{NUM_ACTIONS - 1} (up, down, right, left, "
                    f"stay, interact), got dtype {act.dtype}"
                )
            joint.append(jnp.reshape(act, ()))
        out = oc_step(key, state, jnp.stack(joint).astype(jnp.int32), self.params)
        rewards = dict.fromkeys(self.agents, out.reward)
        dones = {**dict.fromkeys(self.agents, out.done), "__all__": out.done}
        # Only the shaped reward, as JaxMARL's Overcooked: IPPO loops reshape every other info leaf.
        info = {"shaped_reward": {a: out.shaped_reward[i] for i, a in enumerate(self.agents)}}
        return self._split(out.obs), out.state, rewards, dones, info

    @partial(jax.jit, static_argnums=(0,))
    def step(
        self,
        key: jax.Array,
        state: EnvState,
        actions: Mapping[str, jax.Array],
        reset_state: EnvState | None = None,
    ) -> tuple[dict[str, jax.Array], EnvState, dict[str, jax.Array], dict[str, jax.Array], dict[str, Any]]:
        """`step_env`, then, when the episode ended, the first observation and state of the next one.

        As JaxMARL's `MultiAgentEnv.step`: the key is split into the step's and the reset's; the next episode
        starts from `reset(reset key)` (a new kitchen from the level source), or from `reset_state` when
        given. Rewards, dones and info are those of the step that ended the episode.
        """
        key, key_reset = jax.random.split(key)
        obs_st, state_st, rewards, dones, info = self.step_env(key, state, actions)
        if reset_state is None:
            obs_re, state_re = self.reset(key_reset)
        else:
            state_re, obs_re = reset_state, self.get_obs(reset_state)
        done = dones["__all__"]
        state = jax.tree.map(lambda x, y: jax.lax.select(done, x, y), state_re, state_st)
        obs = jax.tree.map(lambda x, y: jax.lax.select(done, x, y), obs_re, obs_st)
        return obs, state, rewards, dones, info

    def get_obs(self, state: EnvState) -> dict[str, jax.Array]:
        """Both agents' observations of `state`, keyed by agent."""
        return self._split(oc_get_obs(state, self.params))

    def get_avail_actions(self, state: EnvState) -> dict[str, jax.Array]:
        """Every action is always available (a blocked move turns the agent, as in JaxMARL)."""
        del state
        return {a: jnp.ones((NUM_ACTIONS,), jnp.bool_) for a in self.agents}

    def observation_space(self, agent: str = AGENTS[0]) -> Box:
        """uint8 (h, w, 26) per agent (the same for both; JaxMARL's IPPO calls it without an agent)."""
        return self.observation_spaces[agent]

    def action_space(self, agent: str = AGENTS[0]) -> Discrete:
        """Discrete(6) per agent: up, down, right, left, stay, interact."""
        return self.action_spaces[agent]

    @property
    def name(self) -> str:
        return "Overcooked"

    @property
    def num_actions(self) -> int:
        return NUM_ACTIONS

    @property
    def agent_classes(self) -> dict[str, list[str]]:
        return {"agent": list(self.agents)}

    def __repr__(self) -> str:
        source = self.levels
        if isinstance(source, GeneratorConfig):
            what = "generator"
        elif np.ndim(source.grid) == 3:
            what = f"{source.grid.shape[0]} levels"
        else:
            what = "one level"
        return (
            f"OvercookedMultiAgentEnv({what}, obs {self.obs_shape}, max_steps={int(self.params.max_steps)})"
        )
