"""`make up` as a newcomer runs it, in a terminal: Ctrl-C stops the run with a checkpoint, make ends with
status 0 (not "Error 130" or "Interrupt"), and the resume command printed, run as printed, continues the
run where it stopped. The stack is the smallest one: the learner and its actors in one process
(`distributed.pool=local`), no evaluator, Dual Destination (no streamed kitchens)."""

from __future__ import annotations

import json
import re
import shlex
import shutil
import subprocess
import time
from pathlib import Path

import pytest

from tests.terminal import REPO, Terminal

pytestmark = pytest.mark.timeout(600)


def _rows(run: Path) -> list[int]:
    path = run / "metrics.jsonl"
    return [json.loads(line)["update"] for line in path.read_text().splitlines()] if path.exists() else []


def _wait_rows(run: Path, n: int, term: Terminal, timeout: float = 300) -> None:
    deadline = time.monotonic() + timeout
    while len(_rows(run)) < n:
        log = term.log.read_text(errors="replace") if term.log.exists() else ""
        assert term.proc.poll() is None, f"make up ended early:\n{log[-3000:]}"
        assert time.monotonic() < deadline, f"no {n} metrics rows after {timeout} s:\n{log[-3000:]}"
        time.sleep(0.2)


def _interrupt(term: Terminal) -> tuple[int, str]:
    term.ctrl_c()
    try:
        code = term.proc.wait(180)
    finally:
        term.close()
    return code, term.log.read_text(errors="replace")


def test_make_up_stops_on_ctrl_c_with_status_0_and_its_printed_command_continues(tmp_path: Path) -> None:
    for tool in ("make", "setsid", "redis-server"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs {tool}")
    if subprocess.run(["make", "-q", ".venv/.installed"], cwd=REPO).returncode != 0:
        pytest.skip("the project's .venv is not installed by make (make install): make up would install it")
    args = [
        "level_server_port=0", "level_server_metrics_port=-1", "evaluator=false", "distributed.pool=local",
        "distributed.metrics_port=-1", "train=configs/train/dd_ippo_quick.yaml", "train.num_envs=32",
        "train.num_steps=50", "train.total_env_steps=1600000", "train.updates_per_call=1",
        "train.checkpoint.every_updates=1", f"train.run_dir={tmp_path}", "train.name=up",
    ]  # fmt: skip
    run = tmp_path / "up"
    term = Terminal(["make", "up", f"ARGS={shlex.join(args)}"], tmp_path / "first.log")
    _wait_rows(run, 3, term)
    code, text = _interrupt(term)
    assert code == 0, text[-3000:]
    assert "Error 130" not in text and "Interrupt" not in text and "Traceback" not in text, text[-3000:]
    stopped = _rows(run)
    assert stopped == list(range(1, len(stopped) + 1))
    assert sorted((run / "checkpoints").iterdir())[-1].name == f"update_{stopped[-1]:09d}"
    hints = re.findall(r"continue with: (make up ARGS=.*?)\r?$", text, re.MULTILINE)
    assert hints, text[-3000:]
    assert shlex.split(shlex.split(hints[-1])[2].removeprefix("ARGS=")) == ["--resume", *args]
    # the command as printed, typed into a shell in the same terminal
    term = Terminal(["bash", "-c", hints[-1]], tmp_path / "second.log")
    _wait_rows(run, len(stopped) + 2, term)
    code, text = _interrupt(term)
    assert code == 0, text[-3000:]
    more = _rows(run)
    assert more[: len(stopped)] == stopped and more == list(range(1, len(more) + 1)), more
