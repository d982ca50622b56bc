"""The machine and commit a command ran on, for results that name them (benchmarks, `cec reproduce`)."""

from __future__ import annotations

import os
import platform
import subprocess
from pathlib import Path
from typing import Any


def machine_info(load_average: bool = False) -> dict[str, Any]:
    """Host, CPU model, cores, JAX device, Python and JAX versions (and the load average if asked)."""
    import jax

    cpu = platform.processor() or ""
    try:
        with open("/proc/cpuinfo") as f:
            cpu = next((line.split(":", 1)[1].strip() for line in f if line.startswith("model name")), cpu)
    except OSError:
        pass
    dev = jax.devices()[0]
    info: dict[str, Any] = {
        "host": platform.node(),
        "cpu": cpu,
        "cpu_count": os.cpu_count(),
        "device": f"{dev.platform}:{getattr(dev, 'device_kind', '')}",
    }
    if load_average:
        try:
            info["load_average_1_5_15min"] = [round(x, 2) for x in os.getloadavg()]
        except OSError:
            info["load_average_1_5_15min"] = []
    info.update(python=platform.python_version(), jax=jax.__version__)
    return info


REPO = Path(__file__).resolve().parents[1]


def git_rev(root: Path = REPO) -> str:
    """The checkout's short commit, marked when the working tree has uncommitted changes; in a copy without
    its `.git` (a lent GPU machine gets the tree alone), `$CEC_GIT_REV` as the sender set it, else unknown."""
    copied = os.environ.get("CEC_GIT_REV") or "unknown"
    try:
        out = subprocess.run(
            ["git", "rev-parse", "--short", "HEAD"], capture_output=True, text=True, cwd=root
        )
        if out.returncode != 0:
            return copied
        dirty = subprocess.run(["git", "status", "--porcelain"], capture_output=True, text=True, cwd=root)
        return (out.stdout.strip() or "unknown") + (" (uncommitted changes)" if dirty.stdout.strip() else "")
    except OSError:
        return copied


def log_line(log: Any, who: str, msg: str) -> None:
    """One timestamped progress line of a long command (`[who HH:MM:SS] msg`), flushed."""
    import time

    print(f"[{who} {time.strftime('%H:%M:%S')}] {msg}", file=log, flush=True)


def duration(s: float) -> str:
    """Seconds as minutes, hours or days; `?` when not known (NaN)."""
    if s != s:
        return "?"
    if s < 3600:
        return f"{s / 60:.0f} min"
    if s < 2 * 86400:
        return f"{s / 3600:.1f} h"
    return f"{s / 86400:.1f} days"
