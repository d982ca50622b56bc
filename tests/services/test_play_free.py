"""`cec play serve --partner cec`, the README's first play command, through the command a newcomer types: a
real server process with the shipped CEC agents in the default kitchen, serving its page."""

from __future__ import annotations

import signal
import urllib.request
from pathlib import Path

import pytest

from tests.play_server import PlayServer

pytestmark = pytest.mark.slow


def test_cec_play_serve_partner_cec_serves_the_page_and_stops_on_ctrl_c(tmp_path: Path) -> None:
    server = PlayServer(["--partner", "cec", "--port", "0", "--data", str(tmp_path)], None)
    try:
        with urllib.request.urlopen(server.url, timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    seeds = ", ".join(f"cec758m-s{s} (cec)" for s in range(200, 204))
    assert f"free play's partner: 4 policies loaded: {seeds}\n" in server.log, server.log


def test_cec_play_serve_partner_best_plays_the_partner_chosen_for_the_kitchen(tmp_path: Path) -> None:
    """The README's second play command: in Forced Coordination what best.yaml names (one shipped policy,
    or every seed of a shipped group), loaded and nothing else, and the log names it (it said "partner
    partner: 1 policies loaded")."""
    from cec.agents.zoo import best_shipped, shipped_entries

    choice = best_shipped("forced_coord")
    named = [e for e in shipped_entries() if choice in (e.name, e.algorithm)]
    assert named, choice
    cmd = ["--partner", "best", "--level", "forced_coord", "--port", "0", "--data", str(tmp_path)]
    server = PlayServer(cmd, None)
    try:
        with urllib.request.urlopen(server.url, timeout=30) as page:
            assert page.status == 200
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    assert f"--partner best in forced_coord: {choice} (chosen there by cec/shipped/best.yaml)" in server.log
    loaded = ", ".join(f"{e.name} ({e.algorithm})" for e in named)
    count = "1 policy" if len(named) == 1 else f"{len(named)} policies"
    assert f"free play's partner: {count} loaded: {loaded}\n" in server.log, server.log


def test_a_busy_port_is_refused_before_the_partners_load(tmp_path: Path) -> None:
    import socket
    import subprocess
    import sys

    from tests.play_server import ROOT

    # a port that is no TCP port: refused by name before anything loads (was an OverflowError traceback)
    cmd = [sys.executable, "-m", "apps.cli", "play", "serve", "--partner", "cec", "--port", "70000"]
    proc = subprocess.run(
        cmd + ["--data", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 2 and "--port must be a TCP port in 1..65535" in proc.stderr, proc.stderr[
        -2000:
    ]
    assert "policies loaded" not in proc.stderr and "Traceback" not in proc.stderr
    with socket.socket() as held:
        held.bind(("127.0.0.1", 0))
        held.listen()
        port = held.getsockname()[1]
        cmd = [sys.executable, "-m", "apps.cli", "play", "serve", "--partner", "cec", "--port", str(port)]
        proc = subprocess.run(
            cmd + ["--data", str(tmp_path)], cwd=ROOT, capture_output=True, text=True, timeout=120
        )
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert f"cannot listen on 127.0.0.1:{port}" in proc.stderr and "choose another --port" in proc.stderr
    assert "policies loaded" not in proc.stderr and "Traceback" not in proc.stderr  # nothing loaded first
