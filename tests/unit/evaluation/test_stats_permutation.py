"""The exact permutation test of cross-play over seeds and the Holm correction: what a report may claim at
four seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cec.evaluation.stats import holm, permutation_crossplay


def test_four_seeds_each_cannot_go_below_one_in_35_and_a_clear_split_reaches_it() -> None:
    m = np.full((8, 8), 1.0)
    m[:4, :4] = 10.0  # A's seeds score 10 together, B's 1, across the groups 1
    out = permutation_crossplay(m, 4)
    assert out.relabellings == 70 and out.diff == pytest.approx(9.0)
    assert out.p_min == pytest.approx(2 / 70) and out.p == pytest.approx(2 / 70)


def test_exchangeable_seeds_give_large_p_and_the_false_positive_rate_holds() -> None:
    rng = np.random.default_rng(0)
    rejected = 0
    for _ in range(200):
        x = rng.normal(size=(8, 8))
        m = (x + x.T) / 2  # a symmetric round robin with no difference between the algorithms
        rejected += permutation_crossplay(m, 4).p <= 0.05
    assert rejected / 200 <= 0.08  # nominal 5% (2/70 and 4/70 are the attainable levels near it)


def test_bad_shapes_are_refused() -> None:
    with pytest.raises(ValueError, match=">= 2 seeds per algorithm"):
        permutation_crossplay(np.ones((4, 4)), 1)
    with pytest.raises(ValueError, match="max_relabellings"):
        permutation_crossplay(np.ones((20, 20)), 10, max_relabellings=100)


def test_holm_adjusts_in_order_and_keeps_nan() -> None:
    adjusted = holm([0.01, 0.04, math.nan, 0.03, 0.2])
    assert adjusted[0] == pytest.approx(0.04)  # 4 tests: 4 x 0.01
    assert adjusted[3] == pytest.approx(0.09)  # 3 x 0.03
    assert adjusted[1] == pytest.approx(0.09)  # max(0.09, 2 x 0.04)
    assert adjusted[4] == pytest.approx(0.2) and math.isnan(adjusted[2])
