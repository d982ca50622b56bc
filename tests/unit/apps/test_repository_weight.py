"""The repository stays light: no tracked file over 1 MiB (a training checkpoint, a results table) but the
shipped policies (`cec/shipped/`, what users play with: exported parameters of at most 2 MiB each, a CEC
policy's are 1.3 MB), and at most 25 MB in all under `benchmarks/results/`. Git keeps what cannot be
regenerated (reports, figures, benchmark JSON, configs, metrics, one compressed table per report); work
folders' policies and training states stay out, a command regenerates them (`benchmarks/results/README.md`).
Commit a policy's exported parameters (`cec zoo export`) instead of a training state, and compress tables
(`.csv.bz2`, `.csv.gz`: read as they are).

History too stops growing: every file version committed since the round's base obeys the same 1 MiB, but the
shipped policies and one compact run state a session under `carry/` (120 MB in all for the round;
`scripts/history_weight.py`, run by `make lint`), so a state added and then removed from the tree is still
found."""

from __future__ import annotations

import os
import shutil
import subprocess
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[3]
MAX_BYTES = 1 << 20
SHIPPED, MAX_SHIPPED_BYTES = "cec/shipped/", 2 << 20
CARRY = "carry/"  # a long run's compact state, its size bounded by the history check's budget
RESULTS, MAX_RESULTS_BYTES = "benchmarks/results/", 25_000_000


def _tracked() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p]


def large_files(paths: list[str], root: Path = ROOT) -> list[str]:
    def limit(p: str) -> int:
        return MAX_SHIPPED_BYTES if p.startswith(SHIPPED) else MAX_BYTES

    return sorted(
        p
        for p in paths
        if not p.startswith(CARRY) and (root / p).is_file() and (root / p).stat().st_size > limit(p)
    )


def results_bytes(paths: list[str], root: Path = ROOT) -> int:
    """The bytes of the files of `paths` under `benchmarks/results/`."""
    return sum((root / p).stat().st_size for p in paths if p.startswith(RESULTS) and (root / p).is_file())


def test_no_tracked_file_is_over_1_mib_but_the_shipped_policies() -> None:
    large = large_files(_tracked())
    assert large == [], (
        f"tracked files over {MAX_BYTES >> 20} MiB: {large}; commit an exported policy (`cec zoo export`) "
        "instead of a training state, compress a table (.csv.bz2), or keep the file out of git"
    )


def test_the_tracked_benchmark_results_stay_under_25_mb() -> None:
    size = results_bytes(_tracked())
    assert size < MAX_RESULTS_BYTES, (
        f"{RESULTS} holds {size / 1e6:.1f} MB of tracked files (at most {MAX_RESULTS_BYTES / 1e6:.0f} MB): "
        "keep a work folder's policies and training states out of git (a command regenerates them; say which "
        "in its README) and compress its tables and metrics (.csv.bz2)"
    )


def test_the_rules_find_a_large_file_and_a_heavy_results_folder(tmp_path: Path) -> None:
    (tmp_path / "state.msgpack").write_bytes(b"\0" * (MAX_BYTES + 1))
    (tmp_path / "small.msgpack").write_bytes(b"\0" * 10)
    shipped = tmp_path / "cec" / "shipped" / "p"
    shipped.mkdir(parents=True)
    (shipped / "state.msgpack").write_bytes(b"\0" * (MAX_BYTES + 1))
    carried = tmp_path / "carry" / "run"
    carried.mkdir(parents=True)
    (carried / "state.msgpack").write_bytes(b"\0" * (MAX_BYTES + 1))
    paths = ["state.msgpack", "small.msgpack", "cec/shipped/p/state.msgpack", "carry/run/state.msgpack"]
    assert large_files(paths, tmp_path) == ["state.msgpack"]
    results = tmp_path / "benchmarks" / "results"
    results.mkdir(parents=True)
    (results / "table.csv").write_bytes(b"\0" * 1000)
    assert results_bytes([*paths, "benchmarks/results/table.csv"], tmp_path) == 1000


# History: every file version committed since the round's base (scripts/history_weight.py, in `make lint`).


def _history() -> Any:
    from tests.scripts import tool

    return tool("history_weight")


def _repo(tmp_path: Path) -> Path:
    """A throwaway repository whose first commit is the base."""
    repo = tmp_path / "repo"
    repo.mkdir()
    _commit(repo, {"README.md": b"base\n"}, "base")
    return repo


