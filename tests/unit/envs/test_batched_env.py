"""One compiled step serves every kitchen: jit/vmap over classic and mixed batches, auto-reset."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np

from cec.envs import overcooked as oc
from cec.levels import Level, stack_levels

PARAMS = oc.EnvParams(max_steps=20)


def test_jit_steps_every_classic_layout_and_a_mixed_batch_in_one_compiled_function() -> None:
    traces = 0

    def rollout(key: jax.Array, levels: Level) -> tuple[jax.Array, jax.Array]:
        nonlocal traces
        traces += 1
        keys = jax.random.split(key, levels.grid.shape[0])
        _, state = jax.vmap(oc.reset, in_axes=(0, 0, None))(keys, levels, PARAMS)

        def body(state: oc.EnvState, k: jax.Array) -> tuple[oc.EnvState, tuple[jax.Array, jax.Array]]:
            ks = jax.random.split(k, levels.grid.shape[0])
            actions = jax.random.randint(k, (levels.grid.shape[0], 2), 0, oc.NUM_ACTIONS)
            out = jax.vmap(oc.step, in_axes=(0, 0, 0, None))(ks, state, actions, PARAMS)
            return out.state, (out.obs.sum(dtype=jnp.int32), out.state.agent_pos)

        _, (obs_sums, positions) = jax.lax.scan(body, state, jax.random.split(key, 10))
        return obs_sums, positions

    fn = jax.jit(rollout)
    classic = list(oc.classic_levels().values())
    mixed = stack_levels([classic[i % 5] for i in range(5)][::-1])
    for levels in (stack_levels(classic), mixed):
        obs_sums, positions = fn(jax.random.PRNGKey(0), levels)
        assert obs_sums.shape == (10,) and positions.shape == (10, 5, 2, 2)
        # every agent stays on a floor cell of its own kitchen
        grids = np.asarray(levels.grid)
        for t in range(10):
            for e in range(5):
                for seat in range(2):
                    r, c = np.asarray(positions[t, e, seat])
                    assert grids[e, r, c] == 0
    assert traces == 1  # the same compiled function served both batches


def test_each_env_in_a_mixed_batch_matches_stepping_it_alone() -> None:
    levels = stack_levels(list(oc.classic_levels().values()))
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    _, batch_state = jax.vmap(oc.reset, in_axes=(0, 0, None))(keys, levels, PARAMS)
    actions = jax.random.randint(jax.random.PRNGKey(4), (5, 2), 0, oc.NUM_ACTIONS)
    out = jax.jit(jax.vmap(oc.step, in_axes=(0, 0, 0, None)))(keys, batch_state, actions, PARAMS)
    for e in range(5):
        _, single = oc.reset(keys[e], jax.tree.map(lambda x, e=e: x[e], levels), PARAMS)
        alone = oc.step(keys[e], single, actions[e], PARAMS)
        np.testing.assert_array_equal(np.asarray(out.obs[e]), np.asarray(alone.obs))
        np.testing.assert_array_equal(np.asarray(out.state.agent_pos[e]), np.asarray(alone.state.agent_pos))


def test_autoreset_takes_the_next_level_from_the_buffer() -> None:
    names = ["cramped_room", "coord_ring", "counter_circuit"]
    buffer = stack_levels([oc.classic_level(n) for n in names])
    params = oc.EnvParams(max_steps=3)
    _, state = oc.reset(jax.random.PRNGKey(0), oc.classic_level(names[0]), params)
    step = jax.jit(oc.step_autoreset)
    seen = []
    for t in range(10):
        out = step(
            jax.random.PRNGKey(t),
            state,
            jnp.asarray([oc.Action.INTERACT, oc.Action.RIGHT]),
            buffer,
            params,
        )
        state = out.state
        assert bool(out.done) == (t % 3 == 2)
        if out.done:
            assert int(state.time) == 0
            assert int(state.agent_inv.sum()) == 0 and int(state.items.sum()) == 0
            np.testing.assert_array_equal(np.asarray(out.obs), np.asarray(oc.get_obs(state, params)))
        seen.append(next(n for n in names if np.array_equal(state.level.grid, oc.classic_level(n).grid)))
    assert seen[:3] == ["cramped_room"] * 2 + ["coord_ring"]
    assert seen[5] == "counter_circuit" and seen[8] == "cramped_room"
    assert int(state.episode) == 3


def test_reset_accepts_levels_held_as_numpy_arrays() -> None:
    level = jax.device_get(oc.classic_level("coord_ring"))
    obs, state = oc.reset(jax.random.PRNGKey(0), level, PARAMS)
    out = oc.step(jax.random.PRNGKey(1), state, jnp.asarray([4, 5]), PARAMS)
    assert obs.shape == out.obs.shape == (2, 9, 9, 26)
