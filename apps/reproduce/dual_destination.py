"""`cec reproduce dual-destination [--quick | --paper]`: the paper's Dual Destination results, end to end.

    cec reproduce dual-destination --plan      # what would be trained and evaluated, and how long it takes
    cec reproduce dual-destination --quick     # a reduced version (under 30 minutes on a 2-core CPU)
    cec reproduce dual-destination             # the full version, sized for a CPU (--plan states its time)
    cec reproduce dual-destination --paper     # the paper's networks and budgets (a GPU job)

For each variant of the game (fully observable, partially observable 3x3 view, multi-task green + pink):

1. **Train** (`cec zoo build`, resumable: run the same command again after an interruption; several
   processes may share it, one per core, and `--train-only` stops each before step 2) IPPO seeds
   and FCP seeds on the fixed task (the multi-task layout for the multi-task variant; FCP's population is
   the IPPO seeds at their first, middle and last milestones), and CEC seeds on procedurally generated
   tasks, the fixed tasks and the 100 evaluation tasks held out of its training.
2. **Evaluate** cross-play (`cec.evaluation.crossplay`, common random numbers, both seat orders) on the
   fixed task and on the 100 held-out generated tasks: every pair of different seeds of one algorithm
   (zero-shot coordination with unseen partners, the paper's measure), self-play, and every policy with
   the scripted oracle partner (`dd_oracle`) as a reference point.
3. **Report** (`dd_summary.py`, `dd_report.py`) `report.md` (+ `summary.json`, bar plots) beside the
   paper's numbers (`paper_dual_destination.yaml`, through `dd_paper.py`): per variant, task set
   and algorithm the normalised cross-play score (return / 200) with its standard error over seeds (each
   seed's mean with the other seeds); the paper's orderings with Welch t-tests and bootstrap intervals over
   those per-seed means (seeds are the independent units; pairs share seeds); and, where a number
   differs from the paper's by more than 0.05, by how much.

The work directory (`--work`, default `runs/reproduce/dual_destination-<mode>`) holds one zoo per
variant (`<variant>/zoo`), its spec and the result tables; the report goes to `--out` (default
`benchmarks/results/dual_destination/<mode>`).
"""

from __future__ import annotations

import argparse
import datetime
import math
import sys
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any, TextIO

from apps.machine import duration, machine_info
from apps.reproduce import pipeline
from apps.reproduce.dd_modes import FULL as FULL
from apps.reproduce.dd_modes import MODES as MODES
from apps.reproduce.dd_modes import PAPER_SCALE as PAPER_SCALE
from apps.reproduce.dd_modes import QUICK as QUICK
from apps.reproduce.dd_modes import Mode, algorithm_of
from apps.reproduce.dd_paper import (
    ABLATIONS,
    LEVEL_SET_TITLES,
    LEVEL_SETS,
    ORACLE,
    VARIANT_TITLES,
    VARIANTS,
    fixed_level_name,
)

# Defined by the modules below since the split; still importable from here under their old names
from apps.reproduce.dd_paper import CLAIMS as CLAIMS
from apps.reproduce.dd_paper import ORACLE_FIXED as ORACLE_FIXED
from apps.reproduce.dd_paper import PAPER as PAPER
from apps.reproduce.dd_paper import PaperNumber as PaperNumber
from apps.reproduce.dd_paper import paper_number as paper_number
from apps.reproduce.dd_report import write_report
from apps.reproduce.dd_summary import ALPHA as ALPHA
from apps.reproduce.dd_summary import Score as Score
from apps.reproduce.dd_summary import conventions, summarise, training_stats
from apps.reproduce.pipeline import play_seconds
from cec.checkpoints import code_version
from cec.config import ConfigError

if TYPE_CHECKING:
    from apps.zoo_build import BuildResult

ROOT = Path(__file__).resolve().parents[2]


# ---------------------------------------------------------------------------------------------------------
# THE PLAN
# ---------------------------------------------------------------------------------------------------------


def _variant_overrides(variant: str, algorithm: str) -> list[str]:
    if variant == "partial_obs":
        return ["env.dual_destination.partial_obs=true"]
    if variant == "multi_task":
        levels = "procedural_multi_task" if algorithm_of(algorithm) == "cec" else "multi_task"
        return ["env.dual_destination.multi_task=true", f"env.levels={levels}"]
    return []


def zoo_spec(mode: Mode, variant: str) -> dict[str, Any]:
    """The `cec zoo build` spec of one variant: IPPO, then FCP (population: the IPPO run), then CEC."""
    ippo_seeds = list(mode.seeds["ippo"])
    population = (
        f"[{{run: runs/ippo-s{ippo_seeds[0]}, seeds: {ippo_seeds}, checkpoints: [first, middle, last]}}]"
    )
    extra = {
        "ippo": ["checkpoint.milestones=[0.0,0.5,1.0]"],  # FCP's early, middle and final partners
        "fcp": [f"partner.population={population}"],
    }
    entries = []
    for row in mode.rows:
        preset, overrides = _run_config(mode, variant, row, extra.get(row, []))
        entry = {"preset": preset, "seeds": list(mode.seeds[row]), "name": row, "overrides": overrides}
        entries.append(entry | ({"label": row} if row in ABLATIONS else {}))
    return {"entries": entries}


