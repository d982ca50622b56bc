"""The level server under hostile and careless input (issue 23): what a client sends can neither poison the
curriculum nor exhaust the server, and every bad request gets a clear status code, never INTERNAL.

Servers here run on loopback ports with small limits; each test takes a few seconds at most.
"""

from __future__ import annotations

import threading
import urllib.error
import urllib.request

import grpc
import jax
import numpy as np
import pytest
from hypothesis import HealthCheck, example, given, settings
from hypothesis import strategies as st

from cec.config import ConfigError, load_config
from cec.levels import from_ascii, stack_levels
from cec.levels.fingerprint import fingerprint_host
from cec.levels.heldout import heldout_levels
from cec.levels.solvability import validate_solvable
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.wire import encode
from services.level_server.client import LevelClient
from services.level_server.config import SMALL_REQUEST_BYTES, CurriculumConfig, LevelServerConfig
from services.level_server.curriculum import ServedWindow
from services.level_server.server import MAX_DETAIL_CHARS, SERVICE_NAME, ThreadedLevelServer
from services.metrics import MetricsEndpoint

UNSOLVABLE = [
    "WWWWW\nO0 1P\nW   X\nWWWWW\nWBWWW",  # the plate pile is walled off
    "WWWWWWW\nO0WWW1P\nB WWW X\nWWWWWWW",  # two regions, nothing to hand over
    "WWWWW\nW0 1W\nWWWWW\nOBPXW",  # every object out of reach
]
SEQUENCE_END = 512 * 2**32  # levels in a sequence at the default chunk_levels (fold_in's uint32 chunk index)


def _rows(levels) -> list[bytes]:
    """Each level's exact content (tiles, start cells, facings, size) as bytes, for set membership."""
    n = int(np.asarray(levels.grid).shape[0])
    parts = (levels.grid, levels.agent_pos, levels.agent_dir, levels.size)
    flat = np.concatenate([np.asarray(x).astype(np.uint8).reshape(n, -1) for x in parts], axis=1)
    return [row.tobytes() for row in flat]


def _fingerprints(levels) -> set[tuple[int, int]]:
    """Content identities as the held-out exclusion sees them (tiles and start cells, seat order ignored)."""
    return {tuple(fp) for fp in np.asarray(fingerprint_host(levels)).reshape(-1, 2).tolist()}


def _pad(raw: bytes, n: int) -> bytes:
    """`raw` plus a length-delimited field 15 of `n` bytes (a field no request defines)."""
    length, rest = bytearray(), n
    while True:
        length.append((rest & 0x7F) | (0x80 if rest > 0x7F else 0))
        rest >>= 7
        if not rest:
            break
    return raw + b"\x7a" + bytes(length) + b"u" * n


def _error(fn) -> grpc.RpcError:
    with pytest.raises(grpc.RpcError) as info:
        fn()
    return info.value


def _raw(client: LevelClient, method: str, payload: bytes, streaming: bool = False, timeout: float = 10):
    path = f"/{SERVICE_NAME}/{method}"
    if streaming:
        call = client.channel.unary_stream(path)(payload, timeout=timeout)
        try:
            return next(iter(call), None)  # the first batch is enough: an endless stream is then cancelled
        finally:
            call.cancel()
    return client.channel.unary_unary(path)(payload, timeout=timeout)


# --- finding 1: curriculum poisoning ---


@pytest.fixture(scope="module")
def curriculum_server():
    curriculum = CurriculumConfig(enabled=True, min_fill=20, replay_prob=0.5, capacity=200)
    config = LevelServerConfig(port=0, seed=5, max_concurrent_streams=4, curriculum=curriculum)
    with ThreadedLevelServer(config) as s, LevelClient(s.address) as c:
        yield s, c


