"""The scripted cook really cooks: it delivers soups in every classic kitchen, handing over where needed,
with a copy of itself and no random actions (two cooks yield instead of blocking each other), and it plays
as well from what one seat observes as from the env state."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.agents.policy import scripted_policy
from cec.envs import overcooked as oc
from cec.envs.overcooked.scripted import _seat_action, scripted_actions, state_from_obs
from cec.envs.task import EnvConfig
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from cec.levels.heldout import heldout_levels

PARAMS = oc.EnvParams(max_steps=400)


def _returns(level: oc.Level, epsilon: float, episodes: int = 4, yields: bool = True) -> jax.Array:
    @jax.jit
    def episode(key: jax.Array) -> jax.Array:
        _, state = oc.reset(key, level, PARAMS)

        def body(state: oc.EnvState, k: jax.Array) -> tuple[oc.EnvState, jax.Array]:
            out = oc.step(k, state, scripted_actions(k, state, epsilon, yields), PARAMS)
            return out.state, out.reward

        return jax.lax.scan(body, state, jax.random.split(key, PARAMS.max_steps))[1].sum()

    return jax.vmap(episode)(jax.random.split(jax.random.PRNGKey(0), episodes))


@pytest.mark.parametrize("name", sorted(oc.CLASSIC_ASCII))
def test_two_greedy_cooks_deliver_in_every_classic_kitchen(name: str) -> None:
    # Before the cooks yielded to each other, two greedy cooks delivered nothing in Cramped Room,
    # Coordination Ring and Counter Circuit (they blocked each other trying to swap cells).
    returns = _returns(oc.classic_level(name), epsilon=0.0)
    assert float(returns.min()) >= 8 * 20.0  # at least 8 soups in every 400-step episode


@pytest.mark.parametrize("name", ["coord_ring", "counter_circuit", "cramped_room"])
def test_cooks_that_never_yield_block_each_other_where_yielding_cooks_deliver(name: str) -> None:
    # The partner that never gives way (`yields=False`, a training partner): two of them walk into each
    # other in the one-cell passages of these kitchens unless a random start spares them (measured, in
    # this order: 100, 40, 60 per 400 steps against 280, 200, 240).
    level = oc.classic_level(name)
    stubborn = _returns(level, epsilon=0.0, yields=False)
    assert float(stubborn.mean()) < float(_returns(level, epsilon=0.0).mean()) / 2


def test_the_cook_reads_the_whole_state_from_one_seats_observation() -> None:
    @jax.jit
    def check(key: jax.Array, level: oc.Level) -> jax.Array:
        obs, state = oc.reset(key, level, PARAMS)

        def body(carry: tuple, k: jax.Array) -> tuple[tuple, jax.Array]:
            obs, state = carry
            oks = []
            for seat in (0, 1):
                seen = state_from_obs(obs[seat])
                order = jnp.array([seat, 1 - seat])  # the observing seat is seat 0 of what it sees
                oks += [
                    jnp.all(seen.level.grid == state.level.grid),
                    jnp.all(seen.items == state.items),
                    jnp.all(seen.pot == state.pot),
                    jnp.all(seen.agent_pos == state.agent_pos[order]),
                    jnp.all(seen.agent_dir == state.agent_dir[order]),
                    jnp.all(seen.agent_inv == state.agent_inv[order]),
                    _seat_action(seen, 0) == _seat_action(state, seat),
                ]
            out = oc.step(k, state, scripted_actions(k, state, 0.2), PARAMS)
            return (out.obs, out.state), jnp.stack(oks)

        return jax.lax.scan(body, (obs, state), jax.random.split(key, 150))[1]

    levels = dict(heldout_levels())
    for name in ("forced_coord", "counter_circuit", "generated_000", "generated_017", "generated_042"):
        oks = np.asarray(check(jax.random.PRNGKey(1), levels[name]))
        assert oks.all(), f"{name}: first mismatch at step {np.argwhere(~oks)[0]}"


def test_the_cook_is_a_zoo_partner_that_delivers_in_cross_play() -> None:
    env = EnvConfig(name="overcooked", levels="generator", overcooked=PARAMS)
    cook = scripted_policy("cook", env=env)
    table = crossplay([cook], eval_levels("overcooked", "classic"), EvalConfig(episodes=1, max_steps=400))
    assert len(table) == 5 and set(table.level) == set(oc.CLASSIC_ASCII)
    assert table.returns.min() >= 5 * 20.0, dict(zip(table.level, table.returns, strict=True))


def test_an_episode_for_a_gif_is_crossplays_episode_and_renders() -> None:
    """`episode_states` (`cec render --partners`) replays exactly the episode `crossplay` scores."""
    from cec.envs.overcooked.render import rollout_frames
    from cec.evaluation.crossplay import episode_states

    env = EnvConfig(name="overcooked", levels="generator", overcooked=PARAMS)
    cook = scripted_policy("cook", env=env)
    table = crossplay([cook], eval_levels("overcooked", "coord_ring"), EvalConfig(episodes=1, max_steps=120))
    states, team_return = episode_states(
        cook, cook, oc.classic_level("coord_ring"), "coord_ring", max_steps=120
    )
    assert team_return == table.returns[0] > 0
    assert np.shape(states.agent_pos) == (120, 2, 2)
    frames = rollout_frames(jax.tree.map(lambda x: x[:3], states), tile_size=8)
    assert len(frames) == 3 and frames[0].shape[2] == 3
