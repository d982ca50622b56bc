"""Rounds of `cec play serve --partner cec`'s default free play (Cramped Room, or `--level`; 200 turn-based
steps, the agent's actions sampled) played through the play server's own `Round` by a scripted "person": the
scripted cook, greedy, with a share `--epsilon` of uniformly random actions (0: a perfectly stubborn person;
the evaluations' cook has 0.05), which steps aside where its route and the agent's collide, or with
`--never-yield` keeps its route and walks into the agent until the agent moves (the person who never gives
way); or with `--proxy` a behaviour-cloned proxy of people (its sampled actions). The browser test
`tests/e2e/test_play_browser.py` plays one such round.

    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --epsilon 0 --rounds 12 \\
        cec/shipped/cec758m-s20?
    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --never-yield --rounds 12 \\
        cec/shipped/cec758m-s20?            # --give-way-after 0: the agent never steps aside; --untrained
    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --never-yield --rounds 12 \\
        --level forced_coord cec/shipped/ft758m-forced_coord      # `--partner best` there
    .venv/bin/python benchmarks/results/overcooked/shipped/play_rounds.py --rounds 12 \\
        --proxy cec/shipped/hp_cramped_room --untrained cec/shipped/cec758m-s20?   # a cloned person

The agent steps onto a free cell after `--give-way-after` (3, `cec play serve`'s default) collisions in a
row. Per policy: the team return per round (20 per soup) over `--rounds` round seeds x both seats.
"""

from __future__ import annotations

import argparse
from pathlib import Path
from typing import Any

import jax
import jax.numpy as jnp
import numpy as np

from apps.cli import build_parser, parse_args
from cec.agents.network import ActorCritic, empty_history
from cec.agents.policy import load_policy, random_policy
from cec.agents.zoo import ZooEntry
from cec.envs import overcooked as oc
from cec.envs.overcooked.scripted import scripted_actions
from cec.envs.overcooked.state import NUM_ACTIONS
from cec.levels.named import resolve_level
from services.play.game import Round, RoundSetup, act, expand_state
from services.play.main import free_play_config


class Proxy:
    """A behaviour-cloned person: its policy's sampled action on its seat's view, its memory kept over a
    round."""

    def __init__(self, path: str, env: Any) -> None:
        self.policy = load_policy(ZooEntry(Path(path).name, path))
        network = ActorCritic(self.policy.network, NUM_ACTIONS)
        self.carry0 = network.initial_carry((1,))
        history = empty_history((1, 1), network.config.partner_history)

        def step(lstm: Any, state: Any, seat: jax.Array, first: jax.Array, key: jax.Array) -> Any:
            obs = oc.get_obs(state, env)[seat]
            return act(network, self.policy.params, lstm, obs, first, history, key, False)

        self._act = jax.jit(step)

    def start(self, seed: int) -> None:
        self.lstm, self.key, self.first = self.carry0, jax.random.PRNGKey(1000 + seed), True

    def act(self, state: Any, seat: int) -> int:
        self.key, sub = jax.random.split(self.key)
        self.lstm, action = self._act(self.lstm, state, jnp.int32(seat), jnp.asarray(self.first), sub)
        self.first = False
        return int(action)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("policies", nargs="+", help="exported policy folders (`cec zoo export`)")
    ap.add_argument("--level", default="cramped_room", help="the kitchen (default: free play's)")
    ap.add_argument("--epsilon", type=float, default=0.0, help="the person's share of random actions")
    ap.add_argument("--rounds", type=int, default=12, help="round seeds per seat")
    ap.add_argument("--never-yield", action="store_true", help="the person never steps aside for the agent")
    ap.add_argument("--give-way-after", type=int, default=3, help="as `cec play serve`'s (0: never)")
    ap.add_argument("--untrained", action="store_true", help="also an untrained network (a control)")
    ap.add_argument(
        "--proxy", help="the person is this behaviour-cloned proxy (e.g. cec/shipped/hp_cramped_room)"
    )
    args = ap.parse_args()
    serve = ["play", "serve", "--partner", "cec", "--give-way-after", str(args.give_way_after)]
    study = free_play_config(parse_args(build_parser(), serve))
    _, level = resolve_level(args.level, Path.cwd(), np.random.default_rng(0))
    key = jax.random.PRNGKey(0)
    yields = not args.never_yield
    cook = jax.jit(lambda s, t: scripted_actions(jax.random.fold_in(key, t), s, args.epsilon, yields))
    proxy = Proxy(args.proxy, study.env) if args.proxy else None
    policies = [load_policy(ZooEntry(Path(path).name, path)) for path in args.policies]
    if args.untrained:  # the control: what the person scores with a partner that learned nothing
        policies.append(random_policy("untrained", jax.random.PRNGKey(1), network=policies[0].network))
    for policy in policies:
        returns, collisions = [], []
        for seat in (0, 1):
            for seed in range(args.rounds):
                r = Round(RoundSetup(policy, args.level, level, seat, 200, study.mode, seed), study)
                state, _ = r.start()
                if proxy:
                    proxy.start(seed)
                while not r.done:
                    full = expand_state(state, level)
                    action = proxy.act(full, seat) if proxy else int(cook(full, r.t)[seat])
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
