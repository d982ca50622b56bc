"""`cec reproduce overcooked`: its arguments, `--plan`'s lines, and `reproduce_overcooked`, which trains
(`plan`), plays (`evaluate`: each line-up between training runs once its agents are trained, the rest
after), summarises (`summary`) and reports (`report`, `sections`, `figures`) in that order (see the
package's docstring).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from apps.machine import duration, machine_info
from apps.reproduce import pipeline
from apps.reproduce.overcooked.evaluate import (
    cached_controls,
    cached_curves,
    cached_evaluation,
    cached_short,
    level_spec,
    planned_episodes,
    play_ready,
    played_lineups,
)
from apps.reproduce.overcooked.figures import write_figures
from apps.reproduce.overcooked.modes import AUTHORS_STEPS, EVAL_STEPS, LEVEL_SETS, MACHINE_FILE, MODES, Mode
from apps.reproduce.overcooked.plan import plan_lines, trained_runs, zoo
from apps.reproduce.overcooked.report import write_report
from apps.reproduce.overcooked.sections import analysis_lines, curve_lines, curve_points
from apps.reproduce.overcooked.summary import seed_scores
from apps.reproduce.pipeline import play_seconds, read_metrics, train_seconds
from cec.agents.zoo import HUMAN_PROXY
from cec.checkpoints import code_version
from cec.config import ConfigError

if TYPE_CHECKING:
    from apps.zoo_build import PlannedRun


def reproduce_overcooked(
    mode: Mode, work: Path, out: Path, *, progress: bool = True, log: TextIO = sys.stdout, command: str = "",
    report_only: bool = False, policies: Path | None = None,
) -> Path | None:  # fmt: skip
    """Train (resumable), evaluate (cached), report. Returns the report, or None when interrupted.

    `report_only`: neither train nor play the zoo; the report from the work folder's cross-play table,
    curves and `machine.json` as the machine that trained and played wrote them (a work folder brought back
    from a GPU machine without its checkpoints); the controls, which need no trained agent, are played if
    the folder lacks them (`cached_controls`). `policies`: a manifest whose CEC entries draw the GIF
    instead of the zoo's (the exported CEC seeds); where neither has the checkpoints, the GIF in `out` is
    kept as it is (`figures.crossplay_gif`)."""
    commit = code_version(short=True)  # before this command writes anything into the checkout
    if report_only:
        table = pipeline.played_table(work, "overcooked", MACHINE_FILE)
        ran_on = json.loads((work / MACHINE_FILE).read_text())
        short = cached_short(work)
    else:
        the_zoo = zoo(mode, work)

        def between(plan: list[PlannedRun]) -> None:  # a line-up's games, once its agents are trained
            play_ready(mode, plan, the_zoo.zoo_dir, work, log=log)

        try:
            result = the_zoo.build(progress=progress, log=log, between=between)
            if result.interrupted or result.manifest is None:
                pipeline.note(log, "training interrupted; run the same command again to continue")
                return None
            table = cached_evaluation(mode, result.manifest, work, log=log, commit=commit)
            # the authors' code's 100-step episodes, the same line-ups and draws (a quarter of the steps)
            short = cached_evaluation(
                mode, result.manifest, work, log=log, commit=commit, steps=AUTHORS_STEPS
            )
        except KeyboardInterrupt:  # Ctrl-C while a line-up played (training stops at its own checkpoint)
            pipeline.note(log, "cross-play interrupted; the line-ups played are kept: run the same command "
                               "again to continue")  # fmt: skip
            return None
        record = work / MACHINE_FILE  # where someone removed it: this machine, unknown training commits
        ran_on = (
            json.loads(record.read_text())
            if record.is_file()
            else {"machine": machine_info(), "commit": commit}
        )
    from cec.evaluation.results import EpisodeTable

    controls = cached_controls(mode, work, log=log, commit=commit)
    with_controls = EpisodeTable.concat([table, controls])
    if (work / "controls" / MACHINE_FILE).is_file():
        ran_on = {**ran_on, "controls": json.loads((work / "controls" / MACHINE_FILE).read_text())}
    from cec.evaluation.seeds import seed_matrix

    summary = {ls: seed_scores(with_controls, level_spec(mode, ls).split(",")) for ls in LEVEL_SETS}
    matrices = {ls: seed_matrix(table, level_spec(mode, ls).split(",")) for ls in LEVEL_SETS}
    short_summary = None if short is None else {
        ls: seed_scores(short, level_spec(mode, ls).split(",")) for ls in LEVEL_SETS
    }  # fmt: skip
    plan, missing = trained_runs(mode, work)
    train_s = {p.run: train_seconds(read_metrics(work / "zoo" / "runs" / p.run)) for p in plan}
    points, kitchens = curve_points(cached_curves(mode, work, log=log, report_only=report_only))
    sections = [*analysis_lines(mode, table, work / "zoo" / "runs", controls), *curve_lines(points, kitchens)]
    with pipeline.held(out, what=f"the report in {out}", log=log):  # two invocations side by side: in turn
        figures = write_figures(
            mode, work, out, table, points, log=log, policies=policies or work / "zoo" / "zoo.yaml"
        )
        report = write_report(
            mode, summary, out, figures=figures, plan=plan, command=command, ran_on=ran_on, commit=commit,
            skipped=table.skipped, train_s=train_s, played_s=play_seconds(work), sections=sections,
            missing=missing, matrices=matrices, short=short_summary,
        )  # fmt: skip
    pipeline.note(log, f"report: {report}")
    return report


def _cmd(args: argparse.Namespace) -> int:
    name = "quick" if args.quick else "paper" if args.paper else "cpu"
    mode = MODES[name]
    work = Path(args.work or f"runs/reproduce/overcooked-{name}")
    # under runs/ (which git ignores) unless told; the committed reports: --out benchmarks/results/...
    out = Path(args.out or f"runs/reproduce/overcooked-{name}/report")
    command = "cec reproduce overcooked" + ("" if name == "cpu" else f" --{name}")
    if args.plan:
        lines = plan_lines(mode, work)
        total = sum(p.estimate_s for p in lines)
        left = sum(p.left_s for p in lines)
        print(f"{command}: {len(lines)} training runs into {work}/zoo, report to {out}")
        for p in lines:
            print(f"  {p.run:<36} {p.seeds} seed(s) x {p.env_steps:>13,} steps ({p.updates} updates)"
                  f"  ~{duration(p.estimate_s)}, {p.done:.0%} done")  # fmt: skip
        print(f"training: ~{duration(total)} on one core, ~{duration(left)} left "
              f"(s per update and seed: {', '.join(f'{a} {s:g}' for a, s in mode.seconds_per_update.items())}"
              f"; measured on {mode.measured_on or 'no machine yet'})")  # fmt: skip
        counts = planned_episodes(mode)
        parts = ", ".join(f"{part} {n:,}" for part, n in counts.items())
        played = sum(counts.values())
        rate = "time not measured"
        if set(counts) <= set(mode.episodes_per_s):
            seconds = sum(n / mode.episodes_per_s[part] for part, n in counts.items())
            rates = ", ".join(f"{part} {r:g}" for part, r in mode.episodes_per_s.items())
            rate = f"~{duration(seconds)} (episodes/s: {rates}; measured in {mode.eval_measured_on})"
        done, lineups = played_lineups(mode, work)
        print(
            f"then cross-play: {played:,} episodes of {EVAL_STEPS} steps ({parts}), {rate}; the same "
            f"line-ups at the authors' {AUTHORS_STEPS} steps (about a quarter of that time); then the "
            "report (cached games are not played again)"
        )
        print(f"line-ups played (each as soon as its agents are trained): {done} of {lineups}")
        return 0
    if args.proxies is not None:
        mode = dataclasses.replace(mode, proxies=args.proxies)
    if args.policies and not args.report_only:
        raise ConfigError("--policies draws the GIF of --report-only; add --report-only or drop it")
    report = reproduce_overcooked(
        mode, work, out, progress=not args.quiet, command=command, report_only=args.report_only,
        policies=Path(args.policies) if args.policies else None,
    )  # fmt: skip
    return 0 if report is not None else 130


def add_subcommand(rep_sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers `overcooked` on the `cec reproduce` subparsers."""
    oc = rep_sub.add_parser(
        "overcooked",
        help="train CEC and the baselines on Overcooked, cross-play on classic and held-out kitchens, report",
    )
    size = oc.add_mutually_exclusive_group()
    size.add_argument("--quick", action="store_true", help="the pipeline at a small budget (minutes)")
    size.add_argument("--cpu", action="store_true", help="the CPU version (the default; see --plan)")
    size.add_argument("--paper", action="store_true", help="the paper's networks and budgets (a GPU job)")
    oc.add_argument("--plan", action="store_true", help="print the runs and their expected time, then exit")
    oc.add_argument("--work", help="runs and result tables (default runs/reproduce/overcooked-MODE)")
    oc.add_argument(
        "--out",
        help="report folder (default runs/reproduce/overcooked-MODE/report, which git ignores; the committed "
        "reports are --out benchmarks/results/overcooked/MODE)",
    )
    oc.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    oc.add_argument(
        "--report-only",
        action="store_true",
        help="neither train nor play: the report from the work folder's cross-play table and curves",
    )
    oc.add_argument(
        "--policies",
        metavar="MANIFEST",
        help="with --report-only: CEC policies that replay the GIF (without them, the GIF in --out is kept)",
    )
    oc.add_argument(
        "--proxies",
        metavar="MANIFEST",
        help=f"zoo whose {HUMAN_PROXY} entries play every agent on the classic kitchens (default: shipped; "
        "'' none); they need the agents' network (cec humans bc --preset)",
    )
    oc.set_defaults(func=_cmd)
