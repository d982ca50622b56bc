"""The evaluator service against a real `redis-server` (LocalRedis): in-process and as a real process.

Checkpoints are real `cec.checkpoints` directories of `small`-preset Overcooked networks at a random init
(numpy draws into the trainer's state template: no training, no init compile). The zoo is two of them
(labels `ippo` and `fcp`, one partner group each); the scored runs hold two seeds per checkpoint. Episodes
are 16 steps, 1 per pairing and level, on level sets of one level each (in-process: one compilation serves
every test) or of two and three levels (the service).
"""

from __future__ import annotations

import dataclasses
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
import urllib.request
import uuid
from pathlib import Path

import jax
import numpy as np
import pytest
from prometheus_client import REGISTRY
from prometheus_client.parser import text_string_to_metric_families

from apps.cli import main as cec_main
from cec import checkpoints
from cec.config import ConfigError, from_dict, load_config
from cec.evaluation.analysis import policies_of
from cec.evaluation.checkpoint_results import summarize
from cec.evaluation.crossplay import EvalConfig
from cec.evaluation.results import make_table, read_csv
from cec.training.config import TrainConfig
from cec.training.run import config_dict
from cec.training.trainer import Trainer
from services.evaluator.config import EvaluatorConfig, LevelSetConfig, PartnerGroupConfig
from services.evaluator.evaluator import FAILED_GROUP, TRACKED_METRICS, Evaluator
from services.store import CheckpointEvent, CheckpointMessage, ControlPlane, LocalRedis, PartnerRecord

pytestmark = pytest.mark.skipif(
    shutil.which("redis-server") is None, reason="needs redis-server (sudo apt-get install redis-server)"
)
ROOT = Path(__file__).resolve().parents[2]
STEPS = 16
CLASSIC = LevelSetConfig("classic", levels="cramped_room")
HELDOUT = LevelSetConfig("heldout", levels="generated", max_levels=1)
GROUPS = ("self_play", "cross_play", "ippo", "fcp")


# --- checkpoints -------------------------------------------------------------------------------------------


