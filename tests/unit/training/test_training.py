"""The rollout, the update step and the single-process trainer: shapes, resets, resume, checkpoints."""

import io
import json
import shutil
import subprocess
import sys

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec import checkpoints
from cec.config import ConfigError, from_dict
from cec.training.config import TrainConfig
from cec.training.ppo import make_batch
from cec.training.rollout import rollout
from cec.training.run import MetricsWriter, config_dict, train, trains_as
from cec.training.trainer import Trainer


def _config(tmp_path, **over):
    base = {
        "algorithm": "ippo",
        "num_envs": 4,
        "num_steps": 12,
        "total_env_steps": 4 * 12 * 4,
        "updates_per_call": 1,
        "network": "small",
        "env": {"name": "overcooked", "levels": "cramped_room", "overcooked": {"max_steps": 10}},
        "run_dir": str(tmp_path),
        "name": "run",
        "checkpoint": {"every_updates": 1, "keep_last": 2, "milestones": [0.0, 0.5, 1.0]},
    }
    for key, value in over.items():
        base[key] = {**base.get(key, {}), **value} if isinstance(value, dict) else value
    return from_dict(TrainConfig, base)


def _tree_equal(a, b):
    return all(np.array_equal(x, y) for x, y in zip(jax.tree.leaves(a), jax.tree.leaves(b), strict=True))


def _cramped_room_rollout(tmp_path):
    """(trainer, seed 0's state, carry after, trajectory) of one rollout of 5-step Cramped Room episodes."""
    cfg = _config(
        tmp_path, env={"name": "overcooked", "levels": "cramped_room", "overcooked": {"max_steps": 5}}
    )
    tr = Trainer(cfg)
    state = jax.tree.map(lambda x: x[0], tr.init())
    levels = tr.task.sample_levels(jax.random.PRNGKey(1), jnp.arange(cfg.num_envs), cfg.levels_per_env)
    carry, traj = jax.jit(
        lambda p, c, lv, k: rollout(
            p, c, lv, k, task=tr.task, network=tr.network, env_params=tr.env_params, num_steps=cfg.num_steps
        )
    )(state.params, state.carry, levels, state.key)
    return tr, state, carry, traj


def test_rollout_and_update_shapes(tmp_path):
    tr, state, carry, traj = _cramped_room_rollout(tmp_path)
    cfg = tr.config
    t, e, h = cfg.num_steps, cfg.num_envs, 64
    assert traj.obs.shape == (t, e, 2, 9, 9, 26) and traj.obs.dtype == jnp.uint8
    assert traj.action.shape == traj.log_prob.shape == traj.value.shape == traj.shaped.shape == (t, e, 2)
    assert traj.reward.shape == traj.done.shape == traj.first.shape == (t, e)
    assert traj.init_lstm.h.shape == (e, 2, h) and traj.last_value.shape == (e, 2)
    # 5-step episodes: done every 5th step, and the next observation is flagged as an episode start.
    np.testing.assert_array_equal(np.asarray(traj.done[:, 0]), [(i + 1) % 5 == 0 for i in range(t)])
    np.testing.assert_array_equal(np.asarray(traj.first[1:]), np.asarray(traj.done[:-1]))
    assert bool(traj.first[0].all())  # fresh envs start with a reset
    # Episode returns are reported exactly where episodes end.
    assert np.all(np.asarray(traj.episode_return)[~np.asarray(traj.done)] == 0)
    # The carry continues: the next rollout starts from the last observation.
    assert carry.first.shape == (e,) and bool(jnp.all(carry.first == traj.done[-1]))
    batch = make_batch(traj, jnp.float32(1.0), 0.99, 0.95)
    assert batch.obs.shape == (t, 2 * e, 9, 9, 26) and batch.advantage.shape == (t, 2 * e)
    new_state, metrics = jax.jit(tr.update_step)(state)
    assert int(new_state.update) == 1
    assert np.isfinite(float(metrics.loss.total_loss)) and float(metrics.episodes) >= 0
    assert not _tree_equal(new_state.params, state.params)


