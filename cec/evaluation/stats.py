"""Statistics for comparing algorithms: standard errors, Welch t-tests, bootstrap intervals, IQM.

The t-test is scipy's (two-sided Welch test, as the paper reports two-sided t-tests); the bootstrap is a
vectorised percentile bootstrap of the difference of means (each group resampled on its own).

The unit of a sample is the caller's choice, and it must be an independent draw. Comparing algorithms'
cross-play, that is a training seed, not a pair of seeds: the pairs (i, j) and (i, k) share seed i, so
testing over pairs as if independent counts each seed several times and grants significance that the
seeds do not carry. `seed_means` turns one algorithm's seed x seed matrix into one number per seed (its
mean with the other seeds), for display. Those numbers are not independent either: seed i's mean and seed
k's both contain the pair (i, k), so a standard error or a t-test over them understates the uncertainty
(about 3x for 4 seeds). `crossplay_estimate` gives an algorithm's cross-play with a leave-one-seed-out
jackknife standard error, which counts the shared pairs, and `compare_crossplay` tests two algorithms
with it; every report's cross-play uncertainty and test comes from these two. `compare_crossplay_paired`
compares the same seeds at two points of their training (seed i of A is seed i of B trained on): the
jackknife of the difference matrix, so that what the seeds share at both points cancels.

Beside each t-test over a handful of seeds, an exact test whose p cannot fall below what the seed count
allows: `permutation_crossplay` (two algorithms' cross-play, relabelling the seeds of a pooled round robin;
at 4 + 4 seeds no p below 2/70), `permutation_two_sample` (independent per-seed scores, e.g. with the human
proxies; the same floor) and `sign_flip` / `sign_flip_crossplay_paired` (the same seeds at two points; at 4
seeds no p below 2/16 = 0.125). `holm` adjusts a family of them.
"""

from __future__ import annotations

import itertools
import math
from typing import NamedTuple

import numpy as np
from scipy import stats as sps


class Comparison(NamedTuple):
    """Algorithm A against algorithm B on one score.

    Attributes:
        mean_a, mean_b: sample means; n_a, n_b: sample sizes.
        diff: mean_a - mean_b.
        ci_low, ci_high: percentile bootstrap confidence interval of `diff`.
        t, df, p: Welch's t statistic, its degrees of freedom, the two-sided p-value (NaN when a group
            has fewer than 2 samples or both have zero variance).
    """

    mean_a: float
    mean_b: float
    n_a: int
    n_b: int
    diff: float
    ci_low: float
    ci_high: float
    t: float
    df: float
    p: float


def sem(x: np.ndarray) -> float:
    """Standard error of the mean (ddof 1); NaN for fewer than 2 samples."""
    x = np.asarray(x, np.float64)
    if x.size < 2:
        return math.nan
    return float(np.std(x, ddof=1) / math.sqrt(x.size))


def iqm(x: np.ndarray) -> float:
    """Interquartile mean (25% trimmed from each end), as ZSC-Eval aggregates BR-Prox; NaN if empty."""
    x = np.asarray(x, np.float64)
    return float(sps.trim_mean(x, 0.25)) if x.size else math.nan


