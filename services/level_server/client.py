"""Client library of the level server, for actors and users.

    client = LevelClient("127.0.0.1:50051")             # token=..., root_cert=... for a guarded server
    levels = client.get_levels(64, seed=0)              # a batched NumPy `Level`, ready for a jitted rollout
    names, heldout = client.heldout()
    client.validate("WWPWW\\nO0 1O\\nW   W\\nWBWXW").solvable

    with LevelStreamBuffer("127.0.0.1:50051", seed=7, capacity=8192) as stream:
        batch = stream.take(256)                        # from the local buffer; no network wait when full

`LevelStreamBuffer` keeps a background stream filling a bounded local buffer; when the connection drops it
reconnects with exponential backoff and resumes the seeded sequence at the next index, so a consumer sees
the same levels it would have seen without the outage.
"""

from __future__ import annotations

import logging
import random
import threading
import time
from collections import deque
from collections.abc import Generator
from dataclasses import dataclass
from typing import Any

import grpc
import numpy as np

from cec.levels.generator import GeneratorConfig
from cec.levels.level import Level
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.v1 import level_service_pb2_grpc as pb_grpc
from cec.levels.wire import config_to_proto, decode, encode
from services.level_server.config import TOKEN_ENV, check_token, is_loopback_address, read_pem
from services.level_server.source import Validation, concat, take_rows

log = logging.getLogger("cec.level_client")

MAX_MESSAGE_BYTES = 128 * 1024 * 1024


def _channel(address: str, root_cert: str | None) -> grpc.Channel:
    # Each client owns its connection state: with gRPC's process-wide subchannel pool, a new client (or a
    # reconnecting stream) to a server that was down inherits the old connection's reconnect backoff (up to
    # 2 minutes) and fails fast with the stale "connection refused". The backoff is capped at 5 s, like the
    # stream buffer's own.
    options = [
        ("grpc.max_receive_message_length", MAX_MESSAGE_BYTES),
        ("grpc.use_local_subchannel_pool", 1),
        ("grpc.initial_reconnect_backoff_ms", 100),
        ("grpc.max_reconnect_backoff_ms", 5000),
    ]
    if root_cert is None:
        return grpc.insecure_channel(address, options=options)
    creds = grpc.ssl_channel_credentials(root_certificates=read_pem(root_cert, "root certificate"))
    return grpc.secure_channel(address, creds, options=options)


