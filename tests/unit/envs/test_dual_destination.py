"""Hand-computed cases for the Dual Destination env, its oracle and its generator."""

from __future__ import annotations

import dataclasses

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.envs import dual_destination as dd
from cec.envs.dual_destination import Action as A
from cec.levels import LevelError

KEY = jax.random.PRNGKey(0)
SINGLE = dd.DDParams()
MULTI = dd.DDParams(multi_task=True)

# One compiled generator serves both variants (`multi_task` may be traced) and every test that draws
# N levels against N excluded ones: exclusion sets are padded to N rows by repeating levels.
N = 500
_generate = jax.jit(jax.vmap(dd.generate_dd_level, in_axes=(0, None, None)))


def generate(key: jax.Array, multi: bool, exclude: dd.DDLevel, n: int = N) -> dd.DDLevel:
    """n levels, each drawn with its own key; `exclude` is repeated to N rows."""
    k = exclude.agent_pos.shape[0]
    padded = jax.tree.map(lambda x: jnp.take(x, jnp.arange(N) % k, axis=0), exclude)
    return _generate(jax.random.split(key, n), jnp.asarray(multi), padded)


def row(levels: dd.DDLevel, i: int) -> dd.DDLevel:
    return jax.tree.map(lambda x: x[i], levels)


def level(
    agents: tuple[tuple[int, int], tuple[int, int]] = ((2, 0), (2, 4)),
    green: tuple[tuple[int, int], tuple[int, int]] = ((0, 2), (4, 2)),
    pink: tuple[tuple[int, int], tuple[int, int]] | None = None,
) -> dd.DDLevel:
    return dd.DDLevel.create(agent_pos=agents, green_goals=green, pink_goals=pink)


def start(lv: dd.DDLevel, params: dd.DDParams = SINGLE) -> dd.DDState:
    return dd.reset(KEY, lv, params)[1]


def act(state: dd.DDState, a0: int, a1: int = A.STAY, params: dd.DDParams = SINGLE) -> dd.DDStepOutput:
    return dd.step(KEY, state, jnp.asarray([a0, a1], jnp.int32), params)


def pos_of(out: dd.DDStepOutput) -> list[tuple[int, int]]:
    return [tuple(p) for p in np.asarray(out.state.agent_pos).tolist()]


def play(lv: dd.DDLevel, actions: np.ndarray, params: dd.DDParams) -> tuple[float, bool]:
    """Steps the env (eagerly) through `actions` (T, 2); returns the total reward and the last done."""
    state = start(lv, params)
    total, done = 0.0, False
    for a in actions:
        out = dd.step(KEY, state, jnp.asarray(a, jnp.int32), params)
        state, total, done = out.state, total + float(out.reward), bool(out.done)
    return total, done


# --- levels -------------------------------------------------------------------------------------


def test_fixed_and_multi_task_levels_are_the_reference_cells_in_row_col() -> None:
    fx = dd.fixed_level()
    assert np.asarray(fx.agent_pos).tolist() == [[2, 0], [2, 4]]
    assert np.asarray(fx.green_goals).tolist() == [[0, 2], [4, 2]]
    assert np.asarray(fx.pink_goals).tolist() == [[1, 2], [3, 2]] and bool(fx.has_pink)
    mt = dd.multi_task_level()
    # reference (x, y): green (1,0), (3,4); pink (1,4), (3,1)
    assert np.asarray(mt.green_goals).tolist() == [[0, 1], [4, 3]]
    assert np.asarray(mt.pink_goals).tolist() == [[4, 1], [1, 3]]
    assert not bool(level().has_pink) and np.all(np.asarray(level().pink_goals) == dd.NO_CELL)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"agents": ((2, 0), (2, 5))}, r"agent 1 cell \(2, 5\) lies outside the 5x5 grid"),
        ({"green": ((-1, 2), (4, 2))}, r"green goal 0 cell \(-1, 2\) lies outside"),
        ({"agents": ((2, 0), (2, 0))}, r"agent 0 and agent 1 share the cell \(2, 0\)"),
        ({"green": ((2, 0), (4, 2))}, r"agent 0 and green goal 0 share"),
        ({"pink": ((0, 2), (3, 2))}, r"green goal 0 and pink goal 0 share"),
        ({"agents": ((2, 0, 1), (2, 4, 1))}, r"agent_pos must have shape \(\.\.\., 2, 2\)"),
    ],
)
def test_invalid_levels_raise_a_clear_error(kwargs: dict, message: str) -> None:
    with pytest.raises(LevelError, match=message):
        level(**kwargs)