class Checkpoints:
    """Writes real checkpoints of a tiny `small` Overcooked run with random parameters."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self._templates: dict[int, object] = {}

    def config(self, num_seeds: int, name: str, tracking: dict | None = None) -> TrainConfig:
        return from_dict(TrainConfig, {
            "algorithm": "cec", "num_seeds": num_seeds, "num_envs": 2, "num_steps": 8, "total_env_steps": 16,
            "network": "small", "run_dir": str(self.root),  "name": name, "tracking": tracking or {},
            "env": {"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": STEPS}},
        })  # fmt: skip

    def write(
        self, run: str, update: int, seeds: list[int], label: str = "cec", tracking: dict | None = None
    ) -> Path:
        config = self.config(len(seeds), run, tracking)
        if len(seeds) not in self._templates:
            self._templates[len(seeds)] = Trainer(config).state_template()
        template = self._templates[len(seeds)]
        rng = np.random.default_rng([update, *seeds, len(run)])
        state = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), template)
        params = jax.tree.map(lambda s: rng.normal(0.0, 0.5, s.shape).astype(s.dtype), template.params)
        return checkpoints.CheckpointStore(self.root / run, keep_last=100).save(
            state._replace(params=params),
            update=update,
            env_steps=update * 16,
            config=config_dict(config),
            metadata={"algorithm": label, "seeds": seeds},
            milestone=False,
        )


@pytest.fixture(scope="module")
def ckpts(tmp_path_factory):
    return Checkpoints(tmp_path_factory.mktemp("runs"))


@pytest.fixture(scope="module")
def zoo(ckpts):
    """A manifest of two partners: ippo seed 5 and fcp seed 7."""
    ippo = ckpts.write("zoo-ippo", 10, [5], "ippo")
    fcp = ckpts.write("zoo-fcp", 10, [7], "fcp")
    path = ckpts.root / "zoo.yaml"
    path.write_text(
        f"policies:\n  - {{name: ippo_s5, checkpoint: {ippo}}}\n  - {{name: fcp_s7, checkpoint: {fcp}}}\n"
    )
    return path


@pytest.fixture
def plane(redis_config):
    with ControlPlane.connect(redis_config) as p:
        yield p


def _config(plane: ControlPlane, zoo: Path, results: Path, **kw) -> EvaluatorConfig:
    base = dict(
        store=plane.config, zoo=str(zoo), redis_zoo=False, level_sets=(CLASSIC, HELDOUT),
        play=EvalConfig(episodes=1, max_steps=STEPS, games_per_call=1), results_dir=str(results),
        metrics_port=-1, poll_s=0.2, zoo_algorithms=(),
    )  # fmt: skip
    return EvaluatorConfig(**{**base, **kw})


def _publish(plane: ControlPlane, path: Path, run: str) -> CheckpointEvent:
    event = CheckpointEvent.from_checkpoint(path, run)
    assert plane.publish_checkpoint(event).outcome == "published"
    return event


def _counter(name: str) -> float:
    return REGISTRY.get_sample_value(name) or 0.0


def _episode_keys(table) -> list[tuple]:
    return list(zip(table.policy_a, table.policy_b, table.level, table.seat, table.episode, strict=True))


def _expected_rows(seeds: int, partners: int, levels: int, episodes: int = 1) -> int:
    """Episodes in one checkpoint's table on one level set: self-play, both seats with each other seed
    (cross-play within the checkpoint), then both seats with each partner."""
    return seeds * (1 + (seeds - 1) + 2 * partners) * levels * episodes


# --- configuration and pure logic --------------------------------------------------------------------------


def test_config_is_strict_and_the_shipped_preset_is_the_default():
    assert load_config(EvaluatorConfig, ROOT / "configs/evaluator.yaml") == EvaluatorConfig()
    cfg = load_config(EvaluatorConfig, None, [
        "store.url=redis://10.0.0.2:6379/0", "results_dir=/data/runs", "metrics_port=0",
        "level_sets=[{name: classic, levels: classic}, {name: heldout, levels: generated, max_levels: 5}]",
        "groups=[{name: population, partners: [fcp_s0, fcp_s1]}]",
    ])  # fmt: skip
    assert cfg.store.url == "redis://10.0.0.2:6379/0" and cfg.results_dir == "/data/runs"
    assert cfg.level_sets[1] == LevelSetConfig("heldout", "overcooked", "generated", 5)
    assert cfg.groups == (PartnerGroupConfig("population", ("fcp_s0", "fcp_s1")),)
    assert [s.name for s in cfg.level_sets_of("dual_destination")] == []
    for overrides, message in [
        (["zooo=x"], "did you mean 'zoo'"),
        (["store.urll=redis://x:1/0"], "unknown key 'store.urll'"),
        (["group_by=seed"], "group_by"),
        (["level_sets=[]"], "level_sets is empty"),
        (["level_sets=[{name: a b}]"], "level set name 'a b'"),
        (["level_sets=[{name: x, env: chess}]"], "env 'chess' is unknown"),
        (["level_sets=[{name: x}, {name: x}]"], "unique"),
        (["groups=[{name: self_play, partners: [a]}]"], "reserved"),
        (["groups=[{name: g, partners: [a]}, {name: h, partners: [a]}]"], "more than one partner group"),
        (["play.episodes=0"], "episodes"),
        (["metrics_port=70000"], "metrics_port"),
    ]:
        with pytest.raises(ConfigError, match=message):
            load_config(EvaluatorConfig, None, overrides)


def test_summary_aggregates_pairs_like_the_report():
    """Per pair and level: episodes then seat orders averaged; per pair: levels; then pairs."""
    rows = []
    # (seed of the checkpoint, level, seat, return) with partner p, ippo seed 5.
    data = [(0, "a", 0, 2.0), (0, "a", 1, 4.0), (0, "b", 0, 10.0), (0, "b", 1, 10.0),
            (1, "a", 0, 0.0), (1, "a", 1, 0.0), (1, "b", 0, 6.0), (1, "b", 1, 6.0)]  # fmt: skip
    for seed, level, seat, ret in data:
        rows.append(dict(policy_a=f"r/s{seed}", algorithm_a="r@1", seed_a=seed, policy_b="p",
                         algorithm_b="ippo", seed_b=5, level=level, seat=seat, episode=0, returns=ret,
                         deliveries=ret / 20, collisions=1.0, shaped_return=3.0, env="overcooked",
                         episode_steps=STEPS, actions="sampled"))  # fmt: skip
    table = make_table({k: [r[k] for r in rows] for k in rows[0]})
    out = summarize(table, "r@1")
    # seed 0: level a (2+4)/2 = 3, level b 10 -> 6.5; seed 1: level a 0, level b 6 -> 3.
    assert out["per_seed"] == {"0": 6.5, "1": 3.0} and out["return_mean"] == 4.75
    assert out["pairs"] == 2 and out["return_sem"] == pytest.approx(1.75)
    assert out["per_partner"] == {"ippo/s5": 4.75} and out["partners"] == ["p"]
    # a second partner: the standard error is over the seeds (the units), not over their shared pairs
    more = [dict(r, policy_b="q", seed_b=6, returns=r["returns"] + 1.0) for r in rows]
    two = summarize(make_table({k: [r[k] for r in rows + more] for k in rows[0]}), "r@1")
    assert two["pairs"] == 4 and two["per_seed"] == {"0": 7.0, "1": 3.5}
    assert two["return_sem"] == pytest.approx(1.75)  # sem of (7.0, 3.5); over the 4 pairs it would be ~1.0
    assert out["episodes"] == 8 and out["levels"] == ["a", "b"] and out["collisions_mean"] == 1.0
    assert out["deliveries_mean"] == pytest.approx(4.75 / 20) and out["episode_steps"] == STEPS
    empty = summarize(table.select(np.zeros(len(table), bool)), "r@1")
    assert empty["episodes"] == 0 and empty["return_mean"] is None and empty["pairs"] == 0


def test_cross_play_within_a_checkpoint_is_the_mean_over_pairs_of_different_seeds_with_the_jackknife():
    """Three seeds of one checkpoint, each pair on one level, both seats: pair (0, 1) scores 10, (0, 2) 4,
    (1, 2) 7; self-play rows, if present, are not cross-play."""
    pair = {(0, 1): 10.0, (0, 2): 4.0, (1, 2): 7.0}
    rows = []
    for (i, j), ret in pair.items():
        for seat in (0, 1):
            rows.append(dict(policy_a=f"r/s{i}", algorithm_a="r@1", seed_a=i, policy_b=f"r/s{j}",
                             algorithm_b="r@1", seed_b=j, level="a", seat=seat, episode=0, returns=ret,
                             deliveries=ret / 20, collisions=0.0, shaped_return=0.0, env="overcooked",
                             episode_steps=STEPS, actions="sampled"))  # fmt: skip
    table = make_table({k: [r[k] for r in rows] for k in rows[0]})
    out = summarize(table, "r@1", kind="cross_play")
    assert out["return_mean"] == pytest.approx(7.0) and out["pairs"] == 6  # each ordered pair of seeds
    assert out["per_seed"] == {"0": 7.0, "1": 8.5, "2": 5.5} and out["per_partner"] == {}
    # leaving one seed out leaves one pair: 7, 4, 10 -> jackknife SE sqrt(2/3 * 18) = sqrt(12)
    assert out["return_sem"] == pytest.approx(12**0.5)
    two = summarize(table.select(np.isin(table.seed_a, [0, 1]) & np.isin(table.seed_b, [0, 1])), "r@1",
                    kind="cross_play")  # fmt: skip
    assert two["return_mean"] == 10.0 and two["return_sem"] is None  # the jackknife needs three seeds
    with pytest.raises(ValueError, match="kind"):
        summarize(table, "r@1", kind="everyone")


# --- the Evaluator object ----------------------------------------------------------------------------------


class StopWhenStored(threading.Event):
    """A stop request that raises itself once `n` results of `checkpoint_id` are in Redis (so a test can
    stop the evaluator between two parts without racing it)."""

    def __init__(self, plane: ControlPlane, checkpoint_id: str, n: int) -> None:
        super().__init__()
        self.plane, self.checkpoint_id, self.n = plane, checkpoint_id, n

    def is_set(self) -> bool:
        return super().is_set() or len(self.plane.get_results(self.checkpoint_id)) >= self.n


def test_a_stopped_evaluator_resumes_without_rescoring_and_redelivery_is_idempotent(
    plane, ckpts, zoo, tmp_path
):
    path = ckpts.write("cec-resume", 1, [0, 1])
    event = _publish(plane, path, "cec-resume")
    cid = event.checkpoint_id
    config = _config(plane, zoo, tmp_path / "results")
    scored = _counter("cec_evaluator_checkpoints_scored_total")

    # A first evaluator is stopped once the classic parts are stored: it abandons the checkpoint.
    with Evaluator(config, plane) as first:
        [outcome] = first.poll_once(stop=StopWhenStored(plane, cid, len(GROUPS)))
    assert outcome.status == "abandoned" and not plane.is_scored(cid)
    before = {(r.partner_group, r.level_set): r.written_at for r in plane.get_results(cid)}
    assert set(before) == {(g, "classic") for g in GROUPS}
    assert first.consumer.pending_count() == 1  # not acknowledged: it will be delivered again

    # A restart (same consumer name) gets the event back at once and plays only the missing parts.
    with Evaluator(config, plane) as second:
        [outcome] = second.poll_once(block_s=0.1)
        assert outcome.status == "scored"
        assert set(outcome.reused) == {f"{g}|classic" for g in GROUPS}
        assert set(outcome.computed) == {f"{g}|heldout" for g in GROUPS}
        results = {(r.partner_group, r.level_set): r for r in plane.get_results(cid)}
        assert set(results) == {(g, s) for g in GROUPS for s in ("classic", "heldout")}
        assert all(results[k].written_at == t for k, t in before.items())  # stored parts untouched
        assert results[("ippo", "heldout")].metrics["partners"] == ["ippo_s5"]
        assert results[("self_play", "classic")].metrics["per_seed"].keys() == {"0", "1"}
        assert second.consumer.pending_count() == 0 and plane.is_scored(cid)
        assert _counter("cec_evaluator_checkpoints_scored_total") == scored + 1

        # Redelivery of the same event (a crash after scoring, before the ack): nothing is played again.
        again = second.handle(CheckpointMessage("0-1", event, redelivered=True))
        assert again.status == "already_scored" and again.computed == ()
        assert plane.publish_checkpoint(event).outcome == "duplicate"
        assert second.poll_once(block_s=0.1) == []
    assert _counter("cec_evaluator_checkpoints_scored_total") == scored + 1
    assert {(r.partner_group, r.level_set): r.written_at for r in plane.get_results(cid)} == {
        k: r.written_at for k, r in results.items()
    }

    # The table in the run directory: every episode once, readable by the analyses of `cec report`.
    table = read_csv(tmp_path / "results" / "cec-resume" / "eval" / "update_000000001.csv")
    keys = _episode_keys(table)
    assert len(keys) == len(set(keys)) == 2 * _expected_rows(seeds=2, partners=2, levels=1)
    assert len(policies_of(table)) == 4 and set(table.algorithm_a) == {"cec-resume@1"}
    assert not (tmp_path / "results" / "cec-resume" / "eval" / ".parts").exists()

    # Common random numbers: an uninterrupted scoring elsewhere produces exactly the same episodes.
    store = dataclasses.replace(plane.config, key_prefix=plane.config.key_prefix + "b")
    other = _config(plane, zoo, tmp_path / "other", store=store)
    with Evaluator(other) as fresh:
        assert fresh.score(event).status == "scored"
    table2 = read_csv(tmp_path / "other" / "cec-resume" / "eval" / "update_000000001.csv")
    order = np.lexsort((table.episode, table.seat, table.level, table.policy_b))
    order2 = np.lexsort((table2.episode, table2.seat, table2.level, table2.policy_b))
    for column in ("returns", "shaped_return", "collisions"):
        np.testing.assert_array_equal(getattr(table, column)[order], getattr(table2, column)[order2])
    assert len(set(table.collisions.tolist())) > 1  # the episodes differ: the comparison is not vacuous


def test_bad_checkpoints_are_recorded_and_do_not_stop_the_stream(plane, ckpts, zoo, tmp_path):
    good = ckpts.write("cec-bad", 4, [0])
    corrupt = ckpts.write("cec-bad", 1, [0])
    data = bytearray((corrupt / "state.msgpack").read_bytes())
    data[len(data) // 2] ^= 0xFF
    (corrupt / "state.msgpack").write_bytes(bytes(data))
    gone = ckpts.write("cec-bad", 2, [0])
    replaced = ckpts.write("cec-bad", 3, [0])
    events = [_publish(plane, p, "cec-bad") for p in (corrupt, gone, replaced, good)]
    shutil.rmtree(gone)  # deleted by keep-last-N before the evaluator got to it
    ckpts.write("cec-bad", 3, [1])  # the same update written again after the event (other state)
    failures = _counter("cec_evaluator_failures_total")

    config = _config(plane, zoo, tmp_path / "results", level_sets=(CLASSIC,))
    stop = threading.Event()
    with Evaluator(config, plane) as ev:
        outcomes = []
        while len(outcomes) < 4:
            outcomes += ev.poll_once(block_s=0.5, stop=stop)
        assert ev.consumer.pending_count() == 0  # every event acknowledged
    assert [o.status for o in outcomes] == ["failed", "failed", "failed", "scored"]
    assert _counter("cec_evaluator_failures_total") == failures + 3
    reasons = [o.error for o in outcomes[:3]]
    assert "corrupt" in reasons[0] and "missing" in reasons[1] and "replaced after its event" in reasons[2]
    for event, reason in zip(events[:3], reasons, strict=True):
        [result] = plane.get_results(event.checkpoint_id)
        assert (result.partner_group, result.metrics["error"]) == (FAILED_GROUP, reason)
        assert not plane.is_scored(event.checkpoint_id)
    assert plane.is_scored(events[3].checkpoint_id)
    groups = {r.partner_group for r in plane.get_results(events[3].checkpoint_id)}
    assert groups == set(GROUPS) - {"cross_play"}  # one seed: no other seed of its own to play with


def test_partner_groups_redis_zoo_skipped_partners_and_the_run_filter(plane, ckpts, zoo, tmp_path):
    path = ckpts.write("cec-groups", 1, [3])
    single = ckpts.write("zoo-ippo-cramped", 10, [9], "ippo")
    # a human proxy of one kitchen (as `cec humans bc` writes them): its own partner group
    proxy = ckpts.write("zoo-hp", 10, [0], "human_proxy")
    manifest = tmp_path / "zoo.yaml"
    manifest.write_text(
        zoo.read_text() + f"  - {{name: hp_cramped_room, checkpoint: {proxy}, levels: [cramped_room]}}\n"
    )
    meta = checkpoints.read_meta(single)
    plane.add_partner(PartnerRecord("ippo_cramped_s9", "ippo", 9, "overcooked:cramped_room", 0, str(single),
                                    meta["sha256"]))  # fmt: skip
    plane.add_partner(PartnerRecord("lost", "e3t", 0, "overcooked:procedural", 0, str(tmp_path / "no"), ""))
    foreign = dataclasses.replace(
        CheckpointEvent.from_checkpoint(path, "cec-other"), path=str(tmp_path / "no")
    )
    assert plane.publish_checkpoint(foreign).outcome == "published"
    event = _publish(plane, path, "cec-groups")
    config = _config(
        plane, manifest, tmp_path / "results", redis_zoo=True, self_play=False, level_sets=(CLASSIC, HELDOUT),
        groups=(PartnerGroupConfig("population", ("fcp_s7", "ippo_cramped_s9")),), runs=("cec-groups",),
    )  # fmt: skip
    with Evaluator(config, plane) as ev:
        [ignored] = ev.poll_once(block_s=0.5)  # another run's event: acknowledged, not scored
        [outcome] = ev.poll_once(block_s=0.5)
        assert ev.consumer.pending_count() == 0
    assert ignored.status == "ignored" and plane.get_results(foreign.checkpoint_id) == []
    assert outcome.status == "scored"
    results = {(r.partner_group, r.level_set): r.metrics for r in plane.get_results(event.checkpoint_id)}
    groups = ("population", "ippo", "e3t", "human_proxy")
    assert set(results) == {(g, s) for g in groups for s in ("classic", "heldout")}
    assert results[("human_proxy", "classic")]["per_partner"].keys() == {"human_proxy/s0"}
    assert results[("human_proxy", "classic")]["episodes"] == 2  # both seat orders on its kitchen
    assert "none of its levels" in results[("human_proxy", "heldout")]["skipped"][0]["reason"]
    # The single-task partner (Redis env overcooked:cramped_room) plays on its own kitchen only.
    assert results[("population", "classic")]["partners"] == ["fcp_s7", "ippo_cramped_s9"]
    assert results[("population", "classic")]["per_partner"].keys() == {"fcp/s7", "ippo/s9"}
    skipped = results[("population", "heldout")]["skipped"]
    assert [s["name"] for s in skipped] == ["ippo_cramped_s9"] and "none of its levels" in skipped[0][
        "reason"
    ]
    assert results[("e3t", "classic")]["episodes"] == 0 and results[("e3t", "classic")]["return_mean"] is None
    assert "missing" in results[("e3t", "classic")]["skipped"][0]["reason"]
    table = read_csv(tmp_path / "results" / "cec-groups" / "eval" / "update_000000001.csv")
    assert {s.name for s in table.skipped} == {"ippo_cramped_s9", "hp_cramped_room", "lost"}
    # Both seats, 1 episode: classic (cramped_room) with 4 partners, the held-out kitchen with 2.
    assert len(table) == 2 * 4 + 2 * 2

    # zoo_algorithms: only the named labels play (the shipped zoo's CEC seeds and proxies, say)
    event = _publish(plane, ckpts.write("cec-groups", 2, [3]), "cec-groups")
    config = dataclasses.replace(config, groups=(), zoo_algorithms=("human_proxy", "fcp"))
    with Evaluator(config, plane) as ev:
        [outcome] = ev.poll_once(block_s=0.5)
    assert outcome.status == "scored"
    assert {r.partner_group for r in plane.get_results(event.checkpoint_id)} == {"human_proxy", "fcp"}


def test_scores_go_into_the_runs_tensorboard_events_at_the_checkpoints_env_steps(plane, ckpts, zoo, tmp_path):
    from tests.unit.training.test_tracking import read_scalars

    paths = [ckpts.write("cec-tb", update, [0, 1]) for update in (2, 5)]  # env steps 32 and 80
    quiet = ckpts.write("cec-tb-off", 2, [0], tracking={"tensorboard": False})
    events = [_publish(plane, p, "cec-tb") for p in paths] + [_publish(plane, quiet, "cec-tb-off")]
    config = _config(plane, zoo, tmp_path / "results", level_sets=(CLASSIC,))
    with Evaluator(config, plane) as ev:
        outcomes = []
        while len(outcomes) < len(events):
            outcomes += ev.poll_once(block_s=0.5)
        assert [o.status for o in outcomes] == ["scored"] * 3
        again = ev.handle(CheckpointMessage("0-1", events[0], redelivered=True))  # nothing written again
        assert again.status == "already_scored"
    tb = ckpts.root / "cec-tb" / "tb"
    assert len(list(tb.glob("*tfevents*.evaluator"))) == 1, "one writer for the run's checkpoints"
    got = read_scalars(tb)
    assert {f"eval/{g}/classic/{m}" for g in GROUPS for m in ("return", "score", "deliveries")} <= set(got)
    for event in events[:2]:
        for result in plane.get_results(event.checkpoint_id):
            for key, name in TRACKED_METRICS.items():
                if result.metrics[key] is None:  # the jackknife of two seeds' cross-play: no value, no point
                    assert f"eval/{result.partner_group}/{result.level_set}/{name}" not in got
                    continue
                points = dict(got[f"eval/{result.partner_group}/{result.level_set}/{name}"])
                assert points[event.env_steps] == pytest.approx(result.metrics[key], rel=1e-6), (key, event)
    assert [step for step, _ in got["eval/fcp/classic/return"]] == [32, 80]
    assert any(dict(series)[32] != dict(series)[80] for series in got.values()), "two checkpoints' own scores"
    assert not (ckpts.root / "cec-tb-off" / "tb").exists(), "the run's tracking.tensorboard=false is kept"


def test_cli_errors_are_one_line(tmp_path, capsys):
    assert cec_main(["evaluator", "--config", str(tmp_path / "none.yaml")]) == 2
    assert "does not exist" in capsys.readouterr().err
    assert cec_main(["evaluator", "play.episodes=0"]) == 2
    assert "play: episodes must be at least 1" in capsys.readouterr().err
    with LocalRedis() as s:
        port = s.port
    code = cec_main(["evaluator", f"store.url=redis://127.0.0.1:{port}/0", "store.retries=0",
                     "store.connect_timeout_s=0.5", "metrics_port=-1"])  # fmt: skip
    err = capsys.readouterr().err
    assert code == 1 and "cannot reach Redis" in err and "Traceback" not in err
    manifest = tmp_path / "zoo.yaml"
    manifest.write_text("policies: [{name: x}]\n")
    with LocalRedis() as s:
        code = cec_main(["evaluator", f"store.url={s.url}", f"zoo={manifest}", "metrics_port=-1"])
    assert code == 2 and "`checkpoint` is required" in capsys.readouterr().err


# --- the service as a process ------------------------------------------------------------------------------


class Service:
    """`python -m services.evaluator` as a child process; its output collected line by line."""

    def __init__(self, args: list[str], cache: Path) -> None:
        # JAX's persistent compilation cache: the restarted process loads what the first one compiled.
        env = {
            **os.environ,
            "JAX_PLATFORMS": "cpu",
            "PYTHONUNBUFFERED": "1",
            "JAX_COMPILATION_CACHE_DIR": str(cache),
            "JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS": "0",
        }
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "services.evaluator", *args],
            cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        self.lines: list[str] = []
        self.ready = threading.Event()
        self._reader = threading.Thread(target=self._read, daemon=True)
        self._reader.start()

    def _read(self) -> None:
        assert self.proc.stdout is not None
        for line in self.proc.stdout:
            self.lines.append(line.rstrip("\n"))
            if line.startswith("evaluator ready"):
                self.ready.set()

    @property
    def output(self) -> str:
        return "\n".join(self.lines)

    def wait_ready(self, timeout: float = 120.0) -> str:
        deadline = time.monotonic() + timeout
        while not self.ready.wait(0.1):
            assert self.proc.poll() is None, f"the evaluator exited early:\n{self.output}"
            assert time.monotonic() < deadline, f"no 'evaluator ready' line:\n{self.output}"
        line = next(x for x in self.lines if x.startswith("evaluator ready"))
        return line.rsplit(" ", 1)[-1]  # the metrics URL

    def stop(self, sig: int = signal.SIGTERM, timeout: float = 60.0) -> int:
        self.proc.send_signal(sig)
        code = self.proc.wait(timeout)
        self._reader.join(10)
        return code


def _wait(condition, what: str, service: Service, timeout: float = 180.0) -> None:
    deadline = time.monotonic() + timeout
    while not condition():
        assert service.proc.poll() is None, (
            f"the evaluator exited while waiting for {what}:\n{service.output}"
        )
        assert time.monotonic() < deadline, f"timed out waiting for {what}:\n{service.output}"
        time.sleep(0.02)


def _metrics(url: str) -> dict[str, dict[tuple, float]]:
    text = urllib.request.urlopen(url, timeout=10).read().decode()
    out: dict[str, dict[tuple, float]] = {}
    for family in text_string_to_metric_families(text):
        for sample in family.samples:
            out.setdefault(sample.name, {})[tuple(sorted(sample.labels.items()))] = sample.value
    return out


def test_service_scores_each_checkpoint_exactly_once_across_a_sigkill(redis_server, ckpts, zoo, tmp_path):
    prefix = f"e2e{uuid.uuid4().hex[:6]}"
    plane = ControlPlane.connect(redis_server.config(key_prefix=prefix))
    results_dir = tmp_path / "results"
    # Level sets of 2 and 3 levels: two compiled shapes; the second compile (seconds) happens while the
    # first checkpoint's classic parts are stored and its held-out parts are not: there the kill lands.
    args = [
        f"store.url={redis_server.url}", f"store.key_prefix={prefix}", f"zoo={zoo}", "redis_zoo=false",
        f"results_dir={results_dir}", "metrics_port=0", "play.episodes=1", f"play.max_steps={STEPS}",
        "poll_s=0.2", "zoo_algorithms=[]",
        "level_sets=[{name: classic, levels: 'cramped_room,coord_ring'}, "
        "{name: heldout, levels: generated, max_levels: 3}]",
    ]  # fmt: skip
    paths = [ckpts.write("cec-e2e", u, [0, 1]) for u in (1, 2, 3, 4)]
    events = [CheckpointEvent.from_checkpoint(p, "cec-e2e") for p in paths]
    ids = [e.checkpoint_id for e in events]
    parts = {(g, s) for g in GROUPS for s in ("classic", "heldout")}

    def stored(cid: str) -> set[tuple[str, str]]:
        return {(r.partner_group, r.level_set) for r in plane.get_results(cid)}

    first = Service(args, tmp_path / "jax-cache")
    try:
        first.wait_ready()
        for e in events[:2]:  # the first checkpoints appear; the evaluator works through them in order
            plane.publish_checkpoint(e)
        _wait(lambda: ("fcp", "classic") in stored(ids[0]), "the first parts of checkpoint 1", first)
        first.proc.send_signal(signal.SIGSTOP)  # freeze it, check where it is, then kill it there
        at_kill = {(r.partner_group, r.level_set): r.written_at for r in plane.get_results(ids[0])}
        assert not plane.is_scored(ids[0]) and set(at_kill) == {(g, "classic") for g in GROUPS}, (
            f"the kill did not land mid-checkpoint: {sorted(at_kill)}"
        )
        first.stop(signal.SIGKILL)
    finally:
        if first.proc.poll() is None:
            first.proc.kill()
    assert not any(" scored cec-e2e" in line for line in first.lines)

    plane.publish_checkpoint(events[2])  # appears while no evaluator runs: it waits in the group
    second = Service(args, tmp_path / "jax-cache")
    try:
        url = second.wait_ready()
        _wait(lambda: plane.is_scored(ids[2]), "checkpoints 1-3", second)
        plane.publish_checkpoint(events[3])  # one more while it runs
        _wait(lambda: plane.is_scored(ids[3]), "checkpoint 4", second)
        # The gauges move after `mark_scored`, the pending gauge after the acknowledgement.
        done = {
            "cec_evaluator_checkpoints_scored_total": {(): 4.0},
            "cec_evaluator_pending_checkpoints": {(): 0.0},
        }
        _wait(
            lambda: all(_metrics(url)[k] == v for k, v in done.items()), "the metrics of checkpoint 4", second
        )
        scrape = _metrics(url)
        code = second.stop(signal.SIGTERM)
    finally:
        if second.proc.poll() is None:
            second.proc.kill()
    assert code == 0, second.output
    assert "evaluator stopped" in second.output

    # Exactly once: each checkpoint scored by one process, the resumed one without its stored parts.
    log = first.lines + second.lines
    for cid in ids:
        assert sum(f" scored {cid} in " in line for line in log) == 1, cid
        assert stored(cid) == parts and plane.is_scored(cid)
    assert any(
        f"scored {ids[0]} in" in x and "(4 part(s) computed, 4 already stored)" in x for x in second.lines
    )
    after = {(r.partner_group, r.level_set): r.written_at for r in plane.get_results(ids[0])}
    assert all(after[k] == t for k, t in at_kill.items())
    group = plane.consumer("evaluator", "inspector", from_start=True)
    assert group.pending_count() == 0

    # One table per checkpoint in the run directory, no episode twice, no staging left behind.
    for cid, event in zip(ids, events, strict=True):
        table = read_csv(results_dir / "cec-e2e" / "eval" / f"update_{event.update:09d}.csv")
        keys = _episode_keys(table)
        want = _expected_rows(2, 2, 2) + _expected_rows(2, 2, 3)
        assert len(keys) == len(set(keys)) == want, cid
    assert not (results_dir / "cec-e2e" / "eval" / ".parts").exists()

    # Prometheus: the newest checkpoint's return per partner group and level set, and the counters.
    newest = {(r.partner_group, r.level_set): r.metrics["return_mean"] for r in plane.get_results(ids[3])}
    gauges = {
        (dict(k)["partner_group"], dict(k)["level_set"]): v for k, v in scrape["cec_evaluator_return"].items()
    }
    assert gauges == pytest.approx(newest) and set(gauges) == parts
    assert scrape["cec_evaluator_scored_update"][()] == 4
    assert scrape["cec_evaluator_failures_total"][()] == 0
    # Episodes played by the second process: checkpoint 1's held-out parts only, then 2-4 in full.
    assert scrape["cec_evaluator_episodes_total"][()] == _expected_rows(2, 2, 3) + 3 * want
    assert scrape["cec_evaluator_checkpoint_duration_seconds_count"][()] == 4
    plane.close()
