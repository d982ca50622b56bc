"""`cec play serve` (a study, or free play with one partner) and `cec play export` (records -> tables).

    cec play serve configs/study/default.yaml --port 8000          # the paper's study design
    cec play serve --checkpoint runs/cec-s0 --level coord_ring     # try one agent in the browser
    cec play serve --zoo zoo/zoo.yaml --group cec --level generated:random --mode real_time
    cec play export configs/study/default.yaml --out out/human    # results.csv (+ survey.csv)

Serving prints `cec play: serving ... at http://HOST:PORT/` once the port accepts connections (port 0: a
free one), and stops on Ctrl-C / SIGTERM.
"""

from __future__ import annotations

import argparse
import hashlib
import json
import logging
import re
import socket
import sys
import time
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cec.agents.zoo import SHIPPED, best_shipped
from cec.config import ConfigError, from_dict
from cec.signals import GracefulStop
from services.entry import Service, override_arguments
from services.play.config import AGENT_ACTIONS, MODES, StudyConfig, load_study
from services.ports import check_port
from services.progress import Heartbeat
from services.store import StoreError  # needs redis: without it `cec X` names the package

if TYPE_CHECKING:
    from services.play.game import PartnerPool

log = logging.getLogger("cec.play")


def add_arguments(play: argparse.ArgumentParser) -> None:
    """`serve` and `export` under `cec play`."""
    play_sub = play.add_subparsers(dest="play_command", required=True)

    serve = play_sub.add_parser("serve", help="serve a study (or free play with one partner) over HTTP")
    serve.add_argument(
        "study", nargs="?", help="study YAML (e.g. configs/study/default.yaml); omit for free play"
    )
    override_arguments(serve, "mode=real_time", "study")
    src = serve.add_argument_group("free play (no study file): one partner, one kitchen, no survey")
    src.add_argument(
        "--partner",
        metavar="NAME",
        help="a policy shipped with the package (`cec zoo`: cec/shipped/zoo.yaml), or an algorithm of them "
        "(e.g. `cec`: one of its seeds drawn per round), or `best`: the shipped partner that cooked most "
        "with a cloned person in --level (cec/shipped/best.yaml, which also names the partner of every "
        "other kitchen); no training, no download. `cec`, `cec_finetune`: CEC, the paper's method; "
        "`cec_teacher`, `cec_finetune_teacher` (what `best` plays in the classic kitchens): CEC with a "
        "scripted teacher (imitates a hand-written cook; not the paper's method), so they show how far that "
        "cook's skill carries, not what training across kitchens alone gives; README, Results",
    )
    src.add_argument("--checkpoint", help="checkpoint or run directory of the partner")
    src.add_argument("--seed", type=int, help="with --checkpoint: the seed of a multi-seed checkpoint")
    src.add_argument("--zoo", help="zoo manifest: a random entry per round")
    src.add_argument("--group", default="", help="with --zoo: only entries of this algorithm")
    src.add_argument("--random-init", action="store_true", help="a randomly initialised `small` network")
    src.add_argument(
        "--level",
        default="cramped_room",
        help="level spec (classic, generated_NNN, generated:SEED); default cramped_room, where the shipped "
        "CEC partner cooks most (docs/play.md)",
    )
    src.add_argument("--mode", choices=MODES, default="turn_based")
    src.add_argument(
        "--agent-actions",
        choices=AGENT_ACTIONS,
        default="sampled",
        help="how the agent picks its action from its policy: sampled (default; the shipped agents freeze "
        "in place when they always take the most likely action) or greedy",
    )
    src.add_argument(
        "--give-way-after",
        type=int,
        default=3,
        metavar="N",
        help="the agent steps onto a free cell after N collisions in a row (default 3; 0: never, as the "
        "paper's agents; docs/play.md)",
    )
    src.add_argument("--steps", type=int, default=200, help="round length")
    serve.add_argument("--host", default="127.0.0.1", help="bind address (default 127.0.0.1)")
    serve.add_argument("--port", type=int, default=8000, help="port (0: a free one; default 8000)")
    serve.add_argument("--data", help="records folder (overrides storage.dir)")
    serve.add_argument("--redis-url", help="also record to this Redis (overrides storage.redis_url)")
    serve.set_defaults(play_func=_cmd_serve)

    export = play_sub.add_parser(
        "export", help="a study's records -> results.csv (cec report) and survey.csv"
    )
    export.add_argument("study", help="the study YAML the records belong to")
    override_arguments(export, "storage.dir=...", "study")
    export.add_argument("--data", help="records folder (overrides storage.dir)")
    export.add_argument("--redis-url", help="read the records from this Redis instead of files")
    export.add_argument(
        "--out", required=True, metavar="DIR", help="writes DIR/results.csv and DIR/survey.csv"
    )
    export.set_defaults(play_func=_cmd_export)


