"""Graceful stop on SIGINT/SIGTERM: the one way every long-running command handles them.

The first signal asks the work to stop at its next safe point (between compiled calls, after an update,
after a checkpoint is scored) and says so; the second aborts at once. Work polls `stop` (or waits on
`event`); `on_first` tells work running elsewhere (a Ray actor) to stop.

    with GracefulStop("finishing the current call, then saving a checkpoint") as stopping:
        while not stopping.stop:
            ...

Handlers are installed only from the main thread (elsewhere Python refuses them; the context then does
nothing) and the previous ones are restored on exit.
"""

from __future__ import annotations

import signal
import sys
import threading
from collections.abc import Callable
from types import FrameType
from typing import Any, TextIO

SIGNALS = (signal.SIGINT, signal.SIGTERM)


class GracefulStop:
    """First SIGINT/SIGTERM: set `event`, call `on_first`, print what happens next; second: abort.

    Args:
        what: what the first signal makes the work do (printed after the signal's name).
        on_first: called once, from the handler, on the first signal.
        abort_status: the second signal raises `SystemExit(abort_status)`; None: `KeyboardInterrupt`.
        out: where the messages go.
    """

    def __init__(
        self,
        what: str,
        *,
        on_first: Callable[[], None] | None = None,
        abort_status: int | None = None,
        out: TextIO | None = None,
    ) -> None:
        self.what = what
        self.on_first = on_first
        self.abort_status = abort_status
        self.out = out
        self.event = threading.Event()
        self._old: dict[int, Any] = {}

    @property
    def stop(self) -> bool:
        return self.event.is_set()

    def __enter__(self) -> GracefulStop:
        if threading.current_thread() is threading.main_thread():
            for sig in SIGNALS:
                self._old[sig] = signal.signal(sig, self._handle)
        return self

    def _handle(self, signum: int, frame: FrameType | None) -> None:
        name = signal.Signals(signum).name
        out = self.out or sys.stderr
        if self.event.is_set():
            print(f"{name} again: stopping now", file=out, flush=True)
            if self.abort_status is not None:
                raise SystemExit(self.abort_status)
            raise KeyboardInterrupt
        self.event.set()
        print(f"\n{name}: {self.what} (send it again to stop at once)", file=out, flush=True)
        if self.on_first is not None:
            self.on_first()

    def __exit__(self, *exc: object) -> None:
        for sig, handler in self._old.items():
            signal.signal(sig, handler)
        self._old.clear()
