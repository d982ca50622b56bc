"""The gRPC adapter: `cec.levels.v1.LevelService` served by `grpc.aio` over a `LevelSource`.

Requests are parsed here (raw bytes in, so that undecodable bytes get INVALID_ARGUMENT rather than a
generic error; a request larger than its RPC can need gets RESOURCE_EXHAUSTED before it is parsed),
checked against the limits, and handed to the source on a thread pool, so generation never blocks the event
loop. Client-sent levels (`ValidateLevel`, `ReportScores`) are checked on a second, smaller pool whose
admission is bounded, so that validations can neither starve generation nor queue up without end. Error
messages are clipped (`clip`), so an echoed input never outgrows what gRPC can carry in a status. Streams
prefetch one batch and yield under gRPC flow control: a slow client makes the server wait, never buffer.
The standard health service and server reflection are registered; a bearer token (if configured) guards
everything but health checks; TLS when configured.

Size: the gRPC servicer and the server around it (auth, TLS, limits, health, reflection) are one
unit of configuration; the level sources are `source.py`.
"""

from __future__ import annotations

import asyncio
import hmac
import logging
import threading
import time
from collections.abc import AsyncIterator, Awaitable, Callable
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any, NoReturn, TypeVar

import grpc
import numpy as np
from google.protobuf.message import DecodeError, Message
from grpc_health.v1 import health_pb2, health_pb2_grpc
from grpc_health.v1.health import aio as health_aio
from grpc_reflection.v1alpha import reflection

from cec import __version__
from cec.checkpoints import code_version
from cec.config import ConfigError
from cec.levels.level import LevelError
from cec.levels.v1 import level_service_pb2 as pb
from cec.levels.wire import (
    API_VERSION,
    config_from_proto,
    config_to_proto,
    decode,
    encode,
    reject_unknown_fields,
)
from services import metrics
from services.level_server.config import SMALL_REQUEST_BYTES, LevelServerConfig, read_pem
from services.level_server.source import (
    InvalidRequestError,
    LevelSource,
    LimitExceededError,
    UnknownLevelError,
    take_rows,
)

log = logging.getLogger("cec.level_server")

SERVICE_NAME = pb.DESCRIPTOR.services_by_name["LevelService"].full_name
M = TypeVar("M", bound=Message)
#: longest status message sent (characters): gRPC carries it in a trailer limited to 16 KiB in all, and
#: messages may echo client input (an unknown structure name, a bad facing line)
MAX_DETAIL_CHARS = 600


def clip(text: str, limit: int = MAX_DETAIL_CHARS) -> str:
    """`text`, its middle cut out if longer than `limit` (the cause leads a message, the fix ends it)."""
    if len(text) <= limit:
        return text
    head = limit * 2 // 3
    tail = limit - head
    return f"{text[:head]} [... {len(text) - head - tail} characters cut ...] {text[-tail:]}"


async def _abort(
    rpc: str, context: grpc.aio.ServicerContext, code: grpc.StatusCode, message: str
) -> NoReturn:
    """Ends the call with `code`, counted first: a client that has seen the status may read the metrics
    at once, so the count must not wait for the status to be sent."""
    metrics.RPCS.labels(rpc, code.name).inc()
    await context.abort(code, message)
    raise AssertionError("unreachable: abort raises")


def _status_of(err: BaseException) -> tuple[grpc.StatusCode, str]:
    if isinstance(err, InvalidRequestError | ConfigError | LevelError):
        return grpc.StatusCode.INVALID_ARGUMENT, clip(str(err))
    if isinstance(err, LimitExceededError):
        return grpc.StatusCode.RESOURCE_EXHAUSTED, clip(str(err))
    if isinstance(err, UnknownLevelError):
        return grpc.StatusCode.NOT_FOUND, clip(str(err))
    log.exception("internal error", exc_info=err)
    return grpc.StatusCode.INTERNAL, f"internal server error ({type(err).__name__}); see the server log"


def _parse(cls: type[M], raw: bytes) -> M:
    try:
        msg = cls.FromString(raw)
    except DecodeError as err:
        name = cls.DESCRIPTOR.full_name
        raise InvalidRequestError(f"the request is not a valid {name} message: {err}") from err
    reject_unknown_fields(msg)
    return msg