def seed_means(matrix: np.ndarray) -> np.ndarray:
    """Each seed's mean score with the *other* seeds of one algorithm's seed x seed matrix (`[i, j]`: seed
    i with seed j; the diagonal, self-play, and NaN entries left out; NaN for a seed without a partner):
    the per-seed cross-play to compare algorithms with."""
    m = np.array(matrix, np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise ValueError(f"expected a square seed x seed matrix, got shape {m.shape}")
    np.fill_diagonal(m, np.nan)
    count = np.sum(~np.isnan(m), axis=1)
    total = np.nansum(m, axis=1)
    with np.errstate(invalid="ignore", divide="ignore"):
        return np.where(count > 0, total / count, np.nan)


def welch_ttest(a: np.ndarray, b: np.ndarray) -> tuple[float, float, float]:
    """(t, df, two-sided p) of Welch's unequal-variance t-test of mean(a) = mean(b)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.size < 2 or b.size < 2:
        return math.nan, math.nan, math.nan
    va, vb = a.var(ddof=1) / a.size, b.var(ddof=1) / b.size
    if va + vb == 0:
        return math.nan, math.nan, math.nan
    res = sps.ttest_ind(a, b, equal_var=False)
    df = (va + vb) ** 2 / (va**2 / (a.size - 1) + vb**2 / (b.size - 1))
    return float(res.statistic), float(df), float(res.pvalue)


def bootstrap_diff_ci(
    a: np.ndarray,
    b: np.ndarray,
    *,
    confidence: float = 0.95,
    n_resamples: int = 10_000,
    seed: int = 0,
) -> tuple[float, float]:
    """Percentile bootstrap interval of mean(a) - mean(b), resampling each group with replacement (NaN
    when a group has fewer than 2 samples)."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if a.size < 2 or b.size < 2:  # one sample says nothing about its group's spread
        return math.nan, math.nan
    rng = np.random.default_rng(seed)
    ma = a[rng.integers(0, a.size, (n_resamples, a.size))].mean(axis=1)
    mb = b[rng.integers(0, b.size, (n_resamples, b.size))].mean(axis=1)
    tail = (1.0 - confidence) / 2
    low, high = np.quantile(ma - mb, [tail, 1.0 - tail])
    return float(low), float(high)


def compare(a: np.ndarray, b: np.ndarray, *, confidence: float = 0.95, seed: int = 0) -> Comparison:
    """Welch t-test and bootstrap interval of the difference of means of two groups of samples."""
    a, b = np.asarray(a, np.float64), np.asarray(b, np.float64)
    t, df, p = welch_ttest(a, b)
    low, high = bootstrap_diff_ci(a, b, confidence=confidence, seed=seed)
    mean_a = float(a.mean()) if a.size else math.nan
    mean_b = float(b.mean()) if b.size else math.nan
    return Comparison(mean_a, mean_b, int(a.size), int(b.size), mean_a - mean_b, low, high, t, df, p)


class CrossPlay(NamedTuple):
    """An algorithm's cross-play from its seed x seed matrix.

    Attributes:
        mean: the mean over every off-diagonal (seed i with seed j != i) entry.
        se: leave-one-seed-out jackknife standard error of `mean` (NaN with fewer than 3 seeds: leaving one
            of two seeds out leaves no pair).
        seeds: seeds with at least one partner (the jackknife's units; `df` = seeds - 1).
    """

    mean: float
    se: float
    seeds: int

    @property
    def df(self) -> int:
        return self.seeds - 1


def _off_diagonal_mean(m: np.ndarray) -> float:
    cells = m[~np.eye(m.shape[0], dtype=bool)]
    cells = cells[~np.isnan(cells)]
    return float(cells.mean()) if cells.size else math.nan


def crossplay_estimate(matrix: np.ndarray) -> CrossPlay:
    """Cross-play mean and its jackknife standard error over seeds (the units): the estimate is recomputed
    with each seed's row and column removed, and SE^2 = (n - 1) / n * sum((theta_-i - theta_.)^2). Seeds
    without any partner entry are dropped first."""
    m = np.array(matrix, np.float64)
    if m.ndim != 2 or m.shape[0] != m.shape[1]:
        raise ValueError(f"expected a square seed x seed matrix, got shape {m.shape}")
    np.fill_diagonal(m, np.nan)
    keep = np.flatnonzero(~np.all(np.isnan(m), axis=1) | ~np.all(np.isnan(m), axis=0))
    m = m[np.ix_(keep, keep)]
    n = m.shape[0]
    mean = _off_diagonal_mean(m) if n else math.nan
    if n < 3:
        return CrossPlay(mean, math.nan, n)
    loo = np.array([_off_diagonal_mean(np.delete(np.delete(m, i, 0), i, 1)) for i in range(n)])
    return CrossPlay(mean, jackknife_se(loo[~np.isnan(loo)]), n)


def jackknife_se(leave_one_out: np.ndarray) -> float:
    """The jackknife standard error of an estimate from its leave-one-unit-out values:
    SE^2 = (n - 1) / n * sum((theta_-i - theta_.)^2); NaN with fewer than 2."""
    loo = np.asarray(leave_one_out, np.float64)
    n = loo.size
    return float(np.sqrt((n - 1) / n * np.sum((loo - loo.mean()) ** 2))) if n > 1 else math.nan


def compare_estimates(a: CrossPlay, b: CrossPlay, *, confidence: float = 0.95) -> Comparison:
    """Two independent cross-play estimates (each a mean with its jackknife standard error over its own
    seeds): the difference, a t-test with Welch-Satterthwaite degrees of freedom from each side's seeds - 1,
    and the matching t interval. Same fields as `compare` (n_a, n_b are seeds). What `compare_crossplay`
    computes from two seed matrices, also for estimates recorded earlier (a time-to-skill row)."""
    diff = a.mean - b.mean
    var = a.se**2 + b.se**2
    if not np.isfinite(var) or var == 0:
        return Comparison(a.mean, b.mean, a.seeds, b.seeds, diff, *[math.nan] * 5)
    df = var**2 / (a.se**4 / a.df + b.se**4 / b.df)
    t = diff / math.sqrt(var)
    p = float(2 * sps.t.sf(abs(t), df))
    half = float(sps.t.ppf(0.5 + confidence / 2, df)) * math.sqrt(var)
    return Comparison(a.mean, b.mean, a.seeds, b.seeds, diff, diff - half, diff + half, t, df, p)


def compare_crossplay(a: np.ndarray, b: np.ndarray, *, confidence: float = 0.95) -> Comparison:
    """Algorithm A's cross-play against B's, each from its seed x seed matrix (`compare_estimates` of their
    `crossplay_estimate`s)."""
    return compare_estimates(crossplay_estimate(a), crossplay_estimate(b), confidence=confidence)


def compare_crossplay_paired(a: np.ndarray, b: np.ndarray, *, confidence: float = 0.95) -> Comparison:
    """The same seeds' cross-play at two points (`a[i, j]` and `b[i, j]`: seed i with seed j, rows in the
    same seed order, e.g. after and before more training): the mean of the difference matrix `a - b` with
    its leave-one-seed-out jackknife standard error (`crossplay_estimate`), a t-test with seeds - 1 degrees
    of freedom and the matching t interval. Pairing removes what a seed brings to both points, so this is
    usually tighter than `compare_crossplay`, which treats A's and B's seeds as independent."""
    ma, mb = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if ma.shape != mb.shape:
        raise ValueError(f"the two seed x seed matrices differ in shape: {ma.shape} and {mb.shape}")
    ea, eb, d = crossplay_estimate(ma), crossplay_estimate(mb), crossplay_estimate(ma - mb)
    if not np.isfinite(d.se) or d.se == 0:
        return Comparison(ea.mean, eb.mean, d.seeds, d.seeds, d.mean, *[math.nan] * 5)
    t = d.mean / d.se
    p = float(2 * sps.t.sf(abs(t), d.df))
    half = float(sps.t.ppf(0.5 + confidence / 2, d.df)) * d.se
    return Comparison(ea.mean, eb.mean, d.seeds, d.seeds, d.mean, d.mean - half, d.mean + half, t, d.df, p)


class Permutation(NamedTuple):
    """An exact permutation test of two algorithms' cross-play over their seeds.

    Attributes:
        diff: A's cross-play minus B's (each the mean over its pairs of two different seeds).
        p: two-sided p-value: the share of the seed relabellings whose |diff| reaches the observed one.
        p_min: the smallest p any outcome could give with these seed counts (2 / C(n_a + n_b, n_a) when A
            and B have as many seeds, 1 / C(...) otherwise): with 4 seeds each it is 0.029, so a p below
            it cannot be claimed whatever a t-test says.
        relabellings: how many splits were enumerated.
    """

    diff: float
    p: float
    p_min: float
    relabellings: int


def permutation_crossplay(pooled: np.ndarray, n_a: int, max_relabellings: int = 20_000) -> Permutation:
    """Exact permutation test of cross-play over seeds, valid at any seed count: `pooled` is the seed x seed
    matrix of A's `n_a` seeds followed by B's (every seed played every other, across the algorithms too,
    as a round robin does). Under the null the algorithm labels are exchangeable among seeds, so every split
    of the pooled seeds into n_a and n_b is as likely; the statistic is the difference of the two groups'
    within-group cross-play. Every split is enumerated (at most `max_relabellings`: 8 + 8 seeds is 12,870)."""
    m = np.array(pooled, np.float64)
    n = m.shape[0]
    if m.ndim != 2 or m.shape[1] != n or not 2 <= n_a <= n - 2:
        raise ValueError(f"need a square pooled matrix with >= 2 seeds per algorithm; got {m.shape}, {n_a=}")
    splits = math.comb(n, n_a)
    if splits > max_relabellings:
        raise ValueError(f"{splits} relabellings exceed max_relabellings={max_relabellings}; raise it")

    def stat(group: tuple[int, ...]) -> float:
        rest = [i for i in range(n) if i not in group]
        return _off_diagonal_mean(m[np.ix_(group, group)]) - _off_diagonal_mean(m[np.ix_(rest, rest)])

    observed = stat(tuple(range(n_a)))
    values = np.array([stat(g) for g in itertools.combinations(range(n), n_a)])
    p = float(np.mean(np.abs(values) >= abs(observed) - 1e-12))
    p_min = (2 if 2 * n_a == n else 1) / splits
    return Permutation(observed, p, p_min, splits)


def holm(p_values: list[float] | np.ndarray) -> np.ndarray:
    """Holm-Bonferroni adjusted p-values of one family of tests (NaN stays NaN and does not count): reject
    the k-th smallest when its adjusted value is below alpha; controls the family-wise error rate."""
    p = np.asarray(p_values, np.float64)
    out = np.full(p.shape, np.nan)
    idx = np.flatnonzero(~np.isnan(p))
    order = idx[np.argsort(p[idx], kind="stable")]
    running, m = 0.0, len(order)
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        out[i] = running
    return out


class SignFlip(NamedTuple):
    """An exact sign-flip test of a mean against 0 over independent units (seeds).

    Attributes:
        mean: the units' mean.
        p: two-sided p-value: the share of the 2^n sign assignments whose |mean| reaches the observed one.
        p_min: the smallest p any outcome could give with these units (2 / 2^n; with 4 seeds 0.125, so a p
            below it cannot be claimed whatever a t-test over the same seeds says).
        flips: how many sign assignments were enumerated (2^n).
        units: n, the units with a finite value.
    """

    mean: float
    p: float
    p_min: float
    flips: int
    units: int


def sign_flip(values: np.ndarray, max_units: int = 20) -> SignFlip:
    """Exact sign-flip (randomisation) test of mean(values) = 0: under the null each unit's value is as
    likely to be x as -x, independently of the others, so every assignment of signs to the units is as
    likely; all 2^n are enumerated (NaN units dropped; at most `max_units`). The statistic is |mean|. What a
    paired comparison over seeds can claim with few seeds: with n seeds no p is below 2 / 2^n."""
    x = np.asarray(values, np.float64)
    x = x[~np.isnan(x)]
    n = x.size
    if n == 0:
        return SignFlip(math.nan, math.nan, math.nan, 0, 0)
    if n > max_units:
        raise ValueError(f"2^{n} sign assignments exceed max_units={max_units}; raise it")
    signs = 1 - 2 * ((np.arange(2**n)[:, None] >> np.arange(n)) & 1)  # every +-1 vector, 2^n x n
    means = signs @ x / n
    observed = float(x.mean())
    p = float(np.mean(np.abs(means) >= abs(observed) - 1e-12))
    return SignFlip(observed, p, 2 / 2**n, 2**n, n)


def sign_flip_crossplay_paired(a: np.ndarray, b: np.ndarray) -> SignFlip:
    """The exact sign-flip test beside `compare_crossplay_paired` (the same seeds' cross-play at two points,
    `a[i, j]` and `b[i, j]` in the same seed order): each seed's unit is its mean with the other seeds in the
    difference matrix `a - b`, both seats (`seed_means` of the symmetrised difference; their mean is the
    difference of the two cross-play means when every pair played), and `sign_flip` over those units. The
    units share pairs (seed i's and seed k's both hold the pair (i, k)), which the flip treats as
    independent; what holds whatever that dependence is its floor: with n seeds no p below 2 / 2^n (0.125
    at 4 seeds), the bound a t-test at n - 1 degrees of freedom does not respect."""
    ma, mb = np.asarray(a, np.float64), np.asarray(b, np.float64)
    if ma.shape != mb.shape:
        raise ValueError(f"the two seed x seed matrices differ in shape: {ma.shape} and {mb.shape}")
    d = ma - mb
    return sign_flip(seed_means((d + d.T) / 2))


def permutation_two_sample(a: np.ndarray, b: np.ndarray, max_relabellings: int = 20_000) -> Permutation:
    """Exact two-sample permutation test of mean(a) = mean(b) over independent units (seeds of two
    algorithms each scored with the same fixed partners, e.g. the human proxies): under the null the labels
    are exchangeable, so every split of the pooled units into groups of the two sizes is as likely; all are
    enumerated (NaN units dropped). `Permutation.p_min`: 2 / C(n_a + n_b, n_a) for equal sizes (0.029 at 4
    and 4), 1 / C(...) otherwise. For cross-play, where the seeds partner each other, use
    `permutation_crossplay`."""
    x, y = (np.asarray(v, np.float64) for v in (a, b))
    x, y = x[~np.isnan(x)], y[~np.isnan(y)]
    n_a, n = x.size, x.size + y.size
    if n_a < 1 or y.size < 1:
        raise ValueError(f"need at least one unit per group; got {x.size} and {y.size}")
    splits = math.comb(n, n_a)
    if splits > max_relabellings:
        raise ValueError(f"{splits} relabellings exceed max_relabellings={max_relabellings}; raise it")
    pooled, total = np.concatenate([x, y]), float(np.concatenate([x, y]).sum())
    sums = np.array([pooled[list(g)].sum() for g in itertools.combinations(range(n), n_a)])
    diffs = sums / n_a - (total - sums) / y.size
    observed = float(x.mean() - y.mean())
    p = float(np.mean(np.abs(diffs) >= abs(observed) - 1e-12))
    p_min = (2 if 2 * n_a == n else 1) / splits
    return Permutation(observed, p, p_min, splits)