def test_validation_names_the_bad_level_of_a_batch_and_reset_rejects_bad_levels() -> None:
    batch = dd.stack_dd_levels([dd.fixed_level(), dd.multi_task_level()])
    dd.validate_dd_level(batch)
    bad = dataclasses.replace(batch, green_goals=batch.green_goals.at[1, 0].set(jnp.asarray([2, 4])))
    with pytest.raises(LevelError, match=r"level 1: agent 1 and green goal 0 share the cell \(2, 4\)"):
        dd.validate_dd_level(bad)
    with pytest.raises(LevelError, match="share the cell"):
        dd.reset(KEY, dataclasses.replace(dd.fixed_level(), agent_pos=jnp.asarray([[2, 0], [2, 0]])), SINGLE)
    with pytest.raises(LevelError, match=r"multi_task=True\) needs a level with pink goals"):
        dd.reset(KEY, level(), MULTI)


# --- movement -----------------------------------------------------------------------------------


def test_action_names_match_movement_and_moves_are_clipped_to_the_grid() -> None:
    s = start(level(agents=((2, 2), (0, 0)), green=((4, 4), (4, 3))))
    assert pos_of(act(s, A.UP))[0] == (1, 2)
    assert pos_of(act(s, A.DOWN))[0] == (3, 2)
    assert pos_of(act(s, A.RIGHT))[0] == (2, 3)
    assert pos_of(act(s, A.LEFT))[0] == (2, 1)
    assert pos_of(act(s, A.STAY))[0] == (2, 2)
    assert pos_of(act(s, A.STAY, A.UP))[1] == (0, 0)  # clipped at the top edge
    assert pos_of(act(s, A.STAY, A.LEFT))[1] == (0, 0)
    assert pos_of(act(s, A.STAY, A.DOWN))[1] == (1, 0)


def test_reference_action_order_maps_to_the_same_movement() -> None:
    # reference: 0 right (+1 x), 1 down (+1 y), 2 left, 3 up, 4 stay
    s = start(level(agents=((2, 2), (0, 0)), green=((4, 4), (4, 3))))
    expected = [(2, 3), (3, 2), (2, 1), (1, 2), (2, 2)]
    for ref, cell in enumerate(expected):
        assert pos_of(act(s, int(dd.FROM_REFERENCE_ACTION[ref])))[0] == cell


def test_same_intended_cell_blocks_both_agents() -> None:
    s = start(level(agents=((2, 1), (2, 3)), green=((0, 0), (4, 4))))
    assert pos_of(act(s, A.RIGHT, A.LEFT)) == [(2, 1), (2, 3)]  # both want (2, 2)
    # moving into a partner who stays: both intend the partner's cell -> neither moves
    s = start(level(agents=((2, 1), (2, 2)), green=((0, 0), (4, 4))))
    assert pos_of(act(s, A.RIGHT, A.STAY)) == [(2, 1), (2, 2)]
    # a partner clipped at the edge stays where it is: same rule
    s = start(level(agents=((0, 3), (0, 4)), green=((4, 0), (4, 4))))
    assert pos_of(act(s, A.RIGHT, A.RIGHT)) == [(0, 3), (0, 4)]


