"""Hand-over counting: an item put on the shared counter of Forced Coordination and taken by the partner
is one hand-over; taken back by the seat that put it, none."""

from __future__ import annotations

import jax
import numpy as np

from cec.envs.overcooked.dynamics import reset, step
from cec.envs.overcooked.state import Action, EnvParams
from cec.evaluation.handovers import count_handovers, pass_directions, shared_counters, summarise_directions
from cec.levels.classic import classic_level

A = Action


def _episode(actions: list[tuple[Action, Action]], kitchen: str = "forced_coord") -> object:
    """The states of the classic `kitchen` played by `actions` (seat 0's, seat 1's), facing as it starts."""
    level = classic_level(kitchen)
    params = EnvParams(random_start_facing=False)
    _, state = reset(jax.random.PRNGKey(0), level, params)
    states = [state]
    for a in actions:
        state = step(jax.random.PRNGKey(1), state, np.asarray(a, np.int32), params).state
        states.append(state)
    return jax.tree.map(lambda *x: np.stack([np.asarray(v) for v in x]), *states)


ONION_ON_COUNTER = [(A.LEFT, A.DOWN), (A.INTERACT, A.LEFT), (A.RIGHT, A.STAY), (A.INTERACT, A.STAY)]


def test_the_shared_counters_of_forced_coordination_are_the_middle_column() -> None:
    level = classic_level("forced_coord")
    shared = shared_counters(np.asarray(level.grid), np.asarray(level.agent_pos))
    assert sorted(zip(*np.nonzero(shared), strict=True)) == [(1, 2), (2, 2), (3, 2)]


def test_an_onion_put_on_the_counter_and_taken_by_the_partner_is_a_handover() -> None:
    states = _episode([*ONION_ON_COUNTER, (A.STAY, A.INTERACT), (A.STAY, A.UP), (A.STAY, A.RIGHT)])
    counts = count_handovers(states)
    assert counts.puts.tolist() == [1, 0] and counts.taken.tolist() == [0, 1]
    assert counts.taken_back.tolist() == [0, 0] and counts.soups == 0
    # the left seat reaches no pot, the right one does: the put is a pass, taken by the partner
    assert counts.passes.tolist() == [1, 0] and counts.passes_taken.tolist() == [0, 1]


def test_an_onion_taken_back_is_no_handover() -> None:
    counts = count_handovers(_episode([*ONION_ON_COUNTER, (A.INTERACT, A.STAY)]))
    assert counts.puts.tolist() == [1, 0] and counts.taken.tolist() == [0, 0]
    assert counts.taken_back.tolist() == [1, 0]
    assert counts.passes.tolist() == [1, 0] and counts.passes_taken_back.tolist() == [1, 0]
    assert counts.taken_back_soon.tolist() == [1, 0]  # at once


def test_an_onion_taken_back_after_a_walk_is_not_taken_back_soon() -> None:
    walk = [(A.DOWN, A.STAY), (A.UP, A.STAY), (A.UP, A.STAY), (A.DOWN, A.STAY), (A.RIGHT, A.STAY)]
    counts = count_handovers(_episode([*ONION_ON_COUNTER, *walk, (A.INTERACT, A.STAY)]))
    assert counts.taken_back.tolist() == [1, 0] and counts.taken_back_soon.tolist() == [0, 0]


def test_an_onion_put_back_by_a_seat_that_can_use_it_is_no_pass() -> None:
    # the right seat takes the onion and puts it down again on the same counter
    counts = count_handovers(_episode([*ONION_ON_COUNTER, (A.STAY, A.INTERACT), (A.STAY, A.INTERACT)]))
    assert counts.puts.tolist() == [1, 1] and counts.passes.tolist() == [1, 0]
    assert counts.passes_taken.tolist() == [0, 1] and counts.passes_taken_back.tolist() == [0, 0]


def test_passes_read_per_direction_name_the_giver_and_the_receiver() -> None:
    """A seed's pass taken by the cook and one it took back, read as `seed -> cook`; the cook's seat passed
    nothing (its direction counts the episode, with no share where nothing was passed)."""
    taken = count_handovers(_episode([*ONION_ON_COUNTER, (A.STAY, A.INTERACT), (A.STAY, A.UP)]))
    back = count_handovers(_episode([*ONION_ON_COUNTER, (A.INTERACT, A.STAY)]))
    rows = pass_directions(taken, ("seed", "cook")) + pass_directions(back, ("seed", "cook"))
    assert rows[0] == ("seed", "cook", 1, 1, 0) and rows[1] == ("cook", "seed", 0, 0, 0)
    summary = summarise_directions(rows)
    assert summary["seed -> cook"] == {
        "episodes": 2,
        "passes_per_episode": 1.0,
        "share_with_a_pass": 1.0,
        "share_taken": 0.5,
        "share_taken_back": 0.5,
    }
    assert summary["cook -> seed"]["passes_per_episode"] == 0.0
    assert summary["cook -> seed"]["share_taken"] is None
