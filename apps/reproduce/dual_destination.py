"""`cec reproduce dual-destination [--quick | --paper]`: the paper's Dual Destination results, end to end.

    cec reproduce dual-destination --plan      # what would be trained and evaluated, and how long it takes
    cec reproduce dual-destination --quick     # a reduced version (under 30 minutes on a 2-core CPU)
    cec reproduce dual-destination             # the full version, sized for a CPU (--plan states its time)
    cec reproduce dual-destination --paper     # the paper's networks and budgets (a GPU job)

For each variant of the game (fully observable, partially observable 3x3 view, multi-task green + pink):

1. **Train** (`cec zoo build`, resumable: run the same command again after an interruption) IPPO seeds
   and FCP seeds on the fixed task (the multi-task layout for the multi-task variant; FCP's population is
   the IPPO seeds at their first, middle and last milestones), and CEC seeds on procedurally generated
   tasks, the fixed tasks and the 100 evaluation tasks held out of its training.
2. **Evaluate** cross-play (`cec.evaluation.crossplay`, common random numbers, both seat orders) on the
   fixed task and on the 100 held-out generated tasks: every pair of different seeds of one algorithm
   (zero-shot coordination with unseen partners, the paper's measure), self-play, and every policy with
   the scripted oracle partner (`dd_oracle`) as a reference point.
3. **Report** `report.md` (+ `summary.json`, bar plots) beside the paper's numbers: per variant, task set
   and algorithm the normalised cross-play score (return / 200) with its standard error over seeds (each
   seed's mean with the other seeds); the paper's orderings with Welch t-tests and bootstrap intervals over
   those per-seed means (seeds are the independent units; pairs share seeds); and, where a number
   differs from the paper's by more than 0.05, by how much.

The work directory (`--work`, default `runs/reproduce/dual_destination-<mode>`) holds one zoo per
variant (`<variant>/zoo`), its spec and the result tables; the report goes to `--out` (default
`benchmarks/results/dual_destination/<mode>`).
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from apps.machine import duration, log_line
from apps.machine import machine_info as _machine_info
from cec.checkpoints import code_version
from cec.config import ConfigError

ROOT = Path(__file__).resolve().parents[2]
VARIANTS = ("full_obs", "partial_obs", "multi_task")
VARIANT_TITLES = {
    "full_obs": "Fully observable",
    "partial_obs": "Partially observable (3x3 view)",
    "multi_task": "Multi-task (green and pink pairs)",
}
ALGORITHMS = ("ippo", "fcp", "cec")
ORACLE = "oracle"
LEVEL_SETS = ("fixed", "generated")  # the fixed task (multi_task layout in that variant); 100 generated tasks
LEVEL_SET_TITLES = {"fixed": "fixed task", "generated": "held-out generated tasks"}
ORACLE_FIXED = 0.955  # the oracle's normalised score on the fixed task (the paper's ceiling)
TOLERANCE = 0.05  # "within 0.05 of the paper's"
ALPHA = 0.05  # significance level of the ordering tests


# ---------------------------------------------------------------------------------------------------------
# THE PAPER'S NUMBERS
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class PaperNumber:
    """One number the paper reports: normalised cross-play with unseen partners.

    Attributes:
        variant, level_set, algorithm: where it belongs.
        mean: the paper's value, or None where the paper shows it only in a figure.
        sem: its standard error where the paper gives one.
        text: how the paper states it.
    """

    variant: str
    level_set: str
    algorithm: str
    mean: float | None
    sem: float | None
    text: str


PAPER: tuple[PaperNumber, ...] = (
    PaperNumber("full_obs", "fixed", "cec", 0.931, 0.013, "CEC scored 0.931 normalized reward (SE 0.013)"),
    PaperNumber("full_obs", "generated", "cec", 0.966, None, "CEC = 0.966 on procedurally generated tasks"),
    PaperNumber("full_obs", "fixed", "fcp", None, None, "figure only: FCP does better than IPPO"),
    PaperNumber("full_obs", "fixed", "ippo", None, None, "figure only: IPPO fails with novel partners"),
    PaperNumber("full_obs", "generated", "fcp", None, None, "figure only: fails on novel tasks (near 0)"),
    PaperNumber("full_obs", "generated", "ippo", None, None, "figure only: fails on novel tasks (near 0)"),
    PaperNumber("partial_obs", "generated", "cec", 0.74, None, "CEC 0.74 on novel environments"),
    PaperNumber("partial_obs", "generated", "fcp", 0.61, None, "population based methods 0.61"),
    PaperNumber("partial_obs", "generated", "ippo", 0.03, None, "naive self-play 0.03"),
    PaperNumber("multi_task", "fixed", "cec", 0.404, None, "CEC agents (0.404)"),
    PaperNumber("multi_task", "fixed", "fcp", 0.251, None, "PBT methods (0.251)"),
    PaperNumber("multi_task", "fixed", "ippo", 0.083, None, "naive self-play (0.083)"),
    PaperNumber("multi_task", "generated", "cec", 0.446, None, "CEC can (0.446)"),
    PaperNumber("multi_task", "generated", "fcp", 0.005, None, "PBT (0.005)"),
    PaperNumber("multi_task", "generated", "ippo", 0.004, None, "naive self-play (0.004)"),
)

#: (variant, level set, better, worse): the orderings the paper states.
CLAIMS: tuple[tuple[str, str, str, str], ...] = (
    ("full_obs", "fixed", "cec", "fcp"),
    ("full_obs", "fixed", "cec", "ippo"),
    ("full_obs", "fixed", "fcp", "ippo"),
    ("full_obs", "generated", "cec", "fcp"),
    ("full_obs", "generated", "cec", "ippo"),
    ("partial_obs", "generated", "cec", "fcp"),
    ("partial_obs", "generated", "cec", "ippo"),
    ("partial_obs", "generated", "fcp", "ippo"),
    ("multi_task", "fixed", "cec", "fcp"),
    ("multi_task", "fixed", "cec", "ippo"),
    ("multi_task", "fixed", "fcp", "ippo"),
    ("multi_task", "generated", "cec", "fcp"),
    ("multi_task", "generated", "cec", "ippo"),
)


def paper_number(variant: str, level_set: str, algorithm: str) -> PaperNumber | None:
    return next(
        (p for p in PAPER if (p.variant, p.level_set, p.algorithm) == (variant, level_set, algorithm)), None
    )


# ---------------------------------------------------------------------------------------------------------
# THE PLAN
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Mode:
    """What one version of the reproduction trains and plays.

    Attributes:
        name: `quick` or `full`.
        presets: training preset per algorithm (`configs/train/...`).
        seeds: seeds per algorithm (FCP's population is every IPPO seed, as in the paper's code).
        steps: env steps per seed, per variant and algorithm.
        episodes: episodes per pairing, seat order and level, per level set.
        seconds_per_update: measured seconds of one training update per algorithm's preset (one seed;
            `num_seeds` seeds vmapped in one process take about that many times as long on a CPU); the
            basis of `--plan`'s estimate.
        measured_on: where and how `seconds_per_update` was measured.
        overrides: `key=value` overrides applied to every training run (e.g. a smaller network in tests).
        generated_levels: how many of the 100 held-out generated tasks to play (fewer only in tests).
        variants: the variants run when `--variants` is not given.
    """

    name: str
    presets: dict[str, str]
    seeds: dict[str, tuple[int, ...]]
    steps: dict[str, dict[str, int]]
    episodes: dict[str, int]
    seconds_per_update: dict[str, float] = field(default_factory=dict)
    measured_on: str = ""
    overrides: tuple[str, ...] = ()
    generated_levels: int = 100
    variants: tuple[str, ...] = VARIANTS


QUICK = Mode(
    name="quick",
    presets={
        "ippo": "configs/train/dd_ippo_quick.yaml",
        "fcp": "configs/train/dd_fcp_quick.yaml",
        "cec": "configs/train/dd_cec_quick.yaml",
    },
    seeds={"ippo": (0, 1, 2), "fcp": (100, 101, 102), "cec": (200, 201, 202)},
    steps={v: {"ippo": 256_000, "fcp": 256_000, "cec": 768_000} for v in VARIANTS},
    episodes={"fixed": 8, "generated": 1},
    variants=("full_obs",),  # ~25 minutes; each further variant (--variants) adds about as much
    # from the quick run's own metrics (3 seeds vmapped, per seed), load 4-9
    seconds_per_update={"ippo": 1.7, "fcp": 1.3, "cec": 7.1},
    measured_on="the project's 2-core AMD EPYC CPU, 3 seeds vmapped, other jobs running (load 4-9), "
    "2026-11-21",
)

FULL = Mode(
    name="full",
    presets={
        "ippo": "configs/train/dd_ippo_cpu.yaml",
        "fcp": "configs/train/dd_fcp_cpu.yaml",
        "cec": "configs/train/dd_cec_cpu.yaml",
    },
    seeds={"ippo": (0, 1, 2, 3, 4, 5), "fcp": (100, 101, 102, 103), "cec": (200, 201, 202, 203)},
    steps={v: {"ippo": 512_000, "fcp": 512_000, "cec": 2_048_000} for v in VARIANTS},
    episodes={"fixed": 16, "generated": 2},
    # CEC measured with `cec train`, one seed alone on the idle machine (4.8k env steps/s); IPPO has the same
    # network and cost, FCP ~10% more for its partners' forward passes (estimates; in the full run, sharing
    # the cores with a second run, IPPO and FCP ran at the same speed, 2.5k env steps/s)
    seconds_per_update={"ippo": 2.7, "fcp": 3.0, "cec": 2.7},
    measured_on="the project's 2-core AMD EPYC CPU (no GPU), one seed, 2026-11-21",
)

PAPER_SCALE = Mode(
    name="paper",
    presets={
        "ippo": "configs/train/dd_ippo.yaml",
        "fcp": "configs/train/dd_fcp.yaml",
        "cec": "configs/train/dd_cec.yaml",
    },
    seeds={"ippo": (0, 1, 2, 3, 4, 5), "fcp": (100, 101, 102, 103), "cec": (200, 201, 202, 203)},
    steps={
        "full_obs": {"ippo": 100_000_000, "fcp": 100_000_000, "cec": 100_000_000},
        "partial_obs": {"ippo": 300_000_000, "fcp": 300_000_000, "cec": 300_000_000},
        "multi_task": {"ippo": 300_000_000, "fcp": 300_000_000, "cec": 300_000_000},
    },
    episodes={"fixed": 32, "generated": 4},
    # `cec train` with each preset, one seed, 3 updates of 512 envs x 100 steps (FCP with 18 partners)
    seconds_per_update={"ippo": 92.0, "fcp": 150.0, "cec": 78.0},
    measured_on="the project's 2-core AMD EPYC CPU (no GPU), one seed, other jobs running (load 4-5), "
    "2026-11-21",
)

MODES = {"quick": QUICK, "full": FULL, "paper": PAPER_SCALE}


def _variant_overrides(variant: str, algorithm: str) -> list[str]:
    if variant == "partial_obs":
        return ["env.dual_destination.partial_obs=true"]
    if variant == "multi_task":
        levels = "procedural_multi_task" if algorithm == "cec" else "multi_task"
        return ["env.dual_destination.multi_task=true", f"env.levels={levels}"]
    return []


def fixed_level_name(variant: str) -> str:
    """The variant's fixed task: the paper's fixed task, or its multi-task layout."""
    return "multi_task" if variant == "multi_task" else "fixed"


def zoo_spec(mode: Mode, variant: str) -> dict[str, Any]:
    """The `cec zoo build` spec of one variant: IPPO, then FCP (population: the IPPO run), then CEC."""
    ippo_seeds = list(mode.seeds["ippo"])
    population = (
        f"[{{run: runs/ippo-s{ippo_seeds[0]}, seeds: {ippo_seeds}, checkpoints: [first, middle, last]}}]"
    )
    extra = {
        "ippo": ["checkpoint.milestones=[0.0,0.5,1.0]"],  # FCP's early, middle and final partners
        "fcp": [f"partner.population={population}"],
        "cec": [],
    }
    entries = []
    for algo in ALGORITHMS:
        overrides = [
            f"total_env_steps={mode.steps[variant][algo]}",
            *_variant_overrides(variant, algo),
            *extra[algo],
            *mode.overrides,
        ]
        preset = str(ROOT / mode.presets[algo])  # absolute: the spec works from any directory
        entries.append(
            {"preset": preset, "seeds": list(mode.seeds[algo]), "name": algo, "overrides": overrides}
        )
    return {"entries": entries}


@dataclass(frozen=True)
class PlanLine:
    """One training run of the plan with its size and estimated time."""

    variant: str
    algorithm: str
    seeds: int
    env_steps: int
    updates: int
    estimate_s: float


def plan_lines(mode: Mode, variants: Sequence[str] = VARIANTS) -> list[PlanLine]:
    """Every training run of `variants`, with the estimate from `mode.seconds_per_update` (NaN where not
    measured)."""
    from cec.config import load_config
    from cec.training.config import TrainConfig

    lines = []
    for variant in variants:
        for algo in ALGORITHMS:
            overrides = [*_variant_overrides(variant, algo), *mode.overrides]
            cfg = load_config(TrainConfig, ROOT / mode.presets[algo], overrides)
            steps = mode.steps[variant][algo]
            updates = math.ceil(steps / cfg.steps_per_update)
            n = len(mode.seeds[algo])
            per = mode.seconds_per_update.get(algo, math.nan)
            lines.append(PlanLine(variant, algo, n, steps, updates, per * updates * n))
    return lines


# ---------------------------------------------------------------------------------------------------------
# TRAIN AND EVALUATE
# ---------------------------------------------------------------------------------------------------------


def _log(log: TextIO, msg: str) -> None:
    log_line(log, "reproduce", msg)


def train_variant(
    mode: Mode, variant: str, work: Path, *, progress: bool, log: TextIO
) -> tuple[Path, tuple[str, ...]]:
    """Writes the variant's zoo spec and builds the zoo (resuming, skipping finished runs); returns the
    manifest and the runs found finished. Raises `ConfigError` when the build was interrupted (run the
    command again)."""
    from apps.zoo_build import build_zoo

    vdir = work / variant
    vdir.mkdir(parents=True, exist_ok=True)
    spec = vdir / "spec.yaml"
    text = yaml.safe_dump(zoo_spec(mode, variant), sort_keys=False)
    spec.write_text(f"# Written by `cec reproduce dual-destination` ({mode.name}, {variant}).\n" + text)
    result = build_zoo(spec, vdir / "zoo", progress=progress, log=log)
    if result.interrupted or result.manifest is None:
        raise ConfigError(f"training of {variant} was interrupted; run the same command again to continue")
    return result.manifest, result.skipped


def _generated_spec(mode: Mode) -> str:
    if mode.generated_levels >= 100:
        return "generated"
    return ",".join(f"generated_{i:03d}" for i in range(mode.generated_levels))


def evaluate_variant(mode: Mode, variant: str, manifest: Path, *, log: TextIO, seed: int = 0) -> Any:
    """Cross-play of the variant's zoo and the oracle partner -> one `EpisodeTable`.

    Per level set and algorithm, one evaluation of its seeds and the oracle partner, every pair: XP
    (two different seeds), SP, and every seed with the oracle (in both seats). Algorithms are evaluated
    apart (their networks may differ, and cross-algorithm pairs are not in the paper's figures); the
    oracle's self-play is kept once.
    """
    from cec.agents.policy import load_policies, scripted_policy
    from cec.agents.zoo import load_zoo
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
    from cec.evaluation.results import EpisodeTable

    policies, skipped = load_policies(load_zoo(manifest))
    if skipped:
        reasons = "; ".join(f"{s.name}: {s.reason}" for s in skipped)
        raise ConfigError(f"{variant}: zoo entries could not be loaded: {reasons}")
    oracle = scripted_policy("dd_oracle", ORACLE, algorithm=ORACLE)
    tables = []
    for level_set in LEVEL_SETS:
        spec = fixed_level_name(variant) if level_set == "fixed" else _generated_spec(mode)
        levels = eval_levels("dual_destination", spec)
        config = EvalConfig(levels=spec, episodes=mode.episodes[level_set], seed=seed, games_per_call=1)
        for k, algo in enumerate(ALGORITHMS):
            group = [p for p in policies if p.algorithm == algo]
            t0 = time.perf_counter()
            table = crossplay([*group, oracle], levels, config)
            if k:  # the oracle's self-play once
                table = table.select((table.policy_a != ORACLE) | (table.policy_b != ORACLE))
            tables.append(table)
            _log(
                log,
                f"{variant}: {len(group)} {algo} seeds + oracle partner, every pair, on the "
                f"{LEVEL_SET_TITLES[level_set]}: {len(table)} episodes in {time.perf_counter() - t0:.0f}s",
            )
    return EpisodeTable.concat(tables)


def evaluation_key(mode: Mode, variant: str, manifest: Path) -> dict[str, Any]:
    """What a variant's results depend on: the evaluation settings and every zoo entry (its checkpoint and
    the state's SHA-256 that `cec zoo build` pinned)."""
    from cec.agents.zoo import load_zoo

    entries = [[e.name, e.seed, str(e.checkpoint), e.sha256] for e in load_zoo(manifest)]
    return {
        "variant": variant,
        "episodes": mode.episodes,
        "generated_levels": mode.generated_levels,
        "zoo": sorted(entries, key=str),
    }


def cached_evaluation(mode: Mode, variant: str, manifest: Path, vdir: Path, *, log: TextIO) -> Any:
    """`evaluate_variant`, or the table an earlier invocation wrote (`vdir/results.csv`) when nothing it
    depends on has changed (`evaluation_key`); see `apps.reproduce.common.cached_table`."""
    from apps.reproduce.common import cached_table

    key = evaluation_key(mode, variant, manifest)
    play = lambda: evaluate_variant(mode, variant, manifest, log=log)  # noqa: E731
    return cached_table(vdir, key, play, label=f"{variant}: ", log=log)


@dataclass(frozen=True)
class TrainingStats:
    """What an algorithm's training run of one variant recorded in its metrics.

    Attributes:
        seeds: seeds trained; env_steps: per seed.
        seconds: training time of the run (its updates' env steps over their env steps/s; compilation and
            checkpointing not included), also when this invocation skipped the finished run.
        final_return: normalised training return at the end (mean over seeds of the last 5 updates), with
            the partner it trained with (itself; FCP: its population).
    """

    seeds: int
    env_steps: int
    seconds: float
    final_return: float


def training_stats(zoo_dir: Path) -> dict[str, TrainingStats]:
    """Per algorithm, from `zoo_dir/runs/<algorithm>-s<first seed>/metrics.jsonl`."""
    out = {}
    for metrics in sorted(zoo_dir.glob("runs/*/metrics.jsonl")):
        algo = metrics.parent.name.rsplit("-s", 1)[0]
        rows = [json.loads(line) for line in metrics.read_text().splitlines() if line.strip()]
        if algo not in ALGORITHMS or not rows:
            continue
        seeds = sorted({r["seed"] for r in rows})
        per_update = {r["update"]: r for r in rows}
        steps = [r["env_steps"] for r in sorted(per_update.values(), key=lambda r: r["update"])]
        step_sizes = np.diff([0, *steps])
        seconds = sum(
            len(seeds) * size / max(r.get("env_steps_per_s") or math.inf, 1e-9)
            for size, r in zip(
                step_sizes, sorted(per_update.values(), key=lambda r: r["update"]), strict=True
            )
        )
        last = sorted(per_update)[-5:]
        final = [r["normalised_return"] for r in rows if r["update"] in last and "normalised_return" in r]
        out[algo] = TrainingStats(
            len(seeds), int(steps[-1]), float(seconds), float(np.mean(final)) if final else math.nan
        )
    return out


# ---------------------------------------------------------------------------------------------------------
# SUMMARY
# ---------------------------------------------------------------------------------------------------------


@dataclass(frozen=True)
class Score:
    """One algorithm's score of one kind on one level set of one variant.

    Attributes:
        mean, sem: over the samples (NaN when there are none / fewer than 2).
        n_seeds: the algorithm's seeds; n: the samples, one per seed (`xp`: the seed's mean with the other
            seeds, `cec.evaluation.stats.seed_means`; `sp`: with itself; `oracle`: with the oracle).
        samples: the samples themselves (normalised scores); tests compare them, seeds being the units.
    """

    mean: float
    sem: float
    n_seeds: int
    n: int
    samples: tuple[float, ...]


def summarise(table: Any, variant: str) -> dict[str, dict[str, dict[str, Score]]]:
    """{level set: {kind: {algorithm: Score}}} with kinds `xp` (per seed, its mean with the algorithm's
    other seeds: the paper's measure, with seeds as the units), `sp` (each seed with itself) and `oracle`
    (each seed with the oracle partner); the oracle partner's own self-play is under `sp` as `oracle`."""
    from cec.evaluation import analysis as an
    from cec.evaluation.stats import seed_means, sem

    out: dict[str, dict[str, dict[str, Score]]] = {}
    for level_set in LEVEL_SETS:
        names = sorted(
            {str(n) for n in table.level if (n == fixed_level_name(variant)) == (level_set == "fixed")}
        )
        if not names:
            continue
        pl = an.pair_level_scores(table, names)
        m = an.pair_scores(pl)
        seeds = {a: [i for i, p in enumerate(pl.policies) if p.algorithm == a] for a in (*ALGORITHMS, ORACLE)}
        kinds: dict[str, dict[str, Score]] = {"xp": {}, "sp": {}, "oracle": {}}
        for algo, idx in seeds.items():
            if not idx:
                continue
            xp = [x for x in seed_means(m[np.ix_(idx, idx)]) if not math.isnan(x)]  # seeds: the units
            sp = [m[i, i] for i in idx if not math.isnan(m[i, i])]
            with_oracle = [m[i, o] for i in idx for o in seeds[ORACLE] if not math.isnan(m[i, o])]
            for kind, vals in (("xp", xp), ("sp", sp), ("oracle", with_oracle)):
                if vals and not (kind == "oracle" and algo == ORACLE):
                    arr = np.asarray(vals, np.float64)
                    kinds[kind][algo] = Score(
                        float(arr.mean()), sem(arr), len(idx), arr.size, tuple(arr.tolist())
                    )
        out[level_set] = kinds
    return out


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


def check_claims(summaries: dict[str, dict[str, dict[str, dict[str, Score]]]]) -> list[ClaimResult]:
    """Every `CLAIMS` ordering present in `summaries`: holds = better's mean > worse's mean; significant =
    holds and two-sided p < ALPHA."""
    from cec.evaluation.stats import compare

    out = []
    for variant, level_set, better, worse in CLAIMS:
        xp = summaries.get(variant, {}).get(level_set, {}).get("xp", {})
        if better not in xp or worse not in xp:
            continue
        c = compare(np.asarray(xp[better].samples), np.asarray(xp[worse].samples))
        holds = c.diff > 0
        out.append(
            ClaimResult(
                variant, level_set, better, worse, c.diff, c.ci_low, c.ci_high, c.p, holds,
                bool(holds and not math.isnan(c.p) and c.p < ALPHA),
            )
        )  # fmt: skip
    return out


# ---------------------------------------------------------------------------------------------------------
# REPORT
# ---------------------------------------------------------------------------------------------------------


def machine_info() -> dict[str, Any]:
    """The machine the command ran on: host, CPU model, cores, JAX device, load average."""
    return _machine_info(load_average=True)


def _pm(s: Score | None) -> str:
    if s is None:
        return "—"
    err = "" if math.isnan(s.sem) else f" ± {s.sem:.3f}"
    return f"{s.mean:.3f}{err}"


def _paper_cell(p: PaperNumber | None) -> str:
    if p is None:
        return "not reported"
    if p.mean is None:
        return f"({p.text})"
    return f"{p.mean:.3f}" + (f" ± {p.sem:.3f}" if p.sem is not None else "")


def _verdict(ours: Score | None, p: PaperNumber | None) -> str:
    if ours is None or p is None or p.mean is None:
        return ""
    d = ours.mean - p.mean
    return f"{d:+.3f}" + ("" if abs(d) <= TOLERANCE else f" (differs by {abs(d):.3f} > {TOLERANCE})")


def bar_plot(summary: dict[str, dict[str, dict[str, Score]]], variant: str, path: Path) -> Path:
    """The paper's bar figure for one variant: XP per algorithm on both task sets, standard error bars,
    the paper's values as black markers, the oracle's ceiling on the fixed task dashed."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    width = 0.26
    for k, algo in enumerate(ALGORITHMS):
        xs, means, errs = [], [], []
        for i, level_set in enumerate(LEVEL_SETS):
            s = summary.get(level_set, {}).get("xp", {}).get(algo)
            if s is None:
                continue
            xs.append(i + (k - 1) * width)
            means.append(s.mean)
            errs.append(0.0 if math.isnan(s.sem) else s.sem)
            p = paper_number(variant, level_set, algo)
            if p is not None and p.mean is not None:
                ax.plot([i + (k - 1) * width], [p.mean], "k_", markersize=18, mew=2)
        ax.bar(xs, means, width, yerr=errs, capsize=3, label=algo.upper())
    ax.axhline(ORACLE_FIXED, xmin=0.02, xmax=0.48, ls="--", color="grey", lw=1)
    ax.plot([], [], "k_", markersize=12, mew=2, label="paper")
    ax.set_xticks(range(len(LEVEL_SETS)), [LEVEL_SET_TITLES[s] for s in LEVEL_SETS])
    ax.set_ylabel("normalised cross-play (unseen seeds)")
    ax.set_title(f"Dual Destination, {VARIANT_TITLES[variant].lower()}")
    ax.set_ylim(min(-0.1, ax.get_ylim()[0]), 1.05)
    ax.axhline(0, color="k", lw=0.5)
    ax.plot([], [], ls="--", color="grey", lw=1, label="oracle")
    ax.legend(fontsize=8, ncols=5, loc="upper center", bbox_to_anchor=(0.5, -0.1), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def write_report(
    out: Path,
    mode: Mode,
    summaries: dict[str, dict[str, dict[str, dict[str, Score]]]],
    meta: dict[str, Any],
) -> Path:
    """Writes `report.md`, `summary.json` and one bar plot per variant into `out`; returns the report."""
    out.mkdir(parents=True, exist_ok=True)
    claims = check_claims(summaries)
    md: list[str] = [f"# Dual Destination: the paper's results reproduced ({mode.name} version)\n"]
    m = meta["machine"]
    md.append(
        f"Command: `{meta['command']}`. Machine: {m['cpu']} ({m['cpu_count']} cores, {m['device']}), host "
        f"`{m['host']}`, load average at the start {m.get('load_average_start')} and at the end "
        f"{m.get('load_average_1_5_15min')} (1/5/15 min). Date {meta['date']}, git {meta['git']}, "
        f"JAX {m['jax']}. Wall time {meta['wall_s'] / 60:.1f} min "
        f"(training {meta['train_s'] / 60:.1f}, evaluation {meta['eval_s'] / 60:.1f}).\n"
    )
    if meta.get("skipped_runs"):
        md.append(
            f"Training runs found finished by an earlier invocation and not trained again: "
            f"{', '.join(meta['skipped_runs'])} (their training time is in the Training section).\n"
        )
    md.append(
        "Score: the paper's normalised score, return / (2 x 100 steps); the oracle reaches 0.955 on the "
        "fixed task. **XP** (the paper's measure, zero-shot coordination): per seed, the mean score with "
        "each other seed of its algorithm (both seat orders, all episodes, all levels of the set), then the "
        "mean over seeds; ± is the standard error over seeds (the independent units: pairs share seeds). "
        "The multi-task variant's fixed task is its two-pair layout. CEC never trains on either task set "
        "(both fixed tasks and the 100 generated evaluation tasks are excluded from its generator).\n"
    )
    budget = ", ".join(
        f"{a.upper()} {len(mode.seeds[a])} seeds x {mode.steps['full_obs'][a]:,} steps ({mode.presets[a]})"
        for a in ALGORITHMS
    )
    md.append(
        f"Budget per variant: {budget}; partial-obs and multi-task steps: "
        + "; ".join(
            f"{v}: " + ", ".join(f"{a} {mode.steps[v][a]:,}" for a in ALGORITHMS) for v in VARIANTS[1:]
        )
        + f". Episodes per pair, seat order and level: {mode.episodes['fixed']} on the fixed task, "
        f"{mode.episodes['generated']} on each of {min(mode.generated_levels, 100)} held-out generated "
        "tasks. FCP's population: every IPPO seed at its first, middle and last milestone.\n"
    )
    md.append("## Our numbers beside the paper's\n")
    missing = [VARIANT_TITLES[v] for v in VARIANTS if v not in summaries]
    if missing:
        md.append(f"Not run for this report: {', '.join(missing)} (`--variants`).\n")
    md.append("| variant | task set | algorithm | ours: XP mean ± SE | seeds | paper | ours − paper |")
    md.append("|---|---|---|---|---|---|---|")
    for variant in [v for v in VARIANTS if v in summaries]:
        for level_set in LEVEL_SETS:
            for algo in ALGORITHMS:
                s = summaries.get(variant, {}).get(level_set, {}).get("xp", {}).get(algo)
                p = paper_number(variant, level_set, algo)
                n = "—" if s is None else str(s.n)
                where = f"| {VARIANT_TITLES[variant]} | {LEVEL_SET_TITLES[level_set]} | {algo.upper()} |"
                md.append(f"{where} {_pm(s)} | {n} | {_paper_cell(p)} | {_verdict(s, p)} |")
    md.append("")
    md.append("## The paper's orderings\n")
    md.append(
        f"Welch two-sided t-test on the per-seed XP and a 95% bootstrap interval of the difference; "
        f"*significant* = the ordering holds and p < {ALPHA}.\n"
    )
    md.append("| variant | task set | ordering | difference [95% CI] | p | holds | significant |")
    md.append("|---|---|---|---|---|---|---|")
    for c in claims:
        p_text = "—" if math.isnan(c.p) else f"{c.p:.2g}"
        ci = "—" if math.isnan(c.ci_low) else f"[{c.ci_low:+.3f}, {c.ci_high:+.3f}]"
        md.append(
            f"| {VARIANT_TITLES[c.variant]} | {LEVEL_SET_TITLES[c.level_set]} | {c.better.upper()} > "
            f"{c.worse.upper()} | {c.diff:+.3f} {ci} | {p_text} | {'yes' if c.holds else '**no**'} | "
            f"{'yes' if c.significant else 'no'} |"
        )
    md.append("")
    held = sum(c.holds for c in claims)
    sig = sum(c.significant for c in claims)
    md.append(f"{held} of {len(claims)} orderings hold, {sig} of them significantly.\n")
    failed = [ordering_reason(c, summaries[c.variant][c.level_set]) for c in claims if not c.holds]
    if failed:
        md.append("Where an ordering does not hold, what the same seeds' self-play (SP) shows:\n")
        md.extend(failed)
        md.append("")
    cec_full = [
        (
            ls,
            summaries.get("full_obs", {}).get(ls, {}).get("xp", {}).get("cec"),
            paper_number("full_obs", ls, "cec"),
        )
        for ls in LEVEL_SETS
    ]
    lines = []
    for ls, s, p in cec_full:
        if s is not None and p is not None and p.mean is not None:
            ok = abs(s.mean - p.mean) <= TOLERANCE
            lines.append(
                f"- CEC, fully observable, {LEVEL_SET_TITLES[ls]}: {s.mean:.3f} vs the paper's {p.mean:.3f}: "
                + ("within" if ok else f"**not within** (by {abs(s.mean - p.mean):.3f})")
                + f" {TOLERANCE}."
            )
    if lines:
        md.append("## CEC, fully observable, against the paper's values\n")
        md.extend(lines)
        md.append("")
    md.append("## Where our numbers differ from the paper's by more than 0.05\n")
    diffs = []
    for variant in VARIANTS:
        for level_set in LEVEL_SETS:
            for algo in ALGORITHMS:
                s = summaries.get(variant, {}).get(level_set, {}).get("xp", {}).get(algo)
                p = paper_number(variant, level_set, algo)
                if (
                    s is not None
                    and p is not None
                    and p.mean is not None
                    and abs(s.mean - p.mean) > TOLERANCE
                ):
                    kinds = summaries[variant][level_set]
                    diffs.append(
                        f"- {VARIANT_TITLES[variant]}, {LEVEL_SET_TITLES[level_set]}, {algo.upper()}: "
                        f"{s.mean:.3f} vs {p.mean:.3f} ({s.mean - p.mean:+.3f}). "
                        + difference_reason(
                            s,
                            p.mean,
                            kinds.get("sp", {}).get(algo),
                            kinds.get("oracle", {}).get(algo),
                            trained_on_set=algo == "cec" or level_set == "fixed",
                        )
                    )
    md.extend(diffs or ["None."])
    md.append("")
    if diffs:
        md.append(meta.get("why", _default_why(mode)))
        md.append("")
    if meta.get("training"):
        md.append("## Training\n")
        md.append(
            "From each run's metrics (also for runs this invocation found finished and skipped): the "
            "training time (env steps over env steps/s of each update, without compilation) and the "
            "normalised training return at the end (last 5 updates, mean over seeds; IPPO and CEC in "
            "self-play, on the fixed task and on generated tasks; FCP with its population, untrained "
            "first milestones included).\n"
        )
        md.append("| variant | algorithm | seeds | env steps per seed | training time | return at the end |")
        md.append("|---|---|---|---|---|---|")
        for variant, per in meta["training"].items():
            for algo in ALGORITHMS:
                t = per.get(algo)
                if t is not None:
                    md.append(
                        f"| {VARIANT_TITLES[variant]} | {algo.upper()} | {t['seeds']} | {t['env_steps']:,} | "
                        f"{t['seconds'] / 60:.1f} min | {t['final_return']:.3f} |"
                    )
        md.append("")
    md.append("## Reference points: self-play and the oracle partner\n")
    md.append(
        "SP: each seed with itself. With oracle: each seed with the scripted oracle partner (`dd_oracle`: "
        "the oracle's joint plan until the partner shows a choice, then a best response to it; docs/"
        "dual_destination.md); mean ± SE over seeds. The oracle partner with itself scores the oracle's "
        "return with the full view.\n"
    )
    md.append("| variant | task set | algorithm | SP | with oracle partner |")
    md.append("|---|---|---|---|---|")
    for variant in VARIANTS:
        for level_set in LEVEL_SETS:
            kinds = summaries.get(variant, {}).get(level_set, {})
            for algo in (*ALGORITHMS, ORACLE):
                sp, wo = kinds.get("sp", {}).get(algo), kinds.get("oracle", {}).get(algo)
                if sp is None and wo is None:
                    continue
                md.append(
                    f"| {VARIANT_TITLES[variant]} | {LEVEL_SET_TITLES[level_set]} | {algo} | {_pm(sp)} | "
                    f"{'—' if algo == ORACLE else _pm(wo)} |"
                )
    md.append("")
    md.append("## Bar plots\n")
    for variant in VARIANTS:
        if variant in summaries:
            name = f"bars_{variant}.png"
            bar_plot(summaries[variant], variant, out / name)
            md.append(f"![{VARIANT_TITLES[variant]}]({name})\n")
    md.append("## Timings\n")
    md.append("| stage | seconds |")
    md.append("|---|---|")
    md.extend(f"| {k} | {v:.0f} |" for k, v in meta.get("stages", {}).items())
    md.append("")
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")
    (out / "summary.json").write_text(
        json.dumps(
            {
                "meta": meta,
                "mode": {
                    "name": mode.name,
                    "seeds": mode.seeds,
                    "steps": mode.steps,
                    "episodes": mode.episodes,
                },
                "summaries": {
                    v: {
                        ls: {k: {a: s.__dict__ for a, s in d.items()} for k, d in kinds.items()}
                        for ls, kinds in per.items()
                    }
                    for v, per in summaries.items()
                },  # fmt: skip
                "claims": [c.__dict__ for c in claims],
                "paper": [p.__dict__ for p in PAPER],
            },
            indent=1,
            default=float,
        )
        + "\n"
    )
    return path


#: SP above XP by more than this: the seeds learned the task but do not play one convention.
CONVENTION_GAP = 0.1


def difference_reason(
    xp: Score, paper: float, sp: Score | None, oracle: Score | None, *, trained_on_set: bool = True
) -> str:
    """What the other measures of the same seeds say about an XP score that differs from the paper's:
    whether the seeds learned the task at all (SP), whether they fail only with each other (SP well above
    XP), and how they play with the oracle partner (a best response to whatever they do)."""
    facts = []
    if sp is not None:
        facts.append(f"with themselves (SP) its seeds score {sp.mean:.3f}")
    if oracle is not None:
        facts.append(f"with the oracle partner {oracle.mean:.3f}")
    said = ("Reading: " + " and ".join(facts) + "; ") if facts else "Reading: "
    if not trained_on_set:
        return said + (
            "it never trained on these tasks and fails on them, as in the paper; a policy that never "
            "reaches a goal pair scores -0.5 on our scale (return / 200 with a step cost of -1), where the "
            "paper reports about 0 for the same failure, so this gap looks like one of scale."
        )
    if sp is not None and sp.mean - xp.mean > CONVENTION_GAP:
        return said + (
            "the seeds learned the task but settled on conventions that do not match across seeds, so "
            "the gap is in coordination with unseen partners, not in skill."
        )
    if sp is not None and sp.mean < paper - TOLERANCE:
        return said + (
            "they play about as badly with themselves, so at this budget the policy has not learned the "
            "task set to the paper's level (see the Training section)."
        )
    if xp.mean > paper:
        return said + "ours is higher: these seeds coordinate with each other better than the paper's did."
    return said + "the seeds play well with themselves and each other but below the paper's value."


def ordering_reason(claim: ClaimResult, kinds: dict[str, dict[str, Score]]) -> str:
    """One line on a failed ordering `better > worse`: whether `worse` coordinates with unseen seeds about
    as well as with itself (the coordination failure the ordering rests on did not occur) and whether
    `better` learned the task as well as `worse` did (SP)."""
    xp, sp = kinds.get("xp", {}), kinds.get("sp", {})
    b, w = claim.better, claim.worse
    head = (
        f"- {VARIANT_TITLES[claim.variant]}, {LEVEL_SET_TITLES[claim.level_set]}, {b.upper()} > {w.upper()}: "
    )
    if b not in sp or w not in sp:
        return head + "no self-play scores to compare."
    parts = [
        f"{w.upper()} XP {xp[w].mean:.3f} vs SP {sp[w].mean:.3f}, {b.upper()} XP {xp[b].mean:.3f} vs SP "
        f"{sp[b].mean:.3f}"
    ]
    if sp[w].mean - xp[w].mean <= CONVENTION_GAP:
        parts.append(
            f"{w.upper()}'s seeds coordinate with each other about as well as with themselves, so the "
            "failure with unseen partners that the paper's ordering rests on did not occur"
        )
    if sp[b].mean < sp[w].mean - TOLERANCE:
        parts.append(f"{b.upper()} also plays the task less well with itself than {w.upper()} does")
    return head + "; ".join(parts) + "."


def _default_why(mode: Mode) -> str:
    if mode.name == "quick":
        return (
            "Why: this is the reduced version, sized to finish within 30 minutes on a 2-core CPU: per seed "
            "2.56e5 (IPPO, FCP) and 7.68e5 (CEC) env steps with small networks, against the paper's 1e8-3e8 "
            "steps with its larger network, and 3 seeds per algorithm (3 XP pairs). The Training section "
            "shows how far each algorithm got: where CEC's training return at the end is still low, its "
            "policy has not yet learned the generated tasks (its learning takes off between about 6e5 and "
            "1.5e6 steps per seed on this setting), and its XP numbers measure an untrained policy. The "
            "quick version checks the pipeline, not the paper's values."
        )
    if mode.name == "full":
        return (
            "Why, in general: this version is sized for a CPU (docs/reproduce.md): one CNN without an LSTM "
            "for all three algorithms and 5e5-2e6 env steps per seed, against the paper's CNN + LSTM and "
            "1e8-3e8 steps. Each line above says what the same seeds' self-play and oracle-partner scores "
            "show."
        )
    return (
        "Why: this version has the paper's networks and budgets, so a difference is in what the seeds "
        "learned; each line above says what their self-play and oracle-partner scores show."
    )


# ---------------------------------------------------------------------------------------------------------
# THE COMMAND
# ---------------------------------------------------------------------------------------------------------


def reproduce_dual_destination(
    mode: Mode,
    out: Path,
    work: Path,
    *,
    variants: Sequence[str] = VARIANTS,
    progress: bool = True,
    log: TextIO = sys.stderr,
    command: str = "",
) -> Path:
    """Trains, evaluates and reports (see the module docstring); returns the report's path."""
    t_start = time.perf_counter()
    load_start = machine_info()["load_average_1_5_15min"]
    stages: dict[str, float] = {}
    summaries = {}
    trained: dict[str, dict[str, Any]] = {}
    skipped_runs: list[str] = []
    train_s = eval_s = 0.0
    for variant in variants:
        t0 = time.perf_counter()
        _log(log, f"{variant}: training (cec zoo build into {work / variant / 'zoo'})")
        manifest, finished = train_variant(mode, variant, work, progress=progress, log=log)
        skipped_runs += [f"{variant}/{name}" for name in finished]
        stages[f"{variant}: train"] = time.perf_counter() - t0
        train_s += stages[f"{variant}: train"]
        t0 = time.perf_counter()
        table = cached_evaluation(mode, variant, manifest, work / variant, log=log)
        summaries[variant] = summarise(table, variant)
        trained[variant] = {a: t.__dict__ for a, t in training_stats(manifest.parent).items()}
        stages[f"{variant}: evaluate"] = time.perf_counter() - t0
        eval_s += stages[f"{variant}: evaluate"]
    machine = machine_info()
    machine["load_average_start"] = load_start
    meta = {
        "command": command or command_of(mode),
        "date": datetime.date.today().isoformat(),
        "git": code_version(short=True),
        "machine": machine,
        "wall_s": time.perf_counter() - t_start,
        "train_s": train_s,
        "eval_s": eval_s,
        "stages": stages,
        "training": trained,
        "skipped_runs": skipped_runs,
        "work": str(work),
    }
    path = write_report(out, mode, summaries, meta)
    _log(log, f"wrote {path}")
    return path


def command_of(mode: Mode) -> str:
    """The command line that runs `mode` (the full version has no flag)."""
    return "cec reproduce dual-destination" + ("" if mode.name == "full" else f" --{mode.name}")


def _print_plan(mode: Mode, variants: Sequence[str], work: Path, out: Path, file: TextIO) -> None:
    lines = plan_lines(mode, variants)
    print(f"cec reproduce dual-destination ({mode.name}): work {work}, report {out}", file=file)
    print(
        f"{'variant':12s} {'algorithm':9s} {'seeds':>5s} {'steps/seed':>12s} {'updates':>8s} "
        f"{'estimate':>10s}",
        file=file,
    )
    for ln in lines:
        est = "?" if math.isnan(ln.estimate_s) else duration(ln.estimate_s)
        print(
            f"{ln.variant:12s} {ln.algorithm:9s} {ln.seeds:5d} {ln.env_steps:12,d} {ln.updates:8d} "
            f"{est:>10s}",
            file=file,
        )
    total = sum(ln.estimate_s for ln in lines)
    basis = f" (from seconds per update measured on {mode.measured_on})" if mode.measured_on else ""
    print(f"training total: {'?' if math.isnan(total) else duration(total)}{basis}", file=file)
    print(
        "evaluation: XP within each algorithm and everyone with the oracle partner, "
        f"{mode.episodes['fixed']} episodes on the fixed task and {mode.episodes['generated']} on each of "
        "100 generated tasks",
        file=file,
    )


def _cmd_reproduce_dd(args: argparse.Namespace) -> int:
    if args.quick and args.paper:
        raise ConfigError("--quick and --paper are two versions: give one of them, or neither (the full one)")
    mode = QUICK if args.quick else PAPER_SCALE if args.paper else FULL
    work = Path(args.work or ROOT / "runs" / "reproduce" / f"dual_destination-{mode.name}")
    out = Path(args.out or ROOT / "benchmarks" / "results" / "dual_destination" / mode.name)
    variants = tuple(args.variants.split(",")) if args.variants else mode.variants
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ConfigError(f"unknown variant(s) {unknown}; choose from {list(VARIANTS)}")
    if args.plan:
        _print_plan(mode, variants, work, out, sys.stdout)
        return 0
    command = command_of(mode)
    command += f" --variants {','.join(variants)}" if args.variants else ""
    command += "".join(f" --{k} {getattr(args, k)}" for k in ("work", "out") if getattr(args, k))
    path = reproduce_dual_destination(
        mode, out, work, variants=variants, progress=not args.quiet, command=command
    )
    print(f"wrote {path}")
    return 0


def add_subcommand(rep_sub: Any) -> None:
    """Registers `dual-destination` on the `cec reproduce` subparsers."""
    dd = rep_sub.add_parser(
        "dual-destination",
        help="train IPPO, FCP and CEC on the Dual Destination variants, cross-play, report beside the paper",
    )
    dd.add_argument(
        "--quick", action="store_true", help="the reduced version (under 30 minutes on a 2-core CPU)"
    )
    dd.add_argument(
        "--paper",
        action="store_true",
        help="the paper's networks and budgets (1e8-3e8 steps per seed: a GPU job; see --plan)",
    )
    dd.add_argument(
        "--plan", action="store_true", help="print what would run and its expected time, then exit"
    )
    dd.add_argument(
        "--work", help="runs, zoos and result tables (default runs/reproduce/dual_destination-MODE)"
    )
    dd.add_argument("--out", help="report folder (default benchmarks/results/dual_destination/MODE)")
    dd.add_argument(
        "--variants",
        help=f"comma-separated subset of {','.join(VARIANTS)} (default: all; --quick: full_obs)",
    )
    dd.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    dd.set_defaults(func=_cmd_reproduce_dd)
