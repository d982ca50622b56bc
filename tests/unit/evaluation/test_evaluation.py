"""Cross-play as a library: self-play consistency, seat symmetry, common random numbers, the zoo, bad input.

Tiny `small`-preset networks with random initialisation (no training); short episodes on two kitchens.
"""

import dataclasses
import functools
import json
import shutil

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from apps.cli import main
from cec.agents.network import ActorCritic, NetworkConfig, network_preset
from cec.agents.policy import Policy, load_policies, random_policy
from cec.agents.zoo import load_zoo, parse_zoo
from cec.config import ConfigError
from cec.envs import dual_destination as dd
from cec.envs import overcooked as oc
from cec.envs.task import EnvConfig, Task
from cec.evaluation.analysis import pair_level_scores, pair_scores, policies_of
from cec.evaluation.crossplay import EvalConfig, crossplay, episode_key, eval_levels, plan_games
from cec.evaluation.results import EpisodeTable, read_csv, write_csv
from cec.levels.classic import CLASSIC_ASCII
from cec.training.rollout import init_carry, rollout

STEPS = 24
EPISODES = 3
# Every Overcooked call below plays 4 games x (2 levels x 3 episodes) envs: one compilation serves them all.
CFG = EvalConfig(episodes=EPISODES, games_per_call=4)
OC_ENV = EnvConfig(name="overcooked", levels="cramped_room", overcooked=oc.EnvParams(max_steps=STEPS))
DD_ENV = EnvConfig(name="dual_destination", levels="fixed", dual_destination=dd.DDParams(max_steps=STEPS))
LEVELS = "cramped_room,coord_ring"


def _policy(name, key, algorithm="a", seed=0, env=OC_ENV, **kw):
    """A random `small` policy whose output layer is scaled up: at initialisation (gain 0.01) every policy
    is almost uniform, so under common random numbers different policies would act alike."""
    p = random_policy(name, jax.random.PRNGKey(key), env=env, algorithm=algorithm, seed=seed, **kw)
    params = {"params": {**p.params["params"]}}
    params["params"]["actor_out"] = jax.tree.map(lambda x: 300.0 * x, params["params"]["actor_out"])
    return Policy(p.name, p.algorithm, p.seed, params, p.network, p.env, p.levels)


def _renamed(p: Policy, name: str, seed: int) -> Policy:
    return Policy(name, p.algorithm, seed, p.params, p.network, p.env, p.levels)


@pytest.fixture(scope="module")
def zoo():
    return [_policy("a0", 0, "a", 0), _policy("a1", 1, "a", 1), _policy("b0", 2, "b", 0)]


@pytest.fixture(scope="module")
def levels():
    return eval_levels("overcooked", LEVELS)


def _cfg(**kw):
    return dataclasses.replace(CFG, **kw)


def _rows(table: EpisodeTable, a: str, b: str, seat: int):
    """(level, episode) -> (return, shaped, collisions) of the rows of pairing (a, b) in one seat order."""
    m = (table.policy_a == a) & (table.policy_b == b) & (table.seat == seat)
    return {
        (lv, int(ep)): (r, s, c)
        for lv, ep, r, s, c in zip(
            table.level[m],
            table.episode[m],
            table.returns[m],
            table.shaped_return[m],
            table.collisions[m],
            strict=True,
        )
    }


@functools.cache
def _self_play_fn(policy_env: EnvConfig, network):
    """The self-play score through the trainer's path: `rollout` with one shared parameter set."""
    task = Task.from_config(policy_env)
    net = ActorCritic(network, task.num_actions)
    env_params = policy_env.params

    def one(params, level, key):
        k_reset, k_play = jax.random.split(key)
        buf = jax.tree.map(lambda x: x[None, None], level)
        carry = init_carry(task, net, env_params, buf, k_reset)
        _, traj = rollout(params, carry, buf, k_play, task=task, network=net, env_params=env_params,
                          num_steps=STEPS)  # fmt: skip
        return traj.reward.sum(), traj.shaped.sum(), traj.collision.sum()

    return jax.jit(jax.vmap(one, in_axes=(None, 0, 0)))


