"""The `cec eval` and `cec report` subcommands (registered by `apps.cli.build_parser`).

cec eval --zoo zoo.yaml [--levels heldout] [--episodes 4] [--greedy] [--out results.csv]
cec report results.csv [more.csv ...] [--out report/]

Imports of JAX and plotting happen inside the commands, so building the parser stays cheap.
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path

log = logging.getLogger("cec")


def _cmd_eval(args: argparse.Namespace) -> int:
    from cec.agents.policy import load_policies
    from cec.agents.zoo import load_zoo
    from cec.config import ConfigError
    from cec.envs.registry import game
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels, plan_games
    from cec.evaluation.results import write_csv
    from cec.levels.named import names_files

    config = EvalConfig(
        levels=args.levels,
        episodes=args.episodes,
        greedy=args.greedy,
        seed=args.seed,
        max_steps=args.max_steps,
        pairs=args.pairs,
        games_per_call=args.games_per_call,
    )  # config errors before any work
    entries = load_zoo(args.zoo)
    # The user's kitchen files are read and checked before any checkpoint is loaded or anything compiled.
    own = eval_levels("overcooked", config.levels) if names_files(config.levels) else None
    policies, skipped = load_policies(entries)
    for s in skipped:
        print(f"cec eval: skipping {s.name}: {s.reason}", file=sys.stderr)
    env = policies[0].env.name if policies else "overcooked"
    if own is not None and not game(env).level_files:
        raise ConfigError(f"--levels names Overcooked kitchen files, but the zoo's policies play {env}")
    levels = own if own is not None else eval_levels(env, config.levels)
    games = plan_games(policies, levels.names, config.pairs) if policies else []
    if policies and not games:
        names = ", ".join(levels.names[:8]) + (", ..." if len(levels.names) > 8 else "")
        off = "; ".join(
            f"{p.name} plays only {list(p.levels)[:8]}"
            for p in policies
            if p.levels is not None and not set(p.levels) & set(levels.names)
        )
        raise ConfigError(
            f"no game to play on --levels {config.levels!r} ({names}): no pair of the zoo's policies shares"
            f" a level of it{'; ' + off if off else ''}; fix the entries' `levels` (level names of the set) "
            "or choose --levels"
        )
    log.info(
        "%d policies (%d skipped), %d levels, %d games x %d episodes",
        len(policies),
        len(skipped),
        len(levels.names),
        len(games),
        config.episodes,
    )
    t0 = time.perf_counter()
    table = crossplay(policies, levels, config, skipped=skipped, progress=log.info)
    dt = time.perf_counter() - t0
    path = write_csv(table, args.out)
    for s in table.skipped[len(skipped) :]:
        print(f"cec eval: skipped {s.name}: {s.reason}", file=sys.stderr)
    print(
        f"wrote {len(table)} episodes ({len(table) / dt:,.0f} episodes/s including compilation) "
        f"and {len(table.skipped)} skipped entr{'y' if len(table.skipped) == 1 else 'ies'} to {path}"
    )
    return 0


def _cmd_report(args: argparse.Namespace) -> int:
    from cec.evaluation.report import write_report
    from cec.evaluation.results import read_csv

    table = read_csv(args.results)
    path = write_report(table, args.out, sources=[str(p) for p in args.results])
    print(f"wrote {path} ({len(list(Path(args.out).glob('*.png')))} figures)")
    return 0


def add_subcommands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Adds `eval` and `report` to the `cec` command's subparsers."""
    ev = sub.add_parser(
        "eval",
        help="cross-play a zoo of checkpoints on a level set -> one long CSV table (docs/evaluation.md)",
    )
    ev.add_argument("--zoo", required=True, metavar="YAML", help="zoo manifest: policies with checkpoints")
    ev.add_argument(
        "--levels",
        default="heldout",
        help="heldout (5 classic + 100 generated), classic, generated, level names, ASCII kitchen files or "
        "folders of them, comma-separated; "
        "Dual Destination: fixed, multi_task, generated (100 held-out tasks), heldout (fixed + generated) "
        "(default: heldout)",
    )
    ev.add_argument("--episodes", type=int, default=4, help="episodes per pairing, seat order and level")
    ev.add_argument("--greedy", action="store_true", help="argmax actions (default: sampled)")
    ev.add_argument("--seed", type=int, default=0, help="seed of the common random numbers")
    ev.add_argument("--max-steps", type=int, default=0, help="episode length (default: the first policy's)")
    ev.add_argument("--pairs", default="all", help="all | self | with:NAME (default: all)")
    ev.add_argument("--games-per-call", type=int, default=0, help="games per compiled call (0: all)")
    ev.add_argument("--out", default="results.csv", help="CSV to write (default: results.csv)")
    ev.set_defaults(func=_cmd_eval)

    rep = sub.add_parser("report", help="Markdown report with PNG figures from cross-play result tables")
    rep.add_argument("results", nargs="+", type=Path, help="results CSV file(s) written by `cec eval`")
    rep.add_argument("--out", default="report", help="output folder (default: report/)")
    rep.set_defaults(func=_cmd_report)
