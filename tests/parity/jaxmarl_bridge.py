"""Runs JaxMARL 0.2.0's Overcooked beside ours on the same actions and counts every disagreement.

Both envs run in one jitted scan per episode. JaxMARL plays the classic layout at its native size; ours
plays the same kitchen in the top-left of the 9x9 frame, so JaxMARL's (x, y) is our (col, row) and its
observation equals ours restricted to the kitchen's own cells.
"""

from __future__ import annotations

import warnings
from typing import NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs import overcooked as oc
from cec.envs.overcooked.scripted import scripted_actions
from cec.levels import Item, Level

with warnings.catch_warnings():
    warnings.simplefilter("ignore")
    from flax.core.frozen_dict import FrozenDict
    from jaxmarl.environments.overcooked import overcooked as jm_module
    from jaxmarl.environments.overcooked.common import OBJECT_TO_INDEX
    from jaxmarl.environments.overcooked.layouts import overcooked_layouts

PAD = 4  # JaxMARL pads its maze_map by agent_view_size - 1 cells
# JaxMARL object code -> our Item code (anything that is not an item maps to NONE)
JM_TO_ITEM = np.zeros(11, np.int32)
JM_TO_ITEM[OBJECT_TO_INDEX["onion"]] = Item.ONION
JM_TO_ITEM[OBJECT_TO_INDEX["plate"]] = Item.PLATE
JM_TO_ITEM[OBJECT_TO_INDEX["dish"]] = Item.DISH
JM_TO_ITEM = jnp.asarray(JM_TO_ITEM)

FIELDS = ("pos", "dir", "inv", "pot", "items", "reward", "shaped", "done", "obs")


class Mismatches(NamedTuple):
    """Per-field count of steps at which the two envs disagree, plus coverage counters."""

    counts: dict[str, int]
    steps: int
    deliveries: int
    onions_in_pot: int
    soups_plated: int
    plate_bonuses: int
    first: dict[str, tuple[int, int]]  # field -> (episode, step) of the first disagreement


def make_jaxmarl_env(name: str, max_steps: int, params: oc.EnvParams):  # noqa: ANN201
    """JaxMARL's Overcooked on the native classic layout, shaped rewards set to `params`' values."""
    jm_module.BASE_REW_SHAPING_PARAMS.update(
        PLACEMENT_IN_POT_REW=params.onion_in_pot_reward,
        SOUP_PICKUP_REWARD=params.soup_pickup_reward,
        PLATE_PICKUP_REWARD=params.plate_pickup_reward,
    )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return jm_module.Overcooked(layout=FrozenDict(overcooked_layouts[name]), max_steps=max_steps)


def _jm_view(jm_state, h: int, w: int) -> dict[str, jax.Array]:  # noqa: ANN001
    maze = jm_state.maze_map[PAD : PAD + h, PAD : PAD + w]
    obj = maze[..., 0]
    pots = jnp.where(obj == OBJECT_TO_INDEX["pot"], maze[..., 2], 0)
    return {
        "pos": jm_state.agent_pos[:, ::-1].astype(jnp.int32),  # (x, y) -> (row, col)
        "dir": jm_state.agent_dir_idx.astype(jnp.int32),
        "inv": JM_TO_ITEM[jm_state.agent_inv],
        "pot": pots.astype(jnp.int32),
        "items": JM_TO_ITEM[obj],
    }


def _our_view(state: oc.EnvState, h: int, w: int) -> dict[str, jax.Array]:
    return {
        "pos": state.agent_pos,
        "dir": state.agent_dir,
        "inv": state.agent_inv,
        "pot": state.pot[:h, :w].astype(jnp.int32),
        "items": state.items[:h, :w].astype(jnp.int32),
    }