def _storage_overrides(args: argparse.Namespace) -> list[str]:
    out = []
    if args.data is not None:
        out.append(f"storage.dir={args.data}")
    if args.redis_url is not None:
        out.append(f"storage.redis_url={args.redis_url}")
    return out


FREE_PLAY_DIR = "runs/play"  # free play's records folder unless --data gives one (runs/ is ignored by git)


def free_play_name(data: dict[str, Any]) -> str:
    """The record folder of one set of free-play flags: `free_play-<partner>-<kitchen>-<digest>`, so that
    changing a flag starts a folder of its own (its rounds never meet those of other flags)."""
    (partner,) = data["partners"]
    source = partner.get("group") or Path(partner.get("checkpoint") or partner.get("zoo") or "random").name
    words = [re.sub(r"[^A-Za-z0-9_]+", "_", w).strip("_")[:16] for w in (source, data["levels"][0])]
    digest = hashlib.sha256(json.dumps(data, sort_keys=True).encode()).hexdigest()[:8]
    return "-".join(["free_play", *(w for w in words if w), digest])


BEST = "best"  # `--partner best`: `best_shipped(--level)`


def free_play_config(args: argparse.Namespace) -> StudyConfig:
    """Free play from `cec play serve` flags: one partner condition, rounds without end (`free_play`), no
    consent, practice or survey; records in `runs/play/<free_play_name>/` unless `--data` says where."""
    partner: dict[str, Any] = {"name": "partner"}
    if args.partner:
        group = best_shipped(args.level) if args.partner == BEST else args.partner
        if args.partner == BEST:
            log.info("--partner best in %s: %s (chosen there by cec/shipped/best.yaml)", args.level, group)
        partner.update(zoo=SHIPPED, group=group)
    if args.checkpoint:  # a path, or the name of a shipped policy
        path = Path(args.checkpoint)
        partner.update(checkpoint=str(path.resolve()) if path.exists() else args.checkpoint, seed=args.seed)
    if args.zoo:
        path = Path(args.zoo)
        partner.update(zoo=str(path.resolve()) if path.exists() else args.zoo, group=args.group)
    if args.random_init:
        partner.update(random_init=True)
    data: dict[str, Any] = {
        "title": "Cook with an agent",
        "levels": [args.level],
        "partners": [partner],
        "rounds_per_partner": 1,
        "mode": args.mode,
        "agent_actions": args.agent_actions,
        "agent_gives_way_after": args.give_way_after,
        "env": {"max_steps": args.steps, "random_start_facing": False},
        "survey": {"items": []},
        "free_play": True,
    }
    data["name"] = free_play_name(data)
    data["storage"] = {
        "dir": args.data if args.data is not None else FREE_PLAY_DIR,
        "redis_url": args.redis_url or "",
    }
    return from_dict(StudyConfig, data)