def test_swapping_and_following_are_allowed() -> None:
    s = start(level(agents=((2, 1), (2, 2)), green=((0, 0), (4, 4))))
    assert pos_of(act(s, A.RIGHT, A.LEFT)) == [(2, 2), (2, 1)]  # swap through each other
    assert pos_of(act(s, A.RIGHT, A.RIGHT)) == [(2, 2), (2, 3)]  # follow into the cell being left


# --- reward and done ----------------------------------------------------------------------------


def test_reward_pays_only_on_two_different_green_cells() -> None:
    lv = level(agents=((1, 2), (3, 2)), green=((0, 2), (4, 2)))
    s = start(lv)
    assert float(act(s, A.STAY).reward) == -1.0
    assert float(act(s, A.UP).reward) == -1.0  # only one agent on a green cell
    out = act(s, A.UP, A.DOWN)
    assert pos_of(out) == [(0, 2), (4, 2)] and float(out.reward) == 2.0
    assert float(act(out.state, A.STAY).reward) == 2.0  # paid on every step they stay
    # either assignment pays
    s = start(level(agents=((1, 2), (3, 2)), green=((4, 2), (0, 2))))
    assert float(act(s, A.UP, A.DOWN).reward) == 2.0
    # custom values
    assert float(act(s, A.UP, A.DOWN, params=dd.DDParams(step_cost=-0.5, goal_bonus=10.0)).reward) == 9.5


def test_pink_pairs_pay_only_in_the_multi_task_variant() -> None:
    lv = dd.fixed_level()  # pink one step inside the green goals
    # seat 0 walks (2, 0) -> (2, 1) -> (1, 1), seat 1 (2, 4) -> (2, 3) -> (3, 3)
    state = start(lv, MULTI)
    for a0, a1 in [(A.RIGHT, A.LEFT), (A.UP, A.DOWN)]:
        state = act(state, a0, a1, MULTI).state
    assert [tuple(p) for p in np.asarray(state.agent_pos).tolist()] == [(1, 1), (3, 3)]
    out = act(state, A.RIGHT, A.LEFT, MULTI)
    assert pos_of(out) == [(1, 2), (3, 2)] and float(out.reward) == 2.0
    out_single = act(state, A.RIGHT, A.LEFT, SINGLE)
    assert float(out_single.reward) == -1.0  # the same move pays nothing in the single-task variant
    # one agent on green, the other on pink: no bonus
    mixed = dd.DDState(lv, jnp.asarray([[0, 1], [1, 2]], jnp.int32), jnp.int32(0), jnp.int32(0))
    assert float(act(mixed, A.RIGHT, A.STAY, MULTI).reward) == -1.0  # (0, 2) green + (1, 2) pink


def test_done_exactly_at_max_steps() -> None:
    params = dd.DDParams(max_steps=3)
    s = start(dd.fixed_level(), params)
    dones = []
    for _ in range(3):
        out = act(s, A.STAY, params=params)
        s = out.state
        dones.append(bool(out.done))
    assert dones == [False, False, True] and int(s.time) == 3


# --- observation --------------------------------------------------------------------------------


def test_observation_channels_and_perspective_swap() -> None:
    obs, _ = dd.reset(KEY, dd.fixed_level(), SINGLE)
    assert obs.shape == (2, 5, 5, 4) and obs.dtype == jnp.float32
    o = np.asarray(obs)
    one_hot = np.zeros((5, 5))
    left, right = one_hot.copy(), one_hot.copy()
    left[2, 0] = right[2, 4] = 1
    green = one_hot.copy()
    green[0, 2] = green[4, 2] = 1
    np.testing.assert_array_equal(o[0, :, :, 0], left)  # seat 0: self
    np.testing.assert_array_equal(o[0, :, :, 1], right)  # seat 0: other
    np.testing.assert_array_equal(o[1, :, :, 0], right)  # seat 1 swaps 0/1
    np.testing.assert_array_equal(o[1, :, :, 1], left)
    for seat in range(2):
        np.testing.assert_array_equal(o[seat, :, :, 2], green)
        assert o[seat, :, :, 3].sum() == 0  # pink goals only in the multi-task variant
    o_mt = np.asarray(dd.reset(KEY, dd.fixed_level(), MULTI)[0])
    pink = one_hot.copy()
    pink[1, 2] = pink[3, 2] = 1
    np.testing.assert_array_equal(o_mt[0, :, :, 3], pink)
    np.testing.assert_array_equal(o_mt[1, :, :, 3], pink)


