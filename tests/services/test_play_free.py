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
    server = PlayServer(["--partner", "cec", "--port", "0", "--data", str(tmp_path)], "free_play")
    try:
        with urllib.request.urlopen(server.url, timeout=30) as page:
            assert page.status == 200 and b"<html" in page.read().lower()
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    assert "partner partner: 4 policies loaded" in server.log, server.log
