"""GracefulStop: first signal asks to stop (flag, event, callback), second aborts; handlers restored."""

from __future__ import annotations

import io
import os
import signal
import threading

import pytest

from cec.signals import GracefulStop


def _raise(sig: signal.Signals) -> None:
    os.kill(os.getpid(), sig)  # delivered to the main thread before os.kill returns


def test_first_signal_asks_second_aborts_and_handlers_come_back() -> None:
    before = signal.getsignal(signal.SIGINT)
    calls: list[str] = []
    out = io.StringIO()
    with GracefulStop("finishing the update", on_first=lambda: calls.append("first"), out=out) as stopping:
        assert not stopping.stop
        _raise(signal.SIGTERM)
        assert stopping.stop and stopping.event.is_set() and calls == ["first"]
        assert "SIGTERM: finishing the update (send it again to stop at once)" in out.getvalue()
        with pytest.raises(KeyboardInterrupt):
            _raise(signal.SIGINT)
        assert calls == ["first"]  # not called again
    assert signal.getsignal(signal.SIGINT) is before


def test_abort_status_exits_with_it() -> None:
    with GracefulStop("stopping", abort_status=130, out=io.StringIO()):
        _raise(signal.SIGINT)
        with pytest.raises(SystemExit) as exc:
            _raise(signal.SIGINT)
    assert exc.value.code == 130


def test_outside_the_main_thread_it_installs_nothing() -> None:
    before = signal.getsignal(signal.SIGTERM)
    seen: list[object] = []

    def work() -> None:
        with GracefulStop("x") as stopping:
            seen.append(signal.getsignal(signal.SIGTERM))
            seen.append(stopping.stop)

    thread = threading.Thread(target=work)
    thread.start()
    thread.join()
    assert seen == [before, False]