def test_partial_observation_keeps_the_3x3_window_and_marks_the_rest_minus_one() -> None:
    params = dd.DDParams(partial_obs=True, multi_task=True)
    lv = level(agents=((1, 1), (0, 4)), green=((2, 2), (4, 4)), pink=((0, 0), (0, 3)))
    o = np.asarray(dd.reset(KEY, lv, params)[0])
    full = np.asarray(dd.reset(KEY, lv, dd.DDParams(multi_task=True))[0])
    rows, cols = np.meshgrid(np.arange(5), np.arange(5), indexing="ij")
    for seat, (r, c) in enumerate([(1, 1), (0, 4)]):
        window = (np.abs(rows - r) <= 1) & (np.abs(cols - c) <= 1)
        np.testing.assert_array_equal(o[seat][window], full[seat][window])
        assert np.all(o[seat][~window] == dd.OUTSIDE_WINDOW)
    assert o[0, 2, 2, 2] == 1 and o[0, 0, 0, 3] == 1  # seat 0 sees a green and a pink goal
    assert o[0, :, :, 1].max() == 0  # but not the other agent at (0, 4)
    assert o[1, 0, 3, 3] == 1 and o[1, 0, 4, 0] == 1 and o[1, :, :, 2].max() == 0
    assert int(((o[1] != -1).all(-1)).sum()) == 4  # a corner agent sees a clipped 2x2 window


# --- oracle -------------------------------------------------------------------------------------


def test_oracle_scores_191_and_0955_on_the_fixed_task_when_played_in_the_env() -> None:
    plan = dd.oracle_plan(dd.fixed_level(), SINGLE)
    assert plan.actions.shape == (100, 2) and plan.steps_to_goal == 4
    total, done = play(dd.fixed_level(), plan.actions, SINGLE)
    assert total == 191.0 == plan.return_ and done
    assert dd.normalised_score(total, 100) == pytest.approx(0.955)
    assert dd.oracle_return(dd.fixed_level()) == 191.0


def test_oracle_multi_task_prefers_the_closer_pair_and_matches_the_env() -> None:
    for lv, steps in [(dd.fixed_level(), 3), (dd.multi_task_level(), 3)]:
        plan = dd.oracle_plan(lv, MULTI)
        assert plan.steps_to_goal == steps
        total, _ = play(lv, plan.actions, MULTI)
        assert total == plan.return_ == -100 + 3 * (100 - steps + 1)


def test_oracle_equals_assignment_manhattan_bound_and_env_on_random_levels() -> None:
    for multi, params in [(False, SINGLE), (True, MULTI)]:
        levels = jax.tree.map(
            lambda x: x[:40], generate(jax.random.PRNGKey(7), multi, dd.held_out_dd_levels())
        )
        plans = [dd.oracle_plan(row(levels, i), params) for i in range(40)]

        def bound(agents: np.ndarray, goals: np.ndarray) -> int:
            d = np.abs(agents[:, None] - goals[None]).sum(-1)
            return int(min(max(d[0, 0], d[1, 1]), max(d[0, 1], d[1, 0])))

        for i, plan in enumerate(plans):
            agents = np.asarray(levels.agent_pos[i])
            t = bound(agents, np.asarray(levels.green_goals[i]))
            if multi:
                t = min(t, bound(agents, np.asarray(levels.pink_goals[i])))
            assert plan.steps_to_goal == t

        # execute every plan in the env, jitted and vmapped
        def rollout(lv: dd.DDLevel, actions: jax.Array, params: dd.DDParams = params) -> jax.Array:
            _, state = dd.reset(KEY, lv, params)

            def body(s: dd.DDState, a: jax.Array) -> tuple[dd.DDState, jax.Array]:
                out = dd.step(KEY, s, a, params)
                return out.state, out.reward

            return jax.lax.scan(body, state, actions)[1].sum()

        returns = jax.jit(jax.vmap(rollout))(levels, jnp.asarray(np.stack([p.actions for p in plans])))
        np.testing.assert_array_equal(np.asarray(returns), [p.return_ for p in plans])


