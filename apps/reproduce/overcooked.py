"""`cec reproduce overcooked [--quick | --cpu | --paper]`: CEC on Overcooked against the paper's baselines.

    cec reproduce overcooked --plan      # every training run, its size and the time it takes here
    cec reproduce overcooked --quick     # the pipeline end to end at a small budget (minutes)
    cec reproduce overcooked             # the CPU version (--cpu): the recipe of docs/reproduce_overcooked.md
    cec reproduce overcooked --paper     # the paper's networks and budgets (a GPU job)

1. **Train** (`cec zoo build`: finished runs are skipped, interrupted ones resumed, so the same command
   continues after any interruption) CEC seeds on the procedural generator (the 100 held-out kitchens and
   the five classic ones excluded), CEC-E3T seeds (the same with E3T's partner), and on each classic
   kitchen IPPO seeds, FCP seeds (population: the IPPO seeds of that kitchen at their first, middle and
   last checkpoints), E3T seeds, and CEC-Finetune from each CEC seed. Every algorithm has the CEC recipe's
   network, so that only the training differs.
2. **Evaluate** (`cec.evaluation.crossplay`, common random numbers, both seat orders, 400-step episodes)
   every agent with every other (cross-play: two seeds of one algorithm, partners they never met; ad hoc:
   two algorithms), with itself (self-play) and with the scripted cook (`cook`, a partner none of them
   trained with), on the five classic kitchens and on the 100 held-out kitchens; on the classic kitchens
   also with the human proxies (`--proxies`, default the shipped `hp_<kitchen>`: behaviour-cloned from
   recorded human games, each in its own kitchen). A single-kitchen agent meets others on its own kitchen
   among the classic ones; on the held-out kitchens each kitchen's agents meet each other and the
   generator-trained agents (`lineups`).
3. **Report** `report.md` + `summary.json`: per level set and algorithm the mean team return over seeds
   (each seed's mean over its partners first: seeds are the independent units), SP beside XP beside the
   cook and the human proxies, the paper's values (`paper_overcooked.yaml`, read off its figures) and its
   human study's ordering beside ours, Welch tests of CEC against each baseline on per-seed XP and score
   with the proxies, the cross-algorithm matrices, held-out play by training kitchen, what the failing
   baselines did in training, learning curves (PNG) and a GIF of two CEC seeds in a held-out kitchen;
   `crossplay/report.md` is `cec report` of the agents' table (seed matrices, heatmaps, the meta-game).

The work directory (`--work`, default `runs/reproduce/overcooked-<mode>`) holds the zoo (`zoo/`), its spec
and the result tables; the report goes to `--out` (default `benchmarks/results/overcooked/<mode>`).

Size: one command's pipeline (plan, train, evaluate, summarise, report) in the order it runs; the
numbers it compares with are data (`paper_overcooked.yaml`).
"""

from __future__ import annotations

import argparse
import dataclasses
import functools
import json
import math
import shutil
import sys
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, TextIO

import numpy as np
import yaml

from apps.machine import duration, machine_info
from apps.reproduce import pipeline
from apps.reproduce.pipeline import play_seconds, read_metrics, results_file, train_seconds
from cec.agents.zoo import HUMAN_PROXY, SHIPPED
from cec.checkpoints import code_version
from cec.config import ConfigError
from cec.evaluation.curves import metrics_file
from cec.levels.classic import CLASSIC_ASCII
from cec.training.config import ALGORITHMS as TRAINING

ROOT = Path(__file__).resolve().parents[2]
PAPER_FILE = Path(__file__).with_name("paper_overcooked.yaml")
KITCHENS = tuple(CLASSIC_ASCII)
ALGORITHMS = ("cec", "cec_e3t", "cec_finetune", "e3t", "fcp", "ippo")
# as the trainer defines them: trained on the generator (they play every kitchen; the others one each), and
# trained with themselves as the partner
GENERALISTS = tuple(a for a in ALGORITHMS if TRAINING[a][1])
SELF_PLAY = tuple(a for a in ALGORITHMS if TRAINING[a][0] == "self_play")
UNTRAINED, NOOP = "untrained", "noop"  # the controls: partners that learned nothing (`control_policies`)
TITLES = {
    "cec": "CEC", "cec_e3t": "CEC-E3T", "cec_finetune": "CEC-Finetune", "e3t": "E3T", "fcp": "FCP",
    "ippo": "IPPO",
    UNTRAINED: "control: untrained CEC network", NOOP: "control: no-op agent",
}  # fmt: skip
COOK = "cook"
LEVEL_SETS = ("classic", "heldout")
EVAL_STEPS = 400  # the paper's episode length; its absolute scores need it
ALPHA = 0.05
MEASURED_ON = "the CEC CPU preset, one seed, 2-core AMD EPYC, both cores busy (2.4k steps/s), 2026-11-22"
TTS_MEASURED_ON = (
    "the CPU zoo's runs of the time-to-skill preset, four seeds per process, each run's median env-steps/s "
    "(metrics.csv), 2-core Intel Xeon, both cores busy, 2026-11-28; CEC-Finetune not measured, taken as IPPO "
    "(self-play on one kitchen, the same network and episodes)"
)
MACHINE_FILE = "machine.json"  # the machine and commit that trained and played, in the work folder
TABLE_HEAD = (
    "| algorithm | self-play | cross-play (unseen partners) | XP / SP | with the cook | with human proxies "
    "| paper (XP) |"
)
#: The paper's human study (score with real people on Counter Circuit and Coordination Ring, its Q3).
HUMAN_STUDY = (
    "E3T ahead; CEC and CEC-Finetune next; FCP and IPPO behind (CEC ahead of FCP, p < 0.001). People "
    "rated CEC and CEC-Finetune the better partners on all seven subjective measures."
)


@dataclass(frozen=True)
class Mode:
    """One version of the reproduction.

    Attributes:
        name: `quick`, `cpu` or `paper`.
        preset: the CEC preset; every algorithm trains this network (the baselines with overrides).
        seeds: per algorithm; CEC-Finetune fine-tunes each CEC seed (its seeds are the CEC seeds + 100).
        steps: env steps per seed and algorithm (per kitchen for the single-kitchen ones).
        kitchens: the classic kitchens the single-kitchen baselines train on.
        episodes: evaluation episodes per pairing, seat order and level, per level set.
        finetune: overrides of CEC-Finetune (on top of the CEC preset).
        tuned: per algorithm, overrides its tuning probes chose (on top of the preset; docs/
            reproduce_overcooked.md, "Tuning the baselines").
        seconds_per_update: per algorithm, measured seconds of one update of one seed (the basis of
            `--plan`).
        measured_on: where and how they were measured.
        episodes_per_s: measured evaluation episodes (`EVAL_STEPS` steps) per second, per part of
            `planned_episodes` (each level set, the controls, the curves; the basis of `--plan`'s
            cross-play estimate); `eval_measured_on`: where and how.
        overrides: applied to every run (a tiny network in tests).
        generated_levels: held-out generated kitchens played (fewer only in tests).
        proxies: a zoo manifest (or `shipped`) whose `human_proxy` entries play every agent on the classic
            kitchens ('' none); they must have the agents' network (`cec humans bc --preset`).
    """

    name: str
    preset: str
    seeds: dict[str, tuple[int, ...]]
    steps: dict[str, int]
    kitchens: tuple[str, ...] = KITCHENS
    episodes: dict[str, int] = field(default_factory=lambda: {"classic": 4, "heldout": 1})
    finetune: tuple[str, ...] = ("ppo.lr=0.001",)
    tuned: dict[str, tuple[str, ...]] = field(default_factory=dict)
    seconds_per_update: dict[str, float] = field(default_factory=dict)
    measured_on: str = ""
    episodes_per_s: dict[str, float] = field(default_factory=dict)
    eval_measured_on: str = ""
    overrides: tuple[str, ...] = ()
    generated_levels: int = 100
    proxies: str = SHIPPED


QUICK = Mode(
    name="quick",
    preset="configs/train/cec_overcooked_cpu.yaml",
    seeds={
        "cec": (200, 201),
        "cec_e3t": (400, 401),
        "ippo": (0, 1),
        "fcp": (100,),
        "e3t": (150,),
        "cec_finetune": (300, 301),
    },
    steps={
        "cec": 327_680,
        "cec_e3t": 327_680,
        "ippo": 163_840,
        "fcp": 163_840,
        "e3t": 163_840,
        "cec_finetune": 81_920,
    },  # fmt: skip
    kitchens=("cramped_room",),
    episodes={"classic": 2, "heldout": 1},
    seconds_per_update=dict.fromkeys(ALGORITHMS, 6.8),
    measured_on=MEASURED_ON,
    generated_levels=20,
)

