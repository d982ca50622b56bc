"""The machine and commit a command ran on, for results that name them (benchmarks, `cec reproduce`)."""

from __future__ import annotations

import os
import platform
from typing import Any, TextIO


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


def log_line(log: TextIO | None, who: str, msg: str) -> None:
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
