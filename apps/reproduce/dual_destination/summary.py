"""The numbers `cec reproduce dual-destination` reports, from what its runs wrote.

`summarise`: per task set, kind (XP, SP, with the oracle partner; sampled and greedy) and algorithm, a
variant's score over seeds, from its cross-play table (`evaluate.evaluate_variant`); `conventions`:
the goal each seed sends seat 0 to in greedy self-play. `check_claims`: the paper's
orderings (`paper.CLAIMS`) tested on per-seed XP, `check_ablations` each ablation against its
algorithm. `training_stats`: each algorithm's training time and
return at the end, from its runs' metrics. `report.write_report` writes them beside the paper's numbers.
"""

from __future__ import annotations

import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from apps.reproduce.dual_destination.paper import (
    ABLATIONS,
    CLAIMS,
    LEVEL_SETS,
    ORACLE,
    ROWS,
    fixed_level_name,
)
from apps.reproduce.pipeline import read_metrics, train_seconds

if TYPE_CHECKING:
    from cec.envs.dual_destination.level import DDLevel
    from cec.evaluation.results import EpisodeTable

ALPHA = 0.05  # significance level of the ordering tests
LEARNED = 0.5  # a seed whose sampled self-play reaches this normalised score has learned the task set


# ---------------------------------------------------------------------------------------------------------
# CROSS-PLAY
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """One algorithm's score of one kind on one level set of one variant.

    Attributes:
        mean, sem: over the samples (NaN when there are none / fewer than 2); for cross-play kinds the mean
            over every pair of two different seeds and its leave-one-seed-out jackknife standard error
            (`cec.evaluation.stats.crossplay_estimate`: a seed's pairs are shared with the other seeds).
        n_seeds: the algorithm's seeds; n: the samples, one per seed (`xp`: the seed's mean with the other
            seeds, `cec.evaluation.stats.seed_means`; `sp`: with itself; `oracle`: with the oracle).
        samples: the samples themselves (normalised scores), for display; seeds are the units.
        seeds: the seed of each sample (`oracle`: one per seed and oracle partner).
        matrix: cross-play kinds: the seed x seed matrix the score comes from (tests compare these).
    """

    mean: float
    sem: float
    n_seeds: int
    n: int
    samples: tuple[float, ...]
    seeds: tuple[int, ...] = ()
    matrix: tuple[tuple[float, ...], ...] = ()


#: The kinds of score `summarise` gives: (kind, actions played, episode returns clipped at 0).
KINDS = (
    ("xp", "sampled", False),  # the paper's protocol: sampled actions, cross-play with unseen seeds
    ("sp", "sampled", False),
    ("oracle", "sampled", False),
    ("xp_clipped", "sampled", True),  # each episode's return clipped at 0 before normalising
    ("greedy_xp", "greedy", False),  # each seed's most likely action: its convention, unblurred
    ("greedy_sp", "greedy", False),
    ("xp_learned", "sampled", False),  # `xp` among the seeds whose self-play reached LEARNED
)


def summarise(table: EpisodeTable, variant: str) -> dict[str, dict[str, dict[str, Score]]]:
    """{level set: {kind: {algorithm: Score}}} for the `KINDS` the table has episodes of: `xp` (per seed,
    its mean with the algorithm's other seeds: the paper's measure, with seeds as the units), `sp` (each
    seed with itself), `oracle` (each seed with the oracle partner; the oracle's own self-play is under
    `sp` as `oracle`), `xp_clipped` (`xp` with every episode's return clipped at 0, the scale on which a
    failed episode scores 0 rather than -0.5), `greedy_xp`/`greedy_sp` (the table's greedy episodes), and
    `xp_learned` (`xp` among the seeds whose sampled self-play reached `LEARNED`: a seed that never learned
    the task lowers XP for a reason other than conventions)."""
    import dataclasses

    out: dict[str, dict[str, dict[str, Score]]] = {}
    for level_set in LEVEL_SETS:
        names = sorted(
            {str(n) for n in table.level if (n == fixed_level_name(variant)) == (level_set == "fixed")}
        )
        if not names:
            continue
        kinds: dict[str, dict[str, Score]] = {}
        for kind, actions, clipped in KINDS:
            played = table.select(table.actions == actions)
            if not len(played):
                continue
            if clipped:
                played = dataclasses.replace(played, returns=np.maximum(played.returns, 0.0))
            kinds[kind] = _scores(played, names, kind.removeprefix("greedy_").removesuffix("_clipped"))
        out[level_set] = kinds
    return out


