"""The figures' shared parts: no two series of a figure share a colour, and heatmap scales include zero."""

from __future__ import annotations

import numpy as np
import pytest

from cec.evaluation.plotting import colour_range, distinct_colours


@pytest.mark.parametrize("n", [1, 3, 10, 11, 12, 20, 21, 40])
def test_every_series_gets_its_own_colour(n: int) -> None:
    colours = [tuple(np.round(np.asarray(c, float)[:3], 4)) for c in distinct_colours(n)]
    assert len(colours) == n and len(set(colours)) == n


def test_a_heatmap_scale_starts_at_zero_so_a_small_gap_stays_small() -> None:
    assert colour_range(np.array([[20.0, 21.0], [np.nan, 20.5]])) == (0.0, 21.0)
    assert colour_range(np.array([-0.4, 0.8])) == (-0.4, 0.8)
    assert colour_range(np.array([-0.4, -0.1])) == (-0.4, 0.0)
    assert colour_range(np.array([np.nan])) == (None, None)
