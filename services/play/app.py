"""The web app of `cec play` (Starlette on uvicorn): the study pages, the game over a WebSocket, metrics.

Routes:

    GET  /                 the single page (static/index.html); it asks /api/state what to show
    GET  /static/...       its script and style
    POST /api/join         starts a participant: sets the session cookie (opaque, HttpOnly, SameSite=Strict);
                           429 or 503 with {"error", "limit"} beyond the study's `limits` (config.py)
    GET  /api/state        the participant's current stage (`{"stage": "welcome"}` without a session)
    POST /api/submit       a form of the current stage (consent, info, instructions, survey) -> next stage

When a store cannot record (Redis down, a full disk), `/api/join` and `/api/submit` answer 503 with
`{"error", "store"}` naming the store and `Retry-After`, and nothing changes for the participant; a retry is
recorded once (`services.play.recording`). A round whose events cannot be recorded ends with an `error`
message and close code 1013 (try again later); reloading plays it again.
    WS   /ws/round         the current round: start message, then steps (see below); past a cap of `limits`
                           (free-play rounds, reconnects, recorded bytes: `services.play.caps`) an `error`
                           with `capped` and the setting, and /api/state shows the `capped` page
    GET  /metrics          Prometheus exposition; GET /healthz: "ok"

WebSocket messages (JSON). Server -> browser: `start` (kitchen, seat, start state, in turn-based mode the six
next states), `frame` (t, state, reward, score, collision, done, in turn-based mode the next six states; in
real-time mode `ack`, the sequence number of the key it played), `error` (message; the action was not
played), `end` (the round is over; fetch /api/state). Browser -> server: turn-based `{"type": "act", "t": T,
"action": A, "rt_ms": R}` (T: steps played so far, so a repeated message is not played twice), real-time
`{"type": "key", "seq": S, "action": A, "rt_ms": R}` (the latest key before a tick is played at that tick).
A malformed message (not a JSON object, nested deeper than 16 levels, a number longer than 64 characters,
larger than 4 KB) gets an `error` reply and the round goes on; a binary frame closes the connection (1003).

Request bodies are JSON objects of at most 16 KB; a longer one is refused with 413 as soon as its 16,385th
byte arrives (a chunked body is not read further). Malformed input never ends in a 500 or a traceback.

The JAX work and the record writes run in worker threads, so one participant's step never blocks another's.
"""

from __future__ import annotations

import asyncio
import contextlib
import logging
import math
import time
from pathlib import Path
from typing import Any
from urllib.parse import urlsplit

from prometheus_client import CONTENT_TYPE_LATEST, generate_latest
from starlette.applications import Starlette
from starlette.requests import ClientDisconnect, Request
from starlette.responses import FileResponse, JSONResponse, PlainTextResponse, Response
from starlette.routing import Mount, Route, WebSocketRoute
from starlette.staticfiles import StaticFiles
from starlette.websockets import WebSocket, WebSocketDisconnect

from services.metrics import ComponentRegistry
from services.play import metrics
from services.play.game import STAY, Round
from services.play.limits import JSONInputError, brief, parse_json
from services.play.study import (
    CapReachedError,
    InputError,
    JoinRefusedError,
    Participant,
    Study,
    validate_action,
    validate_rt,
)
from services.store import StoreError

log = logging.getLogger("cec.play")

STATIC = Path(__file__).with_name("static")
COOKIE = "cec_play"
MAX_BODY_BYTES = 16_384
MAX_WS_MESSAGE_BYTES = 4_096


class BodyTooLargeError(InputError):
    """A request body longer than `MAX_BODY_BYTES` (answered 413)."""


class _ProtocolError(Exception):
    """The client does not speak the round's protocol: close its connection with `code` and `reason`."""

    def __init__(self, code: int, reason: str) -> None:
        super().__init__(reason)
        self.code = code
        self.reason = reason


