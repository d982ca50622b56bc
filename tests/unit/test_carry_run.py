"""A run carried between sessions in compact form (`scripts/carry_run.py`): the newest checkpoint's
parameters, optimizer state, keys and counts kept, the envs' carries dropped, the older checkpoints (the
milestones learning curves are played from) as parameters; restored, `cec train --resume` continues from the
carried update with the carried parameters, and a finished run comes back with every checkpoint it had."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest

from cec import checkpoints

REPO = Path(__file__).resolve().parents[2]
PRESET = ["--config", "configs/train/dd_ippo_quick.yaml", "num_seeds=2", "num_envs=8", "num_steps=20",
          "total_env_steps=1600", "updates_per_call=1", "checkpoint.every_updates=1",
          "checkpoint.keep_last=1", "checkpoint.milestones=[0.2,1.0]", "--quiet"]  # fmt: skip


def _run(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, *args], cwd=REPO, capture_output=True, text=True, timeout=600)


def _carry(run: Path, carried: Path, run_dir: Path, *, into: bool = False) -> Path:
    """`run` saved to `carried` (`--out`, or `--into` its parent), then restored into `run_dir`; the restored
    run's folder."""
    where = ["--into", str(carried.parent)] if into else ["--out", str(carried)]
    saved = _run("scripts/carry_run.py", "save", str(run), *where)
    assert saved.returncode == 0, saved.stderr[-2000:]
    restored = _run("scripts/carry_run.py", "restore", str(carried), "--run-dir", str(run_dir))
    assert restored.returncode == 0, restored.stderr[-2000:]
    return run_dir / run.name


def _checkpoints(run: Path) -> list[tuple[str, int, bool]]:
    return [(c.path.name, c.update, c.milestone) for c in checkpoints.CheckpointStore(run, 1).list()]


def _same_params(a: Path, b: Path) -> bool:
    """Every checkpoint of run `a` and of run `b` holds the same parameters (the same checkpoints)."""
    assert _checkpoints(a) == _checkpoints(b)
    x = [np.asarray(v) for c in _checkpoints(a) for v in jax.tree.leaves(_params(a / "checkpoints" / c[0]))]
    y = [np.asarray(v) for c in _checkpoints(b) for v in jax.tree.leaves(_params(b / "checkpoints" / c[0]))]
    return all(np.array_equal(u, v) for u, v in zip(x, y, strict=True))


def test_a_carried_run_resumes_from_its_update_with_its_parameters(tmp_path: Path) -> None:
    first = _run(
        "-m", "apps.cli", "train", *PRESET, f"run_dir={tmp_path / 'a'}", "name=r", "--max-updates", "3"
    )
    assert first.returncode == 0, first.stderr[-2000:]
    original, carried = tmp_path / "a" / "r", tmp_path / "carry" / "r"
    assert [c[1:] for c in _checkpoints(original)] == [(2, True), (3, False)]
    run = _carry(original, carried, tmp_path / "b")
    newest = checkpoints.read_meta(carried / "state")
    assert newest["update"] == 3 and not (carried / "state" / "carry").exists()
    assert "opt_state" in newest["metadata"]["carried_fields"], "a run still training keeps its Adam state"
    full = (original / "checkpoints" / "update_000000003" / "state.msgpack").stat().st_size
    assert (carried / "state" / "state.msgpack").stat().st_size < full, "the envs' carries are left out"
    assert (run / "metrics.jsonl").read_text() == (original / "metrics.jsonl").read_text()
    kept = checkpoints.read_meta(run / "checkpoints" / "update_000000003")
    assert kept["config"] == newest["config"] and "carried_fields" not in kept["metadata"]
    assert _same_params(original, run), "the milestone and the newest checkpoint come back as they were"

    more = _run("-m", "apps.cli", "train", "--resume", str(run), "--quiet")
    assert more.returncode == 0, more.stderr[-2000:]
    updates = sorted({int(line.split('"update": ')[1].split(",")[0]) for line in
                      (run / "metrics.jsonl").read_text().splitlines()})  # fmt: skip
    assert updates == list(range(1, 11))

    again = _carry(run, tmp_path / "carry2" / "r", tmp_path / "c", into=True)  # finished: nothing goes on
    assert checkpoints.read_meta(tmp_path / "carry2" / "r" / "state")["metadata"]["carried_fields"] == [
        "params", "key", "update"
    ]  # fmt: skip
    assert [c[1:] for c in _checkpoints(again)] == [(2, True), (9, False), (10, True)]
    assert _same_params(run, again), "every checkpoint the finished run kept comes back as it was"

    # a finished run whose games are played, carried as its record: config, metrics, checkpoints' metadata
    record = _run("scripts/carry_run.py", "save", "--record-only", str(run), "--out", str(tmp_path / "rec"))
    assert record.returncode == 0, record.stderr[-2000:]
    assert sum(p.stat().st_size for p in (tmp_path / "rec").rglob("*") if p.is_file()) < 60_000
    restored = _run(
        "scripts/carry_run.py", "restore", str(tmp_path / "rec"), "--run-dir", str(tmp_path / "d")
    )
    assert restored.returncode == 0 and "record" in restored.stdout, restored.stderr[-2000:]
    kept = tmp_path / "d" / "r"
    assert _checkpoints(kept) == _checkpoints(run)  # listed and finished as the run was: nothing retrains
    for c in _checkpoints(run):  # the SHA-256 its cached games are keyed by
        sha = checkpoints.read_meta(kept / "checkpoints" / c[0])["sha256"]
        assert sha == checkpoints.read_meta(run / "checkpoints" / c[0])["sha256"]
    with pytest.raises(
        checkpoints.CorruptCheckpointError, match="a record without its state.msgpack: its run"
    ):
        _params(kept / "checkpoints" / _checkpoints(kept)[-1][0])
    # ... or, to play elsewhere, its last checkpoint alone (no milestone: nothing starts from it there)
    last = _run("scripts/carry_run.py", "save", "--newest-only", str(run), "--out", str(tmp_path / "last"))
    assert last.returncode == 0, last.stderr[-2000:]
    restored = _run(
        "scripts/carry_run.py", "restore", str(tmp_path / "last"), "--run-dir", str(tmp_path / "e")
    )
    assert restored.returncode == 0, restored.stderr[-2000:]
    assert _checkpoints(tmp_path / "e" / "r") == _checkpoints(run)[-1:]
    assert all(
        np.array_equal(u, v)
        for u, v in zip(
            jax.tree.leaves(_params(tmp_path / "e" / "r" / "checkpoints" / _checkpoints(run)[-1][0])),
            jax.tree.leaves(_params(run / "checkpoints" / _checkpoints(run)[-1][0])),
            strict=True,
        )
    )
    unfinished = _run(
        "scripts/carry_run.py", "save", "--record-only", str(original), "--out", str(tmp_path / "u")
    )
    assert unfinished.returncode != 0 and "has not finished" in unfinished.stderr


