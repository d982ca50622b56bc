"""`cec reproduce dual-destination`: its arguments, `--plan`'s table, and `reproduce_dual_destination`,
which trains (`plan`), plays (`evaluate`), summarises (`summary`) and reports (`report`) each variant in
that order (see the package's docstring)."""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import Any, TextIO

from apps.machine import duration, machine_info
from apps.reproduce import pipeline
from apps.reproduce.dual_destination.evaluate import cached_evaluation
from apps.reproduce.dual_destination.modes import FULL, PAPER_SCALE, QUICK, Mode
from apps.reproduce.dual_destination.paper import VARIANTS
from apps.reproduce.dual_destination.plan import ROOT, plan_lines, train_only, train_variant
from apps.reproduce.dual_destination.report import plot_curves, write_report
from apps.reproduce.dual_destination.summary import (
    CONVENTIONS_FILE,
    conventions,
    load_conventions,
    save_conventions,
    summarise,
    training_stats,
)
from apps.reproduce.pipeline import play_seconds
from cec.checkpoints import code_version
from cec.config import ConfigError


def reproduce_dual_destination(
    mode: Mode,
    out: Path,
    work: Path,
    *,
    variants: Sequence[str] = VARIANTS,
    progress: bool = True,
    log: TextIO = sys.stderr,
    command: str = "",
    report_only: bool = False,
) -> Path:
    """Trains, evaluates and reports (see the module docstring); returns the report's path.

    `report_only`: neither train nor play; the report from each variant's cross-play table, the conventions
    the run that played found (`conventions.json`; else from the exported policies) and training metrics in
    `work` (a work folder kept without its policies and training states)."""
    t_start = time.perf_counter()
    commit = code_version(short=True)  # before this command writes anything (a work folder may be tracked)
    load_start = machine_info(load_average=True)["load_average_1_5_15min"]
    stages: dict[str, float] = {}
    summaries = {}
    trained: dict[str, dict[str, Any]] = {}
    seat0: dict[str, dict[str, dict[int, str]]] = {}
    skipped_runs: list[str] = []
    curves: dict[str, str] = {}
    played: dict[str, float | None] = {}  # seconds each variant's cross-play took when it was played
    train_s = eval_s = 0.0
    for variant in variants:
        t0 = time.perf_counter()
        if not report_only:
            pipeline.note(log, f"{variant}: training (cec zoo build into {work / variant / 'zoo'})")
            zoo_manifest, finished = train_variant(mode, variant, work, progress=progress, log=log)
            skipped_runs += [f"{variant}/{name}" for name in finished]
        stages[f"{variant}: train"] = time.perf_counter() - t0
        train_s += stages[f"{variant}: train"]
        t0 = time.perf_counter()
        found = work / variant / CONVENTIONS_FILE
        if report_only:  # the conventions as the run that played found them, or from its exported policies
            from apps.zoo_build import MANIFEST

            exported = work / variant / pipeline.POLICIES / MANIFEST
            need = CONVENTIONS_FILE if found.is_file() or not exported.is_file() else pipeline.POLICIES_SOURCE
            table = pipeline.played_table(work / variant, "dual-destination", need)
            seat0[variant] = load_conventions(found) if found.is_file() else conventions(variant, exported)
        else:
            table = cached_evaluation(mode, variant, zoo_manifest, work / variant, log=log)
            manifest = pipeline.export_policies(zoo_manifest, work / variant / pipeline.POLICIES, log=log)
            seat0[variant] = conventions(variant, manifest)
            save_conventions(seat0[variant], found)
        seconds = play_seconds(work / variant)
        played[variant] = None if math.isnan(seconds) else seconds
        summaries[variant] = summarise(table, variant)
        trained[variant] = {a: t.__dict__ for a, t in training_stats(work / variant / "zoo").items()}
        curves[variant] = plot_curves(mode, work / variant / "zoo", variant, out).name
        stages[f"{variant}: evaluate"] = time.perf_counter() - t0
        eval_s += stages[f"{variant}: evaluate"]
    machine = machine_info(load_average=True)
    machine["load_average_start"] = load_start
    meta = {
        "command": command or command_of(mode),
        "date": datetime.date.today().isoformat(),
        "git": commit,
        "machine": machine,
        "wall_s": time.perf_counter() - t_start,
        "train_s": train_s,
        "eval_s": eval_s,
        "stages": stages,
        "training": trained,
        "played_s": played,
        "conventions": seat0,
        "curves": curves,
        "skipped_runs": skipped_runs,
        "work": str(work),
    }
    path = write_report(out, mode, summaries, meta)
    pipeline.note(log, f"wrote {path}")
    return path


def command_of(mode: Mode) -> str:
    """The command line that runs `mode` (the full version has no flag)."""
    return "cec reproduce dual-destination" + ("" if mode.name == "full" else f" --{mode.name}")


