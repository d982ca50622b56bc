"""The hand-over reward (a lever, not the paper's): both seats are paid when a seat uses an item it could
not have fetched itself; off by default, and then the shaped rewards are exactly the paper's."""

from __future__ import annotations

import jax
import numpy as np

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.state import Action, EnvParams
from cec.levels import from_ascii
from cec.levels.classic import classic_level

A = Action
# Forced Coordination: seat 0 (left) fetches an onion and leaves it on the middle counter; seat 1 (right,
# no onion pile on its side) takes it and puts it in the pot at (1, 4).
HANDOVER = [(A.LEFT, A.DOWN), (A.INTERACT, A.LEFT), (A.RIGHT, A.STAY), (A.INTERACT, A.STAY),
            (A.STAY, A.INTERACT), (A.STAY, A.UP), (A.STAY, A.RIGHT), (A.STAY, A.INTERACT)]  # fmt: skip


def _shaped(level: object, actions: list[tuple[Action, Action]], params: EnvParams) -> np.ndarray:
    _, state = reset(jax.random.PRNGKey(0), level, params)
    rows = []
    for a in actions:
        out = step(jax.random.PRNGKey(1), state, np.asarray(a, np.int32), params)
        state = out.state
        rows.append(np.asarray(out.shaped_reward))
    return np.stack(rows)


def test_an_onion_handed_over_and_put_in_the_pot_pays_both_seats() -> None:
    params = EnvParams(random_start_facing=False, onion_in_pot_reward=3.0, handover_reward=2.0)
    shaped = _shaped(classic_level("forced_coord"), HANDOVER, params)
    assert shaped[:-1].sum() == 0
    assert shaped[-1].tolist() == [2.0, 5.0]  # the giver 2, the receiver 2 + its onion-in-pot 3


def test_off_by_default_and_nothing_for_a_seat_that_fetched_its_own_onion() -> None:
    off = _shaped(classic_level("forced_coord"), HANDOVER, EnvParams(random_start_facing=False))
    assert off[-1].tolist() == [0.0, 10.0]  # the paper's onion-in-pot reward alone
    own = from_ascii("WWPWW\nO0 1W\nW   W\nWBWXW")  # both seats reach everything
    params = EnvParams(random_start_facing=False, onion_in_pot_reward=3.0, handover_reward=2.0)
    shaped = _shaped(own, [(A.LEFT, A.STAY), (A.INTERACT, A.STAY), (A.RIGHT, A.STAY), (A.UP, A.STAY),
                           (A.INTERACT, A.STAY)], params)  # fmt: skip
    assert shaped.sum(0).tolist() == [3.0, 0.0]