# --- generator ----------------------------------------------------------------------------------


def test_generator_draws_distinct_in_grid_cells_and_never_the_held_out_tasks() -> None:
    held_out = dd.held_out_dd_levels()
    for multi in (False, True):
        levels = generate(jax.random.PRNGKey(11), multi, held_out, n=100_000)
        dd.validate_dd_level(levels)  # in the grid, all cells distinct
        assert bool(jnp.all(levels.has_pink == multi))
        cells = np.concatenate([np.asarray(levels.agent_pos), np.asarray(levels.green_goals)], 1)
        if multi:
            cells = np.concatenate([cells, np.asarray(levels.pink_goals)], 1)
        else:
            assert np.all(np.asarray(levels.pink_goals) == dd.NO_CELL)
        codes = cells[..., 0] * 5 + cells[..., 1]
        assert codes.min() >= 0 and codes.max() <= 24
        assert np.all(np.sort(codes, 1)[:, 1:] != np.sort(codes, 1)[:, :-1])
        hits = jax.vmap(dd.same_dd_task, in_axes=(0, None))(levels, held_out)
        assert not bool(jnp.any(hits))
        # uniform: every role uses every cell about 100k / 25 = 4000 times
        for role in range(cells.shape[1]):
            counts = np.bincount(codes[:, role], minlength=25)
            assert counts.min() > 3600 and counts.max() < 4400


def test_exclusion_resamples_exactly_the_draws_that_would_be_excluded() -> None:
    key = jax.random.PRNGKey(5)
    for multi in (False, True):
        free = generate(key, multi, dd.held_out_dd_levels())
        # excluding what these keys draw forces every one of them to draw again
        again = generate(key, multi, free)
        assert not bool(jnp.any(jax.vmap(dd.same_dd_task, in_axes=(0, None))(again, free)))
        # excluding key 0's draw as well changes key 0's output and no other
        held_and_first = jax.tree.map(
            lambda h, f: jnp.concatenate([jnp.asarray(h), f[:1]]), dd.held_out_dd_levels(), free
        )
        only_first = generate(key, multi, held_and_first)
        changed = ~jax.vmap(dd.same_dd_task)(only_first, jax.tree.map(lambda x: x[:, None], free))[:, 0]
        assert np.flatnonzero(np.asarray(changed)).tolist() == [0]


def test_same_task_ignores_seat_and_goal_order_and_pink_only_when_both_have_it() -> None:
    fx = dd.fixed_level()
    relabelled = dd.DDLevel.create(
        agent_pos=[(2, 4), (2, 0)], green_goals=[(4, 2), (0, 2)], pink_goals=[(3, 2), (1, 2)]
    )
    no_pink = level()
    other_pink = level(pink=((0, 0), (0, 4)))
    batch = dd.stack_dd_levels([fx])
    assert bool(dd.same_dd_task(relabelled, batch)[0])
    assert bool(dd.same_dd_task(no_pink, batch)[0])
    assert not bool(dd.same_dd_task(other_pink, batch)[0])
    assert not bool(dd.same_dd_task(dd.multi_task_level(), batch)[0])


# --- batching and auto-reset --------------------------------------------------------------------


