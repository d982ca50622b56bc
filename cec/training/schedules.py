"""Schedules of training on env steps: a value falling linearly to 0 over a horizon, traced inside the
compiled update (the shaped reward's weight, the scripted partner's share, the teacher's weight). The
learning rate's schedule is optax's, of the gradient-step count (`cec.training.ppo.make_optimizer`)."""

from __future__ import annotations

import jax
import jax.numpy as jnp


def anneal_to_zero(start: float, env_steps: jax.Array, horizon: int) -> jax.Array:
    """`start` falling linearly to 0 over `horizon` env steps, then 0, after `env_steps` (traced); `horizon`
    <= 0: `start` throughout."""
    value = jnp.float32(start)
    if horizon <= 0:
        return value
    done = jnp.asarray(env_steps, jnp.float32) / float(horizon)
    return value * jnp.clip(1.0 - done, 0.0, 1.0)
