"""`cec play` under store faults and over damaged records (issue 44): with Redis down an admitted
participant's form is answered 503 naming the store and a retry is recorded once in each store; a record
line that is not an event is quarantined with a warning naming the file and line, so the study restarts
over it and `cec play export` lists it; malformed Redis entries and an empty study file end in a clear
error, never a traceback. The stores agree after faults (issue 63, item 4): what a store refused (Redis
down or frozen) is taken back from the others (no line, no participant file, no counterbalancing index); a
server that starts replays the records folder into a Redis that restarted empty; export names every
participant it passes over and why.

Through the entry point where practical: `python -m apps.cli play serve|export` on a real `redis-server`.
"""

from __future__ import annotations

import json
import os
import shutil
import signal
import subprocess
import sys
import urllib.error
import urllib.request
from http.cookiejar import CookieJar
from pathlib import Path
from typing import Any

import pytest
import redis

from cec.config import ConfigError, from_dict
from services.play.config import StorageConfig
from services.play.export import read_all
from services.play.recording import (
    FileStore,
    Recorder,
    RecordUnavailableError,
    RedisStore,
    open_stores,
    parse_event,
)
from services.store import LocalRedis, StoreConfig
from tests.play_server import ROOT, PlayServer

STUDY = """\
name: faults
levels: [cramped_room]
partners: [{name: a, random_init: true}]
consent: "Do you agree?"
env: {max_steps: 4, random_start_facing: false}
survey: {items: []}
"""
PID = "p" + "cd" * 10


