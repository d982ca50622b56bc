"""The machine a command ran on, for results that name it (benchmarks, `cec reproduce` reports)."""

from __future__ import annotations

import os
import platform
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
