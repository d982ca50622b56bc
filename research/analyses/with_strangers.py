"""Seeds with partners that never trained beside them or their teacher: human proxies and the shipped seeds.

Cross-play between the seeds of one recipe tests partners they never met, but not conventions they never
learned: seeds that share a teacher (lever (q) of research/diary/reproduce_overcooked.md, kickstarting from
the scripted cook) may meet each other half-way because each learned the teacher's ways. This plays each group
of runs' seeds at one checkpoint with partners from outside:

- the human proxies (`cec/shipped/hp_<kitchen>`, behaviour-cloned from people's games), each in its own
  classic kitchen, `--episodes` per seat order;
- the shipped CEC seeds (`cec/shipped/cec758m-s20*`, the paper-scale recipe, 758M env steps per seed, never
  played the cook), on the 100 generated validation kitchens, one episode per seat order and kitchen.

400-step episodes, sampled actions, the evaluation's keys. Give the recipe under test and a control of the
same budget as groups, e.g. (update 320: 2.6M env steps per seed):

    python research/analyses/with_strangers.py --update 320 \
        --out research/diary/reproduce_overcooked/levers/strangers_u320 \
        --group teacher runs/levers/teacher-s400 runs/levers/teacher-s402 \
        --group cooktaken runs/levers/cooktaken-s400 runs/levers/cooktaken-s402

Per group: the mean over its seeds with the standard error over them (each seed's mean over its episodes;
the partners are the same for every seed, so the error is over the group's seeds only). Writes OUT.csv.bz2
(every episode), OUT.json and OUT.md.
"""

from __future__ import annotations

import argparse
import statistics
from pathlib import Path
from typing import Any

from cec.agents.policy import load_policies
from cec.agents.zoo import ZooEntry
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
from cec.evaluation.milestones import run_entries
from cec.evaluation.results import EpisodeTable
from cec.levels.classic import CLASSIC_NAMES

try:  # run as a script (research/analyses/ on sys.path) or as a module
    from with_cook import run_meta, save_episodes, save_summary  # type: ignore[import-not-found]
except ImportError:
    from research.analyses.with_cook import run_meta, save_episodes, save_summary

SHIPPED = Path(__file__).resolve().parents[2] / "cec" / "shipped"
SHIPPED_SEEDS = [f"cec758m-s{s}" for s in (200, 201, 202, 203)]
GENERATED = "generated"


def _play(entries: list[ZooEntry], levels: str, pairs: str, episodes: int, max_steps: int) -> EpisodeTable:
    policies, skipped = load_policies(entries)
    if skipped:
        raise SystemExit("could not load: " + "; ".join(f"{s.name}: {s.reason}" for s in skipped))
    config = EvalConfig(levels=levels, episodes=episodes, max_steps=max_steps, pairs=pairs)
    return crossplay(policies, eval_levels("overcooked", levels), config, progress=print)


def play(groups: dict[str, list[ZooEntry]], episodes: int, max_steps: int) -> EpisodeTable:
    seeds = [e for entries in groups.values() for e in entries]
    tables = []
    for kitchen in CLASSIC_NAMES:
        proxy = ZooEntry(f"hp_{kitchen}", str(SHIPPED / f"hp_{kitchen}"), algorithm="human_proxy", seed=0)
        tables.append(_play([*seeds, proxy], kitchen, f"with:{proxy.name}", episodes, max_steps))
    for name in SHIPPED_SEEDS:
        shipped = ZooEntry(name, str(SHIPPED / name), algorithm="cec")
        tables.append(_play([*seeds, shipped], GENERATED, f"with:{name}", 1, max_steps))
    return EpisodeTable.concat(tables)


def summarise(table: EpisodeTable, groups: dict[str, list[str]]) -> dict[str, Any]:
    """{group: {part: {mean, se, seeds}}}, the parts: each classic kitchen with its proxy, all five, and
    the generated kitchens with the shipped seeds."""
    rows = list(zip(table.policy_a, table.policy_b, table.level, table.returns, strict=True))
    out: dict[str, Any] = {}
    for group, seeds in groups.items():
        parts: dict[str, dict[str, list[float]]] = {}
        for a, b, level, ret in rows:
            seed = a if a in seeds else b if b in seeds else None
            if seed is None:
                continue
            stranger = b if seed == a else a
            if stranger.startswith("hp_"):
                keys: tuple[str, ...] = (f"{level} with its proxy", "classic five with the proxies")
            else:
                keys = ("generated with the shipped seeds",)
            for key in keys:
                parts.setdefault(key, {}).setdefault(seed, []).append(float(ret))
        out[group] = {}
        for part, by_seed in parts.items():
            means = [statistics.fmean(v) for v in by_seed.values()]
            se = statistics.stdev(means) / len(means) ** 0.5 if len(means) > 1 else None
            out[group][part] = {"mean": statistics.fmean(means), "se": se, "seeds": len(means)}
    return out


def markdown(summary: dict[str, Any], meta: dict[str, Any]) -> str:
    parts = sorted({p for g in summary.values() for p in g}, key=lambda p: (p.startswith("generated"), p))
    lines = [
        "# Seeds with partners from outside their recipe",
        "",
        f"{meta['date']}, {meta['machine']}; `{meta['command']}`. Team return per {meta['max_steps']}-step "
        "episode (20 per soup), mean over each group's seeds ± the standard error over them.",
        "",
        "| part | " + " | ".join(summary) + " |",
        "|---|" + "---|" * len(summary),
    ]
    for part in parts:
        cells = []
        for group in summary:
            r = summary[group].get(part)
            cells.append("-" if r is None else f"{r['mean']:.1f}" + (f" ± {r['se']:.1f}" if r["se"] else ""))
        lines.append(f"| {part} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--group", nargs="+", action="append", required=True, metavar="NAME RUN",
        help="a name, then the run directories of one recipe's seeds (repeat per recipe)",
    )  # fmt: skip
    ap.add_argument("--update", type=int, default=None, help="the checkpoint's update (default: the latest)")
    ap.add_argument("--episodes", type=int, default=4, help="episodes per seat order with each proxy")
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.csv.bz2, OUT.json and OUT.md")
    args = ap.parse_args(argv)
    groups: dict[str, list[ZooEntry]] = {}
    for name, *runs in args.group:
        if not runs:
            ap.error(f"--group {name}: give the run directories after the name")
        try:
            groups[name] = run_entries([Path(r) for r in runs], args.update)
        except ValueError as e:
            raise SystemExit(str(e)) from None
    table = play(groups, args.episodes, args.max_steps)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    save_episodes(table, args.out)
    summary = summarise(table, {g: [e.name for e in entries] for g, entries in groups.items()})
    meta = run_meta("with_strangers.py", argv, max_steps=args.max_steps)
    save_summary(args.out, {"meta": meta, "groups": summary}, markdown(summary, meta))
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