def _self_play_reference(policy: Policy, levels, episodes: int, seed: int):
    names = [n for n in levels.names for _ in range(episodes)]
    episode = [e for _ in levels.names for e in range(episodes)]
    env_levels = jax.tree.map(lambda x: jnp.repeat(x, episodes, axis=0), levels.levels)
    keys = jnp.stack([episode_key(seed, n, e) for n, e in zip(names, episode, strict=True)])
    r, s, c = _self_play_fn(policy.env, policy.network)(policy.params, env_levels, keys)
    return {
        (n, e): (float(r[i]), float(s[i]), float(c[i]))
        for i, (n, e) in enumerate(zip(names, episode, strict=True))
    }


def test_xp_matrix_diagonal_equals_the_self_play_score(zoo, levels):
    table = crossplay(zoo, levels, _cfg(seed=3))
    # Both seats of different policies, self-play once: 3 self + 3 pairs x 2 seats, x 2 levels x 3 episodes.
    assert len(table) == (3 + 6) * 2 * EPISODES
    assert set(table.actions) == {"sampled"} and set(table.episode_steps) == {STEPS}
    for p in zoo:
        ref = _self_play_reference(p, levels, EPISODES, seed=3)
        got = _rows(table, p.name, p.name, 0)
        assert got.keys() == ref.keys()
        for k, (r, s, c) in ref.items():
            np.testing.assert_allclose(got[k], (r, s, c), rtol=1e-6)
        # The matrix diagonal (mean over levels of the per-level means) is that self-play score; random
        # policies deliver no soup in 12 steps, so check the matrix of the metric that varies too.
        i = policies_of(table).index((p.algorithm, p.seed))
        for metric, column in (("score", 0), ("collisions", 2)):
            diagonal = pair_scores(pair_level_scores(table, metric=metric))[i, i]
            assert diagonal == pytest.approx(np.mean([v[column] for v in ref.values()]))
        assert len(set(ref.values())) > 1  # the episodes differ, so the comparisons above can fail

    # A self-play-only run in another batch layout meets the same randomness: the same diagonal.
    alone = crossplay(zoo[::-1], levels, _cfg(seed=3, pairs="self"))
    assert len(alone) == 3 * 2 * EPISODES
    for p in zoo:
        assert _rows(alone, p.name, p.name, 0) == _rows(table, p.name, p.name, 0)


def test_seat_swap_is_symmetric_for_identical_policies(zoo, levels):
    twin = _renamed(zoo[0], "a0_twin", 7)
    table = crossplay([zoo[0], twin, zoo[2]], levels, CFG)
    seat0, seat1 = _rows(table, "a0", "a0_twin", 0), _rows(table, "a0", "a0_twin", 1)
    assert seat0 == seat1 and len(seat0) == 2 * EPISODES
    # ... and both equal the policy's self-play on the same keys.
    assert seat0 == _rows(table, "a0", "a0", 0)
    # Different policies do not give the same game in both seat orders (the check above can fail).
    assert _rows(table, "a0", "b0", 0) != _rows(table, "a0", "b0", 1)


def _uniform(p: Policy) -> Policy:
    """The same network with a zero policy output layer: uniform logits whatever the other weights."""
    params = {"params": {**p.params["params"]}}
    params["params"]["actor_out"] = jax.tree.map(jnp.zeros_like, params["params"]["actor_out"])
    return Policy(p.name, p.algorithm, p.seed, params, p.network, p.env, p.levels)


def test_common_random_numbers_make_pairings_comparable(zoo, levels):
    # Two different parameter sets with the same (uniform) action distribution: with the same keys on the
    # same level and episode, every pairing of them plays exactly the same episodes.
    u1, u2 = _uniform(zoo[0]), _uniform(_renamed(zoo[2], "b0", 0))
    table = crossplay([u1, u2], levels, CFG)
    games = [_rows(table, "a0", "a0", 0), _rows(table, "a0", "b0", 0), _rows(table, "a0", "b0", 1),
             _rows(table, "b0", "b0", 0)]  # fmt: skip
    assert all(g == games[0] for g in games)
    # Episodes of one pairing differ from one another (different keys per episode and level).
    assert len({v for v in games[0].values()}) > 1
    # Results do not depend on the batch: another zoo order and one game per call give the same rows.
    other = crossplay([zoo[2], zoo[1], zoo[0]], levels, CFG)
    first = crossplay(zoo, levels, _cfg(games_per_call=1))
    assert _rows(other, "b0", "a0", 1) == _rows(first, "a0", "b0", 0)
    assert _rows(other, "b0", "a0", 0) == _rows(first, "a0", "b0", 1)
    # Another seed of the common random numbers gives other episodes.
    reseeded = crossplay(zoo[:1], levels, _cfg(seed=1))
    assert _rows(reseeded, "a0", "a0", 0) != _rows(first, "a0", "a0", 0)