def _print_plan(mode: Mode, variants: Sequence[str], work: Path, out: Path, file: TextIO) -> None:
    lines = plan_lines(mode, work, variants)
    print(f"cec reproduce dual-destination ({mode.name}): work {work}, report {out}", file=file)
    print(
        f"{'variant':12s} {'algorithm':10s} {'seeds':>5s} {'steps/seed':>12s} {'updates':>8s} "
        f"{'estimate':>10s} {'done':>6s} {'left':>10s}",
        file=file,
    )

    for ln in lines:
        print(
            f"{ln.zoo:12s} {ln.run:10s} {ln.seeds:5d} {ln.env_steps:12,d} {ln.updates:8d} "
            f"{duration(ln.estimate_s):>10s} {ln.done:6.0%} {duration(ln.left_s):>10s}",
            file=file,
        )
    total, left = sum(ln.estimate_s for ln in lines), sum(ln.left_s for ln in lines)
    basis = f" (from seconds per update measured on {mode.measured_on})" if mode.measured_on else ""
    print(f"training total: {duration(total)}, left: {duration(left)}{basis}", file=file)
    print(
        "evaluation: XP within each algorithm and everyone with the oracle partner, "
        f"{mode.episodes['fixed']} episodes on the fixed task and {mode.episodes['generated']} on each of "
        "100 generated tasks",
        file=file,
    )


def _cmd_reproduce_dd(args: argparse.Namespace) -> int:
    if args.quick and args.paper:
        raise ConfigError("--quick and --paper are two versions: give one of them, or neither (the full one)")
    if args.train_only and args.report_only:
        raise ConfigError(
            "--train-only trains without a report and --report-only reports without training: "
            "give one of them"
        )
    mode = QUICK if args.quick else PAPER_SCALE if args.paper else FULL
    work = Path(args.work or ROOT / "runs" / "reproduce" / f"dual_destination-{mode.name}")
    out = Path(args.out or ROOT / "runs" / "reproduce" / f"dual_destination-{mode.name}" / "report")
    variants = tuple(args.variants.split(",")) if args.variants else mode.variants
    unknown = [v for v in variants if v not in VARIANTS]
    if unknown:
        raise ConfigError(f"unknown variant(s) {unknown}; choose from {list(VARIANTS)}")
    if args.plan:
        _print_plan(mode, variants, work, out, sys.stdout)
        return 0
    if args.train_only:
        for variant, manifest in train_only(mode, work, variants, progress=not args.quiet).items():
            print(f"{variant}: trained, zoo {manifest}")
        print("the report: the same command without --train-only (it reuses what was trained)")
        return 0
    if code_version().endswith("+dirty") and not args.allow_dirty:
        raise ConfigError(
            "the working tree has uncommitted changes, so the report could not name the code it came from; "
            "commit them first (or pass --allow-dirty for a report marked +dirty)"
        )
    command = command_of(mode)
    command += f" --variants {','.join(variants)}" if args.variants else ""
    command += "".join(f" --{k} {getattr(args, k)}" for k in ("work", "out") if getattr(args, k))
    command += " --report-only" if args.report_only else ""
    path = reproduce_dual_destination(
        mode, out, work, variants=variants, progress=not args.quiet, command=command,
        report_only=args.report_only,
    )  # fmt: skip
    print(f"wrote {path}")
    return 0


def add_subcommand(rep_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers `dual-destination` on the `cec reproduce` subparsers."""
    dd = rep_sub.add_parser(
        "dual-destination",
        help="train IPPO, FCP and CEC on the Dual Destination variants, cross-play, report beside the paper",
    )
    dd.add_argument(
        "--quick", action="store_true", help="the reduced version (under 30 minutes on a 2-core CPU)"
    )
    dd.add_argument(
        "--paper",
        action="store_true",
        help="the paper's networks and budgets (1e8-3e8 steps per seed: a GPU job; see --plan)",
    )
    dd.add_argument(
        "--plan", action="store_true", help="print what would run and its expected time, then exit"
    )
    dd.add_argument(
        "--work", help="runs, zoos and result tables (default runs/reproduce/dual_destination-MODE)"
    )
    dd.add_argument(
        "--out",
        help="report folder (default runs/reproduce/dual_destination-MODE/report, which git ignores; the "
        "committed reports are --out benchmarks/results/dual_destination/MODE)",
    )
    dd.add_argument(
        "--variants",
        help=f"comma-separated subset of {','.join(VARIANTS)} (default: all; --quick: full_obs)",
    )
    dd.add_argument(
        "--allow-dirty",
        action="store_true",
        help="write the report from a tree with uncommitted changes (its git revision is marked +dirty)",
    )
    dd.add_argument(
        "--train-only",
        action="store_true",
        help="train (resuming) and stop before cross-play and the report: for several processes or "
        "sessions sharing the training; the run without it reuses what they trained",
    )
    dd.add_argument(
        "--report-only",
        action="store_true",
        help="neither train nor play: the report from the work folder's cross-play tables, conventions "
        "and training metrics (a work folder kept without its policies and training states)",
    )
    dd.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    dd.set_defaults(func=_cmd_reproduce_dd)
