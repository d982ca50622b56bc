"""`cec play`'s caps on what one participant, and the server in all, may make it record (issue 88): free-play
rounds, reconnects (a round started again) and recorded bytes, each a `limits` setting with a default. Past a
cap no round starts, the round's connection says so and the page shows why; the server's byte cap also
refuses joins (503). Driven through the app's ASGI interface, as `tests/services/test_play_hardening.py`."""

from __future__ import annotations

import asyncio
import json
from pathlib import Path
from typing import Any

import pytest

from cec.config import ConfigError, from_dict
from services.play.app import create_app
from services.play.config import StudyConfig
from services.play.game import load_partner
from services.play.recording import FileStore, Recorder
from services.play.study import Study
from tests.services.test_play_hardening import _http, _json_post, _replies, _ws

ROOT = Path(__file__).resolve().parents[2]


def _config(**limits: int) -> StudyConfig:
    return from_dict(
        StudyConfig,
        {
            "name": "capped",
            "levels": ["cramped_room"],
            "partners": [{"name": "a", "random_init": True}],
            "env": {"max_steps": 2, "random_start_facing": False},
            "survey": {"items": []},
            "free_play": True,
            "limits": limits,
        },
    )


@pytest.fixture(scope="module")
def pools() -> dict[str, Any]:
    return {p.name: load_partner(p, ROOT) for p in _config().partners}


def _server(tmp_path: Path, pools: dict[str, Any], **limits: int) -> tuple[Study, Any, FileStore]:
    store = FileStore(tmp_path, "capped")
    study = Study(_config(**limits), ROOT, pools, Recorder([store]))
    return study, create_app(study), store


def _joined(app: Any) -> str:
    status, headers, _, _ = asyncio.run(_http(app, "POST", "/api/join", [b"{}"], _json_post(b"{}")))
    assert status == 200
    token = headers["set-cookie"].split("=", 1)[1].split(";", 1)[0]
    body = json.dumps({"stage": "instructions"}).encode()
    status, _, _, _ = asyncio.run(_http(app, "POST", "/api/submit", [body], _json_post(body, token)))
    assert status == 200
    return token


def _state(app: Any, token: str) -> dict[str, Any]:
    headers = {"cookie": f"cec_play={token}"}
    return asyncio.run(_http(app, "GET", "/api/state", [], headers))[2]


def _types(store: FileStore, study: Study) -> list[str]:
    (pid,) = store.participants()
    return [e["type"] for e in store.events(pid)]


def test_one_cookie_reconnecting_300_times_stops_recording_at_its_cap(tmp_path, pools):
    """Before: every reconnect recorded the round's start again (and its abort), without end: one cookie
    reconnecting 300 times in 3.5 s wrote about 180 MB an hour without playing."""
    study, app, store = _server(tmp_path, pools, max_reconnects_per_participant=20)
    token = _joined(app)
    first = [_replies(asyncio.run(_ws(app, token, []))) for _ in range(21)]
    assert all(r[0]["type"] == "start" for r in first)  # the first start and 20 restarts
    (path,) = store.dir.glob("p*.jsonl")
    size = path.stat().st_size
    for _ in range(279):
        (reply,) = _replies(asyncio.run(_ws(app, token, [])))
        assert reply["type"] == "error" and reply["fatal"] and reply["capped"]
        assert reply["limit"] == "limits.max_reconnects_per_participant"
    assert path.stat().st_size == size  # nothing recorded past the cap
    assert _types(store, study).count("round_start") == 21
    page = _state(app, token)
    assert page["stage"] == "capped" and page["limit"] == "limits.max_reconnects_per_participant"
    assert "started again 20 times" in page["text"]


def _play_round(app: Any, token: str) -> list[dict[str, Any]]:
    acts = [json.dumps({"type": "act", "t": t, "action": 4, "rt_ms": 5}) for t in range(2)]
    return _replies(asyncio.run(_ws(app, token, acts)))


def test_free_play_stops_starting_rounds_at_its_cap_and_says_so(tmp_path, pools):
    study, app, store = _server(tmp_path, pools, max_rounds_per_participant=3)
    token = _joined(app)
    for _ in range(3):
        assert _play_round(app, token)[-1]["type"] == "end"
    page = _state(app, token)
    assert page["stage"] == "capped" and page["limit"] == "limits.max_rounds_per_participant"
    assert "You have played 3 rounds" in page["text"] and len(page["played"]) == 3
    (reply,) = _play_round(app, token)
    assert reply["capped"] and reply["limit"] == "limits.max_rounds_per_participant"
    assert _types(store, study).count("round_end") == 3 and _types(store, study).count("round_start") == 3


def test_a_participant_past_their_byte_cap_finishes_the_round_under_way_and_starts_no_other(tmp_path, pools):
    study, app, store = _server(tmp_path, pools, max_record_bytes_per_participant=4_096)
    token = _joined(app)
    rounds = 0
    while _state(app, token)["stage"] == "round":
        assert _play_round(app, token)[-1]["type"] == "end"  # a round started is recorded to its end
        rounds += 1
    assert rounds >= 1 and _state(app, token)["limit"] == "limits.max_record_bytes_per_participant"
    (path,) = store.dir.glob("p*.jsonl")
    assert 4_096 <= path.stat().st_size < 4_096 + 4_096  # at most one round past the cap
    (reply,) = _play_round(app, token)
    assert reply["capped"] and _types(store, study).count("round_start") == rounds


def test_the_servers_byte_cap_refuses_joins_with_503_also_after_a_restart(tmp_path, pools):
    study, app, store = _server(tmp_path, pools, max_record_bytes=4_096)
    token = _joined(app)
    while _state(app, token)["stage"] == "round":
        _play_round(app, token)
    assert _state(app, token)["limit"] == "limits.max_record_bytes"
    status, _, body, _ = asyncio.run(_http(app, "POST", "/api/join", [b"{}"], _json_post(b"{}")))
    assert status == 503 and body["limit"] == "limits.max_record_bytes"
    again, app2, _ = _server(tmp_path, pools, max_record_bytes=4_096)  # the records of earlier runs count
    again.restore({pid: store.events(pid) for pid in store.participants()})
    status, _, body, _ = asyncio.run(_http(app2, "POST", "/api/join", [b"{}"], _json_post(b"{}")))
    assert status == 503 and "the most it records" in body["error"]


@pytest.mark.parametrize(
    ("key", "value"),
    [("max_rounds_per_participant", 0), ("max_reconnects_per_participant", -1), ("max_record_bytes", 100)],
)
def test_the_caps_are_settings_with_finite_ranges(key, value):
    with pytest.raises(ConfigError, match=f"limits.{key} must lie in"):
        _config(**{key: value})
