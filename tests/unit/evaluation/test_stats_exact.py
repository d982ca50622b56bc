"""The exact tests beside the t-tests over a handful of seeds: the sign-flip test of a paired difference and
the two-sample relabelling test of per-seed scores, and the floors they put on a p at four seeds."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cec.evaluation.stats import (
    compare_crossplay_paired,
    permutation_two_sample,
    sign_flip,
    sign_flip_crossplay_paired,
)


def test_four_units_of_one_sign_reach_the_floor_of_one_in_eight() -> None:
    out = sign_flip([1.0, 2.0, 3.0, 4.0])
    assert out.flips == 16 and out.units == 4 and out.mean == pytest.approx(2.5)
    assert out.p_min == pytest.approx(0.125) and out.p == pytest.approx(0.125)


def test_a_mixed_sign_counts_every_assignment_as_large() -> None:
    # means of the 16 assignments of +-(1, 2, 3, -4)/4: |mean| >= 0.5 in 12 of them
    out = sign_flip([1.0, 2.0, 3.0, -4.0])
    values = [abs(sum(s * x for s, x in zip(signs, (1, 2, 3, -4), strict=True))) / 4
              for signs in np.array(np.meshgrid(*[[1, -1]] * 4)).T.reshape(-1, 4)]  # fmt: skip
    assert out.p == pytest.approx(np.mean(np.array(values) >= 0.5))
    assert sign_flip([math.nan, 1.0, 1.0]).units == 2


def test_the_paired_cross_play_flip_cannot_confirm_what_a_t_test_at_3_df_calls_significant() -> None:
    rng = np.random.default_rng(3)
    before = rng.normal(30, 5, (4, 4))
    after = before + 14 + rng.normal(0, 6, (4, 4))  # a gain every pair shares, with noise
    t = compare_crossplay_paired(after, before)
    flip = sign_flip_crossplay_paired(after, before)
    assert flip.mean == pytest.approx(t.diff)  # the units average to the same difference
    assert flip.p >= 0.125 and flip.p_min == pytest.approx(0.125)
    with pytest.raises(ValueError, match="differ in shape"):
        sign_flip_crossplay_paired(after, before[:3, :3])


def test_two_samples_of_four_cannot_go_below_one_in_35() -> None:
    out = permutation_two_sample([10.0, 11.0, 12.0, 13.0], [1.0, 2.0, 3.0, 4.0])
    assert out.relabellings == 70 and out.diff == pytest.approx(9.0)
    assert out.p == pytest.approx(2 / 70) and out.p_min == pytest.approx(2 / 70)
    unequal = permutation_two_sample([10.0, 11.0, 12.0], [1.0, 2.0, 3.0, 4.0, math.nan])
    assert unequal.relabellings == 35 and unequal.p_min == pytest.approx(1 / 35)


def test_two_samples_from_one_distribution_keep_the_false_positive_rate() -> None:
    rng = np.random.default_rng(0)
    draws = (permutation_two_sample(rng.normal(size=5), rng.normal(size=5)) for _ in range(300))
    rejected = sum(d.p <= 0.05 for d in draws)
    assert rejected / 300 <= 0.08
    with pytest.raises(ValueError, match="at least one unit"):
        permutation_two_sample([], [1.0])
