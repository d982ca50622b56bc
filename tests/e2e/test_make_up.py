"""`make up` as a newcomer runs it, in a terminal: Ctrl-C stops the run with a checkpoint, make ends with
status 0 (not "Error 130" or "Interrupt"), and the resume command printed, run as printed, continues the
run where it stopped; a Ctrl-C while `cec up` is still loading (seconds of imports, before anything
starts) stops it with status 0 too. The stack is the smallest one: the learner and its actors in one process
(`distributed.pool=local`), no evaluator, Dual Destination (no streamed kitchens)."""

from __future__ import annotations

import json
import os
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
    """The updates of the run's metrics rows (one row per update and seed: those of its first seed)."""
    path = run / "metrics.jsonl"
    rows = [json.loads(line) for line in path.read_text().splitlines()] if path.exists() else []
    first = min((r["seed"] for r in rows), default=0)
    return [r["update"] for r in rows if r["seed"] == first]


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


def _needs_make_up() -> None:
    for tool in ("make", "setsid", "redis-server"):
        if shutil.which(tool) is None:
            pytest.skip(f"needs {tool}")
    if subprocess.run(["make", "-q", ".venv/.installed"], cwd=REPO).returncode != 0:
        pytest.skip("the project's .venv is not installed by make (make install): make up would install it")


def _args(tmp_path: Path) -> list[str]:
    return [
        "level_server_port=0", "level_server_metrics_port=-1", "evaluator=false", "distributed.pool=local",
        "distributed.metrics_port=-1", "train=configs/train/dd_ippo_quick.yaml", "train.num_envs=32",
        "train.num_steps=50", "train.total_env_steps=1600000", "train.updates_per_call=1",
        "train.checkpoint.every_updates=1", f"train.run_dir={tmp_path}", "train.name=up",
    ]  # fmt: skip


def test_make_up_stops_on_ctrl_c_with_status_0_and_its_printed_command_continues(tmp_path: Path) -> None:
    _needs_make_up()
    args = _args(tmp_path)
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


def test_make_up_stopped_while_cec_up_loads_ends_with_status_0(tmp_path: Path) -> None:
    """The newcomer's Ctrl-C in the first seconds, while `cec up` imports JAX and Ray and nothing has started:
    it reached make too, which said "Interrupt" (at once, or when the run ended: `cec up` could lose it and
    train on). The Ctrl-C is typed the moment make's recipe has the terminal's foreground for its own group
    (apps/make_up.py), seconds before its imports end."""
    _needs_make_up()
    term = Terminal(["make", "up", f"ARGS={shlex.join(_args(tmp_path))}"], tmp_path / "early.log")
    deadline = time.monotonic() + 120
    for make_has_it in (True, False):  # the terminal's foreground: make's group, then the recipe's own
        while (os.tcgetpgrp(term.master) == term.proc.pid) != make_has_it:
            log = term.log.read_text(errors="replace") if term.log.exists() else ""
            assert term.proc.poll() is None and time.monotonic() < deadline, log
            time.sleep(0.01)
    code, text = _interrupt(term)
    assert code == 0, text[-3000:]
    assert "Interrupt" not in text and "Traceback" not in text, text[-3000:]
    assert "cec up: stopped by Ctrl-C while it was loading; nothing was started" in text, text[-3000:]
    assert not (tmp_path / "up").exists(), "nothing started: no run directory, no Redis"
