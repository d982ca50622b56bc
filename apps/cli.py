"""The `cec` command line.

cec demo [--out FILE]                        random (or scripted) play in every classic kitchen -> GIF
cec render LEVEL --png FILE                  any kitchen (a name, generated:SEED, an ASCII file) -> PNG
cec render LEVEL --gif FILE [--steps N]      an episode on that kitchen -> GIF
cec layouts                                  list the classic kitchens with their ASCII
cec levels sample --n 16 --out levels.png     a contact sheet of generated kitchens
cec levels validate FILE                      is an ASCII kitchen well-formed and solvable? why not?
cec levels stream --server ADDR --n 100       stream kitchens from a level server (levels/s, ASCII, PNG)
cec level-server [--config YAML] [k=v]        serve generated kitchens over gRPC (configs/level_server.yaml)
cec train --config configs/train/X.yaml [k=v]  train (IPPO / CEC) in one process; --resume RUN_DIR continues
cec eval --zoo zoo.yaml [--levels heldout]     cross-play a zoo of checkpoints -> results.csv (one long table)
cec report results.csv [...] [--out DIR]       Markdown report + PNG figures from result tables
cec zoo build SPEC.yaml --out ZOO_DIR          train a partner zoo from a spec (resumable) -> ZOO_DIR/zoo.yaml
cec reproduce dual-destination [--quick]       the paper's Dual Destination results end to end -> report
cec release RUN --prefix NAME [--ship]        a cec up run's release: chosen on validation, tested once
cec up [--config YAML] [--monitoring]         the whole stack: Redis, level server, Ray learner, evaluator
cec evaluator [--config YAML] [k=v]            score new checkpoints from Redis vs the zoo (a service)
cec play serve [STUDY.yaml] [--checkpoint DIR]  human-AI play in the browser (study flow, records)
cec play export STUDY.yaml --out DIR           a study's records -> results.csv (cec report) + survey.csv
cec monitoring [--target JOB=HOST:PORT]      Prometheus (+ Grafana) scraping a stack's /metrics

A `cec` process that seems stuck prints every thread's stack on stderr when sent SIGUSR1 (`kill -USR1 PID`).

Size: the library's own small commands (demo, render, layouts, levels, train) and the one registration list
of every other command; each command's body is a few lines over the library.
"""

from __future__ import annotations

import argparse
import contextlib
import faulthandler
import functools
import importlib
import io
import logging
import shlex
import signal
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import TYPE_CHECKING

from cec.checkpoints import CheckpointError
from cec.config import ConfigError
from cec.levels import Level
from services.entry import configure_logging, override_arguments, run_reporting

if TYPE_CHECKING:
    from cec.envs.overcooked import EnvParams
    from cec.training.config import TrainConfig

log = logging.getLogger("cec")


def _load_level(spec: str) -> Level:
    """One kitchen by name (`cec.levels.named.resolve_level`: classic, held-out, generated:SEED, a file)."""
    from cec.levels.named import resolve_level

    return resolve_level(spec)[1]


def _env_params(args: argparse.Namespace) -> EnvParams:
    from cec.config import load_config
    from cec.envs.overcooked import EnvParams

    return load_config(EnvParams, args.env, args.overrides)


def _add_env_options(p: argparse.ArgumentParser) -> None:
    p.add_argument("--env", metavar="YAML", help="EnvParams preset, e.g. configs/env/cec_paper.yaml")
    override_arguments(p, "max_steps=100", "EnvParams")
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
    if args.gif and args.partners:
        path, team_return = _render_partners(level, args)
        print(f"wrote {path} (team return {team_return:g})")
    elif args.gif:
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


def _render_partners(level: Level, args: argparse.Namespace) -> tuple[Path, float]:
    """`cec render --partners A B`: an episode of two trained policies (checkpoints, run directories or
    shipped policies' names) as a GIF."""
    from cec.agents.policy import load_policy
    from cec.agents.zoo import ZooEntry
    from cec.envs.overcooked.render import rollout_frames, save_gif
    from cec.evaluation.crossplay import episode_states

    a, b = (load_policy(ZooEntry(spec, spec)) for spec in args.partners)
    states, team_return = episode_states(
        a, b, level, args.layout, seed=args.seed, max_steps=args.steps or 400, greedy=False
    )
    return save_gif(rollout_frames(states, args.tile_size), args.gif, fps=args.fps), team_return


