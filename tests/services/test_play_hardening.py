"""`cec play` against hostile or careless clients (issue 23): record files open only while written, joins
bounded per address and overall (429/503 naming the limit), bodies read only up to their limit (413),
malformed JSON bodies and WebSocket messages answered with a message, never a 500 or a traceback.

The app is driven through ASGI directly (no sockets): fast, and every exception the app lets through
fails the test. `benchmarks/play_joins_soak.py` runs the same over loopback against a real server.
"""

from __future__ import annotations

import asyncio
import json
import logging
import os
from collections.abc import Iterable, Iterator
from pathlib import Path
from typing import Any

import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from cec.config import ConfigError, from_dict
from services.play.app import COOKIE, MAX_BODY_BYTES, create_app
from services.play.config import StudyConfig
from services.play.game import load_partner
from services.play.limits import MAX_JSON_DEPTH, RateLimiter, json_depth, parse_json
from services.play.limits import JSONInputError as LimitsJSONError
from services.play.recording import FileStore, Recorder
from services.play.study import JoinRefusedError, Study

ROOT = Path(__file__).resolve().parents[2]


def _config(**changes: Any) -> StudyConfig:
    data: dict[str, Any] = {
        "name": "hardening",
        "levels": ["cramped_room"],
        "partners": [{"name": "a", "random_init": True}],
        "env": {"max_steps": 1000, "random_start_facing": False},
        "survey": {"items": []},
    }
    data.update(changes)
    return from_dict(StudyConfig, data)


@pytest.fixture(scope="module")
def pools() -> dict[str, Any]:
    return {p.name: load_partner(p, ROOT) for p in _config().partners}


class Clock:
    def __init__(self) -> None:
        self.now = 1000.0

    def __call__(self) -> float:
        return self.now


def _study(root: Path, pools: dict[str, Any], clock: Clock | None = None, **changes: Any) -> Study:
    config = _config(**changes)
    recorder = Recorder([FileStore(root, config.name)])
    if clock is None:  # the default clock (and a Study that predates the limits)
        return Study(config, ROOT, pools, recorder)
    return Study(config, ROOT, pools, recorder, clock)


def _open_fds() -> int:
    return len(os.listdir("/proc/self/fd"))


# --- ASGI, without sockets --------------------------------------------------------------------------------


async def _http(
    app: Any,
    method: str,
    path: str,
    chunks: Iterable[bytes] = (),
    headers: dict[str, str] | None = None,
    client: tuple[str, int] = ("10.0.0.1", 5000),
) -> tuple[int, dict[str, str], Any, int]:
    """(status, headers, JSON or text body, body chunks the app read)."""
    pieces: Iterator[bytes] = iter(chunks)
    pending = next(pieces, None)
    read = 0

    async def receive() -> dict[str, Any]:
        nonlocal pending, read
        if pending is None:
            return {"type": "http.disconnect"}
        chunk, pending = pending, next(pieces, None)
        read += 1
        return {"type": "http.request", "body": chunk, "more_body": pending is not None}

    sent: list[dict[str, Any]] = []

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    hdrs = {"host": "testserver", **(headers or {})}
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": method,
        "scheme": "http",
        "path": path,
        "raw_path": path.encode(),
        "root_path": "",
        "query_string": b"",
        "headers": [(k.lower().encode("latin-1"), v.encode("latin-1")) for k, v in hdrs.items()],
        "client": client,
        "server": ("127.0.0.1", 8000),
    }
    await app(scope, receive, send)
    start = next(m for m in sent if m["type"] == "http.response.start")
    body = b"".join(m.get("body", b"") for m in sent if m["type"] == "http.response.body")
    out_headers = {k.decode(): v.decode() for k, v in start["headers"]}
    is_json = out_headers.get("content-type") == "application/json"
    return start["status"], out_headers, json.loads(body) if is_json else body.decode(), read