def test_games_involving_some_policies_are_those_games_of_the_whole_lineup(zoo, levels):
    # a line-up that adds one agent to games already played plays only that agent's games, exactly as the
    # whole line-up plays them (the reproduction adds each kitchen's agents to the generalists this way)
    whole = crossplay(zoo, levels, CFG)
    added = crossplay(zoo, levels, CFG, involving={"b0"})
    pairs = set(zip(added.policy_a, added.policy_b, strict=True))
    assert pairs == {("a0", "b0"), ("a1", "b0"), ("b0", "b0")}
    for a, seats in (("a0", (0, 1)), ("a1", (0, 1)), ("b0", (0,))):
        for seat in seats:
            assert _rows(added, a, "b0", seat) == _rows(whole, a, "b0", seat)
    assert plan_games(zoo, levels.names, "all", involving=()) == []


def test_networks_play_each_other_alike_with_and_without_the_cook_in_the_lineup(zoo, levels):
    """The games of two networks play without the scripted kinds (faster: the cook's rollout would run in
    every env of every call); they are the games a line-up without the cook plays, and the cook's games
    are played too, in both seats."""
    from cec.agents.policy import scripted_policy

    cook = scripted_policy("cook", "cook", env=zoo[0].env, algorithm="cook")
    with_cook = crossplay([*zoo[:2], cook], levels, CFG)
    alone = crossplay(zoo[:2], levels, CFG)
    for a, b, seat in (("a0", "a0", 0), ("a0", "a1", 0), ("a0", "a1", 1)):
        assert _rows(with_cook, a, b, seat) == _rows(alone, a, b, seat)
    cooked = [shaped for seat in (0, 1) for _, shaped, _ in _rows(with_cook, "a0", "cook", seat).values()]
    assert len(cooked) == 2 * 2 * EPISODES and max(cooked) > 0  # the cook plays its part (in 24 steps)


def test_dual_destination_greedy_and_deliveries():
    pols = [_policy("p", 0, env=DD_ENV), _policy("q", 1, env=DD_ENV, algorithm="b")]
    table = crossplay(pols, eval_levels("dual_destination", "fixed"), EvalConfig(episodes=3, greedy=True))
    assert set(table.actions) == {"greedy"} and set(table.env) == {"dual_destination"}
    # Greedy play on a fixed task has no randomness left: every episode of a game is the same.
    for a, b, seat in (("p", "p", 0), ("p", "q", 0), ("p", "q", 1)):
        assert len(set(_rows(table, a, b, seat).values())) == 1
    # Deliveries count steps on a goal pair: return = -steps + 3 x goal steps.
    np.testing.assert_allclose(table.returns, -STEPS + 3 * table.deliveries)


def test_level_restrictions_and_incompatible_policies_are_recorded(zoo, levels):
    a0 = zoo[0]
    # a0's twin restricted to Cramped Room (single-task): its games run in a batch of another layout.
    twin = Policy("twin_cr", "ippo", 0, a0.params, a0.network, a0.env, ("cramped_room",))
    # Policies that cannot join (their parameters are never run, only their descriptions checked).
    dd_policy = Policy("dd", "a", 1, a0.params, a0.network, DD_ENV)
    big = Policy("big", "a", 2, a0.params, network_preset("reference", "overcooked"), a0.env)
    nowhere = Policy("nowhere", "a", 3, a0.params, a0.network, a0.env, ("forced_coord",))
    games = plan_games([a0, twin], levels.names)
    assert [g.levels for g in games] == [(0, 1), (0,), (0,), (0,)]  # self a0; a0 x twin both seats; self
    table = crossplay([a0, twin, dd_policy, big, nowhere], levels, CFG)
    assert set(table.level[(table.policy_a == "twin_cr") | (table.policy_b == "twin_cr")]) == {"cramped_room"}
    # Common random numbers do not depend on the batch layout: the twin pairing equals a0's self-play there.
    on_cramped = {k: v for k, v in _rows(table, "a0", "a0", 0).items() if k[0] == "cramped_room"}
    assert _rows(table, "a0", "twin_cr", 0) == on_cramped == _rows(table, "a0", "twin_cr", 1)
    reasons = {s.name: s.reason for s in table.skipped}
    assert set(reasons) == {"dd", "big", "nowhere"}
    assert "dual_destination" in reasons["dd"]
    assert "network" in reasons["big"] and "own run" in reasons["big"]
    assert "forced_coord" in reasons["nowhere"]


