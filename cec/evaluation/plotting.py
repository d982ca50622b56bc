"""What every figure of the evaluation shares: pyplot on the file-only backend, a colour per series that no
other series of the figure has, and colour scales that start at zero when the values cannot go below it."""

from __future__ import annotations

from typing import Any

import numpy as np


def pyplot() -> Any:
    """matplotlib.pyplot on the non-interactive Agg backend (imported on first use)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    return plt


def distinct_colours(n: int) -> list[Any]:
    """`n` colours, all different: matplotlib's tab10 up to 10 series, tab20 up to 20, then evenly spaced
    hues (the default colour cycle repeats after 10, giving two legend entries one colour)."""
    import matplotlib

    if n <= 20:
        table = matplotlib.colormaps["tab10" if n <= 10 else "tab20"]
        return [table(i) for i in range(n)]
    return [matplotlib.colormaps["hsv"](i / n) for i in range(n)]


def colour_range(values: np.ndarray) -> tuple[float, float] | tuple[None, None]:
    """(vmin, vmax) for a heatmap of `values` (NaN ignored) that always includes 0, so that a small gap
    between large scores is not stretched over the whole scale; (None, None) when there is no value."""
    finite = values[np.isfinite(values)]
    if not finite.size:
        return None, None
    return min(float(finite.min()), 0.0), max(float(finite.max()), 0.0)
