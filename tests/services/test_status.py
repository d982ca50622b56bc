"""`cec status` from the files a run writes (the live `cec up` case is in tests/e2e/test_stack_metrics.py)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from apps.cli import main
from services.processes import ChildRecord
from services.status import collect, find_run, render, write_stack_file


def _run(root: Path, name: str = "r") -> Path:
    run = root / name
    (run / "checkpoints" / "update_000000010").mkdir(parents=True)
    (run / "checkpoints" / "update_000000020").mkdir()
    cfg = {"algorithm": "cec", "total_env_steps": 1000, "env": {"name": "overcooked", "levels": "generator"}}
    (run / "config.yaml").write_text(yaml.safe_dump(cfg))
    rows = [
        {"update": u, "env_steps": 25 * u, "mean_return": 0.5 * u, "env_steps_per_s": 50.0} for u in (1, 20)
    ]
    text = "".join(json.dumps(r) + "\n" for r in rows)
    (run / "metrics.jsonl").write_text(text + '{"update": 21, "env_st')  # a row being written
    return run


def test_status_reads_progress_checkpoints_and_eta_from_the_run_files(tmp_path: Path, capsys) -> None:
    run = _run(tmp_path)
    (run / ".lock").write_text(str(os.getpid()))  # a live process trains it
    s = collect(run)
    assert s["progress"]["update"] == 20 and s["checkpoint"]["name"] == "update_000000020"
    assert s["stack"]["state"] == "none" and s["control_plane"] == {}
    screen = render(s)
    assert "env steps 500 / 1,000 (50.0%)" in screen and "ETA 10 s" in screen and "return 10" in screen
    assert "update_000000020" in screen and "(2 on disk)" in screen
    assert find_run(tmp_path) == run
    # What a `cec up` that failed after starting Redis leaves: newer, but not a run.
    failed = tmp_path / "failed-start"
    for sub in ("logs", "redis"):
        (failed / sub).mkdir(parents=True)
    (failed / "logs" / "level_server.log").write_text("error\n")
    assert find_run(tmp_path) == run
    assert main(["status", str(run)]) == 0 and "no `cec up` running" in capsys.readouterr().out
    assert main(["status", str(tmp_path / "gone")]) == 2
    assert "does not exist" in capsys.readouterr().err
    # Several seeds: env steps count per seed, the rate is every seed's together (the learner's line)
    config = yaml.safe_load((run / "config.yaml").read_text())
    (run / "config.yaml").write_text(yaml.safe_dump({**config, "num_seeds": 6}))
    screen = render(collect(run))
    assert "env steps 500 / 1,000 (50.0%)  50 steps/s (6 seeds)  ETA 60 s" in screen, screen


def test_a_stopped_run_says_where_it_stopped_and_how_to_continue_without_an_eta(tmp_path: Path) -> None:
    """No process holds the run (its lock names a process that is gone): no ETA, but the update it stopped
    at and the command that continues it: `cec train --resume` for a `cec train` run, the recorded command
    for a distributed one (`cec up` records its own)."""
    run = _run(tmp_path)
    gone = subprocess.run([sys.executable, "-c", "import os; print(os.getpid())"], capture_output=True)
    (run / ".lock").write_text(gone.stdout.decode().strip())
    screen = render(collect(run))
    assert "ETA" not in screen and "env steps 500 / 1,000 (50.0%)" in screen
    assert f"interrupted at update 20; continue with: cec train --resume {run}" in screen
    (run / "logs").mkdir()
    (run / "logs" / "resume_command").write_text("make up ARGS=--resume\n")
    assert "interrupted at update 20; continue with: make up ARGS=--resume" in render(collect(run))
    with (run / "metrics.jsonl").open("a") as f:  # the last row's budget reached: finished
        f.write('\n{"update": 40, "env_steps": 1000, "env_steps_per_s": 50.0}\n')
    screen = render(collect(run))
    assert "finished" in screen and "continue" not in screen and "ETA" not in screen


def test_the_evaluators_training_record_shows_during_and_after_the_run(tmp_path: Path, capsys) -> None:
    """The evaluator's scores come from the run's record on disk (no stack, no Redis: it has stopped): the
    newest checkpoint's per partner group and level set, with where each started."""
    from cec.evaluation.checkpoint_results import ResultFiles

    run = _run(tmp_path)
    ResultFiles(tmp_path, "r", 10).record(10, 250, [("cross_play", "validation", {"return_mean": 12.5,
                                                    "return_sem": None, "episodes": 40})])  # fmt: skip
    latest = [
        ("cross_play", "validation", {"return_mean": 44.0, "return_sem": 3.5, "episodes": 40}),
        ("human_proxy", "classic", {"return_mean": 30.0, "return_sem": 2.0, "episodes": 60}),
        ("human_proxy", "validation", {"return_mean": None, "return_sem": None, "episodes": 0}),
        ("cec_teacher", "validation", {"return_mean": None, "return_sem": None, "episodes": 0}),
    ]
    ResultFiles(tmp_path, "r", 20).record(20, 500, latest)
    screen = render(collect(run))
    assert "2 checkpoint(s) scored; update 20" in screen, screen
    assert "cross_play" in screen and "return 44 ± 3.5 (40 episodes); 12.5 at update 10" in screen, screen
    # a group that plays in some sets only (the proxies: their own classic kitchens) shows where it played;
    # a group that played nowhere (no loadable partner of it) says so
    assert "human_proxy          classic      return 30 ± 2 (60 episodes)" in screen, screen
    assert "human_proxy          validation" not in screen, screen
    assert "cec_teacher          validation   return - (0 episodes)" in screen, screen
    # a torn record (a disk that filled up mid-write is never left: it is renamed into place) reads as none
    (run / "eval" / "record.csv").write_bytes(b"\xff\x00garbage")
    assert "checkpoint(s) scored" not in render(collect(run))
    assert main(["status", str(run)]) == 0
    assert "Traceback" not in capsys.readouterr().err


