"""The terminal's foreground process group for `cec up` (imports nothing heavy: `make up` enters it before
JAX or Ray are imported, `apps/make_up.py`).

A Ctrl-C in a terminal goes to its foreground process group. Under `make up`, `cec up` starts in make's
group, so a Ctrl-C would reach make and its shell too, and make would end with `make: *** [up] Interrupt`
however cleanly `cec up` stopped. `foreground_group` moves this process into a group of its own and makes it
the terminal's foreground one while inside, then gives the terminal back; without a terminal, or as the
leader of its group already (run from a shell), it changes nothing.
"""

from __future__ import annotations

import contextlib
import os
import signal
from collections.abc import Iterator


@contextlib.contextmanager
def foreground_group() -> Iterator[None]:
    """While inside, this process leads a process group of its own, the terminal's foreground one, when it
    shared the foreground group with its parent (make's); the terminal goes back to that group on exit."""
    try:
        tty = os.open("/dev/tty", os.O_RDWR | os.O_NOCTTY)
    except OSError:
        yield
        return
    try:
        shared = os.getpgrp()
        if os.tcgetpgrp(tty) != shared or shared == os.getpid():
            yield
            return
        quiet = signal.signal(signal.SIGTTOU, signal.SIG_IGN)  # a background group may then take the terminal
        try:
            os.setpgid(0, 0)
            os.tcsetpgrp(tty, os.getpgrp())
            yield
        finally:
            with contextlib.suppress(OSError):
                os.tcsetpgrp(tty, shared)  # back to make, before it reads our exit status
            signal.signal(signal.SIGTTOU, quiet)
    finally:
        os.close(tty)
