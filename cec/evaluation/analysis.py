"""Analyses derived from the long result table: matrices, per-level scores, BR-normalised scores, tests.

A *policy* here is (algorithm, seed): single-task zoo entries of one algorithm and seed trained on
different layouts (each restricted to its layout) are one policy, as in the paper's figures.

Aggregation, bottom up (every step an unweighted mean, so unequal episode counts weigh nothing):

    pair-level score   one unordered pair of policies on one level: mean over episodes and seat orders
    pair score         mean of its pair-level scores over the levels of a level set both policies play
    SP (policy)        its pair score with itself;   XP (algorithm): pair scores of two different seeds
    ad hoc (algorithm) pair scores with the policies of every other algorithm
    cell (alpha, beta) mean pair score over pairs of different policies of algorithms alpha and beta

Standard errors and t-tests take the pair score as the sample (pairs share policies, so they are not
independent: treat p-values as descriptive). Scores are returns, or for Dual Destination the paper's
oracle-normalised score return / (2 x episode length).
"""

from __future__ import annotations

import math
from collections import defaultdict
from collections.abc import Sequence
from typing import NamedTuple

import numpy as np

from cec.agents.zoo import HUMAN_PROXY
from cec.envs.registry import GAMES
from cec.evaluation.results import EpisodeTable, ResultsError
from cec.evaluation.stats import iqm, sem
from cec.levels.classic import CLASSIC_ASCII

CLASSIC_SET = "classic"
GENERATED_SET = "held-out generated"


class PolicyId(NamedTuple):
    algorithm: str
    seed: int

    def label(self) -> str:
        return f"{self.algorithm}/s{self.seed}"


class Matrix(NamedTuple):
    """A labelled square matrix (NaN where no pair was played)."""

    labels: tuple[str, ...]
    values: np.ndarray


class PairLevel(NamedTuple):
    """Pair-level scores: policies `a` <= `b` (indices into `policies`) on `level` (arrays of length M)."""

    policies: tuple[PolicyId, ...]
    a: np.ndarray
    b: np.ndarray
    level: np.ndarray
    score: np.ndarray


class LevelStat(NamedTuple):
    """An algorithm's score on one level: mean and standard error over pairs (`n` of them)."""

    algorithm: str
    level: str
    mean: float
    sem: float
    n: int


class BRProx(NamedTuple):
    """Best-response-normalised score of one algorithm's policies with every other policy."""

    iqm: float
    q25: float
    q75: float
    n: int


def check_single_env(table: EpisodeTable) -> tuple[str, int]:
    """(env, episode length) of the table; `ResultsError` when runs of different games or lengths mix."""
    envs = sorted(set(table.env.tolist()))
    steps = sorted(set(table.episode_steps.tolist()))
    if len(envs) > 1 or len(steps) > 1:
        raise ResultsError(f"the results mix games {envs} / episode lengths {steps}; report each on its own")
    if not envs:
        raise ResultsError("the results hold no played episode")
    return envs[0], steps[0]


METRICS = ("score", "return", "deliveries", "collisions", "shaped_return")


def normalised_score(env: str) -> bool:
    """The game `env` scores return / (2 x episode length) (False for a name no game has)."""
    game = GAMES.get(env)
    return game is not None and game.normalised_score


def scores(table: EpisodeTable, metric: str = "score") -> np.ndarray:
    """One value per row: `score` is the return, or for Dual Destination return / (2 x episode length);
    the other `METRICS` are the table's columns."""
    if metric == "score":
        if len(table) and normalised_score(str(table.env[0])):
            return table.returns / (2.0 * table.episode_steps)
        return table.returns.astype(np.float64)
    if metric not in METRICS:
        raise ValueError(f"unknown metric {metric!r}; choose one of {list(METRICS)}")
    column = table.returns if metric == "return" else getattr(table, metric)
    return np.asarray(column, np.float64)


def level_sets(names: Sequence[str]) -> dict[str, list[str]]:
    """Level names grouped as the paper reports them: `classic`, `held-out generated`, others one each."""
    out: dict[str, list[str]] = {}
    for name in sorted(set(names)):
        if name in CLASSIC_ASCII:
            out.setdefault(CLASSIC_SET, []).append(name)
        elif name.startswith("generated_"):
            out.setdefault(GENERATED_SET, []).append(name)
        else:
            out.setdefault(name, []).append(name)
    return out