class LevelServicer:
    """The RPC methods. Each takes the raw request bytes and the call context.

    Generation runs on `executor`; checks of client-sent levels on `check_executor` (its own threads, at
    most `max_concurrent_validations` calls admitted at once, counted until their job ends, so a client
    that cancels cannot pile up queued work).
    """

    def __init__(
        self,
        source: LevelSource,
        executor: ThreadPoolExecutor,
        check_executor: ThreadPoolExecutor | None = None,
    ) -> None:
        self.source = source
        self.config = source.config
        self.executor = executor
        self.check_executor = check_executor or ThreadPoolExecutor(
            self.config.max_concurrent_validations, thread_name_prefix="level-check"
        )
        self._check_slots = threading.BoundedSemaphore(self.config.max_concurrent_validations)
        self.active_streams = 0
        self.version = f"{__version__} ({code_version()})"

    async def _run(self, fn: Callable[..., Any], *args: Any) -> Any:
        return await asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)

    async def _check(self, rpc: str, fn: Callable[..., Any], *args: Any) -> Any:
        """Runs a check of client-sent levels on the check pool, or refuses it when the pool is full."""
        if not self._check_slots.acquire(blocking=False):
            raise LimitExceededError(
                f"the server is already checking {self.config.max_concurrent_validations} requests with "
                f"client levels (ValidateLevel, ReportScores; max_concurrent_validations="
                f"{self.config.max_concurrent_validations}); retry {rpc} with backoff"
            )
        try:
            job: Future[Any] = self.check_executor.submit(fn, *args)
        except BaseException:
            self._check_slots.release()
            raise
        job.add_done_callback(lambda _: self._check_slots.release())
        return await asyncio.wrap_future(job)

    @staticmethod
    def _check_size(rpc: str, raw: bytes, limit: int, why: str) -> None:
        if len(raw) > limit:
            raise LimitExceededError(
                f"a {rpc} request of {len(raw)} bytes exceeds the {limit} bytes this server accepts for it "
                f"({why}); send a smaller request"
            )

    async def _unary(
        self, rpc: str, context: grpc.aio.ServicerContext, body: Callable[[], Awaitable[M]]
    ) -> M:
        start = time.perf_counter()
        try:
            reply = await body()
        except asyncio.CancelledError:
            metrics.RPCS.labels(rpc, "CANCELLED").inc()
            raise
        except Exception as err:  # every failure becomes a status code, never a crash
            await _abort(rpc, context, *_status_of(err))
        # counted before the reply leaves, as failures are before their status does (`_abort`)
        metrics.RPCS.labels(rpc, "OK").inc()
        metrics.RPC_LATENCY.labels(rpc).observe(time.perf_counter() - start)
        return reply

    # --- unary RPCs -----------------------------------------------------------------------------------------

    async def get_levels(self, raw: bytes, context: grpc.aio.ServicerContext) -> pb.LevelBatch:
        async def body() -> pb.LevelBatch:
            self._check_size("GetLevels", raw, SMALL_REQUEST_BYTES, "a request without levels")
            req = _parse(pb.GetLevelsRequest, raw)
            gen = config_from_proto(req.config, self.config.generator)

            def job() -> pb.LevelBatch:
                if req.HasField("seed"):
                    start, levels = req.start_index, self.source.levels(req.seed, req.start_index, req.n, gen)
                else:
                    if req.start_index:
                        raise InvalidRequestError("start_index needs a seed: it indexes a seeded sequence")
                    start, levels = self.source.fresh(req.n, gen)
                return encode(self.source.with_replay(levels), first_index=start)

            msg: pb.LevelBatch = await self._run(job)
            metrics.LEVELS_SENT.labels("GetLevels").inc(msg.count)
            return msg

        return await self._unary("GetLevels", context, body)

    async def get_heldout(self, raw: bytes, context: grpc.aio.ServicerContext) -> pb.LevelBatch:
        async def body() -> pb.LevelBatch:
            self._check_size("GetHeldout", raw, SMALL_REQUEST_BYTES, "a request without levels")
            _parse(pb.GetHeldoutRequest, raw)
            names, levels = self.source.heldout
            metrics.LEVELS_SENT.labels("GetHeldout").inc(len(names))
            return encode(levels, names=names)

        return await self._unary("GetHeldout", context, body)

    async def validate_level(self, raw: bytes, context: grpc.aio.ServicerContext) -> pb.ValidateLevelResponse:
        async def body() -> pb.ValidateLevelResponse:
            limit = SMALL_REQUEST_BYTES + self.config.max_ascii_bytes
            self._check_size("ValidateLevel", raw, limit, "one level: max_ascii_bytes plus room for a config")
            req = _parse(pb.ValidateLevelRequest, raw)
            gen = config_from_proto(req.config, self.config.generator)
            which = req.WhichOneof("level")
            if which is None:
                raise InvalidRequestError("ValidateLevelRequest needs a level: set `packed` or `ascii`")
            if which == "packed":
                if req.packed.count != 1:
                    raise InvalidRequestError(
                        f"`packed` must hold exactly one level, got count={req.packed.count}"
                    )
                level: Any = take_rows(decode(req.packed, check=False), 0)
            else:
                level = req.ascii
                if len(level) > self.config.max_ascii_bytes:
                    raise InvalidRequestError(
                        f"the ASCII level has {len(level)} characters; a kitchen is at most 9x9 tiles plus a "
                        "facing line (about 100), and this server parses at most "
                        f"{self.config.max_ascii_bytes} (max_ascii_bytes)"
                    )
            v = await self._check("ValidateLevel", self.source.validate, level, gen)
            return pb.ValidateLevelResponse(
                solvable=v.solvable,
                reasons=list(v.reasons),
                heldout=bool(v.heldout_name),
                heldout_name=v.heldout_name,
                in_generator_space=v.in_generator_space,
                content_hash=v.content_hash,
                level=encode(v.level),
            )

        return await self._unary("ValidateLevel", context, body)

    async def report_scores(self, raw: bytes, context: grpc.aio.ServicerContext) -> pb.ReportScoresResponse:
        async def body() -> pb.ReportScoresResponse:
            req = _parse(pb.ReportScoresRequest, raw)
            if req.levels.count > self.config.max_levels_per_request:
                raise LimitExceededError(
                    f"{req.levels.count} levels exceed max_levels_per_request="
                    f"{self.config.max_levels_per_request}; report in several requests"
                )

            def job() -> int:
                levels = decode(req.levels)
                return self.source.report_scores(levels, np.asarray(req.scores, np.float32))

            accepted = await self._check("ReportScores", job)
            replay = self.source.replay
            return pb.ReportScoresResponse(
                accepted=accepted, buffer_size=len(replay) if replay else 0, curriculum_enabled=bool(replay)
            )

        return await self._unary("ReportScores", context, body)

    async def get_server_info(self, raw: bytes, context: grpc.aio.ServicerContext) -> pb.ServerInfo:
        async def body() -> pb.ServerInfo:
            self._check_size("GetServerInfo", raw, SMALL_REQUEST_BYTES, "a request without levels")
            _parse(pb.GetServerInfoRequest, raw)
            c = self.config
            return pb.ServerInfo(
                version=self.version,
                api_version=API_VERSION,
                generator=config_to_proto(c.generator),
                layout_space_size=str(self.source.layout_space_size),
                heldout_count=len(self.source.heldout[0]),
                limits=pb.Limits(
                    max_batch_size=c.max_batch_size,
                    max_levels_per_request=c.max_levels_per_request,
                    max_concurrent_streams=c.max_concurrent_streams,
                    max_distinct_configs=c.max_distinct_configs,
                ),
                curriculum_enabled=c.curriculum.enabled,
                auth_required=bool(c.token),
            )

        return await self._unary("GetServerInfo", context, body)

    # --- the stream -----------------------------------------------------------------------------------------

    async def stream_levels(
        self, raw: bytes, context: grpc.aio.ServicerContext
    ) -> AsyncIterator[pb.LevelBatch]:
        start_time = time.perf_counter()
        code: str | None = "OK"  # None: counted by `_abort`
        counted = False
        pending: asyncio.Future[pb.LevelBatch] | None = None
        try:
            self._check_size("StreamLevels", raw, SMALL_REQUEST_BYTES, "a request without levels")
            req = _parse(pb.StreamLevelsRequest, raw)
            if not 1 <= req.batch_size <= self.config.max_batch_size:
                raise (LimitExceededError if req.batch_size > 0 else InvalidRequestError)(
                    f"batch_size must lie in 1..{self.config.max_batch_size} (max_batch_size), got "
                    f"{req.batch_size}"
                )
            if req.count < 0 or req.start_index < 0:
                raise InvalidRequestError(
                    f"count (0 = until cancelled) and start_index must be >= 0, got count={req.count}, "
                    f"start_index={req.start_index}"
                )
            self.source.check_range(req.start_index, req.count or None)
            gen = config_from_proto(req.config, self.config.generator)
            if self.active_streams >= self.config.max_concurrent_streams:
                raise LimitExceededError(
                    f"the server is serving {self.active_streams} streams (max_concurrent_streams="
                    f"{self.config.max_concurrent_streams}); retry with backoff or share a stream"
                )
            self.active_streams += 1
            counted = True
            metrics.ACTIVE_STREAMS.inc()
            await self._run(self.source.check_config, gen)
            # an endless stream ends (OK) at the end of its sequence, after 2**41 levels at the default chunk
            end = req.start_index + req.count if req.count else self.source.sequence_length

            def job(i: int) -> pb.LevelBatch:
                n = min(req.batch_size, end - i)
                levels = self.source.with_replay(self.source.levels(req.seed, i, n, gen))
                return encode(levels, first_index=i)

            i = req.start_index
            pending = asyncio.ensure_future(self._run(job, i))
            first = True
            while pending is not None:
                msg = await pending
                i += msg.count
                pending = asyncio.ensure_future(self._run(job, i)) if i < end else None
                if first:
                    metrics.RPC_LATENCY.labels("StreamLevels").observe(time.perf_counter() - start_time)
                    first = False
                yield msg  # waits for the client under HTTP/2 flow control
                metrics.LEVELS_SENT.labels("StreamLevels").inc(msg.count)
        except (asyncio.CancelledError, GeneratorExit):
            code = "CANCELLED"
            raise
        except Exception as err:
            code = None
            await _abort("StreamLevels", context, *_status_of(err))
        finally:
            if pending is not None:
                pending.cancel()
            if counted:
                self.active_streams -= 1
                metrics.ACTIVE_STREAMS.dec()
            if code is not None:
                metrics.RPCS.labels("StreamLevels", code).inc()


