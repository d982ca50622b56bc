"""`cec play serve` as a real process for the tests: started, its output pumped, its address read from
the line it prints once the port accepts connections."""

from __future__ import annotations

import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


class PlayServer:
    """`python -m apps.cli play serve ARGS` until `stop()`; `url` once it serves study `study` (None: any
    name, e.g. free play's folder of its flags), whose name is then `study`."""

    def __init__(self, args: list[str], study: str | None, timeout: float = 180) -> None:
        cmd = [sys.executable, "-m", "apps.cli", "play", "serve", *args]
        self.proc = subprocess.Popen(
            cmd, cwd=ROOT, env={**os.environ, "JAX_PLATFORMS": "cpu"}, stdout=subprocess.PIPE,
            stderr=subprocess.STDOUT, text=True,
        )  # fmt: skip
        self.lines: list[str] = []
        self.url = ""
        self.study = study or ""
        name = re.escape(study) if study else r"[A-Za-z0-9_-]+"
        ready = threading.Event()

        def pump() -> None:
            assert self.proc.stdout is not None
            for line in self.proc.stdout:
                self.lines.append(line)
                m = re.search(rf"serving study '({name})' at (http://\S+/)", line)
                if m:
                    self.study, self.url = m.group(1), m.group(2)
                    ready.set()
            ready.set()

        threading.Thread(target=pump, daemon=True).start()
        ready.wait(timeout=timeout)
        if not self.url:
            self.proc.kill()
            raise RuntimeError("the play server did not start:\n" + self.log)

    @property
    def log(self) -> str:
        return "".join(self.lines)

    def stop(self, sig: int | None = None, timeout: float = 30) -> int:
        """Sends `sig` (default SIGTERM) and returns the exit code (killed after `timeout`)."""
        if self.proc.poll() is None:
            self.proc.send_signal(sig) if sig is not None else self.proc.terminate()
            try:
                self.proc.wait(timeout=timeout)
            except subprocess.TimeoutExpired:  # where it hangs goes into the log (the CLI's SIGUSR1 dump)
                self.proc.send_signal(signal.SIGUSR1)
                time.sleep(2)
                self.proc.kill()
                self.proc.wait()
        return int(self.proc.returncode)
