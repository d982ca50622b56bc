"""`cec up` through its entry point in a terminal, as a person waits for it: a line at least every 10 s from
the command to the first update, through the level server's warm-up (the kitchen generator compiled before
it serves, announced and reported while it lasts) and the learner's compile (a heartbeat until its first
metrics row); and a preset that does not stream kitchens starts no level server at all."""

from __future__ import annotations

import re
import shutil
import sys
import time
from pathlib import Path

import pytest

from tests.terminal import REPO, Terminal

pytestmark = pytest.mark.timeout(900)

MAX_SILENCE_S = 10.0


def _entry_point() -> list[str]:
    cec = Path(sys.executable).with_name("cec")
    return [str(cec)] if cec.exists() else [sys.executable, "-m", "apps.cli"]


def _lines_until_first_update(term: Terminal, run: Path, timeout: float) -> list[tuple[float, str]]:
    """(seconds since the start, line) of every line the terminal shows until `run` has a metrics row."""
    start = time.monotonic()
    seen: list[tuple[float, str]] = []
    metrics = run / "metrics.jsonl"
    while not (metrics.exists() and metrics.read_text().strip()):
        text = term.log.read_text(errors="replace") if term.log.exists() else ""
        lines = [line.rstrip("\r") for line in text.split("\n")[:-1]]
        now = time.monotonic() - start
        seen += [(now, line) for line in lines[len(seen) :]]
        shown = "\n".join(f"{t:6.1f} s  {line}" for t, line in seen)
        assert term.proc.poll() is None, f"cec up ended before its first update:\n{shown}"
        assert now < timeout, f"no update within {timeout:.0f} s:\n{shown}"
        time.sleep(0.1)
    return seen


def test_cec_up_prints_a_line_at_least_every_10_s_until_the_first_update(tmp_path: Path) -> None:
    if shutil.which("redis-server") is None or shutil.which("setsid") is None:
        pytest.skip("needs redis-server and setsid")
    args = [
        "level_server_port=0", "level_server_metrics_port=-1", "evaluator=false", "distributed.pool=local",
        "distributed.metrics_port=-1", "train=configs/train/cramped_room_ci.yaml",
        "train.algorithm=cec", "train.env.levels=generator", "train.num_envs=16", "train.num_steps=32",
        f"train.run_dir={tmp_path}", "train.name=up",
    ]  # fmt: skip
    term = Terminal([*_entry_point(), "up", *args], tmp_path / "up.log")
    try:
        seen = _lines_until_first_update(term, tmp_path / "up", timeout=780)
        term.ctrl_c()
        term.proc.wait(180)
    finally:
        term.close()
    shown = "\n".join(f"{t:6.1f} s  {line}" for t, line in seen)
    print(f"\n{shown}")
    times = [0.0, *(t for t, _ in seen)]
    gaps = [b - a for a, b in zip(times, times[1:], strict=False)]
    assert max(gaps) <= MAX_SILENCE_S, f"a silence of {max(gaps):.1f} s:\n{shown}"
    text = "\n".join(line for _, line in seen)
    assert "level server           starting: it compiles the kitchen generator first" in text, shown
    assert re.search(r"level server\s+grpc://", text), shown


def test_a_preset_on_fixed_kitchens_starts_no_level_server(tmp_path: Path) -> None:
    """`--max-updates 1` on Dual Destination: the stack says why there is no level server, and trains."""
    if shutil.which("redis-server") is None or shutil.which("setsid") is None:
        pytest.skip("needs redis-server and setsid")
    args = [
        "--max-updates", "1", "evaluator=false", "distributed.pool=local", "distributed.metrics_port=-1",
        "train=configs/train/dd_ippo_quick.yaml", "train.num_envs=16", "train.num_steps=20",
        f"train.run_dir={tmp_path}", "train.name=up",
    ]  # fmt: skip
    term = Terminal([*_entry_point(), "up", *args], tmp_path / "up.log", cwd=REPO)
    try:
        code = term.proc.wait(600)
    finally:
        term.close()
    text = term.log.read_text(errors="replace")
    assert code == 0, text[-3000:]
    assert "level server           not started: the preset's kitchens (env.levels=fixed)" in text, text[
        -3000:
    ]
    assert not (tmp_path / "up" / "logs" / "level_server.log").exists()