CPU = Mode(
    name="cpu",
    # the recipe chosen by cross-play per core-hour (docs/reproduce_overcooked.md, "Time to skill"): the CPU
    # preset's held-out cross-play at 10.5M steps and 0.38 core-h per seed instead of 15M and about 1.7
    preset="configs/train/cec_overcooked_tts.yaml",
    seeds={
        "cec": (200, 201, 202, 203),
        "cec_e3t": (400, 401, 402, 403),
        "ippo": (0, 1, 2, 3),
        "fcp": (100, 101, 102, 103),
        "e3t": (150, 151, 152, 153),
        "cec_finetune": (300, 301, 302, 303),
    },
    # CEC: the recipe's 1,280 updates; IPPO reached 56 per 128-step episode on Cramped Room at 2M steps
    steps={
        "cec": 10_485_760,
        "cec_e3t": 10_485_760,
        "ippo": 1_966_080,
        "fcp": 1_966_080,
        "e3t": 1_966_080,
        "cec_finetune": 983_040,
    },  # fmt: skip
    episodes={"classic": 4, "heldout": 1},
    # the tuning probes' choice (docs/reproduce_overcooked.md, "Tuning the baselines"): FCP and E3T train on
    # the evaluation's 400-step episodes (FCP: no soup with itself on Cramped Room in 128-step ones; E3T:
    # none on Forced Coordination); IPPO keeps CEC's 128 (its cross-play on Cramped Room fell with 400); all
    # keep CEC's LR and shaping (LR 1e-3 and shaping annealed to 0 did worse for FCP and E3T), and E3T its
    # partner's epsilon 0.55 (0.3 did worse on Counter Circuit)
    tuned={"fcp": ("env.overcooked.max_steps=400",), "e3t": ("env.overcooked.max_steps=400",)},
    seconds_per_update={
        "cec": 1.14,
        "cec_e3t": 0.82,
        "ippo": 1.13,
        "cec_finetune": 1.13,
        "fcp": 1.65,
        "e3t": 0.92,
    },
    measured_on=TTS_MEASURED_ON,
    # the CPU zoo's own evaluation (logs in benchmarks/results/overcooked/cpu/work/logs): classic 13,520
    # episodes in 509 s (before the cook's games were split off, 92a0115), held-out 280,100 in 1,933 s,
    # controls 4,200 in 100 s, curves 16,000 in 136 s
    episodes_per_s={"classic": 26.6, "heldout": 145.0, "controls": 42.0, "curves": 118.0},
    eval_measured_on="the CPU zoo's own evaluation on the 2-vCPU Intel Xeon, both cores, 2026-11-28",
)

PAPER = Mode(
    name="paper",
    preset="configs/train/cec_overcooked.yaml",
    seeds=CPU.seeds,
    steps={
        "cec": 3_000_000_000,
        "cec_e3t": 3_000_000_000,
        "ippo": 100_000_000,
        "fcp": 100_000_000,
        "e3t": 100_000_000,
        "cec_finetune": 100_000_000,
    },  # fmt: skip
    finetune=("ppo.lr=0.00003",),
)

MODES = {"quick": QUICK, "cpu": CPU, "paper": PAPER}


# ---------------------------------------------------------------------------------------------------------
# THE PLAN: one `cec zoo build` spec
# ---------------------------------------------------------------------------------------------------------


def _run_name(algorithm: str, kitchen: str = "") -> str:
    return f"{algorithm}_{kitchen}" if kitchen else algorithm


def zoo_spec(mode: Mode) -> dict[str, Any]:
    """CEC first (the runs CEC-Finetune starts from) and CEC-E3T (the paper's appendix: CEC's kitchens with
    E3T's partner, epsilon 0.5 as the paper sets it there), then per kitchen IPPO, FCP (its population: that
    kitchen's IPPO run), E3T and CEC-Finetune (one run per CEC seed)."""
    preset = str(ROOT / mode.preset)  # absolute: the spec works from any directory
    common = list(mode.overrides)
    cec_seeds = list(mode.seeds["cec"])

    def entry(algo: str, seeds: Sequence[int], overrides: list[str], kitchen: str = "") -> dict[str, Any]:
        return {
            "preset": preset,
            "seeds": list(seeds),
            "name": _run_name(algo, kitchen),
            "overrides": [
                f"total_env_steps={mode.steps[algo]}",
                *overrides,
                *mode.tuned.get(algo, ()),
                *common,
            ],
        }

    cec_e3t = ["algorithm=cec_e3t", "partner.kind=e3t", "partner.epsilon=0.5", "partner.predict_partner=10"]
    entries = [entry("cec", cec_seeds, []), entry("cec_e3t", mode.seeds["cec_e3t"], cec_e3t)]
    for k in mode.kitchens:
        single = [f"env.levels={k}"]
        ippo = mode.seeds["ippo"]
        population = (
            f"[{{run: runs/{_run_name('ippo', k)}-s{ippo[0]}, seeds: {list(ippo)}, "
            "checkpoints: [first, middle, last]}]"
        )
        entries += [
            entry("ippo", ippo, ["algorithm=ippo", *single, "checkpoint.milestones=[0.0,0.5,1.0]"], k),
            entry("fcp", mode.seeds["fcp"], ["algorithm=fcp", *single, "partner.kind=fcp",
                                             f"partner.population={population}"], k),
            entry("e3t", mode.seeds["e3t"], ["algorithm=e3t", *single, "partner.kind=e3t",
                                             "partner.epsilon=0.55", "partner.predict_partner=10"], k),
        ]  # fmt: skip
        for cec_seed, ft_seed in zip(cec_seeds, mode.seeds["cec_finetune"], strict=True):
            start = [f"init_from=runs/cec-s{cec_seeds[0]}", f"init_from_seed={cec_seed}"]
            finetune = ["algorithm=cec_finetune", *start, *single, *mode.finetune]
            entries.append(entry("cec_finetune", [ft_seed], finetune, k))
    return {"entries": entries}


def zoo(mode: Mode, work: Path) -> pipeline.Zoo:
    """The mode's zoo: its spec in `work/spec.yaml`, built into `work/zoo`."""
    return pipeline.Zoo(work, zoo_spec(mode), f"`cec reproduce overcooked` ({mode.name})")


def _generalist_run(mode: Mode, work: Path, algorithm: str) -> Path:
    """The run directory of a generator-trained algorithm's seeds in the work folder."""
    return work / "zoo" / "runs" / f"{_run_name(algorithm)}-s{mode.seeds[algorithm][0]}"


def trained_runs(mode: Mode, work: Path) -> tuple[list[pipeline.PlanLine], list[str]]:
    """The runs of the mode's plan as the work folder trained them, each read from its own `config.yaml`
    (a folder trained by an earlier version of the mode reports the steps it trained, not the mode's
    present ones), and the runs it lacks (without metrics: planning a run makes its folder)."""
    from cec.config import load_config
    from cec.training.config import TrainConfig

    runs, trained, missing = work / "zoo" / "runs", [], []
    for e in zoo_spec(mode)["entries"]:
        run = f"{e['name']}-s{e['seeds'][0]}"
        if not metrics_file(runs / run).is_file():
            missing.append(run)
            continue
        cfg = load_config(TrainConfig, runs / run / "config.yaml")
        size = (cfg.num_seeds, cfg.total_env_steps, cfg.num_updates)
        trained.append(pipeline.PlanLine(run, *size, math.nan, 1.0, algorithm=cfg.algorithm))
    return trained, missing


def plan_lines(mode: Mode, work: Path) -> list[pipeline.PlanLine]:
    """Every run of the mode's zoo, with the estimate from `mode.seconds_per_update` (x seeds) and the
    share of it already trained under `work`."""
    return [
        pipeline.plan_line(r.config.run_name, [r], mode.seconds_per_update.get(r.config.algorithm, math.nan))
        for r in zoo(mode, work).plan()
    ]


def planned_episodes(mode: Mode) -> dict[str, int]:
    """The episodes the evaluation plays, by part: `evaluate`'s on each level set (every line-up with the
    cook, the human proxies on the classic kitchens), the controls' (`evaluate_controls`) and the learning
    curves' (`cached_curves`: every seed pair of each CEC and CEC-E3T checkpoint the preset saves), counted
    as they are played, from the mode alone (nothing loaded)."""
    from cec.agents.policy import Policy
    from cec.agents.zoo import load_zoo
    from cec.config import load_config
    from cec.evaluation.crossplay import plan_games
    from cec.training.config import TrainConfig

    def stand_in(name: str, algorithm: str, levels: tuple[str, ...] | None = None) -> Policy:
        return Policy(name, algorithm, 0, None, None, None, levels)  # type: ignore[arg-type]

    def episodes(lineup: Sequence[Policy], level_set: str, involving: frozenset[str] | None = None) -> int:
        names = level_spec(mode, level_set).split(",")
        games = plan_games(lineup, names, "all", involving)
        return sum(len(g.levels) for g in games) * mode.episodes[level_set]

    agents = [
        stand_in(f"{algo}-{kitchen}-s{s}", algo, (kitchen,) if kitchen else None)
        for algo in ALGORITHMS
        for kitchen in (("",) if algo in GENERALISTS else mode.kitchens)
        for s in mode.seeds[algo]
    ]
    cook = stand_in(COOK, COOK)
    proxies = [
        stand_in(e.name, HUMAN_PROXY, e.levels) for e in (load_zoo(mode.proxies) if mode.proxies else [])
        if e.algorithm == HUMAN_PROXY
    ]  # fmt: skip
    controls = [*(stand_in(f"{UNTRAINED}-s{s}", UNTRAINED) for s in mode.seeds["cec"]), stand_in(NOOP, NOOP)]
    partners = {"classic": [cook, *proxies], "heldout": [cook]}
    counts = {
        level_set: sum(episodes([*lineup, *partners[level_set]], level_set, adds)
                       for lineup, adds in lineups(agents, level_set))
        for level_set in LEVEL_SETS
    }  # fmt: skip
    names = frozenset(c.name for c in controls)
    counts["controls"] = sum(episodes([*controls, cook], level_set, names) for level_set in LEVEL_SETS)
    milestones = set(load_config(TrainConfig, str(ROOT / mode.preset)).checkpoint.milestones) | {1.0}
    counts["curves"] = sum(
        len(milestones) * episodes([stand_in(f"{a}-s{s}", a) for s in mode.seeds[a]], "heldout")
        for a in GENERALISTS
    )
    return counts


