"""The numbers `cec reproduce overcooked` reports, seeds as units: per level set and algorithm each seed's
scores (`seed_scores`), and CEC against each baseline (`comparisons`: the jackknife or Welch t-test, an
exact permutation test over seeds beside each, Holm within each family).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from apps.reproduce.overcooked.modes import ALGORITHMS, COOK
from cec.agents.zoo import HUMAN_PROXY

if TYPE_CHECKING:
    from cec.evaluation.results import EpisodeTable
    from cec.evaluation.seeds import SeedMatrix
    from cec.evaluation.stats import CrossPlay

ALPHA = 0.05


@dataclass(frozen=True)
class SeedScores:
    """One algorithm on one level set: per seed, its mean team return per episode with the other seeds of
    its algorithm (`xp`), with itself (`sp`), with the scripted cook (`cook`) and with the human proxies
    (`human`: the mean over the proxies, each on its kitchen; NaN where none played); `xp`, `sp` and
    `xp_matrix` are its `cec.evaluation.seeds.SeedSummary`."""

    seeds: tuple[int, ...]
    xp: tuple[float, ...]
    sp: tuple[float, ...]
    cook: tuple[float, ...]
    human: tuple[float, ...] = ()
    xp_matrix: tuple[tuple[float, ...], ...] = ()

    def crossplay(self) -> CrossPlay:
        """The algorithm's cross-play with its jackknife standard error over seeds
        (`cec.evaluation.stats.CrossPlay`; a seed's pairs are shared with the other seeds)."""
        from cec.evaluation.seeds import SeedSummary

        return SeedSummary(self.seeds, self.xp, self.sp, self.xp_matrix).crossplay()


def seed_scores(table: EpisodeTable, level_names: Sequence[str]) -> dict[str, SeedScores]:
    """{algorithm: SeedScores} on `level_names` (the cook's own self-play under `cook`; the proxies are
    partners, not an algorithm of the summary)."""
    from cec.evaluation.seeds import seed_matrix

    sm = seed_matrix(table, level_names)
    cook, humans = sm.indices(COOK), sm.indices(HUMAN_PROXY)
    out = {}
    for algo in sorted({p.algorithm for p in sm.policies} - {HUMAN_PROXY}):
        idx = sm.indices(algo)
        s = sm.summary(idx)
        with_cook, with_humans = (tuple(float(x) for x in sm.partner_means(idx, p)) for p in (cook, humans))
        out[algo] = SeedScores(s.seeds, s.xp, s.sp, with_cook, with_humans, s.matrix)
    return out


def finite(values: Sequence[float]) -> np.ndarray:
    arr = np.asarray(values, np.float64)
    return arr[~np.isnan(arr)]


MEASURES = {"xp": "cross-play", "human": "with human proxies"}


def comparisons(
    summary: dict[str, dict[str, SeedScores]], matrices: dict[str, SeedMatrix] | None = None
) -> list[dict[str, Any]]:
    """CEC against each baseline, per level set: cross-play with the jackknife over seeds (seeds partner
    each other, so their per-seed XP are not independent; `compare_crossplay`), the score with the human
    proxies (the same partners for every seed) with a Welch t-test over seeds and a bootstrap interval.
    Beside each, an exact test over seeds (`p_exact`, its smallest attainable value `p_min`): for
    cross-play, with `matrices` ({level set: `cec.evaluation.seeds.SeedMatrix`} of the same table), the
    permutation test of CEC's and the baseline's pooled seed x seed matrix (NaN where two of their seeds
    never played, or without `matrices`); with the human proxies, the two-sample relabelling test of the
    per-seed scores (`permutation_two_sample`: the seeds are independent there). Every p is also
    Holm-adjusted within its family, one level set and one score (`p_holm`, `p_exact_holm`)."""
    from cec.evaluation.stats import compare, compare_crossplay, holm, permutation_two_sample

    out = []
    for level_set, scores in summary.items():
        if "cec" not in scores:
            continue
        for measure in MEASURES:
            family: list[dict[str, Any]] = []
            for other in ALGORITHMS[1:]:
                if other not in scores:
                    continue
                p_exact = p_min = math.nan
                if measure == "xp":
                    mine, theirs = (np.asarray(scores[x].xp_matrix, np.float64) for x in ("cec", other))
                    if min(mine.size, theirs.size) == 0:
                        continue
                    c = compare_crossplay(mine, theirs)
                    if matrices is not None and level_set in matrices:
                        p_exact, p_min = exact_crossplay(matrices[level_set], "cec", other)
                else:
                    a, b = finite(scores["cec"].human), finite(scores[other].human)
                    if a.size < 2 or b.size < 2:
                        continue
                    c = compare(a, b)
                    exact = permutation_two_sample(a, b)
                    p_exact, p_min = exact.p, exact.p_min
                if math.isnan(c.p):
                    continue
                family.append({"level_set": level_set, "measure": measure, "better": "cec", "worse": other,
                               "diff": c.diff, "ci_low": c.ci_low, "ci_high": c.ci_high, "p": c.p,
                               "significant": bool(c.p < ALPHA), "p_exact": p_exact,
                               "p_min": p_min})  # fmt: skip
            for t, h, h_exact in zip(
                family, holm([t["p"] for t in family]), holm([t["p_exact"] for t in family]), strict=True
            ):
                t.update(p_holm=float(h), p_exact_holm=float(h_exact), family=len(family))
            out += family
    return out


def exact_crossplay(matrix: SeedMatrix, a: str, b: str) -> tuple[float, float]:
    """The exact permutation p of algorithm `a`'s cross-play against `b`'s over their seeds and its
    smallest attainable value (`cec.evaluation.stats.permutation_crossplay`), from `matrix` (a
    `cec.evaluation.seeds.SeedMatrix`): the pooled seed x seed matrix of both algorithms' seeds. NaN, NaN
    where two of these seeds never played each other (no pooled matrix), or a side has fewer than 2 seeds."""
    from cec.evaluation.stats import permutation_crossplay

    ia, ib = matrix.indices(a), matrix.indices(b)
    idx = ia + ib
    pooled = matrix.scores[np.ix_(idx, idx)]
    if min(len(ia), len(ib)) < 2 or np.isnan(pooled[~np.eye(len(idx), dtype=bool)]).any():
        return math.nan, math.nan
    r = permutation_crossplay(pooled, len(ia))
    return r.p, r.p_min
