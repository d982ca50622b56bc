"""Seeds with the scripted cook in the validation kitchens that need a hand-over, beside the same seeds with
each other: is the exchange learned with a partner that does its half, and does it carry over to a copy?
(research/diary/reproduce_overcooked.md, levers (m) and (n)).

Every pair of the line-up, the seeds of the runs at one checkpoint plus `cook` (Overcooked's scripted cook)
and `noop` (a partner that stands still), plays every seat order once, one 400-step episode with sampled
actions per kitchen (the evaluation's keys), on the 24 validation kitchens where neither seat can finish a
soup alone (`cec.levels.kinds`, `hand-over needed`). Read per seed: with the cook, with itself, with the other
seeds; the controls: the cook with the still partner (it cannot deliver alone there) and two cooks. With the
cook, the learner's episodes are split by its side of the kitchen: whether the floor region it starts in
reaches the onion pile (it holds the first half of the exchange, passing onions) or not (it takes them).

    L=research/diary/reproduce_overcooked/levers
    python research/analyses/with_cook.py --runs runs/levers/cookanneal-s400 runs/levers/cookanneal-s402 \\
        --out $L/cookanneal_with_cook_u1280    # the latest checkpoints
    python research/analyses/with_cook.py --runs ... --update 640 --out ...         # a milestone

    L=research/diary/reproduce_overcooked/levers/cookho_with_cook_u1280    # re-read a committed table:
    python research/analyses/with_cook.py --from-csv $L.csv.bz2 --out $L

Writes OUT.csv.bz2 (every episode, when it plays), OUT.json and OUT.md (the summary).
"""

from __future__ import annotations

import argparse
import bz2
import datetime
import json
import shutil
import statistics
import sys
from pathlib import Path
from typing import Any

import numpy as np

from cec.agents.policy import load_policies
from cec.agents.zoo import ZooEntry
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from cec.evaluation.milestones import run_entries
from cec.evaluation.results import EpisodeTable, read_csv, write_csv
from cec.levels.kinds import subsets
from cec.levels.level import REQUIRED_TILES, Tile, unstack_levels
from cec.levels.solvability import reaches

PART = "hand-over needed"
COOK, NOOP = "cook", "noop"


def entries(runs: list[Path], update: int | None) -> list[ZooEntry]:
    """The seeds of `runs` at checkpoint `update` (None: each run's latest), then the cook and the noop."""
    try:
        seeds = run_entries(runs, update)
    except ValueError as e:
        raise SystemExit(str(e)) from None
    return seeds + [ZooEntry(COOK, "", scripted="cook"), ZooEntry(NOOP, "", scripted="noop")]


def onion_side(levels: dict[str, Any]) -> dict[str, tuple[bool, ...]]:
    """{kitchen: (seat 0 reaches an onion pile, seat 1 does)}."""
    onion = REQUIRED_TILES.index(Tile.ONION_PILE)
    out = {}
    for name, lv in levels.items():
        out[name] = tuple(
            bool(np.asarray(reaches(lv.grid, lv.agent_pos[s], REQUIRED_TILES))[onion]) for s in (0, 1)
        )
    return out


def _mean(xs: list[float]) -> float | None:
    return statistics.fmean(xs) if xs else None


def summarise(table: EpisodeTable, seeds: list[str], sides: dict[str, tuple[bool, ...]]) -> dict[str, Any]:
    """Per seed and for the controls: mean team return per episode and share of episodes that deliver."""

    def episodes(a: str, b: str) -> list[int]:  # rows of a with b in either seat order
        pa, pb = table.policy_a, table.policy_b
        return [i for i in range(len(table)) if {pa[i], pb[i]} == {a, b} and (a != b or pa[i] == pb[i])]

    def read(rows: list[int]) -> dict[str, Any]:
        ret = [float(table.returns[i]) for i in rows]
        return {"episodes": len(rows), "return": _mean(ret), "delivered": _mean([float(r > 0) for r in ret])}

    per_seed: dict[str, Any] = {}
    sides_of_all: dict[str, list[int]] = {"onion": [], "other": []}
    for s in seeds:
        with_cook = episodes(s, COOK)
        # the learner's seat: `seat` is policy_a's; with the cook as policy_a, the learner sits in the other
        learner_seat = {
            i: (table.seat[i] if table.policy_a[i] == s else 1 - table.seat[i]) for i in with_cook
        }
        giver = [i for i in with_cook if sides[table.level[i]][learner_seat[i]]]
        taker = [i for i in with_cook if not sides[table.level[i]][learner_seat[i]]]
        sides_of_all["onion"] += giver
        sides_of_all["other"] += taker
        others = [i for o in seeds if o != s for i in episodes(s, o)]
        per_seed[s] = {
            "with_cook": read(with_cook),
            "with_cook_on_the_onion_side": read(giver),
            "with_cook_on_the_other_side": read(taker),
            "self_play": read(episodes(s, s)),
            "cross_play": read(others),
        }
    pairs = [i for i in range(len(table)) if table.policy_a[i] in seeds and table.policy_b[i] in seeds]
    xp = [i for i in pairs if table.policy_a[i] != table.policy_b[i]]
    return {
        "per_seed": per_seed,
        "seeds_with_cook": read([i for s in seeds for i in episodes(s, COOK)]),
        "seeds_with_cook_on_the_onion_side": read(sides_of_all["onion"]),
        "seeds_with_cook_on_the_other_side": read(sides_of_all["other"]),
        "seeds_cross_play": read(xp),
        "seeds_self_play": read([i for i in pairs if table.policy_a[i] == table.policy_b[i]]),
        "cook_with_noop": read(episodes(COOK, NOOP)),
        "cook_with_cook": read(episodes(COOK, COOK)),
    }


