"""A line every few seconds while a person waits: `Heartbeat` (the start of `cec up`, the compile of
`cec play serve`), so that no wait of more than `every_s` seconds is silent; `Stamped`, a stream that says
when it was last written to."""

from __future__ import annotations

import threading
import time
from collections.abc import Callable
from types import TracebackType
from typing import Any, TextIO


class Heartbeat:
    """While inside, `say(line(seconds waited))` every `every_s` seconds, unless something else was said
    meanwhile (`touch()`, or `quiet_since()` returning the time of the last line printed), until `done()`
    (when given) is true."""

    def __init__(
        self,
        say: Callable[[str], None],
        line: Callable[[float], str],
        every_s: float = 8.0,
        quiet_since: Callable[[], float] | None = None,
        done: Callable[[], bool] | None = None,
    ) -> None:
        self.say = say
        self.line = line
        self.every_s = every_s
        self.quiet_since = quiet_since
        self.done = done
        self._last = self._start = time.monotonic()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="heartbeat", daemon=True)

    def touch(self) -> None:
        """Something was said now: the next heartbeat comes `every_s` seconds later."""
        self._last = time.monotonic()

    def _run(self) -> None:
        while not self._stop.wait(0.5):
            if self.done is not None and self.done():
                return
            now = time.monotonic()
            last = max(self._last, self.quiet_since() if self.quiet_since else 0.0)
            if now - last >= self.every_s:
                self.say(self.line(now - self._start))
                self._last = now

    def __enter__(self) -> Heartbeat:
        self._thread.start()
        return self

    def __exit__(
        self, kind: type[BaseException] | None, err: BaseException | None, tb: TracebackType | None
    ) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


class Stamped:
    """A text stream that remembers when it was last written to (the heartbeat stays quiet meanwhile)."""

    def __init__(self, out: TextIO) -> None:
        self.out = out
        self.last = time.monotonic()

    def write(self, text: str) -> int:
        self.last = time.monotonic()
        return self.out.write(text)

    def flush(self) -> None:
        self.out.flush()

    def say(self, text: str) -> None:
        print(text, file=self, flush=True)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.out, name)


__all__ = ["Heartbeat", "Stamped"]