def _cmd_layouts(args: argparse.Namespace) -> int:
    from cec.envs.overcooked import CLASSIC_ASCII, CLASSIC_NAMES

    for name, text in CLASSIC_ASCII.items():
        print(f"{name} ({CLASSIC_NAMES[name]}):{text}")
    return 0


def _cmd_levels_sample(args: argparse.Namespace) -> int:
    import jax

    from cec.config import load_config
    from cec.envs.overcooked.render import contact_sheet, render_level, save_png
    from cec.levels import to_ascii, unstack_levels
    from cec.levels.generator import GeneratorConfig, generate_batch

    config = load_config(GeneratorConfig, args.config, args.overrides)
    _check_sample_arguments(args)  # before anything is compiled
    t0 = time.perf_counter()
    levels = unstack_levels(jax.device_get(generate_batch(jax.random.PRNGKey(args.seed), args.n, config)))
    log.info("generated %d kitchens in %.1fs", args.n, time.perf_counter() - t0)
    if args.ascii:
        print("\n\n".join(to_ascii(lv) for lv in levels))
    if args.out:
        sheet = contact_sheet([render_level(lv, args.tile_size) for lv in levels], args.columns)
        try:
            print(f"wrote {save_png(sheet, args.out)}")
        except OSError as err:  # a full disk, a folder that cannot be written
            raise ValueError(f"--out {args.out!r} cannot be written: {err.strerror or err}") from None
    return 0


#: `cec levels sample`'s bounds: kitchens generated at once, the contact sheet's pixels (RGB, 3 bytes each),
#: its tile size and columns, the seed (a PRNG key's 32 bits).
SAMPLE_MAX_LEVELS = 100_000
SHEET_MAX_PIXELS = 64 << 20
TILE_SIZES = (4, 256)
MAX_COLUMNS = 1_000
MAX_SEED = 2**32 - 1


def _check_sample_arguments(args: argparse.Namespace) -> None:
    """`ValueError` naming the argument of `cec levels sample` that is out of its range, or an `--out` that
    cannot be a PNG file (a folder, a device), before any work."""
    for flag, value, lo, hi in (
        ("--n", args.n, 1, SAMPLE_MAX_LEVELS),
        ("--seed", args.seed, 0, MAX_SEED),
        ("--tile-size", args.tile_size, *TILE_SIZES),
        ("--columns", args.columns, 1, MAX_COLUMNS),
    ):
        if not lo <= value <= hi:
            raise ValueError(f"{flag} must lie in [{lo:,}, {hi:,}], got {value}")
    if not args.out:
        return
    pixels = args.n * (9 * args.tile_size) ** 2
    if pixels > SHEET_MAX_PIXELS:
        raise ValueError(
            f"a contact sheet of {args.n:,} kitchens at --tile-size {args.tile_size} holds {pixels:,} "
            f"pixels, more than {SHEET_MAX_PIXELS:,} ({__name__}.SHEET_MAX_PIXELS); lower --n or --tile-size "
            f"(--ascii alone prints up to {SAMPLE_MAX_LEVELS:,})"
        )
    out = Path(args.out)
    if out.is_dir():
        raise ValueError(f"--out {args.out!r} is a folder; give a PNG file's name")
    if out.exists() and not out.is_file():
        raise ValueError(f"--out {args.out!r} is not a regular file (a device, FIFO or socket); give a file")
    parent = next((p for p in out.parents if p.exists()), Path("."))
    if not parent.is_dir():
        raise ValueError(f"--out {args.out!r}: {parent} is a file, not a folder")


def _cmd_levels_validate(args: argparse.Namespace) -> int:
    from cec.levels.fingerprint import content_hash
    from cec.levels.heldout import heldout_levels
    from cec.levels.named import read_kitchen
    from cec.levels.solvability import validate_solvable

    path = Path(args.file)  # a file is read as it is (unsolvable: reported below), malformed: exit 2
    level = read_kitchen(path) if path.is_file() else _load_level(args.file)
    problems = validate_solvable(level, args.allow_decoys)
    digest = content_hash(level)
    heldout = [name for name, lv in heldout_levels() if content_hash(lv) == digest]
    print(f"{args.file}: {'solvable' if not problems else 'NOT solvable'} (content hash {digest})")
    for p in problems:
        print(f"  - {p}")
    if heldout:
        print(f"  note: this is held-out evaluation kitchen {heldout[0]!r}")
    return 0 if not problems else 1


