"""A PettingZoo `ParallelEnv` over the one Overcooked env, for users outside JAX: NumPy in, NumPy out.

Needs the optional `pettingzoo` extra (``pip install -e '.[pettingzoo]'``); nothing else in `cec` imports
this module. The env is `OvercookedMultiAgentEnv` (cec.envs.overcooked.jaxmarl_api) driven one step at a
time through two jitted functions, so it takes the same level sources (a classic layout name,
``"generator"``, a `Level` or a batch of them, a `GeneratorConfig`) and plays the same dynamics.

PettingZoo's conventions: an Overcooked episode has no terminal state, so `terminations` are always False
and the time limit (``max_steps``) is a truncation; at the end of an episode `agents` becomes empty and the
next `reset` starts a new one (on a new kitchen, for a batch or the generator). Rewards are the team's
sparse delivery reward, the same for both agents; each agent's shaped reward is in
``infos[agent]["shaped_reward"]``.
"""

from __future__ import annotations

from typing import Any

import jax
import numpy as np

from cec.envs.overcooked.jaxmarl_api import LevelSource, OvercookedMultiAgentEnv
from cec.envs.overcooked.render import render_frame, state_to_ascii
from cec.envs.overcooked.state import NUM_ACTIONS, EnvParams, EnvState

try:
    import gymnasium
    from pettingzoo import ParallelEnv
except ImportError as e:  # pragma: no cover - depends on the installed extras
    raise ImportError(
        "cec.envs.overcooked.pettingzoo_api needs PettingZoo and Gymnasium: pip install -e '.[pettingzoo]'"
    ) from e


class OvercookedParallelEnv(ParallelEnv[str, np.ndarray, int]):
    """Overcooked as a PettingZoo `ParallelEnv` (agents ``agent_0`` and ``agent_1``, simultaneous moves).

    Args:
        levels: the kitchens (see `OvercookedMultiAgentEnv`).
        params: dynamics settings (rewards, episode length, random start facings).
        max_steps: episode length; overrides ``params.max_steps`` when given.
        crop: observations cropped to the kitchen (default: only for one fixed kitchen).
        render_mode: None, ``"rgb_array"`` (an RGB image of the kitchen) or ``"ansi"`` (text).
        tile_size: pixels per cell of ``"rgb_array"`` frames.

    Observations are uint8 arrays of JaxMARL's 26 channels (``observation_space(agent).shape``); actions are
    integers 0..5: up, down, right, left, stay, interact.
    """

    metadata: dict[str, Any] = {
        "name": "cec_overcooked_v0",
        "render_modes": ["rgb_array", "ansi"],
        "is_parallelizable": True,
    }

    def __init__(
        self,
        levels: LevelSource = "cramped_room",
        *,
        params: EnvParams = EnvParams(),
        max_steps: int | None = None,
        crop: bool | None = None,
        render_mode: str | None = None,
        tile_size: int = 32,
    ) -> None:
        if render_mode is not None and render_mode not in self.metadata["render_modes"]:
            raise ValueError(
                f"render_mode must be None or one of {self.metadata['render_modes']}, got {render_mode!r}"
            )
        self.env = OvercookedMultiAgentEnv(levels, params=params, max_steps=max_steps, crop=crop)
        self.render_mode = render_mode
        self.tile_size = tile_size
        self.possible_agents: list[str] = list(self.env.agents)
        self.agents: list[str] = []
        self._observation_spaces = {
            a: gymnasium.spaces.Box(0, 255, self.env.obs_shape, np.uint8) for a in self.possible_agents
        }
        self._action_spaces: dict[str, gymnasium.spaces.Discrete] = {
            a: gymnasium.spaces.Discrete(NUM_ACTIONS) for a in self.possible_agents
        }
        self._reset = self.env.reset  # jitted already
        self._step = jax.jit(self.env.step_env)
        self._key: jax.Array | None = None
        self._state: EnvState | None = None

    def observation_space(self, agent: str) -> gymnasium.spaces.Box:
        return self._observation_spaces[agent]

    def action_space(self, agent: str) -> gymnasium.spaces.Discrete:
        return self._action_spaces[agent]

    def reset(
        self, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[dict[str, np.ndarray], dict[str, dict[str, Any]]]:
        """Starts an episode. `seed` restarts the env's key chain (same seed, same episodes); without one
        the chain goes on (the first reset of an unseeded env draws a seed from the OS). `options` is
        accepted and unused."""
        del options
        if seed is not None:
            self._key = jax.random.PRNGKey(seed)
        elif self._key is None:
            self._key = jax.random.PRNGKey(int(np.random.SeedSequence().generate_state(1)[0]))
        self._key, key = jax.random.split(self._key)
        obs, self._state = self._reset(key)
        self.agents = list(self.possible_agents)
        return self._host_obs(obs), {a: {} for a in self.agents}

    def step(
        self, actions: dict[str, Any]
    ) -> tuple[
        dict[str, np.ndarray],
        dict[str, float],
        dict[str, bool],
        dict[str, bool],
        dict[str, dict[str, Any]],
    ]:
        """One simultaneous step of both agents; `actions` maps each live agent to an integer 0..5."""
        if not self.agents or self._state is None or self._key is None:
            raise RuntimeError("the episode is over (or never started): call reset() first")
        missing = [a for a in self.agents if a not in actions]
        if missing:
            raise ValueError(f"no action for {missing}; both agents act at every step")
        joint = {}
        for a in self.agents:
            act = np.asarray(actions[a])
            if act.shape != () or not np.issubdtype(act.dtype, np.integer) or not 0 <= act < NUM_ACTIONS:
                raise ValueError(
                    f"the action of {a} must be one integer in 0..{NUM_ACTIONS - 1} (up, down, right, left, "
                    f"stay, interact), got {actions[a]!r}"
                )
            joint[a] = np.int32(act)
        self._key, key = jax.random.split(self._key)
        obs, self._state, rewards, dones, info = self._step(key, self._state, joint)
        rewards, dones, shaped = jax.device_get((rewards, dones, info["shaped_reward"]))
        truncated = bool(dones["__all__"])
        out = (
            self._host_obs(obs),
            {a: float(rewards[a]) for a in self.agents},
            dict.fromkeys(self.agents, False),
            dict.fromkeys(self.agents, truncated),
            {a: {"shaped_reward": float(shaped[a])} for a in self.agents},
        )
        if truncated:
            self.agents = []
        return out

    def render(self) -> np.ndarray | str | None:
        """The current state: an RGB image (``"rgb_array"``), text (``"ansi"``), or None without a mode."""
        if self.render_mode is None:
            gymnasium.logger.warn("render() without a render_mode: give render_mode='rgb_array' or 'ansi'")
            return None
        if self._state is None:
            raise RuntimeError("nothing to render yet: call reset() first")
        if self.render_mode == "rgb_array":
            return render_frame(self._state, self.tile_size)
        return state_to_ascii(self._state)

    def close(self) -> None:
        """Nothing to release."""

    def _host_obs(self, obs: dict[str, jax.Array]) -> dict[str, np.ndarray]:
        host = jax.device_get(obs)
        return {a: np.asarray(host[a]) for a in self.possible_agents}
