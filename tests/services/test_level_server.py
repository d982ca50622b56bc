"""Integration tests of the level server: a real grpc.aio server on a loopback port, real clients.

One server (default limits, fixed seed) serves most tests; tests that need other limits, auth or TLS start
their own. Each bad-input test also checks that the server keeps serving.
"""

from __future__ import annotations

import random
import socket
import subprocess
import sys
import threading
import time
import urllib.request
from pathlib import Path

import grpc
import jax
import numpy as np
import pytest
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_reflection.v1alpha import reflection_pb2, reflection_pb2_grpc
from prometheus_client import REGISTRY
from prometheus_client.parser import text_string_to_metric_families

from cec.levels import to_ascii
from cec.levels.classic import classic_levels
from cec.levels.generator import GeneratorConfig
from cec.levels.heldout import heldout_levels
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.wire import encode
from services.level_server.client import LevelClient, LevelStreamBuffer
from services.level_server.config import CurriculumConfig, LevelServerConfig
from services.level_server.server import SERVICE_NAME, ThreadedLevelServer
from services.metrics import MetricsEndpoint

ROOT = Path(__file__).resolve().parents[2]
SMALL = GeneratorConfig(structures=("cramped_room", "coord_ring"))


@pytest.fixture(scope="module")
def server():
    with ThreadedLevelServer(LevelServerConfig(port=0, seed=11, max_concurrent_streams=4)) as s:
        yield s


@pytest.fixture(scope="module")
def client(server):
    with LevelClient(server.address) as c:
        yield c


def _same(a, b) -> bool:
    return all(jax.tree.leaves(jax.tree.map(lambda x, y: np.array_equal(np.asarray(x), np.asarray(y)), a, b)))


def _code(fn) -> grpc.StatusCode:
    with pytest.raises(grpc.RpcError) as info:
        fn()
    return info.value.code()


def _still_serving(client: LevelClient) -> None:
    assert client.get_levels(3, seed=0).grid.shape == (3, 9, 9)


def _raw(client: LevelClient, method: str, payload: bytes, streaming: bool = False, timeout: float = 10):
    """Calls a method with raw request bytes (what a broken or hostile client can send)."""
    path = f"/{SERVICE_NAME}/{method}"
    call = client.channel.unary_stream(path) if streaming else client.channel.unary_unary(path)
    out = call(payload, timeout=timeout)
    return list(out) if streaming else out


# --- the API ---


def test_sequences_are_deterministic_and_independent_of_batching(client):
    whole = client.get_levels(700, seed=5)  # crosses a chunk boundary (512)
    streamed = [lv for _, lv in client.stream(seed=5, batch_size=96, count=700)]
    assert _same(whole, jax.tree.map(lambda *x: np.concatenate(x), *streamed))
    assert _same(client.get_levels(50, seed=5, start_index=650), jax.tree.map(lambda x: x[650:], whole))
    assert not np.array_equal(client.get_levels(50, seed=6).grid, whole.grid[:50])
    # every level is well-formed, solvable and not held out
    for lv in [jax.tree.map(lambda x, i=i: x[i], whole) for i in range(0, 700, 70)]:
        v = client.validate(lv)
        assert v.solvable and not v.heldout_name and v.in_generator_space


def test_stream_honours_count_and_first_index(client):
    batches = list(client.stream(seed=1, batch_size=64, count=150, start_index=10))
    assert [first for first, _ in batches] == [10, 74, 138]
    assert [int(lv.grid.shape[0]) for _, lv in batches] == [64, 64, 22]


def test_unseeded_requests_never_repeat(client):
    a, b = client.get_levels(20), client.get_levels(20)
    assert not np.array_equal(a.grid, b.grid)


def test_request_config_is_applied(client):
    levels = client.get_levels(64, seed=0, config=SMALL)
    sizes = {tuple(s) for s in np.asarray(levels.size).tolist()}
    assert sizes <= {(4, 5), (5, 4), (5, 5)}  # cramped room 4x5 (or rotated), coord ring 5x5