# ---------------------------------------------------------------------------------------------------------
# EVALUATE
# ---------------------------------------------------------------------------------------------------------


def level_spec(mode: Mode, level_set: str) -> str:
    if level_set == "classic":
        return ",".join(mode.kitchens)
    return pipeline.generated_levels(mode.generated_levels)


def human_proxies(mode: Mode) -> list[Any]:
    """The `human_proxy` policies of `mode.proxies` (none when it is ''), numbered 0, 1, ... as their seeds:
    result tables tell policies apart by algorithm and seed, and `cec humans bc` gives its `bc_` and `hp_`
    proxies of a kitchen the same training seed."""
    if not mode.proxies:
        return []
    proxies = [
        p for p in pipeline.load_zoo_policies(mode.proxies, mode.proxies) if p.algorithm == HUMAN_PROXY
    ]
    return [dataclasses.replace(p, seed=i) for i, p in enumerate(proxies)]


def eval_config(mode: Mode, level_set: str, seed: int = 0) -> Any:
    """How every policy plays on a level set: the mode's episodes per pair, seat order and kitchen, the
    paper's episode length, common random numbers from `seed` (per level and episode: the same games
    whatever the games per call, 8 on a CPU and 64 on an accelerator, which plays them side by side)."""
    import jax

    from cec.evaluation.crossplay import EvalConfig

    return EvalConfig(
        levels=level_spec(mode, level_set), episodes=mode.episodes[level_set], seed=seed,
        max_steps=EVAL_STEPS, games_per_call=8 if jax.default_backend() == "cpu" else 64,
    )  # fmt: skip


def _eval_key(mode: Mode) -> dict[str, Any]:
    """What a table of `evaluate` or `evaluate_controls` depends on besides its policies."""
    settings = {"episodes": mode.episodes, "kitchens": mode.kitchens, "levels": mode.generated_levels}
    return {**settings, "steps": EVAL_STEPS}


def lineups(policies: Sequence[Any], level_set: str) -> list[tuple[list[Any], frozenset[str] | None]]:
    """Who meets whom on a level set, as (line-up, the names whose games it adds; None: all of them). On
    the classic kitchens one line-up of every agent, each on the kitchens it plays (a single-kitchen agent
    on its own, so it meets that kitchen's agents and the generator-trained ones). On the held-out kitchens
    one line-up per training kitchen: that kitchen's agents, free of their kitchen, with the
    generator-trained ones, whose games without a kitchen's agent the first line-up already has. A seed of
    a single-kitchen algorithm is then, as on the classic kitchens, its agents of every kitchen: the
    result table names a policy by algorithm and seed, and a pair's score averages its kitchens."""
    if level_set == "classic":
        return [(list(policies), None)]
    generalists = [p for p in policies if p.levels is None]
    by_kitchen: dict[tuple[str, ...], list[Any]] = {}
    for p in policies:
        if p.levels is not None:
            by_kitchen.setdefault(tuple(p.levels), []).append(dataclasses.replace(p, levels=None))
    if not by_kitchen:
        return [(generalists, None)]
    return [
        ([*generalists, *agents], None if i == 0 else frozenset(a.name for a in agents))
        for i, agents in enumerate(by_kitchen.values())
    ]


def evaluate(
    mode: Mode, manifest: Path, *, log: TextIO, parts: Path, key: dict[str, Any], seed: int = 0
) -> Any:
    """Per level set, every line-up (`lineups`) with the scripted cook, every pair (XP, SP, ad hoc, with
    the cook), and on the classic kitchens the human proxies, both seat orders -> one `EpisodeTable`.
    Proxies that cannot play with the agents (another network) are the table's skipped entries, with the
    reason. Each line-up's table is kept in `parts/<level set>-<i>` under `key` (`cached_table`) until the
    whole one is written: an interrupted evaluation (the CPU version's line-ups took 6 to 9 minutes
    each on the 2-vCPU Xeon) resumes at the line-up it was playing."""
    from apps.reproduce.pipeline import cached_table
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import eval_levels
    from cec.evaluation.results import EpisodeTable

    policies = pipeline.load_zoo_policies(manifest, str(manifest))
    proxies = human_proxies(mode)
    cook = scripted_policy(COOK, COOK, env=policies[0].env, algorithm=COOK)
    tables = []
    for level_set in LEVEL_SETS:
        config = eval_config(mode, level_set, seed)
        levels = eval_levels("overcooked", config.levels)
        partners = [cook, *proxies] if level_set == "classic" else [cook]
        with_whom = "the cook" + (f" and {len(proxies)} human proxies" if len(partners) > 1 else "")
        where = f"{len(levels.names)} {level_set} kitchens"
        everyone = lineups(policies, level_set)
        for i, (lineup, adds) in enumerate(everyone):
            what = f"{len(lineup)} agents + {with_whom} on {where}"
            play = functools.partial(
                _play_lineup, [*lineup, *partners], levels, config, adds, what=what, log=log
            )
            label = f"{level_set} line-up {i + 1} of {len(everyone)}: "
            tables.append(cached_table(parts / f"{level_set}-{i}", key, play, label=label, log=log))
    return EpisodeTable.concat(tables)


def _play_lineup(players: list[Any], levels: Any, config: Any, adds: Any, *, what: str, log: TextIO) -> Any:
    """One line-up's cross-play (`evaluate`), logged with how many episodes it played and how long it took."""
    from cec.evaluation.crossplay import crossplay

    t0 = time.perf_counter()
    table = crossplay(players, levels, config, involving=adds)
    pipeline.note(log, f"{what}: {len(table)} episodes in {time.perf_counter() - t0:.0f}s")
    return table


def cec_config(mode: Mode, work: Path) -> Any:
    """The config of the work folder's CEC agents: their run's recorded `config.yaml` (a folder trained by
    an earlier version of the mode has that version's network), else the mode's preset."""
    from cec.config import load_config
    from cec.training.config import TrainConfig

    recorded = _generalist_run(mode, work, "cec") / "config.yaml"
    if recorded.is_file():
        return load_config(TrainConfig, recorded)
    return load_config(TrainConfig, str(ROOT / mode.preset), list(mode.overrides))


def control_policies(mode: Mode, cfg: Any) -> list[Any]:
    """The controls beside every score with the cook (and a chance level for XP and SP): the CEC network
    of `cfg` (`cec_config`) at its random initialisation, one per CEC seed (`untrained`), and the agent
    that always stays (`noop`): what the cook delivers with a partner that learned nothing, so that an
    agent's own contribution reads as the difference."""
    import jax

    from cec.agents.policy import random_policy, scripted_policy

    untrained = [
        random_policy(f"{UNTRAINED}-s{s}", jax.random.PRNGKey(s), env=cfg.env, network=cfg.network_config,
                      algorithm=UNTRAINED, seed=s)
        for s in mode.seeds["cec"]
    ]  # fmt: skip
    return [*untrained, scripted_policy(NOOP, NOOP, env=cfg.env, algorithm=NOOP)]


def evaluate_controls(mode: Mode, cfg: Any, *, log: TextIO, seed: int = 0) -> Any:
    """The controls (`control_policies` of `cfg`) with each other and the cook on both level sets, as
    `evaluate` plays the algorithms (the cook's own games left out: `evaluate` has them)."""
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import crossplay, eval_levels
    from cec.evaluation.results import EpisodeTable

    controls = control_policies(mode, cfg)
    cook = scripted_policy(COOK, COOK, env=controls[0].env, algorithm=COOK)
    tables = []
    for level_set in LEVEL_SETS:
        config = eval_config(mode, level_set, seed)
        t0 = time.perf_counter()
        levels = eval_levels("overcooked", config.levels)
        table = crossplay([*controls, cook], levels, config, involving={c.name for c in controls})
        tables.append(table)
        pipeline.note(log, f"controls on the {level_set} kitchens: {len(table)} episodes in "
                      f"{time.perf_counter() - t0:.0f}s")  # fmt: skip
    return EpisodeTable.concat(tables)


def cached_controls(mode: Mode, work: Path, *, log: TextIO, commit: str) -> Any:
    """`evaluate_controls`, or the table an earlier invocation wrote in `work/controls` while the settings
    are unchanged (the untrained network: that of the folder's CEC agents, `cec_config`). They need no
    trained agent, so `--report-only` plays them when a work folder lacks them. `commit`: the checkout's
    as the command started (written beside a table it plays, with the machine)."""
    from apps.reproduce.pipeline import cached_table

    cfg = cec_config(mode, work)
    network = dataclasses.asdict(cfg.network_config)
    key = {**_eval_key(mode), "network": network, "seeds": mode.seeds["cec"]}
    folder = work / "controls"
    folder.mkdir(parents=True, exist_ok=True)

    def play() -> Any:  # they may be played by another machine than the zoo: it is named in the report
        table = evaluate_controls(mode, cfg, log=log)
        ran_on = {"machine": machine_info(), "commit": commit}
        (folder / MACHINE_FILE).write_text(json.dumps(ran_on, indent=1) + "\n")
        return table

    return cached_table(folder, key, play, label="controls: ", log=log)