def prepare(config: StudyConfig, base_dir: Path) -> dict[str, Any]:
    """Checks the levels and loads (and compiles) every partner; `ConfigError` naming what is wrong."""
    from cec.levels.named import check_level
    from services.play.game import load_partner, warm_up

    for level in (*config.levels, *([config.practice.level] if config.practice else [])):
        check_level(level, base_dir)
    t0 = time.perf_counter()
    pools = {}
    for partner in config.partners:
        pools[partner.name] = pool = load_partner(partner, base_dir)
        flags = config.free_play and partner.name == "partner"  # `cec play serve --partner ...`
        log.info("%s", loaded_line(pool, "free play's partner" if flags else f"partner {partner.name!r}"))
    practice = (
        [(config.practice.partner or config.partners[0].name, config.practice.level)]
        if config.practice
        else []
    )
    for name, spec in [*((p.name, lv) for p in config.partners for lv in config.levels), *practice]:
        if not pools[name].eligible(spec):
            kitchens = sorted({lv for p in pools[name].policies for lv in p.levels or ()})
            raise ConfigError(
                f"partner {name!r} has no policy that plays {spec!r} (its policies are single-task agents of "
                f"{kitchens}); change the levels or the partner's zoo group"
            )
    log.info(
        "loaded %d partner conditions in %.1f s; compiling the game and the agents (once per start: about 15 "
        "s on a busy 2-core CPU)", len(pools), time.perf_counter() - t0,
    )  # fmt: skip
    with Heartbeat(log.info, lambda s: f"still compiling ({s:.0f} s)", every_s=5.0):
        seconds = warm_up(list(pools.values()), config)
    log.info("compiled the game and the agents in %.1f s", seconds)
    return pools


def loaded_line(pool: PartnerPool, label: str, shown: int = 6) -> str:
    """What a partner condition loaded, by name: `label: N policies loaded: name (algorithm), ...`."""
    n = len(pool.policies)
    names = [f"{p.name} ({p.algorithm})" for p in pool.policies[:shown]]
    more = f" and {n - shown} more" if n > shown else ""
    return f"{label}: {n} {'policy' if n == 1 else 'policies'} loaded: {', '.join(names)}{more}"


def serve(config: StudyConfig, base_dir: Path, host: str, port: int) -> int:
    """Serves `config` until interrupted. Returns the exit status."""
    import uvicorn

    from services.play.app import MAX_WS_MESSAGE_BYTES, create_app
    from services.play.export import read_all
    from services.play.recording import Recorder, open_stores
    from services.play.study import Study

    sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
    with sock:  # closed however serving ends, a failed start included
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:  # before the partners load and compile: a busy port is found at once, not after that wait
            sock.bind((host, port))
        except OSError as err:
            raise ConfigError(
                f"cannot listen on {host}:{port} ({err.strerror or err}); choose another --port (0: any free "
                "one)"
            ) from None
        pools = prepare(config, base_dir)
        storage = config.storage
        stores = open_stores(
            config.name, storage.dir, storage.redis_url, storage.key_prefix,
            redis_timeout_s=storage.redis_timeout_s,
        )  # fmt: skip
        recorder = Recorder(stores)
        study = Study(config, base_dir, pools, recorder)
        records = read_all(stores[0])  # validated: bad lines are quarantined with a warning, never fatal
        recorder.replay(records)  # Redis gets what it lacks of the primary's records (before anything new)
        restored = study.restore(records)
        if stores[0].quarantined:
            log.warning(
                "%d record line(s) quarantined (left out; `cec play export` lists them)",
                len(stores[0].quarantined),
            )
        app = create_app(study)
        sock.listen(128)
        bound = sock.getsockname()[1]
        where = [f"files in {Path(config.storage.dir).resolve() / config.name}"] if config.storage.dir else []
        where += [f"Redis {config.storage.redis_url}"] if config.storage.redis_url else []
        log.info(
            "recording to %s (%d participants so far, %d can continue)",
            " and ".join(where), len(records), restored,
        )  # fmt: skip
        uv = uvicorn.Config(
            app, log_level="warning", access_log=False, ws_max_size=MAX_WS_MESSAGE_BYTES, lifespan="off"
        )
        server = uvicorn.Server(uv)
        # Our handler, not Python's KeyboardInterrupt, from before the line is out: JAX's garbage-collector
        # callback swallows an exception raised inside it, so a Ctrl-C that lands there (before uvicorn
        # installs its own handlers, which it then hands back to ours) was lost and the server served on.
        # uvicorn checks `should_exit` before it serves and on every tick.
        stopping = GracefulStop(
            "stopping the server", on_first=lambda: setattr(server, "should_exit", True), out=sys.stdout
        )
        try:
            with stopping:
                print(f"cec play: serving study {config.name!r} at http://{host}:{bound}/", flush=True)
                server.run(sockets=[sock])
        except KeyboardInterrupt:  # a second signal: stop at once, the records are closed below
            log.info("stopped at once by a second signal")
        finally:
            recorder.close()
        if stopping.stop:
            log.info("stopped by a signal")
    return 0


