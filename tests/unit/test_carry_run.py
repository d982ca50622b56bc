"""A run carried between sessions in compact form (`scripts/carry_run.py`): parameters, optimizer state,
keys and counts kept, the envs' carries dropped; restored, `cec train --resume` continues from the carried
update with the carried parameters."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import jax
import numpy as np

from cec import checkpoints

REPO = Path(__file__).resolve().parents[2]
PRESET = ["--config", "configs/train/dd_ippo_quick.yaml", "num_seeds=2", "num_envs=8", "num_steps=20",
          "total_env_steps=1600", "updates_per_call=1", "checkpoint.every_updates=1", "--quiet"]  # fmt: skip


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=600)


def test_a_carried_run_resumes_from_its_update_with_its_parameters(tmp_path: Path) -> None:
    first = _run(
        "-m", "apps.cli", "train", *PRESET, f"run_dir={tmp_path / 'a'}", "name=r", "--max-updates", "3"
    )
    assert first.returncode == 0, first.stderr[-2000:]
    carried = tmp_path / "carry" / "r"
    saved = _run("scripts/carry_run.py", "save", str(tmp_path / "a" / "r"), "--out", str(carried))
    assert saved.returncode == 0, saved.stderr[-2000:]
    original = checkpoints.read_meta(carried / "state")
    assert original["update"] == 3 and not (carried / "state" / "carry").exists()
    full = (tmp_path / "a" / "r" / "checkpoints" / "update_000000003" / "state.msgpack").stat().st_size
    assert (carried / "state" / "state.msgpack").stat().st_size < full, "the envs' carries are left out"
    restored = _run("scripts/carry_run.py", "restore", str(carried), "--run-dir", str(tmp_path / "b"))
    assert restored.returncode == 0, restored.stderr[-2000:]
    run = tmp_path / "b" / "r"
    assert (run / "metrics.jsonl").read_text() == (tmp_path / "a" / "r" / "metrics.jsonl").read_text()
    kept = checkpoints.read_meta(run / "checkpoints" / "update_000000003")
    assert kept["config"] == original["config"]
    a = [
        np.asarray(x)
        for x in jax.tree.leaves(_params(tmp_path / "a" / "r" / "checkpoints" / "update_000000003"))
    ]
    b = [np.asarray(x) for x in jax.tree.leaves(_params(run / "checkpoints" / "update_000000003"))]
    assert all(np.array_equal(x, y) for x, y in zip(a, b, strict=True))
    more = _run("-m", "apps.cli", "train", "--resume", str(run), "--max-updates", "2", "--quiet")
    assert more.returncode == 0, more.stderr[-2000:]
    updates = sorted({int(line.split('"update": ')[1].split(",")[0]) for line in
                      (run / "metrics.jsonl").read_text().splitlines()})  # fmt: skip
    assert updates == [1, 2, 3, 4, 5]


def _params(path: Path) -> object:
    from cec.agents.policy import load_policy
    from cec.agents.zoo import ZooEntry

    return [
        load_policy(ZooEntry("x", str(path), seed=s)).params
        for s in checkpoints.read_meta(path)["metadata"]["seeds"]
    ]