def test_coverage_and_structure_weights_reach_the_stream(client):
    """The generator settings that the wire used to drop: a stream asked for kitchens that need a hand-over
    gets only those, and structure weights choose the structures, as the library's generator would."""
    from cec.levels.generator import generate_batch
    from cec.levels.kinds import Kind, classify

    covered = GeneratorConfig(handover_share=1.0)
    (_, levels), *_ = client.stream(seed=3, batch_size=48, count=48, config=covered)
    kinds = np.asarray(jax.vmap(classify)(levels).kind)
    assert (kinds == Kind.HANDOVER).all(), kinds
    local = jax.device_get(generate_batch(jax.random.PRNGKey(3), 48, covered))
    assert (np.asarray(jax.vmap(classify)(local).kind) == Kind.HANDOVER).all()  # the same rule as local draws
    weighted = GeneratorConfig(structures=("cramped_room", "coord_ring"), structure_weights=(1.0, 1e5))
    sizes = {tuple(s) for s in np.asarray(client.get_levels(64, seed=0, config=weighted).size).tolist()}
    assert sizes == {(5, 5)}, sizes  # coord ring only (cramped room is 4x5)


def test_heldout_set_matches_the_library(client):
    names, levels = client.heldout()
    expected = heldout_levels()
    assert names == [n for n, _ in expected]
    assert _same(levels, jax.tree.map(lambda *x: np.stack(x), *[lv for _, lv in expected]))


def test_validate_explains_unsolvable_and_recognises_held_out(client):
    # the plate pile is walled off: no agent can reach it
    v = client.validate("WWWWW\nO0 1P\nW   X\nWWWWW\nWBWWW")
    assert not v.solvable and any("plate" in r for r in v.reasons)
    cramped = client.validate(to_ascii(classic_levels()["cramped_room"]))
    assert cramped.solvable and cramped.heldout_name == "cramped_room"


def test_server_info(client):
    info = client.info()
    assert info.api_version == "cec.levels.v1" and info.heldout_count == 105
    assert int(info.layout_space_size) > 10**15 and info.limits.max_concurrent_streams == 4
    assert not info.auth_required and not info.curriculum_enabled


def test_health_and_reflection(server, client):
    health = health_pb2_grpc.HealthStub(client.channel)
    for name in ("", SERVICE_NAME):
        resp = health.Check(health_pb2.HealthCheckRequest(service=name), timeout=5)
        assert resp.status == health_pb2.HealthCheckResponse.SERVING
    refl = reflection_pb2_grpc.ServerReflectionStub(client.channel)
    [resp] = list(refl.ServerReflectionInfo(iter([reflection_pb2.ServerReflectionRequest(list_services="")])))
    listed = {s.name for s in resp.list_services_response.service}
    assert {SERVICE_NAME, "grpc.health.v1.Health"} <= listed


# --- streams: cancellation, deadlines, flow control, limits ---


def _active_streams(server) -> int:
    return server.server.servicer.active_streams


def _wait_for(cond, timeout=10.0) -> bool:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if cond():
            return True
        time.sleep(0.02)
    return cond()


def test_cancelling_an_endless_stream_frees_the_server(server, client):
    it = client.stream(seed=2, batch_size=32)
    next(it)
    assert _active_streams(server) == 1
    it.close()  # cancels the call
    assert _wait_for(lambda: _active_streams(server) == 0)
    _still_serving(client)


def test_deadline_ends_a_stream_with_deadline_exceeded(server, client):
    def consume():
        for _ in client.stream(seed=3, batch_size=16, timeout=0.5):
            time.sleep(0.05)

    assert _code(consume) == grpc.StatusCode.DEADLINE_EXCEEDED
    assert _wait_for(lambda: _active_streams(server) == 0)
    _still_serving(client)