def test_agents_with_different_egocentric_frames_play_each_other_as_they_play_alone(levels):
    """An agent trained with a cut egocentric frame (the time-to-skill recipe's) and one with the whole
    frame (the shipped agents and human proxies) play in one evaluation, through the larger frame: the cut
    agent's games with itself are the ones it plays alone (common random numbers, the same policy)."""
    ego = NetworkConfig(conv_features=(), encoder_features=(32,), lstm_features=0, actor_features=(16,),
                        critic_features=(16,), egocentric=True, cell_features=4)  # fmt: skip
    whole = _policy("whole", 5, "a", 0, network=ego)
    cut = _policy("cut", 6, "b", 0, network=dataclasses.replace(ego, egocentric_radius=3))
    table = crossplay([whole, cut], levels, CFG)
    assert not table.skipped and set(table.seat[(table.policy_a == "whole") & (table.policy_b == "cut")]) == {
        0,
        1,
    }
    alone = crossplay([cut], levels, CFG)
    assert _rows(table, "cut", "cut", 0) == _rows(alone, "cut", "cut", 0)
    assert len(set(table.returns)) > 1 or len(set(table.collisions)) > 1  # the games were not all alike


def test_zoo_manifest_errors_name_the_cause(tmp_path):
    ok = parse_zoo({"policies": [{"name": "x", "checkpoint": "c", "seed": 1}]}, tmp_path)
    assert ok[0].checkpoint == str(tmp_path / "c") and ok[0].seed == 1 and ok[0].algorithm is None
    bad = [
        ({"policies": []}, "non-empty list"),
        ([{"name": "x"}], "`checkpoint` is required"),
        ([{"name": "x", "checkpoint": "c", "sede": 1}], "unknown key"),
        ([{"name": "x", "checkpoint": "c"}, {"name": "x", "checkpoint": "d"}], "repeated: ['x']"),
        ([{"name": "x", "checkpoint": "c", "seed": "0"}], "`seed` must be an integer"),
        ({"zoo": []}, "unknown top-level"),
    ]
    for data, message in bad:
        with pytest.raises(ConfigError, match=message.replace("[", r"\[").replace("]", r"\]")):
            parse_zoo(data)
    with pytest.raises(ConfigError, match="does not exist"):
        load_zoo(tmp_path / "nope.yaml")


