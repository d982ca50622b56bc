"""Hand-computed cases for every movement and interact rule of the Overcooked dynamics."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.envs import overcooked as oc
from cec.envs.overcooked import Action as A
from cec.levels import Direction as D
from cec.levels import Item, from_ascii

# Row 0: onion pile (0,1), plate pile (0,2), pot (0,3); goal (1,4); counters elsewhere.
KITCHEN = """
WOBPW
W0 1X
W   W
WWWWW
"""
PARAMS = oc.EnvParams(max_steps=400, random_start_facing=False)
KEY = jax.random.PRNGKey(0)


def make_state(
    *,
    pos: tuple[tuple[int, int], tuple[int, int]] = ((1, 1), (1, 3)),
    facing: tuple[int, int] = (D.NORTH, D.NORTH),
    inv: tuple[int, int] = (Item.NONE, Item.NONE),
    items: dict[tuple[int, int], int] | None = None,
    pot: int = oc.POT_EMPTY,
    kitchen: str = KITCHEN,
) -> oc.EnvState:
    level = from_ascii(kitchen)
    level = level.replace(agent_pos=jnp.asarray(pos, jnp.int32), agent_dir=jnp.asarray(facing, jnp.int32))
    _, state = oc.reset(KEY, level, PARAMS)
    grid_items = np.zeros((9, 9), np.uint8)
    for (r, c), it in (items or {}).items():
        grid_items[r, c] = it
    pots = np.where(np.asarray(level.grid) == 4, pot, 0).astype(np.uint8)
    return state.replace(
        agent_inv=jnp.asarray(inv, jnp.int32), items=jnp.asarray(grid_items), pot=jnp.asarray(pots)
    )


def act(state: oc.EnvState, a0: int, a1: int = A.STAY) -> oc.StepOutput:
    return oc.step(KEY, state, jnp.asarray([a0, a1], jnp.int32), PARAMS)


def pos_of(out: oc.StepOutput) -> list[tuple[int, int]]:
    return [tuple(p) for p in np.asarray(out.state.agent_pos).tolist()]


# --- movement -----------------------------------------------------------------------------------


def test_action_names_match_movement() -> None:
    s = make_state(pos=((2, 2), (1, 3)))
    assert pos_of(act(s, A.UP))[0] == (1, 2)
    assert pos_of(act(s, A.DOWN))[0] == (2, 2)  # counter below: blocked
    assert pos_of(act(s, A.LEFT))[0] == (2, 1)
    assert pos_of(act(s, A.RIGHT))[0] == (2, 3)


def test_blocked_move_turns_without_moving() -> None:
    out = act(make_state(facing=(D.SOUTH, D.NORTH)), A.LEFT)  # counter at (1,0)
    assert pos_of(out)[0] == (1, 1)
    assert int(out.state.agent_dir[0]) == D.WEST


def test_goal_blocks_movement() -> None:
    out = act(make_state(), A.STAY, A.RIGHT)  # goal at (1,4)
    assert pos_of(out)[1] == (1, 3)
    assert int(out.state.agent_dir[1]) == D.EAST


def test_stay_and_interact_keep_facing() -> None:
    s = make_state(facing=(D.SOUTH, D.WEST))
    out = act(s, A.STAY, A.INTERACT)
    assert np.asarray(out.state.agent_dir).tolist() == [D.SOUTH, D.WEST]


def test_both_into_same_cell_neither_moves() -> None:
    out = act(make_state(), A.RIGHT, A.LEFT)  # both want (1,2)
    assert pos_of(out) == [(1, 1), (1, 3)]
    assert bool(out.collision)
    assert np.asarray(out.state.agent_dir).tolist() == [D.EAST, D.WEST]


def test_moving_into_a_standing_partner_is_blocked() -> None:
    out = act(make_state(pos=((1, 1), (1, 2))), A.RIGHT, A.STAY)
    assert pos_of(out) == [(1, 1), (1, 2)]
    assert bool(out.collision)


def test_swapping_is_blocked() -> None:
    out = act(make_state(pos=((1, 1), (1, 2))), A.RIGHT, A.LEFT)
    assert pos_of(out) == [(1, 1), (1, 2)]
    assert bool(out.collision)


def test_following_into_a_vacated_cell_is_allowed() -> None:
    out = act(make_state(pos=((1, 1), (1, 2))), A.RIGHT, A.DOWN)
    assert pos_of(out) == [(1, 2), (2, 2)]
    assert not bool(out.collision)


# --- piles, counters ----------------------------------------------------------------------------


def test_pick_onion_from_pile() -> None:
    out = act(make_state(), A.INTERACT)
    assert int(out.state.agent_inv[0]) == Item.ONION
    assert float(out.shaped_reward[0]) == 0.0


def test_pile_gives_nothing_to_a_full_hand() -> None:
    out = act(make_state(inv=(Item.PLATE, Item.NONE)), A.INTERACT)
    assert int(out.state.agent_inv[0]) == Item.PLATE


def test_drop_on_bare_counter_and_pick_up_again() -> None:
    s = make_state(facing=(D.WEST, D.NORTH), inv=(Item.DISH, Item.NONE))
    out = act(s, A.INTERACT)
    assert int(out.state.agent_inv[0]) == Item.NONE
    assert int(out.state.items[1, 0]) == Item.DISH
    back = act(out.state, A.INTERACT)
    assert int(back.state.agent_inv[0]) == Item.DISH
    assert int(back.state.items[1, 0]) == Item.NONE


def test_cannot_drop_on_occupied_counter_pile_pot_or_goal() -> None:
    s = make_state(facing=(D.WEST, D.EAST), inv=(Item.ONION, Item.PLATE), items={(1, 0): Item.PLATE})
    out = act(s, A.INTERACT, A.INTERACT)  # seat 0 at occupied counter, seat 1 at goal
    assert np.asarray(out.state.agent_inv).tolist() == [Item.ONION, Item.PLATE]
    assert int(out.state.items[1, 0]) == Item.PLATE
    assert int(out.state.items[1, 4]) == Item.NONE
    on_pile = act(make_state(inv=(Item.PLATE, Item.NONE)), A.INTERACT)
    assert int(on_pile.state.items[0, 1]) == Item.NONE


def test_interact_facing_floor_or_partner_does_nothing() -> None:
    s = make_state(pos=((1, 1), (1, 2)), facing=(D.EAST, D.SOUTH), inv=(Item.ONION, Item.ONION))
    out = act(s, A.INTERACT, A.INTERACT)
    assert np.asarray(out.state.agent_inv).tolist() == [Item.ONION, Item.ONION]
    assert not np.asarray(out.state.items).any()


def test_seat_zero_resolves_first_on_the_same_counter() -> None:
    # Both face the shared counter (1,2): seat 0 takes the onion, then seat 1 drops its plate there.
    kitchen = """
