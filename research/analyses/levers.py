"""The levers of the every-kitchen work, each against the recipe it changes, at equal env steps per seed.

A lever is a `benchmarks/time_to_skill.py` output (its seeds' cross-play and self-play on the validation
kitchens, by kind and per classic kitchen, at every milestone). The recipe without the lever is CEC of the
CPU reproduction (`cec reproduce overcooked --cpu`: the time-to-skill recipe, 4 seeds x 10.5M env steps,
its committed table), read by the same parts (`cec.levels.kinds.validation_parts`), and the recipe's own
time-to-skill curve (8 seeds) at exactly the lever's env steps, on the generated kitchens (that curve
predates the split by kind). Every figure is the
cross-play over pairs of two different seeds with its jackknife standard error over seeds; the difference
is tested with `cec.evaluation.stats.compare_estimates` (independent seeds; the t-test's p beside the
interval: with 4 seeds a side treat p as a reading, not a verdict), Holm-adjusted over the parts shown.

With `--control JSON` the recipe is instead the time-to-skill output of the recipe itself trained beside the
levers (the same machine and seeds): every part against its row at exactly the lever's env steps. A lever
and its control may also be result tables of `cec eval` (CSV, one recipe's seeds each, `--steps` saying
where their checkpoints are): how the test set, played once after the choice, reports a chosen lever.

    L=research/diary/reproduce_overcooked/levers
    python research/analyses/levers.py --lever coverage=$L/cov35.json --out $L/summary
    python research/analyses/levers.py --lever ent02=$L/ent02_4seeds.json \\
        --control $L/control_4seeds.json --steps 2621440 --out ...

prints a Markdown table and writes OUT.json.
"""

from __future__ import annotations

import argparse
import datetime
import json
import math
from pathlib import Path
from typing import Any

from cec.evaluation.markdown import interval, num, pm, table_lines
from cec.evaluation.parts import part_scores
from cec.evaluation.results import read_csv
from cec.evaluation.stats import CrossPlay, compare_estimates, holm
from cec.levels.heldout import heldout_levels, test_levels

BASELINE_TABLE = Path("benchmarks/results/overcooked/cpu/work/results.csv.bz2")
BASELINE_STEPS = 10_485_760


def baseline(table_path: Path, algorithm: str) -> dict[str, dict[str, float]]:
    """{part: {levels, xp, xp_se, sp, sp_se, seeds}} of `algorithm`'s seeds with each other in a table."""
    parts = part_scores(read_csv(table_path), algorithm, dict(heldout_levels()))
    return {name: part._asdict() for name, part in parts.items()}


def _is_table(path: Path) -> bool:
    return path.name.endswith((".csv", ".csv.bz2"))


def table_row(path: Path, steps: int) -> dict[str, Any]:
    """A result table of `cec eval` (one algorithm's seeds, e.g. a recipe's final checkpoints on the test
    set) as a time-to-skill row at `steps`: its parts over the validation and test kitchens it played."""
    table = read_csv(path)
    algorithms = sorted(set(table.algorithm_a.astype(str)))
    if len(algorithms) != 1:
        raise SystemExit(f"{path}: holds the algorithms {algorithms}; give one recipe's seeds per table")
    played = set(table.level.astype(str))
    levels = {n: lv for n, lv in (*heldout_levels(), *test_levels()) if n in played}
    parts = part_scores(table, algorithms[0], levels)
    seeds = sorted({int(s) for s in table.seed_a})
    return {"run": path.name, "update": None, "env_steps_per_seed": steps, "seeds": seeds,
            "parts": {name: part._asdict() for name, part in parts.items()}}  # fmt: skip


def lever_row(path: Path, steps: int) -> dict[str, Any]:
    """The row of a time-to-skill output at `steps` env steps per seed (the closest one at or below), or a
    result table's (`table_row`)."""
    if _is_table(path):
        return table_row(path, steps)
    rows = [
        r for r in json.loads(path.read_text())["rows"] if r["env_steps_per_seed"] <= steps and "parts" in r
    ]
    if not rows:
        raise SystemExit(f"{path}: no row with parts at or below {steps:,} env steps per seed")
    return max(rows, key=lambda r: r["env_steps_per_seed"])


BASELINE_CURVE = Path("benchmarks/results/overcooked/cpu/runs/probes/tts-e64ep2mb8-10m-r6-8seeds.json")
EQUAL_STEPS = "generated, the recipe at equal steps"


def curve_point(path: Path, steps: int) -> dict[str, float] | None:
    """The recipe's own time-to-skill row at exactly `steps` env steps per seed (its generated kitchens
    only: the curve predates the split by kind), as a part; None if it has no such milestone."""
    for r in json.loads(path.read_text())["rows"]:
        if r["env_steps_per_seed"] == steps:
            return {
                "levels": 100,
                "xp": r["xp"],
                "xp_se": r["xp_se"],
                "sp": r["sp"],
                "seeds": len(r["seeds"]),
            }
    return None


def control_parts(path: Path, steps: int) -> dict[str, dict[str, float]]:
    """{part: score with its `seeds` count} of a time-to-skill output's row at exactly `steps` (or of a
    result table)."""
    row = lever_row(path, steps)
    if row["env_steps_per_seed"] != steps:
        raise SystemExit(f"{path}: no row at {steps:,} env steps per seed (the lever's)")
    return {part: {**score, "seeds": len(row["seeds"])} for part, score in row["parts"].items()}


