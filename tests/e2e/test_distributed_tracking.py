"""The distributed learner's TensorBoard events, with real Ray (the driver of `cec up` and `cec train
--distributed`, run in-process): every metrics-row column at the row's env steps, the learner's own
(policy lag, dropped batches, level feed) included, and the start-up lines naming the events."""

from __future__ import annotations

import io
import json
from pathlib import Path

import pytest

ray = pytest.importorskip("ray")

from cec.config import load_config  # noqa: E402
from cec.training.config import TrainConfig  # noqa: E402
from cec.training.tracking import TB_DIR, row_scalars  # noqa: E402
from services.learner.config import DistributedConfig  # noqa: E402
from services.learner.driver import run_distributed  # noqa: E402
from services.learner.learner import DISTRIBUTED_COLUMNS  # noqa: E402
from tests.unit.training.test_tracking import read_scalars  # noqa: E402

pytestmark = pytest.mark.timeout(600)
REPO = Path(__file__).resolve().parents[2]
DD_QUICK = str(REPO / "configs/train/dd_ippo_quick.yaml")


@pytest.mark.own_process  # hosts Ray's driver (tests/own_process.py)
def test_the_learners_events_hold_its_rows_with_policy_lag_and_the_level_feed(tmp_path: Path) -> None:
    # 4 updates of 25-step rollouts. The async learner drops stale batches and replaces held ones, so it need
    # not train on the rollout that holds an episode's end (with the game's 100 steps only every 4th rollout
    # did, and one run of the suite here, 2026-11-27, logged no episode return): 20-step episodes put an end
    # in every rollout
    cfg = load_config(TrainConfig, DD_QUICK, [
        "num_envs=16", "num_steps=25", "total_env_steps=1600", "updates_per_call=1",
        "env.dual_destination.max_steps=20", f"run_dir={tmp_path}", "name=dist",
    ])  # fmt: skip
    dist = DistributedConfig(mode="async", num_actors=2, actor_cpus=0.5, metrics_port=-1)
    out = io.StringIO()
    # "local": a Ray of its own, whatever other cluster this machine runs or last ran
    ray.init(address="local", num_cpus=2, include_dashboard=False, logging_level="WARNING")
    try:
        assert run_distributed(cfg, dist, None, log_to=out) == 0
    finally:
        ray.shutdown()
    run_dir = tmp_path / "dist"
    assert f"tensorboard --logdir {run_dir / TB_DIR}" in out.getvalue()

    rows = [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]
    assert [r["update"] for r in rows] == [1, 2, 3, 4]
    assert all(set(DISTRIBUTED_COLUMNS) <= set(r) for r in rows)
    assert rows[0]["policy_lag_max"] == 0 and rows[-1]["levels_buffered"] == 0  # levels drawn by the actors
    want = row_scalars(rows, {c: "distributed" for c in DISTRIBUTED_COLUMNS})
    got = read_scalars(run_dir / TB_DIR)
    expected = {
        tag: [(step, want[step][tag]) for step in sorted(want) if tag in want[step]]
        for tag in {t for points in want.values() for t in points}
    }
    assert set(got) == set(expected)
    for name in (*DISTRIBUTED_COLUMNS, "loss/total_loss", "loss/entropy", "episode/mean_return"):
        tag = name if "/" in name else f"distributed/{name}"
        assert tag in got, tag
    for tag, series in expected.items():
        assert [s for s, _ in got[tag]] == [s for s, _ in series], tag
        assert [v for _, v in got[tag]] == pytest.approx([v for _, v in series], rel=1e-6), tag