async def _ws(app: Any, token: str, frames: Iterable[str | bytes]) -> list[dict[str, Any]]:
    """What the app sends over one /ws/round connection that sends `frames` and then goes away."""
    inbox: asyncio.Queue[dict[str, Any]] = asyncio.Queue()
    inbox.put_nowait({"type": "websocket.connect"})
    for frame in frames:
        key = "bytes" if isinstance(frame, bytes) else "text"
        inbox.put_nowait({"type": "websocket.receive", key: frame})
    inbox.put_nowait({"type": "websocket.disconnect", "code": 1001})
    sent: list[dict[str, Any]] = []

    async def send(message: dict[str, Any]) -> None:
        sent.append(message)

    scope = {
        "type": "websocket",
        "asgi": {"version": "3.0"},
        "scheme": "ws",
        "path": "/ws/round",
        "raw_path": b"/ws/round",
        "root_path": "",
        "query_string": b"",
        "headers": [(b"host", b"testserver"), (b"cookie", f"{COOKIE}={token}".encode())],
        "client": ("10.0.0.1", 5000),
        "server": ("127.0.0.1", 8000),
        "subprotocols": [],
    }
    await asyncio.wait_for(app(scope, inbox.get, send), timeout=60)
    return sent


def _json_post(body: bytes, token: str | None = None, **headers: str) -> dict[str, str]:
    out = {"content-type": "application/json", "content-length": str(len(body)), **headers}
    if token is not None:
        out["cookie"] = f"{COOKIE}={token}"
    return out


# --- record files ----------------------------------------------------------------------------------------


def test_record_files_are_open_only_while_written(tmp_path: Path) -> None:
    store = FileStore(tmp_path, "s")
    before = _open_fds()
    pids = [f"p{i:020x}" for i in range(300)]
    for pid in pids:
        store.append(pid, {"type": "participant", "index": 0, "session": "", "code": "", "config_digest": ""})
    assert _open_fds() == before  # the old store kept one descriptor per participant
    for pid in pids[:3]:
        store.append(pid, {"type": "consent", "accepted": True})
    assert [e["type"] for e in store.events(pids[0])] == ["participant", "consent"]
    assert len(store.participants()) == 300 and _open_fds() == before


# --- join limits -----------------------------------------------------------------------------------------


def test_joins_are_bounded_per_address(tmp_path: Path, pools: dict[str, Any]) -> None:
    clock = Clock()
    study = _study(tmp_path, pools, clock, limits={"joins_per_address_per_minute": 3})
    for _ in range(3):
        study.join("10.0.0.1")
    with pytest.raises(JoinRefusedError, match="limits.joins_per_address_per_minute = 3") as refused:
        study.join("10.0.0.1")
    assert refused.value.rate and refused.value.limit == "limits.joins_per_address_per_minute"
    assert refused.value.retry_after == pytest.approx(20.0)
    study.join("10.0.0.2")  # another address is not held up
    clock.now += 21.0  # 3 a minute: one more after 20 s
    study.join("10.0.0.1")
    with pytest.raises(JoinRefusedError):
        study.join("10.0.0.1")


def test_joins_are_bounded_by_participants_in_progress(tmp_path: Path, pools: dict[str, Any]) -> None:
    clock = Clock()
    limits = {"max_active_participants": 3, "idle_minutes": 10, "max_participants": 7}
    study = _study(tmp_path, pools, clock, consent="Agree?", limits=limits)
    joined = [study.join(f"10.0.1.{i}") for i in range(3)]
    with pytest.raises(JoinRefusedError, match="full right now") as full:
        study.join("10.0.1.9")
    assert not full.value.rate and full.value.limit == "limits.max_active_participants"
    study.submit(joined[0][1], {"stage": "consent", "accept": False})  # declined: no longer in progress
    study.join("10.0.1.9")
    with pytest.raises(JoinRefusedError, match="limits.max_active_participants"):
        study.join("10.0.1.10")
    clock.now += 5 * 60
    assert study.participant(joined[1][0]) is joined[1][1]  # seen again: stays active
    clock.now += 6 * 60  # the others have been idle for 11 minutes
    study.join("10.0.1.11")
    study.join("10.0.1.12")
    assert study.active_participants() == 3
    clock.now += 11 * 60
    study.join("10.0.1.13")  # the 7th participant in all
    with pytest.raises(JoinRefusedError, match="no more participants") as total:
        study.join("10.0.1.14")
    assert total.value.limit == "limits.max_participants" and total.value.retry_after is None
    token, p = joined[2]
    assert study.participant(token) is p and study.view(p)["stage"] == "consent"  # idle ones go on


