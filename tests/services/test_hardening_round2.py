"""Second hardening round (issue 44) for services: `cec status` over a run folder an adversary wrote
(run files that never end or have the wrong shapes, metrics URLs of other schemes, slow or huge replies,
NaN in `--json`), and the evaluator given a checkpoint whose parameters are all NaN from its stream."""

from __future__ import annotations

import hashlib
import http.server
import json
import shutil
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import jax
import numpy as np
import pytest

from services import status

ROOT = Path(__file__).resolve().parents[2]
HUGE = status.SCRAPE_MAX_BYTES + 1024  # a reply past the cap (13 MB made an 8 MB error line)


def _status_json(run: Path) -> dict:
    proc = subprocess.run(
        [sys.executable, "-m", "apps.cli", "status", str(run), "--json"],
        cwd=ROOT, capture_output=True, text=True, timeout=60,
    )  # fmt: skip
    assert proc.returncode == 0 and "Traceback" not in proc.stderr, proc.stderr

    def strict(name: str) -> None:
        raise AssertionError(f"{name} in --json output")

    return json.loads(proc.stdout, parse_constant=strict)


def _run(tmp_path: Path) -> Path:
    run = tmp_path / "run"
    (run / "logs").mkdir(parents=True)
    return run


def test_cec_status_reads_run_files_that_never_end_in_bounded_time(tmp_path):
    run = _run(tmp_path)
    for name in ("config.yaml", "metrics.jsonl", status.STACK_FILE, status.CHILDREN_FILE):
        (run / name).symlink_to("/dev/zero")  # each was read until MemoryError
    t0 = time.monotonic()
    out = _status_json(run)
    assert time.monotonic() - t0 < 30
    assert "is not a regular file" in out["config"]["error"] and "config.yaml" in out["config"]["error"]
    assert out["progress"] == {} and "is not a regular file" in out["stack"]["error"]


def test_cec_status_takes_wrong_shapes_and_nan_without_a_traceback(tmp_path):
    run = _run(tmp_path)
    (run / "config.yaml").write_text("- a list\n- not a config\n")
    (run / status.STACK_FILE).write_text("[1, 2, 3]")
    row = {"update": [1], "env_steps": [5], "env_steps_per_s": {"x": 1}, "mean_return": float("nan")}
    (run / "metrics.jsonl").write_text(json.dumps({"update": 1}) + "\n" + json.dumps(row) + "\n")
    out = _status_json(run)
    assert "not a mapping" in out["config"]["error"] and "not a JSON object" in out["stack"]["error"]
    assert "env_steps" not in out["progress"] and "mean_return" not in out["progress"]
    text = subprocess.run(
        [sys.executable, "-m", "apps.cli", "status", str(run)], cwd=ROOT, capture_output=True, text=True,
        timeout=60,
    )  # fmt: skip
    assert text.returncode == 0 and "Traceback" not in text.stderr, text.stderr
    # a NaN in a part that is passed through (a score from the control plane) is null in --json
    assert json.loads(status.to_json({"x": [float("nan"), float("inf"), 1.5]})) == {"x": [None, None, 1.5]}


def test_cec_status_fetches_only_http_urls(tmp_path):
    run = _run(tmp_path)
    secret = tmp_path / "secret.txt"
    secret.write_text("TOP-SECRET first line\n")
    urls = {"level server metrics": secret.as_uri(), "learner metrics": "ftp://127.0.0.1/x"}
    (run / status.STACK_FILE).write_text(json.dumps({"owner": 0, "started_at": 0, "urls": urls}))
    out = _status_json(run)
    for part in ("level_server", "learner"):
        assert "not an http(s) URL" in out[part]["error"]
    assert "TOP-SECRET" not in json.dumps(out)


class _Handler(http.server.BaseHTTPRequestHandler):
    mode = "slow"

    def do_GET(self) -> None:  # noqa: N802 (the standard library's name)
        self.send_response(200)
        self.end_headers()
        try:
            if self.mode == "slow":  # a byte every 0.3 s: each read is within the socket timeout
                for _ in range(200):
                    self.wfile.write(b"#")
                    self.wfile.flush()
                    time.sleep(0.3)
            else:  # a page far larger than any metrics page, with a line Prometheus cannot parse
                self.wfile.write(b"x" * HUGE)
        except OSError:
            pass

    def log_message(self, *args: object) -> None:
        pass