def _cmd_levels_stream(args: argparse.Namespace) -> int:
    import grpc
    import jax

    from cec.envs.overcooked.render import contact_sheet, render_level, save_png
    from cec.levels import to_ascii, unstack_levels
    from services.level_server.client import LevelClient

    if args.n < 1 or args.batch_size < 1:
        raise ValueError(f"--n and --batch-size must be at least 1, got {args.n} and {args.batch_size}")
    client = LevelClient(args.server, token=args.token, root_cert=args.root_cert)
    kept: list[Level] = []
    received = 0
    t0 = last = time.perf_counter()
    try:
        for _, batch in client.stream(args.seed, min(args.batch_size, args.n), args.n, args.start_index):
            received += int(batch.grid.shape[0])
            if args.ascii or args.out:
                kept.extend(unstack_levels(batch))
            now = time.perf_counter()
            if now - last > 1.0:
                log.info("%d / %d levels (%.0f levels/s)", received, args.n, received / (now - t0))
                last = now
    except grpc.RpcError as err:
        print(f"cec levels stream: {args.server}: {err.code().name}: {err.details()}", file=sys.stderr)
        return 1
    finally:
        client.close()
    dt = time.perf_counter() - t0
    print(f"received {received} levels (seed {args.seed}) from {args.server} in {dt:.2f}s: "
          f"{received / dt:,.0f} levels/s")  # fmt: skip
    if args.ascii:
        print("\n\n".join(to_ascii(lv) for lv in kept))
    if args.out:
        sheet = contact_sheet([render_level(jax.device_get(lv), args.tile_size) for lv in kept[:64]], 8)
        print(f"wrote {save_png(sheet, args.out)}")
    return 0


def _cmd_train(args: argparse.Namespace) -> int:
    from cec.config import load_config
    from cec.training.config import TrainConfig
    from cec.training.run import train

    train_overrides = [o for o in args.overrides if not o.startswith(("distributed.", "store."))]
    if args.distributed:
        return _train_distributed(args, [o for o in args.overrides if o not in train_overrides])
    if args.resume:
        where = [o for o in args.overrides if o.startswith("devices=")]  # changes where, not what, it trains
        if args.config or len(where) != len(args.overrides):
            raise ConfigError(
                "--resume continues a run with its own config.yaml; drop --config and overrides (devices=N "
                "aside)"
            )
        config_file = Path(args.resume) / "config.yaml"
        if not config_file.is_file():
            raise CheckpointError(f"{args.resume} is not a run directory (no config.yaml)")
        config = _at_run_directory(load_config(TrainConfig, config_file, where), Path(args.resume))
    else:
        if not args.config:
            raise ConfigError("give --config configs/train/<preset>.yaml (or --resume RUN_DIR)")
        config = load_config(TrainConfig, args.config, train_overrides)
    result = train(config, resume=bool(args.resume), max_updates=args.max_updates, progress=not args.quiet)
    state = "interrupted" if result.interrupted else "finished"
    print(f"{state} after {result.updates_done} updates; run directory: {result.run_dir}")
    return 130 if result.interrupted else 0


def _at_run_directory(config: TrainConfig, run_dir: Path) -> TrainConfig:
    """`config` re-pointed at `run_dir` when the run was moved or copied there (its config.yaml names the
    place it was started in): resuming continues the run found at `run_dir`, never a run elsewhere."""
    import dataclasses

    if (Path(config.run_dir) / config.run_name).resolve() == run_dir.resolve():
        return config
    print(
        f"{run_dir} was started as {Path(config.run_dir) / config.run_name}; continuing it where it is now",
        file=sys.stderr,
    )
    return dataclasses.replace(config, run_dir=str(run_dir.parent), name=run_dir.name)


