"""`cec up --monitoring` end to end: every series a dashboard reads is on some live `/metrics` of the
running stack, and Prometheus' scraped counters move with the run's own records."""

from __future__ import annotations

import json
import re
import shutil
import signal
import subprocess
import sys
import time
import urllib.parse
import urllib.request
from pathlib import Path

import pytest
from prometheus_client.parser import text_string_to_metric_families

from services.monitoring import dashboard_metric_names

pytest.importorskip("ray")
pytestmark = pytest.mark.timeout(600)
REPO = Path(__file__).resolve().parents[2]
MLP = [
    "train.network_overrides.conv_features=[]",
    "train.network_overrides.encoder_features=[32]",
    "train.network_overrides.lstm_features=0",
    "train.network_overrides.actor_features=[32]",
    "train.network_overrides.critic_features=[32]",
]


SERVICE_URL = re.compile(
    r"^(learner metrics|level server metrics|evaluator metrics|prometheus)\s+(https?://\S+)", re.M
)


def _get(url: str) -> str:
    with urllib.request.urlopen(url, timeout=10) as r:
        return str(r.read().decode())


def _series(url: str) -> dict[str, float]:
    out: dict[str, float] = {}
    for family in text_string_to_metric_families(_get(url)):
        for sample in family.samples:
            out[sample.name] = out.get(sample.name, 0.0) + float(sample.value)  # summed over labels
    return out


def _prom(base: str, query: str) -> float | None:
    data = json.loads(_get(f"{base}/api/v1/query?query={urllib.parse.quote(query)}"))
    result = data["data"]["result"]
    return float(result[0]["value"][1]) if result else None


def _cec(*args: str) -> str:
    done = subprocess.run([sys.executable, "-m", "apps.cli", *args], capture_output=True, text=True, cwd=REPO)
    assert done.returncode == 0, done.stderr
    return done.stdout


def _rows(run_dir: Path) -> int:
    path = run_dir / "metrics.jsonl"
    return len(path.read_text().splitlines()) if path.exists() else 0


@pytest.mark.skipif(shutil.which("prometheus") is None, reason="needs Debian's prometheus package")
def test_dashboards_read_only_live_series_and_scraped_counters_follow_the_run(tmp_path: Path) -> None:
    cmd = [
        sys.executable, "-m", "apps.cli", "up", "--monitoring",
        "--config", str(REPO / "configs/up/smoke.yaml"),
        "level_server_port=0", "level_server_metrics_port=0", "evaluator_metrics_port=0",
        "ray_dashboard=false", "distributed.metrics_port=0", "distributed.ray_num_cpus=4",
        "monitoring_config.prometheus_port=0", "monitoring_config.scrape_interval_s=1",
        "evaluator_config=" + str(REPO / "tests/e2e/evaluator_small.yaml"),
        "train.algorithm=cec", "train.env.levels=generator", "train.env.overcooked.max_steps=16", *MLP,
        "train.num_envs=8", "train.num_steps=32", "train.total_env_steps=2560000",
        "train.ppo.num_minibatches=2",
        "train.checkpoint.every_updates=5", f"train.run_dir={tmp_path}", "train.name=metrics",
    ]  # fmt: skip
    log_path = tmp_path / "up.log"
    log = open(log_path, "w")  # noqa: SIM115
    proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, cwd=REPO)
    run_dir = tmp_path / "metrics"
    try:
        urls: dict[str, str] = {}
        deadline = time.monotonic() + 300
        while time.monotonic() < deadline and len(urls) < 4:
            for name, url in SERVICE_URL.findall(log_path.read_text()):
                urls[name] = url
            assert proc.poll() is None, log_path.read_text()[-3000:]
            time.sleep(0.5)
        assert len(urls) == 4, log_path.read_text()[-3000:]
        prom = urls["prometheus"].rstrip("/")
        # run until the evaluator has scored a checkpoint, so that every component has reported
        while _series(urls["evaluator metrics"]).get("cec_evaluator_checkpoints_scored_total", 0) < 1:
            assert time.monotonic() < deadline + 200, "the evaluator scored nothing"
            assert proc.poll() is None, log_path.read_text()[-3000:]
            time.sleep(1)
        live: set[str] = set()
        for key in ("learner metrics", "level server metrics", "evaluator metrics"):
            live |= set(_series(urls[key]))
        missing = dashboard_metric_names() - live
        assert not missing, f"dashboards read series no component exports: {sorted(missing)}"

        learner = _series(urls["learner metrics"])
        rows = _rows(run_dir)
        assert abs(learner["cec_learner_updates_total"] - rows) <= 1, (
            "the counter is the run's own update count"
        )
        per_update = 8 * 32
        assert learner["cec_learner_env_steps_total"] == learner["cec_learner_updates_total"] * per_update
        # each job serves only its own families: one series per metric, from the learner
        assert _prom(prom, "count(cec_learner_updates_total)") == 1
        assert "cec_learner_updates_total" not in _series(urls["evaluator metrics"])
        updates = 'cec_learner_updates_total{job="learner"}'
        first = None
        while first is None or (_prom(prom, updates) or 0) <= first:
            assert time.monotonic() < deadline + 400, "Prometheus' scraped counter did not move"
            first = first if first is not None else _prom(prom, updates)
            time.sleep(1)
        scraped = _prom(prom, updates)
        assert scraped is not None and scraped <= _rows(run_dir), "Prometheus never runs ahead of the run"
        ckpts = _prom(prom, 'cec_learner_checkpoints_total{job="learner"}')
        assert ckpts is not None and 1 <= ckpts <= _rows(run_dir) // 5 + 1, "one checkpoint per 5 updates"

        # `cec status` on the live run: one screen from the run files, Redis and the services' endpoints
        status = json.loads(_cec("status", str(run_dir), "--json"))
        assert status["stack"]["state"] == "running" and all(status["stack"]["services"].values())
        assert status["progress"]["update"] >= 5 and status["checkpoint"]["name"].startswith("update_")
        plane = status["control_plane"]
        assert plane["run_status"] == "running" and plane["latest_scored"].startswith("metrics/update_")
        assert {(r["partner_group"], r["level_set"]) for r in plane["scores"]} == {("self_play", "classic")}
        assert status["level_server"]["levels_sent"] > 0 and status["learner"]["policy_version"] >= 1
        screen = _cec("status", str(run_dir))
        assert (
            "running (pid" in screen and "checkpoint(s) scored; update " in screen and "levels sent" in screen
        )
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(300) == 130
        assert "no `cec up` running" in _cec("status", str(run_dir)), "the stopped stack says so"
    finally:
        if proc.poll() is None:
            proc.kill()
        log.close()
