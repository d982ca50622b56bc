"""Where the time goes in a kitchen: what the seats carry, which chores of a soup they do and how long the
finished soups wait (`cec.evaluation.chores`; research/diary/reproduce_overcooked.md, "Why Counter Circuit
fails").

Every seed plays every seed, itself included (self-play beside cross-play), in both seat orders,
`--episodes` 400-step episodes with sampled actions per pairing and kitchen (the evaluation's keys:
`episode_states`); with `--with-cook` each seed also plays Overcooked's scripted cook, and the cook
itself (the control: what the kitchen allows). Parts: each classic kitchen on its own, the validation
kitchens of a kind (`cec.levels.kinds`: `loop`, `hand-over needed`, ...) together, so a classic kitchen
stands beside the generated kitchens like it, and Counter Circuit with one thing moved (`VARIANTS`, e.g.
`counter_circuit/window_top`: its delivery window from the end of the middle row to the top row), so what
a kitchen's failure hangs on is measured, not guessed.

    python research/analyses/chores.py --algorithm cec_teacher --with-cook --episodes 4 \
        --parts counter_circuit counter_circuit/window_on_island \
        --out research/diary/reproduce_overcooked/chores_teachcov   # shipped seeds
    python research/analyses/chores.py --runs runs/levers/teachcov-s400 runs/levers/teachcov-s402 \
        --update 1280 --parts counter_circuit loop --out ...     # checkpoints of runs, their seeds

Writes OUT.json (per part and group: `sp`, `xp`, `cook` (a seed with the cook), `cook+cook`), OUT.md
(the table) and OUT.png (the frames of one episode in the first part's first kitchen: the first two seeds,
seat order as listed, episode 0, every 25th step).
"""

from __future__ import annotations

import argparse
import datetime
import itertools
import json
from pathlib import Path
from typing import Any

from cec.agents.policy import Policy, load_policies
from cec.evaluation.chores import Chores, count_chores
from cec.evaluation.crossplay import episode_sheet, episode_states, eval_levels
from cec.evaluation.milestones import COOK, add_seed_arguments, seed_entries
from cec.humans.data import KITCHENS
from cec.levels.ascii import from_ascii
from cec.levels.kinds import subsets
from cec.levels.level import unstack_levels

VARIANTS = {  # Counter Circuit (cec.levels.classic) with one thing moved; the seats start where they do there
    "counter_circuit/rotated": "WWWOOWWW\nW1     W\nX WWWW B\nW    0 W\nWWWPPWWW",  # the control: turned 180
    "counter_circuit/window_top": "WWWPPWXW\nW 0    W\nB WWWW W\nW     1W\nWWWOOWWW",
    "counter_circuit/plates_top": "WBWPPWWW\nW 0    W\nW WWWW X\nW     1W\nWWWOOWWW",
    "counter_circuit/window_and_plates_top": "WBWPPWXW\nW 0    W\nW WWWW W\nW     1W\nWWWOOWWW",
    "counter_circuit/window_on_island": "WWWPPWWW\nW 0    W\nB WWXW W\nW     1W\nWWWOOWWW",
    "counter_circuit/onions_top": "WOWPPWOW\nW 0    W\nB WWWW X\nW     1W\nWWWWWWWW",
}
GROUPS = ("sp", "xp", COOK, "cook+cook")
ROWS = (  # (label, key in a group's summary, item of `carrying` or None)
    ("team return per episode", "return", None),
    ("steps carrying nothing / an onion / a plate / a soup (share)", "carrying", "none/onion/plate/dish"),
    ("steps standing still (share)", "still", None),
    ("onions from a pile", "onions_taken", None),
    ("onions into a pot", "onions_in", None),
    ("soups cooked", "soups_ready", None),
    ("steps a cooked soup waits in its pot", "ready_wait", None),
    ("plates from a pile", "plates_taken", None),
    ("soups plated", "soups_plated", None),
    ("soups delivered", "soups", None),
    ("soups put on a counter", "soups_put_down", None),
    ("items put on a counter", "put_down", None),
    ("... taken back at once by the same seat", "taken_back_soon", None),
)