def test_slow_client_is_flow_controlled(server, client):
    """A client that stops reading makes the server stop producing (bounded buffering, not a backlog).

    The server may fill the transport's windows first; how fast depends on the machine, so the test waits
    for production to stop (a plateau), then checks it stays stopped and that what was sent is bounded.
    """
    batch = 4096

    def sent() -> float:
        return REGISTRY.get_sample_value("cec_level_server_levels_sent_total", {"rpc": "StreamLevels"}) or 0.0

    def plateau() -> bool:
        before = sent()
        time.sleep(0.5)
        return sent() == before

    before_stream = sent()
    it = client.stream(seed=4, batch_size=batch)
    try:
        next(it)  # then the client reads nothing
        assert _wait_for(plateau, timeout=60.0), "the server kept producing for a client that reads nothing"
        stopped_at = sent()
        time.sleep(1.0)
        assert sent() == stopped_at, "the server resumed producing for a client that reads nothing"
        # Unbounded, a backlog grows by tens of thousands of levels a second; the windows held 12 batches.
        assert stopped_at - before_stream <= 64 * batch, f"{stopped_at - before_stream} levels buffered"
    finally:
        it.close()
    assert _wait_for(lambda: _active_streams(server) == 0)


def test_concurrent_stream_limit_is_resource_exhausted(server, client):
    assert _wait_for(lambda: _active_streams(server) == 0)
    streams = [client.stream(seed=10 + i, batch_size=8) for i in range(4)]
    try:
        for s in streams:
            next(s)
        with pytest.raises(grpc.RpcError) as info:
            next(client.stream(seed=99, batch_size=8))
        assert (
            info.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
            and "max_concurrent_streams" in info.value.details()
        )
    finally:
        for s in streams:
            s.close()
    assert _wait_for(lambda: _active_streams(server) == 0)
    _still_serving(client)


# --- bad input ---


@pytest.mark.parametrize(
    ("request_", "code", "words"),
    [
        (pb.GetLevelsRequest(n=0), grpc.StatusCode.INVALID_ARGUMENT, ">= 1"),
        (pb.GetLevelsRequest(n=-5, seed=1), grpc.StatusCode.INVALID_ARGUMENT, ">= 1"),
        (pb.GetLevelsRequest(n=10**12, seed=1), grpc.StatusCode.RESOURCE_EXHAUSTED, "max_levels_per_request"),
        (pb.GetLevelsRequest(n=5, seed=1, start_index=-1), grpc.StatusCode.INVALID_ARGUMENT, "start_index"),
        (pb.GetLevelsRequest(n=5, start_index=3), grpc.StatusCode.INVALID_ARGUMENT, "needs a seed"),
        (
            pb.GetLevelsRequest(n=5, config=pb.GeneratorConfig(structures=["kitchen_sink"])),
            grpc.StatusCode.INVALID_ARGUMENT,
            "unknown structures",
        ),
        (
            pb.GetLevelsRequest(n=5, config=pb.GeneratorConfig(pots=pb.Bounds(min=3, max=1))),
            grpc.StatusCode.INVALID_ARGUMENT,
            "pots",
        ),
        (
            pb.GetLevelsRequest(n=5, config=pb.GeneratorConfig(count_decay=-1.0)),
            grpc.StatusCode.INVALID_ARGUMENT,
            "count_decay",
        ),
    ],
)
def test_bad_unary_requests_get_status_codes(client, request_, code, words):
    with pytest.raises(grpc.RpcError) as info:
        client._call("GetLevels", request_)
    assert info.value.code() == code and words in info.value.details()
    _still_serving(client)


@pytest.mark.parametrize(
    ("request_", "code"),
    [
        (pb.StreamLevelsRequest(batch_size=0), grpc.StatusCode.INVALID_ARGUMENT),
        (pb.StreamLevelsRequest(batch_size=-1), grpc.StatusCode.INVALID_ARGUMENT),
        (pb.StreamLevelsRequest(batch_size=10**9), grpc.StatusCode.RESOURCE_EXHAUSTED),
        (pb.StreamLevelsRequest(batch_size=8, count=-3), grpc.StatusCode.INVALID_ARGUMENT),
    ],
)
def test_bad_stream_requests_get_status_codes(client, request_, code):
    assert _code(lambda: list(client.stub.StreamLevels(request_, timeout=10))) == code
    _still_serving(client)