def run_parity(
    name: str,
    level: Level,
    n_episodes: int,
    max_steps: int,
    seed: int = 0,
    params: oc.EnvParams | None = None,
    jaxmarl_env: object | None = None,
    our_max_steps: int | None = None,
) -> Mismatches:
    """Plays `n_episodes` episodes of `max_steps` steps in lockstep and counts disagreements.

    A quarter of the episodes use uniform random actions, a quarter interact-heavy random actions
    (half of all actions are interact), and half the scripted cook with 10-40% random actions, so that
    soups are cooked, plated and delivered and items are handed over on counters.
    """
    params = (params or oc.EnvParams()).replace(max_steps=max_steps, random_start_facing=False)
    jm_env = jaxmarl_env or make_jaxmarl_env(name, max_steps, params)
    if our_max_steps is not None:  # only to check that the harness sees differences
        params = params.replace(max_steps=our_max_steps)
    h, w = (int(v) for v in np.asarray(level.size))

    def episode(key: jax.Array, mode: jax.Array) -> tuple[dict[str, jax.Array], jax.Array]:
        k_reset, k_steps = jax.random.split(key)
        _, jm_state = jm_env.reset(k_reset)
        # Same start facings as JaxMARL's random ones.
        _, state = oc.reset(
            k_reset, level.replace(agent_dir=jm_state.agent_dir_idx.astype(jnp.int32)), params
        )

        def body(carry, k):  # noqa: ANN001, ANN202
            state, jm_state = carry
            k_pol, k_uni, k_int, k_step = jax.random.split(k, 4)
            uniform = jax.random.randint(k_uni, (2,), 0, oc.NUM_ACTIONS)
            interact_heavy = jnp.where(jax.random.uniform(k_int, (2,)) < 0.5, oc.Action.INTERACT, uniform)
            eps = 0.1 + 0.3 * (mode - 2) / 2.0
            scripted = scripted_actions(k_pol, state, eps)
            actions = jnp.select([mode == 0, mode == 1], [uniform, interact_heavy], scripted)
            actions = actions.astype(jnp.int32)

            out = oc.step(k_step, state, actions, params)
            jm_obs, jm_next, jm_rew, jm_done, jm_info = jm_env.step_env(
                k_step, jm_state, {"agent_0": actions[0], "agent_1": actions[1]}
            )
            ours, theirs = _our_view(out.state, h, w), _jm_view(jm_next, h, w)
            jm_shaped = jnp.stack([jm_info["shaped_reward"]["agent_0"], jm_info["shaped_reward"]["agent_1"]])
            jm_obs_both = jnp.stack([jm_obs["agent_0"], jm_obs["agent_1"]])
            diff = {k: jnp.any(ours[k] != theirs[k]) for k in ours}
            diff["reward"] = out.reward != jm_rew["agent_0"]
            diff["shaped"] = jnp.any(out.shaped_reward != jm_shaped)
            diff["done"] = out.done != jm_done["__all__"]
            diff["obs"] = jnp.any(out.obs[:, :h, :w, :] != jm_obs_both)
            stats = {
                "deliveries": (out.reward > 0).astype(jnp.int32),
                "onions_in_pot": jnp.sum(out.shaped_reward == params.onion_in_pot_reward),
                "soups_plated": jnp.sum(out.shaped_reward == params.soup_pickup_reward),
                "plate_bonuses": jnp.sum(out.shaped_reward == params.plate_pickup_reward),
            }
            return (out.state, jm_next), ({k: diff[k] for k in FIELDS}, stats)

        _, (diffs, stats) = jax.lax.scan(body, (state, jm_state), jax.random.split(k_steps, max_steps))
        return diffs, stats

    keys = jax.random.split(jax.random.PRNGKey(seed), n_episodes)
    modes = jnp.arange(n_episodes) % 4
    diffs, stats = jax.jit(jax.vmap(episode))(keys, modes)
    diffs = jax.device_get(diffs)
    counts = {k: int(np.sum(v)) for k, v in diffs.items()}
    first = {}
    for k, v in diffs.items():
        if v.any():
            ep, st = np.argwhere(v)[0]
            first[k] = (int(ep), int(st))
    return Mismatches(
        counts=counts,
        steps=n_episodes * max_steps,
        deliveries=int(np.sum(stats["deliveries"])),
        onions_in_pot=int(np.sum(stats["onions_in_pot"])),
        soups_plated=int(np.sum(stats["soups_plated"])),
        plate_bonuses=int(np.sum(stats["plate_bonuses"])),
        first=first,
    )
