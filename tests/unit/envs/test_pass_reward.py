"""The pass reward (a lever, not the paper's): the seat that puts down an item only its partner can use, where
the partner can reach it, is paid; taking it back costs the same, or more with the take-back cost; off by
default and in evaluation."""

from __future__ import annotations

import dataclasses

import jax
import numpy as np

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.state import Action, EnvParams
from cec.levels import Item, from_ascii
from cec.levels.classic import classic_level

A = Action
FC = classic_level("forced_coord")  # the left seat reaches the onions and plates, the right the pots and goal
# the left seat fetches an onion and puts it on the middle counter (step 3); the right seat takes it (4) and
# puts it in the pot at (1, 4) (7)
PASS = [(A.LEFT, A.DOWN), (A.INTERACT, A.LEFT), (A.RIGHT, A.STAY), (A.INTERACT, A.STAY),
        (A.STAY, A.INTERACT), (A.STAY, A.UP), (A.STAY, A.RIGHT), (A.STAY, A.INTERACT)]  # fmt: skip
PARAMS = EnvParams(random_start_facing=False, onion_in_pot_reward=3.0, pass_reward=1.5)


def _play(level: object, actions: list[tuple[Action, Action]], params: EnvParams) -> tuple[np.ndarray, list]:
    """Each step's shaped rewards, and the counters' items after each step."""
    _, state = reset(jax.random.PRNGKey(0), level, params)
    rows, items = [], []
    for a in actions:
        out = step(jax.random.PRNGKey(1), state, np.asarray(a, np.int32), params)
        state = out.state
        rows.append(np.asarray(out.shaped_reward))
        items.append(np.asarray(state.items))
    return np.stack(rows), items


def _shaped(level: object, actions: list[tuple[Action, Action]], params: EnvParams) -> np.ndarray:
    return _play(level, actions, params)[0]


def test_the_giver_is_paid_when_it_puts_the_onion_down_and_the_receiver_only_for_the_pot() -> None:
    shaped = _shaped(FC, PASS, PARAMS)
    assert shaped[3].tolist() == [1.5, 0.0]  # the put
    assert shaped[4].tolist() == [0.0, 0.0]  # the partner takes it: nothing to pay back
    assert shaped[7].tolist() == [0.0, 3.0]  # the onion in the pot: the paper's shaping alone
    assert shaped.sum(0).tolist() == [1.5, 3.0]


def test_putting_an_item_down_and_taking_it_back_earns_nothing() -> None:
    back = [*PASS[:4], (A.INTERACT, A.STAY), (A.INTERACT, A.STAY)]  # take it back, put it down again
    shaped = _shaped(FC, back, PARAMS)
    assert shaped[:, 0].tolist() == [0.0, 0.0, 0.0, 1.5, -1.5, 1.5]
    assert shaped[:5].sum() == 0


def test_the_take_back_cost_makes_the_loop_cost_and_leaves_the_pass_as_it_was() -> None:
    params = dataclasses.replace(PARAMS, pass_take_back_cost=1.0)
    back = [*PASS[:4], (A.INTERACT, A.STAY), (A.INTERACT, A.STAY)]  # take it back, put it down again
    assert _shaped(FC, back, params)[:, 0].tolist() == [0.0, 0.0, 0.0, 1.5, -2.5, 1.5]
    assert _shaped(FC, PASS, params).sum(0).tolist() == [1.5, 3.0]  # a pass the partner takes: as before
    assert params.without_training_levers().pass_take_back_cost == 0.0


def test_a_plate_passed_pays_too() -> None:
    plate = [(A.DOWN, A.STAY), (A.LEFT, A.STAY), (A.INTERACT, A.STAY), (A.RIGHT, A.STAY),
             (A.INTERACT, A.STAY)]  # fmt: skip
    assert _shaped(FC, plate, PARAMS)[:, 0].tolist() == [0.0, 0.0, 0.0, 0.0, 1.5]


def test_nothing_where_the_giver_could_use_the_item_itself() -> None:
    own = from_ascii("WWPWW\nO0 1W\nW   W\nWBWXW")  # both seats reach everything
    # an onion onto the counter at (2, 0) and back
    put_down = [(A.LEFT, A.STAY), (A.INTERACT, A.STAY), (A.DOWN, A.STAY), (A.LEFT, A.STAY),
                (A.INTERACT, A.STAY), (A.INTERACT, A.STAY)]  # fmt: skip
    shaped, items = _play(own, put_down, PARAMS)
    assert items[4][2, 0] == Item.ONION and items[5][2, 0] == Item.NONE  # it was put down, then taken back
    assert not shaped.any()


def test_off_by_default_and_in_evaluation() -> None:
    assert _shaped(FC, PASS, EnvParams(random_start_facing=False))[3].tolist() == [0.0, 0.0]
    assert PARAMS.without_training_levers().pass_reward == 0.0
    evaluated = _shaped(FC, PASS, PARAMS.without_training_levers())
    assert evaluated.sum(0).tolist() == [0.0, 3.0]


def test_the_pass_taken_reward_pays_the_giver_when_the_partner_takes_the_item() -> None:
    params = EnvParams(random_start_facing=False, onion_in_pot_reward=3.0, pass_taken_reward=2.5)
    shaped = _shaped(FC, PASS, params)
    assert shaped[3].tolist() == [0.0, 0.0]  # the put alone pays nothing
    assert shaped[4].tolist() == [2.5, 0.0]  # the partner takes it: the giver is paid
    assert shaped.sum(0).tolist() == [2.5, 3.0]
    back = [*PASS[:4], (A.INTERACT, A.STAY), (A.INTERACT, A.STAY)]  # taken back and put down again
    assert not _shaped(FC, back, params).any()
    assert params.without_training_levers() == EnvParams(random_start_facing=False, onion_in_pot_reward=3.0)


def test_the_pass_received_reward_pays_the_receiver_when_it_takes_the_item() -> None:
    params = EnvParams(random_start_facing=False, onion_in_pot_reward=3.0, pass_received_reward=2.0)
    shaped = _shaped(FC, PASS, params)
    assert shaped[3].tolist() == [0.0, 0.0]  # the put pays the giver nothing
    assert shaped[4].tolist() == [0.0, 2.0]  # the receiver takes it up: paid at once
    assert shaped.sum(0).tolist() == [0.0, 5.0]  # and for the pot as before
    # taken up, put back on the counter, taken up again: the loop earns what one take-up does
    loop = [*PASS[:5], (A.STAY, A.INTERACT), (A.STAY, A.INTERACT)]
    assert _shaped(FC, loop, params)[:, 1].tolist() == [0.0, 0.0, 0.0, 0.0, 2.0, -2.0, 2.0]
    assert params.without_training_levers() == EnvParams(random_start_facing=False, onion_in_pot_reward=3.0)
