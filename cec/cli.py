"""The `cec` command line.

cec demo [--out FILE]                        random (or scripted) play in every classic kitchen -> GIF
cec render LAYOUT --png FILE                 a kitchen (classic name or ASCII file) -> PNG
cec render LAYOUT --gif FILE [--steps N]     an episode on that kitchen -> GIF
cec layouts                                  list the classic kitchens with their ASCII
"""

from __future__ import annotations

import argparse
import logging
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING

from cec.config import ConfigError
from cec.levels import Level, LevelError, from_ascii

if TYPE_CHECKING:
    from cec.envs.overcooked import EnvParams

log = logging.getLogger("cec")


def _load_level(spec: str) -> Level:
    """A classic layout name, or a path to an ASCII kitchen file."""
    from cec.envs.overcooked import CLASSIC_ASCII, classic_level

    if spec in CLASSIC_ASCII:
        return classic_level(spec)
    path = Path(spec)
    if not path.is_file():
        raise LevelError(
            f"{spec!r} is neither a classic layout ({', '.join(sorted(CLASSIC_ASCII))}) nor an ASCII "
            "kitchen file"
        )
    return from_ascii(path.read_text())


def _env_params(args: argparse.Namespace) -> EnvParams:
    from cec.config import load_config
    from cec.envs.overcooked import EnvParams

    return load_config(EnvParams, args.env, args.set)


def _add_env_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--env", metavar="YAML", help="EnvParams preset, e.g. configs/env/cec_paper.yaml")
    p.add_argument(
        "--set", action="append", default=[], metavar="KEY=VALUE", help="override an EnvParams field"
    )
    p.add_argument("--steps", type=int, default=None, help="episode length (default: the preset's max_steps)")


def _cmd_demo(args: argparse.Namespace) -> int:
    from cec.envs.overcooked import CLASSIC_ASCII, CLASSIC_NAMES, classic_level
    from cec.envs.overcooked.render import render_episode_gif

    params = _env_params(args)  # config errors before any work
    steps = args.steps if args.steps is not None else int(params.max_steps)
    names = sorted(CLASSIC_ASCII)
    log.info(
        "rolling out %s agents for %d steps in the classic kitchens: %s",
        args.policy,
        steps,
        ", ".join(CLASSIC_NAMES[n] for n in names),
    )
    t0 = time.perf_counter()
    path = render_episode_gif(
        [classic_level(n) for n in names],
        Path(args.out),
        steps=steps,
        policy=args.policy,
        seed=args.seed,
        params=params,
    )
    log.info("rendered %d kitchens x %d states in %.1fs", len(names), steps + 1, time.perf_counter() - t0)
    print(f"wrote {path}")
    return 0


def _cmd_render(args: argparse.Namespace) -> int:
    from cec.envs.overcooked.render import render_episode_gif, render_level, save_png

    if not args.png and not args.gif:
        raise SystemExit("cec render: give --png FILE and/or --gif FILE")
    level = _load_level(args.layout)
    params = _env_params(args)
    if args.png:
        print(f"wrote {save_png(render_level(level, args.tile_size), args.png)}")
    if args.gif:
        path = render_episode_gif(
            level,
            args.gif,
            steps=args.steps,
            policy=args.policy,
            seed=args.seed,
            tile_size=args.tile_size,
            fps=args.fps,
            params=params,
        )
        print(f"wrote {path}")
    return 0


def _cmd_layouts(args: argparse.Namespace) -> int:
    from cec.envs.overcooked import CLASSIC_ASCII, CLASSIC_NAMES

    for name, text in CLASSIC_ASCII.items():
        print(f"{name} ({CLASSIC_NAMES[name]}):{text}")
    return 0


def build_parser() -> argparse.ArgumentParser:
    from cec.envs.overcooked.render import POLICIES

    parser = argparse.ArgumentParser(
        prog="cec", description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter
    )
    parser.add_argument("-v", "--verbose", action="store_true", help="debug logging")
    sub = parser.add_subparsers(dest="command", required=True)

    demo = sub.add_parser("demo", help="play every classic kitchen, side by side, into one GIF")
    demo.add_argument("--out", default="out/demo.gif", help="GIF to write (default: out/demo.gif)")
    _add_env_options(demo)
    demo.add_argument("--policy", choices=POLICIES, default="random", help="who plays (default: random)")
    demo.add_argument("--seed", type=int, default=0)
    demo.set_defaults(func=_cmd_demo)

    render = sub.add_parser("render", help="render a kitchen to PNG or an episode to GIF")
    render.add_argument("layout", help="classic layout name or path to an ASCII kitchen file")
    render.add_argument("--png", help="write the kitchen's start state to this PNG")
    render.add_argument("--gif", help="write an episode to this GIF")
    _add_env_options(render)
    render.add_argument("--policy", choices=POLICIES, default="scripted")
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--tile-size", type=int, default=32)
    render.add_argument("--fps", type=int, default=8)
    render.set_defaults(func=_cmd_render)

    layouts = sub.add_parser("layouts", help="print the classic kitchens")
    layouts.set_defaults(func=_cmd_layouts)
    return parser


def main(argv: list[str] | None = None) -> int:
    args = build_parser().parse_args(argv)
    logging.basicConfig(
        level=logging.DEBUG if args.verbose else logging.INFO,
        format="%(asctime)s %(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.func(args))
    except (LevelError, ConfigError, ValueError) as err:
        print(f"cec {args.command}: error: {err}", file=sys.stderr)
        return 2


if __name__ == "__main__":
    raise SystemExit(main())
