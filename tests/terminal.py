"""A command run in a pseudo-terminal as a person runs it, Ctrl-C typed (the pty tests of `cec up` and
`make up`)."""

from __future__ import annotations

import os
import pty
import subprocess
import threading
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


class Terminal:
    """A command run as a newcomer runs it: in a pseudo-terminal that is its controlling terminal, in the
    terminal's foreground process group (`setsid --ctty`), its output drained to a log file. `ctrl_c()`
    types ^C: the terminal sends SIGINT to the whole foreground group, as a real one does."""

    def __init__(self, cmd: list[str], log: Path, cwd: Path = REPO) -> None:
        self.master, slave = pty.openpty()
        self.log = log
        self.proc = subprocess.Popen(
            ["setsid", "--ctty", *cmd], stdin=slave, stdout=slave, stderr=slave, cwd=cwd, close_fds=True
        )
        os.close(slave)
        self._pump = threading.Thread(target=self._drain, daemon=True)
        self._pump.start()

    def _drain(self) -> None:
        with self.log.open("ab") as out:
            while True:
                try:
                    data = os.read(self.master, 65536)
                except OSError:
                    return  # the terminal closed
                if not data:
                    return
                out.write(data)
                out.flush()

    def ctrl_c(self) -> None:
        os.write(self.master, b"\x03")

    def close(self) -> None:
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait()
        os.close(self.master)
        self._pump.join(timeout=5)
