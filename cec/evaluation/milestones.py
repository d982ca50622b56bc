"""Cross-play learning curves: a run's seeds play each other at every checkpoint they all saved (its
milestones and its latest), so that what training bought is read as cross-play, not only training return.

    saved = checkpoints_by_update([Path("runs/cec-s200")])
    table = EpisodeTable.concat([play_milestone("cec", paths, levels, config) for paths in saved.values()])
    for point in milestone_points(table): ...

The games of one checkpoint are played among its seeds only (every pair, self-play included). In the table
an agent's algorithm is `<name>@<env steps per seed>` (`milestone_label`), so one table holds every
checkpoint of every run and `milestone_points` reads each one's seed matrix back from it: cross-play as the
mean over pairs of two different seeds ± its jackknife standard error over seeds (the pairs are shared
between seeds: `cec.evaluation.stats.crossplay_estimate`), self-play as the mean over seeds. Several runs
under one name are one population: one recipe's seeds trained in separate processes.
"""

from __future__ import annotations

import argparse
import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from cec.agents.policy import load_policies
from cec.agents.zoo import ZooEntry, load_zoo, shipped_entries
from cec.checkpoints import CheckpointStore, read_meta
from cec.evaluation import analysis as an
from cec.evaluation.crossplay import EvalConfig, crossplay
from cec.evaluation.results import EpisodeTable
from cec.evaluation.stats import crossplay_estimate, sem

SEPARATOR = "@"


@dataclass(frozen=True)
class MilestonePoint:
    """One checkpoint of one population: its seeds with each other.

    Attributes:
        name: the population (a run, or runs joined).
        env_steps: env steps per seed at the checkpoint.
        seeds: the seeds that played.
        xp: mean over every pair of two different seeds (NaN with one seed).
        xp_se: its jackknife standard error over seeds (NaN under 3 seeds).
        sp: mean of each seed with itself.
        sp_se: standard error of `sp` over seeds.
    """

    name: str
    env_steps: int
    seeds: tuple[int, ...]
    xp: float
    xp_se: float
    sp: float
    sp_se: float


def milestone_label(name: str, env_steps: int) -> str:
    """The algorithm label of `name`'s agents at `env_steps` per seed in a milestone table."""
    return f"{name}{SEPARATOR}{env_steps}"


def checkpoints_by_update(runs: Sequence[Path]) -> dict[int, list[Path]]:
    """{update: one checkpoint directory per run} for every update that all `runs` saved (their milestones
    and their latest), in update order."""
    saved = [{c.update: c.path for c in CheckpointStore(run, keep_last=1).list()} for run in runs]
    common = set.intersection(*(set(s) for s in saved)) if saved else set()
    return {u: [s[u] for s in saved] for u in sorted(common)}


def run_entries(runs: Sequence[Path], update: int | None = None) -> list[ZooEntry]:
    """The seeds of `runs` at checkpoint `update` (None: each run's latest) as zoo entries named
    `<run>-u<update>-s<seed>`; a run without checkpoints, or without that update, is refused by name."""
    out = []
    for run in runs:
        by_update = checkpoints_by_update([run])
        if not by_update:
            raise ValueError(f"{run}: no checkpoints (is it a run directory of `cec train`?)")
        if update is not None and update not in by_update:
            raise ValueError(f"{run}: no checkpoint at update {update}; it has {sorted(by_update)}")
        u = max(by_update) if update is None else update
        [path] = by_update[u]
        out += [
            ZooEntry(f"{run.name}-u{u}-s{seed}", str(path), algorithm="cec", seed=int(seed))
            for seed in read_meta(path)["metadata"]["seeds"]
        ]
    return out


COOK = "cook"


def add_seed_arguments(ap: argparse.ArgumentParser) -> None:
    """The options of an analysis that plays a recipe's seeds: a zoo's entries of one algorithm, or run
    directories at one checkpoint, and optionally the scripted cook beside them (`seed_entries`)."""
    ap.add_argument("--zoo", default="shipped", help="a zoo manifest, or `shipped` (default)")
    ap.add_argument("--algorithm", default="cec", help="the zoo's entries of this algorithm play")
    ap.add_argument("--runs", nargs="+", type=Path, default=[], help="run directories instead of a zoo")
    ap.add_argument("--update", type=int, default=None, help="the runs' checkpoint (default: the latest)")
    ap.add_argument("--with-cook", action="store_true", help="each seed also plays the scripted cook")