def _fmt(r: dict[str, Any]) -> str:
    if r["return"] is None:
        return "-"
    return f"{r['return']:.1f} ({100 * r['delivered']:.0f}%)"


def markdown(summary: dict[str, Any], meta: dict[str, Any]) -> str:
    lines = [
        f"# With the cook in the {meta['kitchens']} validation kitchens that need a hand-over",
        "",
        f"Generated {meta['date']} on {meta['machine']} by `{meta['command']}`: one {meta['max_steps']}-step "
        "episode per seat order and kitchen, sampled actions. Team return per episode (20 per soup), the "
        "share of episodes that deliver in brackets.",
        "",
        "| seed | with the cook | ... on the onion side | ... on the other side | with itself | with the "
        "other seeds |",
        "|---|---|---|---|---|---|",
    ]
    keys = ("with_cook", "with_cook_on_the_onion_side", "with_cook_on_the_other_side", "self_play")
    for seed, r in summary["per_seed"].items():
        lines.append(f"| {seed} | " + " | ".join(_fmt(r[k]) for k in (*keys, "cross_play")) + " |")
    lines += [
        "",
        f"All seeds with the cook {_fmt(summary['seeds_with_cook'])} (on the onion side "
        f"{_fmt(summary['seeds_with_cook_on_the_onion_side'])} in "
        f"{summary['seeds_with_cook_on_the_onion_side']['episodes']} episodes, on the other "
        f"{_fmt(summary['seeds_with_cook_on_the_other_side'])} in "
        f"{summary['seeds_with_cook_on_the_other_side']['episodes']}), with each other "
        f"{_fmt(summary['seeds_cross_play'])}, self-play {_fmt(summary['seeds_self_play'])}; controls: the "
        f"cook with a partner that stands still {_fmt(summary['cook_with_noop'])}, two cooks "
        f"{_fmt(summary['cook_with_cook'])}.",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--runs", nargs="+", type=Path, default=[], help="run directories of `cec train`")
    ap.add_argument("--update", type=int, default=None, help="the checkpoint's update (default: the latest)")
    ap.add_argument("--from-csv", type=Path, help="summarise this table of an earlier run instead of playing")
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.csv.bz2, OUT.json and OUT.md")
    args = ap.parse_args(argv)
    if bool(args.runs) == bool(args.from_csv):
        ap.error("give either --runs (to play) or --from-csv (to read an earlier table)")

    levels = eval_levels("overcooked", "validation")
    named = dict(zip(levels.names, unstack_levels(levels.levels), strict=True))
    kitchens = subsets(named)[PART]
    args.out.parent.mkdir(parents=True, exist_ok=True)
    if args.from_csv:
        table = read_csv(args.from_csv)
        seeds = sorted((set(table.policy_a) | set(table.policy_b)) - {COOK, NOOP})
    else:
        policies, skipped = load_policies(entries(args.runs, args.update))
        if skipped:
            raise SystemExit("could not load: " + "; ".join(f"{s.name}: {s.reason}" for s in skipped))
        print(f"{len(policies)} policies x {len(kitchens)} kitchens ({PART})", flush=True)
        config = EvalConfig(levels=",".join(kitchens), episodes=1, max_steps=args.max_steps, pairs="all")
        table = crossplay(policies, eval_levels("overcooked", config.levels), config, progress=print)
        save_episodes(table, args.out)
        seeds = [p.name for p in policies if p.scripted is None]
    summary = summarise(table, seeds, onion_side({k: named[k] for k in kitchens}))
    meta = run_meta("with_cook.py", argv, kitchens=len(kitchens),
                    max_steps=int(table.episode_steps.max()) if len(table) else args.max_steps)  # fmt: skip
    save_summary(args.out, {"meta": meta, **summary}, markdown(summary, meta))
    return 0


def save_episodes(table: EpisodeTable, out: Path) -> None:
    """Every episode as OUT.csv.bz2."""
    csv_path = write_csv(table, out.with_suffix(".csv"))
    with open(csv_path, "rb") as src, bz2.open(out.with_suffix(".csv.bz2"), "wb") as dst:
        shutil.copyfileobj(src, dst)
    csv_path.unlink()


def run_meta(script: str, argv: list[str] | None, **extra: Any) -> dict[str, Any]:
    """The date, the machine and the command of a run of `research/analyses/<script>`, then `extra`."""
    from apps.machine import machine_info

    info = machine_info()
    args = sys.argv[1:] if argv is None else argv
    return {
        "date": datetime.date.today().isoformat(),
        "machine": f"{info['cpu']}, {info['cpu_count']} cores",
        "command": f"python research/analyses/{script} " + " ".join(args),
        **extra,
    }


def save_summary(out: Path, data: dict[str, Any], text: str) -> None:
    """OUT.json (`data`) and OUT.md (`text`, also printed)."""
    out.with_suffix(".json").write_text(json.dumps(data, indent=1) + "\n")
    out.with_suffix(".md").write_text(text)
    print(text)


if __name__ == "__main__":
    raise SystemExit(main())