def test_team_shaping_pays_the_seat_whose_item_its_partner_used(tmp_path):
    _, _, _, traj = _cramped_room_rollout(tmp_path)
    # no team reward, zero values; at step 2 of env 0 seat 0 earns a shaped 3 (it put an onion in the pot)
    shaped = np.zeros(traj.shaped.shape, np.float32)
    shaped[2, 0, 0] = 3.0
    traj = traj._replace(
        reward=jnp.zeros_like(traj.reward), shaped=jnp.asarray(shaped),
        value=jnp.zeros_like(traj.value), last_value=jnp.zeros_like(traj.last_value),
    )  # fmt: skip
    t, e = traj.reward.shape
    own, team = (
        np.asarray(make_batch(traj, jnp.float32(1.0), 0.99, 0.95, team_shaping=x).target).reshape(t, e, 2)
        for x in (False, True)
    )
    # the paper's own shaping pays only seat 0, at and before the step; the team's pays both the same
    assert own[0, 0, 0] > 0 and np.all(own[:, :, 1] == 0)
    np.testing.assert_allclose(team[:, 0, 1], team[:, 0, 0])
    np.testing.assert_allclose(team[:, :, 0], own[:, :, 0])
    assert np.all(team[:, 1:] == 0)  # other envs untouched
    # halved by the schedule's weight like the own shaping
    half = make_batch(traj, jnp.float32(0.5), 0.99, 0.95, team_shaping=True).target
    np.testing.assert_allclose(np.asarray(half).reshape(t, e, 2), team / 2, rtol=1e-6)


@pytest.mark.parametrize("repeats", [1, 3])
def test_level_repeats_replays_each_kitchen_that_many_episodes(tmp_path, repeats):
    # one 10-step episode per rollout: the kitchen of rollout u+1 is the one its env reset to in rollout u
    cfg = _config(
        tmp_path, algorithm="cec", num_steps=10, level_repeats=repeats,
        env={"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": 10}},
    )  # fmt: skip
    tr = Trainer(cfg)
    state = jax.tree.map(lambda x: x[0], tr.init())
    step = jax.jit(tr.update_step)
    played = []  # [rollout][env] the kitchen's grid
    for _ in range(7):
        played.append(np.asarray(state.carry.env_state.level.grid))
        state, _ = step(state)
    same = [np.all(played[u] == played[u + 1], axis=(1, 2)) for u in range(6)]  # per env, u -> u+1
    for u, kept in enumerate(same):
        # rollouts 1-3 play the kitchens drawn at update 0, 4-6 those of update 3; without repeats
        # every rollout a fresh one (a generated kitchen repeats by chance almost never)
        expect = repeats == 3 and (u + 1) % 3 != 1
        assert kept.all() if expect else not kept.any(), (u, kept)


def test_seeds_are_independent_and_reproducible(tmp_path):
    cfg = _config(tmp_path, num_seeds=2)
    tr = Trainer(cfg)
    a = tr.init()
    b = tr.init()
    assert _tree_equal(a, b)
    assert not np.array_equal(a.params["params"]["fc0"]["kernel"][0], a.params["params"]["fc0"]["kernel"][1])
    # Seed 1 of a two-seed run equals seed 0 of a run with seed=1.
    single = Trainer(_config(tmp_path, seed=1)).init()
    assert _tree_equal(jax.tree.map(lambda x: x[1], a.params), jax.tree.map(lambda x: x[0], single.params))


def test_interrupted_and_resumed_run_is_bit_exact(tmp_path):
    full = train(_config(tmp_path / "a"), progress=False)
    assert full.updates_done == 4
    first = train(_config(tmp_path / "b"), max_updates=2, progress=False)
    assert first.updates_done == 2 and not first.interrupted
    resumed = train(_config(tmp_path / "b"), resume=True, progress=False)
    assert resumed.updates_done == 4
    assert _tree_equal(full.state, resumed.state)
    rows = [json.loads(line) for line in (tmp_path / "b" / "run" / "metrics.jsonl").read_text().splitlines()]
    assert [r["update"] for r in rows] == [1, 2, 3, 4]
    rows_full = [
        json.loads(line) for line in (tmp_path / "a" / "run" / "metrics.jsonl").read_text().splitlines()
    ]
    assert [r["total_loss"] for r in rows] == [r["total_loss"] for r in rows_full]


def test_checkpoints_keep_last_n_plus_milestones(tmp_path):
    cfg = _config(tmp_path, checkpoint={"keep_last": 1})
    train(cfg, progress=False)
    store = checkpoints.CheckpointStore(tmp_path / "run", keep_last=1)
    saved = {c.update: c.milestone for c in store.list()}
    assert saved == {0: True, 2: True, 3: False, 4: True}  # update 1 pruned; milestones 0, 2, 4 kept
    meta = checkpoints.read_meta(store.path(4))
    assert meta["metadata"]["algorithm"] == "ippo" and meta["config"]["num_envs"] == 4
    assert meta["env_steps"] == 4 * cfg.steps_per_update
    with pytest.raises(checkpoints.CheckpointError, match="already has checkpoints.*name=NEW"):
        train(cfg, progress=False)


