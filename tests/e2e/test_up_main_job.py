"""`make up`'s main job as a newcomer meets it, at a test's size: `cec up` with the default preset (CEC on
kitchens the level server streams, two seeds of the kickstarted recipe, the evaluator with the shipped
partners) starts the level server, the actors train on streamed kitchens, the start-up says what is not the
paper's method, and the evaluator's cross-play of the two seeds on validation kitchens arrives in `cec
status`, during the run and after it stopped. Sizes: 8 envs x 32 steps, 32-step episodes, a checkpoint every
2 updates, the evaluator on 2 validation kitchens with the kickstarted seeds as its zoo
(`evaluator_main_small.yaml`); the learner and its actors in the driver's process
(`distributed.pool=local`)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import time
from pathlib import Path

import pytest

pytestmark = pytest.mark.timeout(900)
REPO = Path(__file__).resolve().parents[2]


def _cec(*args: str) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "apps.cli", *args], cwd=REPO, capture_output=True, text=True,
                          timeout=120)  # fmt: skip


def test_the_main_job_streams_kitchens_and_its_cross_play_reaches_cec_status(tmp_path: Path) -> None:
    cmd = [
        sys.executable, "-m", "apps.cli", "up", "level_server_port=0", "level_server_metrics_port=0",
        "evaluator_metrics_port=-1", "distributed.pool=local", "distributed.metrics_port=-1",
        "evaluator_config=" + str(REPO / "tests/e2e/evaluator_main_small.yaml"),
        "train.num_envs=8", "train.num_steps=32", "train.env.overcooked.max_steps=32",
        "train.total_env_steps=5120", "train.ppo.teacher_anneal_env_steps=5120",
        "train.ppo.num_minibatches=2",
        "train.checkpoint.every_updates=2", f"train.run_dir={tmp_path}", "train.name=main",
    ]  # fmt: skip
    log_path = tmp_path / "up.log"
    with open(log_path, "w") as log:
        proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    run = tmp_path / "main"
    try:
        deadline = time.monotonic() + 780
        status: dict = {}
        while time.monotonic() < deadline:  # the first figure, through the command a user runs, while it runs
            assert proc.poll() is None, log_path.read_text()[-3000:]
            done = _cec("status", str(run), "--json")
            status = json.loads(done.stdout) if done.returncode == 0 else {}
            if any(r["partner_group"] == "cross_play" for r in status.get("record", {}).get("latest", [])):
                break
            time.sleep(2)
        latest = {(r["partner_group"], r["level_set"]): r for r in status["record"]["latest"]}
        cross = latest[("cross_play", "validation")]
        assert cross["episodes"] == 2 * 2 and cross["return_mean"] is not None, (
            latest
        )  # 2 kitchens, both seats
        assert ("cec_teacher", "validation") in latest and ("self_play", "validation") in latest
        screen = _cec("status", str(run)).stdout
        assert re.search(r"cross_play\s+validation\s+return \S+ \(4 episodes\)", screen), screen
        # the run finishes; the stack waits for the evaluator to score its last checkpoints, then stops
        assert proc.wait(max(1.0, deadline - time.monotonic())) == 0, log_path.read_text()[-3000:]
        text = log_path.read_text()
        assert "level server           grpc://" in text, text[-3000:]
        assert (
            "2 seeds (0..1)" in text
            and "not the paper's method: this run learns from the scripted cook" in text
        )
        assert "it has scored every checkpoint of the run" in text, text[-3000:]
        rows = [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]
        assert max(r["levels_buffered"] for r in rows) > 0, "the actors hold kitchens streamed to them"
        assert {r["seed"] for r in rows} == {0, 1}
        after = _cec("status", str(run)).stdout  # the stack has stopped, Redis with it: the record remains
        assert "no `cec up` running" in after and "scored; update 20:" in after, after
        assert re.search(r"cross_play\s+validation\s+return", after), after
    finally:
        if proc.poll() is None:
            proc.kill()