def create_app(study: Study) -> Starlette:
    """The ASGI app serving `study`.

    Long because its handlers are closures over `study` (the routing table at its end lists them); each
    handler is a few lines.
    """

    async def index(request: Request) -> Response:
        return FileResponse(STATIC / "index.html", headers={"Cache-Control": "no-store"})

    def session(request: Request | WebSocket) -> Participant | None:
        return study.participant(request.cookies.get(COOKIE))

    async def read_json(request: Request) -> Any:
        if not _is_json(request):
            raise InputError("send the body as JSON (Content-Type: application/json)")
        too_large = BodyTooLargeError(f"request body larger than {MAX_BODY_BYTES} bytes")
        declared = request.headers.get("content-length")
        if declared is not None and not (declared.isascii() and declared.isdigit()):
            raise InputError(f"Content-Length {brief(declared)} is not a number of bytes")
        if declared is not None and int(declared) > MAX_BODY_BYTES:
            raise too_large
        body = bytearray()
        try:
            async for chunk in request.stream():  # a chunked body is read only up to the limit
                body += chunk
                if len(body) > MAX_BODY_BYTES:
                    raise too_large
        except ClientDisconnect:
            raise InputError("the client went away before the body arrived") from None
        try:
            return parse_json(bytes(body) or b"{}")
        except JSONInputError as err:
            raise InputError(f"the request body is not acceptable JSON: {err}") from None

    async def join(request: Request) -> Response:
        if not _is_json(request):  # a plain cross-site form cannot send JSON
            return JSONResponse({"error": "send the body as JSON (Content-Type: application/json)"}, 415)
        p = session(request)
        if p is not None:  # already joined in this browser: continue where they are
            return JSONResponse(study.view(p))
        address = request.client.host if request.client else ""
        try:
            token, joined = await asyncio.to_thread(study.join, address)
        except JoinRefusedError as refusal:
            wait = refusal.retry_after
            headers = {} if wait is None else {"Retry-After": str(math.ceil(wait))}
            return JSONResponse(
                {"error": str(refusal), "limit": refusal.limit}, 429 if refusal.rate else 503, headers
            )
        except (OSError, StoreError) as err:  # the records cannot be written: say so, admit nobody
            log.error("cannot record a new participant: %s", err)
            return _unavailable(err, "a new participant")
        response = JSONResponse(study.view(joined))
        response.set_cookie(
            COOKIE, token, httponly=True, samesite="strict", secure=request.url.scheme == "https", path="/"
        )
        return response

    async def state(request: Request) -> Response:
        p = session(request)
        if p is None:
            return JSONResponse({"stage": "welcome", "title": study.config.title})
        return JSONResponse(study.view(p))

    async def submit(request: Request) -> Response:
        p = session(request)
        if p is None:
            return JSONResponse({"error": "no session: start the study first"}, status_code=401)
        try:
            payload = await read_json(request)
            view = await asyncio.to_thread(study.submit, p, payload)
        except BodyTooLargeError as err:
            return JSONResponse({"error": str(err)}, status_code=413)
        except InputError as err:
            return JSONResponse({"error": str(err)}, status_code=400)
        except (OSError, StoreError) as err:  # nothing changed for the participant: they may retry
            log.error("participant %s: cannot record a form: %s", p.id, err)
            return _unavailable(err, "your answer")
        return JSONResponse(view)

    async def metrics_route(request: Request) -> Response:
        return Response(generate_latest(ComponentRegistry("play")), media_type=CONTENT_TYPE_LATEST)

    async def healthz(request: Request) -> Response:
        return PlainTextResponse("ok")

    async def round_ws(ws: WebSocket) -> None:
        origin = ws.headers.get("origin")
        if origin is not None and urlsplit(origin).netloc != ws.headers.get("host"):
            await ws.close(code=1008, reason="cross-origin connection refused")
            return
        p = session(ws)
        if p is None:
            await ws.close(code=1008, reason="no session: start the study first")
            return
        await ws.accept()
        try:
            rnd, start = await asyncio.to_thread(study.begin_round, p)
        except InputError as err:  # past a cap of `limits`: the page then shows why (/api/state)
            capped = {"capped": True, "limit": err.limit} if isinstance(err, CapReachedError) else {}
            await ws.send_json({"type": "error", "message": str(err), "fatal": True, **capped})
            await ws.close()
            return
        except (OSError, StoreError) as err:
            log.error("participant %s: cannot record the start of a round: %s", p.id, err)
            await _close_unrecorded(ws, err)
            return
        await ws.send_json(start)
        try:
            if start["mode"] == "turn_based":
                await _turn_based(ws, study, p, rnd)
            else:
                await _real_time(ws, study, p, rnd)
        except WebSocketDisconnect:
            pass
        except (OSError, StoreError) as err:  # a step not recorded: the round cannot go on
            log.error("participant %s: cannot record a step; the round ends: %s", p.id, err)
            await _close_unrecorded(ws, err)
            return
        except _ProtocolError as err:  # the client's fault: one line, no traceback
            log.warning("participant %s: round connection closed (%d): %s", p.id, err.code, err.reason)
            with contextlib.suppress(RuntimeError, WebSocketDisconnect):
                await ws.close(code=err.code, reason=err.reason)
        except Exception:  # the server's fault: the traceback, and a close frame for the browser
            log.exception("participant %s: the round's connection failed", p.id)
            with contextlib.suppress(RuntimeError, WebSocketDisconnect):
                await ws.close(code=1011, reason="server error; reload the page to play the round again")
        finally:  # a round not ended (or whose end could not be recorded) is recorded as aborted
            try:
                await asyncio.to_thread(study.abort_round, p, rnd)
            except (OSError, StoreError) as err:  # recorded when the participant starts it again
                log.error("participant %s: cannot record the round's abort now: %s", p.id, err)
        if rnd.done:
            with contextlib.suppress(RuntimeError, WebSocketDisconnect):
                await ws.send_json({"type": "end", "return": rnd.team_return, "collisions": rnd.collisions})
                await ws.close()

    routes = [
        Route("/", index),
        Route("/api/join", join, methods=["POST"]),
        Route("/api/state", state),
        Route("/api/submit", submit, methods=["POST"]),
        Route("/metrics", metrics_route),
        Route("/healthz", healthz),
        WebSocketRoute("/ws/round", round_ws),
        Mount("/static", StaticFiles(directory=STATIC), name="static"),
    ]
    return Starlette(routes=routes)


