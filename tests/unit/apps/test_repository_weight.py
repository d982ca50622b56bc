"""The repository stays light: no tracked file over 1 MiB (a training checkpoint, a results table) but the
shipped policies (`cec/shipped/`, what users play with: exported parameters of at most 2 MiB each, a CEC
policy's are 1.3 MB), and at most 25 MB in all under `benchmarks/results/`. Git keeps what cannot be
regenerated (reports, figures, benchmark JSON, configs, metrics, one compressed table per report); work
folders' policies and training states stay out, a command regenerates them (`benchmarks/results/README.md`).
Commit a policy's exported parameters (`cec zoo export`) instead of a training state, and compress tables
(`.csv.bz2`, `.csv.gz`: read as they are)."""

from __future__ import annotations

import shutil
import subprocess
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[3]
MAX_BYTES = 1 << 20
SHIPPED, MAX_SHIPPED_BYTES = "cec/shipped/", 2 << 20
RESULTS, MAX_RESULTS_BYTES = "benchmarks/results/", 25_000_000


def _tracked() -> list[str]:
    if shutil.which("git") is None or not (ROOT / ".git").exists():
        pytest.skip("not a git checkout")
    out = subprocess.run(["git", "ls-files", "-z"], cwd=ROOT, capture_output=True, check=True).stdout
    return [p for p in out.decode().split("\0") if p]


def large_files(paths: list[str], root: Path = ROOT) -> list[str]:
    def limit(p: str) -> int:
        return MAX_SHIPPED_BYTES if p.startswith(SHIPPED) else MAX_BYTES

    return sorted(p for p in paths if (root / p).is_file() and (root / p).stat().st_size > limit(p))


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
    paths = ["state.msgpack", "small.msgpack", "cec/shipped/p/state.msgpack"]
    assert large_files(paths, tmp_path) == ["state.msgpack"]
    results = tmp_path / "benchmarks" / "results"
    results.mkdir(parents=True)
    (results / "table.csv").write_bytes(b"\0" * 1000)
    assert results_bytes([*paths, "benchmarks/results/table.csv"], tmp_path) == 1000