def test_a_dead_stack_and_its_down_services_are_named(tmp_path: Path) -> None:
    run = _run(tmp_path)
    code = "import time; print('ready', flush=True); time.sleep(60)"
    child = subprocess.Popen([sys.executable, "-c", code], stdout=subprocess.PIPE, text=True)
    try:
        assert child.stdout is not None and child.stdout.readline() == "ready\n"  # its own command line now
        record = ChildRecord(run / "logs" / "children.json")
        record.add("level server", child.pid)
        record.add("evaluator", 2**22 + 7)  # no such process
        write_stack_file(run, {"redis": "redis://127.0.0.1:1/0"}, redis_needs_password=False)
        s = collect(run)
        assert s["stack"]["state"] == "running" and s["stack"]["pid"] == os.getpid()
        assert s["stack"]["services"] == {"level server": True, "evaluator": False}
        assert "did not answer" in s["control_plane"]["error"], "an unreachable Redis is shown, not raised"
        assert "level server up, evaluator DOWN" in render(s)
        info = json.loads((run / "logs" / "stack.json").read_text())
        (run / "logs" / "stack.json").write_text(json.dumps({**info, "owner": 2**22 + 9}))
        assert "NOT running" in render(collect(run))
    finally:
        child.kill()
        child.wait()


@pytest.mark.parametrize("masked", ["redis://:***@127.0.0.1:6379/0"])
def test_a_masked_redis_url_asks_for_the_password(tmp_path: Path, masked: str) -> None:
    run = _run(tmp_path)
    write_stack_file(run, {"redis": masked}, redis_needs_password=True)
    assert "--redis" in collect(run)["control_plane"]["error"]


def test_status_without_a_run_says_there_is_none_and_how_to_start_one(tmp_path: Path) -> None:
    """`cec status` in a fresh clone (no runs/): not an error of any config, but "no run yet" and the commands
    that start one; `--watch` waits for the run and shows it once it writes its first row."""
    cmd = [sys.executable, "-m", "apps.cli", "status"]
    proc = subprocess.run(cmd, cwd=tmp_path, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 1 and proc.stdout == "", proc.stderr
    assert proc.stderr.startswith("cec status: no run under runs/ yet. Start one: `make up` or `cec up`"), (
        proc.stderr
    )
    assert "cec train --config configs/train/cramped_room_ci.yaml" in proc.stderr
    assert "config error" not in proc.stderr and "Traceback" not in proc.stderr
    watch = subprocess.Popen(
        [*cmd, "--watch", "0.2"], cwd=tmp_path, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True
    )
    try:
        assert watch.stdout is not None
        screens = (line for line in watch.stdout)
        assert any("no run under runs/ yet" in line for line in screens)
        _run(tmp_path / "runs", "late")  # a run starts while it watches
        assert any("late  cec on overcooked/generator" in line for line in screens)
        watch.send_signal(signal.SIGINT)
        assert watch.wait(30) == 0
    finally:
        watch.kill()
        watch.wait()