def test_unknown_fields_are_invalid_argument(client):
    # field 15 (varint) does not exist in cec.levels.v1: a client of another API version
    raw = pb.GetLevelsRequest(n=2, seed=1).SerializeToString() + bytes([0x78, 0x05])
    with pytest.raises(grpc.RpcError) as info:
        _raw(client, "GetLevels", raw)
    assert info.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "[15]" in info.value.details()
    nested = pb.GetLevelsRequest(n=2, seed=1)
    raw = nested.SerializeToString() + b"\x22\x02\x78\x01"  # config (field 4) holding unknown field 15
    with pytest.raises(grpc.RpcError) as info:
        _raw(client, "GetLevels", raw)
    assert info.value.code() == grpc.StatusCode.INVALID_ARGUMENT and "config" in info.value.details()


def _packed_cramped():
    return encode(classic_levels()["cramped_room"])


def test_malformed_levels_are_invalid_argument(client):
    bad_length = _packed_cramped()
    bad_length.grid = bad_length.grid[:-1]
    bad_tile = _packed_cramped()
    bad_tile.grid = bytes([9]) + bad_tile.grid[1:]
    agent_on_wall = _packed_cramped()
    agent_on_wall.agent_pos = bytes([0, 0, 1, 2])
    two = encode(jax.tree.map(lambda *x: np.stack(x), *list(classic_levels().values())[:2]))
    cases = [
        (pb.ValidateLevelRequest(packed=bad_length), "bytes"),
        (pb.ValidateLevelRequest(packed=bad_tile), "tile"),
        (pb.ValidateLevelRequest(packed=agent_on_wall), "agent 0"),
        (pb.ValidateLevelRequest(packed=two), "exactly one"),
        (pb.ValidateLevelRequest(ascii="WWWW\nW??W"), ""),
        (pb.ValidateLevelRequest(), "set `packed` or `ascii`"),
        (pb.ReportScoresRequest(levels=bad_length, scores=[1.0]), "bytes"),
        (pb.ReportScoresRequest(levels=_packed_cramped(), scores=[1.0, 2.0]), "one score per level"),
    ]
    for request_, words in cases:
        method = "ValidateLevel" if isinstance(request_, pb.ValidateLevelRequest) else "ReportScores"
        with pytest.raises(grpc.RpcError) as info:
            client._call(method, request_)
        assert info.value.code() == grpc.StatusCode.INVALID_ARGUMENT, (request_, info.value.details())
        assert words in info.value.details()
    _still_serving(client)


def test_oversized_request_is_resource_exhausted(client):
    payload = pb.ValidateLevelRequest(ascii="W" * (5 * 1024 * 1024)).SerializeToString()
    with pytest.raises(grpc.RpcError) as info:
        _raw(client, "ValidateLevel", payload)
    assert info.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    _still_serving(client)


def test_fuzzed_request_bytes_never_crash_or_hang_the_server(client):
    rng = random.Random(1234)
    seen = set()
    methods = ["GetLevels", "GetHeldout", "ValidateLevel", "ReportScores", "GetServerInfo", "StreamLevels"]
    for i in range(120):
        payload = bytes(rng.getrandbits(8) for _ in range(rng.randint(0, 200)))
        method = methods[i % len(methods)]
        try:
            _raw(client, method, payload, streaming=method == "StreamLevels", timeout=10)
            seen.add("OK")
        except grpc.RpcError as err:
            assert err.code() in {grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.RESOURCE_EXHAUSTED}, (
                method, err.code(), err.details())  # fmt: skip
            seen.add(err.code().name)
    assert "INVALID_ARGUMENT" in seen
    _still_serving(client)


def test_too_many_generator_configs_is_resource_exhausted():
    with ThreadedLevelServer(LevelServerConfig(port=0, seed=0, max_distinct_configs=2)) as s, \
            LevelClient(s.address) as c:  # fmt: skip
        c.get_levels(2, seed=0, config=SMALL)  # default + SMALL = 2
        with pytest.raises(grpc.RpcError) as info:
            c.get_levels(2, seed=0, config=SMALL.replace(count_decay=0.9))
        assert info.value.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        assert "max_distinct_configs" in info.value.details()
        c.get_levels(2, seed=0, config=SMALL)  # known configs still work