def _run_config(mode: Mode, variant: str, row: str, extra: Sequence[str] = ()) -> tuple[str, list[str]]:
    """The preset (absolute: a spec that names it works from any directory) and the overrides of one row's
    run: its budget, the variant's settings, `extra`, the mode's overrides, and an ablation's last."""
    ablation = list(ABLATIONS[row].overrides) if row in ABLATIONS else []
    budget = f"total_env_steps={mode.steps[variant][row]}"
    overrides = [budget, *_variant_overrides(variant, row), *extra, *mode.overrides, *ablation]
    return str(ROOT / mode.presets[algorithm_of(row)]), overrides


def zoo(mode: Mode, variant: str, work: Path) -> pipeline.Zoo:
    """The variant's zoo: its spec in `work/<variant>/spec.yaml`, built into `work/<variant>/zoo`."""
    return pipeline.Zoo(
        work / variant, zoo_spec(mode, variant), f"`cec reproduce dual-destination` ({mode.name}, {variant})"
    )


def plan_lines(mode: Mode, work: Path, variants: Sequence[str] = VARIANTS) -> list[pipeline.PlanLine]:
    """Every training run of `variants` (one line per row, `zoo` its variant), with the estimate from
    `mode.seconds_per_update` (NaN where not measured) and the share already trained under `work`. Writes
    each variant's zoo spec there, as training does, and so refuses (`ConfigError`) a finished run trained
    with another config."""
    lines = []
    for variant in variants:
        plan = zoo(mode, variant, work).plan()
        for i, row in enumerate(mode.rows):
            runs = [r for r in plan if r.entry == i]
            lines.append(pipeline.plan_line(row, runs, mode.seconds_per_update.get(row, math.nan), variant))
    return lines


# ---------------------------------------------------------------------------------------------------------
# TRAIN AND EVALUATE
# ---------------------------------------------------------------------------------------------------------


def _build_variant(
    mode: Mode, variant: str, work: Path, *, progress: bool, log: TextIO, wait: bool
) -> BuildResult:
    """Writes the variant's zoo spec and builds the zoo (resuming, skipping finished runs); returns
    `build_zoo`'s result. Raises `ConfigError` when the build was interrupted (run the command again)."""
    result = zoo(mode, variant, work).build(progress=progress, log=log, wait=wait)
    if result.interrupted:
        raise ConfigError(f"training of {variant} was interrupted; run the same command again to continue")
    return result


def train_variant(
    mode: Mode, variant: str, work: Path, *, progress: bool, log: TextIO
) -> tuple[Path, tuple[str, ...]]:
    """Trains the variant's zoo, waiting for runs other processes train; returns the manifest and the runs
    found finished."""
    result = _build_variant(mode, variant, work, progress=progress, log=log, wait=True)
    assert result.manifest is not None  # not interrupted, and it waited for every run
    return result.manifest, result.skipped


def train_only(
    mode: Mode, work: Path, variants: Sequence[str], *, progress: bool = True, log: TextIO = sys.stderr
) -> dict[str, Path]:
    """Trains `variants` (step 1 alone, as `--train-only`); returns each one's zoo manifest. A variant whose
    remaining runs other processes train is passed over until the later variants are done, so processes
    sharing a reproduction keep their cores busy instead of waiting on each other's runs."""
    manifests = {}
    for v in variants:
        result = _build_variant(mode, v, work, progress=progress, log=log, wait=False)
        if result.manifest is not None:
            manifests[v] = result.manifest
        else:
            pipeline.note(
                log, f"{v}: {', '.join(result.left)} trained by other processes; back to it at the end"
            )
    for v in variants:
        if v not in manifests:  # the rest is done: wait for the others' runs (and train any left over)
            manifests[v] = train_variant(mode, v, work, progress=progress, log=log)[0]
    return {v: manifests[v] for v in variants}


def _generated_spec(mode: Mode) -> str:
    if mode.generated_levels >= 100:
        return "generated"
    return pipeline.generated_levels(mode.generated_levels)