def seed_entries(ap: argparse.ArgumentParser, args: argparse.Namespace) -> list[ZooEntry]:
    """The entries `add_seed_arguments` named (the cook last, as `COOK`); a bad choice exits through `ap`
    with the reason."""
    if args.update is not None and not args.runs:
        ap.error("--update picks a checkpoint of --runs; give the run directories too")
    if args.runs:
        try:
            entries = run_entries(args.runs, args.update)
        except ValueError as e:
            ap.error(str(e))
    else:
        zoo = shipped_entries() if args.zoo == "shipped" else load_zoo(args.zoo)
        entries = [e for e in zoo if e.algorithm == args.algorithm]
    return entries + ([ZooEntry(COOK, "", scripted="cook")] if args.with_cook else [])


def play_milestone(name: str, checkpoints: Sequence[Path], levels: Any, config: EvalConfig) -> EpisodeTable:
    """Every seed of `checkpoints` (one update of one population) with every other and itself on `levels`
    (`config.pairs` is replaced by `all`); their algorithm is `milestone_label(name, env steps per seed)`."""
    metas = [read_meta(path) for path in checkpoints]
    steps = {int(m["env_steps"]) for m in metas}
    if len(steps) != 1:
        raise ValueError(f"{name}: the checkpoints {list(checkpoints)} are at different env steps: {steps}")
    label = milestone_label(name, steps.pop())
    entries = [
        ZooEntry(f"{label}-s{seed}", str(path), algorithm=label, seed=int(seed))
        for path, meta in zip(checkpoints, metas, strict=True)
        for seed in meta["metadata"]["seeds"]
    ]
    policies, skipped = load_policies(entries)
    if skipped:
        raise ValueError(f"{label}: checkpoints that cannot be loaded: {skipped}")
    return crossplay(policies, levels, dataclasses.replace(config, pairs="all"))


def milestone_points(table: EpisodeTable, levels: Sequence[str] | None = None) -> list[MilestonePoint]:
    """The cross-play and self-play of every checkpoint in a table of `play_milestone` games, by name and
    env steps, on `levels` (None: every level of the table)."""
    pl = an.pair_level_scores(table, levels)
    points = []
    for label in an.algorithms_of(pl.policies):
        name, _, steps = label.rpartition(SEPARATOR)
        m = an.seed_matrix(pl, label)
        est, sp = crossplay_estimate(m.values), np.diag(m.values)
        seeds = tuple(int(s[1:]) for s in m.labels)
        points.append(MilestonePoint(name, int(steps), seeds, est.mean, est.se, float(sp.mean()), sem(sp)))
    return sorted(points, key=lambda p: (p.name, p.env_steps))


def plot_milestones(points: Sequence[MilestonePoint], path: Path, *, title: str) -> None:
    """Cross-play (solid, ± its jackknife standard error) and self-play (dashed) against env steps per
    seed, one colour per population."""
    from cec.evaluation.plotting import distinct_colours, pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(8, 4.5))
    names = sorted({p.name for p in points})
    for name, colour in zip(names, distinct_colours(len(names)), strict=True):
        mine = [p for p in points if p.name == name]
        steps = [p.env_steps for p in mine]
        ax.errorbar(steps, [p.xp for p in mine], yerr=[p.xp_se for p in mine], fmt="o-", color=colour,
                    capsize=3, label=name)  # fmt: skip
        ax.plot(steps, [p.sp for p in mine], "x--", color=colour)
    ax.plot([], [], "o-", color="k", label="cross-play (XP)")  # the styles once, beside one entry per name
    ax.plot([], [], "x--", color="k", label="self-play (SP)")
    ax.set_xlabel("env steps per seed")
    ax.set_ylabel("team return per episode")
    ax.set_title(title)
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))
    fig.tight_layout()
    path.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(path, dpi=110)
    plt.close(fig)
