"""Fourth hardening round (issue 88) for the library and the `cec` commands that need no service: shipping
choices fail closed, a run's files are rewritten only after they are checked (and never in place), every
file is read in bounded memory (checkpoints hashed in chunks), a run stops at its first non-finite step,
settings have finite ranges, `cec levels sample` checks its arguments before compiling."""

from __future__ import annotations

import bz2
import math
import shutil
import subprocess
import sys
from pathlib import Path

import pytest

from cec.agents.zoo import SkippedEntry
from cec.evaluation.choice import ChoiceError, choose

REPO = Path(__file__).resolve().parents[2]
SHIPPED = REPO / "benchmarks/results/overcooked/shipped"
DAMAGED = "checkpoint runs/humans/proxies/bc_cramped_room is corrupt: state.msgpack has SHA-256 0123"


def _cec(*args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)


def _script(path: Path, *args: str, timeout: float = 180) -> subprocess.CompletedProcess:
    cmd = [sys.executable, str(path), *args]
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=timeout)


# ---- a shipping choice fails closed ------------------------------------------------------------------------


def _without_bc(table: Path, out: Path) -> None:
    """`table` as `cec eval` writes it when it skipped the bc proxy (a damaged checkpoint): its rows gone,
    one skipped row naming it instead."""
    lines = bz2.decompress(table.read_bytes()).decode().splitlines()
    kept = [ln for ln in lines if ",bc_proxy," not in ln]
    assert len(kept) < len(lines)
    kept.append("bc_cramped_room,bc_proxy,0" + "," * 14 + f"skipped,{DAMAGED}")
    out.write_bytes(bz2.compress(("\n".join(kept) + "\n").encode()))


def test_choose_takes_the_highest_mean_and_the_first_on_a_tie():
    assert choose({"a": [1.0, 3.0], "b": [2.5]}, what="x") == "b"
    assert choose({"control": [2.0], "new": [1.0, 3.0]}, what="x") == "control"


@pytest.mark.parametrize(
    ("figures", "skipped", "cause"),
    [
        ({"a": [1.0], "b": []}, (), "b has no figure"),
        ({"a": [1.0], "b": [math.nan, 2.0]}, (), r"b has a figure that is not finite \(1 of 2 are nan\)"),
        ({"a": [math.inf]}, (), "a has a figure that is not finite"),
        ({}, (), "there is no candidate"),
        ({"a": [1.0]}, (SkippedEntry("bc_x", "bc_proxy", 0, "corrupt"),), "skipped 'bc_x' .*: corrupt"),
    ],
)
def test_choose_refuses_an_empty_or_non_finite_group_or_a_skipped_entry(figures, skipped, cause):
    with pytest.raises(ChoiceError, match=f"the seed: refusing to choose.*{cause}"):
        choose(figures, what="the seed", skipped=skipped)


def test_finetune_evaluate_refuses_to_ship_without_the_validation_proxy(tmp_path):
    """The committed Cramped Room table of the kickstarted family with the bc proxy skipped: before, seed 600
    shipped instead of 601, `best` flipped to cec_teacher and the script exited 0."""
    out = tmp_path / "out"
    out.mkdir()
    _without_bc(SHIPPED / "finetune/teacher/cramped_room.csv.bz2", out / "cramped_room.csv.bz2")
    args = ("--family", "ftteach", "--summarise-only", "--kitchens", "cramped_room")
    done = _script(SHIPPED / "finetune/evaluate.py", *args, "--out", str(out), "--work", str(tmp_path / "w"))
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "refusing to choose" in done.stderr and "'bc_cramped_room'" in done.stderr
    assert DAMAGED in done.stderr
    assert sorted(p.name for p in out.iterdir()) == ["cramped_room.csv.bz2"]  # no summary, no ship.yaml
    assert not (tmp_path / "w" / "ship.yaml").exists()


def test_best_py_refuses_to_choose_without_the_validation_proxy(tmp_path):
    """best.py on the committed tables with Cramped Room's bc proxy skipped: a traceback before."""
    tables = tmp_path / "best"
    shutil.copytree(SHIPPED / "best", tables)
    _without_bc(SHIPPED / "best/cramped_room_bc.csv.bz2", tables / "cramped_room_bc.csv.bz2")
    md = tmp_path / "best.md"
    done = _script(
        SHIPPED / "best.py", "--summarise-only", "--tables", str(tables), "--work", str(tmp_path / "w"),
        "--markdown", str(md),
    )  # fmt: skip
    assert done.returncode == 2, done.stderr
    assert "Traceback" not in done.stderr
    assert "cramped_room: the partner of `--partner best`: refusing to choose" in done.stderr
    assert "'bc_cramped_room'" in done.stderr and DAMAGED in done.stderr
    assert not md.exists() and not (tmp_path / "w" / "best.yaml").exists()