def _cmd_serve(args: argparse.Namespace) -> int:
    check_port("--port", args.port)  # 70000 would reach the socket as an OverflowError, after the loading
    free = args.partner or args.checkpoint or args.zoo or args.random_init
    if args.study and free:
        raise ConfigError(
            "give a study file or a free-play partner (--partner/--checkpoint/--zoo/--random-init), not both"
        )
    if args.study:
        config, base_dir = load_study(args.study, [*args.overrides, *_storage_overrides(args)])
    elif free:
        if args.overrides:
            raise ConfigError("KEY=VALUE overrides apply to a study file; free play takes flags only")
        config, base_dir = free_play_config(args), Path.cwd()
    else:
        raise ConfigError(
            "give a study file (e.g. configs/study/default.yaml) or a partner to play with: "
            "--partner NAME (e.g. cec), --checkpoint RUN_DIR, --zoo ZOO.yaml [--group ALG] or --random-init"
        )
    what = "free play" if config.free_play else f"study {config.name!r}"
    log.info("%s: loading the partners and the kitchens, then compiling (a line every few seconds)", what)
    return serve(config, base_dir, args.host, args.port)


def _cmd_export(args: argparse.Namespace) -> int:
    from cec.evaluation.results import write_csv
    from services.play.export import export_tables, write_survey_csv
    from services.play.recording import RecordError, open_stores

    config, _ = load_study(args.study, [*args.overrides, *_storage_overrides(args)])
    directory = "" if args.redis_url is not None else config.storage.dir
    stores = open_stores(
        config.name, directory, config.storage.redis_url, config.storage.key_prefix, create=False
    )
    problems: list[str] = []
    try:
        if not stores[0].participants():
            raise RecordError(f"no records of study {config.name!r} in {directory or 'Redis'}")
        table, survey = export_tables(stores[0], problems)
        quarantined = list(stores[0].quarantined)
    finally:
        for s in stores:
            s.close()
    out = Path(args.out)
    results = write_csv(table, out / "results.csv")
    answers = write_survey_csv(survey, out / "survey.csv")
    participants = len(set(table.policy_a.tolist()))
    print(f"wrote {results} ({len(table)} rounds, {participants} participants)")
    print(f"wrote {answers} ({len(survey)} answers)")
    if quarantined or problems:
        print(f"left out {len(quarantined)} quarantined record line(s) and passed over {len(problems)} "
              "round(s) or participant(s), each with why:")  # fmt: skip
        for line in [*map(str, quarantined), *problems]:
            print(f"  {line}")
    return 0


def run(args: argparse.Namespace) -> int:
    return int(args.play_func(args))


SERVICE = Service(
    "play",
    "services.play",
    "human-AI play in the browser: serve a study, export its records",
    add_arguments,
    run,
    failures=(OSError, StoreError),
)
