"""Time to skill: held-out cross-play of a training recipe against the core-hours it cost, at its milestones.

Recipes are compared by what they buy per core-hour (cross-play with partners a seed never met, in kitchens
it never saw), not by training return. For each run directory (one `cec train` run of S >= 2 vmapped seeds
with `checkpoint.milestones`), every milestone checkpoint's seeds play each other and themselves on the 100
held-out kitchens (400-step episodes, sampled actions, both seat orders, `--episodes` per pairing and
kitchen); the cost of a milestone is the run's recorded training time up to it (from `metrics.csv`: each
update's env steps over its env-steps/s) divided by its seeds, i.e. core-hours per seed when the run had
one core. Cross-play is the mean over every pair of two different seeds with its jackknife standard error
over seeds (`cec.evaluation.stats.crossplay_estimate`; none with 2 seeds).

Train the runs first, one core each, the same budget, e.g. (the two probes of
research/diary/reproduce_overcooked.md):

    M='checkpoint.milestones=[0.25,0.5,0.75,1.0]'
    taskset -c 0 cec train --config configs/train/cec_overcooked_cpu.yaml seed=300 num_seeds=2 \\
        total_env_steps=5242880 "$M" run_dir=runs/probes name=tts-e128
    taskset -c 1 cec train --config configs/train/cec_overcooked_cpu.yaml seed=300 num_seeds=2 \\
        num_envs=1024 ppo.num_minibatches=8 total_env_steps=5242880 updates_per_call=1 \\
        checkpoint.every_updates=5 "$M" run_dir=runs/probes name=tts-e1024
    python benchmarks/time_to_skill.py runs/probes/tts-e128 runs/probes/tts-e1024 \\
        --out research/diary/reproduce_overcooked/tts

Seeds of one recipe trained in separate processes (one per core, e.g. seeds 300-301 and 302-303) are one
population with `--join NAME RUN RUN`: at each update both saved, all their seeds play each other.

`--with OUT.json` adds the rows of earlier evaluations (each row keeps its machine-time cost) without
playing them again, also for a run named again: evaluate a run while it trains, then again with `--with`
the first output, and only the checkpoints saved since are played.
"""

from __future__ import annotations

import argparse
import csv
import datetime
import json
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cec.checkpoints import META_FILE, STATE_FILE, CheckpointError
from cec.config import load_config
from cec.evaluation.crossplay import EvalConfig, eval_levels
from cec.evaluation.milestones import checkpoints_by_update, milestone_points, play_milestone
from cec.levels.kinds import validation_parts
from cec.levels.level import unstack_levels
from cec.training.config import TrainConfig, split_paths
from cec.training.run import config_dict

STALL = 5.0  # an update at under 1/STALL of the run's median env-steps/s was stalled, not slow


def training_seconds(run: Path) -> tuple[dict[int, float], int]:
    """({update: seconds of training up to and including it}, stalled updates) from the run's metrics (one
    row per seed and update; the env-steps/s of a row counts every seed's steps). An update whose rate is
    under 1/STALL of the run's median (the process was stopped, e.g. SIGSTOP while the machine measured
    something else, or the laptop slept) counts at the median rate: the recipe's cost, not the pause's."""
    per_update: dict[int, tuple[float, float]] = {}
    seed_set: set[str] = set()
    with (run / "metrics.csv").open() as f:
        for row in csv.DictReader(f):
            u = int(row["update"])
            steps, sps = float(row["env_steps"]), float(row["env_steps_per_s"])
            per_update.setdefault(u, (steps, sps))
            seed_set.add(row["seed"])
    median = float(np.median([sps for _, sps in per_update.values()]))
    out, total, last_steps, seeds, stalled = {}, 0.0, 0.0, len(seed_set), 0
    for u in sorted(per_update):
        steps, sps = per_update[u]
        if sps < median / STALL:
            sps, stalled = median, stalled + 1
        total += (steps - last_steps) * seeds / max(sps, 1e-9)  # one seed's steps, every seed's rate
        out[u], last_steps = total, steps
    return out, stalled


def _config(run: Path) -> dict[str, Any]:
    config = yaml.safe_load((run / "config.yaml").read_text())
    if not isinstance(config, dict):
        raise SystemExit(f"{run / 'config.yaml'} is not a training config (a mapping); give a run directory")
    return config


