"""One game interface (`cec.envs.base.Game`), one auto-reset (`base.step_autoreset`), one registry."""

from __future__ import annotations

from typing import Any

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.config import ConfigError
from cec.envs import base, registry
from cec.envs import dual_destination as dd
from cec.envs import overcooked as oc
from cec.envs.task import ENV_NAMES, EnvConfig, Task

MAX_STEPS = 3  # an episode ends every 3 steps: 10 steps cross 3 dones and wrap a buffer of K = 3 levels
STEPS = 10


def _three_levels(game: base.Game) -> tuple[list[Any], Any]:
    if game is oc.GAME:
        levels = [oc.classic_level(n) for n in ("cramped_room", "coord_ring", "forced_coord")]
    else:
        levels = [dd.fixed_level(), dd.multi_task_level(), dd.heldout_generated_dd_levels()[0][1]]
    return levels, game.stack_levels(levels)


def _params(game: base.Game) -> Any:
    if game is oc.GAME:  # random start facings: the new episode's first state uses the step's key
        return oc.EnvParams(max_steps=MAX_STEPS, random_start_facing=True)
    return dd.DDParams(max_steps=MAX_STEPS)


def _leaves_equal(a: Any, b: Any) -> None:
    la, lb = jax.tree.leaves(a), jax.tree.leaves(b)
    assert len(la) == len(lb) and jax.tree.structure(a) == jax.tree.structure(b)
    for x, y in zip(la, lb, strict=True):
        assert np.asarray(x).dtype == np.asarray(y).dtype
        np.testing.assert_array_equal(np.asarray(x), np.asarray(y))


@pytest.mark.parametrize("game", registry.GAMES.values(), ids=list(registry.GAMES))
def test_every_game_offers_the_protocol(game: base.Game) -> None:
    assert isinstance(game, base.Game) and registry.game(game.name) is game
    levels, _ = _three_levels(game)
    params = _params(game)
    obs, state = game.reset(jax.random.PRNGKey(0), levels[0], params)
    assert obs.shape == (2, *game.obs_shape)
    _leaves_equal(game.get_obs(state, params), obs)
    _leaves_equal(game.initial_state(jax.random.PRNGKey(0), levels[0], params), state)
    out = game.step(jax.random.PRNGKey(1), state, jnp.asarray([0, game.num_actions - 1]), params)
    assert isinstance(out, base.EnvStep)
    assert out.obs.shape == obs.shape and out.obs.dtype == obs.dtype
    assert out.reward.shape == () and out.reward.dtype == jnp.float32
    assert out.shaped.shape == (2,) and out.shaped.dtype == jnp.float32
    assert out.done.shape == () and out.done.dtype == bool
    assert out.collision.shape == () and out.collision.dtype == bool
    assert game.default_levels in game.level_specs
    assert set(game.procedural_levels) <= set(game.level_specs)
    assert set(game.fixed_levels) == set(game.level_specs) - set(game.procedural_levels)
    named = game.named_levels(game.fixed_levels[0] if game is dd.GAME else "cramped_room")
    assert len(named) == 1
    EnvConfig(name=game.name, levels=game.default_levels)  # the default spec is a valid training config
    with pytest.raises(ValueError, match="actions must lie in"):
        game.step(jax.random.PRNGKey(1), state, jnp.asarray([0, game.num_actions]), params)


def test_the_games_differ_where_their_callers_branched() -> None:
    assert (oc.GAME.num_actions, oc.GAME.obs_shape) == (oc.NUM_ACTIONS, (9, 9, oc.NUM_CHANNELS))
    assert (dd.GAME.num_actions, dd.GAME.obs_shape) == (
        dd.NUM_ACTIONS,
        (dd.DD_SIZE, dd.DD_SIZE, dd.NUM_CHANNELS),
    )
    assert (oc.GAME.default_levels, dd.GAME.default_levels) == ("generator", "fixed")
    assert oc.GAME.fixed_levels == tuple(oc.CLASSIC_ASCII) and dd.GAME.fixed_levels == ("fixed", "multi_task")
    assert oc.GAME.level_files and not dd.GAME.level_files
    assert oc.GAME.egocentric and not dd.GAME.egocentric
    assert dd.GAME.normalised_score and not oc.GAME.normalised_score
    assert oc.GAME.single_task_own_level and not dd.GAME.single_task_own_level
    assert oc.GAME.obs_settings(oc.EnvParams()) == ()
    assert dd.GAME.obs_settings(dd.DDParams(partial_obs=True)) == (True, False)
    returns = np.asarray([0.0, 40.0])
    np.testing.assert_array_equal(oc.GAME.deliveries(returns, 400, oc.EnvParams()), [0.0, 2.0])
    np.testing.assert_array_equal(
        dd.GAME.deliveries(np.asarray([-100.0, -76.0]), 100, dd.DDParams()), [0.0, 8.0]
    )
    with pytest.raises(ConfigError, match="needs env.dual_destination.multi_task=true"):
        EnvConfig(name="dual_destination", levels="multi_task")