def test_limits_are_validated_and_do_not_change_the_study_digest(
    tmp_path: Path, pools: dict[str, Any]
) -> None:
    for bad in ({"max_active_participants": 0}, {"idle_minutes": 0}, {"joins_per_address_per_minute": -1}):
        with pytest.raises(ConfigError, match="limits."):
            _config(limits=bad)
    study = _study(tmp_path, pools)
    token, _ = study.join()
    again = _study(tmp_path, pools, limits={"max_active_participants": 7})  # a restart with other limits
    store = again.recorder.stores[0]
    assert again.restore({pid: store.events(pid) for pid in store.participants()}) == 1
    assert again.participant(token) is not None


def test_the_join_route_answers_429_and_503_naming_the_limit(tmp_path: Path, pools: dict[str, Any]) -> None:
    study = _study(tmp_path, pools, limits={"joins_per_address_per_minute": 2, "max_active_participants": 3})
    app = create_app(study)

    async def run() -> list[tuple[int, dict[str, str], Any, int]]:
        return [
            await _http(app, "POST", "/api/join", [b"{}"], _json_post(b"{}"), (address, 1))
            for address in ("10.0.0.1", "10.0.0.1", "10.0.0.1", "10.0.0.2", "10.0.0.3")
        ]

    ok1, ok2, rate, ok3, full = asyncio.run(run())
    assert [r[0] for r in (ok1, ok2, ok3)] == [200, 200, 200]
    assert rate[0] == 429 and rate[2]["limit"] == "limits.joins_per_address_per_minute"
    assert int(rate[1]["retry-after"]) == 30 and "set-cookie" not in rate[1]
    assert full[0] == 503 and full[2]["limit"] == "limits.max_active_participants"
    assert "retry-after" in full[1] and "full" in full[2]["error"]


def test_many_anonymous_joins_keep_the_server_within_its_bounds(
    tmp_path: Path, pools: dict[str, Any]
) -> None:
    """A small soak: 400 joins from 20 addresses; admitted within the bounds, 429/503 beyond, never a
    500, and no descriptor held per participant."""
    limits = {"joins_per_address_per_minute": 5, "max_active_participants": 60}
    study = _study(tmp_path, pools, limits=limits)
    app = create_app(study)

    async def run() -> list[int]:
        statuses = []
        for i in range(400):
            address = f"10.1.0.{i % 20 if i < 100 else 99}"  # 20 addresses, then one hammering
            status, *_ = await _http(app, "POST", "/api/join", [b"{}"], _json_post(b"{}"), (address, 1))
            statuses.append(status)
        return statuses

    before = _open_fds()
    statuses = asyncio.run(run())
    assert statuses[:60] == [200] * 60 and set(statuses[60:]) == {503}
    assert _open_fds() <= before + 2 and len(list((tmp_path / "hardening").iterdir())) == 60

    fresh = _study(tmp_path / "b", pools, limits=limits)
    app = create_app(fresh)

    async def hammer() -> list[int]:
        return [
            (await _http(app, "POST", "/api/join", [b"{}"], _json_post(b"{}"), ("10.2.0.1", 1)))[0]
            for _ in range(50)
        ]

    assert asyncio.run(hammer()) == [200] * 5 + [429] * 45


def test_the_rate_limiter_table_stays_bounded() -> None:
    clock = Clock()
    limiter = RateLimiter(60, 2, max_keys=100, clock=clock)
    for i in range(10_000):
        limiter.take(f"k{i}")
    assert len(limiter) <= 100
    clock.now += 3.0  # every bucket full again: all forgotten at the next take
    limiter.take("x")
    assert len(limiter) == 1


