"""Cross-play throughput of a line-up with the scripted cook: the networks' games apart from the cook's.

`cec.evaluation.crossplay` plays the games of two networks in a compiled call without the scripted kinds and
only the games with a scripted partner in a call that runs both (`cec.agents.scripted.WithScripted`). The
peer is what it did before (2026-11-28): every game of the line-up in the call with the scripted kinds, so
every env ran the cook's rollout beside the network. Both play the same games with the same random numbers
(the benchmark checks the tables agree), in interleaved rounds after a warm-up that compiles.

`--policies` randomly initialised policies of `--preset` (weights do not change the cost) plus the cook,
every pair in both seat orders and self-play once, one episode per game and level. Reported: episodes/s of
each layout (median over `--repeats`) and their ratio.

    taskset -c 0 python benchmarks/crossplay_cook.py                   # 8 policies + the cook, 20 kitchens
    python benchmarks/crossplay_cook.py --policies 2 --levels cramped_room --max-steps 100 --repeats 1
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import numpy as np

from cec.agents.policy import Policy, scripted_policy
from cec.evaluation.crossplay import (  # the peer reuses the library's internals, as it did before
    _SET_BY_TABLE,
    ARRAY_FIELDS,
    EvalConfig,
    _lineup,
    _play_games,
    _seat_params,
    _stack,
    _to_table,
    crossplay,
    eval_levels,
    plan_games,
    play_fn,
)
from cec.evaluation.results import EpisodeTable

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from crossplay_throughput import policies  # type: ignore[import-not-found]
    from env_throughput import save_result  # type: ignore[import-not-found]
except ImportError:
    from benchmarks.crossplay_throughput import policies
    from benchmarks.env_throughput import save_result

TWENTY = ",".join(f"generated_{i:03d}" for i in range(20))


def every_game_with_the_kinds(pols: list[Policy], levels: Any, config: EvalConfig) -> EpisodeTable:
    """The peer: the line-up's games all in the call with the scripted kinds (the layout before)."""
    task, network, kinds = _lineup(pols, pols[0])
    env_params = pols[0].env.params.replace(max_steps=config.max_steps)
    rows: dict[str, list] = {k: [] for k in ARRAY_FIELDS if k not in _SET_BY_TABLE}
    stacked = _stack([_seat_params(p, network, task, kinds) for p in pols])
    fn = play_fn(task, network, config.max_steps, config.greedy, kinds)
    games = plan_games(pols, levels.names)
    _play_games(games, pols, stacked, fn, levels, env_params, config, rows, None)
    return _to_table(rows, pols[0], env_params, config.max_steps, config.greedy, [])


def _order(table: EpisodeTable) -> np.ndarray:
    columns = (table.policy_a, table.policy_b, table.seat, table.level, table.episode)
    keys = ["|".join(map(str, row)) for row in zip(*columns, strict=True)]
    return table.returns[np.argsort(keys)]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="small", help="network preset (small, reference, paper)")
    ap.add_argument("--policies", type=int, default=8, help="networks in the line-up, besides the cook")
    ap.add_argument("--levels", default=TWENTY, help="level set or names (default: 20 held-out kitchens)")
    ap.add_argument("--max-steps", type=int, default=400, help="episode length (default 400)")
    ap.add_argument("--games-per-call", type=int, default=8, help="games per compiled call (default 8)")
    ap.add_argument("--repeats", type=int, default=3, help="timed line-ups per layout (median reported)")
    ap.add_argument("--out", type=Path, help="results JSON (default: benchmarks/results/...)")
    args = ap.parse_args(argv)

    nets = policies(args.preset, args.policies, args.max_steps)
    pols = [*nets, scripted_policy("cook", "cook", env=nets[0].env, algorithm="cook")]
    levels = eval_levels("overcooked", args.levels)
    config = EvalConfig(episodes=1, max_steps=args.max_steps, games_per_call=args.games_per_call)
    layouts = {
        "apart": lambda: crossplay(pols, levels, config),  # the library
        "one_call": lambda: every_game_with_the_kinds(pols, levels, config),  # the peer
    }
    tables = {name: play() for name, play in layouts.items()}  # warm-up: compiles
    np.testing.assert_array_equal(_order(tables["apart"]), _order(tables["one_call"]))
    episodes = len(tables["apart"])
    print(
        f"{args.policies} networks ({args.preset}) + the cook on {len(levels.names)} levels: {episodes} "
        f"episodes of {args.max_steps} steps per line-up, the same in both layouts",
        flush=True,
    )
    times: dict[str, list[float]] = {name: [] for name in layouts}
    for r in range(args.repeats):  # interleaved rounds
        for name, play in layouts.items():
            t0 = time.perf_counter()
            play()
            times[name].append(time.perf_counter() - t0)
            print(f"round {r + 1}: {name:8s} {times[name][-1]:8.1f} s", flush=True)
    rates = {name: episodes / statistics.median(t) for name, t in times.items()}
    for name, rate in rates.items():
        print(f"{name:8s} {rate:9.1f} episodes/s", flush=True)
    ratio = rates["apart"] / rates["one_call"]
    print(f"apart / one call: {ratio:.2f}x", flush=True)
    fields = {
        "preset": args.preset,
        "policies": args.policies,
        "levels": args.levels,
        "episodes_per_lineup": episodes,
        "max_steps": args.max_steps,
        "games_per_call": args.games_per_call,
        "seconds": times,
        "episodes_per_s": rates,
        "apart_over_one_call": ratio,
    }
    save_result("crossplay_cook", fields, args.out, tag=args.preset)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
