"""Compact trajectories: what a Ray actor ships instead of observations, and how the learner expands them.

An Overcooked observation is 9x9x26 bytes per seat (2,106 B per agent-step); the env state it is computed
from, without the level, is ~200 B per env step. An actor records the level-less states
(`rollout(..., record="state")`) and ships them with the levels its envs played; the learner recomputes the
observations with the env's own `get_obs` (a pure function of state and level), so the update sees exactly
the trajectory the actor saw. Everything crosses the process boundary as msgpack bytes (no pickles).

Which level a step was played on: a rollout starts in the middle of episodes, on the levels the carry holds
(`start_level`); an episode that starts during the rollout plays `levels[e, episode % K]` (auto-reset).
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
from flax import serialization

from cec.envs.task import Task
from cec.training.rollout import Trajectory


class CompactRollout(NamedTuple):
    """One actor's rollout as shipped to the learner.

    Attributes:
        traj: the `Trajectory` recorded with `record="state"` (obs None; state [T, E] level-less states).
        start_level: [E] the levels the envs were playing when the rollout started.
        levels: [E, K] the level buffers the rollout's auto-resets drew from.
    """

    traj: Trajectory
    start_level: Any
    levels: Any


def expand(task: Task, env_params: Any, rollout: CompactRollout) -> Trajectory:
    """The full `Trajectory` (observations recomputed, `state` dropped); jittable."""
    traj = rollout.traj
    k = jax.tree.leaves(rollout.levels)[0].shape[1]
    start_episode = traj.state.episode[0]  # [E]

    def observe_env(states: Any, start: Any, buffer: Any, first_ep: jax.Array) -> jax.Array:  # [T] of one env
        def one(state: Any) -> jax.Array:
            later = jax.tree.map(lambda b: b[state.episode % k], buffer)
            level = jax.tree.map(lambda s, x: jnp.where(state.episode == first_ep, s, x), start, later)
            return task.observe(state, level, env_params)

        return jax.vmap(one)(states)

    obs = jax.vmap(observe_env, in_axes=(1, 0, 0, 0), out_axes=1)(
        traj.state, rollout.start_level, rollout.levels, start_episode
    )
    return traj._replace(obs=obs, state=None)


def to_bytes(tree: Any) -> bytes:
    """msgpack bytes of a pytree of arrays (NamedTuples and dataclasses become nested dicts)."""
    return serialization.msgpack_serialize(serialization.to_state_dict(jax.device_get(tree)))


def from_bytes(template: Any, data: bytes) -> Any:
    """The pytree of `template`'s structure from `to_bytes` output (host numpy leaves)."""
    return serialization.from_state_dict(template, serialization.msgpack_restore(data))


def nbytes(tree: Any) -> int:
    """Bytes of a pytree's array leaves."""
    return sum(np.asarray(x).nbytes for x in jax.tree.leaves(tree))