class LevelClient:
    """Blocking calls to a level server. Errors surface as `grpc.RpcError` with the server's status code.

    Args:
        address: `host:port`.
        token: bearer token (default: the CEC_LEVEL_SERVER_TOKEN environment variable, if set).
        root_cert: PEM file of the CA that signed the server's certificate (TLS); None for plaintext.
        timeout: deadline in seconds of each unary call.
    """

    def __init__(
        self, address: str, token: str | None = None, root_cert: str | None = None, timeout: float = 30.0
    ) -> None:
        import os

        self.address = address
        self.timeout = timeout
        if token is None:
            token = os.environ.get(TOKEN_ENV, "")
            check_token(token, f"the {TOKEN_ENV} environment variable")
        check_token(token, "the level server's token")
        self.metadata = (("authorization", f"Bearer {token}"),) if token else ()
        self.channel = _channel(address, root_cert)
        if token and root_cert is None and not is_loopback_address(address):
            log.warning(
                "sending the level server's token to %s in plaintext (no root certificate, so no TLS): "
                "anyone on the network path can read and reuse it; give the server's CA certificate "
                "(root_cert=, `--root-cert`) and serve with tls_cert/tls_key",
                address,
            )
        self.stub = pb_grpc.LevelServiceStub(self.channel)

    def close(self) -> None:
        self.channel.close()

    def __enter__(self) -> LevelClient:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _call(self, method: str, request: Any, timeout: float | None = None) -> Any:
        fn = getattr(self.stub, method)
        return fn(request, timeout=timeout or self.timeout, metadata=self.metadata)

    def info(self) -> pb.ServerInfo:
        return self._call("GetServerInfo", pb.GetServerInfoRequest())

    def wait_ready(self, timeout: float = 60.0) -> pb.ServerInfo:
        """Waits until the server answers (e.g. right after starting it); returns its info."""
        grpc.channel_ready_future(self.channel).result(timeout=timeout)
        return self.info()

    def get_levels(
        self, n: int, seed: int | None = None, start_index: int = 0, config: GeneratorConfig | None = None
    ) -> Level:
        """`n` generated levels: levels [start_index, start_index + n) of sequence `seed`, or fresh ones."""
        req = pb.GetLevelsRequest(n=n, seed=seed, start_index=start_index)
        if config is not None:
            req.config.CopyFrom(config_to_proto(config))
        return decode(self._call("GetLevels", req))

    def heldout(self) -> tuple[list[str], Level]:
        """The held-out evaluation set: names and levels (105: 5 classic + 100 generated)."""
        msg = self._call("GetHeldout", pb.GetHeldoutRequest())
        return list(msg.names), decode(msg)

    def validate(self, level: Level | str, config: GeneratorConfig | None = None) -> Validation:
        """Server-side verdict on one level (or ASCII text). INVALID_ARGUMENT if it is malformed."""
        req = pb.ValidateLevelRequest()
        if isinstance(level, str):
            req.ascii = level
        else:
            req.packed.CopyFrom(encode(level))
        if config is not None:
            req.config.CopyFrom(config_to_proto(config))
        r = self._call("ValidateLevel", req)
        return Validation(
            level=take_rows(decode(r.level), 0),
            solvable=r.solvable,
            reasons=tuple(r.reasons),
            heldout_name=r.heldout_name,
            in_generator_space=r.in_generator_space,
            content_hash=r.content_hash,
        )

    def report_scores(self, levels: Level, scores: np.ndarray) -> pb.ReportScoresResponse:
        """Curriculum feedback: one learning score per level (e.g. mean |GAE|; higher = replay it more)."""
        req = pb.ReportScoresRequest(levels=encode(levels), scores=np.asarray(scores, np.float32).tolist())
        return self._call("ReportScores", req)

    def stream(
        self,
        seed: int,
        batch_size: int = 256,
        count: int = 0,
        start_index: int = 0,
        config: GeneratorConfig | None = None,
        timeout: float | None = None,
    ) -> Generator[tuple[int, Level], None, None]:
        """Yields (first index, levels) batches of sequence `seed` until `count` levels (0 = forever).

        Breaking out of the loop (or `close()` on the iterator) cancels the call on the server.
        """
        req = pb.StreamLevelsRequest(seed=seed, batch_size=batch_size, count=count, start_index=start_index)
        if config is not None:
            req.config.CopyFrom(config_to_proto(config))
        call = self.stub.StreamLevels(req, timeout=timeout, metadata=self.metadata)
        try:
            for msg in call:
                yield msg.first_index, decode(msg)
        finally:
            call.cancel()


@dataclass
class StreamStats:
    received: int = 0  # levels received from the server
    taken: int = 0  # levels handed to the consumer
    reconnects: int = 0
    waits: int = 0  # `take` calls that found the buffer short and waited on the network
    last_error: str = ""