def test_report_scores_refuses_heldout_unsolvable_and_unserved_levels(curriculum_server):
    server, c = curriculum_server
    heldout = [level for _, level in heldout_levels()]
    unsolvable = [from_ascii(text) for text in UNSOLVABLE]
    assert all(validate_solvable(level, True) for level in unsolvable)

    # each held-out kitchen alone, with a score that would top the buffer
    for name, level in heldout_levels():
        err = _error(lambda lv=level: c.report_scores(stack_levels([lv]), np.array([1e6])))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT, (name, err.details())
        assert "held-out" in err.details() and repr(name) in err.details()
    err = _error(lambda: c.report_scores(stack_levels(heldout), np.full(len(heldout), 1e6)))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    for level in unsolvable:
        err = _error(lambda lv=level: c.report_scores(stack_levels([lv]), np.array([1e6])))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "unsolvable" in err.details(), err.details()

    served = c.get_levels(40, seed=77)
    # a solvable level the server never served (a served one, both cooks turned a quarter): NOT_FOUND
    turned = jax.tree.map(lambda x: np.array(x[:1]), served)
    turned.agent_dir[:] = (turned.agent_dir + 1) % 4
    err = _error(lambda: c.report_scores(turned, np.array([1e6])))
    assert err.code() == grpc.StatusCode.NOT_FOUND and "served_window" in err.details(), err.details()
    # all or nothing: served levels with one held-out kitchen among them are refused whole
    mixed = stack_levels([jax.tree.map(lambda x: x[0], served), heldout[0]])
    err = _error(lambda: c.report_scores(mixed, np.array([1.0, 1e6])))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT
    assert len(server.server.source.replay) == 0

    reply = c.report_scores(served, np.linspace(0.1, 4.0, 40))  # levels it served: taken
    assert reply.accepted == 40 and reply.buffer_size == 40

    forbidden = _fingerprints(stack_levels(heldout + unsolvable))
    streamed = [levels for _, levels in c.stream(seed=8, batch_size=1000, count=10_000)]
    assert sum(int(levels.grid.shape[0]) for levels in streamed) == 10_000
    reported = set(_rows(served))
    replayed = 0
    for levels in streamed:
        assert not _fingerprints(levels) & forbidden  # no held-out or unsolvable kitchen, ever
        assert _rows(turned)[0] not in _rows(levels)  # nor the refused hand-made one
        replayed += sum(row in reported for row in _rows(levels))
    assert 4_000 < replayed < 6_000  # the curriculum is live: half of every batch replays reported levels

    # replayed levels were served too: scores for them are taken again
    again = jax.tree.map(lambda x: x[:50], streamed[0])
    assert c.report_scores(again, np.ones(50)).accepted == 50


def test_served_window_remembers_the_newest_levels_only():
    window = ServedWindow(capacity=3 * ServedWindow.BLOCK)
    digests = np.arange(1, 6 * ServedWindow.BLOCK + 1, dtype=np.uint64) * np.uint64(0x9E3779B97F4A7C15)
    for block in np.split(digests, 12):
        window.add(block)
    hit = window.contains(digests)
    assert hit[-3 * ServedWindow.BLOCK :].all() and not hit[: 2 * ServedWindow.BLOCK].any()
    assert len(window) <= 4 * ServedWindow.BLOCK
    assert not window.contains(np.array([12345], np.uint64)).any()


# --- finding 2: resource exhaustion ---


@pytest.fixture(scope="module")
def small_server():
    config = LevelServerConfig(
        port=0, seed=3, workers=1, max_concurrent_streams=2, max_concurrent_validations=2,
        max_levels_per_request=64, max_batch_size=64, max_distinct_configs=1,
        curriculum=CurriculumConfig(enabled=True, min_fill=4),
    )  # fmt: skip
    with ThreadedLevelServer(config) as s, LevelClient(s.address) as c:
        yield s, c