def test_corrupt_or_mismatched_checkpoints_are_refused(tmp_path):
    cfg = _config(tmp_path, total_env_steps=4 * 12)
    train(cfg, progress=False)
    path = checkpoints.CheckpointStore(tmp_path / "run", 2).latest().path
    template = Trainer(cfg).state_template()
    state, meta = checkpoints.load(path, template)
    assert meta["update"] == 1

    other = Trainer(_config(tmp_path, num_envs=6, name="other")).state_template()
    with pytest.raises(checkpoints.CheckpointError, match="does not fit this run"):
        checkpoints.load(path, other)

    corrupt = tmp_path / "corrupt"
    shutil.copytree(path, corrupt)
    data = bytearray((corrupt / "state.msgpack").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (corrupt / "state.msgpack").write_bytes(bytes(data))
    with pytest.raises(checkpoints.CheckpointError, match="corrupt"):
        checkpoints.load(corrupt, template)
    (corrupt / "meta.json").write_text("{not json")
    with pytest.raises(checkpoints.CheckpointError, match="corrupt"):
        checkpoints.load(corrupt, template)


@pytest.mark.parametrize(
    "change",
    [
        lambda m: [m],  # a list
        lambda m: "update 3",  # a string
        lambda m: {k: v for k, v in m.items() if k != "sha256"},
        lambda m: {**m, "sha256": None},
        lambda m: {**m, "sha256": "ab" * 20},
        lambda m: {**m, "update": None},
        lambda m: {**m, "update": 10**30},
        lambda m: {**m, "update": -1},
        lambda m: {**m, "update": True},
        lambda m: {**m, "env_steps": 1.5},
        lambda m: {**m, "milestone": "yes"},
        lambda m: {k: v for k, v in m.items() if k != "config"},
        lambda m: {**m, "metadata": None},
    ],
)
def test_malformed_checkpoint_metadata_is_refused_with_its_cause(tmp_path, change):
    state = {"w": np.arange(3, dtype=np.float32)}
    store = checkpoints.CheckpointStore(tmp_path, keep_last=1)
    path = checkpoints.save(store.path(3), state, update=3, env_steps=30, config={}, metadata={})
    assert [c.update for c in store.list()] == [3]
    meta = json.loads((path / "meta.json").read_text())
    (path / "meta.json").write_text(json.dumps(change(meta)))
    with pytest.raises(checkpoints.CheckpointError, match="meta.json|format"):
        checkpoints.load(path, state)
    assert store.list() == []  # never offered as a checkpoint to resume from


def test_resume_passes_over_a_damaged_newest_checkpoint_and_says_so(tmp_path):
    cfg = _config(tmp_path, checkpoint={"keep_last": 5}, total_env_steps=4 * 12 * 3)
    train(cfg, progress=False)
    store = checkpoints.CheckpointStore(tmp_path / "run", keep_last=5)
    newest = store.path(3)

    def flip_a_state_byte() -> None:
        data = bytearray((newest / "state.msgpack").read_bytes())
        data[-1] ^= 0xFF
        (newest / "state.msgpack").write_bytes(bytes(data))

    def truncate_meta() -> None:
        (newest / "meta.json").write_text('{"format": "cec-checkpoint/1", "update": 3')

    for damage in (flip_a_state_byte, truncate_meta):
        damage()
        with pytest.raises(checkpoints.CheckpointError, match="already has checkpoints"):
            train(cfg, progress=False)  # a damaged checkpoint still marks the run as started
        log = io.StringIO()
        result = train(cfg, resume=True, progress=False, log=log)
        text = log.getvalue()
        assert "warning: passing over a damaged checkpoint: checkpoint" in text and newest.name in text
        assert "from update 2 (update_000000002)" in text
        assert result.updates_done == 3 and checkpoints.read_meta(newest)["update"] == 3  # redone

    for path in store.directories():  # nothing loadable: refused, naming every damaged one
        (path / "meta.json").write_text("[]")
    with pytest.raises(checkpoints.CorruptCheckpointError, match="no checkpoint of .* can be loaded"):
        train(cfg, resume=True, progress=False, log=io.StringIO())


def test_a_resumed_runs_metrics_keep_their_csv_columns_when_a_newer_version_adds_one(tmp_path):
    """A run started before a metric existed and resumed after: its CSV stays aligned to its own header
    (the new metric is in the JSONL only)."""
    import csv

    writer = MetricsWriter(tmp_path)
    writer.write([{"update": 1, "total_loss": 0.5, "grad_norm": 2.0}])
    writer.write([{"update": 2, "total_loss": 0.4, "teacher_loss": 1.7, "grad_norm": 1.5}])
    with open(tmp_path / "metrics.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert list(rows[0]) == ["update", "total_loss", "grad_norm"]
    assert rows[1] == {"update": "2", "total_loss": "0.4", "grad_norm": "1.5"}
    assert json.loads((tmp_path / "metrics.jsonl").read_text().splitlines()[1])["teacher_loss"] == 1.7


def test_resume_refuses_a_changed_config(tmp_path):
    train(_config(tmp_path, total_env_steps=4 * 12), progress=False)
    with pytest.raises(checkpoints.CheckpointError, match="different config"):
        train(_config(tmp_path, total_env_steps=4 * 12, ppo={"lr": 1e-3}), resume=True, progress=False)


def test_saving_more_often_resumes_the_same_run_but_other_milestones_or_settings_do_not(tmp_path):
    """A long run may be given periodic checkpoints mid-way; its milestones (FCP's partners) must stay."""
    written = config_dict(_config(tmp_path))
    assert trains_as(written, _config(tmp_path, checkpoint={"every_updates": 50, "keep_last": 9}))
    assert not trains_as(written, _config(tmp_path, checkpoint={"milestones": [0.0, 1.0]}))
    assert not trains_as(written, _config(tmp_path, ppo={"lr": 1e-3}))
    assert trains_as(written, _config(tmp_path / "moved"))  # where it lies is not what it trains
    # written before a setting existed (here the region channels): the same run, resumable after an update
    net = {"conv_features": [], "encoder_features": [32], "lstm_features": 0, "actor_features": [16],
           "critic_features": [16]}  # fmt: skip
    written = config_dict(_config(tmp_path, network_overrides=net))
    assert "region_channels" in written["network_overrides"]
    older = dict(written, network_overrides=net)
    assert trains_as(older, _config(tmp_path, network_overrides=net))
    assert not trains_as(older, _config(tmp_path, network_overrides={**net, "region_channels": True}))
    assert not trains_as(dict(written, retired_setting=1), _config(tmp_path, network_overrides=net))


def test_a_run_trained_by_another_process_is_refused_until_that_process_ends(tmp_path):
    """Two trainers never write the same run directory; a killed holder leaves no stale lock."""
    cfg = _config(tmp_path, total_env_steps=4 * 12)
    run_dir = tmp_path / cfg.run_name
    hold = f"from cec import checkpoints; checkpoints.RunLock({str(run_dir)!r}).acquire(); print('held')"
    holder = subprocess.Popen(
        [sys.executable, "-c", hold + "; import sys, time; sys.stdout.flush(); time.sleep(600)"],
        stdout=subprocess.PIPE,
        text=True,
    )
    try:
        assert holder.stdout is not None and holder.stdout.readline().strip() == "held"
        with pytest.raises(checkpoints.RunBusyError, match=rf"another process \(pid {holder.pid}\)"):
            train(cfg, progress=False)
        assert not (run_dir / "checkpoints").exists()  # refused before any work
    finally:
        holder.kill()
        holder.wait()
    train(cfg, progress=False)  # the kernel dropped the killed holder's lock
    train(cfg, resume=True, progress=False)  # and train released its own when it returned


@pytest.mark.parametrize(
    ("over", "message"),
    [
        ({"algorithm": "cec"}, "procedural"),
        ({"algorithm": "ippo", "env": {"name": "overcooked", "levels": "generator"}}, "one fixed level"),
        ({"env": {"name": "overcooked", "levels": "kitchen_9"}}, "not valid"),
        ({"num_envs": 3, "ppo": {"num_minibatches": 4}}, "split evenly"),
        ({"network": "huge"}, "unknown network preset"),
        ({"level_repeats": 0}, "level_repeats must be >= 1"),
        ({"level_repeats": 4}, "one fixed level: leave level_repeats at 1"),
        ({"env": {"name": "dual_destination", "levels": "multi_task"}}, "multi_task=true"),
    ],
)
def test_bad_configs_fail_before_any_work(tmp_path, over, message):
    with pytest.raises(ConfigError, match=message):
        _config(tmp_path, **over)


@pytest.mark.slow
def test_cec_and_dual_destination_tasks_train(tmp_path):
    cec = _config(tmp_path, algorithm="cec", name="cec", env={"name": "overcooked", "levels": "generator"})
    assert train(cec, progress=False).updates_done == 4
    dd = _config(
        tmp_path,
        algorithm="cec",
        name="dd",
        env={"name": "dual_destination", "levels": "procedural", "dual_destination": {"max_steps": 10}},
    )
    result = train(dd, progress=False)
    rows = [json.loads(line) for line in (result.run_dir / "metrics.jsonl").read_text().splitlines()]
    assert rows[-1]["episodes"] == 4 and rows[-1]["normalised_return"] == rows[-1]["mean_return"] / 20