def _cli(*args: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(
        [sys.executable, "-m", "apps.cli", "play", *args], cwd=ROOT, capture_output=True, text=True,
        timeout=300,
    )  # fmt: skip


class _Browser:
    """One participant's browser: a cookie jar and JSON requests."""

    def __init__(self, url: str) -> None:
        self.url = url
        self.opener = urllib.request.build_opener(urllib.request.HTTPCookieProcessor(CookieJar()))

    def post(self, path: str, body: dict[str, Any]) -> tuple[int, dict[str, Any]]:
        request = urllib.request.Request(
            self.url + path.lstrip("/"), json.dumps(body).encode(), {"Content-Type": "application/json"}
        )
        try:
            with self.opener.open(request, timeout=30) as response:
                return response.status, json.loads(response.read())
        except urllib.error.HTTPError as err:
            return err.code, json.loads(err.read())


def _types(events: list[dict[str, Any]]) -> list[str]:
    return [e["type"] for e in events]


@pytest.fixture
def own_redis() -> Any:
    """A Redis of this test's own (it is stopped and started again)."""
    with LocalRedis() as server:
        yield server


def test_the_recorder_records_a_retry_once_in_each_store(tmp_path: Path, own_redis: LocalRedis) -> None:
    files = FileStore(tmp_path, "s")
    red = RedisStore(StoreConfig(url=own_redis.url, key_prefix="t", retries=1), "s")
    recorder = Recorder([files, red])
    head = {"type": "participant", "index": 0, "session": "x", "code": "C", "config_digest": "d"}
    recorder.append(PID, head)
    own_redis.stop()
    consent = {"type": "consent", "accepted": True}
    for _ in range(3):  # retries while Redis is down: the file takes the event back each time
        with pytest.raises(RecordUnavailableError, match="Redis") as caught:
            recorder.append(PID, {**consent, "at": 1.0})
        assert caught.value.store == "Redis"
    assert _types(files.events(PID)) == ["participant"]
    assert len(files.path(PID).read_text().splitlines()) == 1
    own_redis.start()
    recorder.append(PID, {**consent, "at": 2.0})  # the retry: recorded once in each store
    assert len(files.path(PID).read_text().splitlines()) == 2
    assert files.events(PID) == red.events(PID) and _types(red.events(PID)) == ["participant", "consent"]
    assert [e["seq"] for e in red.events(PID)] == [0, 1]

    # a step not recorded in Redis, then replaced by another event (the round's abort) under its seq
    step = {"type": "step", "round": 0, "attempt": 0, "t": 1, "actions": [0, 0], "human_action": 0,
            "reward": 0.0, "collision": False, "done": False, "state": {}}  # fmt: skip
    own_redis.stop()
    with pytest.raises(RecordUnavailableError):
        recorder.append(PID, step)
    own_redis.start()
    recorder.append(PID, {"type": "round_abort", "round": 0, "attempt": 0, "steps": 1})
    assert _types(files.events(PID)) == _types(red.events(PID)) == ["participant", "consent", "round_abort"]
    assert files.events(PID) == red.events(PID)
    recorder.close()


def test_what_a_frozen_redis_refused_is_in_no_store_and_a_restart_replays_the_files(
    tmp_path: Path, own_redis: LocalRedis
) -> None:
    """Redis frozen (SIGSTOP) past its socket timeout: the file gives the event back (and a join's file
    goes), whether or not Redis applies the write when it thaws; a restart's replay makes Redis agree."""
    files = FileStore(tmp_path, "s")
    config = StoreConfig(url=own_redis.url, key_prefix="t", socket_timeout_s=0.5, retries=0)
    red = RedisStore(config, "s")
    recorder = Recorder([files, red])
    head = {"type": "participant", "index": 0, "session": "x", "code": "C", "config_digest": "d"}
    recorder.append(PID, head)
    joiner = "p" + "ef" * 10
    os.kill(own_redis.pid, signal.SIGSTOP)
    try:
        with pytest.raises(RecordUnavailableError, match="Redis"):
            recorder.append(PID, {"type": "consent", "accepted": True})
        with pytest.raises(RecordUnavailableError, match="Redis"):
            recorder.append(joiner, {**head, "index": 1})
        assert _types(files.events(PID)) == ["participant"]  # the refused submit wrote no line
        assert not files.path(joiner).exists()  # the refused join left no file
    finally:
        os.kill(own_redis.pid, signal.SIGCONT)
    recorder.append(PID, {"type": "consent", "accepted": False})  # the participant answers otherwise
    assert files.events(PID) == red.events(PID)  # one consent, the second answer, in each store
    assert [(e["seq"], e.get("accepted")) for e in red.events(PID)] == [(0, None), (1, False)]

    # a server starting again: Redis keeps no participant the files do not have, and gets what it lacks
    red.replace(PID, red.events(PID)[:1])
    restarted = Recorder([files, red])
    restarted.replay(read_all(files))
    assert red.participants() == [PID] and red.events(PID) == files.events(PID)
    recorder.close()


def _serve_args(tmp_path: Path, redis: LocalRedis) -> tuple[list[str], Path]:
    """`cec play serve`'s arguments for the test study (`STUDY`) recorded under tmp_path/data and in
    `redis`, and that data folder."""
    study = tmp_path / "study.yaml"
    study.write_text(STUDY)
    data = tmp_path / "data"
    return [str(study), "--port", "0", "--data", str(data), "--redis-url", redis.url], data


def _restart_empty(server: LocalRedis) -> None:
    """Restarts `server` without its data (a Redis without persistence, or whose files were lost)."""
    server.stop()
    for path in server.data_dir.iterdir():
        if path.name not in ("redis.conf", "redis.log"):
            shutil.rmtree(path) if path.is_dir() else path.unlink()
    server.start()


def test_parse_event_refuses_what_is_not_an_event() -> None:
    assert parse_event('{"type": "instructions"}')[0] == {"type": "instructions"}
    for line, cause in [
        ("[]", "not a JSON object"),
        ("[" * 100_000 + "]" * 100_000, "nested 100000 levels"),
        ("{}", "`type` None"),
        ('{"type": "rocket"}', "not an event type"),
        ('{"type": "consent"}', "without `accepted`"),
        ('{"type": "consent", "accepted": "yes"}', "not true or false"),
        ('{"type": "instructions", "seq": -1}', "seq"),
        ('{"type": "step", "x": NaN}', "NaN"),
        (b"\xff", "not UTF-8"),
        ('{"type": ', "not JSON"),
    ]:
        event, problem = parse_event(line)
        assert event is None and cause in problem, (line[:20], problem)


def test_submit_answers_503_with_redis_down_and_a_restart_quarantines_corrupt_lines(
    tmp_path: Path, own_redis: LocalRedis
) -> None:
    args, data = _serve_args(tmp_path, own_redis)
    server = PlayServer(args, "faults")
    try:
        browser = _Browser(server.url)
        status, view = browser.post("/api/join", {})
        assert status == 200 and view["stage"] == "consent"
        pid = view["participant"]
        own_redis.stop()
        for _ in range(3):  # the participant retries while Redis is down
            status, body = browser.post("/api/submit", {"stage": "consent", "accept": True})
            assert status == 503 and body["store"] == "Redis" and "Redis is unavailable" in body["error"]
        status, _ = _Browser(server.url).post("/api/join", {})
        assert status == 503  # new participants too, leaving no participant file
        assert [p.name for p in (data / "faults").iterdir()] == [f"{pid}.jsonl"]
        own_redis.start()
        status, view = browser.post("/api/submit", {"stage": "consent", "accept": True})
        assert status == 200 and view["stage"] == "instructions"
        status, second = _Browser(server.url).post("/api/join", {})
        assert status == 200
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    files = FileStore(data, "faults", create=False)
    assert files.events(second["participant"])[0]["index"] == 1  # the refused join took no index
    red = RedisStore(StoreConfig(url=own_redis.url, key_prefix="cec", retries=1), "faults")
    assert _types(files.events(pid)) == _types(red.events(pid)) == ["participant", "consent"]
    assert files.events(pid) == red.events(pid)
    red.close()

    # damaged lines: a list, a 100,000-deep line, an event without its fields; the study restarts over them
    path = files.path(pid)
    path.write_text(path.read_text() + "[]\n" + "[" * 100_000 + "]" * 100_000 + "\n" + '{"type": "info"}\n')
    _restart_empty(own_redis)  # and Redis lost everything: the server replays the files into it
    server = PlayServer(args, "faults")
    try:
        browser.url = server.url  # another port; the same cookie
        status, view = browser.post("/api/submit", {"stage": "instructions"})  # the participant goes on
        assert status == 200 and view["stage"] == "round"
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    for line in (3, 4, 5):
        assert f"{path}, line {line}:" in server.log and "quarantined" in server.log
    assert "3 record line(s) quarantined" in server.log
    red = RedisStore(StoreConfig(url=own_redis.url, key_prefix="cec", retries=1), "faults")
    assert red.participants() == files.participants()
    assert red.events(pid) == files.events(pid) and [e["seq"] for e in red.events(pid)] == [0, 1, 2]
    red.close()

    out = _cli("export", args[0], "--data", str(data), "--out", str(tmp_path / "out"))
    assert out.returncode == 0, out.stderr
    assert "left out 3 quarantined record line(s)" in out.stdout
    assert f"{path}, line 3: not a JSON object but a list" in out.stdout
    assert f"{path}, line 4: nested 100000 levels deep" in out.stdout
    assert f"{path}, line 5: an event of type 'info' without `fields`" in out.stdout
    unplayed = "no finished study round (the last event recorded is 'participant')"
    assert f"participant {second['participant']}: {unplayed}" in out.stdout
    assert "Traceback" not in out.stderr


def test_a_submit_and_a_join_refused_while_redis_is_frozen_leave_nothing_and_a_restart_agrees(
    tmp_path: Path, own_redis: LocalRedis
) -> None:
    """`cec play serve` over a Redis frozen (SIGSTOP) past its socket timeout: the submit and the join it
    answers 503 leave no line and no participant file, and the join takes no counterbalancing index. What
    the frozen Redis applies when it thaws is replaced by the retry (the same `seq`) or, for the refused
    join, removed by the next server's replay, so both stores read back the same records."""
    args, data = _serve_args(tmp_path, own_redis)
    server = PlayServer(args, "faults")
    try:
        browser = _Browser(server.url)
        status, view = browser.post("/api/join", {})
        assert status == 200
        pid = view["participant"]
        os.kill(own_redis.pid, signal.SIGSTOP)
        try:
            status, body = browser.post("/api/submit", {"stage": "consent", "accept": True})
            assert status == 503 and body["store"] == "Redis"
            assert _types(FileStore(data, "faults", create=False).events(pid)) == ["participant"]
            status, _ = _Browser(server.url).post("/api/join", {})
            assert status == 503
            assert [p.name for p in (data / "faults").iterdir()] == [f"{pid}.jsonl"]
        finally:
            os.kill(own_redis.pid, signal.SIGCONT)
        status, view = browser.post("/api/submit", {"stage": "consent", "accept": True})
        assert status == 200 and view["stage"] == "instructions"
        status, second = _Browser(server.url).post("/api/join", {})
        assert status == 200
    finally:
        code = server.stop(signal.SIGINT)
    assert code == 0 and "Traceback" not in server.log, server.log
    files = FileStore(data, "faults", create=False)
    red = RedisStore(StoreConfig(url=own_redis.url, key_prefix="cec", retries=1), "faults")
    assert files.events(second["participant"])[0]["index"] == 1  # the refused join took no index
    assert files.events(pid) == red.events(pid)
    assert [(e["type"], e["seq"]) for e in red.events(pid)] == [("participant", 0), ("consent", 1)]
    server = PlayServer(args, "faults")  # a server that starts replays the files into Redis
    assert server.stop(signal.SIGINT) == 0 and "Traceback" not in server.log, server.log
    assert red.participants() == files.participants() == sorted([pid, second["participant"]])
    assert all(red.events(q) == files.events(q) for q in files.participants())
    red.close()


def test_the_serving_stores_give_redis_the_studys_timeout_and_one_retry(own_redis: LocalRedis) -> None:
    """`cec play serve` answers an action 503 after `storage.redis_timeout_s` and one retry (each waiting
    action holds a worker thread every participant's steps share); readers keep the store's defaults."""
    (served,) = open_stores("s", "", own_redis.url, redis_timeout_s=0.5)
    (read,) = open_stores("s", "", own_redis.url)
    assert isinstance(served, RedisStore) and isinstance(read, RedisStore)
    c = served.config
    assert (c.socket_timeout_s, c.connect_timeout_s, c.retries) == (0.5, 0.5, 1)
    assert read.config == StoreConfig(url=own_redis.url)
    served.close()
    read.close()
    assert from_dict(StorageConfig, {"redis_url": own_redis.url}).redis_timeout_s == 1.0
    with pytest.raises(ConfigError, match=r"storage.redis_timeout_s must be > 0 s.*got 0"):
        from_dict(StorageConfig, {"redis_timeout_s": 0})


def test_a_server_started_over_an_empty_redis_replays_the_records_into_it(
    tmp_path: Path, own_redis: LocalRedis
) -> None:
    """Redis restarted without its data between two runs of `cec play serve`: the second replays the records
    folder into it before anything new, so the participant's stream starts at its join (`seq` 0), not at the
    first event after the restart."""
    args, data = _serve_args(tmp_path, own_redis)
    server = PlayServer(args, "faults")
    try:
        browser = _Browser(server.url)
        status, view = browser.post("/api/join", {})
        assert status == 200
        pid = view["participant"]
        status, view = browser.post("/api/submit", {"stage": "consent", "accept": True})
        assert status == 200 and view["stage"] == "instructions"
    finally:
        assert server.stop(signal.SIGINT) == 0 and "Traceback" not in server.log, server.log
    _restart_empty(own_redis)
    server = PlayServer(args, "faults")
    try:
        browser.url = server.url  # another port; the same cookie
        status, view = browser.post("/api/submit", {"stage": "instructions"})
        assert status == 200 and view["stage"] == "round"
    finally:
        assert server.stop(signal.SIGINT) == 0 and "Traceback" not in server.log, server.log
    files = FileStore(data, "faults", create=False)
    red = RedisStore(StoreConfig(url=own_redis.url, key_prefix="cec", retries=1), "faults")
    assert red.participants() == files.participants() == [pid]
    assert red.events(pid) == files.events(pid)
    assert [(e["type"], e["seq"]) for e in red.events(pid)] == [
        ("participant", 0), ("consent", 1), ("instructions", 2)
    ]  # fmt: skip
    red.close()


def test_export_from_redis_quarantines_malformed_entries(tmp_path: Path, redis_server: LocalRedis) -> None:
    study = tmp_path / "study.yaml"
    study.write_text(STUDY + "storage: {key_prefix: rq}\n")
    r = redis.Redis.from_url(redis_server.url)
    key = "rq:play:faults"
    head = {"type": "participant", "index": 0, "session": "x", "code": "C", "config_digest": "d", "seq": 0}
    r.sadd(f"{key}:participants", PID)
    r.xadd(f"{key}:{PID}", {"event": json.dumps(head)})
    r.xadd(f"{key}:{PID}", {"other": "x"})  # no `event`
    r.xadd(f"{key}:{PID}", {"event": "[]"})
    out = _cli("export", str(study), "--redis-url", redis_server.url, "--out", str(tmp_path / "out"))
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    assert "left out 2 quarantined record line(s)" in out.stdout
    assert "no `event` field" in out.stdout and "not a JSON object but a list" in out.stdout

    # a stream that starts at event 2 (Redis restarted empty under a running server), and one with a gap
    late, gap = "p" + "ab" * 10, "p" + "ef" * 10
    abort = {"type": "round_abort", "round": 0, "attempt": 0, "steps": -1}
    r.sadd(f"{key}:participants", late, gap)
    r.xadd(f"{key}:{late}", {"event": json.dumps({**abort, "seq": 2})})
    for event in ({**head, "seq": 0}, {**abort, "seq": 3}):
        r.xadd(f"{key}:{gap}", {"event": json.dumps(event)})
    out = _cli("export", str(study), "--redis-url", redis_server.url, "--out", str(tmp_path / "out"))
    assert out.returncode == 0 and "Traceback" not in out.stderr, out.stderr
    assert f"participant {late}: its records start at event 2 (round_abort), not at its join" in out.stdout
    assert f"participant {gap}: its events 1..2 are missing; left out" in out.stdout
    assert "export from the records folder (--data)" in out.stdout
    assert (
        f"participant {PID}: no finished study round (the last event recorded is 'participant')" in out.stdout
    )
    r.delete(f"{key}:{late}", f"{key}:{gap}")
    r.srem(f"{key}:participants", late, gap)

    r.delete(f"{key}:participants")
    r.set(f"{key}:participants", "not a set")
    out = _cli("export", str(study), "--redis-url", redis_server.url, "--out", str(tmp_path / "out"))
    assert out.returncode == 2 and "Traceback" not in out.stderr
    assert f"Redis key '{key}:participants'" in out.stderr and "storage.key_prefix" in out.stderr
    r.delete(f"{key}:participants", f"{key}:{PID}")
    r.close()


def test_an_empty_study_file_is_a_config_error_naming_it(tmp_path: Path) -> None:
    study = tmp_path / "empty.yaml"
    study.write_text("")
    for command in (["serve", str(study), "--port", "0"], ["export", str(study), "--out", str(tmp_path)]):
        out = _cli(*command)
        assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr
        assert str(study) in out.stderr and "`name`, `levels` and `partners`" in out.stderr


def test_behaviour_cloning_records_quarantine_a_bad_line(tmp_path: Path) -> None:
    """`cec humans bc --from-play` reads the records with the same checks: a `[]` line is left out (it was a
    traceback); a folder that holds no finished round after that is a config error naming it."""
    from cec.config import ConfigError
    from services.play.human_samples import read_play_records

    store = FileStore(tmp_path, "s")
    store.append(PID, {"type": "participant", "index": 0, "session": "x", "code": "C", "config_digest": "d"})
    store.path(PID).write_text(store.path(PID).read_text() + "[]\n")
    with pytest.raises(ConfigError, match="none of its 1 participant"):
        read_play_records(tmp_path / "s")


@pytest.mark.parametrize("study", ["../victim", "absolute", "..", ".hidden", "nul"])
def test_a_study_name_becomes_a_records_folder_only_through_safe_name(study, tmp_path):
    """The records folder is `<storage.dir>/<study name>`: a name that would leave `storage.dir` (or one
    no other system can copy) is refused before any folder is made (issue 63, item 1)."""
    from cec.paths import UnsafeNameError
    from services.play.recording import open_stores

    root = tmp_path / "records"
    root.mkdir()
    study = str(tmp_path / "elsewhere") if study == "absolute" else study
    with pytest.raises(UnsafeNameError, match=r"study name .* cannot be a file or folder name: .*letters"):
        open_stores(study, str(root), "")
    assert sorted(tmp_path.rglob("*")) == [root], "no folder was made"
    assert [type(s).__name__ for s in open_stores("faults", str(root), "")] == ["FileStore"]


def test_cec_play_refuses_a_study_name_that_is_no_folder_name(tmp_path: Path) -> None:
    """`name: nul` passed the study's letters-and-digits check, and its records folder (a device name on
    Windows) was made; now `cec play serve` and `export` refuse it at load, naming the fix, before any
    folder is made (issue 63, item 1)."""
    records = tmp_path / "records"
    study = tmp_path / "study.yaml"
    study.write_text(STUDY.replace("name: faults", "name: nul") + f"storage: {{dir: {records}}}\n")
    out_dir = str(tmp_path / "out")
    for command in (["serve", str(study), "--port", "0"], ["export", str(study), "--out", out_dir]):
        cmd = [sys.executable, "-m", "apps.cli", "play", *command]
        out = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, timeout=120)
        assert out.returncode == 2 and "Traceback" not in out.stderr, out.stderr[-2000:]
        cause = "study name 'nul' cannot be a file or folder name: 'nul' is a reserved device name"
        assert cause in out.stderr
        assert "name the study with 1-64 letters" in out.stderr
    assert not records.exists() and not (tmp_path / "out").exists()