def test_request_sizes_are_bounded_for_every_rpc(small_server):
    _, c = small_server
    big = SMALL_REQUEST_BYTES + 10
    for method, request in [
        ("GetLevels", pb.GetLevelsRequest(n=1, seed=1)),
        ("StreamLevels", pb.StreamLevelsRequest(batch_size=1)),
        ("GetHeldout", pb.GetHeldoutRequest()),
        ("GetServerInfo", pb.GetServerInfoRequest()),
        ("ValidateLevel", pb.ValidateLevelRequest(ascii="W" * 4000)),
    ]:
        raw = _pad(request.SerializeToString(), big + (4096 if method == "ValidateLevel" else 0))
        err = _error(lambda m=method, r=raw: _raw(c, m, r, streaming=m == "StreamLevels"))
        assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED, (method, err.details())
        assert "bytes this server accepts" in err.details()
    err = _error(lambda: c.validate("W" * 5000))  # fits the request limit, not a kitchen's size
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "max_ascii_bytes" in err.details()
    huge = pb.ValidateLevelRequest(ascii="W" * (2 * 1024 * 1024)).SerializeToString()  # > max_message_bytes
    assert _error(lambda: _raw(c, "ValidateLevel", huge)).code() == grpc.StatusCode.RESOURCE_EXHAUSTED
    assert c.get_levels(2, seed=0).grid.shape == (2, 9, 9)


def test_validations_are_bounded_and_never_starve_generation():
    """One slow validation fills the check pool (max 1): a second is refused at once while generation (one
    worker) still answers; a call beyond max_concurrent_rpcs is refused by gRPC, and all recover after."""
    config = LevelServerConfig(
        port=0,
        seed=3,
        workers=1,
        max_concurrent_streams=2,
        max_concurrent_rpcs=3,
        max_concurrent_validations=1,
    )
    with ThreadedLevelServer(config) as server, LevelClient(server.address) as c:
        source = server.server.source
        entered, release = threading.Event(), threading.Event()
        original = source.validate

        def slow_validate(*args, **kwargs):
            entered.set()
            release.wait(30)
            return original(*args, **kwargs)

        source.validate = slow_validate
        results: list = []
        first = threading.Thread(target=lambda: results.append(c.validate(UNSOLVABLE[0])))
        first.start()
        streams = []
        try:
            assert entered.wait(10)
            err = _error(lambda: c.validate(UNSOLVABLE[1]))
            assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED, err.details()
            assert "max_concurrent_validations" in err.details()
            assert c.get_levels(8, seed=1).grid.shape == (8, 9, 9)  # generation is not behind validations
            streams = [c.stream(seed=s, batch_size=1) for s in (1, 2)]
            for s in streams:
                next(s)  # 1 validation + 2 streams: max_concurrent_rpcs=3 calls in flight
            assert _error(lambda: c.get_levels(1, seed=1)).code() == grpc.StatusCode.RESOURCE_EXHAUSTED
        finally:
            for s in streams:
                s.close()
            release.set()
            first.join(30)
        assert not results[0].solvable  # the slow validation finished normally
        source.validate = original
        for _ in range(100):  # the cancelled streams are released shortly
            try:
                assert c.validate(UNSOLVABLE[1]).reasons
                break
            except grpc.RpcError as err:
                assert err.code() == grpc.StatusCode.RESOURCE_EXHAUSTED
                threading.Event().wait(0.05)
        else:
            raise AssertionError("the server did not recover after the calls ended")


# --- finding 3: status codes ---


def test_sequence_end_is_invalid_argument_not_internal(small_server):
    _, c = small_server
    assert c.get_levels(1, seed=1, start_index=SEQUENCE_END - 1).grid.shape == (1, 9, 9)
    for start, n in [(SEQUENCE_END, 1), (SEQUENCE_END - 1, 2), (2**63 - 1, 1)]:
        err = _error(lambda s=start, k=n: c.get_levels(k, seed=1, start_index=s))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and str(SEQUENCE_END) in err.details()
    for start, count in [(SEQUENCE_END, 0), (SEQUENCE_END - 3, 4), (2**63 - 1, 0)]:
        err = _error(lambda s=start, k=count: list(c.stream(seed=1, batch_size=8, count=k, start_index=s)))
        assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and "end of a sequence" in err.details()
    # an endless stream near the end ends cleanly with the sequence's last levels
    got = [
        (first, int(lv.grid.shape[0]))
        for first, lv in c.stream(seed=1, batch_size=4, start_index=SEQUENCE_END - 6)
    ]
    assert got == [(SEQUENCE_END - 6, 4), (SEQUENCE_END - 2, 2)]