def test_missing_and_corrupt_checkpoints_are_skipped_with_the_reason(saved_run, tmp_path, levels):
    run_dir, ckpt, state = saved_run
    corrupt = tmp_path / "corrupt"
    shutil.copytree(ckpt, corrupt)
    data = bytearray((corrupt / "state.msgpack").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (corrupt / "state.msgpack").write_bytes(bytes(data))
    manifest = tmp_path / "zoo.yaml"
    manifest.write_text(
        "policies:\n"
        f"  - {{name: good, seed: 5, checkpoint: {run_dir}}}\n"  # a run directory: its latest checkpoint
        f"  - {{name: also_good, algorithm: fcp, seed: 4, checkpoint: {ckpt}}}\n"
        "  - {name: missing, algorithm: cec, seed: 0, checkpoint: no/such/dir}\n"
        "  - {name: corrupt, seed: 4, checkpoint: corrupt}\n"
        f"  - {{name: wrong_seed, seed: 9, checkpoint: {ckpt}}}\n"
        f"  - {{name: ambiguous, checkpoint: {ckpt}}}\n"
        f"  - {{name: stale, seed: 4, checkpoint: {ckpt}, sha256: {'ab' * 32}, env_steps: 0}}\n"
    )
    policies, skipped = load_policies(load_zoo(manifest))
    assert [p.name for p in policies] == ["good", "also_good"]
    assert (policies[0].algorithm, policies[0].seed, policies[1].algorithm) == ("ippo", 5, "fcp")
    for got, want in zip(jax.tree.leaves(policies[0].params), jax.tree.leaves(state.params), strict=True):
        np.testing.assert_array_equal(got, np.asarray(want)[1])  # seed 5 is the checkpoint's second seed
    reasons = {s.name: s.reason for s in skipped}
    assert list(reasons) == ["missing", "corrupt", "wrong_seed", "ambiguous", "stale"]
    assert "not the one the zoo was built with" in reasons["stale"]
    assert "missing" in reasons["missing"] and "corrupt" in reasons["corrupt"]
    assert "not seed 9" in reasons["wrong_seed"] and "give the entry a `seed`" in reasons["ambiguous"]
    assert skipped[0].algorithm == "cec" and skipped[0].seed == 0

    # The skipped entries travel with the results table, through the CSV, never silently dropped.
    table = crossplay(policies, eval_levels("overcooked", "cramped_room"), EvalConfig(episodes=2),
                      skipped=skipped)  # fmt: skip
    assert [s.name for s in table.skipped] == list(reasons)
    back = read_csv(write_csv(table, tmp_path / "results.csv"))
    assert back.skipped == table.skipped and len(back) == len(table) == 4 * 2  # 4 games x 2 episodes
    np.testing.assert_array_equal(back.returns, table.returns)


def test_cec_eval_and_report_commands(saved_run, tmp_path, capsys):
    _, ckpt, _ = saved_run
    manifest = tmp_path / "zoo.json"
    manifest.write_text(json.dumps({"policies": [
        {"name": "s4", "seed": 4, "checkpoint": str(ckpt)},
        {"name": "s5", "seed": 5, "checkpoint": str(ckpt)},
        {"name": "gone", "algorithm": "fcp", "seed": 0, "checkpoint": "gone"},
    ]}))  # fmt: skip
    out = tmp_path / "results.csv"
    code = main(["eval", "--zoo", str(manifest), "--levels", "cramped_room", "--episodes", "2",
                 "--max-steps", "8", "--out", str(out)])  # fmt: skip
    captured = capsys.readouterr()
    assert code == 0, captured.err
    assert "skipping gone" in captured.err and "1 skipped entry" in captured.out
    table = read_csv(out)
    assert len(table) == (2 + 2) * 2 and set(table.episode_steps) == {8}
    assert main(["report", str(out), "--out", str(tmp_path / "rep")]) == 0
    text = (tmp_path / "rep" / "report.md").read_text()
    assert "## Skipped zoo entries" in text and "| gone | fcp | 0 |" in text
    assert (tmp_path / "rep" / "seed_matrices_classic.png").stat().st_size > 1000
    # Bad input is one clear line and exit status 2.
    assert main(["eval", "--zoo", str(tmp_path / "none.yaml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert main(["report", str(tmp_path / "none.csv")]) == 2
    assert "cec eval" in capsys.readouterr().err


def test_eval_config_and_level_sets_are_checked():
    with pytest.raises(ConfigError, match="episodes"):
        EvalConfig(episodes=0)
    with pytest.raises(ConfigError, match="pairs"):
        EvalConfig(pairs="some")
    with pytest.raises(ConfigError, match="unknown Overcooked level 'nowhere'"):
        eval_levels("overcooked", "cramped_room,nowhere")
    held = eval_levels("overcooked", "heldout")
    assert (
        len(held.names) == 105 and held.names[:5] == tuple(CLASSIC_ASCII) and held.names[5] == "generated_000"
    )
    assert jax.tree.leaves(held.levels)[0].shape[0] == 105
    assert eval_levels("overcooked", "classic,cramped_room").names == tuple(CLASSIC_ASCII)  # no repeats
    assert eval_levels("dual_destination", "fixed,multi_task").names == ("fixed", "multi_task")