def _params(path: Path) -> object:
    from cec.agents.policy import load_policy
    from cec.agents.zoo import ZooEntry

    return [
        load_policy(ZooEntry("x", str(path), seed=s)).params
        for s in checkpoints.read_meta(path)["metadata"]["seeds"]
    ]


def test_a_reproductions_played_line_ups_are_carried_compressed_and_read_back_as_they_were(
    tmp_path: Path,
) -> None:
    """`save-tables`: every line-up table with its key (a finished one) of `parts/` and `steps100/parts/`,
    bzip2; `restore-tables` puts them back, where a table with another key is replaced."""
    from cec.evaluation.results import ARRAY_FIELDS, make_table, read_csv, stored, write_csv

    def table(returns: float) -> object:
        text = {"policy_a", "algorithm_a", "policy_b", "algorithm_b", "level", "env", "actions"}
        return make_table({**{f: ["x"] if f in text else [0] for f in ARRAY_FIELDS}, "returns": [returns]})

    work = tmp_path / "work"
    played = {"parts/classic-cramped_room": 3.0, "steps100/parts/heldout-generalists": 5.0}
    for folder, value in played.items():
        (work / folder).mkdir(parents=True)
        write_csv(table(value), work / folder / "results.csv")
        (work / folder / "results.key.json").write_text(f'{{"lineup": "{folder}"}}\n')
        (work / folder / "results.time.json").write_text('{"seconds": 60}\n')
    (work / "parts" / "heldout-coord_ring").mkdir()  # being played: no key yet, not carried
    write_csv(table(1.0), work / "parts" / "heldout-coord_ring" / "results.csv")
    saved = _run("scripts/carry_run.py", "save-tables", str(work), "--out", str(tmp_path / "tables"))
    assert saved.returncode == 0 and "carried 2 line-up table(s)" in saved.stdout, saved.stderr[-2000:]
    assert sorted(p.name for p in (tmp_path / "tables").rglob("results.csv*")) == ["results.csv.bz2"] * 2
    elsewhere = tmp_path / "elsewhere"
    stale = elsewhere / "parts" / "classic-cramped_room"  # the same line-up played with other players
    stale.mkdir(parents=True)
    write_csv(table(9.0), stale / "results.csv")
    (stale / "results.key.json").write_text('{"lineup": "other"}\n')
    back = _run("scripts/carry_run.py", "restore-tables", str(tmp_path / "tables"), "--work", str(elsewhere))
    assert back.returncode == 0 and "restored 2 line-up table(s)" in back.stdout, back.stderr[-2000:]
    for folder, value in played.items():
        table = read_csv(stored(elsewhere / folder / "results.csv"))
        assert table.returns.tolist() == [value], folder
        assert (elsewhere / folder / "results.key.json").read_text() == f'{{"lineup": "{folder}"}}\n'
    assert not (elsewhere / "parts" / "heldout-coord_ring").exists()
