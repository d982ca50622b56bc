"""The one update loop (`cec.training.loop.run_updates`) with a stand-in source: how it steps, what it writes,
when it checkpoints and how it stops. `cec train` and the learner run it for real: test_training.py,
test_train_cli.py, tests/e2e/test_distributed.py (the learner trains as `cec train` does)."""

from __future__ import annotations

import io
import json
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import numpy as np

from cec.config import load_config
from cec.training import loop
from cec.training.config import TrainConfig
from cec.training.loop import UpdateSource, run_updates
from cec.training.ppo import LossInfo
from cec.training.run import RunFiles
from cec.training.trainer import TrainState, UpdateMetrics

ROOT = Path(__file__).resolve().parents[3]
UPDATES = 6


class Files(RunFiles):
    """The run directory's files, with the checkpoints only recorded: (update, milestone)."""

    def __init__(self, config: TrainConfig) -> None:
        super().__init__(config)
        self.run_dir.mkdir(parents=True)
        self.saved: list[tuple[int, bool]] = []

    def save(self, state: TrainState, update: int, milestone: bool) -> Path:
        self.saved.append((update, milestone))
        return self.run_dir / f"update_{update}"


class Tracker:
    def __init__(self) -> None:
        self.sections: list[Any] = []

    def log_rows(self, rows: list[dict], sections: Any = None) -> None:
        self.sections.append(sections)


class Source(UpdateSource):
    """Updates whose mean return is their own number; records what the loop asks of it."""

    def __init__(self, per_step: int) -> None:
        self.updates_per_step = per_step
        self.steps: list[tuple[int, int]] = []
        self.after: list[int] = []
        self.saves: list[Path] = []

    def step(self, done: int, n: int) -> UpdateMetrics:
        self.steps.append((done, n))
        value = np.arange(done + 1, done + n + 1, dtype=np.float32)[None]  # [1 seed, n]
        zero = np.zeros_like(value)
        return UpdateMetrics(
            zero + 4, value, value, zero, zero, zero, LossInfo(*[zero] * len(LossInfo._fields))
        )

    def state(self) -> TrainState:
        return TrainState(None, None, None, None, None)

    def extra_columns(self) -> dict[str, Any]:
        return {"policy_lag_max": len(self.steps)}

    def sections(self) -> dict[str, str]:
        return {"policy_lag_max": "distributed"}

    def after_update(self, done: int, metrics: UpdateMetrics, sps: float) -> None:
        self.after.append(done)

    def on_save(self, path: Path, seconds: float) -> None:
        self.saves.append(path)


def _config(tmp_path: Path, *overrides: str) -> TrainConfig:
    return load_config(
        TrainConfig,
        ROOT / "configs/train/dd_ippo_quick.yaml",
        [
            "num_envs=4",
            "num_steps=8",
            f"total_env_steps={4 * 8 * UPDATES}",
            f"run_dir={tmp_path}",
            *overrides,
        ],
    )


def _rows(files: Files) -> list[dict]:
    return [json.loads(line) for line in (files.run_dir / "metrics.jsonl").read_text().splitlines()]


def test_it_steps_to_the_end_writes_every_update_and_checkpoints_when_due(tmp_path: Path) -> None:
    files = Files(_config(tmp_path, "checkpoint.every_updates=3", "checkpoint.milestones=[0.0]"))
    source, tracker, log = Source(per_step=4), Tracker(), io.StringIO()
    outcome = run_updates(source, files, tracker, 0, log=log)
    assert outcome == (UPDATES, UPDATES, False)
    assert source.steps == [(0, 4), (4, 2)], "whole steps, the last one cut at the run's end"
    rows = _rows(files)
    assert [r["update"] for r in rows] == [r["mean_return"] for r in rows] == list(range(1, UPDATES + 1))
    assert [r["policy_lag_max"] for r in rows] == [1] * 4 + [2] * 2, "the source's columns, after the rest"
    assert (
        list(rows[0])[-1] == "policy_lag_max" and tracker.sections == [{"policy_lag_max": "distributed"}] * 2
    )
    assert files.saved == [(0, True), (4, False), (6, False)], "milestone 0, every 3 (crossed at 4), the end"
    assert source.saves == [files.run_dir / f"update_{u}" for u in (0, 4, 6)] and source.after == [4, 6]
    lines = log.getvalue().splitlines()
    assert lines[0].startswith("update 4/6 ( 66.7%) | 128/192 steps |") and "return 4.00 | ETA" in lines[0]
    assert "interrupted" not in log.getvalue()


def test_max_updates_stops_early_and_the_last_update_is_saved(tmp_path: Path) -> None:
    files = Files(_config(tmp_path))
    source = Source(per_step=1)
    outcome = run_updates(source, files, Tracker(), 2, max_updates=3, progress=False)
    assert outcome == (5, 5, False) and source.steps == [(2, 1), (3, 1), (4, 1)]
    assert files.saved == [(5, False)]


def test_a_stop_during_a_step_ends_the_loop_after_it_with_a_checkpoint_and_the_hint(tmp_path: Path) -> None:
    files = Files(_config(tmp_path))
    source, log = Source(per_step=1), io.StringIO()
    asked = lambda: len(source.steps) >= 2  # noqa: E731 - asked during the second step
    outcome = run_updates(source, files, Tracker(), 0, stop=asked, resume_hint="go on", log=log)
    assert outcome == (2, UPDATES, True) and files.saved == [(2, False)]
    assert "interrupted at update 2; checkpoint saved. Continue with: go on" in log.getvalue()


def test_a_stop_before_a_step_runs_none_and_one_between_steps_saves_the_last(tmp_path: Path) -> None:
    files = Files(_config(tmp_path))
    source = Source(per_step=1)
    outcome = run_updates(source, files, Tracker(), 0, stop=lambda: True, progress=False)
    assert outcome == (0, UPDATES, True) and source.steps == [] and files.saved == []
    files = Files(_config(tmp_path, "name=between"))
    source = Source(per_step=1)
    answers = iter([False, False, True])  # asked after the first step's check, before the second step
    outcome = run_updates(source, files, Tracker(), 0, stop=lambda: next(answers), progress=False)
    assert outcome == (1, UPDATES, True) and source.steps == [(0, 1)]
    assert files.saved == [(1, False)], "the update done before the stop is in a checkpoint"


def test_the_eta_is_timed_from_the_first_compiled_step(tmp_path: Path, monkeypatch) -> None:
    """The first step compiles (300 s here, on a clock the steps advance), the others take 2 s: the first line
    has no ETA, and every later one is the pace since it, (updates left) x 2 s, never the compile's."""
    clock = [0.0]
    monkeypatch.setattr(loop, "time", SimpleNamespace(perf_counter=lambda: clock[0]))

    class Timed(Source):
        def step(self, done: int, n: int) -> UpdateMetrics:
            clock[0] += 300.0 if not self.steps else 2.0 * n
            return super().step(done, n)

    log = io.StringIO()
    run_updates(Timed(per_step=1), Files(_config(tmp_path)), Tracker(), 0, log=log)
    etas = [line.rsplit("| ETA ", 1)[1] for line in log.getvalue().splitlines()]
    assert etas == ["? (timed from the next update)", "0m08s", "0m06s", "0m04s", "0m02s", "0m00s"], etas