def _commit(repo: Path, files: dict[str, bytes], message: str, date: str = "2026-12-01T12:00:00") -> str:
    if not (repo / ".git").exists():
        subprocess.run(["git", "init", "-q", str(repo)], check=True)
    for name, data in files.items():
        (repo / name).parent.mkdir(parents=True, exist_ok=True)
        (repo / name).write_bytes(data)
    env = {
        **os.environ,
        "GIT_AUTHOR_NAME": "t", "GIT_AUTHOR_EMAIL": "t@example.com", "GIT_AUTHOR_DATE": date,
        "GIT_COMMITTER_NAME": "t", "GIT_COMMITTER_EMAIL": "t@example.com", "GIT_COMMITTER_DATE": date,
    }  # fmt: skip
    subprocess.run(["git", "-C", str(repo), "add", "-A"], check=True, env=env)
    subprocess.run(["git", "-C", str(repo), "commit", "-q", "-m", message], check=True, env=env)
    out = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True, check=True
    )
    return out.stdout.strip()


def test_the_history_since_the_base_passes_the_rule() -> None:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    assert _history().main([]) == 0


def test_a_commit_that_adds_a_2_mib_state_fails_the_history_check(tmp_path: Path, capsys) -> None:
    hw = _history()
    repo = _repo(tmp_path)
    base = subprocess.run(
        ["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True
    ).stdout
    assert hw.main(["--repo", str(repo), "--base", base.strip()]) == 0
    state = b"\1" * (2 << 20)
    added = _commit(repo, {"runs/x/checkpoints/update_1/state.msgpack": state}, "add a state")
    _commit(repo, {"runs/x/checkpoints/update_1/state.msgpack": b"gone"}, "take it out of the tree")
    assert hw.main(["--repo", str(repo), "--base", base.strip()]) == 1  # history keeps it: still refused
    err = capsys.readouterr().err
    assert f"runs/x/checkpoints/update_1/state.msgpack (2.0 MiB, commit {added[:10]})" in err
    assert "carry/" in err and "120 MB" in err and "once a session" in err  # the rule says what is allowed
    assert hw.main(["--repo", str(repo), "--base", added]) == 0  # a base after it: not this round's


def test_the_shipped_policies_and_one_compact_state_a_session_under_carry_pass(
    tmp_path: Path, monkeypatch
) -> None:
    hw = _history()
    repo = _repo(tmp_path)
    base = subprocess.run(["git", "-C", str(repo), "rev-parse", "HEAD"], capture_output=True, text=True)
    args = ["--repo", str(repo), "--base", base.stdout.strip()]
    _commit(repo, {"cec/shipped/p/state.msgpack": b"\1" * (2 << 20)}, "ship a policy")
    _commit(repo, {"carry/run/state.msgpack": b"\2" * (2 << 20)}, "carry a run", "2026-12-01T20:00:00")
    _commit(repo, {"carry/run/state.msgpack": b"\3" * (2 << 20)}, "carry it on", "2026-12-02T20:00:00")
    assert hw.main(args) == 0
    monkeypatch.setattr(hw, "CARRY_BUDGET", 3 << 20)  # two versions of 2 MiB: over a 3 MiB budget
    assert any("carry/ took 4.2 MB" in p for p in hw.problems(hw.new_blobs(repo, args[-1])))
    monkeypatch.undo()
    _commit(repo, {"carry/run/state.msgpack": b"\4" * 10}, "the next session", "2026-12-02T23:05:00")
    assert hw.main(args) == 0  # the same day, another session (3 hours on)
    _commit(repo, {"carry/run/state.msgpack": b"\5" * 10}, "again, same session", "2026-12-03T01:00:00")
    found = hw.problems(hw.new_blobs(repo, args[-1]))
    assert len(found) == 1 and "carry/ committed twice within 3:00:00 (" in found[0], found
    assert "at 2026-12-02 23:05, " in found[0] and "at 01:00; once a session at most)" in found[0]


def test_without_the_base_every_commit_held_is_checked(tmp_path: Path) -> None:
    """A shallow clone lacks the base: all it holds is newer, and all of it is checked."""
    hw = _history()
    repo = _repo(tmp_path)
    _commit(repo, {"big.bin": b"\1" * (MAX_BYTES + 1)}, "big")
    assert [b.path for b in hw.new_blobs(repo, "0" * 40) if b.size > MAX_BYTES] == ["big.bin"]
