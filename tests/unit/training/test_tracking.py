"""Tracking: a run's TensorBoard events hold its metrics rows' values at their env steps; the W&B mirror.

Events are read back with TensorBoard's own reader (`EventAccumulator`), which also applies the purge step
a resumed run writes. The evaluator's scores in the same events: tests/services/test_evaluator.py; the
distributed learner's: tests/e2e/test_distributed_tracking.py.
"""

from __future__ import annotations

import io
import json
import sys
from pathlib import Path

import pytest

from cec.config import ConfigError, load_config
from cec.training.config import TrainConfig
from cec.training.run import train
from cec.training.tracking import TB_DIR, Tracker, TrackingConfig, describe, row_scalars
from tests.unit.training.test_training import _config

event_accumulator = pytest.importorskip(
    "tensorboard.backend.event_processing.event_accumulator", reason="reads events: pip install tensorboard"
)


def read_scalars(tb_dir: Path) -> dict[str, list[tuple[int, float]]]:
    """Every scalar series of a TensorBoard run directory: tag -> [(step, value)] in reading order."""
    acc = event_accumulator.EventAccumulator(str(tb_dir), size_guidance={event_accumulator.SCALARS: 0})
    acc.Reload()
    return {tag: [(e.step, e.value) for e in acc.Scalars(tag)] for tag in acc.Tags()["scalars"]}


def _rows(run_dir: Path) -> list[dict]:
    return [json.loads(line) for line in (run_dir / "metrics.jsonl").read_text().splitlines()]


def test_train_writes_every_metrics_column_and_a_resume_hides_what_its_checkpoint_lost(tmp_path):
    cfg = _config(tmp_path, num_seeds=2)  # 4 updates of 48 env steps, a checkpoint after each
    spu = cfg.steps_per_update
    log = io.StringIO()
    first = train(cfg, max_updates=2, progress=False, log=log)
    tb = first.run_dir / TB_DIR
    assert f"tensorboard --logdir {tb}" in log.getvalue()
    # What a run killed after update 2's checkpoint had written before dying: points of updates 3 and 4.
    with Tracker(first.run_dir, cfg.tracking, name=cfg.run_name) as lost:
        for update in (3, 4):
            lost.log(update * spu, {"loss/total_loss/s0": 1e6, "episode/mean_return/s1": -1e6})
    result = train(cfg, resume=True, progress=False, log=io.StringIO())
    assert result.updates_done == 4

    rows = _rows(result.run_dir)
    got = read_scalars(tb)
    want = row_scalars(rows)
    assert sorted(want) == [spu * u for u in (1, 2, 3, 4)]
    # Each row's every numeric column is a series, with the row's own value at the row's env steps, once.
    columns = {k for r in rows for k, v in r.items() if isinstance(v, int | float)} - {
        "update",
        "env_steps",
        "seed",
    }
    assert {tag.split("/")[1] for tag in got} == columns
    for tag in ("loss/total_loss/s0", "loss/entropy/s1", "episode/mean_return/s0", "perf/env_steps_per_s/s1",
                "episode/mean_shaped_return/s1", "schedule/learning_rate/s0"):  # fmt: skip
        assert tag in got, tag
    expected = {
        tag: [(step, want[step][tag]) for step in sorted(want) if tag in want[step]]
        for tag in {t for points in want.values() for t in points}
    }
    assert set(got) == set(expected)
    for tag, series in expected.items():
        assert [s for s, _ in got[tag]] == [s for s, _ in series], tag  # the lost points are gone
        assert [v for _, v in got[tag]] == pytest.approx([v for _, v in series], rel=1e-6), tag
    # the values are the run's own: the two seeds differ, and so do updates
    assert got["loss/total_loss/s0"] != got["loss/total_loss/s1"]
    assert len({v for _, v in got["loss/total_loss/s0"]}) == 4


