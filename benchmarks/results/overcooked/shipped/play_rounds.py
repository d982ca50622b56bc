"""Rounds of `cec play serve --partner cec`'s default free play (Cramped Room, or `--level`; 200 turn-based
steps, the agent's actions sampled) played through the play server's own `Round` by a scripted "person": the
scripted cook, greedy, with a share `--epsilon` of uniformly random actions (0: a perfectly stubborn person;
the evaluations' cook has 0.05), which steps aside where its route and the agent's collide, or with
`--never-yield` keeps its route and walks into the agent until the agent moves (the person who never gives
way). The browser test `tests/e2e/test_play_browser.py` plays one such round.

    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --epsilon 0 --rounds 12 \\
        cec/shipped/cec758m-s20?
    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --never-yield --rounds 12 \\
        cec/shipped/cec758m-s20?            # --give-way-after 0: the agent never steps aside; --untrained
    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --never-yield --rounds 12 \\
        --level forced_coord cec/shipped/ft758m-forced_coord      # `--partner best` there

The agent steps onto a free cell after `--give-way-after` (3, `cec play serve`'s default) collisions in a
row. Per policy: the team return per round (20 per soup) over `--rounds` round seeds x both seats.
"""

from __future__ import annotations

import argparse
from pathlib import Path

import jax
import numpy as np

from apps.cli import build_parser, parse_args
from cec.agents.policy import load_policy, random_policy
from cec.agents.zoo import ZooEntry
from cec.envs.overcooked.scripted import scripted_actions
from cec.levels.named import resolve_level
from services.play.game import Round, RoundSetup, expand_state
from services.play.main import free_play_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="+", help="exported policy folders (`cec zoo export`)")
    ap.add_argument("--level", default="cramped_room", help="the kitchen (default: free play's)")
    ap.add_argument("--epsilon", type=float, default=0.0, help="the person's share of random actions")
    ap.add_argument("--rounds", type=int, default=12, help="round seeds per seat")
    ap.add_argument("--never-yield", action="store_true", help="the person never steps aside for the agent")
    ap.add_argument("--give-way-after", type=int, default=3, help="as `cec play serve`'s (0: never)")
    ap.add_argument("--untrained", action="store_true", help="also an untrained network (a control)")
    args = ap.parse_args()
    serve = ["play", "serve", "--partner", "cec", "--give-way-after", str(args.give_way_after)]
    study = free_play_config(parse_args(build_parser(), serve))
    _, level = resolve_level(args.level, Path.cwd(), np.random.default_rng(0))
    key = jax.random.PRNGKey(0)
    yields = not args.never_yield
    person = jax.jit(lambda s, t: scripted_actions(jax.random.fold_in(key, t), s, args.epsilon, yields))
    policies = [load_policy(ZooEntry(Path(path).name, path)) for path in args.policies]
    if args.untrained:  # the control: what the person scores with a partner that learned nothing
        policies.append(random_policy("untrained", jax.random.PRNGKey(1), network=policies[0].network))
    for policy in policies:
        returns, collisions = [], []
        for seat in (0, 1):
            for seed in range(args.rounds):
                r = Round(RoundSetup(policy, args.level, level, seat, 200, study.mode, seed), study)
                state, _ = r.start()
                while not r.done:
                    action = int(person(expand_state(state, level), r.t)[seat])
                    state = r.step(action, with_branches=False).state
                returns.append(r.team_return)
                collisions.append(r.collisions)
        ret = np.array(returns)
        print(
            f"{policy.name}: {ret.mean():.1f} per round, {int(np.sum(ret == 0))} of {ret.size} rounds "
            f"without a soup, {np.mean(collisions):.0f} collisions per round",
            flush=True,
        )


if __name__ == "__main__":
    main()