WWOWW
W0W1W
W WPW
WBWXW
WWWWW
"""
    s = make_state(
        kitchen=kitchen,
        pos=((1, 1), (1, 3)),
        facing=(D.EAST, D.WEST),
        inv=(Item.NONE, Item.PLATE),
        items={(1, 2): Item.ONION},
    )
    out = act(s, A.INTERACT, A.INTERACT)
    assert np.asarray(out.state.agent_inv).tolist() == [Item.ONION, Item.NONE]
    assert int(out.state.items[1, 2]) == Item.PLATE  # seat 1 dropped on the counter seat 0 emptied


# --- pots, soups, delivery -----------------------------------------------------------------------


def test_three_onions_start_cooking_and_fourth_is_refused() -> None:
    s = make_state(inv=(Item.NONE, Item.ONION))
    statuses = []
    for _ in range(3):
        out = act(s, A.STAY, A.INTERACT)
        assert float(out.shaped_reward[1]) == PARAMS.onion_in_pot_reward
        assert int(out.state.agent_inv[1]) == Item.NONE
        statuses.append(int(out.state.pot[0, 3]))
        s = out.state.replace(agent_inv=jnp.asarray([Item.NONE, Item.ONION], jnp.int32))
    assert statuses == [
        22,
        21,
        19,
    ]  # the third onion fills the pot (20) and it cooks on the same step
    out = act(s, A.STAY, A.INTERACT)
    assert int(out.state.agent_inv[1]) == Item.ONION
    assert float(out.shaped_reward[1]) == 0.0


def test_soup_is_ready_19_steps_after_the_third_onion() -> None:
    s = make_state(inv=(Item.NONE, Item.ONION), pot=21)
    out = act(s, A.STAY, A.INTERACT)  # step 1: third onion
    s = out.state
    for _ in range(18):
        s = act(s, A.STAY).state
    assert int(s.pot[0, 3]) == 1
    s = act(s, A.STAY).state
    assert int(s.pot[0, 3]) == oc.POT_READY
    assert int(act(s, A.STAY).state.pot[0, 3]) == oc.POT_READY  # stays ready


def test_plate_a_ready_soup() -> None:
    out = act(make_state(inv=(Item.NONE, Item.PLATE), pot=oc.POT_READY), A.STAY, A.INTERACT)
    assert int(out.state.agent_inv[1]) == Item.DISH
    assert int(out.state.pot[0, 3]) == oc.POT_EMPTY
    assert float(out.shaped_reward[1]) == PARAMS.soup_pickup_reward


def test_plate_at_a_cooking_pot_does_nothing() -> None:
    out = act(make_state(inv=(Item.NONE, Item.PLATE), pot=10), A.STAY, A.INTERACT)
    assert int(out.state.agent_inv[1]) == Item.PLATE
    assert int(out.state.pot[0, 3]) == 9  # only the countdown moved


def test_deliver_a_dish_pays_the_team() -> None:
    s = make_state(facing=(D.NORTH, D.EAST), inv=(Item.NONE, Item.DISH))
    out = act(s, A.STAY, A.INTERACT)
    assert float(out.reward) == PARAMS.delivery_reward
    assert int(out.state.agent_inv[1]) == Item.NONE
    assert np.asarray(out.shaped_reward).tolist() == [0.0, 0.0]


def test_goal_refuses_onions_and_plates() -> None:
    for held in (Item.ONION, Item.PLATE):
        out = act(make_state(facing=(D.NORTH, D.EAST), inv=(Item.NONE, held)), A.STAY, A.INTERACT)
        assert float(out.reward) == 0.0
        assert int(out.state.agent_inv[1]) == held


def test_plate_pickup_bonus_fires_only_when_useful() -> None:
    plate = make_state(pos=((1, 2), (1, 3)))  # seat 0 faces the plate pile
    assert float(act(plate, A.INTERACT).shaped_reward[0]) == 0.0  # all pots empty: not useful
    cooking = plate.replace(pot=plate.pot.at[0, 3].set(15))
    assert float(act(cooking, A.INTERACT).shaped_reward[0]) == PARAMS.plate_pickup_reward
    loose = cooking.replace(items=cooking.items.at[1, 0].set(Item.PLATE))
    assert float(act(loose, A.INTERACT).shaped_reward[0]) == 0.0  # a loose plate lies on a counter
    partner = cooking.replace(agent_inv=jnp.asarray([Item.NONE, Item.PLATE], jnp.int32))
    assert float(act(partner, A.INTERACT).shaped_reward[0]) == 0.0  # partner already holds a plate


def test_shaping_values_are_parameters() -> None:
    params = PARAMS.replace(onion_in_pot_reward=3.0, delivery_reward=7.0)
    s = make_state(inv=(Item.NONE, Item.ONION))
    out = oc.step(KEY, s, jnp.asarray([A.STAY, A.INTERACT]), params)
    assert float(out.shaped_reward[1]) == 3.0
    s = make_state(facing=(D.NORTH, D.EAST), inv=(Item.NONE, Item.DISH))
    assert float(oc.step(KEY, s, jnp.asarray([A.STAY, A.INTERACT]), params).reward) == 7.0


# --- episode, observation -------------------------------------------------------------------------


def test_done_at_max_steps_and_urgency_channel() -> None:
    params = PARAMS.replace(max_steps=45)
    s = make_state()
    obs, _ = oc.reset(KEY, s.level, params)
    assert not obs[..., 25].any()
    for t in range(1, 46):
        out = oc.step(KEY, s, jnp.asarray([A.STAY, A.STAY]), params)
        s = out.state
        assert bool(out.done) == (t == 45)
        assert bool(out.obs[..., 25].all()) == (45 - t < 40)


def test_observation_perspective_swap() -> None:
    s = make_state(facing=(D.EAST, D.SOUTH), inv=(Item.ONION, Item.DISH))
    obs = np.asarray(oc.get_obs(s, PARAMS))
    assert obs.shape == (2, 9, 9, 26) and obs.dtype == np.uint8
    assert obs[0, 1, 1, 0] == 1 and obs[0, 1, 3, 1] == 1
    assert obs[1, 1, 3, 0] == 1 and obs[1, 1, 1, 1] == 1
    assert obs[0, 1, 1, 2 + D.EAST] == 1 and obs[0, 1, 3, 6 + D.SOUTH] == 1
    assert obs[1, 1, 3, 2 + D.SOUTH] == 1 and obs[1, 1, 1, 6 + D.EAST] == 1
    np.testing.assert_array_equal(obs[0, ..., 10:], obs[1, ..., 10:])
    assert obs[0, 1, 1, 23] == 1  # held onion at seat 0's cell
    assert obs[0, 1, 3, 21] == 1 and obs[0, 1, 3, 18] == 3  # held dish: soup ready, 3 onions
    assert obs[0, 0, 3, 10] == 1 and obs[0, 0, 1, 12] == 1 and obs[0, 0, 2, 14] == 1
    assert obs[0, 1, 4, 15] == 1
    assert obs[0, 8, 8, 11] == 1  # frame padding reads as counters


def test_observation_pot_channels() -> None:
    for status, in_pot, in_soup, timer, ready in [
        (23, 0, 0, 0, 0),
        (22, 1, 0, 0, 0),
        (20, 3, 0, 0, 0),
        (12, 0, 3, 12, 0),
        (0, 0, 3, 0, 1),
    ]:
        obs = np.asarray(oc.get_obs(make_state(pot=status), PARAMS))[0, 0, 3]
        assert (obs[16], obs[18], obs[20], obs[21]) == (in_pot, in_soup, timer, ready), status


# --- bad input ------------------------------------------------------------------------------------


@pytest.mark.parametrize("bad", [[6, 0], [-1, 0], [0, 9]])
def test_out_of_range_actions_raise(bad: list[int]) -> None:
    with pytest.raises(ValueError, match="actions must lie in 0..5"):
        oc.step(KEY, make_state(), jnp.asarray(bad, jnp.int32), PARAMS)


def test_bad_action_shape_and_dtype_raise() -> None:
    with pytest.raises(ValueError, match="shape"):
        oc.step(KEY, make_state(), jnp.asarray([1, 2, 3]), PARAMS)
    with pytest.raises(ValueError, match="integers"):
        oc.step(KEY, make_state(), jnp.asarray([1.0, 2.0]), PARAMS)


def test_out_of_range_actions_under_jit_act_as_stay() -> None:
    s = make_state(pos=((2, 2), (1, 3)), facing=(D.SOUTH, D.NORTH))
    out = jax.jit(oc.step)(KEY, s, jnp.asarray([-1, 9], jnp.int32), PARAMS)
    assert pos_of(out) == [(2, 2), (1, 3)]
    assert np.asarray(out.state.agent_dir).tolist() == [D.SOUTH, D.NORTH]