def _store_name(err: BaseException) -> str:
    return str(getattr(err, "store", "the study's records"))


def _unavailable(err: BaseException, what: str) -> JSONResponse:
    """503 for an action whose events a store cannot record (the cause named; no detail of the store)."""
    store = _store_name(err)
    return JSONResponse(
        {
            "error": f"the server cannot record {what} now ({store} is unavailable); nothing was changed: "
            "please try again in a minute",
            "store": store,
        },
        503,
        {"Retry-After": "30"},
    )


async def _close_unrecorded(ws: WebSocket, err: BaseException) -> None:
    """Tells the browser that the round cannot be recorded now and closes with 1013 (try again later)."""
    message = (
        f"the server cannot record the game now ({_store_name(err)} is unavailable); reload the page in a "
        "minute to play the round again"
    )
    with contextlib.suppress(RuntimeError, WebSocketDisconnect):
        await ws.send_json({"type": "error", "message": message, "fatal": True})
        await ws.close(code=1013, reason="records unavailable; try again later")


def _is_json(request: Request) -> bool:
    return request.headers.get("content-type", "").split(";")[0].strip() == "application/json"


def _frame(result: Any, rnd: Round, ack: int | None = None) -> dict[str, Any]:
    msg: dict[str, Any] = {
        "type": "frame",
        "t": result.t,
        "state": result.state,
        "reward": result.reward,
        "score": rnd.team_return,
        "collision": result.collision,
        "done": result.done,
    }
    if result.branches is not None:
        msg["branches"] = result.branches
    if ack is not None:
        msg["ack"] = ack
    return msg