# --- request bodies --------------------------------------------------------------------------------------


def _at_round(study: Study) -> str:
    token, p = study.join()
    study.submit(p, {"stage": "instructions"})
    assert p.current == ("round", 0)
    return token


def test_a_chunked_body_is_read_only_up_to_its_limit(tmp_path: Path, pools: dict[str, Any]) -> None:
    study = _study(tmp_path, pools)
    token = _at_round(study)
    app = create_app(study)
    chunk = b" " * 1000
    huge = (chunk for _ in range(20_000))  # 20 MB, chunked (no Content-Length), never materialised
    headers = {
        "content-type": "application/json",
        "cookie": f"{COOKIE}={token}",
        "transfer-encoding": "chunked",
    }
    status, _, body, read = asyncio.run(_http(app, "POST", "/api/submit", huge, headers))
    assert status == 413 and "16384 bytes" in body["error"]
    assert read == MAX_BODY_BYTES // len(chunk) + 1  # stopped at the first chunk past the limit
    declared = _json_post(b"{}", token, **{"content-length": str(MAX_BODY_BYTES + 1)})
    assert asyncio.run(_http(app, "POST", "/api/submit", [b"{}"], declared))[0] == 413
    bad_length = _json_post(b"{}", token, **{"content-length": "12abc"})
    assert asyncio.run(_http(app, "POST", "/api/submit", [b"{}"], bad_length))[0] == 400


JSON_VALUES = st.recursive(
    st.none() | st.booleans() | st.integers() | st.floats(allow_nan=False) | st.text(max_size=20),
    lambda inner: st.lists(inner, max_size=4) | st.dictionaries(st.text(max_size=8), inner, max_size=4),
    max_leaves=20,
)


def _deep(n: int, opener: str = "[") -> str:
    """JSON nested `n` levels deep."""
    return '{"a":' * n + "1" + "}" * n if opener == "{" else "[" * n + "]" * n


BODIES = st.one_of(
    st.binary(max_size=300),
    st.text(max_size=300).map(str.encode),
    JSON_VALUES.map(lambda v: json.dumps(v).encode()),
    st.fixed_dictionaries(
        {"stage": st.sampled_from(["consent", "info", "instructions", "survey", "round"]) | JSON_VALUES},
        optional={"accept": JSON_VALUES, "fields": JSON_VALUES, "round": JSON_VALUES, "answers": JSON_VALUES},
    ).map(lambda v: json.dumps(v).encode()),
    st.integers(MAX_JSON_DEPTH + 1, 8000).map(lambda n: _deep(n).encode()),
    st.integers(MAX_JSON_DEPTH + 1, 2000).map(lambda n: _deep(n, "{").encode()),
    st.integers(65, 6000).map(lambda n: b'{"stage": ' + b"7" * n + b"}"),
    st.integers(1, 3).map(lambda n: b'{"stage": ' + [b"NaN", b"Infinity", b"-Infinity"][n - 1] + b"}"),
)


@pytest.fixture(scope="module")
def at_round(pools: dict[str, Any], tmp_path_factory: pytest.TempPathFactory) -> tuple[Any, str]:
    study = _study(tmp_path_factory.mktemp("records"), pools)
    return create_app(study), _at_round(study)


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(body=BODIES, content_type=st.sampled_from(["application/json", "application/json; charset=utf-8"]))
@example(body=b"[" * 10_000 + b"]" * 10_000, content_type="application/json").via("deep nesting, 20 KB")
@example(body=b"[" * 8_000 + b"]" * 8_000, content_type="application/json").via("deep nesting, 16 KB")
@example(body=b'{"stage": ' + b"1" * 5000 + b"}", content_type="application/json").via("5,000 digits")
def test_malformed_bodies_get_a_400_never_a_500(
    at_round: tuple[Any, str], body: bytes, content_type: str, caplog: pytest.LogCaptureFixture
) -> None:
    app, token = at_round
    headers = _json_post(body, token, **{"content-type": content_type})
    status, _, answer, _ = asyncio.run(_http(app, "POST", "/api/submit", [body], headers))
    assert status in (400, 413) and isinstance(answer["error"], str) and len(answer["error"]) < 300
    assert not any(r.exc_info for r in caplog.records)