def compare(
    levers: dict[str, Path],
    base: dict[str, dict[str, float]],
    steps: int,
    curve: Path | None = None,
    control: Path | None = None,
    control_steps: int | None = None,
) -> dict[str, Any]:
    """Each lever's row at `steps` part by part against `base` (and the `curve` at equal steps), or with a
    `control` output against its row at the lever's steps only (at `control_steps` if given: a longer run
    against a shorter one, each at its own end)."""
    out: dict[str, Any] = {}
    for name, path in levers.items():
        row = lever_row(path, steps)
        mine = dict(base)
        if control is not None:
            mine = control_parts(control, control_steps or row["env_steps_per_seed"])
        elif curve is not None and (point := curve_point(curve, row["env_steps_per_seed"])) is not None:
            mine = {EQUAL_STEPS: point, **base}
            row["parts"] = {EQUAL_STEPS: row["parts"]["generated"], **row["parts"]}
        parts = {}
        for part, b in mine.items():
            a = row["parts"].get(part)
            if a is None:
                continue
            seeds = len(row["seeds"])
            c = compare_estimates(
                CrossPlay(a["xp"], a["xp_se"], seeds), CrossPlay(b["xp"], b["xp_se"], int(b["seeds"]))
            )
            parts[part] = {"lever": a, "baseline": b, "diff": c.diff, "ci": [c.ci_low, c.ci_high], "p": c.p}
        for part, p in zip(parts, holm([v["p"] for v in parts.values()]), strict=True):
            parts[part]["p_holm"] = float(p)
        seeds = next(iter(mine.values()))["seeds"]
        at = f"at {control_steps / 1e6:.1f}M env steps per seed" if control_steps else "at the same steps"
        against = (
            f"the recipe trained beside it ({control.name}, {seeds:.0f} seeds) {at}"
            if control is not None
            else "its time-to-skill curve at the same steps (seeds 300-307, generated kitchens only), then "
            "the CPU reproduction's CEC (seeds 200-203) at 10.5M"
        )
        out[name] = {
            "row": {k: row[k] for k in ("run", "update", "env_steps_per_seed", "seeds")},
            "against": against,
            "parts": parts,
        }
    return out


DASH = "–"  # where there is no figure: 2 seeds have no standard error over seeds and no test
HEAD = ("part", "kitchens", "lever XP (SP)", "recipe XP (SP)", "difference [95% CI]", "p (Holm)")


def _xp_sp(score: dict[str, Any]) -> str:
    """A part's cross-play ± its standard error (`DASH` where there is none), self-play in brackets."""
    return f"{pm(score['xp'], score['xp_se'], no_error=DASH)} ({score['sp']:.1f})"


def markdown(result: dict[str, Any]) -> str:
    lines = []
    for name, lever in result.items():
        steps = lever["row"]["env_steps_per_seed"]
        seeds = lever["row"]["seeds"]
        lines += [
            f"**{name}** at {steps / 1e6:.1f}M env steps per seed (seeds {seeds}) against "
            f"the recipe without it: {lever['against']}, every part"
            + (
                f" ({len(seeds)} seeds: one pair, no standard error over seeds and no test; a reading):"
                if len(seeds) < 3
                else ":"
            ),
            "",
        ]
        rows = []
        for part, v in lever["parts"].items():
            a, b = v["lever"], v["baseline"]
            ci = "" if math.isnan(v["ci"][0]) else " " + interval(*v["ci"])
            p = DASH if math.isnan(v["p"]) else f"{num(v['p'], 3)} ({num(v['p_holm'], 3)})"
            rows.append([part, a["levels"], _xp_sp(a), _xp_sp(b), f"{num(v['diff'], signed=True)}{ci}", p])
        lines += [*table_lines(HEAD, rows), ""]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--lever", action="append", required=True, metavar="NAME=JSON", help="a time-to-skill output (or CSV)"
    )
    ap.add_argument("--steps", type=int, default=BASELINE_STEPS, help="env steps per seed to compare at")
    ap.add_argument("--baseline-table", type=Path, default=BASELINE_TABLE)
    ap.add_argument("--baseline-algorithm", default="cec")
    ap.add_argument(
        "--baseline-curve", type=Path, default=BASELINE_CURVE, help="the recipe's time-to-skill output"
    )
    ap.add_argument(
        "--control", type=Path, help="the recipe's own time-to-skill output, trained beside the levers"
    )
    ap.add_argument(
        "--control-steps", type=int, help="the control's row at these env steps per seed (default: --steps)"
    )
    ap.add_argument("--out", type=Path, required=True, help="writes OUT.json and OUT.md")
    args = ap.parse_args(argv)
    if args.control_steps is not None and args.control is None:
        ap.error("--control-steps picks a row of --control: give --control too")
    levers = {}
    for spec in args.lever:
        name, sep, path = spec.partition("=")
        if not sep or not Path(path).is_file():
            ap.error(f"--lever {spec!r}: write NAME=PATH of a time_to_skill output")
        levers[name] = Path(path)
    base = baseline(args.baseline_table, args.baseline_algorithm)
    result = compare(levers, base, args.steps, args.baseline_curve, args.control, args.control_steps)
    from apps.machine import machine_info

    args.out.parent.mkdir(parents=True, exist_ok=True)
    doc = {"benchmark": "levers", "date": datetime.date.today().isoformat(), "machine": machine_info(),
           "baseline_table": str(args.control or args.baseline_table), "levers": result}  # fmt: skip
    args.out.with_suffix(".json").write_text(json.dumps(doc, indent=1, default=float) + "\n")
    text = markdown(result)
    args.out.with_suffix(".md").write_text(text + "\n")
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
