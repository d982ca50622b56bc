"""The Dual Destination oracle partner: optimal with itself, a best response to a committed partner, only
what its view shows, and a zoo entry that cross-play batches with networks in both seats."""

from __future__ import annotations

from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.agents.policy import load_policies, random_policy, scripted_policy
from cec.agents.zoo import parse_zoo
from cec.config import ConfigError
from cec.envs import dual_destination as dd
from cec.envs.dual_destination.partner import MEMORY_SIZE, oracle_partner_step
from cec.envs.task import EnvConfig
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels

KEY = jax.random.PRNGKey(0)
STEPS = 100
LEVELS = "fixed,generated_000,generated_001"


def _committed_action(pos: jax.Array, goal: jax.Array) -> jax.Array:
    """A stubborn scripted partner: straight for `goal`, rows first, never giving way."""
    dr, dc = goal[0] - pos[0], goal[1] - pos[1]
    return jnp.where(
        dr != 0,
        jnp.where(dr > 0, dd.Action.DOWN, dd.Action.UP),
        jnp.where(dc != 0, jnp.where(dc > 0, dd.Action.RIGHT, dd.Action.LEFT), dd.Action.STAY),
    ).astype(jnp.int32)


def _episode(
    level: dd.DDLevel, params: dd.DDParams, commit: jax.Array, oracle_seat: jax.Array
) -> tuple[jax.Array, jax.Array, jax.Array]:
    """One episode: the oracle partner in `oracle_seat`; in the other seat the oracle partner too when
    `commit` is (-1, -1), else the committed partner heading for cell `commit`.

    Returns (return, positions int32[T, 2, 2] after each step, the oracle seat's actions int32[T])."""
    obs, state = dd.reset(KEY, level, params)
    memory = jnp.zeros((2, MEMORY_SIZE), jnp.float32)
    other = 1 - oracle_seat

    def body(carry: tuple, _: None) -> tuple:
        obs, state, memory = carry
        memory, actions = jax.vmap(oracle_partner_step)(memory, obs)
        committed = _committed_action(state.agent_pos[other], commit)
        actions = jnp.where((jnp.arange(2) == other) & (commit[0] >= 0), committed, actions)
        out = dd.step(KEY, state, actions, params)
        return (out.obs, out.state, memory), (out.reward, out.state.agent_pos, actions[oracle_seat])

    _, (rewards, pos, acts) = jax.lax.scan(body, (obs, state, memory), None, length=STEPS)
    return rewards.sum(), pos, acts


_episodes = jax.jit(jax.vmap(_episode, in_axes=(0, None, 0, 0)))  # one compilation for every test
BATCH = 64