def _generic_handler(servicer: LevelServicer) -> grpc.GenericRpcHandler:
    """Method handlers taking raw request bytes (parsed by the servicer) and serialising replies."""

    def unary(fn: Callable[..., Any]) -> grpc.RpcMethodHandler:
        return grpc.unary_unary_rpc_method_handler(fn, response_serializer=lambda m: m.SerializeToString())

    handlers = {
        "GetLevels": unary(servicer.get_levels),
        "GetHeldout": unary(servicer.get_heldout),
        "ValidateLevel": unary(servicer.validate_level),
        "ReportScores": unary(servicer.report_scores),
        "GetServerInfo": unary(servicer.get_server_info),
        "StreamLevels": grpc.unary_stream_rpc_method_handler(
            servicer.stream_levels, response_serializer=lambda m: m.SerializeToString()
        ),
    }
    return grpc.method_handlers_generic_handler(SERVICE_NAME, handlers)


class _TokenAuth(grpc.aio.ServerInterceptor):
    """Rejects calls without `authorization: Bearer <token>` with UNAUTHENTICATED (health is exempt)."""

    def __init__(self, token: str) -> None:
        self._expected = f"Bearer {token}".encode()

    async def intercept_service(
        self,
        continuation: Callable[[grpc.HandlerCallDetails], Awaitable[grpc.RpcMethodHandler]],
        details: grpc.HandlerCallDetails,
    ) -> grpc.RpcMethodHandler:
        handler = await continuation(details)
        method = details.method
        if method.startswith("/grpc.health.v1.Health/") or handler is None:
            return handler
        metadata = dict(details.invocation_metadata or ())
        got = str(metadata.get("authorization", "")).encode()
        if hmac.compare_digest(got, self._expected):
            return handler
        rpc = method.rsplit("/", 1)[-1]

        async def deny(_request: Any, context: grpc.aio.ServicerContext) -> None:
            await _abort(
                rpc,
                context,
                grpc.StatusCode.UNAUTHENTICATED,
                "missing or wrong bearer token: send metadata `authorization: Bearer <token>` "
                "(LevelClient(token=...), or the CEC_LEVEL_SERVER_TOKEN environment variable)",
            )

        if handler.response_streaming:
            return grpc.unary_stream_rpc_method_handler(deny)
        return grpc.unary_unary_rpc_method_handler(deny)


