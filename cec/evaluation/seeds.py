"""Seeds are the units: one algorithm's per-seed summary, from the pair scores of a result table.

    matrix = seed_matrix(table, ["generated_000", "generated_001"])   # pair scores of every policy
    cec = matrix.summary(matrix.indices("cec"))    # per seed XP and SP, the seed x seed matrix
    cec.crossplay()                                # XP with its jackknife standard error over seeds
    matrix.partner_means(idx, matrix.indices("cook"))   # per seed: its mean with a group of partners

`seed_summary` is the one per-seed summary of cross-play: each seed's mean with the other seeds of its
algorithm (`stats.seed_means`, for display), its self-play (the diagonal), and the algorithm's cross-play
with the leave-one-seed-out jackknife standard error (`stats.crossplay_estimate`, the uncertainty every
report shows and `stats.compare_crossplay` tests with). `partner_means` is each seed's mean with partners
outside its algorithm (a scripted partner, human proxies, an evaluator's partner zoo: the `per_seed` of
`services/evaluator`'s stored results is `partner_means` of the checkpoint's seeds x its partners).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from typing import NamedTuple

import numpy as np

from cec.evaluation.analysis import PolicyId, pair_level_scores, pair_scores
from cec.evaluation.results import EpisodeTable
from cec.evaluation.stats import CrossPlay, crossplay_estimate, seed_means


@dataclass(frozen=True)
class SeedSummary:
    """One algorithm's seeds with each other.

    Attributes:
        seeds: the seeds, in the matrix's order.
        xp: per seed, its mean score with the other seeds (NaN for a seed without a partner).
        sp: per seed, its score with itself (NaN where not played).
        matrix: the seed x seed matrix of pair scores (`[i][j]`: seed i with seed j; NaN: not played).
    """

    seeds: tuple[int, ...]
    xp: tuple[float, ...]
    sp: tuple[float, ...]
    matrix: tuple[tuple[float, ...], ...]

    def crossplay(self) -> CrossPlay:
        """The algorithm's cross-play with its jackknife standard error over seeds (a seed's pairs are
        shared with the other seeds, so a standard error over `xp` would understate it)."""
        return crossplay_estimate(np.asarray(self.matrix, np.float64).reshape(len(self.seeds), -1))


def seed_summary(matrix: np.ndarray, seeds: Sequence[int]) -> SeedSummary:
    """The `SeedSummary` of one algorithm's seed x seed `matrix` of pair scores (self-play on the
    diagonal) whose rows are `seeds`."""
    m = np.asarray(matrix, np.float64)
    if m.ndim != 2 or m.shape != (len(seeds), len(seeds)):
        raise ValueError(f"expected a {len(seeds)} x {len(seeds)} seed x seed matrix, got shape {m.shape}")
    return SeedSummary(
        tuple(int(s) for s in seeds),
        tuple(float(x) for x in seed_means(m)),
        tuple(float(x) for x in m.diagonal()),
        tuple(tuple(float(x) for x in row) for row in m),
    )


def partner_means(block: np.ndarray) -> np.ndarray:
    """Each row's (seed's) mean over its played entries of a seed x partner `block` (NaN entries left
    out; NaN for a seed that played none, or when there are no partners)."""
    rows = np.asarray(block, np.float64)
    means = [float(np.mean(r[~np.isnan(r)])) if np.any(~np.isnan(r)) else np.nan for r in rows]
    return np.asarray(means, np.float64)


class SeedMatrix(NamedTuple):
    """Pair scores of every policy of a result table (`analysis.pair_scores`: symmetric, NaN where a pair
    never played), the rows and columns in `policies`' order."""

    policies: tuple[PolicyId, ...]
    scores: np.ndarray

    def indices(self, algorithm: str) -> list[int]:
        """The rows of `algorithm`'s policies (its seeds), in order."""
        return [i for i, p in enumerate(self.policies) if p.algorithm == algorithm]

    def summary(self, rows: Sequence[int]) -> SeedSummary:
        """`seed_summary` of the policies at `rows` (the seeds of one algorithm, or a subset of them)."""
        idx = list(rows)
        return seed_summary(self.scores[np.ix_(idx, idx)], [self.policies[i].seed for i in idx])

    def partner_means(self, rows: Sequence[int], partners: Sequence[int]) -> np.ndarray:
        """Per policy at `rows`, its mean score with the policies at `partners` (`partner_means`)."""
        return partner_means(self.scores[np.ix_(list(rows), list(partners))])


def seed_matrix(
    table: EpisodeTable, levels: Sequence[str] | None = None, metric: str = "score"
) -> SeedMatrix:
    """The `SeedMatrix` of `table` on `levels` (None: all): per pair of policies, the mean over its levels
    of the mean `metric` over episodes and seat orders (`analysis.pair_level_scores`)."""
    pl = pair_level_scores(table, levels, metric)
    return SeedMatrix(pl.policies, pair_scores(pl))