def _scores(table: EpisodeTable, names: list[str], kind: str) -> dict[str, Score]:
    """{algorithm: Score} of one kind (`xp`, `sp`, `oracle`) on the levels `names`."""
    from cec.evaluation.seeds import seed_matrix
    from cec.evaluation.stats import sem

    sm = seed_matrix(table, names)
    seeds = {a: sm.indices(a) for a in (*ROWS, ORACLE)}
    out = {}
    for algo, idx in seeds.items():
        if not idx or (kind == "oracle" and algo == ORACLE):
            continue
        summary = None
        if kind in ("xp", "xp_learned"):  # seeds: the units; their pairs shared
            kept = [i for i in idx if sm.scores[i, i] >= LEARNED] if kind == "xp_learned" else idx
            summary = sm.summary(kept)
            pairs = list(zip(summary.seeds, summary.xp, strict=True))
        elif kind == "sp":
            own = sm.summary(idx)
            pairs = list(zip(own.seeds, own.sp, strict=True))
        else:
            pairs = [(sm.policies[i].seed, sm.scores[i, o]) for i in idx for o in seeds[ORACLE]]
        pairs = [(seed, v) for seed, v in pairs if not math.isnan(v)]
        if pairs:
            arr = np.asarray([v for _, v in pairs], np.float64)
            ids = tuple(int(seed) for seed, _ in pairs)
            mean, err = float(arr.mean()), sem(arr)
            cells: tuple[tuple[float, ...], ...] = ()
            if summary is not None:
                mean, err = summary.crossplay()[:2]
                cells = summary.matrix
            out[algo] = Score(mean, err, len(idx), arr.size, tuple(arr.tolist()), ids, cells)
    return out


def conventions(variant: str, manifest: Path) -> dict[str, dict[int, str]]:
    """{algorithm: {seed: its convention}}: the goal seat 0 stands on at the end of the seed's greedy
    self-play on the variant's fixed task (`green (0, 2)`: the top goal of the fixed task; `no goal`)."""
    import jax
    import numpy as np

    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo
    from cec.evaluation.crossplay import episode_states, eval_levels

    policies, _ = load_policies(load_zoo(manifest))
    name = fixed_level_name(variant)
    level = jax.tree.map(lambda x: x[0], eval_levels("dual_destination", name).levels)
    out: dict[str, dict[int, str]] = {}
    for p in policies:
        states, _ = episode_states(p, p, level, name, greedy=True)
        at = tuple(int(v) for v in np.asarray(states.agent_pos)[-1, 0])
        out.setdefault(p.algorithm, {})[int(p.seed)] = goal_label(level, at)
    return out


CONVENTIONS_FILE = "conventions.json"  # beside a variant's result table: `conventions` as it found them


def save_conventions(found: dict[str, dict[int, str]], path: Path) -> None:
    """Writes `conventions`' answer to `path` (JSON), for a report written without the policies."""
    path.write_text(
        json.dumps({a: {str(s): c for s, c in seeds.items()} for a, seeds in found.items()}, indent=1) + "\n"
    )


def load_conventions(path: Path) -> dict[str, dict[int, str]]:
    """What `save_conventions` wrote: {algorithm: {seed: its convention}}."""
    return {a: {int(s): c for s, c in seeds.items()} for a, seeds in json.loads(path.read_text()).items()}


def goal_label(level: DDLevel, cell: tuple[int, ...]) -> str:
    """`green (r, c)` / `pink (r, c)` when `cell` is one of `level`'s goals, else `no goal`."""
    import numpy as np

    for colour in ("green", "pink"):
        if any(tuple(int(v) for v in g) == cell for g in np.asarray(getattr(level, f"{colour}_goals"))):
            return f"{colour} {cell}"
    return "no goal"