def cached_evaluation(mode: Mode, manifest: Path, work: Path, *, log: TextIO, commit: str) -> Any:
    """`evaluate`, or the table an earlier invocation wrote when neither the zoo (checkpoints pinned by
    SHA-256) nor the settings changed (`apps.reproduce.pipeline.cached_table`). The invocation that plays it
    writes `work/machine.json`: this machine, `commit` and the commits that wrote the agents' checkpoints
    (a zoo trained over several invocations)."""
    from apps.reproduce.pipeline import PLAY_TIME_FILE, cached_table
    from cec.agents.zoo import load_zoo
    from cec.checkpoints import read_meta

    entries = sorted(pipeline.zoo_entries(manifest))
    proxies = sorted([e.name, e.checkpoint, e.sha256] for e in load_zoo(mode.proxies)) if mode.proxies else []
    # `pairs`: what a table played with fewer pairs (each algorithm alone) lacks; such a table is played again
    key = {**_eval_key(mode), "zoo": entries, "proxies": proxies, "pairs": "every agent (lineups)"}
    parts = work / PARTS

    def play() -> Any:
        table = evaluate(mode, manifest, log=log, parts=parts, key=key)
        # the line-ups' own times, also those an interrupted invocation played
        seconds = sum(play_seconds(part) for part in parts.iterdir())
        (work / PLAY_TIME_FILE).write_text(json.dumps({"seconds": seconds}) + "\n")
        trained = {
            _short(read_meta(checkpoint)["metadata"].get("code_version", "unknown"))
            for _, _, checkpoint, _ in entries
        }
        ran_on = {"machine": machine_info(), "commit": commit, "trained_at": sorted(trained)}
        (work / MACHINE_FILE).write_text(json.dumps(ran_on, indent=1) + "\n")
        return table

    table = cached_table(work, key, play, label="", log=log)
    shutil.rmtree(parts, ignore_errors=True)  # all in the table now
    return table


def _short(version: str) -> str:
    """A commit as `code_version()` records it (40 hex digits, `+dirty` for a changed tree), abbreviated."""
    sha, dirty, rest = version.partition("+")
    return sha[:7] + dirty + rest


PARTS = "parts"  # in the work folder: each line-up's games until the whole table is written (`evaluate`)


CURVES = "curves"  # in the work folder: the milestone checkpoints' games (`cached_curves`)


def cached_curves(mode: Mode, work: Path, *, log: TextIO, report_only: bool = False) -> Any:
    """Cross-play learning curves of the generator-trained runs: at each checkpoint a run saved (its
    milestones and its last), its seeds with each other on the held-out kitchens (`cec.evaluation.
    milestones`), as the evaluation plays them; cached in `work/curves` while neither the checkpoints nor
    the settings changed. `report_only`: the cached games whatever their key (a folder without its
    checkpoints), None where there are none."""
    from apps.reproduce.pipeline import cached_table
    from cec.checkpoints import read_meta
    from cec.evaluation.crossplay import eval_levels
    from cec.evaluation.milestones import checkpoints_by_update, play_milestone
    from cec.evaluation.results import EpisodeTable, read_csv

    folder = work / CURVES
    if report_only:
        cached = results_file(folder)
        return read_csv(cached) if cached.is_file() else None
    runs = {a: _generalist_run(mode, work, a) for a in GENERALISTS}
    saved = {a: checkpoints_by_update([run]) for a, run in runs.items() if run.is_dir()}
    config = eval_config(mode, "heldout")
    states = {a: [read_meta(p)["sha256"] for ps in s.values() for p in ps] for a, s in saved.items()}
    key = {**_eval_key(mode), "checkpoints": states}  # each checkpoint's state by its SHA-256
    folder.mkdir(parents=True, exist_ok=True)

    def play() -> Any:
        levels = eval_levels("overcooked", config.levels)
        return EpisodeTable.concat(
            [play_milestone(a, paths, levels, config) for a, s in saved.items() for paths in s.values()]
        )

    return cached_table(folder, key, play, label="learning curves: ", log=log)


# ---------------------------------------------------------------------------------------------------------
# SUMMARY: seeds are the units
# ---------------------------------------------------------------------------------------------------------


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

    def crossplay(self) -> Any:
        """The algorithm's cross-play with its jackknife standard error over seeds
        (`cec.evaluation.stats.CrossPlay`; a seed's pairs are shared with the other seeds)."""
        from cec.evaluation.seeds import SeedSummary

        return SeedSummary(self.seeds, self.xp, self.sp, self.xp_matrix).crossplay()


def seed_scores(table: Any, level_names: Sequence[str]) -> dict[str, SeedScores]:
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


def _finite(values: Sequence[float]) -> np.ndarray:
    arr = np.asarray(values, np.float64)
    return arr[~np.isnan(arr)]


def _cell(values: Sequence[float]) -> str:
    from cec.evaluation.stats import sem

    arr = _finite(values)
    if not arr.size:
        return "—"
    return _pm(float(arr.mean()), sem(arr), arr.size)


def _xp_cell(scores: SeedScores) -> str:
    """Cross-play: the mean over every pair of two different seeds ± its jackknife standard error."""
    est = scores.crossplay()
    return "—" if math.isnan(est.mean) else _pm(est.mean, est.se, est.seeds)


def _pm(mean: float, err: float, n: int) -> str:
    return f"{mean:.1f}" + ("" if math.isnan(err) else f" ± {err:.1f}") + f" (n={n})"


def paper_values(source: str = "figures") -> dict[str, dict[str, float]]:
    """{level set: {algorithm: the paper's XP}} as read off its figures (approximate), or `source="text"`:
    the few values its text prints (exact; CEC-E3T among them, which is not trained here)."""
    data = yaml.safe_load(PAPER_FILE.read_text())
    data = data.get("text", {}) if source == "text" else data
    return {s: dict(data.get(s, {})) for s in LEVEL_SETS}


def _paper_cell(level_set: str, algo: str, figures: dict[str, dict[str, float]], text: dict) -> str:
    exact = text.get(level_set, {}).get(algo)
    if exact is not None:
        return f"{exact} (text)"
    ref = figures.get(level_set, {}).get(algo)
    return "—" if ref is None else f"≈{ref} (figure)"


MEASURES = {"xp": "cross-play", "human": "with human proxies"}


def comparisons(
    summary: dict[str, dict[str, SeedScores]], matrices: dict[str, Any] | None = None
) -> list[dict[str, Any]]:
    """CEC against each baseline, per level set: cross-play with the jackknife over seeds (seeds partner
    each other, so their per-seed XP are not independent; `compare_crossplay`), the score with the human
    proxies (the same partners for every seed) with a Welch t-test over seeds and a bootstrap interval.
    `matrices`: {level set: `cec.evaluation.seeds.SeedMatrix`} of the same table; with it each cross-play
    test also gets the exact permutation p over seeds from CEC's and the baseline's pooled seed x seed matrix
    (`p_exact`, its smallest attainable value `p_min`; NaN where two of their seeds never played). Every
    p is also Holm-adjusted within its family, one level set and one score (`p_holm`, `p_exact_holm`)."""
    from cec.evaluation.stats import compare, compare_crossplay, holm

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
                    a, b = _finite(scores["cec"].human), _finite(scores[other].human)
                    if a.size < 2 or b.size < 2:
                        continue
                    c = compare(a, b)
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


def exact_crossplay(matrix: Any, a: str, b: str) -> tuple[float, float]:
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


def _reading(test: dict[str, Any]) -> str:
    """What a comparison of `comparisons` shows: CEC ahead, CEC behind, or neither at the 5% level of the
    t-test; a difference the t-test's Holm-adjusted p does not keep below 5% in its family says so."""
    if not test["significant"]:
        return "no difference shown"
    reading = "CEC ahead" if test["diff"] > 0 else "CEC behind"
    held = test.get("p_holm", test["p"]) < ALPHA
    return reading if held else f"{reading}; not after Holm"


def _p(p: float) -> str:
    return "—" if math.isnan(p) else f"{p:.3g}"


def _floor_lines(tests: Sequence[dict[str, Any]]) -> list[str]:
    """Per family with exact tests: the smallest Holm-adjusted exact p it could reach (its smallest test's
    p_min times the family's size), and how many of its tests stay below 5% after Holm, t and exact."""
    families: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for t in tests:
        families.setdefault((t["level_set"], t["measure"]), []).append(t)
    parts = []
    for (level_set, measure), family in families.items():
        floors = [t["p_min"] for t in family if not math.isnan(t["p_exact"])]
        if not floors:
            continue
        k = len(family)
        held_t = sum(t["p_holm"] < ALPHA for t in family)
        held_exact = sum(t["p_exact_holm"] < ALPHA for t in family)
        parts.append(
            f"{level_set} {MEASURES[measure]}: {k} tests, the smallest Holm-adjusted exact p attainable "
            f"{min(1.0, k * min(floors)):.3g}; below {ALPHA:g} after Holm: {held_t} of {k} by the t-test, "
            f"{held_exact} by the exact test"
        )
    return [f"Families: {'; '.join(parts)}.", ""] if parts else []


# ---------------------------------------------------------------------------------------------------------
# REPORT
# ---------------------------------------------------------------------------------------------------------