def test_error_messages_echo_at_most_a_clip_of_the_input(small_server):
    _, c = small_server
    long_name = pb.GetLevelsRequest(n=1, config=pb.GeneratorConfig(structures=["k" * 15_000]))
    err = _error(lambda: c._call("GetLevels", long_name))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT, err.details()  # was RESOURCE_EXHAUSTED (metadata)
    assert "unknown structures" in err.details() and "choose from" in err.details()
    assert len(err.details()) <= MAX_DETAIL_CHARS + 50
    err = _error(lambda: c.validate("WWWWW\nO0 1P\nfacing: " + "N " * 1900))
    assert err.code() == grpc.StatusCode.INVALID_ARGUMENT and len(err.details()) <= MAX_DETAIL_CHARS + 50


METRICS_QUERIES = ["?name[]=x", "?name[]=", "?name[]=cec_level_server_active_streams&name[]=y",
                   "?name[]=%ff%fe", "?format=nope&name[]"]  # fmt: skip


@pytest.mark.parametrize("query", METRICS_QUERIES)
def test_metrics_endpoint_never_answers_500(query):
    endpoint = MetricsEndpoint(0, component="level_server")
    try:
        try:
            reply = urllib.request.urlopen(endpoint.url + query, timeout=5)
            status, body = reply.status, reply.read().decode()
        except urllib.error.HTTPError as err:
            status, body = err.code, ""
        assert status < 500, (query, status)
        if "active_streams" in query:
            names = {line.split()[0] for line in body.splitlines() if line and not line.startswith("#")}
            assert names == {"cec_level_server_active_streams"}
    finally:
        endpoint.close()


# --- property: no malformed request ends in INTERNAL or UNKNOWN ---

INT64 = st.one_of(
    st.integers(-(2**63), 2**63 - 1),
    st.sampled_from([0, 1, -1, 64, 65, SEQUENCE_END - 1, SEQUENCE_END, 2**63 - 1, -(2**63)]),
)
UINT32 = st.one_of(st.integers(0, 2**32 - 1), st.sampled_from([0, 1, 2, 64]))
FLOAT = st.floats(allow_nan=True, allow_infinity=True)
NAMES = st.lists(
    st.one_of(st.sampled_from(["cramped_room", "coord_ring", "forced_coord", ""]), st.text(max_size=300)),
    max_size=6,
)


@st.composite
def generator_configs(draw) -> pb.GeneratorConfig:
    msg = pb.GeneratorConfig(structures=draw(NAMES))
    for name in ("onion_piles", "plate_piles", "pots", "goals"):
        if draw(st.booleans()):
            getattr(msg, name).CopyFrom(pb.Bounds(min=draw(INT64), max=draw(INT64)))
    if draw(st.booleans()):
        msg.count_decay = draw(FLOAT)
    if draw(st.booleans()):
        msg.allow_decoys = draw(st.booleans())
    return msg


