"""`make up`'s command: `cec up ARGS`, in the terminal's foreground from its first line.

    CEC_UP_VIA=make python -m apps.make_up [cec up's options and KEY=VALUE overrides]

Under make, `cec up` starts in make's process group, the one the terminal sends Ctrl-C to, so a Ctrl-C
reaches make and its shell as well, and make then ends with `make: *** [up] Interrupt` (status 130) however
cleanly `cec up` stops. `cec up` takes the terminal for a process group of its own
(`services.terminal.foreground_group`), but only once its modules are imported: seconds of JAX and Ray,
more on a busy machine, in which a Ctrl-C reached make (and in `cec up` itself could be swallowed by JAX's
garbage-collector callback, so that it trained on and make said "Interrupt" only when it ended).

This module imports nothing heavy before it has the terminal: it moves into a process group of its own, makes
it the terminal's foreground one, holds a Ctrl-C that comes while `cec up` is being imported (and then stops
with status 130, nothing started, which the Makefile counts as success), runs `cec up`, and gives the
terminal back to make's group as it ends. Without a terminal, or as the leader of its group already, it
runs `cec up` as it is.
"""

from __future__ import annotations

import signal
import sys

from services.terminal import foreground_group

STOPPED = 130  # `cec up`'s status after a clean Ctrl-C, which `make up` counts as success


def main(argv: list[str] | None = None) -> int:
    args = sys.argv[1:] if argv is None else argv
    with foreground_group():
        held: list[int] = []
        default = signal.signal(signal.SIGINT, lambda signum, frame: held.append(signum))
        try:
            from apps.cli import main as cec
        finally:
            signal.signal(signal.SIGINT, default)
        if held:
            print("cec up: stopped by Ctrl-C while it was loading; nothing was started", file=sys.stderr)
            return STOPPED
        try:
            return cec(["up", *args])
        except KeyboardInterrupt:  # where `cec up` does not handle it itself (reading its config)
            print("cec up: stopped by Ctrl-C", file=sys.stderr)
            return STOPPED


if __name__ == "__main__":
    raise SystemExit(main())
