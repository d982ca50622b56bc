"""Random start items and part-filled pots (training levers, not the paper's): episodes may begin with onions
on the counters, items in the seats' hands and one or two onions in a pot; off by default, and evaluation
always starts from the empty kitchen."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np
import pytest

from cec.agents.policy import Policy, random_policy
from cec.config import ConfigError
from cec.envs import overcooked as oc
from cec.envs.overcooked.dynamics import reset
from cec.envs.overcooked.game import step_autoreset
from cec.envs.overcooked.state import POT_EMPTY, EnvParams
from cec.envs.task import EnvConfig
from cec.evaluation.crossplay import EvalConfig, crossplay, episode_states, eval_levels
from cec.levels import Item, Tile, stack_levels
from cec.levels.classic import classic_level

FC = classic_level("forced_coord")


def _beside_floor(grid: np.ndarray) -> np.ndarray:
    floor = np.pad(grid == Tile.FLOOR, 1)
    return floor[:-2, 1:-1] | floor[2:, 1:-1] | floor[1:-1, :-2] | floor[1:-1, 2:]


def test_with_probability_one_every_reachable_counter_holds_an_onion_and_every_hand_an_item() -> None:
    _, state = reset(jax.random.PRNGKey(0), FC, EnvParams(random_start_items=1.0))
    grid, items = np.asarray(FC.grid), np.asarray(state.items)
    reachable = (grid == Tile.COUNTER) & _beside_floor(grid)
    assert (items[reachable] == Item.ONION).all()
    assert (items[~reachable] == Item.NONE).all()  # nothing on piles, pots, the window or walled-in counters
    assert set(np.asarray(state.agent_inv).tolist()) <= {Item.ONION, Item.PLATE}
    # no free soup: the pots start empty
    assert (np.asarray(state.pot)[grid == Tile.POT] == POT_EMPTY).all()


def test_off_by_default_and_the_rest_of_the_start_is_unchanged() -> None:
    key = jax.random.PRNGKey(7)
    _, plain = reset(key, FC, EnvParams())
    assert not np.asarray(plain.items).any() and not np.asarray(plain.agent_inv).any()
    _, lever = reset(key, FC, EnvParams(random_start_items=0.3))
    np.testing.assert_array_equal(plain.agent_dir, lever.agent_dir)  # the same facings from the same key
    np.testing.assert_array_equal(plain.agent_pos, lever.agent_pos)


def test_each_counter_is_filled_with_the_given_probability_and_every_new_episode_draws_again() -> None:
    params = EnvParams(random_start_items=0.25, max_steps=1)
    keys = jax.random.split(jax.random.PRNGKey(1), 400)
    _, states = jax.vmap(reset, in_axes=(0, None, None))(keys, FC, params)
    grid = np.asarray(FC.grid)
    reachable = (grid == Tile.COUNTER) & _beside_floor(grid)
    share = (np.asarray(states.items)[:, reachable] != Item.NONE).mean()
    assert 0.22 < share < 0.28, share  # 400 x 9 counters: a standard error of 0.007
    # the auto-reset starts the next episode from a fresh draw as well
    _, state = reset(keys[0], FC, params)
    nxt = step_autoreset(keys[1], state, np.asarray([4, 4], np.int32), stack_levels([FC]), params).state
    assert int(nxt.time) == 0 and int(nxt.episode) == 1
    assert not np.array_equal(np.asarray(nxt.items), np.asarray(state.items))


def test_a_policy_trained_with_random_starts_is_evaluated_from_the_empty_kitchen() -> None:
    plain_env = EnvConfig(name="overcooked", levels="generator", overcooked=oc.EnvParams(max_steps=32))
    lever_env = dataclasses.replace(plain_env, overcooked=oc.EnvParams(max_steps=32, random_start_items=1.0))
    p = random_policy("p", jax.random.PRNGKey(0), env=plain_env)
    with_lever = Policy(p.name, p.algorithm, p.seed, p.params, p.network, lever_env, p.levels)
    states, _ = episode_states(with_lever, with_lever, FC, "forced_coord")
    assert not np.asarray(states.items[0]).any() and not np.asarray(states.agent_inv[0]).any()
    levels = eval_levels("overcooked", "forced_coord,cramped_room")
    config = EvalConfig(episodes=4)
    a, b = crossplay([p], levels, config), crossplay([with_lever], levels, config)
    np.testing.assert_array_equal(a.returns, b.returns)
    np.testing.assert_array_equal(a.shaped_return, b.shaped_return)


def test_part_filled_pots_hold_one_or_two_onions_never_a_soup_and_leave_the_other_draws_alone() -> None:
    keys = jax.random.split(jax.random.PRNGKey(3), 400)
    both = EnvParams(random_start_items=0.3, random_start_pot_onions=0.5)
    _, states = jax.vmap(reset, in_axes=(0, None, None))(keys, FC, both)
    pots = np.asarray(states.pot)[:, np.asarray(FC.grid) == Tile.POT]  # 400 episodes x 2 pots
    assert set(np.unique(pots).tolist()) == {POT_EMPTY, POT_EMPTY - 1, POT_EMPTY - 2}  # 0, 1 or 2 onions
    assert 0.45 < (pots != POT_EMPTY).mean() < 0.55  # 800 pots: a standard error of 0.018
    assert 0.4 < (pots == POT_EMPTY - 2).sum() / (pots != POT_EMPTY).sum() < 0.6  # one or two, equally
    _, items_only = jax.vmap(reset, in_axes=(0, None, None))(keys, FC, EnvParams(random_start_items=0.3))
    np.testing.assert_array_equal(states.items, items_only.items)  # the same onions on the counters
    np.testing.assert_array_equal(states.agent_inv, items_only.agent_inv)
    assert EnvParams(random_start_pot_onions=0.5).without_training_levers() == EnvParams()
    _, state = reset(jax.random.PRNGKey(0), FC, EnvParams(random_start_pot_onions=1.0))  # every pot
    assert (np.asarray(state.pot)[np.asarray(FC.grid) == Tile.POT] < POT_EMPTY).all()


@pytest.mark.parametrize("name", ["random_start_items", "random_start_pot_onions"])
def test_a_probability_outside_0_1_is_refused_before_any_work(name: str) -> None:
    with pytest.raises(ConfigError, match=name):
        EnvConfig(overcooked=EnvParams(**{name: 1.5}))
