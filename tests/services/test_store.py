"""Integration tests of the Redis control plane against a real `redis-server` (started by `LocalRedis`).

One password-protected server serves most tests, each under its own key prefix; the restart test runs its
own server so that stopping it disturbs nobody.
"""

from __future__ import annotations

import json
import shutil
import time
import uuid

import pytest

from cec.config import ConfigError, from_dict
from services.processes import free_port
from services.store import (
    ENV_PASSWORD,
    ENV_URL,
    CheckpointEvent,
    ControlPlane,
    LocalRedis,
    PartnerRecord,
    StoreConfig,
    StoreError,
    StoreUnavailableError,
    checkpoint_id,
    redact_url,
)

pytestmark = pytest.mark.skipif(
    shutil.which("redis-server") is None, reason="needs redis-server (sudo apt-get install redis-server)"
)
PASSWORD = "s3cret-pw"


@pytest.fixture(scope="module")
def server():
    with LocalRedis(password=PASSWORD) as s:
        yield s


@pytest.fixture
def plane(server, tmp_path):
    config = server.config(key_prefix=f"t{uuid.uuid4().hex[:8]}", claim_idle_s=0.5, retries=1)
    with ControlPlane.connect(config, outbox_dir=tmp_path) as p:
        yield p


def _event(update: int, run_id: str = "cec-s0") -> CheckpointEvent:
    return CheckpointEvent(
        run_id=run_id,
        update=update,
        env_steps=update * 1000,
        path=f"runs/{run_id}/checkpoints/update_{update:09d}",
        sha256=f"{update:064x}",
        algorithm="cec",
        seed=3,
        created_at=1.7e9 + update,
    )


def test_config_is_strict_and_reads_the_environment(monkeypatch):
    with pytest.raises(ConfigError, match="unknown key 'urll'"):
        from_dict(StoreConfig, {"urll": "redis://x:1/0"})
    with pytest.raises(ConfigError, match="redis://"):
        StoreConfig(url="http://localhost:6379")
    monkeypatch.delenv(ENV_URL, raising=False)
    monkeypatch.delenv(ENV_PASSWORD, raising=False)
    assert StoreConfig().resolved_url == "redis://127.0.0.1:6379/0" and not StoreConfig().url_given
    monkeypatch.setenv(ENV_URL, "redis://db.internal:6390/2")
    monkeypatch.setenv(ENV_PASSWORD, "from-env")
    assert StoreConfig().resolved_url == "redis://db.internal:6390/2" and StoreConfig().url_given
    assert StoreConfig().resolved_password == "from-env"
    assert StoreConfig(password="explicit").resolved_password == "explicit"
    assert StoreConfig(url="redis://:inurl@h:1/0").resolved_password == "inurl"
    assert redact_url("redis://:inurl@h:1/0") == "redis://:***@h:1/0"


def test_run_registry_round_trip(plane):
    first = plane.register_run("cec-s0", config={"seed": 0, "num_envs": 8}, algorithm="cec", started_at=100.0)
    assert (first.run_id, first.algorithm, first.status, first.started_at) == (
        "cec-s0",
        "cec",
        "running",
        100.0,
    )
    assert first.config_dict() == {"seed": 0, "num_envs": 8}
    plane.register_run("ippo-s1", config="algorithm: ippo\nseed: 1\n", algorithm="ippo", started_at=200.0)

    plane.heartbeat("cec-s0", at=150.0)
    plane.set_run_status("ippo-s1", "finished")
    runs = plane.list_runs()
    assert [r.run_id for r in runs] == ["cec-s0", "ippo-s1"]
    assert runs[0].heartbeat_at == 150.0 and runs[1].status == "finished"
    assert runs[1].config_dict() == {"algorithm": "ippo", "seed": 1}

    resumed = plane.register_run("cec-s0", config={"seed": 0}, algorithm="cec", started_at=999.0)
    assert resumed.started_at == 100.0 and resumed.config_dict() == {"seed": 0}  # a resume keeps its start
    assert plane.get_run("nope") is None
    with pytest.raises(StoreError, match="not registered"):
        plane.heartbeat("nope")
    with pytest.raises(ValueError, match="unknown"):
        plane.set_run_status("cec-s0", "exploded")