def test_jit_vmap_over_a_mixed_batch_matches_stepping_each_level_alone() -> None:
    generated = generate(KEY, True, dd.held_out_dd_levels())
    levels = dd.stack_dd_levels(
        [dd.fixed_level(), dd.multi_task_level()] + [row(generated, i) for i in range(3)]
    )
    params = dd.DDParams(multi_task=True, partial_obs=True)
    keys = jax.random.split(jax.random.PRNGKey(3), 5)
    _, batch_state = jax.jit(jax.vmap(dd.reset, in_axes=(0, 0, None)))(keys, levels, params)
    actions = jax.random.randint(jax.random.PRNGKey(4), (6, 5, 2), 0, dd.NUM_ACTIONS)
    step_batch = jax.jit(jax.vmap(dd.step, in_axes=(0, 0, 0, None)))
    singles = [dd.reset(keys[e], jax.tree.map(lambda x, e=e: x[e], levels), params)[1] for e in range(5)]
    step_one = jax.jit(dd.step)
    for t in range(6):
        out = step_batch(keys, batch_state, actions[t], params)
        batch_state = out.state
        for e in range(5):
            alone = step_one(keys[e], singles[e], actions[t, e], params)
            singles[e] = alone.state
            np.testing.assert_array_equal(np.asarray(out.obs[e]), np.asarray(alone.obs))
            assert float(out.reward[e]) == float(alone.reward)
            np.testing.assert_array_equal(
                np.asarray(out.state.agent_pos[e]), np.asarray(alone.state.agent_pos)
            )


def test_autoreset_takes_the_next_level_from_the_buffer() -> None:
    buffer = dd.stack_dd_levels([dd.fixed_level(), dd.multi_task_level(), level(agents=((0, 0), (4, 4)))])
    params = dd.DDParams(max_steps=3)
    _, state = dd.reset(KEY, dd.fixed_level(), params)
    step = jax.jit(dd.step_autoreset)
    starts = []
    for t in range(9):
        out = step(KEY, state, jnp.asarray([A.DOWN, A.UP]), buffer, params)
        state = out.state
        assert bool(out.done) == (t % 3 == 2)
        if out.done:
            assert int(state.time) == 0 and int(state.episode) == t // 3 + 1
            k = int(state.episode) % 3
            np.testing.assert_array_equal(np.asarray(state.agent_pos), np.asarray(buffer.agent_pos[k]))
            np.testing.assert_array_equal(
                np.asarray(state.level.green_goals), np.asarray(buffer.green_goals[k])
            )
            # the observation is the new episode's first one
            np.testing.assert_array_equal(np.asarray(out.obs), np.asarray(dd.get_obs(state, params)))
            starts.append(k)
    assert starts == [1, 2, 0]


# --- bad input ----------------------------------------------------------------------------------


def test_out_of_range_actions_raise_eagerly_and_act_as_stay_under_jit() -> None:
    s = start(dd.fixed_level())
    with pytest.raises(ValueError, match=r"actions must lie in 0\.\.4 .* got values \[5\]"):
        dd.step(KEY, s, jnp.asarray([0, 5]), SINGLE)
    with pytest.raises(ValueError, match=r"got values \[-1\]"):
        dd.step_autoreset(KEY, s, jnp.asarray([-1, 0]), dd.stack_dd_levels([dd.fixed_level()]), SINGLE)
    with pytest.raises(ValueError, match=r"shape \(\.\.\., 2\)"):
        dd.step(KEY, s, jnp.asarray([0, 1, 2]), SINGLE)
    with pytest.raises(ValueError, match="integers"):
        dd.step(KEY, s, jnp.asarray([0.0, 1.0]), SINGLE)
    out = jax.jit(dd.step)(KEY, s, jnp.asarray([7, A.UP]), SINGLE)
    assert [tuple(p) for p in np.asarray(out.state.agent_pos).tolist()] == [(2, 0), (1, 4)]