@st.composite
def level_batches(draw) -> pb.LevelBatch:
    """Level batches from valid ones with fields cut, padded or overwritten, to random bytes."""
    cramped = encode(heldout_levels()[0][1])
    msg = pb.LevelBatch(
        count=draw(st.one_of(st.just(1), UINT32)),
        grid=cramped.grid,
        agent_pos=cramped.agent_pos,
        agent_dir=cramped.agent_dir,
        size=cramped.size,
    )
    for name in ("grid", "agent_pos", "agent_dir", "size"):
        how = draw(st.sampled_from(["keep", "keep", "random", "flip"]))
        if how == "random":
            setattr(msg, name, draw(st.binary(max_size=200)))
        elif how == "flip":
            raw = bytearray(getattr(msg, name))
            raw[draw(st.integers(0, len(raw) - 1))] = draw(st.integers(0, 255))
            setattr(msg, name, bytes(raw))
    return msg


KITCHEN_TEXT = st.text(alphabet="WOBPX 01A\n\rNSEfacing:\t?é\x00", max_size=400)
REQUESTS = st.one_of(
    st.builds(
        lambda n, seed, start, config, has_seed: (
            "GetLevels",
            pb.GetLevelsRequest(n=n, seed=seed if has_seed else None, start_index=start, config=config),
        ),
        st.one_of(st.integers(-3, 70), INT64),
        INT64,
        INT64,
        st.one_of(st.none(), generator_configs()),
        st.booleans(),
    ),
    st.builds(
        lambda seed, batch, count, start, config: (
            "StreamLevels",
            pb.StreamLevelsRequest(
                seed=seed, batch_size=batch, count=count, start_index=start, config=config
            ),
        ),
        INT64,
        st.one_of(st.integers(-2, 70), INT64),
        st.one_of(st.integers(-2, 200), INT64),
        INT64,
        st.one_of(st.none(), generator_configs()),
    ),
    st.builds(
        lambda text, config: ("ValidateLevel", pb.ValidateLevelRequest(ascii=text, config=config)),
        st.one_of(KITCHEN_TEXT, st.sampled_from(UNSOLVABLE), st.text(min_size=4000, max_size=5000)),
        st.one_of(st.none(), generator_configs()),
    ),
    st.builds(lambda batch: ("ValidateLevel", pb.ValidateLevelRequest(packed=batch)), level_batches()),
    st.builds(
        lambda batch, scores: ("ReportScores", pb.ReportScoresRequest(levels=batch, scores=scores)),
        level_batches(),
        st.lists(st.floats(width=32), max_size=3),
    ),
    st.builds(
        lambda method, raw: (method, raw),
        st.sampled_from(
            ["GetLevels", "GetHeldout", "ValidateLevel", "ReportScores", "GetServerInfo", "StreamLevels"]
        ),
        st.binary(max_size=300),
    ),
)
ANSWERS = {
    grpc.StatusCode.INVALID_ARGUMENT,
    grpc.StatusCode.RESOURCE_EXHAUSTED,
    grpc.StatusCode.NOT_FOUND,
}


@settings(max_examples=150, deadline=None, suppress_health_check=[HealthCheck.function_scoped_fixture])
@given(case=REQUESTS)
@example(case=("ReportScores", b""))  # no levels: found by this test (fingerprinting an empty batch)
@example(case=("GetLevels", pb.GetLevelsRequest(n=1, seed=1, start_index=SEQUENCE_END)))  # fold_in overflow
def test_malformed_requests_never_get_internal_or_unknown(small_server, case):
    _, c = small_server
    method, request = case
    raw = request if isinstance(request, bytes) else request.SerializeToString()
    try:
        _raw(c, method, raw, streaming=method == "StreamLevels")
    except grpc.RpcError as err:
        assert err.code() in ANSWERS, (method, request, err.code(), err.details())
        assert len(err.details()) <= MAX_DETAIL_CHARS + 50


@pytest.mark.parametrize(
    "override",
    ["max_ascii_bytes=10", "max_message_bytes=1000", "max_concurrent_validations=0", "max_concurrent_rpcs=32",
     "curriculum.served_window=0"],
)  # fmt: skip
def test_new_limits_are_checked_at_load(override):
    with pytest.raises(ConfigError, match=override.split("=")[0].split(".")[-1]):
        load_config(LevelServerConfig, None, [override])