def test_each_group_consumes_each_checkpoint_once(plane):
    events = [_event(u) for u in (10, 20, 30)]
    assert [plane.publish_checkpoint(e).outcome for e in events] == ["published"] * 3
    for group in ("evaluator", "report"):  # groups are independent
        a, b = plane.consumer(group, "a"), plane.consumer(group, "b")
        got = a.read(count=2) + b.read(count=5)
        assert sorted((m.event for m in got), key=lambda e: e.update) == events
        assert not any(m.redelivered for m in got)
        assert a.pending_count() == 3
        for m in got:
            (a if m in got[:2] else b).ack(m)
        assert a.pending_count() == 0
        assert a.read(count=5) == [] and b.read(count=5) == []
        assert plane.consumer(group, "late").read(count=5) == []  # a new member does not replay the group
    assert plane.list_checkpoints() == events
    assert plane.get_checkpoint(events[1].checkpoint_id) == events[1]


def test_pending_events_of_a_dead_consumer_are_reclaimed(plane):
    plane.publish_checkpoint(_event(1))
    plane.publish_checkpoint(_event(2))
    dying = plane.consumer("evaluator", "dying")
    taken = dying.read(count=2)
    assert len(taken) == 2  # ... and it dies before acknowledging them

    survivor = plane.consumer("evaluator", "survivor")
    assert survivor.read(count=2) == []  # not idle long enough yet: its owner might still be working
    time.sleep(0.55)
    reclaimed = survivor.read(count=2)
    assert [m.event for m in reclaimed] == [m.event for m in taken] and all(m.redelivered for m in reclaimed)
    survivor.ack(reclaimed[0])

    # The dead consumer restarts under its name and first gets what it still holds (here: nothing, the
    # survivor claimed both); the survivor's own restart gets back the one it did not acknowledge.
    assert plane.consumer("evaluator", "dying").read(count=2) == []
    again = plane.consumer("evaluator", "survivor").read(count=2)
    assert [m.event for m in again] == [taken[1].event] and again[0].redelivered


def test_touch_keeps_a_long_job_and_poison_events_are_given_up(server, plane):
    plane.publish_checkpoint(_event(5))
    worker, thief = plane.consumer("g", "worker"), plane.consumer("g", "thief")
    (msg,) = worker.read()
    for _ in range(3):  # a long evaluation that keeps its claim
        time.sleep(0.2)
        worker.touch(msg)
        assert thief.read() == []

    # An event that kills every consumer that takes it is moved aside after max_deliveries.
    poison_plane = ControlPlane(
        server.config(key_prefix=plane.config.key_prefix, claim_idle_s=0.05, max_deliveries=2)
    )
    consumers = [poison_plane.consumer("g", f"c{i}") for i in range(3)]
    time.sleep(0.06)
    assert [m.entry_id for m in consumers[0].read()] == [msg.entry_id]  # delivery 2
    time.sleep(0.06)
    assert consumers[1].read() == []  # delivered twice already: given up
    dead = consumers[2].dead_letters()
    assert list(dead) == [msg.entry_id] and "2 times" in dead[msg.entry_id]["reason"]
    assert consumers[2].pending_count() == 0

    # A malformed entry (not written by publish_checkpoint) is given up on at once.
    bad_id = plane._r.xadd(plane.stream_key, {"run_id": "x", "update": "not a number"})
    assert consumers[2].read() == []
    assert "lacks" in consumers[2].dead_letters()[bad_id]["reason"]
    poison_plane.close()