def evaluate_variant(mode: Mode, variant: str, manifest: Path, *, log: TextIO, seed: int = 0) -> Any:
    """Cross-play of the variant's zoo and the oracle partner -> one `EpisodeTable`.

    Per level set and algorithm, one evaluation of its seeds and the oracle partner, every pair: XP
    (two different seeds), SP, and every seed with the oracle (in both seats). Algorithms are evaluated
    apart (their networks may differ, and cross-algorithm pairs are not in the paper's figures); the
    oracle's self-play is kept once.
    """
    from cec.agents.policy import scripted_policy
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels
    from cec.evaluation.results import EpisodeTable

    policies = pipeline.load_zoo_policies(manifest, variant)
    oracle = scripted_policy("dd_oracle", ORACLE, algorithm=ORACLE)
    tables = []
    for level_set in LEVEL_SETS:
        spec = fixed_level_name(variant) if level_set == "fixed" else _generated_spec(mode)
        levels = eval_levels("dual_destination", spec)
        for greedy in (False, True):
            config = EvalConfig(
                levels=spec, episodes=mode.episodes[level_set], seed=seed, games_per_call=1, greedy=greedy
            )
            for k, algo in enumerate(mode.rows):
                group = [p for p in policies if p.algorithm == algo]
                t0 = time.perf_counter()
                # greedy: the seeds among themselves (XP, SP); sampled: with the oracle partner too
                table = crossplay(group if greedy else [*group, oracle], levels, config)
                if k and not greedy:  # the oracle's self-play once
                    table = table.select((table.policy_a != ORACLE) | (table.policy_b != ORACLE))
                tables.append(table)
                actions = "greedy" if greedy else "sampled"
                pipeline.note(
                    log,
                    f"{variant}: {len(group)} {algo} seeds{'' if greedy else ' + oracle partner'}, every "
                    f"pair, {actions} actions, on the {LEVEL_SET_TITLES[level_set]}: {len(table)} episodes "
                    f"in {time.perf_counter() - t0:.0f}s",
                )
    return EpisodeTable.concat(tables)


def evaluation_key(mode: Mode, variant: str, manifest: Path) -> dict[str, Any]:
    """What a variant's results depend on: the evaluation settings, every zoo entry (its checkpoint and
    the state's SHA-256 that `cec zoo build` pinned) and the oracle partner's code."""
    entries = pipeline.zoo_entries(manifest)
    return {
        "variant": variant,
        "episodes": mode.episodes,
        "generated_levels": mode.generated_levels,
        "zoo": sorted(entries, key=str),
        "oracle_partner": oracle_partner_digest(),
    }


def oracle_partner_digest() -> str:
    """SHA-256 of the oracle partner's source (`cec.envs.dual_destination.partner`): what it played is not
    reused once it changes."""
    import hashlib

    from cec.envs.dual_destination import partner

    return hashlib.sha256(Path(partner.__file__).read_bytes()).hexdigest()


def cached_evaluation(mode: Mode, variant: str, manifest: Path, vdir: Path, *, log: TextIO) -> Any:
    """`evaluate_variant`, or the table an earlier invocation wrote (`vdir/results.csv`) when nothing it
    depends on has changed (`evaluation_key`); see `apps.reproduce.pipeline.cached_table`."""
    from apps.reproduce.pipeline import cached_table

    key = evaluation_key(mode, variant, manifest)
    play = lambda: evaluate_variant(mode, variant, manifest, log=log)  # noqa: E731
    return cached_table(vdir, key, play, label=f"{variant}: ", log=log)


# ---------------------------------------------------------------------------------------------------------
# THE COMMAND
# ---------------------------------------------------------------------------------------------------------


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

    `report_only`: neither train nor play; the report from each variant's cross-play table, exported
    policies (`pipeline.export_policies`, for the conventions) and training metrics in `work` (a work folder
    kept without its training states)."""
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
        if report_only:  # the conventions from the exported policies
            from apps.zoo_build import MANIFEST

            table = pipeline.played_table(work / variant, "dual-destination", pipeline.POLICIES_SOURCE)
            manifest = work / variant / pipeline.POLICIES / MANIFEST
        else:
            table = cached_evaluation(mode, variant, zoo_manifest, work / variant, log=log)
            manifest = pipeline.export_policies(zoo_manifest, work / variant / pipeline.POLICIES, log=log)
        seconds = play_seconds(work / variant)
        played[variant] = None if math.isnan(seconds) else seconds
        summaries[variant] = summarise(table, variant)
        seat0[variant] = conventions(variant, manifest)
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


def plot_curves(mode: Mode, zoo_dir: Path, variant: str, out: Path) -> Path:
    """`out/curves_<variant>.png`: every row's normalised training return and policy entropy per seed
    against env steps, from its runs' metrics (`zoo_dir/runs/<row>-s<seed>`)."""
    from cec.evaluation.curves import plot_learning_curves

    runs = {row.upper(): sorted(zoo_dir.glob(f"runs/{row}-s*")) for row in mode.rows}
    panels = (("normalised_return", "normalised training return"), ("entropy", "policy entropy"))
    title = f"Dual Destination, {VARIANT_TITLES[variant].lower()}: training (IPPO, FCP on the fixed task)"
    return plot_learning_curves(
        {k: v for k, v in runs.items() if v},
        out / f"curves_{variant}.png",
        smooth=5,
        title=title,
        panels=panels,
    )


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
    out = Path(args.out or ROOT / "benchmarks" / "results" / "dual_destination" / mode.name)
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


def add_subcommand(rep_sub: Any) -> None:
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
    dd.add_argument("--out", help="report folder (default benchmarks/results/dual_destination/MODE)")
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
        help="neither train nor play: the report from the work folder's cross-play tables, exported "
        "policies and training metrics (a work folder kept without its training states)",
    )
    dd.add_argument("--quiet", action="store_true", help="no per-update progress lines")
    dd.set_defaults(func=_cmd_reproduce_dd)