def policies_of(table: EpisodeTable) -> tuple[PolicyId, ...]:
    """Every (algorithm, seed) in the table, sorted. A policy may play a level under several names (a
    seed of a single-kitchen algorithm is its agents of every kitchen, each on the held-out kitchens; its
    pair scores then average them), but two names of one (algorithm, seed) that play each other are two
    policies labelled alike: refused."""
    ids = {
        PolicyId(algo, int(seed))
        for algo, seed in set(
            zip(
                [*table.algorithm_a, *table.algorithm_b],
                [*table.seed_a.tolist(), *table.seed_b.tolist()],
                strict=True,
            )
        )
    }
    same = (
        (table.algorithm_a == table.algorithm_b)
        & (table.seed_a == table.seed_b)
        & (table.policy_a != table.policy_b)
    )
    if same.any():
        i = int(np.flatnonzero(same)[0])
        raise ResultsError(
            f"zoo entries {table.policy_a[i]!r} and {table.policy_b[i]!r} are both {table.algorithm_a[i]} "
            f"seed {int(table.seed_a[i])} and play each other on level {table.level[i]!r}; give them "
            "different seeds or algorithm labels"
        )
    return tuple(sorted(ids))


def pair_level_scores(
    table: EpisodeTable, levels: Sequence[str] | None = None, metric: str = "score"
) -> PairLevel:
    """Mean `metric` (see `scores`) per unordered policy pair and level (over episodes and seat orders),
    on `levels` (None: all)."""
    if levels is not None:  # the policies are those that play these levels
        table = table.select(np.isin(table.level, list(levels)))
    policies = policies_of(table)
    value = scores(table, metric)
    # Each row's policies as indices into `policies` (sorted by algorithm, then seed, as np.unique sorts),
    # in arrays: a million rows cost tens of MB, not a Python object per row.
    n = len(table)
    _, algo = np.unique(np.concatenate([table.algorithm_a, table.algorithm_b]), return_inverse=True)
    seeds = np.concatenate([table.seed_a, table.seed_b]).astype(np.int64)
    found, index = np.unique(np.stack([algo.reshape(-1), seeds], 1), axis=0, return_inverse=True)
    assert len(found) == len(policies), "policies_of and the rows disagree"
    ia, ib = index.reshape(-1)[:n], index.reshape(-1)[n:]
    lo, hi = np.minimum(ia, ib), np.maximum(ia, ib)
    level_names, level_code = np.unique(table.level, return_inverse=True)  # str objects: no fixed width
    # Average episodes within each seat order (who sits in seat 0) first, then the seat orders.
    seat0 = np.where(table.seat == 0, ia, ib)
    orders, order_of = np.unique(np.stack([lo, hi, level_code, seat0], 1), axis=0, return_inverse=True)
    order_mean = _group_mean(order_of.reshape(-1), value, len(orders))
    pairs, pair_of = np.unique(orders[:, :3], axis=0, return_inverse=True)
    return PairLevel(
        policies,
        pairs[:, 0].astype(np.int64),
        pairs[:, 1].astype(np.int64),
        level_names[pairs[:, 2]].astype(object),
        _group_mean(pair_of.reshape(-1), order_mean, len(pairs)),
    )


def _group_mean(group: np.ndarray, values: np.ndarray, n: int) -> np.ndarray:
    return np.bincount(group, weights=values, minlength=n) / np.bincount(group, minlength=n)


def pair_scores(pl: PairLevel) -> np.ndarray:
    """[P, P] symmetric matrix of pair scores (mean over the levels both play; NaN: never paired)."""
    p = len(pl.policies)
    total = np.zeros((p, p))
    count = np.zeros((p, p))
    np.add.at(total, (pl.a, pl.b), pl.score)
    np.add.at(count, (pl.a, pl.b), 1)
    with np.errstate(invalid="ignore", divide="ignore"):
        m = total / count
    return np.where(np.isnan(m), m.T, m)  # the lower triangle mirrors the upper one


def algorithms_of(policies: Sequence[PolicyId]) -> list[str]:
    return sorted({p.algorithm for p in policies})


def seed_matrix(pl: PairLevel, algorithm: str) -> Matrix:
    """Seed x seed matrix of one algorithm: SP on the diagonal, XP off it."""
    m = pair_scores(pl)
    idx = [i for i, p in enumerate(pl.policies) if p.algorithm == algorithm]
    return Matrix(tuple(f"s{pl.policies[i].seed}" for i in idx), m[np.ix_(idx, idx)])


def _pairs_between(pl: PairLevel, m: np.ndarray, alpha: str, beta: str) -> np.ndarray:
    """Pair scores of different policies of algorithms alpha and beta (each unordered pair once)."""
    out = []
    n = len(pl.policies)
    for i in range(n):
        for j in range(i + 1, n):
            pi, pj = pl.policies[i], pl.policies[j]
            if {pi.algorithm, pj.algorithm} == {alpha, beta} and not math.isnan(m[i, j]):
                out.append(m[i, j])
    return np.asarray(out, np.float64)


def algorithm_matrix(pl: PairLevel) -> Matrix:
    """Cross-algorithm matrix: cell (alpha, beta) = mean pair score of different policies (symmetric)."""
    m = pair_scores(pl)
    algos = algorithms_of(pl.policies)
    out = np.full((len(algos), len(algos)), np.nan)
    for i, alpha in enumerate(algos):
        for j, beta in enumerate(algos):
            vals = _pairs_between(pl, m, alpha, beta)
            if vals.size:
                out[i, j] = vals.mean()
    return Matrix(tuple(algos), out)