def _parts(names: list[str]) -> dict[str, dict[str, Any]]:
    """{part: {level name: level}}: a classic kitchen on its own, or the validation kitchens of a kind."""
    classic = eval_levels("overcooked", "classic")
    validation = eval_levels("overcooked", "validation")
    by_name = dict(zip(validation.names, unstack_levels(validation.levels), strict=True))
    by_name |= dict(zip(classic.names, unstack_levels(classic.levels), strict=True))
    kinds = subsets({n: by_name[n] for n in validation.names})
    out: dict[str, dict[str, Any]] = {}
    for part in names:
        if part in VARIANTS:
            out[part] = {part: from_ascii(VARIANTS[part])}
        elif part in KITCHENS:
            out[part] = {part: by_name[part]}
        elif part in kinds:
            out[part] = {n: by_name[n] for n in kinds[part]}
        else:
            raise SystemExit(
                f"unknown part {part!r}: name a classic kitchen ({', '.join(KITCHENS)}), a kind of the "
                f"validation kitchens ({', '.join(kinds)}) or a variant ({', '.join(VARIANTS)})"
            )
    return out


def analyse(
    policies: list[Policy], parts: dict[str, dict[str, Any]], max_steps: int, episodes: int
) -> dict[str, Any]:
    """Per part and group (`GROUPS`): the chores per episode and the team return."""
    out: dict[str, Any] = {}
    for part, levels in parts.items():
        sums: dict[str, tuple[Chores, float, int]] = {}
        for i, a in enumerate(policies):
            for j, b in enumerate(policies):
                scripted = bool(a.scripted) + bool(b.scripted)
                group = "cook+cook" if scripted == 2 else COOK if scripted else "sp" if i == j else "xp"
                for (name, level), seed in itertools.product(levels.items(), range(episodes)):
                    states, team_return = episode_states(a, b, level, name, seed=seed, max_steps=max_steps)
                    chores, total, n = sums.get(group, (Chores.zero(), 0.0, 0))
                    sums[group] = (chores + count_chores(states), total + team_return, n + 1)
        out[part] = {"levels": len(levels)}
        for g, (chores, total, n) in sums.items():
            out[part][g] = {"episodes": n, "return": total / n, **chores.per_episode(n)}
        print(f"{part}: " + json.dumps({g: round(out[part][g]["return"], 1) for g in sums}), flush=True)
    return out


def table(result: dict[str, Any]) -> str:
    """The markdown table: a row per chore, a column per part and group."""
    columns = [(part, g) for part, groups in result.items() for g in GROUPS if g in groups]
    lines = [
        "| per 400-step episode | " + " | ".join(f"{part}: {g}" for part, g in columns) + " |",
        "|---" * (len(columns) + 1) + "|",
    ]
    for label, key, item in ROWS:
        cells = []
        for part, g in columns:
            value = result[part][g][key]
            if item:
                cells.append(" / ".join(f"{value[i]:.2f}" for i in item.split("/")))
            else:
                cells.append(f"{value:.2f}" if key == "still" else f"{value:.1f}")
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_seed_arguments(ap)
    ap.add_argument("--parts", nargs="+", default=["counter_circuit", "coord_ring", "loop"])
    ap.add_argument("--episodes", type=int, default=1, help="episodes per pairing, seat order and kitchen")
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.json, OUT.md and OUT.png")
    args = ap.parse_args(argv)
    parts = _parts(args.parts)
    entries = seed_entries(ap, args)
    policies, skipped = load_policies(entries)
    if skipped or not policies:
        raise SystemExit(f"need one or more loadable policies; skipped: {skipped}")
    from apps.machine import machine_info

    chores = analyse(policies, parts, args.max_steps, args.episodes)
    result = {
        "benchmark": "chores",
        "date": datetime.date.today().isoformat(),
        "machine": machine_info(),
        "policies": [p.name for p in policies],
        "max_steps": args.max_steps,
        "episodes": args.episodes,
        "parts": chores,
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    args.out.with_suffix(".md").write_text(table(chores))
    # the picture: the first part's first kitchen, the first two seeds (seat order as listed), episode 0,
    # every 25th step; chosen by that rule, not by what it shows
    name, level = next(iter(next(iter(parts.values())).items()))
    a, b = policies[0], policies[1 % len(policies)]
    team_return = episode_sheet(a, b, level, name, args.out.with_suffix(".png"), max_steps=args.max_steps)
    print(f"{name}: {a.name} + {b.name} returned {team_return:.0f}; frames in {args.out.with_suffix('.png')}")
    print(table(chores) + f"wrote {args.out.with_suffix('.json')} and .md")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