def _play(
    levels: list[dd.DDLevel] | dd.DDLevel,
    params: dd.DDParams,
    commit: np.ndarray | None = None,
    seat: np.ndarray | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Plays up to BATCH levels (a list or a batch) in one padded call of `_episodes`."""
    batch = dd.stack_dd_levels(levels) if isinstance(levels, list) else levels
    n = int(batch.agent_pos.shape[0])
    assert n <= BATCH
    commit = np.full((n, 2), -1) if commit is None else np.asarray(commit)
    seat = np.zeros(n, np.int32) if seat is None else np.asarray(seat)
    pad = list(range(n)) + [n - 1] * (BATCH - n)
    out = _episodes(
        jax.tree.map(lambda x: jnp.asarray(x)[jnp.asarray(pad)], batch),
        params,
        jnp.asarray(commit[pad], jnp.int32),
        jnp.asarray(seat[pad], jnp.int32),
    )
    return tuple(np.asarray(x)[:n] for x in out)  # type: ignore[return-value]


def _generated(n: int, multi: bool, seed: int = 1) -> dd.DDLevel:
    gen = jax.vmap(dd.generate_dd_level, in_axes=(0, None, None))
    return gen(jax.random.split(jax.random.PRNGKey(seed), n), multi, dd.held_out_dd_levels())


def _row(levels: dd.DDLevel, i: int) -> dd.DDLevel:
    return jax.tree.map(lambda x: x[i], levels)


# --- with itself: the oracle's return ---------------------------------------------------------------


def test_with_itself_it_reaches_the_oracle_return_on_the_fixed_tasks() -> None:
    single, multi = dd.DDParams(max_steps=STEPS), dd.DDParams(max_steps=STEPS, multi_task=True)
    ret, _, _ = _play([dd.fixed_level()], single)
    assert ret.tolist() == [dd.oracle_return(dd.fixed_level(), single)]
    assert ret[0] / (2 * STEPS) == pytest.approx(0.955)
    ret, _, _ = _play([dd.fixed_level(), dd.multi_task_level()], multi)
    assert ret.tolist() == [dd.oracle_return(lv, multi) for lv in (dd.fixed_level(), dd.multi_task_level())]


def test_with_itself_it_reaches_the_oracle_return_on_generated_tasks() -> None:
    for multi in (False, True):
        params = dd.DDParams(max_steps=STEPS, multi_task=multi)
        levels = _generated(BATCH, multi)
        returns, _, _ = _play(levels, params)
        np.testing.assert_array_equal(
            returns, [dd.oracle_return(_row(levels, i), params) for i in range(BATCH)]
        )


# --- best response to a partner's choice ----------------------------------------------------------


def test_it_follows_a_committed_partner_to_the_other_goal_on_the_fixed_task_in_either_seat() -> None:
    goals = np.asarray(dd.fixed_level().green_goals)
    cases = [(seat, k) for seat in (0, 1) for k in (0, 1)]
    commit = np.stack([goals[k] for _, k in cases])
    seat = np.asarray([s for s, _ in cases])
    for partial in (False, True):
        params = dd.DDParams(max_steps=STEPS, partial_obs=partial)
        ret, pos, _ = _play([dd.fixed_level()] * len(cases), params, commit, seat)
        for i, (s, k) in enumerate(cases):
            final = pos[i, -1]
            assert final[1 - s].tolist() == goals[k].tolist()
            assert final[s].tolist() == goals[1 - k].tolist()  # the other goal: the best response
            assert ret[i] > 0.8 * 2 * STEPS  # and early: most of the episode is paid


def test_it_best_responds_to_a_committed_partner_on_generated_tasks() -> None:
    """The committed partner picks either green cell, or (multi-task) either pink cell; the oracle
    partner ends on the other cell of that pair, close to the return of knowing the choice in advance."""
    for multi in (False, True):
        params = dd.DDParams(max_steps=STEPS, multi_task=multi)
        levels = _generated(BATCH // 2, multi, seed=3)
        agents = np.asarray(levels.agent_pos)
        for colour in ("green_goals", "pink_goals") if multi else ("green_goals",):
            cells = np.asarray(getattr(levels, colour))
            both = jax.tree.map(lambda x: jnp.concatenate([x, x]), levels)  # partner picks cell 0, then 1
            commit = np.concatenate([cells[:, 0], cells[:, 1]])
            other = np.concatenate([cells[:, 1], cells[:, 0]])
            ret, pos, _ = _play(both, params, commit)
            on_other = np.all(pos[:, -1, 0] == other, axis=-1)
            assert on_other.mean() >= 0.95, (multi, colour, on_other.mean())
            # knowing the choice in advance: both walk at once, T = the longer of the two distances
            starts = np.concatenate([agents, agents])
            t = np.maximum(np.abs(starts[:, 1] - commit).sum(-1), np.abs(starts[:, 0] - other).sum(-1))
            bound = (-STEPS + 3 * (STEPS - t + 1)).mean()
            assert ret.mean() > bound - 0.05 * 2 * STEPS, (multi, colour, ret.mean(), bound)


# --- partial observability -------------------------------------------------------------------------


def test_with_the_3x3_view_it_acts_on_what_it_sees_only() -> None:
    """Two levels that differ only in a goal the agents cannot see yet: the same observations, the same
    actions, until the goal comes into view; and on the fixed task, where no goal is in view at the
    start, it cannot match the oracle's 4 steps."""
    params = dd.DDParams(max_steps=STEPS, partial_obs=True)
    a = dd.DDLevel.create([(2, 0), (2, 4)], [(0, 2), (4, 4)])
    b = dd.DDLevel.create([(2, 0), (2, 4)], [(0, 2), (4, 3)])
    ret, pos, act = _play([a, b, dd.fixed_level()], params)

    def observations(level: dd.DDLevel, positions: np.ndarray) -> np.ndarray:
        start = dd.reset(KEY, level, params)[1]
        return np.stack(
            [np.asarray(dd.get_obs(start.replace(agent_pos=jnp.asarray(p)), params)) for p in positions]
        )

    differ = np.any(observations(a, pos[0]) != observations(b, pos[1]), axis=(1, 2, 3, 4))
    first_diff = int(np.argmax(differ))
    assert first_diff > 0  # the differing goal stays out of view for a while
    # the action of step t depends on the observations up to step t (those after step t - 1)
    np.testing.assert_array_equal(act[0, : first_diff + 1], act[1, : first_diff + 1])
    assert ret[2] < dd.oracle_return(dd.fixed_level(), dd.DDParams(max_steps=STEPS))


# --- the zoo and cross-play ---------------------------------------------------------------------------


def test_zoo_entries_name_a_scripted_kind_instead_of_a_checkpoint(tmp_path: Path) -> None:
    entries = parse_zoo({"policies": [{"name": "oracle", "scripted": "dd_oracle"}]}, tmp_path)
    policies, skipped = load_policies(entries)
    assert not skipped
    (oracle,) = policies
    assert (oracle.scripted, oracle.algorithm, oracle.seed, oracle.params) == (
        "dd_oracle",
        "dd_oracle",
        0,
        None,
    )
    with pytest.raises(ConfigError, match="unknown scripted policy 'nope'"):
        parse_zoo([{"name": "x", "scripted": "nope"}])
    with pytest.raises(ConfigError, match="no `checkpoint`"):
        parse_zoo([{"name": "x", "scripted": "dd_oracle", "checkpoint": "runs/a"}])
    with pytest.raises(ConfigError, match="`checkpoint` is required"):
        parse_zoo([{"name": "x"}])


def test_crossplay_pairs_the_oracle_with_networks_in_both_seats_in_one_table(tmp_path: Path) -> None:
    env = EnvConfig(name="dual_destination", levels="fixed")
    nets = [random_policy(f"net{i}", jax.random.PRNGKey(i), env=env, seed=i) for i in range(2)]
    (oracle,), _ = load_policies(parse_zoo([{"name": "oracle", "scripted": "dd_oracle"}], tmp_path))
    levels = eval_levels("dual_destination", LEVELS)
    config = EvalConfig(levels=LEVELS, episodes=2, games_per_call=1)
    table = crossplay([*nets, oracle], levels, config)
    a, b = table.policy_a.astype(str), table.policy_b.astype(str)
    for net in ("net0", "net1"):
        pair = ((a == "oracle") & (b == net)) | ((a == net) & (b == "oracle"))
        # both seat orders (the row policy's seat), every level and episode
        assert sorted(set(table.seat[pair].tolist())) == [0, 1]
        assert pair.sum() == 2 * 3 * 2
    selfplay = (a == "oracle") & (b == "oracle")
    for name, level in [("fixed", dd.fixed_level()), *dd.heldout_generated_dd_levels()[:2]]:
        on = selfplay & (table.level.astype(str) == name)
        np.testing.assert_array_equal(table.returns[on], dd.oracle_return(level, dd.DDParams()))
    # the networks' own games are untouched by the oracle's presence (common random numbers)
    alone = crossplay(nets, levels, config)
    nets_only = np.isin(a, ["net0", "net1"]) & np.isin(b, ["net0", "net1"])
    np.testing.assert_array_equal(table.returns[nets_only], alone.returns)


def test_the_oracle_takes_the_evaluations_view_and_leads_only_alone() -> None:
    partial = EnvConfig(
        name="dual_destination", levels="fixed", dual_destination=dd.DDParams(partial_obs=True)
    )
    oracle = scripted_policy("dd_oracle", "oracle")
    net = random_policy("net", KEY, env=partial)
    levels = eval_levels("dual_destination", LEVELS)
    config = EvalConfig(levels=LEVELS, episodes=2, games_per_call=1)
    # listed first, the oracle does not lead: the network's partial view is the evaluation's
    table = crossplay([oracle, net], levels, config)
    sp = (table.policy_a.astype(str) == "oracle") & (table.policy_b.astype(str) == "oracle")
    fixed = table.level.astype(str) == "fixed"
    assert np.all(table.returns[sp & fixed] < dd.oracle_return(dd.fixed_level()))  # it looked for the goals
    alone = crossplay([oracle], levels, config)  # alone, it leads: its own (full) view
    oracle_returns = {
        n: dd.oracle_return(lv) for n, lv in [("fixed", dd.fixed_level()), *dd.heldout_generated_dd_levels()]
    }
    assert alone.returns.tolist() == [oracle_returns[n] for n in alone.level.astype(str)]