# --- auth, TLS ---


@pytest.fixture(scope="module")
def tls_files(tmp_path_factory):
    d = tmp_path_factory.mktemp("tls")
    subprocess.run(
        ["openssl", "req", "-x509", "-newkey", "rsa:2048", "-nodes", "-days", "1", "-subj", "/CN=localhost",
         "-addext", "subjectAltName=DNS:localhost,IP:127.0.0.1",
         "-keyout", str(d / "key.pem"), "-out", str(d / "cert.pem")],
        check=True, capture_output=True,
    )  # fmt: skip
    return d / "cert.pem", d / "key.pem"


def test_tls_and_token_authentication(tls_files):
    cert, key = tls_files
    config = LevelServerConfig(port=0, seed=0, auth_token="s3cret", tls_cert=str(cert), tls_key=str(key))
    with ThreadedLevelServer(config) as s:
        with LevelClient(s.address, token="s3cret", root_cert=str(cert)) as good:
            assert good.get_levels(4, seed=1).grid.shape == (4, 9, 9)
            assert good.info().auth_required
            health = health_pb2_grpc.HealthStub(good.channel)  # health checks need no token
            assert health.Check(health_pb2.HealthCheckRequest(), timeout=5, metadata=()).status == 1
        for token in ("wrong", ""):
            with LevelClient(s.address, token=token, root_cert=str(cert)) as bad:
                assert _code(lambda c=bad: c.get_levels(4, seed=1)) == grpc.StatusCode.UNAUTHENTICATED
                assert (
                    _code(lambda c=bad: list(c.stream(seed=1, count=10))) == grpc.StatusCode.UNAUTHENTICATED
                )
        with LevelClient(s.address, token="s3cret") as plaintext:  # a plaintext client cannot talk to it
            assert _code(lambda: plaintext.get_levels(1, seed=1)) == grpc.StatusCode.UNAVAILABLE