class LevelServer:
    """A running (or startable) gRPC level server. `await start()`, then `await stop()`."""

    def __init__(self, config: LevelServerConfig, source: LevelSource | None = None) -> None:
        self.config = config
        self.source = source or LevelSource(config)
        self.executor = ThreadPoolExecutor(config.workers, thread_name_prefix="level-gen")
        self.check_executor = ThreadPoolExecutor(
            config.max_concurrent_validations, thread_name_prefix="level-check"
        )
        self.servicer = LevelServicer(self.source, self.executor, self.check_executor)
        self.health = health_aio.HealthServicer()
        self.port = 0
        self._server: grpc.aio.Server | None = None

    @property
    def address(self) -> str:
        return f"{self.config.host}:{self.port}"

    async def start(self) -> int:
        """Compiles the generator, binds, and starts serving; returns the bound port."""
        c = self.config
        server = grpc.aio.server(
            interceptors=[_TokenAuth(c.token)] if c.token else None,
            maximum_concurrent_rpcs=c.max_concurrent_rpcs,
            options=[
                ("grpc.max_receive_message_length", c.max_message_bytes),
                ("grpc.max_send_message_length", 128 * 1024 * 1024),
                ("grpc.so_reuseport", 0),
            ],
        )
        server.add_generic_rpc_handlers([_generic_handler(self.servicer)])
        health_pb2_grpc.add_HealthServicer_to_server(self.health, server)
        reflection.enable_server_reflection((SERVICE_NAME, reflection.SERVICE_NAME, "grpc.health.v1.Health"),
                                            server)  # fmt: skip
        address = f"{c.host}:{c.port}"
        try:  # bound before the warm-up, so that a port in use is reported at once
            if c.tls:
                creds = grpc.ssl_server_credentials(
                    [(read_pem(c.tls_key, "tls_key"), read_pem(c.tls_cert, "tls_cert"))]
                )
                self.port = server.add_secure_port(address, creds)
            else:
                self.port = server.add_insecure_port(address)
        except RuntimeError:  # grpc's "Failed to bind"
            self.port = 0
        if self.port == 0:
            raise OSError(f"could not bind {address}; is the port in use? choose another with port=...")
        if (exposed := c.exposure_warning()) is not None:
            log.warning("insecure=true: %s", exposed)
        log.info("warming up: compiling the generator and computing the layout space")
        await asyncio.get_running_loop().run_in_executor(self.executor, self.source.warm_up)
        await server.start()
        self._server = server
        for name in ("", SERVICE_NAME):
            await self.health.set(name, health_pb2.HealthCheckResponse.SERVING)
        log.info(
            "level server listening on %s:%d (%s%s); API %s, default config %s, layout space %s",
            c.host, self.port, "TLS" if c.tls else "plaintext", ", token auth" if c.token else "",
            API_VERSION, c.generator, self.source.layout_space_size,
        )  # fmt: skip
        return self.port

    async def stop(self, grace: float | None = None) -> None:
        """Health goes NOT_SERVING, in-flight RPCs get `grace` seconds, then the server stops."""
        if self._server is None:
            return
        await self.health.enter_graceful_shutdown()
        await self._server.stop(self.config.grace_seconds if grace is None else grace)
        self._server = None
        self.executor.shutdown(wait=False, cancel_futures=True)
        self.check_executor.shutdown(wait=False, cancel_futures=True)
        log.info("level server stopped")

    async def wait_for_termination(self) -> None:
        if self._server is not None:
            await self._server.wait_for_termination()


class ThreadedLevelServer:
    """A `LevelServer` on its own event loop in a daemon thread: for embedding in a synchronous process
    (the single-machine stack, tests). `with ThreadedLevelServer(config) as s: LevelClient(s.address)`."""

    def __init__(self, config: LevelServerConfig, source: LevelSource | None = None) -> None:
        self.server = LevelServer(config, source)
        self._loop = asyncio.new_event_loop()
        self._thread = threading.Thread(target=self._loop.run_forever, name="level-server", daemon=True)
        self._thread.start()
        asyncio.run_coroutine_threadsafe(self.server.start(), self._loop).result()

    @property
    def address(self) -> str:
        return self.server.address

    @property
    def port(self) -> int:
        return self.server.port

    def stop(self, grace: float | None = 0.0) -> None:
        if self._thread.is_alive():
            asyncio.run_coroutine_threadsafe(self.server.stop(grace), self._loop).result()
            self._loop.call_soon_threadsafe(self._loop.stop)
            self._thread.join(timeout=10)

    def __enter__(self) -> ThreadedLevelServer:
        return self

    def __exit__(self, *exc: object) -> None:
        self.stop()
