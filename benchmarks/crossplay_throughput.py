"""Cross-play evaluation throughput: a 6 x 6 seed matrix over the 105 held-out levels.

Six randomly initialised policies (the network preset is an option; weights do not change the cost), every
pair in both seat orders and self-play once (36 games), one episode of `--max-steps` steps per game and
level: 36 x 105 = 3,780 episodes per matrix. Measured with `cec.evaluation.crossplay`, i.e. the one
`rollout` vmapped over games and envs, in two layouts, in interleaved rounds:

* batched: every game in one compiled call (`games_per_call=0`), the library's default;
* per game: one compiled call per game (`games_per_call=1`), the peer: what a loop over pairings costs.

Reported: episodes/s and joint env-steps/s of each (median over `--repeats` timed matrices after a warm-up
matrix that includes compilation), and their ratio. `--games-per-call` adds other layouts.

    taskset -c 0 python benchmarks/crossplay_throughput.py                     # small preset, 400 steps
    taskset -c 0 python benchmarks/crossplay_throughput.py --preset paper --repeats 1 --games-per-call 0
"""

from __future__ import annotations

import argparse
import statistics
import time
from pathlib import Path
from typing import Any

import jax

from cec.agents.network import network_preset
from cec.agents.policy import Policy, random_policy
from cec.envs import overcooked as oc
from cec.envs.task import EnvConfig
from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels, plan_games

try:  # run as a script (benchmarks/ on sys.path) or as a module
    from env_throughput import save_result  # type: ignore[import-not-found]
except ImportError:
    from benchmarks.env_throughput import save_result


def policies(preset: str, n: int, max_steps: int) -> list[Policy]:
    env = EnvConfig(name="overcooked", levels="generator", overcooked=oc.EnvParams(max_steps=max_steps))
    net = network_preset(preset, "overcooked")
    return [
        random_policy(f"p{i}", jax.random.PRNGKey(i), env=env, network=net, algorithm="random", seed=i)
        for i in range(n)
    ]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--preset", default="small", help="network preset (small, reference, paper)")
    ap.add_argument("--policies", type=int, default=6, help="seeds in the matrix (default 6)")
    ap.add_argument("--levels", default="heldout", help="level set (default: heldout, 105 levels)")
    ap.add_argument("--max-steps", type=int, default=400, help="episode length (default 400)")
    ap.add_argument("--episodes", type=int, default=1, help="episodes per game and level")
    ap.add_argument("--repeats", type=int, default=3, help="timed matrices per layout (median reported)")
    ap.add_argument(
        "--games-per-call",
        type=int,
        nargs="+",
        default=[0, 1],
        help="layouts to time: games per compiled call (0: all games in one call; default: 0 1)",
    )
    ap.add_argument("--out", type=Path, help="results JSON (default: benchmarks/results/...)")
    args = ap.parse_args(argv)

    pols = policies(args.preset, args.policies, args.max_steps)
    levels = eval_levels("overcooked", args.levels)
    games = len(plan_games(pols, levels.names))
    episodes = games * len(levels.names) * args.episodes
    names = {0: "batched", 1: "per_game"}
    layouts = {names.get(g, f"{g}_per_call"): g for g in args.games_per_call}
    print(
        f"{args.policies} x {args.policies} matrix, {args.preset} preset: {games} games x "
        f"{len(levels.names)} levels x {args.episodes} episode(s) = {episodes} episodes of {args.max_steps} "
        f"steps",
        flush=True,
    )

    def one_matrix(games_per_call: int) -> float:
        config = EvalConfig(episodes=args.episodes, max_steps=args.max_steps, games_per_call=games_per_call)
        t0 = time.perf_counter()
        table = crossplay(pols, levels, config)
        dt = time.perf_counter() - t0
        assert len(table) == episodes
        return dt

    warmup = {name: one_matrix(gpc) for name, gpc in layouts.items()}
    times: dict[str, list[float]] = {name: [] for name in layouts}
    for r in range(args.repeats):  # interleaved rounds
        for name, gpc in layouts.items():
            times[name].append(one_matrix(gpc))
            print(f"round {r + 1}: {name:8s} {times[name][-1]:8.1f} s", flush=True)
    rows: dict[str, Any] = {}
    for name in layouts:
        med = statistics.median(times[name])
        rows[name] = {
            "games_per_call": layouts[name],
            "seconds": times[name],
            "median_s": med,
            "first_matrix_s": warmup[name],  # includes compilation
            "compile_estimate_s": max(0.0, warmup[name] - med),
            "episodes_per_s": episodes / med,
            "env_steps_per_s": episodes * args.max_steps / med,
        }
        row = rows[name]
        print(
            f"{name:8s} {row['episodes_per_s']:9.1f} episodes/s "
            f"({row['env_steps_per_s']:,.0f} joint env-steps/s), first matrix {row['first_matrix_s']:.1f} s",
            flush=True,
        )
    ratio = None
    if "per_game" in rows and "batched" in rows:
        ratio = rows["batched"]["episodes_per_s"] / rows["per_game"]["episodes_per_s"]
        print(f"batched / per game: {ratio:.2f}x", flush=True)
    fields = {
        "preset": args.preset,
        "policies": args.policies,
        "levels": args.levels,
        "num_levels": len(levels.names),
        "games": games,
        "episodes_per_matrix": episodes,
        "max_steps": args.max_steps,
        "rows": rows,
        "batched_over_per_game": ratio,
    }
    save_result("crossplay_throughput", fields, args.out, tag=args.preset)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