def _recipe(run: Path) -> dict[str, Any]:
    """The run's training config without what tells its processes apart (seed, name); an `init_from`
    checkpoint of a run directory stands as that run's recipe and the checkpoint's name, so processes that
    each continue their own seed of one recipe (`init_from=<run of seed i>/checkpoints/update_N`) agree.
    Read through `TrainConfig`, so that a setting added since a run started counts as its default there."""
    _config(run)  # a clear exit for a file that is no config
    config = config_dict(load_config(TrainConfig, run / "config.yaml"))
    recipe = {k: v for k, v in config.items() if k not in ("seed", "name")}
    if recipe.get("init_from"):
        recipe["init_from"] = [_source(Path(p)) for p in split_paths(str(recipe["init_from"]))]
    return recipe


def _source(checkpoint: Path) -> Any:
    """What an `init_from` path says of where a run started: its run's recipe and the checkpoint's name
    when it is a checkpoint of a run directory, else the path as given."""
    run = checkpoint.parent.parent
    if checkpoint.parent.name == "checkpoints" and (run / "config.yaml").is_file():
        return {"run": _recipe(run), "checkpoint": checkpoint.name}
    return str(checkpoint)


def _seeds(run: Path) -> set[int]:
    """The seeds the run trains: `seed` .. `seed + num_seeds - 1` of its config (the defaults 0 and 1)."""
    config = _config(run)
    first, count = config.get("seed", 0), config.get("num_seeds", 1)
    return set(range(int(first), int(first) + int(count)))


def check_population(runs: list[Path], name: str) -> None:
    """`SystemExit` unless `runs` are distinct runs of one recipe with no seed in common: a run given twice,
    or two runs of one seed, would count a policy playing itself as cross-play."""
    if len(runs) == 1:
        return  # one run: its seeds are distinct by construction
    seen: dict[Path, Path] = {}
    for run in runs:
        real = run.resolve()
        if real in seen:
            raise SystemExit(f"{name}: {run} is given twice (as {seen[real]} too); give each run once")
        seen[real] = run
    if any(_recipe(run) != _recipe(runs[0]) for run in runs[1:]):
        raise SystemExit(f"{name}: the runs joined differ in more than seed and name: {runs}")
    owner: dict[int, Path] = {}
    for run in runs:
        for seed in sorted(_seeds(run)):
            if seed in owner:
                raise SystemExit(
                    f"{name}: seed {seed} is trained by both {owner[seed]} and {run}: joined runs must be "
                    "different seeds of one recipe (a seed meeting itself is self-play, not cross-play); "
                    "leave one of them out"
                )
            owner[seed] = run


def evaluate(
    runs: list[Path], episodes: int, done: frozenset[tuple[str, int]] = frozenset(), name: str = ""
) -> list[dict[str, Any]]:
    """One row per checkpoint update (milestones and latest) that every run saved and `done` ((name,
    update) pairs already evaluated) does not hold: env steps per seed, core-hours per seed, XP and SP on
    the held-out kitchens (`cec.evaluation.milestones`). Several runs are one recipe's seeds trained in
    separate processes (`--join`): their seeds play each other as one population, and a seed's cost is
    their training time over all their seeds."""
    name = name or runs[0].name
    check_population(runs, name)
    seconds, stalled = [], 0
    for run in runs:
        run_seconds, run_stalled = training_seconds(run)
        seconds.append(run_seconds)
        stalled += run_stalled
        if run_stalled:
            print(
                f"{run.name}: {run_stalled} stalled update(s) counted at its median env-steps/s", flush=True
            )
    levels = eval_levels("overcooked", "validation")
    parts = validation_parts(dict(zip(levels.names, unstack_levels(levels.levels), strict=True)))
    config = EvalConfig(episodes=episodes, max_steps=400)
    rows = []
    for update, checkpoints in checkpoints_by_update(runs).items():
        if (name, update) in done:
            continue
        try:
            table = play_milestone(name, checkpoints, levels, config)
        except (CheckpointError, FileNotFoundError):
            if all((c / META_FILE).is_file() and (c / STATE_FILE).is_file() for c in checkpoints):
                raise  # there and unreadable: corrupt, refused
            # gone while this ran: a run still training keeps only its latest checkpoint besides milestones
            print(f"{name} update {update}: skipped, its run replaced the checkpoint with a newer one")
            continue
        points = {part: milestone_points(table, names)[0] for part, names in parts.items()}
        point = points["generated"]
        by_part = {
            part: {"levels": len(parts[part]), "xp": p.xp, "xp_se": p.xp_se, "sp": p.sp, "sp_se": p.sp_se}
            for part, p in points.items()
        }
        cost = sum(s.get(update, float("nan")) for s in seconds) / len(point.seeds) / 3600
        rows.append(
            {
                "run": name,
                "runs": [run.name for run in runs],
                "update": update,
                "env_steps_per_seed": point.env_steps,
                "core_hours_per_seed": cost,
                "xp": point.xp,
                "xp_se": point.xp_se,
                "sp": point.sp,
                "sp_se": point.sp_se,
                "seeds": list(point.seeds),
                "stalled_updates_at_median_rate": stalled,
                "parts": by_part,
            }  # fmt: skip
        )
        se = "" if np.isnan(point.xp_se) else f" +- {point.xp_se:.1f}"
        split = ", ".join(
            f"{k} XP {v['xp']:.1f} SP {v['sp']:.1f}" for k, v in by_part.items() if k != "generated"
        )
        print(
            f"{name} update {update}: {point.env_steps:,} steps/seed, {cost:.3f} core-h/seed | "
            f"XP {point.xp:.1f}{se} | SP {point.sp:.1f} ({len(point.seeds)} seeds) | " + split,
            flush=True,
        )
    return rows


