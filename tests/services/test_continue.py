"""How a stopped run is continued, as a newcomer meets it: the refusal of a second start names the command
that continues the run and says nothing else, `cec up` and `cec train` of one preset name their runs
apart, and a clash never proposes the single-process trainer for a distributed run (the `make up` Ctrl-C
itself: tests/e2e/test_make_up.py)."""

from __future__ import annotations

import argparse
import shlex
import shutil
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from cec.checkpoints import CheckpointStore
from cec.config import load_config
from cec.training.config import TrainConfig
from cec.training.run import RESUME_FILE, config_dict, record_resume_command, resume_command
from services.stack import DEFAULT_CONFIG, UpConfig, preset_path, resume_hint, wrote_past

REPO = Path(__file__).resolve().parents[2]
PRESET = "configs/train/cec_overcooked_teacher.yaml"  # the training preset of configs/up/default.yaml


def _cec(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "apps.cli", *args], cwd=REPO, capture_output=True, text=True, timeout=300
    )


def _with_checkpoint(run: Path) -> Path:
    (run / "checkpoints" / "update_000000022").mkdir(parents=True)
    return run


def test_cec_up_and_cec_train_name_their_runs_apart() -> None:
    up = load_config(UpConfig, preset_path(DEFAULT_CONFIG)).train_config()
    single = load_config(TrainConfig, REPO / PRESET)
    assert up.run_name == f"up-{single.run_name}"
    named = load_config(UpConfig, preset_path(DEFAULT_CONFIG)).train_config(("name=mine",))
    assert named.run_name == "mine", "a name given is kept"


def test_the_resume_hint_repeats_the_options_under_cec_up_or_make(monkeypatch: pytest.MonkeyPatch) -> None:
    args = argparse.Namespace(config=DEFAULT_CONFIG, monitoring=False, overrides=[])
    monkeypatch.delenv("CEC_UP_VIA", raising=False)
    assert resume_hint(args) == "cec up --resume"
    args = argparse.Namespace(config="my up.yaml", monitoring=True, overrides=["train.seed=3"])
    assert resume_hint(args) == "cec up --resume --config 'my up.yaml' --monitoring train.seed=3"
    monkeypatch.setenv("CEC_UP_VIA", "make")
    assert resume_hint(argparse.Namespace(config=DEFAULT_CONFIG, monitoring=False, overrides=[])) == (
        "make up ARGS=--resume"
    )
    make, up, value = shlex.split(resume_hint(args))  # as the shell reads it, then make's recipe
    assert (make, up) == ("make", "up") and value.startswith("ARGS=")
    assert shlex.split(value.removeprefix("ARGS=")) == [
        "--resume",
        "--config",
        "my up.yaml",
        "--monitoring",
        "train.seed=3",
    ]


def test_a_refused_cec_up_prints_only_the_refusal_with_the_command_that_continues(tmp_path: Path) -> None:
    run = _with_checkpoint(tmp_path / "up-cec-overcooked-generator-s0")
    proc = _cec("up", f"train.run_dir={tmp_path}", "evaluator=false")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"{run} already has checkpoints; continue it with `cec up --resume train.run_dir={tmp_path} " in (
        proc.stderr
    )
    assert "stack stopped" not in proc.stderr and "redis" not in proc.stderr.lower(), proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr


def test_cec_train_meets_a_distributed_run_and_names_its_own_command(tmp_path: Path) -> None:
    """The README's `cec train --config ...` after `make up`: another run, so no clash; and where a name is
    shared on purpose, the hint is the distributed run's own command, never `cec train --resume`."""
    up_run = _with_checkpoint(tmp_path / "up-cec-overcooked-generator-s0")
    record_resume_command(up_run, "make up ARGS=--resume")
    assert (up_run / RESUME_FILE).is_file() and resume_command(up_run) == "make up ARGS=--resume"
    mine = tmp_path / "cec-overcooked-generator-s0"
    assert resume_command(mine) == f"cec train --resume {mine}"
    proc = _cec("train", "--config", PRESET, f"run_dir={tmp_path}", "name=up-cec-overcooked-generator-s0")
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert "continue it with `make up ARGS=--resume`" in proc.stderr
    assert "cec train --resume" not in proc.stderr


def test_a_finished_run_is_said_finished_before_anything_starts(tmp_path: Path) -> None:
    """`make up` again after its run finished, or the `--resume` it then suggested: one line saying the run
    is finished and how to train another, status 0, before anything starts (resuming used to start Redis,
    Ray and the evaluator to find nothing left to train). A run stopped one update short still resumes."""
    train = load_config(UpConfig, preset_path(DEFAULT_CONFIG)).train_config((f"run_dir={tmp_path}",))
    store = CheckpointStore(tmp_path / train.run_name, keep_last=10)

    def checkpoint(update: int) -> None:
        config, steps = config_dict(train), update * train.steps_per_update
        store.save(
            {"x": np.zeros(1)}, update=update, env_steps=steps, config=config, metadata={}, milestone=False
        )

    checkpoint(train.num_updates)
    run = tmp_path / train.run_name
    for resume in ([], ["--resume"]):
        proc = _cec("up", *resume, f"train.run_dir={tmp_path}", "evaluator=false")
        assert proc.returncode == 0, proc.stderr[-2000:]
        assert proc.stderr == (
            f"cec up: {run} is finished: all {train.num_updates} updates trained, the last in "
            f"{store.path(train.num_updates)}. `cec status {run}` shows it; to train again, give the new run "
            "another name: name=NEW (under `cec up`: train.name=NEW)\n"
        ), proc.stderr
    shutil.rmtree(store.path(train.num_updates))
    checkpoint(train.num_updates - 1)  # one update short: not finished, refused as before without --resume
    proc = _cec("up", f"train.run_dir={tmp_path}", "evaluator=false")
    assert (
        proc.returncode == 2 and "already has checkpoints; continue it with `cec up --resume" in proc.stderr
    )


def test_a_resumed_runs_first_update_ends_the_wait_line_though_its_metrics_file_shrank(
    tmp_path: Path,
) -> None:
    """`cec up --resume` prints "no update yet" until the learner writes its first row; the resume first
    drops the rows after its checkpoint, so the file is smaller than before for as many updates as were
    lost (35 updates, 77 s of a release run that still said "no update yet" while training)."""
    import json

    metrics = tmp_path / "metrics.jsonl"

    def rows(last: int) -> str:
        return "".join(
            json.dumps({"update": u, "env_steps": 8192 * u, "return": 1.5}) + "\n" for u in range(1, last + 1)
        )

    metrics.write_text(rows(35))
    before = metrics.stat().st_size
    metrics.write_text(rows(20))  # resumed from update 20: the rows after it dropped
    assert not wrote_past(metrics, 20)
    metrics.write_text(rows(21))
    assert metrics.stat().st_size < before and wrote_past(metrics, 20)
    metrics.write_text(rows(21) + '{"update": 22, "env_st')  # a row being written
    assert wrote_past(metrics, 20) and not wrote_past(metrics, 21)
    assert not wrote_past(tmp_path / "none.jsonl", 0)