def test_rows_become_tagged_points():
    rows = [
        {"update": 1, "env_steps": 10, "seed": 3, "mean_return": 2.0, "total_loss": 0.5, "episodes": 4,
         "normalised_return": None, "lag": 1, "flag": True, "name": "x"},
        {"update": 2, "env_steps": 20, "seed": 3, "mean_return": None, "total_loss": 0.25, "episodes": 0,
         "normalised_return": None, "lag": 0, "flag": False, "name": "x"},
    ]  # fmt: skip
    assert row_scalars(rows, {"lag": "distributed"}) == {
        10: {"episode/mean_return": 2.0, "loss/total_loss": 0.5, "episode/episodes": 4, "distributed/lag": 1},
        20: {"loss/total_loss": 0.25, "episode/episodes": 0, "distributed/lag": 0},
    }
    two = [dict(rows[0]), {**rows[0], "seed": 4, "total_loss": 0.75}]
    assert row_scalars(two)[10]["loss/total_loss/s4"] == 0.75 and "train/lag/s3" in row_scalars(two)[10]


def test_tracking_config_and_a_missing_wandb_before_any_work(tmp_path, monkeypatch):
    cfg = load_config(
        TrainConfig,
        None,
        ["tracking.wandb=true", "tracking.wandb_project=mine", "tracking.tensorboard=false"],
    )
    assert cfg.tracking == TrackingConfig(tensorboard=False, wandb=True, wandb_project="mine")
    with pytest.raises(ConfigError, match="wandb_mode"):
        load_config(TrainConfig, None, ["tracking.wandb_mode=cloud"])
    with pytest.raises(ConfigError, match="unknown key 'tracking.tensorbord'"):
        load_config(TrainConfig, None, ["tracking.tensorbord=false"])
    assert describe("runs/x", TrackingConfig()) == [
        "TensorBoard events in runs/x/tb; view them with: tensorboard --logdir runs/x/tb"
    ]
    assert describe("runs/x", TrackingConfig(tensorboard=False)) == []

    monkeypatch.setitem(sys.modules, "wandb", None)  # import wandb -> ImportError
    with pytest.raises(ConfigError, match="pip install wandb"):
        TrackingConfig(wandb=True).check()
    TrackingConfig().check()  # off: never imported
    run = _config(tmp_path, tracking={"wandb": True})
    with pytest.raises(ConfigError, match="pip install wandb"):
        train(run, progress=False, log=io.StringIO())
    assert not (tmp_path / "run").exists(), "refused before the run directory was touched"


def test_wandb_offline_writes_a_run_folder(tmp_path, monkeypatch):
    wandb = pytest.importorskip("wandb", reason="the optional W&B mirror: pip install wandb")
    for var in ("WANDB_CACHE_DIR", "WANDB_CONFIG_DIR", "WANDB_DATA_DIR"):
        monkeypatch.setenv(var, str(tmp_path / "wandb-home"))
    run_dir = tmp_path / "run"
    config = TrackingConfig(tensorboard=False, wandb=True, wandb_project="cec-test")
    assert "wandb sync" in describe(run_dir, config)[0]
    with Tracker(run_dir, config, name="run", run_config={"seed": 0}) as tracker:
        tracker.log_rows([{"update": 1, "env_steps": 96, "seed": 0, "total_loss": 0.5, "mean_return": 1.0}])
        tracker.log(96, {"eval/self_play/classic/return": 3.0})
    # run.finish() only tells W&B's service process that the run ended: the service closes the run's file
    # (its last buffered block) on its own time, which under load came after this test read it (CI, once).
    # A `cec` process's exit stops the service and waits for it (W&B's atexit teardown); so does this.
    wandb.teardown()
    [folder] = (run_dir / "wandb").glob("offline-run-*")
    [data] = folder.glob("run-*.wandb")
    content = data.read_bytes()
    for key in (b"loss/total_loss", b"episode/mean_return", b"eval/self_play/classic/return", b"env_steps"):
        assert key in content, key
    assert not (run_dir / TB_DIR).exists(), "tracking.tensorboard=false writes no events"