def test_an_event_with_an_impossible_time_or_count_is_malformed():
    """A stream entry is parsed whole or refused: NaN or infinite creation times and negative counts are
    not checkpoints (they would sort and age wrongly in every consumer)."""
    fields = _event(4).to_fields()
    assert CheckpointEvent.from_fields(fields) == _event(4)
    for key, value in (("created_at", "nan"), ("created_at", "inf"), ("update", "-1"), ("env_steps", "-5")):
        with pytest.raises(ValueError, match="malformed checkpoint event"):
            CheckpointEvent.from_fields({**fields, key: value})


def test_duplicate_publications_are_one_checkpoint(plane):
    event = _event(7)
    first = plane.publish_checkpoint(event)
    again = plane.publish_checkpoint(event)
    assert (first.outcome, again.outcome, again.entry_id) == ("published", "duplicate", first.entry_id)
    assert plane._r.xlen(plane.stream_key) == 1

    # Even a second entry of the same checkpoint (its index entry lost) reaches a group only once.
    plane._r.xadd(plane.stream_key, event.to_fields())
    consumer = plane.consumer("evaluator", "e0")
    (msg,) = consumer.read(count=5)
    consumer.ack(msg)
    plane._r.xadd(plane.stream_key, event.to_fields())
    assert consumer.read(count=5) == [] and consumer.pending_count() == 0


def test_a_redis_restart_loses_no_checkpoint_event(tmp_path):
    with LocalRedis(tmp_path / "redis") as server:
        plane = ControlPlane.connect(
            server.config(retries=1, retry_backoff_s=0.01), outbox_dir=tmp_path / "run"
        )
        consumer = plane.consumer("evaluator", "e0")
        assert plane.publish_checkpoint(_event(1)).outcome == "published"
        (first,) = consumer.read()

        server.stop(kill=True)  # a crash, mid-run
        assert [plane.publish_checkpoint(_event(u)).outcome for u in (2, 3)] == ["queued", "queued"]
        assert [e.update for e in plane.pending_outbox()] == [2, 3]
        assert plane.flush_outbox() == (0, 2)  # still down: kept, no error
        with pytest.raises(StoreUnavailableError):
            consumer.read()

        server.start()  # same port, same data directory
        assert plane.flush_outbox() == (2, 0)
        assert not plane.outbox_path.exists()
        assert [e.update for e in plane.list_checkpoints()] == [1, 2, 3]  # the fsynced log survived the crash
        new = consumer.read(count=5)  # the consumer reconnects by itself
        assert [m.event.update for m in new] == [2, 3] and not any(m.redelivered for m in new)
        for m in [first, *new]:
            consumer.ack(m)
        assert consumer.pending_count() == 0
        assert plane.publish_checkpoint(_event(2)).outcome == "duplicate"  # a retry after the restart
        plane.close()


def test_results_are_idempotent_per_checkpoint_group_and_level_set(plane):
    cid = checkpoint_id("cec-s0", 100)
    assert cid == "cec-s0/update_000000100"
    assert not plane.is_scored(cid) and not plane.has_result(cid, "zoo", "classic")
    assert plane.put_result(cid, "zoo", "classic", {"return_mean": 40.0, "episodes": 50})
    assert not plane.put_result(cid, "zoo", "classic", {"return_mean": 41.0, "episodes": 50})
    assert plane.put_result(cid, "zoo", "heldout", {"return_mean": 12.5})
    results = plane.get_results(cid)
    assert [(r.partner_group, r.level_set, r.metrics["return_mean"]) for r in results] == [
        ("zoo", "classic", 41.0),
        ("zoo", "heldout", 12.5),
    ]
    assert plane.has_result(cid, "zoo", "heldout")
    plane.mark_scored(cid)
    assert plane.is_scored(cid) and list(plane.list_scored()) == [cid]
    plane.put_result("other/update_000000001", "self", "classic", {"return_mean": 1.0})
    assert [r.checkpoint_id for r in plane.list_results()] == [cid, cid, "other/update_000000001"]
    with pytest.raises(ValueError, match="JSON"):
        plane.put_result(cid, "zoo", "classic", {"bad": object()})