def _train_distributed(args: argparse.Namespace, service_overrides: list[str]) -> int:
    """`cec train --distributed`: the learner and actors on an existing Ray cluster (`ray up`), or in this
    process with `distributed.pool=local`; Redis from `store.url` / CEC_REDIS_URL, kitchens from
    `distributed.level_server`."""
    from cec.config import load_config
    from cec.training.config import TrainConfig
    from services.learner.config import DistributedConfig
    from services.learner.driver import connect_ray, disconnect_ray, run_distributed
    from services.store import StoreConfig

    run_config = Path(args.resume) / "config.yaml" if args.resume else None
    if not args.config and run_config is None:
        raise ConfigError("give --config configs/train/<preset>.yaml (or --resume RUN_DIR)")
    train_overrides = [o for o in args.overrides if o not in service_overrides]
    config = load_config(TrainConfig, run_config or args.config, [] if run_config else train_overrides)
    if run_config:
        config = _at_run_directory(config, Path(args.resume))
    dist = load_config(DistributedConfig, None, [o.removeprefix("distributed.") for o in service_overrides
                                                  if o.startswith("distributed.")])  # fmt: skip
    store = load_config(
        StoreConfig, None, [o.removeprefix("store.") for o in service_overrides if o.startswith("store.")]
    )
    run_dir = Path(config.run_dir) / config.run_name
    hint = shlex.join(["cec", "train", "--distributed", "--resume", str(run_dir), *service_overrides])
    on_ray = dist.pool == "ray"  # `local`: the learner and its actors in this process, no Ray
    if on_ray:
        connect_ray(dist.ray_address or "auto")
    try:
        return run_distributed(
            config, dist, store, resume=bool(args.resume), max_updates=args.max_updates, resume_hint=hint
        )
    finally:
        if on_ray:
            disconnect_ray()


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
    render.add_argument(
        "layout",
        metavar="LEVEL",
        help="any kitchen: a classic, held-out or test kitchen's name (e.g. cramped_room, generated_006), "
        "generated:SEED (the generator's kitchen of that seed), or an ASCII kitchen file (docs/kitchens.md)",
    )
    render.add_argument("--png", help="write the kitchen's start state to this PNG")
    render.add_argument("--gif", help="write an episode to this GIF")
    _add_env_options(render)
    render.add_argument("--policy", choices=POLICIES, default="scripted")
    render.add_argument(
        "--partners",
        nargs=2,
        metavar=("SEAT0", "SEAT1"),
        help="two trained policies instead (checkpoint or run directories, or shipped policies' names, "
        "e.g. cec758m-s200); episode length --steps (default 400)",
    )
    render.add_argument("--seed", type=int, default=0)
    render.add_argument("--tile-size", type=int, default=64, help="pixels per cell (default 64)")
    render.add_argument("--fps", type=int, default=8)
    render.set_defaults(func=_cmd_render)

    layouts = sub.add_parser("layouts", help="print the classic kitchens")
    layouts.set_defaults(func=_cmd_layouts)

    levels = sub.add_parser("levels", help="generate and validate kitchens")
    levels_sub = levels.add_subparsers(dest="levels_command", required=True)
    sample = levels_sub.add_parser("sample", help="generate kitchens; write a contact sheet and/or ASCII")
    sample.add_argument("--n", type=int, default=16, help="how many (default 16)")
    sample.add_argument("--out", help="contact sheet PNG to write")
    sample.add_argument("--ascii", action="store_true", help="print the kitchens as ASCII")
    sample.add_argument("--seed", type=int, default=0)
    sample.add_argument("--columns", type=int, default=4)
    sample.add_argument("--tile-size", type=int, default=24)
    sample.add_argument("--config", metavar="YAML", help="GeneratorConfig file")
    override_arguments(sample, "pots=[1,2]", "GeneratorConfig")
    sample.set_defaults(func=_cmd_levels_sample)
    validate = levels_sub.add_parser(
        "validate", help="check an ASCII kitchen: exit 0 solvable, 1 not, 2 malformed"
    )
    validate.add_argument("file", help="ASCII kitchen file (or a classic layout name)")
    validate.add_argument("--allow-decoys", action="store_true", help="accept objects no agent can reach")
    validate.set_defaults(func=_cmd_levels_validate)
    stream = levels_sub.add_parser("stream", help="stream kitchens from a level server (cec level-server)")
    stream.add_argument("--server", default="127.0.0.1:50051", help="host:port (default 127.0.0.1:50051)")
    stream.add_argument("--n", type=int, default=100, help="how many levels (default 100)")
    stream.add_argument("--seed", type=int, default=0, help="the sequence (level i is fixed by seed and i)")
    stream.add_argument("--start-index", type=int, default=0, help="first index of the sequence")
    stream.add_argument("--batch-size", type=int, default=1024, help="levels per streamed message")
    stream.add_argument("--token", help="bearer token (default: $CEC_LEVEL_SERVER_TOKEN)")
    stream.add_argument("--root-cert", help="PEM CA certificate for a TLS server")
    stream.add_argument("--ascii", action="store_true", help="print the kitchens as ASCII")
    stream.add_argument("--out", help="contact sheet PNG of (up to 64 of) the kitchens")
    stream.add_argument("--tile-size", type=int, default=24)
    stream.set_defaults(func=_cmd_levels_stream)

    tr = sub.add_parser("train", help="train agents in one process (rollout + PPO update jitted together)")
    tr.add_argument(
        "--config", metavar="YAML", help="training preset, e.g. configs/train/cec_overcooked.yaml"
    )
    override_arguments(tr, "num_envs=64")
    tr.add_argument(
        "--resume", metavar="RUN_DIR", help="continue an interrupted run from its latest checkpoint"
    )
    tr.add_argument(
        "--max-updates", type=_positive_int, help="stop (with a checkpoint) after this many more updates"
    )
    tr.add_argument("--quiet", action="store_true", help="no progress lines")
    tr.add_argument(
        "--distributed",
        action="store_true",
        help="run the learner + actors on an existing Ray cluster, or in this process with "
        "distributed.pool=local (distributed.KEY=VALUE and store.KEY=VALUE set services/learner/config.py "
        "and the Redis settings; see docs/distributed.md)",
    )
    tr.set_defaults(func=_cmd_train)

    for module, names in COMMANDS:
        _add_optional(sub, functools.partial(_add_module_subcommands, module), *names)
    return parser


