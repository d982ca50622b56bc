"""The one rollout function: scan over steps, vmapped envs, both seats batched through one network.

`rollout(params, carry, levels, key, ...)` is used by the single-process trainer, the Ray actors and the
evaluator (DESIGN.md rule 4). The carry holds everything that continues across rollouts (env states,
current observations, LSTM states, running episode returns), so consecutive rollouts continue episodes
seamlessly; `levels` is the per-env buffer of upcoming levels for auto-reset.

Shapes: E envs, T steps, 2 seats; seat-major flattening `env * 2 + seat` wherever the two are merged.
"""

from __future__ import annotations

from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cec.agents.network import ActorCritic, LSTMState, forward
from cec.training.tasks import Task

NUM_SEATS = 2


class RolloutCarry(NamedTuple):
    """What a rollout continues from (batched over E envs).

    Attributes:
        env_state: the envs' states.
        obs: [E, 2, ...] current observations.
        first: bool[E] the current observation is the first of an episode (the LSTM resets before it).
        lstm: `LSTMState` with [E, 2, H] leaves, the carry before the current observation.
        episode_return: float32[E] team (sparse) return of the running episodes so far.
        episode_shaped: float32[E] shaped return (both seats summed, unscaled) of the running episodes.
    """

    env_state: Any
    obs: jax.Array
    first: jax.Array
    lstm: LSTMState
    episode_return: jax.Array
    episode_shaped: jax.Array


class Trajectory(NamedTuple):
    """T steps of E envs. Per-step fields have leading axes [T, E] (and a seat axis where per seat).

    Attributes:
        obs: [T, E, 2, ...] the observations the actions were taken on.
        first: bool[T, E] `obs` is the first of an episode.
        action: int32[T, E, 2].
        log_prob: float32[T, E, 2] behaviour log-probability of `action`.
        value: float32[T, E, 2] critic value of `obs`.
        reward: float32[T, E] team sparse reward.
        shaped: float32[T, E, 2] per-seat shaped reward (unscaled).
        done: bool[T, E] the episode ended with this step.
        collision: bool[T, E].
        episode_return: float32[T, E] the finished episode's team return where `done`, else 0.
        episode_shaped: float32[T, E] the finished episode's shaped return where `done`, else 0.
        init_lstm: `LSTMState` [E, 2, H], the carry before the first step (for replay in the update).
        last_value: float32[E, 2] critic value of the observation after the last step (bootstrap).
    """

    obs: jax.Array
    first: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    shaped: jax.Array
    done: jax.Array
    collision: jax.Array
    episode_return: jax.Array
    episode_shaped: jax.Array
    init_lstm: LSTMState
    last_value: jax.Array


def _per_seat(x: jax.Array) -> jax.Array:
    """[E] -> [E * 2] (the same flag for both seats of an env)."""
    return jnp.repeat(x, NUM_SEATS, axis=0)


def policy_step(
    network: ActorCritic, params: Any, lstm: LSTMState, obs: jax.Array, first: jax.Array
) -> tuple[LSTMState, jax.Array, jax.Array]:
    """One step of the shared policy for every seat of every env.

    Args:
        lstm: [E, 2, H] carries; obs: [E, 2, ...]; first: bool[E].

    Returns:
        (next lstm [E, 2, H], logits float32[E, 2, A], value float32[E, 2]).
    """
    e = obs.shape[0]
    flat = jax.tree.map(lambda x: x.reshape((e * NUM_SEATS, -1)), lstm)
    flat, logits, value = forward(
        network, params, flat, obs.reshape((1, e * NUM_SEATS, *obs.shape[2:])), _per_seat(first)[None]
    )
    lstm = jax.tree.map(lambda x: x.reshape((e, NUM_SEATS, -1)), flat)
    return lstm, logits[0].reshape((e, NUM_SEATS, -1)), value[0].reshape((e, NUM_SEATS))


def init_carry(
    task: Task, network: ActorCritic, env_params: Any, levels: Any, key: jax.Array
) -> RolloutCarry:
    """Starts E envs, one on each `levels[:, 0]` (a buffer with leading axes [E, K])."""
    first_levels = jax.tree.map(lambda x: x[:, 0], levels)
    e = jax.tree.leaves(first_levels)[0].shape[0]
    obs, state = jax.vmap(task.reset, in_axes=(0, 0, None))(
        jax.random.split(key, e), first_levels, env_params
    )
    zeros = jnp.zeros(e, jnp.float32)
    return RolloutCarry(state, obs, jnp.ones(e, bool), network.initial_carry((e, NUM_SEATS)), zeros, zeros)


def rollout(
    params: Any,
    carry: RolloutCarry,
    levels: Any,
    key: jax.Array,
    *,
    task: Task,
    network: ActorCritic,
    env_params: Any,
    num_steps: int,
) -> tuple[RolloutCarry, Trajectory]:
    """Plays `num_steps` steps of E envs in self-play (both seats act with `params`).

    Args:
        params: network parameters (shared by both seats).
        carry: the `RolloutCarry` to continue from (E envs).
        levels: per-env level buffers, leading axes [E, K]; a finished episode continues on
            `levels[e, (episode + 1) % K]`.
        key: PRNG key for action sampling and the envs.
        task, network, num_steps: static; env_params: the game's settings (traced).

    Returns:
        (carry after the last step, `Trajectory` with T = num_steps).
    """
    e = carry.obs.shape[0]

    def body(c: RolloutCarry, step_key: jax.Array) -> tuple[RolloutCarry, dict[str, jax.Array]]:
        k_act, k_env = jax.random.split(step_key)
        lstm, logits, value = policy_step(network, params, c.lstm, c.obs, c.first)
        action = jax.random.categorical(k_act, logits).astype(jnp.int32)  # [E, 2]
        log_prob = jnp.take_along_axis(jax.nn.log_softmax(logits), action[..., None], axis=-1)[..., 0]
        out = jax.vmap(task.step, in_axes=(0, 0, 0, 0, None))(
            jax.random.split(k_env, e), c.env_state, action, levels, env_params
        )
        ep_return = c.episode_return + out.reward
        ep_shaped = c.episode_shaped + out.shaped.sum(-1)
        record = dict(
            obs=c.obs,
            first=c.first,
            action=action,
            log_prob=log_prob,
            value=value,
            reward=out.reward,
            shaped=out.shaped,
            done=out.done,
            collision=out.collision,
            episode_return=jnp.where(out.done, ep_return, 0.0),
            episode_shaped=jnp.where(out.done, ep_shaped, 0.0),
        )
        zero = jnp.zeros_like(ep_return)
        nxt = RolloutCarry(
            out.state,
            out.obs,
            out.done,
            lstm,
            jnp.where(out.done, zero, ep_return),
            jnp.where(out.done, zero, ep_shaped),
        )
        return nxt, record

    final, steps = jax.lax.scan(body, carry, jax.random.split(key, num_steps))
    _, _, last_value = policy_step(network, params, final.lstm, final.obs, final.first)
    return final, Trajectory(**steps, init_lstm=carry.lstm, last_value=last_value)
