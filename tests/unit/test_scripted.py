"""The scripted cook really cooks: it delivers soups in every classic kitchen, handing over where needed."""

from __future__ import annotations

import jax
import pytest

from cec.envs import overcooked as oc
from cec.envs.overcooked.scripted import scripted_actions

PARAMS = oc.EnvParams(max_steps=200)


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_scripted_cook_delivers_in_every_classic_kitchen(name: str) -> None:
    level = oc.classic_level(name)

    @jax.jit
    def episode(key: jax.Array) -> jax.Array:
        _, state = oc.reset(key, level, PARAMS)

        def body(state: oc.EnvState, k: jax.Array) -> tuple[oc.EnvState, jax.Array]:
            out = oc.step(k, state, scripted_actions(k, state, 0.05), PARAMS)
            return out.state, out.reward

        return jax.lax.scan(body, state, jax.random.split(key, PARAMS.max_steps))[1].sum()

    returns = jax.vmap(episode)(jax.random.split(jax.random.PRNGKey(0), 8))
    assert float(returns.mean()) >= 20.0  # at least one soup per 200 steps on average