def test_bad_tls_files_and_a_port_in_use_are_clear_errors_before_any_work(tls_files, tmp_path):
    from cec.config import ConfigError

    cert, key = tls_files
    garbage = tmp_path / "garbage.pem"
    garbage.write_bytes(b"\x00not a certificate")
    armoured = tmp_path / "armoured.pem"
    armoured.write_text("-----BEGIN CERTIFICATE-----\nnot base64!\n-----END CERTIFICATE-----\n")
    other_key = tmp_path / "other_key.pem"
    subprocess.run(["openssl", "genrsa", "-out", str(other_key), "2048"], check=True, capture_output=True)
    for bad_cert, bad_key, message in (
        (garbage, key, "is not PEM"),
        (tmp_path / "missing.pem", key, "missing.pem. does not exist"),
        (armoured, armoured, "are not a certificate and its unencrypted private key"),
        (cert, other_key, "KEY_VALUES_MISMATCH"),
    ):
        with pytest.raises(ConfigError, match=message):
            LevelServerConfig(tls_cert=str(bad_cert), tls_key=str(bad_key))
    with pytest.raises(ConfigError, match="root certificate file .* does not exist"):
        LevelClient("127.0.0.1:1", root_cert=str(tmp_path / "missing.pem"))

    with socket.socket() as taken:
        taken.bind(("127.0.0.1", 0))
        taken.listen()
        port = taken.getsockname()[1]
        proc = subprocess.run(
            [sys.executable, "-m", "apps.cli", "level-server", f"port={port}", "metrics_port=-1"],
            cwd=ROOT, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
    assert proc.returncode == 1 and "is the port in use?" in proc.stderr
    assert "warming up" not in proc.stderr and "Traceback" not in proc.stderr  # refused before compiling


def test_exposed_bind_without_auth_is_a_config_error():
    from cec.config import ConfigError

    with pytest.raises(ConfigError, match="auth_token"):
        LevelServerConfig(host="0.0.0.0")
    open_bind = LevelServerConfig(host="0.0.0.0", insecure=True)  # an explicit choice, which start-up names
    assert "without TLS or token: anyone there may call it" in open_bind.exposure_warning()
    with_token = LevelServerConfig(host="0.0.0.0", insecure=True, auth_token="s3cret")
    assert "the bearer token crosses the network in clear text" in with_token.exposure_warning()
    assert LevelServerConfig(auth_token="s3cret").exposure_warning() is None  # loopback


def test_cec_level_server_names_what_an_insecure_exposed_bind_leaves_open():
    """`cec level-server` bound beyond loopback with insecure=true says at start-up, before warming up,
    that its token crosses the network in clear text."""
    cmd = [sys.executable, "-m", "apps.cli", "level-server", "host=0.0.0.0", "insecure=true",
           "auth_token=s3cret", "port=0", "metrics_port=-1"]  # fmt: skip
    proc = subprocess.Popen(cmd, cwd=ROOT, stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
    seen = []
    try:
        assert proc.stderr is not None
        for line in proc.stderr:
            seen.append(line)
            if "warming up" in line:
                break
    finally:
        proc.kill()
        proc.wait(30)
    warning = next((s for s in seen if "insecure=true" in s), "")
    assert "the bearer token crosses the network in clear text" in warning, "".join(seen)


@pytest.mark.parametrize("token", ["two\nlines", "naïve", "tab\there", "\x00"])
def test_a_token_no_client_could_send_is_refused_at_start(token: str):
    """gRPC metadata carries printable ASCII only: such a token would start a server nobody can use."""
    from cec.config import ConfigError

    with pytest.raises(ConfigError, match="auth_token must be printable ASCII"):
        LevelServerConfig(auth_token=token)


# --- curriculum, metrics, reconnects, process lifecycle ---


def test_curriculum_replays_reported_high_score_levels():
    curriculum = CurriculumConfig(enabled=True, min_fill=5, replay_prob=0.5)
    config = LevelServerConfig(port=0, seed=0, curriculum=curriculum)
    with ThreadedLevelServer(config) as s, LevelClient(s.address) as c:
        served = c.get_levels(5, seed=1)  # scores are taken only for levels the server served
        reply = c.report_scores(served, np.array([5.0, 0.1, 0.1, 0.1, 0.1]))
        assert reply.curriculum_enabled and reply.accepted == 5 and reply.buffer_size == 5
        levels = c.get_levels(400, seed=3)
        reported = [bytes(np.asarray(served.grid[i]).tobytes()) for i in range(5)]
        replayed = [
            reported.index(grid)
            for grid in (np.asarray(g).tobytes() for g in levels.grid)
            if grid in reported
        ]
        assert 0.3 < len(replayed) / 400 < 0.7  # replay_prob 0.5 of each reply
        assert replayed.count(0) > len(replayed) / 2  # the top-scored level dominates


def test_metrics_are_exported_and_move(server, client):
    endpoint = MetricsEndpoint(0)
    try:

        def scrape() -> dict[str, float]:
            text = urllib.request.urlopen(endpoint.url, timeout=5).read().decode()
            out: dict[str, float] = {}
            for family in text_string_to_metric_families(text):
                for sample in family.samples:
                    key = sample.name + "".join(f"|{k}={v}" for k, v in sorted(sample.labels.items()))
                    out[key] = sample.value
            return out

        before = scrape()
        client.get_levels(77, seed=123_456)  # a fresh chunk: generated, then sent
        with pytest.raises(grpc.RpcError):
            client.get_levels(0, seed=1)
        after = scrape()
        assert after["cec_level_server_levels_sent_total|rpc=GetLevels"] - before.get(
            "cec_level_server_levels_sent_total|rpc=GetLevels", 0) == 77  # fmt: skip
        assert (
            after["cec_level_server_levels_generated_total"]
            > before["cec_level_server_levels_generated_total"]
        )
        key = "cec_level_server_rpcs_total|code=INVALID_ARGUMENT|rpc=GetLevels"
        assert after[key] - before.get(key, 0) == 1
        assert after["cec_level_server_rpc_duration_seconds_count|rpc=GetLevels"] > 0
        for name in ("cec_level_server_active_streams", "cec_level_server_heldout_rejections_total",
                     "cec_level_server_generator_configs"):  # fmt: skip
            assert name in after
    finally:
        endpoint.close()


def test_every_call_is_counted_before_the_client_has_its_answer(server, client):
    """A client (or a test, or an alert) that reads the metrics right after an answer sees that call in
    them: the count is taken before the status or reply is sent. Counted after `abort`, 48 of 300 failed
    GetLevels and 62 of 300 failed StreamLevels calls were not yet counted when the client had their status
    (a 2-core AMD EPYC, 2026-11-26)."""

    def count(rpc: str, code: str) -> float:
        labels = {"rpc": rpc, "code": code}
        return REGISTRY.get_sample_value("cec_level_server_rpcs_total", labels) or 0.0

    calls = {
        "GetLevels": lambda: client.get_levels(0, seed=1),
        "StreamLevels": lambda: list(client.stream(1, count=-1)),
    }
    for rpc, call in calls.items():
        for _ in range(50):
            before = count(rpc, "INVALID_ARGUMENT")
            with pytest.raises(grpc.RpcError):
                call()
            assert count(rpc, "INVALID_ARGUMENT") - before == 1, rpc
    before_ok = count("GetLevels", "OK")
    client.get_levels(3, seed=1)
    assert count("GetLevels", "OK") - before_ok == 1


def test_stream_buffer_reconnects_and_resumes_the_sequence():
    config = LevelServerConfig(port=0, seed=0)
    first = ThreadedLevelServer(config)
    port = first.port
    buf = LevelStreamBuffer(first.address, seed=42, capacity=512, batch_size=64, backoff=(0.05, 0.2))
    parts = []
    try:
        parts.append(buf.take(200, timeout=30))
        assert _wait_for(lambda: buf.buffered >= 512)  # refilled
        first.stop()  # outage: the consumer goes on with the buffer (and what the transport still holds)
        parts.append(buf.take(300, timeout=30))
        with ThreadedLevelServer(LevelServerConfig(port=port, seed=0)) as second:
            for _ in range(20):  # until the buffer has drained what the first server sent, and reconnected
                parts.append(buf.take(256, timeout=60))
                if buf.stats.reconnects and buf.stats.taken > buf.stats.received - 512:
                    break
            assert buf.stats.reconnects >= 1, buf.stats
            got = jax.tree.map(lambda *x: np.concatenate(x), *parts)
            with LevelClient(second.address) as c:
                assert _same(got, c.get_levels(int(got.grid.shape[0]), seed=42))
    finally:
        buf.close()


def test_cli_server_streams_and_stops_gracefully_on_sigterm(tmp_path):
    proc = subprocess.Popen(
        [sys.executable, "-m", "apps.cli", "level-server", "port=0", "metrics_port=-1", "seed=0"],
        cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True,
    )  # fmt: skip
    lines: list[str] = []
    ready = threading.Event()

    def read() -> None:
        assert proc.stdout is not None
        for line in proc.stdout:
            lines.append(line)
            if "ready on" in line:
                ready.set()

    threading.Thread(target=read, daemon=True).start()
    try:
        assert ready.wait(120), "".join(lines)
        address = next(line for line in lines if "ready on" in line).split("ready on ")[1].strip()
        out = subprocess.run(
            [sys.executable, "-m", "apps.cli", "levels", "stream", "--server", address, "--n", "300",
             "--out", str(tmp_path / "sheet.png")],
            cwd=ROOT, capture_output=True, text=True, timeout=120,
        )  # fmt: skip
        assert out.returncode == 0, out.stderr
        assert "received 300 levels" in out.stdout and (tmp_path / "sheet.png").stat().st_size > 0
        proc.terminate()  # SIGTERM
        assert proc.wait(30) == 0
        assert any("level server stopped" in line for line in lines)
    finally:
        proc.kill()