def _partners(pl: PairLevel, alpha: str, kind: str) -> list[int]:
    """Indices of algorithm `alpha`'s partners of `kind`: `adhoc` every policy of another algorithm but the
    human proxies, `human` every human proxy."""
    human = kind == "human"
    return [
        j for j, p in enumerate(pl.policies) if p.algorithm != alpha and (p.algorithm == HUMAN_PROXY) == human
    ]


def algorithm_samples(pl: PairLevel, kind: str) -> dict[str, np.ndarray]:
    """Per algorithm, its pair scores: `sp` (each policy with itself), `xp` (two different seeds of the
    algorithm), `adhoc` (its policies with every policy of another algorithm, human proxies aside) or
    `human` (its policies with every human proxy, `HUMAN_PROXY`)."""
    m = pair_scores(pl)
    out: dict[str, np.ndarray] = {}
    for alpha in algorithms_of(pl.policies):
        idx = [i for i, p in enumerate(pl.policies) if p.algorithm == alpha]
        if kind == "sp":
            vals = np.asarray([m[i, i] for i in idx])
        elif kind == "xp":
            vals = _pairs_between(pl, m, alpha, alpha)
        elif kind in ("adhoc", "human"):
            others = _partners(pl, alpha, kind)
            vals = np.asarray([m[i, j] for i in idx for j in others], np.float64)
        else:
            raise ValueError(f"kind must be sp, xp, adhoc or human, got {kind!r}")
        out[alpha] = vals[~np.isnan(vals)]
    return out


def seed_samples(pl: PairLevel, kind: str) -> dict[str, np.ndarray]:
    """Per algorithm, one score per seed (the units of a test): its mean with its partners of `kind`
    (`adhoc`: every policy of other algorithms; `human`: every human proxy); NaN-free. The partners are
    the same for every seed, so these compare algorithms *with these partners*. Cross-play is different:
    seeds partner each other, so use `cec.evaluation.stats.crossplay_estimate` on `seed_matrix`."""
    if kind not in ("adhoc", "human"):
        raise ValueError(f"kind must be adhoc or human, got {kind!r}")
    m = pair_scores(pl)
    out: dict[str, np.ndarray] = {}
    for alpha in algorithms_of(pl.policies):
        partners = _partners(pl, alpha, kind)
        rows = [m[i, partners] for i, p in enumerate(pl.policies) if p.algorithm == alpha]
        means = np.asarray([np.nanmean(r) if np.isfinite(r).any() else np.nan for r in rows], np.float64)
        out[alpha] = means[~np.isnan(means)]
    return out


def per_level(pl: PairLevel, kind: str = "xp") -> list[LevelStat]:
    """Per algorithm and level: mean and SE over pairs (`xp`: two different seeds; `sp`: self-play)."""
    stats: list[LevelStat] = []
    for level in sorted(set(pl.level.tolist())):
        on = pl.level == level
        for alpha in algorithms_of(pl.policies):
            vals = []
            for a, b, s in zip(pl.a[on], pl.b[on], pl.score[on], strict=True):
                pa, pb = pl.policies[a], pl.policies[b]
                if pa.algorithm == alpha and pb.algorithm == alpha and (a == b) == (kind == "sp"):
                    vals.append(s)
            arr = np.asarray(vals, np.float64)
            if arr.size:
                stats.append(LevelStat(alpha, level, float(arr.mean()), sem(arr), int(arr.size)))
    return stats


def br_prox(pl: PairLevel) -> dict[str, BRProx]:
    """A best-response-normalised score in the spirit of ZSC-Eval's BR-Prox, with an empirical best
    response: on each level, partner p's best response is the zoo policy q (p itself included) with the
    highest pair-level score with p. The ego's score with p is min(1, R(ego, p) / R(BR_p, p)), 1 when
    R(BR_p, p) <= 0; aggregated per algorithm by the interquartile mean over (ego, partner != ego,
    level)."""
    best: dict[tuple[int, str], float] = {}
    by_pair: dict[tuple[int, int, str], float] = {}
    for a, b, level, s in zip(pl.a, pl.b, pl.level, pl.score, strict=True):
        by_pair[(a, b, level)] = by_pair[(b, a, level)] = float(s)
        for partner in (a, b):
            best[(partner, level)] = max(best.get((partner, level), -math.inf), float(s))
    per_algo: dict[str, list[float]] = defaultdict(list)
    for (ego, partner, level), r in by_pair.items():
        if ego == partner:
            continue
        br = best[(partner, level)]
        per_algo[pl.policies[ego].algorithm].append(1.0 if br <= 0 else min(1.0, r / br))
    out = {}
    for alpha, vals in sorted(per_algo.items()):
        arr = np.asarray(vals)
        out[alpha] = BRProx(iqm(arr), float(np.quantile(arr, 0.25)), float(np.quantile(arr, 0.75)), arr.size)
    return out
