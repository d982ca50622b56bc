"""Cross-play uncertainty in a crossed design: seeds are the units, and a seed's cross-play shares its pairs
with the other seeds. The jackknife over seeds must keep a test's false-positive rate at its nominal level
where a t-test over per-seed means (which treats them as independent) does not."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cec.evaluation.stats import compare, compare_crossplay, crossplay_estimate, seed_means


def _crossed(rng: np.random.Generator, seeds: int, mean: float, noise: float) -> np.ndarray:
    """A seed x seed cross-play matrix with shared-pair structure: M[i, j] = mean + s_i + s_j + e_ij (each
    seed's skill enters every pair it plays in), s ~ N(0, 1), e ~ N(0, noise)."""
    skill = rng.normal(0.0, 1.0, seeds)
    return mean + skill[:, None] + skill[None, :] + rng.normal(0.0, noise, (seeds, seeds))


@pytest.mark.parametrize("seeds", [4, 6])
def test_the_jackknife_test_holds_its_false_positive_rate_where_the_per_seed_t_test_does_not(
    seeds: int,
) -> None:
    rng = np.random.default_rng(seeds)
    runs = 1500
    jackknife = per_seed = 0
    for _ in range(runs):  # the null: two algorithms with the same cross-play
        a, b = _crossed(rng, seeds, 10.0, 0.5), _crossed(rng, seeds, 10.0, 0.5)
        jackknife += compare_crossplay(a, b).p < 0.05
        per_seed += compare(seed_means(a), seed_means(b)).p < 0.05
    # nominal 5%: with 1,500 runs the binomial standard error is 0.6%
    assert 0.02 <= jackknife / runs <= 0.07, jackknife / runs
    assert per_seed / runs > 0.25, per_seed / runs  # the per-seed test grants 5x too many "differences"


def test_the_jackknife_still_finds_a_real_difference() -> None:
    rng = np.random.default_rng(7)
    found = sum(
        compare_crossplay(_crossed(rng, 6, 14.0, 0.5), _crossed(rng, 6, 10.0, 0.5)).p < 0.05
        for _ in range(200)
    )
    assert found / 200 > 0.8


def test_crossplay_estimate_is_the_off_diagonal_mean_with_a_leave_one_seed_out_error() -> None:
    m = np.array([[50.0, 1.0, 2.0, 3.0], [4.0, 60.0, 5.0, 6.0], [7.0, 8.0, 70.0, 9.0], [1.0, 2.0, 3.0, 80.0]])
    est = crossplay_estimate(m)
    off = m[~np.eye(4, dtype=bool)]
    assert est.mean == pytest.approx(off.mean()) and est.seeds == 4 and est.df == 3  # self-play left out
    loo = [np.delete(np.delete(m, i, 0), i, 1) for i in range(4)]
    loo_means = np.array([x[~np.eye(3, dtype=bool)].mean() for x in loo])
    expected = math.sqrt(3 / 4 * np.sum((loo_means - loo_means.mean()) ** 2))
    assert est.se == pytest.approx(expected)
    # ... and larger than the standard error over per-seed means, which ignores the shared pairs
    per_seed = seed_means(m)
    assert est.se > np.std(per_seed, ddof=1) / 2


def test_too_few_seeds_give_no_uncertainty_rather_than_a_false_one() -> None:
    two = crossplay_estimate(np.array([[9.0, 1.0], [2.0, 9.0]]))
    assert two.mean == pytest.approx(1.5) and math.isnan(two.se)
    c = compare_crossplay(np.array([[9.0, 1.0], [2.0, 9.0]]), np.array([[9.0, 5.0], [6.0, 9.0]]))
    assert math.isnan(c.p) and c.diff == pytest.approx(-4.0)
    with pytest.raises(ValueError, match="square"):
        crossplay_estimate(np.zeros((2, 3)))