def plot(rows: list[dict[str, Any]], path: Path) -> None:
    from cec.evaluation.plotting import distinct_colours, pyplot

    plt = pyplot()
    fig, ax = plt.subplots(figsize=(9, 4.5))
    runs = sorted({r["run"] for r in rows})
    for run, colour in zip(runs, distinct_colours(len(runs)), strict=True):
        mine = sorted((r for r in rows if r["run"] == run), key=lambda r: r["core_hours_per_seed"])
        hours = [r["core_hours_per_seed"] for r in mine]
        ax.plot(hours, [r["xp"] for r in mine], "o-", color=colour, label=run)
        ax.plot(hours, [r["sp"] for r in mine], "x--", color=colour)
    ax.plot([], [], "o-", color="k", label="cross-play (XP)")  # one entry per run, the styles once
    ax.plot([], [], "x--", color="k", label="self-play (SP)")
    ax.axhline(20, color="grey", lw=0.8, ls=":")
    ax.set_xlabel("core-hours per seed (this CPU, one core per run)")
    ax.set_ylabel("team return per 400 steps, 100 held-out kitchens")
    ax.set_title("time to skill")
    ax.legend(fontsize=7, loc="upper left", bbox_to_anchor=(1.01, 1.0))  # beside the curves, not over them
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("runs", nargs="*", type=Path, help="run directories with milestone checkpoints")
    ap.add_argument("--episodes", type=int, default=1, help="episodes per pairing, seat order and kitchen")
    ap.add_argument(
        "--with", dest="earlier", nargs="+", type=Path, default=[], metavar="JSON",
        help="rows of earlier outputs (OUT.json) to show beside the new ones, not evaluated again",
    )  # fmt: skip
    ap.add_argument(
        "--join", metavar="NAME",
        help="the runs are one recipe's seeds trained in separate processes: evaluate them together as NAME",
    )  # fmt: skip
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.json and OUT.png")
    args = ap.parse_args(argv)
    if not (args.runs or args.earlier):
        ap.error("give run directories and/or --with OUT.json of earlier evaluations")
    missing = [str(run) for run in args.runs if not (run / "metrics.csv").is_file()]
    if missing:  # before any evaluation starts: a mistyped or unexpanded path ("s40{0,1}" under sh)
        ap.error(f"not a training run (no metrics.csv): {', '.join(missing)}; give each run's directory")
    rows = [r for path in args.earlier for r in json.loads(path.read_text())["rows"]]
    done = frozenset((r["run"], r["update"]) for r in rows)  # a run still training: only what is new
    groups = [(args.runs, args.join)] if args.join else [([run], run.name) for run in args.runs]
    rows += [r for runs, name in groups for r in evaluate(runs, args.episodes, done, name)]
    from apps.machine import machine_info

    args.out.parent.mkdir(parents=True, exist_ok=True)
    result = {"benchmark": "time_to_skill", "date": datetime.date.today().isoformat(),
              "machine": machine_info(), "episodes": args.episodes, "rows": rows}  # fmt: skip
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1, default=float) + "\n")
    plot(rows, args.out.with_suffix(".png"))
    print(f"wrote {args.out.with_suffix('.json')} and {args.out.with_suffix('.png')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