def write_report(
    mode: Mode, summary: dict[str, dict[str, SeedScores]], out: Path, *, figures: dict[str, str],
    plan: list[pipeline.PlanLine], command: str, ran_on: dict[str, Any], commit: str,
    skipped: Sequence[Any] = (), train_s: dict[str, float] | None = None, played_s: float = math.nan,
    sections: Sequence[str] = (), missing: Sequence[str] = (), matrices: dict[str, Any] | None = None,
) -> Path:  # fmt: skip
    """`out/report.md` and `out/summary.json`; `ran_on`: the machine and commit that trained and played;
    `commit`: the checkout's as the command started; `skipped`: the cross-play table's skipped entries
    (proxies that could not play with the agents); `train_s`: the recorded seconds of each training run (by
    run name) and `played_s` of the cross-play (NaN: not recorded), whichever invocation did them;
    `sections`: the lines after the tests (`analysis_lines`); `missing`: runs of the mode's plan that the
    work folder does not have (a folder trained before the mode had them); `matrices`: {level set:
    `cec.evaluation.seeds.SeedMatrix`} of the same table, for the exact tests (`comparisons`)."""

    paper, paper_text = paper_values(), paper_values("text")
    tests = comparisons(summary, matrices)
    out.mkdir(parents=True, exist_ok=True)
    machine, ran = machine_info(), ran_on["machine"]
    lines = [
        f"# CEC on Overcooked: `{command}`",
        "",
        f"Trained and played on: {_machine_text(ran)}; cross-play finished at commit {ran_on['commit']}"
        + _trained_at(ran_on)
        + ".",
        "",
        *_controls_machine_lines(ran_on),
        f"Report written on: {_machine_text(machine)}; commit {commit}; {time.strftime('%Y-%m-%d %H:%M')}.",
        "",
        *_time_lines(train_s or {}, played_s),
        f"Team return per {EVAL_STEPS}-step episode (20 per soup), sampled actions, common random numbers, "
        "both seat orders. SP, cook and proxies: the mean over seeds of each seed's mean (SP: with itself; "
        "cook: with the scripted cook), ± the standard error over seeds, n = seeds. XP: the mean over every "
        "pair of two different seeds of the algorithm ± its leave-one-seed-out jackknife standard error (a "
        "seed's pairs are shared with the other seeds, so a standard error over per-seed means would "
        "understate it about 3x for 4 seeds). The controls are partners that learned nothing: the CEC "
        "network at its random initialisation (one per CEC seed) and an agent that always stays; what an "
        "algorithm adds with the cook is its score there minus theirs. The paper's values are read off its "
        "figures (approximate, marked 'figure') or, where its text prints one, that value ('text'; "
        "`apps/reproduce/paper_overcooked.yaml`).",
        "",
        *_human_lines(mode, summary, skipped),
    ]
    for level_set, scores in summary.items():
        title = (
            f"{len(mode.kitchens)} classic" if level_set == "classic" else f"{mode.generated_levels} held-out"
        )
        lines += [f"## The {title} kitchens", "", TABLE_HEAD, "|---|---|---|---|---|---|---|"]
        for algo in [*ALGORITHMS, UNTRAINED, NOOP, COOK]:
            if algo not in scores:
                continue
            s = scores[algo]
            sp, xp = _finite(s.sp), _finite(s.xp)
            ratio = f"{xp.mean() / sp.mean():.2f}" if xp.size and sp.size and sp.mean() > 0 else "—"
            lines.append(
                f"| {TITLES.get(algo, algo)} | {_cell(s.sp)} | {_xp_cell(s)} | {ratio} | "
                f"{_cell(s.cook) if algo != COOK else '—'} | {_cell(s.human)} | "
                f"{_paper_cell(level_set, algo, paper, paper_text)} |"
            )
        absent = {a: v for a, v in paper_text[level_set].items() if a not in scores}
        if absent:
            named = ", ".join(f"{a.upper().replace('_', '-')} {v}" for a, v in absent.items())
            lines += ["", f"Not trained here; the paper's text gives: {named}."]
        lines.append("")
    lines += ["## CEC against the baselines (seeds as units)", "",
              "Cross-play: the difference of the algorithms' cross-play, a t-test with the jackknife "
              "standard errors over seeds (Welch-Satterthwaite degrees of freedom) and its 95% t "
              "interval. With human proxies: a Welch t-test over per-seed scores and a 95% bootstrap "
              "interval. No test is printed where a side has too few seeds to estimate its spread "
              "(the jackknife needs 3).", "",
              "The interval is the headline; the p-values come second. Beside the t-test's p, for "
              "cross-play, the exact permutation test over seeds (`cec.evaluation.stats."
              "permutation_crossplay`: every split of CEC's and the baseline's seeds into two groups of "
              "their sizes, from the pooled seed x seed matrix, as every CEC seed played every seed of "
              "the baseline), valid at any seed count, with the smallest p it can give at these seed "
              "counts in brackets: with 4 seeds each it cannot go below 0.0286 whatever the difference. "
              "None with human proxies: the proxies are the same fixed partners for every seed, not seeds "
              "of either algorithm, so there is no pooled matrix to permute. Holm: each p adjusted for the "
              "tests of its family, one level set and one score (CEC against each baseline).",
              ""]  # fmt: skip
    if not tests:
        lines += ["No test: too few seeds, or no spread between them.", ""]
    else:
        lines += ["| level set | score | CEC − | difference | 95% CI | p | Holm p | "
                  "exact p (smallest possible) | Holm exact p | reading (p < 0.05) |",
                  "|---|---|---|---|---|---|---|---|---|---|"]  # fmt: skip
        for t in tests:
            exact = "—" if math.isnan(t["p_exact"]) else f"{_p(t['p_exact'])} ({_p(t['p_min'])})"
            lines.append(
                f"| {t['level_set']} | {MEASURES[t['measure']]} | {TITLES[t['worse']]} | {t['diff']:+.1f} | "
                f"[{t['ci_low']:+.1f}, {t['ci_high']:+.1f}] | {t['p']:.3g} | {_p(t['p_holm'])} | {exact} | "
                f"{_p(t['p_exact_holm'])} | {_reading(t)} |"
            )
        lines += ["", *_floor_lines(tests)]
    lines += sections
    lines += ["## Training", "", "| run | seeds | env steps per seed | updates | recorded time |",
              "|---|---|---|---|---|"]  # fmt: skip
    recorded = {run: duration(t) for run, t in (train_s or {}).items() if math.isfinite(t) and t > 0}
    lines += [
        f"| {p.run} | {p.seeds} | {p.env_steps:,} | {p.updates} | {recorded.get(p.run, '—')} |" for p in plan
    ]
    lines += ["", *budget_lines(mode, plan)]
    if missing:
        lines += ["", f"Not in this work folder (trained before the mode had them; the tables have none of "
                  f"their games): {', '.join(missing)}."]  # fmt: skip
    lines.append("")
    for title, rel in figures.items():
        lines += [f"![{title}]({rel})", ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    data = {
        "mode": mode.name, "command": command, "ran_on": ran_on, "machine": machine, "commit": commit,
        "eval_steps": EVAL_STEPS, "paper": paper, "tests": tests,
        "summary": {ls: {a: dataclasses.asdict(s) for a, s in sc.items()} for ls, sc in summary.items()},
    }  # fmt: skip
    (out / "summary.json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    return report


def budget_lines(mode: Mode, plan: Sequence[pipeline.PlanLine]) -> list[str]:
    """Env steps per trained model (one seed; a single-kitchen model: one kitchen) by algorithm, and CEC's
    against those of one single-kitchen model and of all of an algorithm's kitchens together; the paper
    trains every model for the same 3e9 steps (its section on the generator: "all other baselines, for 3
    billion steps"), 1:1."""
    steps: dict[str, int] = {}
    for p in plan:  # `trained_runs`' lines: each with its run's algorithm
        steps.setdefault(p.algorithm, p.env_steps)
    if "cec" not in steps:
        return []
    cec, k = steps["cec"], len(mode.kitchens)
    parts = [f"{TITLES[a]} {steps[a]:,} per model" for a in GENERALISTS if a in steps]
    single = [a for a in ALGORITHMS if a in steps and a not in (*GENERALISTS, "cec_finetune")]
    for n in sorted({steps[a] for a in single}):
        names = ", ".join(TITLES[a] for a in single if steps[a] == n)
        parts.append(
            f"{names} {n:,} per model, one per kitchen (CEC trains {cec / n:.1f}x the steps of one of their "
            f"models, {cec / (n * k):.1f}x those of all {k} together)"
        )
    if "cec_finetune" in steps:
        parts.append(f"CEC-Finetune {steps['cec_finetune']:,} per kitchen on top of its CEC seed's")
    return [
        f"Budget (env steps per seed): {'; '.join(parts)}. The paper trains every model for 3e9 steps (1:1)."
    ]


def episode_lines(mode: Mode, table: Any, controls: Any = None) -> list[str]:
    """The per-kitchen view the seed-level tables average over: per algorithm, cross-play (two different
    seeds) and self-play in each classic kitchen and over the held-out ones, then per level set the
    collisions per episode, the share of cross-play episodes without a soup and the collisions per soup
    (with the untrained network's cross-play from `controls`, the controls' table, beside them). Means over
    episodes (descriptive; the seed-level tests are above)."""
    xp, sp = _xp_sp(table)
    held = _held_out(mode, table)
    columns = [(k, table.level == k) for k in mode.kitchens] + [("held-out", held)]
    algos = [a for a in ALGORITHMS if np.any(table.algorithm_a == a)]
    kitchens = [k for k in mode.kitchens if any(_of_kitchen(table.policy_a[held], a, k).any() for a in algos)]

    def mean(values: np.ndarray, mask: np.ndarray, fmt: str = "{:.1f}") -> str:
        return fmt.format(float(values[mask].mean())) if mask.any() else "—"

    lines = [
        "## Per kitchen, collisions and episodes without a soup",
        "",
        f"Team return per {EVAL_STEPS}-step episode, the mean over episodes: cross-play (two different seeds "
        "of the algorithm) and, in brackets, self-play, in each classic kitchen and over the held-out ones. "
        "The baselines of a classic kitchen are that kitchen's agents; on the held-out kitchens the "
        "single-kitchen agents that played are those trained on "
        + ", ".join(kitchens or ["none"])
        + " (as in the tables above; by training kitchen below).",
        "",
        "| algorithm | " + " | ".join(k for k, _ in columns) + " |",
        "|---" * (len(columns) + 1) + "|",
    ]
    for algo in algos:
        mine = table.algorithm_a == algo
        cells = [
            f"{mean(table.returns, mine & xp & m)} ({mean(table.returns, mine & sp & m)})" for _, m in columns
        ]
        lines.append(f"| {TITLES[algo]} | " + " | ".join(cells) + " |")
    lines += [
        "",
        "Collisions per cross-play episode (steps where the two cooks move to the same cell or try to swap "
        "cells), the share of cross-play episodes that deliver no soup, and the collisions per soup (every "
        "collision of those episodes over every soup they delivered; — where none): an agent that cooks "
        "moves more, so it has more steps to collide on. The untrained CEC network (the control; its seeds "
        "with each other) is the baseline of an agent that learned nothing:",
        "",
        "| algorithm | collisions, classic | collisions, held-out | no soup, classic | no soup, held-out "
        "| per soup, classic | per soup, held-out |",
        "|---|---|---|---|---|---|---|",
    ]
    rows = [(TITLES[a], table, a) for a in algos]
    if controls is not None and np.any(controls.algorithm_a == UNTRAINED):
        rows.append((TITLES[UNTRAINED], controls, UNTRAINED))
    for title, t, algo in rows:
        t_xp, t_held = _xp_sp(t)[0], _held_out(mode, t)
        sets = [(t.algorithm_a == algo) & t_xp & m for m in (~t_held, t_held)]
        coll = [mean(t.collisions, m) for m in sets]
        none = [mean((t.deliveries == 0).astype(float), m, "{:.0%}") for m in sets]
        per_soup = [_per_soup(t.collisions[m].sum(), t.deliveries[m].sum()) for m in sets]
        lines.append(f"| {title} | {' | '.join(coll)} | {' | '.join(none)} | {' | '.join(per_soup)} |")
    return [*lines, ""]


def _per_soup(collisions: float, soups: float) -> str:
    if not soups:
        return "—"
    ratio = float(collisions) / float(soups)
    return f"{ratio:.1f}" if ratio < 1000 else f"{ratio:,.0f}"


def _xp_sp(table: Any) -> tuple[np.ndarray, np.ndarray]:
    """Rows of cross-play (two different seeds of one algorithm) and of self-play."""
    same = table.algorithm_a == table.algorithm_b
    return same & (table.seed_a != table.seed_b), same & (table.seed_a == table.seed_b)


def _held_out(mode: Mode, table: Any) -> np.ndarray:
    """Rows played on the mode's held-out kitchens."""
    return np.isin(table.level, level_spec(mode, "heldout").split(","))


def _agents(table: Any, *, with_proxies: bool = True) -> Any:
    """The games of the trained agents with each other (and with the human proxies): the table without the
    cook and the controls."""
    who = (*ALGORITHMS, HUMAN_PROXY) if with_proxies else ALGORITHMS
    return table.select(np.isin(table.algorithm_a, who) & np.isin(table.algorithm_b, who))


def _of_kitchen(names: np.ndarray, algo: str, kitchen: str) -> np.ndarray:
    """Which policy names are `algo`'s agents of `kitchen` (the zoo's run names: `ALGO_KITCHEN-sSEED`)."""
    return np.char.startswith(names.astype(str), f"{_run_name(algo, kitchen)}-s")


def analysis_lines(mode: Mode, table: Any, runs: Path, controls: Any = None) -> list[str]:
    """The sections after the tests: per kitchen (`episode_lines`, with the `controls`' table), the
    cross-algorithm matrices, held-out play by training kitchen, whether the single-kitchen runs levelled
    off, and the baselines without a soup in their own kitchen."""
    return [
        *episode_lines(mode, table, controls), *cross_algorithm_lines(mode, table),
        *heldout_kitchen_lines(mode, table), *plateau_lines(mode, runs), *failing_lines(mode, table, runs),
    ]  # fmt: skip


def curve_points(curves: Any) -> tuple[list[Any], int]:
    """The cross-play learning curves' points (`cec.evaluation.milestones.milestone_points`) of
    `cached_curves`' games, and the held-out kitchens they were played on (none: no games)."""
    from cec.evaluation.milestones import milestone_points

    if curves is None or not len(curves):
        return [], 0
    return milestone_points(curves), len(set(curves.level))


def curve_lines(points: Sequence[Any], kitchens: int) -> list[str]:
    """The cross-play learning curves (`curve_points`) as a table: each checkpoint's cross-play and
    self-play on the held-out kitchens."""
    head = "## Cross-play learning curves (held-out kitchens)"
    if not points:
        missing = "Not measured: the work folder has neither the runs' milestone checkpoints nor their games."
        return [head, "", missing, ""]
    about = (
        "At each checkpoint a generator-trained run saved (its milestones and its last), its seeds with each "
        f"other on the {kitchens} held-out kitchens, {EVAL_STEPS}-step episodes: cross-play "
        "(every pair of two different seeds) ± its jackknife standard error over seeds, and self-play ± "
        "the standard error over seeds (`curves_xp.png`)."
    )
    lines = [head, "", about, "", "| algorithm | env steps per seed | seeds | cross-play | self-play |",
             "|---|---|---|---|---|"]  # fmt: skip

    def cell(mean: float, se: float) -> str:
        return "—" if math.isnan(mean) else f"{mean:.1f}" + ("" if math.isnan(se) else f" ± {se:.1f}")

    for p in points:
        lines.append(
            f"| {TITLES.get(p.name, p.name)} | {p.env_steps:,} | {len(p.seeds)} | {cell(p.xp, p.xp_se)} | "
            f"{cell(p.sp, p.sp_se)} |"
        )
    return [*lines, ""]


def cross_algorithm_lines(mode: Mode, table: Any) -> list[str]:
    """Per level set the cross-algorithm matrix (`cec.evaluation.analysis.algorithm_matrix`): cell (A, B)
    the mean team return of the pairs of an A agent and a different B agent (on the diagonal: cross-play),
    each pair's score the mean over the kitchens both play (the paper's ad-hoc teamplay heatmaps)."""
    from cec.evaluation import analysis as an

    agents = _agents(table, with_proxies=False)
    lines = [
        "## Cross-algorithm play (ad-hoc teamplay)",
        "",
        "Team return per 400-step episode of an agent of the row's algorithm with a different agent of the "
        "column's (the diagonal is cross-play), each pair's score the mean over the kitchens both play: on "
        "the classic kitchens a single-kitchen agent meets the others of its kitchen and the "
        "generator-trained agents, on the held-out kitchens its kitchen's agents and the generator-trained "
        "ones. Means over pairs (descriptive; seeds as units for tests above). Heatmaps, seed matrices and "
        "the meta-game (replicator dynamics): [crossplay/report.md](crossplay/report.md).",
        "",
    ]
    for level_set in LEVEL_SETS:
        m = an.algorithm_matrix(an.pair_level_scores(agents, level_spec(mode, level_set).split(",")))
        if not m.labels:
            continue
        titles = [TITLES.get(a, a) for a in m.labels]
        lines += [f"**{level_set}**", "", "| | " + " | ".join(titles) + " |", "|---" * len(titles) + "|---|"]
        for title, row in zip(titles, m.values, strict=True):
            cells = ("—" if math.isnan(v) else f"{v:.1f}" for v in row)
            lines.append(f"| {title} | " + " | ".join(cells) + " |")
        off = m.values[~np.eye(len(m.labels), dtype=bool)]
        if off.size and np.isnan(off).all():
            lines += ["", "No two algorithms met in this table (it was played before every agent met every "
                      "other): the cells off the diagonal are empty."]  # fmt: skip
        lines.append("")
    return lines


def heldout_kitchen_lines(mode: Mode, table: Any) -> list[str]:
    """Held-out cross-play (self-play) of each single-kitchen algorithm by the kitchen its agents trained
    on: which kitchens' agents carry anything to kitchens they never saw."""
    xp, sp = _xp_sp(table)
    held = _held_out(mode, table)
    algos = [a for a in ALGORITHMS if a not in GENERALISTS and np.any(table.algorithm_a == a)]
    if not algos:
        return []
    lines = [
        "## The held-out kitchens by training kitchen",
        "",
        f"Team return per {EVAL_STEPS}-step episode on the held-out kitchens, the mean over episodes: "
        "cross-play (two different seeds of one algorithm, both trained on the column's kitchen) and, in "
        "brackets, self-play; — where that kitchen's agents did not play them.",
        "",
        "| algorithm | " + " | ".join(mode.kitchens) + " |",
        "|---" * (len(mode.kitchens) + 1) + "|",
    ]
    for algo in algos:
        cells = []
        for k in mode.kitchens:
            mine = held & _of_kitchen(table.policy_a, algo, k) & _of_kitchen(table.policy_b, algo, k)
            cells.append(
                f"{table.returns[mine & xp].mean():.1f} ({table.returns[mine & sp].mean():.1f})"
                if (mine & xp).any() and (mine & sp).any() else "—"
            )  # fmt: skip
        lines.append(f"| {TITLES[algo]} | " + " | ".join(cells) + " |")
    return [*lines, ""]


def _kitchen_runs(runs: Path, algo: str, kitchen: str) -> list[Path]:
    """`algo`'s run directories on `kitchen` under `runs` (one per spec entry)."""
    return sorted(runs.glob(f"{_run_name(algo, kitchen)}-s*"))


def _curves(runs: Path, algo: str, kitchen: str, column: str) -> list[np.ndarray]:
    """Per seed of `algo`'s runs on `kitchen` under `runs`, `column` of its `metrics.csv` by update."""
    from cec.evaluation.curves import read_curve

    runs_k = [r for r in _kitchen_runs(runs, algo, kitchen) if metrics_file(r).is_file()]
    return [v for r in runs_k for _, v in read_curve(r, column).values() if len(v)]


def _episode_steps(runs: Path, algo: str, kitchens: Sequence[str]) -> str:
    """The training episode length of `algo`'s runs on `kitchens` under `runs`, as each run's `config.yaml`
    recorded it ('128', or '128/400' where they differ; '—' when no run has its config there)."""
    configs = [r / "config.yaml" for k in kitchens for r in _kitchen_runs(runs, algo, k)]
    steps = {
        int(yaml.safe_load(c.read_text())["env"]["overcooked"]["max_steps"]) for c in configs if c.is_file()
    }
    return "/".join(str(s) for s in sorted(steps)) or "—"


def plateau_lines(mode: Mode, runs: Path) -> list[str]:
    """Whether each single-kitchen algorithm's training had levelled off: its team return per training
    episode over the last 10 updates, and how much it rose over the last quarter of the run (the mean over
    seeds; `metrics.csv` of its runs under `runs`)."""
    from cec.evaluation.curves import trailing_mean

    algos = [a for a in ALGORITHMS if a not in GENERALISTS]
    cells = {}
    for algo in algos:
        for k in mode.kitchens:
            smooth = [trailing_mean(v, 10) for v in _curves(runs, algo, k, "mean_return") if len(v) >= 4]
            ends = [(m[-1], m[(3 * len(m)) // 4 - 1]) for m in smooth]
            if ends:
                last, earlier = np.mean(ends, axis=0)
                cells[algo, k] = f"{last:.1f} ({last - earlier:+.1f})"
    if not cells:
        return []
    return [
        "## Single-kitchen training: levelled off?",
        "",
        "Team return per training episode (of the steps given; its run's `config.yaml`) with its training "
        "partners over the last 10 updates and, in brackets, its rise over the last quarter of the run (the "
        "mean over seeds): a rise that is large beside the return means the run stopped before its "
        "self-play levelled off.",
        "",
        "| algorithm | training episode (steps) | " + " | ".join(mode.kitchens) + " |",
        "|---" * (len(mode.kitchens) + 2) + "|",
        *(
            f"| {TITLES[a]} | {_episode_steps(runs, a, mode.kitchens)} | "
            + " | ".join(cells.get((a, k), "—") for k in mode.kitchens)
            + " |"
            for a in algos
        ),
        "",
    ]


def failing_lines(mode: Mode, table: Any, runs: Path) -> list[str]:
    """Every single-kitchen algorithm and kitchen whose self-play there delivers nothing, with what its
    training recorded (`metrics.csv` of its runs under `runs`): the team return per training episode with
    its training partners at the first update and over the last 10, the shaped return, and the reading
    those numbers allow."""
    from cec.evaluation.curves import trailing_mean

    xp, sp = _xp_sp(table)
    rows = []
    for algo in (a for a in ALGORITHMS if a not in GENERALISTS):
        for k in mode.kitchens:
            own = (table.algorithm_a == algo) & (table.level == k)
            if not (own & sp).any() or table.returns[own & sp].mean() > 0:
                continue
            curves = {c: _curves(runs, algo, k, c) for c in ("mean_return", "mean_shaped_return")}
            if not curves["mean_return"]:
                rows.append(f"| {TITLES[algo]} | {k} | 0.0 | — | — | — | — | its training metrics are not in "
                            "the work folder |")  # fmt: skip
                continue
            first = float(np.mean([v[0] for v in curves["mean_return"]]))
            last, shaped = (float(np.mean([trailing_mean(v, 10)[-1] for v in curves[c]])) for c in curves)
            if last < 1.0:
                reading = "no soup in training either: it learned the shaped steps only, not to deliver"
            elif algo in SELF_PLAY:
                reading = "it delivered in its training episodes (with itself), not in these"
            elif first >= last / 2:
                reading = (
                    f"its training partners delivered from its first update ({first:.1f}): it scored with "
                    "them, not by itself"
                )
            else:
                reading = "it learned to deliver with its training partners, but not with a copy of itself"
            xp_k = f"{table.returns[own & xp].mean():.1f}" if (own & xp).any() else "—"
            rows.append(f"| {TITLES[algo]} | {k} | 0.0 | {xp_k} | {_episode_steps(runs, algo, [k])} | "
                        f"{first:.1f} → {last:.1f} | {shaped:.1f} | {reading} |")  # fmt: skip
    if not rows:
        return ["## Baselines in their own kitchen", "", "Every single-kitchen algorithm delivers in "
                "self-play in its own kitchen (self-play > 0 in each).", ""]  # fmt: skip
    return [
        "## Baselines without a soup in their own kitchen",
        "",
        "Each algorithm and kitchen whose self-play there (every seed with itself, 400-step episodes) "
        "delivers nothing, with what its training recorded: the team return per training episode (of the "
        "steps given) with its training partners (IPPO and CEC-Finetune: itself; FCP: its population; E3T: "
        "itself mixed with random moves) at the first update and over the last 10 (the mean over seeds), "
        "and the shaped return over the last 10.",
        "",
        "| algorithm | kitchen | self-play | cross-play | training episode (steps) | training return, first "
        "→ last | shaped, last | reading |",
        "|---|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def _human_lines(mode: Mode, summary: dict[str, dict[str, SeedScores]], skipped: Sequence[Any]) -> list[str]:
    """What the human-proxy column holds, the paper's human study beside it, or why it is empty."""
    played = any(_finite(s.human).size for scores in summary.values() for s in scores.values())
    if played:
        return [
            f"With human proxies: each seed with every `{HUMAN_PROXY}` entry of `{mode.proxies}` "
            "(behaviour-cloned from recorded human-human games, `cec humans bc`; each plays its own "
            "kitchen), the mean over the proxies. The paper's human study (score with real people, "
            f"Counter Circuit and Coordination Ring): {HUMAN_STUDY}",
            "",
        ]
    reasons = sorted({s.reason for s in skipped if s.algorithm == HUMAN_PROXY})
    why = f"they could not play with the agents: {'; '.join(reasons)}" if reasons else "none in the table"
    return [f"With human proxies: not played ({why}).", ""]


def _time_lines(train_s: dict[str, float], played_s: float) -> list[str]:
    """The recorded time of the work behind the report, reused work included (empty when none is known)."""
    recorded = [t for t in train_s.values() if math.isfinite(t) and t > 0]
    if not recorded:  # a work folder from before training times were kept
        return []
    train = sum(recorded)
    unknown = "not recorded (played before play times were kept)"
    play = duration(played_s) if math.isfinite(played_s) else unknown
    return [
        f"Recorded times of the work behind these numbers, whichever invocation did it: training "
        f"{duration(train)} on the machine that trained (per run in the Training section; runs that share "
        f"it run side by side, so this is not its wall time); cross-play {play}.",
        "",
    ]


def _controls_machine_lines(ran_on: dict[str, Any]) -> list[str]:
    """Where the controls were played, when not where the zoo was (`--report-only` plays them)."""
    controls = ran_on.get("controls")
    if not controls or controls["machine"]["host"] == ran_on["machine"]["host"]:
        return []
    return [f"Controls played on: {_machine_text(controls['machine'])}; commit {controls['commit']}.", ""]


def _trained_at(ran_on: dict[str, Any]) -> str:
    """The commits that wrote the agents' checkpoints, where the folder's `machine.json` records them."""
    commits = ran_on.get("trained_at")
    if not commits:
        return ""
    many = "s" if len(commits) > 1 else ""
    return f"; the agents' last checkpoints written at {len(commits)} commit{many} ({', '.join(commits)})"


def _machine_text(m: dict[str, Any]) -> str:
    return f"{m['device']} (JAX {m['jax']}), {m['cpu']} ({m['cpu_count']} cores), host {m['host']}"


def _figures(
    mode: Mode, work: Path, out: Path, table: Any, points: Sequence[Any], *, log: TextIO, policies: Path
) -> dict[str, str]:
    """Learning curves of every run (PNG), the cross-play learning curves (`curve_points`), a GIF of a
    median cross-play episode (`crossplay_gif`) and `cec report` of the agents' games (`out/crossplay/`:
    heatmaps, seed matrices, the meta-game)."""
    from cec.evaluation.curves import plot_learning_curves
    from cec.evaluation.milestones import plot_milestones
    from cec.evaluation.report import write_report as crossplay_report

    figures = {}
    runs = {d.name: d for d in sorted((work / "zoo" / "runs").glob("*")) if metrics_file(d).exists()}
    generalist = tuple(f"{a}-" for a in GENERALISTS)
    cec_runs = {k: v for k, v in runs.items() if k.startswith(generalist)}
    if cec_runs:
        plot_learning_curves(cec_runs, out / "curves_cec.png", title="trained on the generator's kitchens")
        figures["CEC (and CEC-E3T) learning curves"] = "curves_cec.png"
    others = {k: v for k, v in runs.items() if not k.startswith(generalist)}
    if others:
        plot_learning_curves(others, out / "curves_baselines.png", title="single-kitchen runs")
        figures["Single-kitchen learning curves"] = "curves_baselines.png"
    if points:
        title = f"cross-play at each checkpoint, held-out kitchens ({EVAL_STEPS}-step episodes)"
        plot_milestones(points, out / "curves_xp.png", title=title)
        figures["Cross-play learning curves (held-out kitchens)"] = "curves_xp.png"
    figures.update(crossplay_gif(table, policies, out / "cec_xp_heldout.gif"))
    crossplay_report(_agents(table), out / "crossplay", sources=[str(results_file(work))])
    pipeline.note(log, f"figures: {', '.join(figures.values())}; crossplay/report.md")
    return figures


# ---------------------------------------------------------------------------------------------------------
# THE COMMAND
# ---------------------------------------------------------------------------------------------------------


def reproduce_overcooked(
    mode: Mode, work: Path, out: Path, *, progress: bool = True, log: TextIO = sys.stdout, command: str = "",
    report_only: bool = False, policies: Path | None = None,
) -> Path | None:  # fmt: skip
    """Train (resumable), evaluate (cached), report. Returns the report, or None when interrupted.

    `report_only`: neither train nor play the zoo; the report from the work folder's cross-play table,
    curves and `machine.json` as the machine that trained and played wrote them (a work folder brought back
    from a GPU machine without its checkpoints); the controls, which need no trained agent, are played if
    the folder lacks them (`cached_controls`). `policies`: a manifest whose CEC entries draw the GIF
    instead of the zoo's (the exported CEC seeds)."""
    commit = code_version(short=True)  # before this command writes anything into the checkout
    if report_only:
        table = pipeline.played_table(work, "overcooked", MACHINE_FILE)
        ran_on = json.loads((work / MACHINE_FILE).read_text())
    else:
        result = zoo(mode, work).build(progress=progress, log=log)
        if result.interrupted or result.manifest is None:
            pipeline.note(log, "training interrupted; run the same command again to continue")
            return None
        table = cached_evaluation(mode, result.manifest, work, log=log, commit=commit)
        record = work / MACHINE_FILE  # where someone removed it: this machine, unknown training commits
        ran_on = (
            json.loads(record.read_text())
            if record.is_file()
            else {"machine": machine_info(), "commit": commit}
        )
    from cec.evaluation.results import EpisodeTable

    controls = cached_controls(mode, work, log=log, commit=commit)
    with_controls = EpisodeTable.concat([table, controls])
    if (work / "controls" / MACHINE_FILE).is_file():
        ran_on = {**ran_on, "controls": json.loads((work / "controls" / MACHINE_FILE).read_text())}
    from cec.evaluation.seeds import seed_matrix

    summary = {ls: seed_scores(with_controls, level_spec(mode, ls).split(",")) for ls in LEVEL_SETS}
    matrices = {ls: seed_matrix(table, level_spec(mode, ls).split(",")) for ls in LEVEL_SETS}
    plan, missing = trained_runs(mode, work)
    train_s = {p.run: train_seconds(read_metrics(work / "zoo" / "runs" / p.run)) for p in plan}
    points, kitchens = curve_points(cached_curves(mode, work, log=log, report_only=report_only))
    figures = _figures(
        mode, work, out, table, points, log=log, policies=policies or work / "zoo" / "zoo.yaml"
    )  # fmt: skip
    sections = [*analysis_lines(mode, table, work / "zoo" / "runs", controls), *curve_lines(points, kitchens)]
    report = write_report(
        mode, summary, out, figures=figures, plan=plan, command=command, ran_on=ran_on, commit=commit,
        skipped=table.skipped, train_s=train_s, played_s=play_seconds(work), sections=sections,
        missing=missing, matrices=matrices,
    )  # fmt: skip
    pipeline.note(log, f"report: {report}")
    return report


def _cmd(args: argparse.Namespace) -> int:
    name = "quick" if args.quick else "paper" if args.paper else "cpu"
    mode = MODES[name]
    work = Path(args.work or f"runs/reproduce/overcooked-{name}")
    out = Path(args.out or f"benchmarks/results/overcooked/{name}")
    command = "cec reproduce overcooked" + ("" if name == "cpu" else f" --{name}")
    if args.plan:
        lines = plan_lines(mode, work)
        total = sum(p.estimate_s for p in lines)
        left = sum(p.left_s for p in lines)
        print(f"{command}: {len(lines)} training runs into {work}/zoo, report to {out}")
        for p in lines:
            print(f"  {p.run:<36} {p.seeds} seed(s) x {p.env_steps:>13,} steps ({p.updates} updates)"
                  f"  ~{duration(p.estimate_s)}, {p.done:.0%} done")  # fmt: skip
        print(f"training: ~{duration(total)} on one core, ~{duration(left)} left "
              f"(s per update and seed: {', '.join(f'{a} {s:g}' for a, s in mode.seconds_per_update.items())}"
              f"; measured on {mode.measured_on or 'no machine yet'})")  # fmt: skip
        counts = planned_episodes(mode)
        parts = ", ".join(f"{part} {n:,}" for part, n in counts.items())
        played = sum(counts.values())
        rate = "time not measured"
        if set(counts) <= set(mode.episodes_per_s):
            seconds = sum(n / mode.episodes_per_s[part] for part, n in counts.items())
            rates = ", ".join(f"{part} {r:g}" for part, r in mode.episodes_per_s.items())
            rate = f"~{duration(seconds)} (episodes/s: {rates}; measured in {mode.eval_measured_on})"
        print(
            f"then cross-play: {played:,} episodes of {EVAL_STEPS} steps ({parts}), {rate}; then the "
            "report (cached games are not played again)"
        )
        return 0
    if args.proxies is not None:
        mode = dataclasses.replace(mode, proxies=args.proxies)
    if args.policies and not args.report_only:
        raise ConfigError("--policies draws the GIF of --report-only; add --report-only or drop it")
    report = reproduce_overcooked(
        mode, work, out, progress=not args.quiet, command=command, report_only=args.report_only,
        policies=Path(args.policies) if args.policies else None,
    )  # fmt: skip
    return 0 if report is not None else 130


def add_subcommand(rep_sub: Any) -> None:
    """Registers `overcooked` on the `cec reproduce` subparsers."""
    oc = rep_sub.add_parser(
        "overcooked",
        help="train CEC and the baselines on Overcooked, cross-play on classic and held-out kitchens, report",
    )
    size = oc.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="the pipeline at a small budget (minutes)")
    size.add_argument("--cpu", action="store_true", help="the CPU version (the default; see --plan)")
    size.add_argument("--paper", action="store_true", help="the paper's networks and budgets (a GPU job)")
    oc.add_argument("--plan", action="store_true", help="print the runs and their expected time, then exit")
    oc.add_argument("--work", help="runs and result tables (default runs/reproduce/overcooked-MODE)")
    oc.add_argument("--out", help="report folder (default benchmarks/results/overcooked/MODE)")
    oc.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    oc.add_argument(
        "--report-only",
        action="store_true",
        help="neither train nor play: the report from the work folder's cross-play table and curves",
    )
    oc.add_argument("--policies", metavar="MANIFEST", help="with --report-only: CEC policies for the GIF")
    oc.add_argument(
        "--proxies",
        metavar="MANIFEST",
        help=f"zoo whose {HUMAN_PROXY} entries play every agent on the classic kitchens (default: shipped; "
        "'' none); they need the agents' network (cec humans bc --preset)",
    )
    oc.set_defaults(func=_cmd)


def crossplay_gif(table: Any, policies: Path, gif: Path) -> dict[str, str]:
    """{caption: file name} of a GIF of the pair and held-out kitchen of the median-return cross-play
    episode of two different CEC seeds of `policies` (a zoo manifest) in `table`: a typical episode, not the
    best, replayed (another draw of the sampled actions); its caption says how it was chosen, the table's
    and the replay's return and the share of episodes that deliver nothing. Empty when there is none."""
    import jax

    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo
    from cec.envs.overcooked.render import rollout_frames, save_gif
    from cec.evaluation.crossplay import episode_states, eval_levels

    cec = {p.seed: p for p in load_policies(load_zoo(policies))[0] if p.algorithm == "cec"}
    rows = table.select(
        (table.algorithm_a == "cec") & (table.algorithm_b == "cec") & (table.seed_a != table.seed_b)
        & np.char.startswith(table.level.astype(str), "generated_")
    )  # fmt: skip
    if len(cec) < 2 or not len(rows):
        return {}
    i = int(np.argsort(rows.returns, kind="stable")[len(rows) // 2])  # the median episode
    kitchen = str(rows.level[i])
    a, b = cec[int(rows.seed_a[i])], cec[int(rows.seed_b[i])]
    level = jax.tree.map(lambda x: x[0], eval_levels("overcooked", kitchen).levels)
    states, ret = episode_states(a, b, level, kitchen, max_steps=EVAL_STEPS)
    save_gif(rollout_frames(states, 24), gif, fps=10)
    zero = float(np.mean(rows.returns == 0))
    caption = (
        f"CEC seeds {a.seed} and {b.seed} (never trained together) in {kitchen}, a held-out kitchen: the "
        f"pair and kitchen of the median-return episode of {len(rows)} cross-play episodes (return "
        f"{rows.returns[i]:g}; {zero:.0%} of them deliver nothing), replayed: team return {ret:g} per "
        f"{EVAL_STEPS} steps"
    )
    return {caption: gif.name}
