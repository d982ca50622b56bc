"""Where the agents stall in kitchens that need a hand-over: do they put items on a shared counter, does the
partner take them, do soups follow? (`cec.evaluation.handovers`; research/diary/reproduce_overcooked.md,
"Why the hard kitchens fail").

Every seed plays every seed, itself included (self-play beside cross-play), in both seat orders, one
400-step episode with sampled actions per pairing and kitchen (the evaluation's keys: `episode_states`), on
the validation kitchens of the kinds asked (`cec.levels.kinds`). Per kind and for self-play and cross-play
separately: the share of episodes that put anything on a shared counter, in which the partner took an item,
in which a seat served a pot the partner had filled, and that delivered; and the mean counts per episode.

    D=research/diary/reproduce_overcooked
    python research/analyses/handover_analysis.py --out $D/handovers_shipped   # shipped seeds
    python research/analyses/handover_analysis.py --runs runs/levers/cov35-s400 runs/levers/cov35-s402 \\
        --out $D/handovers_cov35      # the latest checkpoints of runs, their seeds
    python research/analyses/handover_analysis.py --runs ... --update 1280 --with-cook \\
        --kinds "hand-over needed" --out ...    # one milestone, and each seed with the scripted cook too

Passes (an item put on a shared counter that only the partner can use: `cec.evaluation.handovers`) are also
read per direction, giver -> receiver: per giver seat and episode, and the shares the receiver took and the
giver took back; with `--with-cook`, in both directions between each seed and the cook (where the cook
gives, where it receives), so a seed's take-up of the cook's passes stands beside its take-up of its own.

Writes OUT.json and OUT.png: the frames of one cross-play episode in Forced Coordination (the pair of the
first two seeds, seat order as listed, episode 0: chosen by that rule, not by what it shows), every 25th
step.
"""

from __future__ import annotations

import argparse
import datetime
import json
from pathlib import Path
from typing import Any

from cec.agents.policy import Policy, load_policies
from cec.evaluation.crossplay import episode_sheet, episode_states, eval_levels
from cec.evaluation.handovers import Handovers, count_handovers, pass_directions, summarise_directions
from cec.evaluation.milestones import COOK, add_seed_arguments, seed_entries
from cec.levels.kinds import subsets
from cec.levels.level import unstack_levels

SHOW_LEVEL, SHOW_EVERY = "forced_coord", 25


def _summary(per_episode: list[Handovers]) -> dict[str, float]:
    n = len(per_episode)

    def share(test: Any) -> float:
        return sum(bool(test(h)) for h in per_episode) / max(n, 1)

    total = sum(per_episode, Handovers.zero())
    return {
        "episodes": n,
        "share_put_on_shared_counter": share(lambda h: h.puts.sum() > 0),
        "share_partner_took": share(lambda h: h.taken.sum() > 0),
        "share_served_partners_pot": share(lambda h: h.pot_serves.sum() > 0),
        "share_delivered": share(lambda h: h.soups > 0),
        "puts_per_episode": float(total.puts.sum()) / max(n, 1),
        "taken_per_episode": float(total.taken.sum()) / max(n, 1),
        "taken_back_per_episode": float(total.taken_back.sum()) / max(n, 1),
        "pot_serves_per_episode": float(total.pot_serves.sum()) / max(n, 1),
        "soups_per_episode": float(total.soups) / max(n, 1),
        "passes_per_episode": float(total.passes.sum()) / max(n, 1),
        "passes_taken_per_episode": float(total.passes_taken.sum()) / max(n, 1),
        "passes_taken_back_per_episode": float(total.passes_taken_back.sum()) / max(n, 1),
        "taken_back_soon_per_episode": float(total.taken_back_soon.sum()) / max(n, 1),
    }


def analyse(policies: list[Policy], kinds: list[str], max_steps: int) -> dict[str, Any]:
    """Every ordered pair of `policies` (a scripted one plays only the others) in the validation kitchens
    of `kinds`: the seeds' self-play (`sp`) and cross-play (`xp`) summaries, and under `passes` the passes
    read per direction (giver -> receiver) in self-play, cross-play and with the cook."""
    levels = eval_levels("overcooked", "validation")
    named = dict(zip(levels.names, unstack_levels(levels.levels), strict=True))
    parts = {k: v for k, v in subsets(named).items() if k in kinds}
    out: dict[str, Any] = {}
    for part, names in parts.items():
        games: dict[str, list[Handovers]] = {"sp": [], "xp": []}
        directions: dict[str, list[tuple[str, str, int, int, int]]] = {"sp": [], "xp": [], COOK: []}
        for i, a in enumerate(policies):
            for j, b in enumerate(policies):
                if a.scripted and b.scripted:
                    continue
                group = COOK if a.scripted or b.scripted else "sp" if i == j else "xp"
                seats = (COOK if a.scripted else "seed", COOK if b.scripted else "seed")
                for name in names:
                    states, _ = episode_states(a, b, named[name], name, max_steps=max_steps)
                    counts = count_handovers(states)
                    if group != COOK:
                        games[group].append(counts)
                    directions[group] += pass_directions(counts, seats)
        out[part] = {
            "levels": len(names),
            **{k: _summary(v) for k, v in games.items()},
            "passes": {k: summarise_directions(v) for k, v in directions.items() if v},
        }
        print(f"{part} ({len(names)} kitchens): " + json.dumps(out[part]), flush=True)
    return out


def picture(policies: list[Policy], path: Path, max_steps: int) -> None:
    levels = eval_levels("overcooked", SHOW_LEVEL)
    level, (a, b) = unstack_levels(levels.levels)[0], policies[:2]
    team_return = episode_sheet(a, b, level, SHOW_LEVEL, path, every=SHOW_EVERY, max_steps=max_steps)
    print(f"{SHOW_LEVEL}: {a.name} + {b.name} returned {team_return:.0f}; frames in {path}")


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    add_seed_arguments(ap)
    ap.add_argument(
        "--kinds", nargs="+", default=["hand-over needed", "one seat alone"], help="kitchen kinds to read"
    )
    ap.add_argument("--max-steps", type=int, default=400)
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.json and OUT.png")
    args = ap.parse_args(argv)
    entries = seed_entries(ap, args)
    policies, skipped = load_policies(entries)
    if skipped or len(policies) < 2:
        raise SystemExit(f"need two or more loadable policies; skipped: {skipped}")
    from apps.machine import machine_info

    result = {
        "benchmark": "handover_analysis",
        "date": datetime.date.today().isoformat(),
        "machine": machine_info(),
        "policies": [p.name for p in policies],
        "max_steps": args.max_steps,
        "kinds": analyse(policies, args.kinds, args.max_steps),
    }
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.with_suffix(".json").write_text(json.dumps(result, indent=1) + "\n")
    picture(policies, args.out.with_suffix(".png"), args.max_steps)
    print(f"wrote {args.out.with_suffix('.json')}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