@pytest.fixture
def server() -> Iterator[str]:
    httpd = http.server.ThreadingHTTPServer(("127.0.0.1", 0), _Handler)
    httpd.daemon_threads = True
    thread = threading.Thread(target=httpd.serve_forever, daemon=True)
    thread.start()
    yield f"http://127.0.0.1:{httpd.server_address[1]}/metrics"
    httpd.shutdown()
    httpd.server_close()


def test_a_slow_metrics_server_is_cut_at_the_deadline(server, monkeypatch):
    monkeypatch.setattr(_Handler, "mode", "slow")
    monkeypatch.setattr(status, "HTTP_DEADLINE_S", 1.5)
    t0 = time.monotonic()
    out = status._scrape(server, {"up": "up"})
    assert time.monotonic() - t0 < 1.5 + status.HTTP_TIMEOUT_S + 1
    assert "took longer than 1.5 s" in out["error"] and "HTTP_DEADLINE_S" in out["error"]


def test_a_huge_metrics_reply_is_cut_and_its_error_clipped(server, monkeypatch):
    monkeypatch.setattr(_Handler, "mode", "huge")
    out = status._scrape(server, {"up": "up"})
    assert "sent more than" in out["error"] and "SCRAPE_MAX_BYTES" in out["error"]
    assert len(out["error"]) < 2 * status.ERROR_CHARS
    monkeypatch.setattr(status, "SCRAPE_MAX_BYTES", 2 * HUGE)  # read whole: one unparseable line
    out = status._scrape(server, {"up": "up"})
    assert "did not send Prometheus metrics" in out["error"] and len(out["error"]) < 2 * status.ERROR_CHARS


# ---- the evaluator ----------------------------------------------------------------------------------------


@pytest.mark.skipif(shutil.which("redis-server") is None, reason="needs redis-server")
def test_the_evaluator_fails_an_all_nan_checkpoint_from_its_stream(redis_config, tmp_path):
    from cec import checkpoints
    from services.evaluator.evaluator import FAILED_GROUP, Evaluator
    from services.store import ControlPlane
    from tests.services.test_evaluator import CLASSIC, Checkpoints, _config, _publish

    ckpts = Checkpoints(tmp_path / "runs")
    partner = ckpts.write("zoo-ippo", 10, [5], "ippo")
    zoo = tmp_path / "zoo.yaml"
    zoo.write_text(f"policies:\n  - {{name: ippo_s5, checkpoint: {partner}}}\n")
    path = ckpts.write("cec-nan", 1, [0])
    # every weight NaN and the SHA-256 recomputed, as a diverged run (or an adversary) would leave it
    template = ckpts._templates[1]
    state, _ = checkpoints.load(path, template)
    nan = state._replace(params=jax.tree.map(lambda x: np.full_like(x, np.nan), state.params))
    data = __import__("flax").serialization.to_bytes(jax.device_get(nan))
    (path / checkpoints.STATE_FILE).write_bytes(data)
    meta = json.loads((path / checkpoints.META_FILE).read_text())
    meta["sha256"] = hashlib.sha256(data).hexdigest()
    (path / checkpoints.META_FILE).write_text(json.dumps(meta))

    with ControlPlane.connect(redis_config) as plane:
        event = _publish(plane, path, "cec-nan")
        config = _config(plane, zoo, tmp_path / "results", level_sets=(CLASSIC,))
        with Evaluator(config, plane) as ev:
            outcomes = []
            deadline = time.monotonic() + 60
            while not outcomes and time.monotonic() < deadline:
                outcomes += ev.poll_once(block_s=0.5)
            assert ev.consumer.pending_count() == 0
        [outcome] = outcomes
        assert outcome.status == "failed" and "non-finite parameters" in outcome.error
        [result] = plane.get_results(event.checkpoint_id)
        assert result.partner_group == FAILED_GROUP and "NaN" in result.metrics["error"]
        assert not plane.is_scored(event.checkpoint_id)