def test_parse_json_bounds() -> None:
    assert parse_json(b'{"a": [1, 2.5, "[[[["], "b": null}') == {"a": [1, 2.5, "[[[["], "b": None}
    assert json_depth('["[[[", {"x": ["\\"[["]}]') == 3
    cases: list[tuple[str | bytes, str]] = [
        ("[" * 17 + "]" * 17, "17 levels deep"),
        ("1" * 65, "65 characters"),
        ("[NaN]", "NaN is not"),
        (b"\xff", "UTF-8"),
        ("{", "not JSON"),
    ]
    for bad, message in cases:
        with pytest.raises(LimitsJSONError, match=message):
            parse_json(bad)


# --- WebSocket messages ----------------------------------------------------------------------------------


def _replies(sent: list[dict[str, Any]]) -> list[dict[str, Any]]:
    return [json.loads(m["text"]) for m in sent if m["type"] == "websocket.send"]


def test_a_binary_frame_closes_the_round_with_1003(
    at_round: tuple[Any, str], caplog: pytest.LogCaptureFixture
) -> None:
    app, token = at_round
    with caplog.at_level(logging.INFO, logger="cec.play"):
        sent = asyncio.run(_ws(app, token, ['{"type": "act", "t": 99, "action": 1}', b"\x00\x01", "{}"]))
    replies = _replies(sent)
    assert [r["type"] for r in replies] == ["start", "error"]  # the message after the frame is not read
    close = sent[-1]
    assert close["type"] == "websocket.close" and close["code"] == 1003 and "binary" in close["reason"]
    assert not any(r.exc_info for r in caplog.records)
    assert sum("round connection closed (1003)" in r.getMessage() for r in caplog.records) == 1


MESSAGES = st.one_of(
    st.text(max_size=200),
    JSON_VALUES.map(json.dumps),
    st.fixed_dictionaries(
        {"type": st.sampled_from(["act", "key", "x"]) | JSON_VALUES},
        optional={"t": JSON_VALUES, "action": JSON_VALUES, "rt_ms": JSON_VALUES, "seq": JSON_VALUES},
    ).map(json.dumps),
    st.integers(MAX_JSON_DEPTH + 1, 3000).map(lambda n: '{"type": "act", "t": ' + _deep(n) + "}"),
    st.integers(65, 4000).map(lambda n: '{"type": "act", "t": 0, "action": ' + "9" * n + "}"),
    st.integers(4097, 6000).map(lambda n: "x" * n),
)


@settings(max_examples=40, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(frames=st.lists(MESSAGES | st.binary(max_size=50), min_size=1, max_size=6))
@example(frames=['{"type": "act", "t": ' + "[" * 1500 + "]" * 1500 + "}"]).via("nested 1,500 deep")
@example(frames=['{"type": "act", "t": 0, "action": ' + "1" * 4000 + "}"]).via("4,000 digits")
@example(frames=[b"binary"]).via("a binary frame")
def test_malformed_round_messages_are_answered_never_crash_the_round(
    at_round: tuple[Any, str], frames: list[str | bytes], caplog: pytest.LogCaptureFixture
) -> None:
    app, token = at_round
    sent = asyncio.run(_ws(app, token, frames))
    assert sent[0]["type"] == "websocket.accept"
    replies = _replies(sent)
    assert replies[0]["type"] == "start"
    binary = next((i for i, f in enumerate(frames) if isinstance(f, bytes)), None)
    answered = frames if binary is None else frames[:binary]
    assert len(replies) - 1 == len(answered)  # one reply (error or frame) per message before a binary one
    assert all(r["type"] in ("error", "frame") and not r.get("fatal") for r in replies[1:])
    assert all(len(r.get("message", "")) < 300 for r in replies)
    if binary is not None:
        assert sent[-1]["type"] == "websocket.close" and sent[-1]["code"] == 1003
    assert not any(r.exc_info for r in caplog.records)
