"""The repository stays light: no tracked file over 1 MiB (a training checkpoint, a results table) may be
added; the ones committed before the rule are listed in tests/data/large_files_before_the_rule.txt. Commit a
policy's exported parameters (`cec zoo export`) instead of a training state, and compress tables. The shipped
policies (`cec/shipped/`, what users play with) are exported parameters of at most 2 MiB each (a CEC policy's
are 1.3 MB)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
MAX_BYTES = 1 << 20
SHIPPED, MAX_SHIPPED_BYTES = "cec/shipped/", 2 << 20
BEFORE = ROOT / "tests" / "data" / "large_files_before_the_rule.txt"


def _tracked() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p]


def large_files(paths: list[str], root: Path = ROOT) -> list[str]:
    def limit(p: str) -> int:
        return MAX_SHIPPED_BYTES if p.startswith(SHIPPED) else MAX_BYTES

    return sorted(p for p in paths if (root / p).is_file() and (root / p).stat().st_size > limit(p))


def test_no_tracked_file_over_1_mib_was_added_after_the_rule() -> None:
    before = {line for line in BEFORE.read_text().splitlines() if line and not line.startswith("#")}
    added = [p for p in large_files(_tracked()) if p not in before]
    assert added == [], (
        f"tracked files over {MAX_BYTES >> 20} MiB: {added}; commit an exported policy (`cec zoo export`) "
        "instead of a training state, compress a table (.csv.gz), or keep the file out of git"
    )


def test_the_rule_finds_a_large_file(tmp_path: Path) -> None:
    (tmp_path / "state.msgpack").write_bytes(b"\0" * (MAX_BYTES + 1))
    (tmp_path / "small.msgpack").write_bytes(b"\0" * 10)
    shipped = tmp_path / "cec" / "shipped" / "p"
    shipped.mkdir(parents=True)
    (shipped / "state.msgpack").write_bytes(b"\0" * (MAX_BYTES + 1))
    paths = ["state.msgpack", "small.msgpack", "cec/shipped/p/state.msgpack"]
    assert large_files(paths, tmp_path) == ["state.msgpack"]