@dataclass(frozen=True)
class ClaimResult:
    """One of the paper's orderings tested on our numbers (Welch t-test on per-seed XP)."""

    variant: str
    level_set: str
    better: str
    worse: str
    diff: float
    ci_low: float
    ci_high: float
    p: float
    holds: bool
    significant: bool


def check_claims(
    summaries: dict[str, dict[str, dict[str, dict[str, Score]]]], kind: str = "xp"
) -> list[ClaimResult]:
    """Every `CLAIMS` ordering present in `summaries`, on per-seed scores of `kind` (`xp`; `xp_learned`:
    among the seeds that learned): holds = better's mean > worse's mean; significant = holds and
    two-sided p < ALPHA."""
    return [r for c in CLAIMS if (r := _ordering(summaries, *c, kind=kind)) is not None]


def check_ablations(summaries: dict[str, dict[str, dict[str, dict[str, Score]]]]) -> list[ClaimResult]:
    """Each ablation (`ABLATIONS`) against the algorithm it varies (`cec > cec_nolstm`), per variant and
    task set present in `summaries`, tested as `check_claims` tests the paper's orderings."""
    return [
        r
        for variant in summaries
        for level_set in LEVEL_SETS
        for label, ablation in ABLATIONS.items()
        if (r := _ordering(summaries, variant, level_set, ablation.algorithm, label)) is not None
    ]


def _ordering(
    summaries: dict[str, dict[str, dict[str, dict[str, Score]]]],
    variant: str,
    level_set: str,
    better: str,
    worse: str,
    kind: str = "xp",
) -> ClaimResult | None:
    from cec.evaluation.stats import compare, compare_crossplay

    xp = summaries.get(variant, {}).get(level_set, {}).get(kind, {})
    if better not in xp or worse not in xp:
        return None
    a, b = xp[better], xp[worse]
    if a.matrix and b.matrix:  # cross-play: the jackknife over seeds
        c = compare_crossplay(np.asarray(a.matrix), np.asarray(b.matrix))
    else:
        c = compare(np.asarray(a.samples), np.asarray(b.samples))
    holds = c.diff > 0
    significant = bool(holds and not math.isnan(c.p) and c.p < ALPHA)
    return ClaimResult(
        variant, level_set, better, worse, c.diff, c.ci_low, c.ci_high, c.p, holds, significant
    )


# ---------------------------------------------------------------------------------------------------------
# TRAINING
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class TrainingStats:
    """What an algorithm's training run of one variant recorded in its metrics.

    Attributes:
        seeds: seeds trained; env_steps: per seed.
        seconds: training time of the run (its updates' env steps over their env steps/s; compilation and
            checkpointing not included), also when this invocation skipped the finished run.
        final_return: normalised training return at the end (mean over seeds of the last 5 updates), with
            the partner it trained with (itself; FCP: its population).
        final_entropy: policy entropy (nats; log 5 = 1.61 is uniform) at the end, the same way; low means
            the seeds act almost deterministically, so sampled and greedy play agree.
        best_return: the highest normalised training return of any update (mean over seeds); above 0 means
            the seeds reached a positive reward (the paper's criterion for its no-LSTM ablation).
        best_by_seed: each seed's highest normalised training return of any update (keys: the seeds, as
            text, as JSON keeps them): one seed may reach a positive reward where the mean does not.
        positive_at: each seed's env steps at its first update with a positive normalised training return
            (None: never), the step at which it took off; seeds take off at very different steps.
        late_slope: how fast the normalised training return still rose at the end: per seed, the slope of
            a straight line through its last quarter of updates, per 1e6 env steps; the mean over seeds.
            Near 0: the return levelled off, more steps of the same training will not raise it.
    """

    seeds: int
    env_steps: int
    seconds: float
    final_return: float
    final_entropy: float = math.nan
    best_return: float = math.nan
    best_by_seed: dict[str, float] = field(default_factory=dict)
    positive_at: dict[str, int | None] = field(default_factory=dict)
    late_slope: float = math.nan