def test_zoo_manifest(plane):
    fcp = PartnerRecord("fcp_s0", "fcp", 0, "overcooked:cramped_room", 10**7, "zoo/fcp_s0", "ab" * 32)
    ippo = PartnerRecord("ippo_s1", "ippo", 1, "overcooked:coord_ring", 10**7, "zoo/ippo_s1", "cd" * 32, 5.0)
    assert plane.add_partner(ippo) and plane.add_partner(fcp)
    assert not plane.add_partner(ippo)  # replaced, not added twice
    listed = plane.list_partners()
    assert [p.name for p in listed] == ["fcp_s0", "ippo_s1"] and listed[0].added_at > 0
    assert plane.get_partner("ippo_s1") == ippo
    assert plane.remove_partner("fcp_s0") and not plane.remove_partner("fcp_s0")
    assert [p.name for p in plane.list_partners()] == ["ippo_s1"]
    assert json.loads(plane._r.hget(plane.key("zoo"), "ippo_s1"))["env"] == "overcooked:coord_ring"


def test_unreachable_redis_stops_start_up_with_the_fix():
    url = f"redis://127.0.0.1:{free_port('127.0.0.1')}/0"
    with pytest.raises(StoreUnavailableError) as info:
        ControlPlane.connect(StoreConfig(url=url, retries=0))
    message = str(info.value)
    assert url in message and "redis-server" in message and ENV_URL in message and "Traceback" not in message
    no_outbox = ControlPlane(StoreConfig(url=url, retries=0))
    with pytest.raises(StoreUnavailableError):
        no_outbox.publish_checkpoint(_event(1))  # nowhere to keep it: the caller must know


def test_wrong_or_missing_password_names_the_fix(server, monkeypatch):
    monkeypatch.delenv(ENV_PASSWORD, raising=False)
    for password in ("wrong-pw", ""):
        with pytest.raises(StoreError) as info:
            ControlPlane.connect(StoreConfig(url=server.url, password=password, retries=0))
        assert ENV_PASSWORD in str(info.value) and server.url in str(info.value)
        assert not isinstance(info.value, StoreUnavailableError)
    with pytest.raises(StoreError) as info:
        ControlPlane.connect(StoreConfig(url=f"redis://:wrong-pw@127.0.0.1:{server.port}/0", retries=0))
    assert "wrong-pw" not in str(info.value) and ":***@" in str(info.value)  # never echo a password

    monkeypatch.setenv(ENV_PASSWORD, PASSWORD)
    with ControlPlane.connect(StoreConfig(url=server.url)) as plane:
        assert plane.ping()


def test_missing_redis_server_binary_says_how_to_install():
    with pytest.raises(StoreError, match="apt-get install redis-server"):
        LocalRedis(executable="no-such-redis-server-binary").start()


def test_event_from_a_saved_checkpoint(plane, tmp_path):
    import numpy as np

    from cec import checkpoints

    path = checkpoints.save(
        tmp_path / "ippo-s4" / "checkpoints" / "update_000000005",
        {"w": np.zeros(3, np.float32)},
        update=5,
        env_steps=500,
        config={"algorithm": "ippo", "seed": 4},
        metadata={"algorithm": "ippo", "seeds": [4, 5]},
    )
    event = CheckpointEvent.from_checkpoint(path, "ippo-s4")
    meta = checkpoints.read_meta(path)
    assert (event.update, event.env_steps, event.algorithm, event.seed) == (5, 500, "ippo", 4)
    assert event.sha256 == meta["sha256"] and event.path == str(path)
    assert event.checkpoint_id == "ippo-s4/update_000000005" and event.checkpoint_id.endswith(path.name)
    plane.publish_checkpoint(event)
    assert plane.get_checkpoint(event.checkpoint_id) == event