async def _receive(ws: WebSocket) -> dict[str, Any] | None:
    """The next JSON object from the browser; None (after an error reply) for a malformed message.
    `_ProtocolError` for a binary frame, `WebSocketDisconnect` when the browser went away."""
    message = await ws.receive()
    if message["type"] == "websocket.disconnect":
        raise WebSocketDisconnect(message.get("code", 1000), message.get("reason"))
    text = message.get("text")
    if text is None:
        raise _ProtocolError(1003, "binary frames are not accepted; send JSON text")
    if len(text) > MAX_WS_MESSAGE_BYTES:
        await ws.send_json({"type": "error", "message": f"message larger than {MAX_WS_MESSAGE_BYTES} bytes"})
        return None
    try:
        msg = parse_json(text)
    except JSONInputError as err:
        await ws.send_json({"type": "error", "message": f"messages must be JSON objects: {err}"})
        return None
    if not isinstance(msg, dict):
        await ws.send_json({"type": "error", "message": "messages must be JSON objects"})
        return None
    return msg


async def _turn_based(ws: WebSocket, study: Study, p: Participant, rnd: Round) -> None:
    while not rnd.done:
        msg = await _receive(ws)
        if msg is None:
            continue
        if msg.get("type") != "act":
            await ws.send_json(
                {"type": "error", "message": "turn-based rounds take {type: act, t, action, rt_ms}"}
            )
            continue
        if msg.get("t") != rnd.t:
            await ws.send_json(
                {"type": "error", "message": f"stale action for step {brief(msg.get('t'))}; now {rnd.t}"}
            )
            continue
        try:
            result = await asyncio.to_thread(study.step, p, rnd, msg.get("action"), msg.get("rt_ms"))
        except InputError as err:
            replaced = p.round is not rnd  # restarted from another tab or connection
            await ws.send_json({"type": "error", "message": str(err), "fatal": replaced})
            if replaced:
                return
            continue
        await ws.send_json(_frame(result, rnd))


async def _real_time(ws: WebSocket, study: Study, p: Participant, rnd: Round) -> None:
    pending: dict[str, Any] = {}  # the latest valid key since the last tick: action, rt_ms, seq

    async def receive_keys() -> None:
        while True:
            msg = await _receive(ws)
            if msg is None:
                continue
            try:
                if msg.get("type") != "key":
                    raise InputError("real-time rounds take {type: key, seq, action, rt_ms}")
                seq = msg.get("seq")
                if isinstance(seq, bool) or not isinstance(seq, int):
                    raise InputError("seq must be an integer")
                pending.update(
                    action=validate_action(msg.get("action")), rt_ms=validate_rt(msg.get("rt_ms")), seq=seq
                )
            except InputError as err:
                await ws.send_json({"type": "error", "message": str(err)})

    receiver = asyncio.create_task(receive_keys())
    period = 1.0 / study.config.ticks_per_second
    next_tick = time.monotonic() + period
    try:
        while not rnd.done:
            if receiver.done():  # the browser went away, or sent what closes the connection
                receiver.result()
                return
            delay = next_tick - time.monotonic()
            if delay > 0:
                done, _ = await asyncio.wait({receiver}, timeout=delay)
                if done:  # the browser went away (or sent garbage that broke the socket)
                    receiver.result()
                    return
            else:
                metrics.TICK_OVERRUNS.inc()
                next_tick = time.monotonic()
            next_tick += period
            key = dict(pending)
            pending.clear()
            action = key.get("action", STAY)
            try:
                result = await asyncio.to_thread(study.step, p, rnd, action, key.get("rt_ms"))
            except InputError as err:  # the round was restarted from another connection
                await ws.send_json({"type": "error", "message": str(err), "fatal": True})
                return
            await ws.send_json(_frame(result, rnd, ack=key.get("seq")))
    finally:
        receiver.cancel()
        with contextlib.suppress(asyncio.CancelledError, WebSocketDisconnect, RuntimeError):
            await receiver


__all__ = ["COOKIE", "create_app"]
