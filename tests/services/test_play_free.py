"""`cec play serve --partner cec`, the README's first play command, through the command a newcomer types: a
real server process with the shipped CEC agents in the default kitchen, serving its page."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import urllib.request
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[2]
pytestmark = pytest.mark.slow


def test_cec_play_serve_partner_cec_serves_the_page_and_stops_on_ctrl_c(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "apps.cli", "play", "serve", "--partner", "cec", "--port", "0"]
    cmd += ["--data", str(tmp_path)]
    proc = subprocess.Popen(
        cmd, cwd=ROOT, env={**os.environ, "JAX_PLATFORMS": "cpu"}, stdout=subprocess.PIPE,
        stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: list[str] = []
    found: dict[str, str] = {}
    ready = threading.Event()

    def pump() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            m = re.search(r"serving study 'free_play' at (http://\S+/)", line)
            if m:
                found["url"] = m.group(1)
                ready.set()
        ready.set()

    threading.Thread(target=pump, daemon=True).start()
    try:
        ready.wait(timeout=180)
        assert "url" in found, "the play server did not start:\n" + "".join(lines)
        with urllib.request.urlopen(found["url"], timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
        proc.send_signal(signal.SIGINT)
        assert proc.wait(timeout=30) == 0, "".join(lines)
    finally:
        if proc.poll() is None:
            proc.kill()
    log = "".join(lines)
    assert "Traceback" not in log, log
    assert "partner partner: 5 policies loaded" in log or "policies loaded" in log, log