class LevelStreamBuffer:
    """A bounded local buffer of levels kept full by a background stream (reconnecting with backoff).

    Args:
        address, token, root_cert: as for `LevelClient`.
        seed: the sequence to stream; resumed at the next index after a reconnect.
        capacity: levels to keep buffered (at most one batch more is held); the stream pauses, under
            gRPC flow control, while the buffer is full.
        batch_size: levels per streamed message.
        config: generator config (None: the server's default).
        backoff: (initial, maximum) seconds between reconnect attempts; doubles with jitter.
    """

    def __init__(
        self,
        address: str,
        seed: int,
        capacity: int = 8192,
        batch_size: int = 512,
        config: GeneratorConfig | None = None,
        token: str | None = None,
        root_cert: str | None = None,
        backoff: tuple[float, float] = (0.1, 5.0),
        start_index: int = 0,
    ) -> None:
        if capacity < batch_size:
            raise ValueError(f"capacity ({capacity}) must be at least batch_size ({batch_size})")
        self.client = LevelClient(address, token=token, root_cert=root_cert)
        self.seed, self.capacity, self.batch_size, self.config = seed, capacity, batch_size, config
        self.backoff = backoff
        self.next_index = start_index  # index of the next level to request from the server
        self.stats = StreamStats()
        self._chunks: deque[Level] = deque()
        self._buffered = 0
        self._cond = threading.Condition()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="level-stream", daemon=True)
        self._thread.start()

    @property
    def buffered(self) -> int:
        return self._buffered

    def _run(self) -> None:
        delay = self.backoff[0]
        while not self._stop.is_set():
            try:
                stream = self.client.stream(self.seed, self.batch_size, 0, self.next_index, self.config)
                for first, levels in stream:
                    n = int(levels.grid.shape[0])
                    with self._cond:
                        while self._buffered >= self.capacity and not self._stop.is_set():
                            self._cond.wait(0.1)
                        if self._stop.is_set():
                            stream.close()
                            return
                        self._chunks.append(levels)
                        self._buffered += n
                        self.next_index = first + n
                        self.stats.received += n
                        self._cond.notify_all()
                    delay = self.backoff[0]
            except grpc.RpcError as err:
                code = err.code() if hasattr(err, "code") else None
                self.stats.last_error = f"{code}: {err.details() if hasattr(err, 'details') else err}"
                if code in (grpc.StatusCode.INVALID_ARGUMENT, grpc.StatusCode.UNAUTHENTICATED,
                            grpc.StatusCode.PERMISSION_DENIED, grpc.StatusCode.UNIMPLEMENTED):  # fmt: skip
                    log.error("level stream refused, not retrying: %s", self.stats.last_error)
                    with self._cond:
                        self._cond.notify_all()
                    return
                if self._stop.is_set():
                    return
                log.warning("level stream lost (%s); reconnecting in %.2f s", self.stats.last_error, delay)
            if self._stop.wait(delay * (0.5 + random.random())):
                return
            self.stats.reconnects += 1
            delay = min(delay * 2, self.backoff[1])

    def take(self, n: int, timeout: float | None = 60.0) -> Level:
        """`n` levels from the buffer, in sequence order; waits for the network only if fewer are buffered.

        Raises `TimeoutError` after `timeout` seconds (None: wait forever) and `RuntimeError` if the server
        refused the stream for good (bad token, bad config).
        """
        if n > self.capacity:
            raise ValueError(f"take({n}) exceeds the buffer capacity {self.capacity}")
        deadline = None if timeout is None else time.monotonic() + timeout
        with self._cond:
            if self._buffered < n:
                self.stats.waits += 1
            while self._buffered < n:
                if not self._thread.is_alive():
                    raise RuntimeError(f"the level stream stopped: {self.stats.last_error}")
                left = None if deadline is None else deadline - time.monotonic()
                if left is not None and left <= 0:
                    raise TimeoutError(
                        f"waited {timeout} s for {n} levels from {self.client.address} ({self._buffered} "
                        f"buffered; last error: {self.stats.last_error or 'none'})"
                    )
                self._cond.wait(left if left is None else min(left, 0.5))
            parts, got = [], 0
            while got < n:
                head = self._chunks[0]
                size = int(head.grid.shape[0])
                if got + size <= n:
                    parts.append(self._chunks.popleft())
                    got += size
                else:
                    cut = n - got
                    parts.append(take_rows(head, slice(0, cut)))
                    self._chunks[0] = take_rows(head, slice(cut, size))
                    got = n
            self._buffered -= n
            self.stats.taken += n
            self._cond.notify_all()
        return concat(parts)

    def close(self) -> None:
        self._stop.set()
        with self._cond:
            self._cond.notify_all()
        self.client.close()  # also ends a stream blocked on the network
        self._thread.join(timeout=5)

    def __enter__(self) -> LevelStreamBuffer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()