# Every subcommand defined outside this file, in one list: (module, the commands it adds). A module adds
# its commands with `add_subcommands(sub)`, or is a service (`services.entry.Service`) named `SERVICE`.
# The services' commands register only where their packages (Ray, Redis, gRPC's health and reflection
# services, the web stack) are installed: training, evaluation and the reports run on the `cec` core alone.
COMMANDS = (
    ("apps.evaluate", ("eval", "report")),
    ("apps.zoo_build", ("zoo",)),
    ("apps.humans", ("humans",)),
    ("apps.reproduce", ("reproduce",)),
    ("apps.release", ("release",)),
    ("apps.partners", ("partners",)),
    ("apps.results_table", ("results",)),
    ("services.level_server.main", ("level-server",)),
    ("services.stack", ("up",)),
    ("services.status", ("status",)),
    ("services.cluster", ("cluster",)),
    ("services.evaluator.main", ("evaluator",)),
    ("services.play.main", ("play",)),
    ("services.monitoring.main", ("monitoring",)),
)


def _add_module_subcommands(module: str, sub: argparse._SubParsersAction) -> None:
    imported = importlib.import_module(module)
    service = getattr(imported, "SERVICE", None)
    if service is not None:
        service.register(sub)
    else:
        imported.add_subcommands(sub)


def _add_optional(
    sub: argparse._SubParsersAction, add: Callable[[argparse._SubParsersAction], None], *names: str
) -> None:
    """`add(sub)`; where it needs a package that is not installed, each of `names` still parses and exits 2
    with the package's name and the install command instead of the whole CLI failing to start."""
    try:
        add(sub)
    except ModuleNotFoundError as err:
        for name in names:
            stub = sub.add_parser(name, help=f"(needs {err.name}, not installed)", add_help=False)
            stub.add_argument("rest", nargs=argparse.REMAINDER)
            stub.set_defaults(func=functools.partial(_missing_package, err.name or str(err)))


def _missing_package(package: str, args: argparse.Namespace) -> int:
    print(
        f"cec {args.command}: error: needs the package {package!r}, which is not installed here "
        "(the `cec` core trains, evaluates and reports without it); install the services: "
        "pip install -e '.[services]'",
        file=sys.stderr,
    )
    return 2


def _positive_int(text: str) -> int:
    value = int(text)
    if value < 1:
        raise argparse.ArgumentTypeError(f"must be a positive integer, got {text}")
    return value


def parse_args(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """`parser.parse_args`, also taking KEY=VALUE overrides written after a flag (`cec train --config X
    --quiet num_envs=8`), which argparse leaves unrecognised once the positional list has been read."""
    args, extra = parser.parse_known_args(argv)
    overrides = getattr(args, "overrides", None)
    if extra and isinstance(overrides, list) and all("=" in e and not e.startswith("-") for e in extra):
        overrides += extra
        extra = []
    if extra:
        parser.error(f"unrecognized arguments: {' '.join(extra)}")
    return args


def main(argv: list[str] | None = None) -> int:
    if hasattr(signal, "SIGUSR1"):  # `kill -USR1 PID`: every thread's stack on stderr, where it hangs
        with contextlib.suppress(io.UnsupportedOperation, ValueError):  # stderr without a file (captured)
            faulthandler.register(signal.SIGUSR1, all_threads=True)
    args = parse_args(build_parser(), argv)
    configure_logging(args.verbose)
    return run_reporting(args.command, lambda: int(args.func(args)), failures=())


if __name__ == "__main__":
    raise SystemExit(main())