def _level(buffer: Any, i: int) -> Any:
    return jax.tree.map(lambda x: x[i], buffer)


def _hand_written(
    game: base.Game, key: jax.Array, state: Any, actions: jax.Array, buffer: Any, params: Any
) -> Any:
    """A step and, on done, a reset onto the next level of the buffer, written out by hand."""
    if game is oc.GAME:
        o = oc.step(key, state, actions, params)
        obs, nxt, reward, shaped, done, collision = (
            o.obs,
            o.state,
            o.reward,
            o.shaped_reward,
            o.done,
            o.collision,
        )
    else:
        o = dd.step(key, state, actions, params)
        obs, nxt, reward, done = o.obs, o.state, o.reward, o.done
        shaped, collision = jnp.zeros(2, jnp.float32), jnp.zeros((), bool)
    if bool(done):
        episode = int(state.episode) + 1
        obs, nxt = (oc.reset if game is oc.GAME else dd.reset)(key, _level(buffer, episode % 3), params)
        nxt = nxt.replace(episode=jnp.asarray(episode, jnp.int32))
    return base.EnvStep(obs, nxt, reward, shaped, done, collision)


@pytest.mark.parametrize("game", registry.GAMES.values(), ids=list(registry.GAMES))
def test_the_one_auto_reset_is_a_step_and_a_reset_onto_the_next_level(game: base.Game) -> None:
    levels, buffer = _three_levels(game)
    params = _params(game)
    _, state = game.reset(jax.random.PRNGKey(7), levels[0], params)
    own = oc.step_autoreset if game is oc.GAME else dd.step_autoreset  # each game's public name
    jitted = jax.jit(base.step_autoreset, static_argnums=0)
    task = Task(game.name, game.default_levels, EnvConfig().generator)
    expected, ref = state, state
    episodes = []
    for t, key in enumerate(jax.random.split(jax.random.PRNGKey(8), STEPS)):
        actions = jax.random.randint(jax.random.fold_in(key, 1), (2,), 0, game.num_actions)
        ref_out = _hand_written(game, key, ref, actions, buffer, params)
        out = base.step_autoreset(game, key, expected, actions, buffer, params)
        _leaves_equal(out, ref_out)
        _leaves_equal(jitted(game, key, expected, actions, buffer, params), ref_out)
        _leaves_equal(
            tuple(own(key, expected, actions, buffer, params)),
            tuple(ref_out) if game is oc.GAME else (ref_out.obs, ref_out.state, ref_out.reward, ref_out.done),
        )
        _leaves_equal(task.step(key, expected, actions, buffer, params), ref_out)
        assert bool(out.done) == ((t + 1) % MAX_STEPS == 0)
        if bool(out.done):
            episode = int(out.state.episode)
            episodes.append(episode)
            _leaves_equal(out.state.level, _level(buffer, episode % 3))
            for name, x in vars(levels[episode % 3]).items():  # the very level given, in the buffer's dtypes
                np.testing.assert_array_equal(np.asarray(getattr(out.state.level, name)), np.asarray(x))
        expected, ref = out.state, ref_out.state
    assert episodes == [1, 2, 3]  # levels[1], levels[2], then back to levels[0]
    assert int(expected.episode) == 3


def test_a_buffer_of_one_level_restarts_on_it() -> None:
    params = oc.EnvParams(max_steps=1)
    level = oc.classic_level("cramped_room")
    _, state = oc.reset(jax.random.PRNGKey(0), level, params)
    out = base.step_autoreset(
        oc.GAME, jax.random.PRNGKey(1), state, jnp.asarray([4, 4]), oc.GAME.stack_levels([level]), params
    )
    assert bool(out.done) and int(out.state.episode) == 1 and int(out.state.time) == 0
    _leaves_equal(out.state.level, jax.tree.map(jnp.asarray, level))


def test_the_registry_names_the_known_games() -> None:
    assert tuple(registry.GAMES) == ENV_NAMES == ("overcooked", "dual_destination")
    assert registry.game("dual_destination") is dd.GAME
    with pytest.raises(
        ConfigError, match=r"unknown game 'hanabi'; choose one of \['overcooked', 'dual_destination'\]"
    ):
        registry.game("hanabi")
    with pytest.raises(TypeError):
        registry.GAMES["hanabi"] = oc.GAME  # type: ignore[index]