_COUNTS = ("update", "env_steps", "seed", "episodes")  # logged as integers, read back from a CSV as floats


def return_slope(curve: list[tuple[int, float]], fraction: float = 0.25) -> float:
    """The slope, per 1e6 env steps, of a least-squares line through the last `fraction` of a seed's
    (env steps, normalised return) points, in update order; NaN with fewer than 3 points there."""
    tail = curve[-max(3, round(len(curve) * fraction)) :]
    steps = np.array([x for x, _ in tail], dtype=float)
    if len(tail) < 3 or np.ptp(steps) == 0:
        return math.nan
    return float(np.polyfit(steps / 1e6, [y for _, y in tail], 1)[0])


def training_stats(zoo_dir: Path) -> dict[str, TrainingStats]:
    """Per algorithm, from its runs' `zoo_dir/runs/<algorithm>-s<first seed>/metrics.jsonl` (or, in a
    committed work folder, their `metrics.csv`, plain or compressed: the same rows); one run of vmapped
    seeds, or one run per seed: their times add up, their seeds pool."""
    runs: dict[str, list[list[dict[str, Any]]]] = {}
    for run in sorted(d for d in zoo_dir.glob("runs/*") if d.is_dir()):
        algo = run.name.rsplit("-s", 1)[0]
        # the counts as the integers `metrics.jsonl` holds (a CSV's rows read as floats)
        rows = [
            {k: int(v) if k in _COUNTS and isinstance(v, float) else v for k, v in r.items()}
            for r in read_metrics(run)
        ]
        if algo in ROWS and rows:
            runs.setdefault(algo, []).append(rows)
    out = {}
    for algo, per_run in runs.items():
        seeds, seconds, steps = set(), 0.0, 0
        final: list[float] = []
        entropy: list[float] = []
        by_update: dict[int, list[float]] = {}
        by_seed: dict[str, float] = {}
        positive_at: dict[str, int | None] = {}
        slopes: list[float] = []
        for rows in per_run:
            run_seeds = {r["seed"] for r in rows}
            seeds |= run_seeds
            ordered = sorted({r["update"]: r for r in rows}.values(), key=lambda r: r["update"])
            seconds += train_seconds(rows)
            steps = max(steps, int(ordered[-1]["env_steps"]))
            last = {r["update"] for r in ordered[-5:]}
            final += [
                r["normalised_return"] for r in rows if r["update"] in last and "normalised_return" in r
            ]
            entropy += [r["entropy"] for r in rows if r["update"] in last and r.get("entropy") is not None]
            latest = {(r["seed"], r["update"]): r for r in rows if "normalised_return" in r}  # resumes repeat
            curves: dict[str, list[tuple[int, float]]] = {}
            for r in sorted(latest.values(), key=lambda r: r["update"]):
                seed, ret = str(r["seed"]), float(r["normalised_return"])
                by_update.setdefault(r["update"], []).append(ret)
                by_seed[seed] = max(by_seed.get(seed, -math.inf), ret)
                curves.setdefault(seed, []).append((int(r["env_steps"]), ret))
                if ret > 0:
                    positive_at.setdefault(seed, int(r["env_steps"]))
            slopes += [s for s in map(return_slope, curves.values()) if not math.isnan(s)]
            for seed in map(str, run_seeds):
                positive_at.setdefault(seed, None)
        out[algo] = TrainingStats(
            len(seeds),
            steps,
            float(seconds),
            float(np.mean(final)) if final else math.nan,
            float(np.mean(entropy)) if entropy else math.nan,
            max((float(np.mean(v)) for v in by_update.values()), default=math.nan),
            dict(sorted(by_seed.items(), key=lambda kv: int(kv[0]))),
            dict(sorted(positive_at.items(), key=lambda kv: int(kv[0]))),
            float(np.mean(slopes)) if slopes else math.nan,
        )
    return out
