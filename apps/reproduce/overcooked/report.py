"""The report of `cec reproduce overcooked`: `report.md` (the seed-level tables beside the paper's values,
the tests, the sections of `sections`, training, figures) and `summary.json`.
"""

from __future__ import annotations

import dataclasses
import json
import math
import time
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

from apps.machine import duration, machine_info
from apps.reproduce import pipeline
from apps.reproduce.overcooked.modes import (
    ALGORITHMS,
    AUTHORS_STEPS,
    COOK,
    EVAL_STEPS,
    GENERALISTS,
    NOOP,
    TITLES,
    UNTRAINED,
    Mode,
)
from apps.reproduce.overcooked.paper import HUMAN_STUDY, paper_values
from apps.reproduce.overcooked.sections import TEMPLATES  # the folder's templates, one instance
from apps.reproduce.overcooked.summary import ALPHA, MEASURES, SeedScores, comparisons, finite
from cec.agents.zoo import HUMAN_PROXY, SkippedEntry
from cec.evaluation.markdown import NONE, interval, num, p_value, pm, table_lines

if TYPE_CHECKING:
    from cec.evaluation.seeds import SeedMatrix

TABLE_HEAD = (
    "algorithm",
    "self-play",
    "cross-play (unseen partners)",
    "XP / SP",
    "with the cook",
    "with human proxies",
    "paper (XP)",
)

TEST_HEAD = (
    "level set",
    "score",
    "CEC −",
    "difference",
    "95% CI",
    "p",
    "Holm p",
    "exact p (smallest possible)",
    "Holm exact p",
    "reading (p < 0.05)",
)
TRAINING_HEAD = ("run", "seeds", "env steps per seed", "updates", "recorded time")


def write_report(
    mode: Mode, summary: dict[str, dict[str, SeedScores]], out: Path, *, figures: dict[str, str],
    plan: list[pipeline.PlanLine], command: str, ran_on: dict[str, Any], commit: str,
    skipped: Sequence[SkippedEntry] = (), train_s: dict[str, float] | None = None, played_s: float = math.nan,
    sections: Sequence[str] = (), missing: Sequence[str] = (), matrices: dict[str, SeedMatrix] | None = None,
    short: dict[str, dict[str, SeedScores]] | None = None,
) -> Path:  # fmt: skip
    """`out/report.md` and `out/summary.json`; `ran_on`: the machine and commit that trained and played;
    `commit`: the checkout's as the command started; `skipped`: the cross-play table's skipped entries
    (proxies that could not play with the agents); `train_s`: the recorded seconds of each training run (by
    run name) and `played_s` of the cross-play (NaN: not recorded), whichever invocation did them;
    `sections`: the lines after the tests (`analysis_lines`); `missing`: runs of the mode's plan that the
    work folder does not have (a folder trained before the mode had them); `matrices`: {level set:
    `cec.evaluation.seeds.SeedMatrix`} of the same table, for the exact tests (`comparisons`); `short`: the
    summary of the same line-ups at the authors' 100-step episodes (None: not played)."""

    paper, paper_text = paper_values(), paper_values("text")
    tests = comparisons(summary, matrices)
    out.mkdir(parents=True, exist_ok=True)
    machine, ran = machine_info(), ran_on["machine"]
    lines = [
        f"# CEC on Overcooked: `{command}`",
        "",
        f"Trained and played on: {_machine_text(ran)}; cross-play finished at commit {ran_on['commit']}"
        + _trained_at(ran_on)
        + ".",
        "",
        *_controls_machine_lines(ran_on),
        f"Report written on: {_machine_text(machine)}; commit {commit}; {time.strftime('%Y-%m-%d %H:%M')}.",
        "",
        *_time_lines(train_s or {}, played_s),
        *TEMPLATES.lines("about", eval_steps=EVAL_STEPS),
        *_human_lines(mode, summary, skipped),
    ]
    for level_set, scores in summary.items():
        title = (
            f"{len(mode.kitchens)} classic" if level_set == "classic" else f"{mode.generated_levels} held-out"
        )
        lines += [f"## The {title} kitchens", "", *table_lines(TABLE_HEAD, _score_rows(level_set, scores))]
        absent = {a: v for a, v in paper_text[level_set].items() if a not in scores}
        if absent:
            named = ", ".join(f"{a.upper().replace('_', '-')} {v}" for a, v in absent.items())
            lines += ["", f"Not trained here; the paper's text gives: {named}."]
        lines.append("")
    lines += steps_lines(summary, short)
    if not tests:
        results = ["No test: too few seeds, or no spread between them."]
    else:
        results = table_lines(TEST_HEAD, (_test_row(t) for t in tests))
        floor = _floor_lines(tests)  # a line and a blank one, or none
        results += ["", floor[0]] if floor else []
    lines += TEMPLATES.lines("tests", results="\n".join(results), floor=_floor_sentence(tests, summary))
    lines += sections
    recorded = {run: duration(t) for run, t in (train_s or {}).items() if math.isfinite(t) and t > 0}
    training = [[p.run, p.seeds, f"{p.env_steps:,}", p.updates, recorded.get(p.run, NONE)] for p in plan]
    lines += ["## Training", "", *table_lines(TRAINING_HEAD, training)]
    lines += ["", *budget_lines(mode, plan)]
    if missing:
        lines += ["", f"Not in this work folder (trained before the mode had them; the tables have none of "
                  f"their games): {', '.join(missing)}."]  # fmt: skip
    lines.append("")
    for title, rel in figures.items():
        lines += [f"![{title}]({rel})", ""]
    report = out / "report.md"
    report.write_text("\n".join(lines))
    data = {
        "mode": mode.name, "command": command, "ran_on": ran_on, "machine": machine, "commit": commit,
        "eval_steps": EVAL_STEPS, "paper": paper, "tests": tests,
        "summary": {ls: {a: dataclasses.asdict(s) for a, s in sc.items()} for ls, sc in summary.items()},
    }  # fmt: skip
    if short is not None:
        data[f"summary_steps{AUTHORS_STEPS}"] = {
            ls: {a: dataclasses.asdict(s) for a, s in sc.items()} for ls, sc in short.items()
        }
    (out / "summary.json").write_text(json.dumps(data, indent=1, default=float) + "\n")
    return report


STEPS_HEAD = (
    "level set",
    "algorithm",
    f"cross-play, {EVAL_STEPS} steps",
    f"cross-play, {AUTHORS_STEPS} steps",
    f"self-play, {EVAL_STEPS}",
    f"self-play, {AUTHORS_STEPS}",
    f"XP {AUTHORS_STEPS} over {EVAL_STEPS}",
)


def steps_lines(
    summary: dict[str, dict[str, SeedScores]], short: dict[str, dict[str, SeedScores]] | None
) -> list[str]:
    """The section of the authors' evaluation length: each algorithm's cross-play and self-play at
    `EVAL_STEPS` beside the same line-ups at `AUTHORS_STEPS` (`short`); where they were not played, why."""
    head = [f"## At the authors' {AUTHORS_STEPS}-step episodes", ""]
    if short is None:
        return [*head, f"Not played: this work folder has no table of {AUTHORS_STEPS}-step episodes (it was "
                f"played before the reproduction played one, and its checkpoints are not kept, so the "
                f"agents cannot be played again). A run of `cec reproduce overcooked` that trains plays it "
                f"after the {EVAL_STEPS}-step table (`work/steps{AUTHORS_STEPS}`).", ""]  # fmt: skip
    rows = []
    for level_set, scores in summary.items():
        for algo in ALGORITHMS:
            if algo not in scores or algo not in short.get(level_set, {}):
                continue
            long_, cut = scores[algo].crossplay(), short[level_set][algo].crossplay()
            ratio = num(cut.mean / long_.mean, 2) if long_.mean > 0 else NONE
            rows.append([level_set, TITLES[algo], pm(long_.mean, long_.se), pm(cut.mean, cut.se),
                         _cell(scores[algo].sp), _cell(short[level_set][algo].sp), ratio])  # fmt: skip
    about = (f"The same line-ups, seeds and draws as the tables above, the episodes cut at {AUTHORS_STEPS} "
             f"steps (the authors' code evaluates so; {EVAL_STEPS} is the paper's figures' length and ours): "
             "cross-play ± its jackknife standard error over seeds, self-play ± the standard error over "
             "seeds. A quarter of the steps holds less than a quarter of the return: the first soup of an "
             "episode takes the walk to the onions and the pot's cooking before any delivery.")  # fmt: skip
    return [*head, about, "", *table_lines(STEPS_HEAD, rows), ""]


def _score_rows(level_set: str, scores: dict[str, SeedScores]) -> list[list[str]]:
    """The rows of a level set's table (`TABLE_HEAD`): each algorithm and control the summary has."""
    paper, paper_text = paper_values(), paper_values("text")
    rows = []
    for algo in [*ALGORITHMS, UNTRAINED, NOOP, COOK]:
        if algo not in scores:
            continue
        s = scores[algo]
        sp, xp = finite(s.sp), finite(s.xp)
        ratio = num(xp.mean() / sp.mean(), 2) if xp.size and sp.size and sp.mean() > 0 else NONE
        cook = _cell(s.cook) if algo != COOK else NONE
        paper_cell = _paper_cell(level_set, algo, paper, paper_text)
        rows.append(
            [TITLES.get(algo, algo), _cell(s.sp), _xp_cell(s), ratio, cook, _cell(s.human), paper_cell]
        )
    return rows


def _test_row(t: dict[str, Any]) -> list[str]:
    """One comparison of `comparisons` as a row of `TEST_HEAD`."""
    exact = NONE if math.isnan(t["p_exact"]) else f"{p_value(t['p_exact'], 3)} ({p_value(t['p_min'], 3)})"
    return [
        t["level_set"], MEASURES[t["measure"]], TITLES[t["worse"]], num(t["diff"], signed=True),
        interval(t["ci_low"], t["ci_high"]), p_value(t["p"], 3), p_value(t["p_holm"], 3), exact,
        p_value(t["p_exact_holm"], 3), _reading(t),
    ]  # fmt: skip


def _cell(values: Sequence[float]) -> str:
    from cec.evaluation.stats import sem

    arr = finite(values)
    if not arr.size:
        return NONE
    return pm(float(arr.mean()), sem(arr), n=arr.size)


def _xp_cell(scores: SeedScores) -> str:
    """Cross-play: the mean over every pair of two different seeds ± its jackknife standard error."""
    est = scores.crossplay()
    return pm(est.mean, est.se, n=est.seeds)


def _paper_cell(level_set: str, algo: str, figures: dict[str, dict[str, float]], text: dict) -> str:
    exact = text.get(level_set, {}).get(algo)
    if exact is not None:
        return f"{exact} (text)"
    ref = figures.get(level_set, {}).get(algo)
    return NONE if ref is None else f"≈{ref} (figure)"


def _reading(test: dict[str, Any]) -> str:
    """What a comparison of `comparisons` shows at the 5% level: CEC ahead, CEC behind, or neither. The
    t-test finds it; where an exact test stands beside it (`p_exact`), the reading holds only if the exact
    test's Holm-adjusted p does too, and otherwise says which test shows it and which does not (with 4 seeds
    a side and 5 tests in the family the exact test cannot go below 0.143 after Holm, whatever the data; with
    6, 0.011).
    Without an exact p, a difference the t-test's Holm-adjusted p does not keep below 5% says so."""
    if not test["significant"]:
        return "no difference shown"
    reading = "CEC ahead" if test["diff"] > 0 else "CEC behind"
    held = test.get("p_holm", test["p"]) < ALPHA
    exact, exact_holm = test.get("p_exact", math.nan), test.get("p_exact_holm", math.nan)
    if math.isnan(exact):
        return reading if held else f"{reading}; not after Holm"
    if exact_holm < ALPHA:
        return f"{reading} (the exact test too, after Holm)"
    t_part = f"t-test: {reading}" + ("" if held else ", not after Holm")
    exact_part = "exact test: below 5%, not after Holm" if exact < ALPHA else "exact test: not shown"
    return f"{t_part}; {exact_part}"


def _floor_sentence(tests: Sequence[dict[str, Any]], summary: dict[str, dict[str, SeedScores]]) -> str:
    """What the exact tests cannot go below at these seed counts, whatever the data (empty without one): the
    smallest `p_min` of the tests, and that times the largest family's size after Holm."""
    exact = [t for t in tests if not math.isnan(t["p_exact"])]
    if not exact:
        return ""
    sizes = sorted({len(summary[t["level_set"]][a].seeds) for t in exact for a in (t["better"], t["worse"])})
    seeds = f"{sizes[0]} seeds each" if len(sizes) == 1 else f"{sizes[0]}-{sizes[-1]} seeds a side"
    floor, k = min(t["p_min"] for t in exact), max(t["family"] for t in exact)
    return (
        f"With {seeds} neither can go below {floor:.3g} whatever the difference, and with {k} tests in a "
        f"family no Holm-adjusted exact p below {min(1.0, k * floor):.3g}. "
    )


def _floor_lines(tests: Sequence[dict[str, Any]]) -> list[str]:
    """Per family with exact tests: the smallest Holm-adjusted exact p it could reach (its smallest test's
    p_min times the family's size), and how many of its tests stay below 5% after Holm, t and exact."""
    families: dict[tuple[str, str], list[dict[str, Any]]] = {}
    for t in tests:
        families.setdefault((t["level_set"], t["measure"]), []).append(t)
    parts = []
    for (level_set, measure), family in families.items():
        floors = [t["p_min"] for t in family if not math.isnan(t["p_exact"])]
        if not floors:
            continue
        k = len(family)
        held_t = sum(t["p_holm"] < ALPHA for t in family)
        held_exact = sum(t["p_exact_holm"] < ALPHA for t in family)
        parts.append(
            f"{level_set} {MEASURES[measure]}: {k} tests, the smallest Holm-adjusted exact p attainable "
            f"{min(1.0, k * min(floors)):.3g}; below {ALPHA:g} after Holm: {held_t} of {k} by the t-test, "
            f"{held_exact} by the exact test"
        )
    return [f"Families: {'; '.join(parts)}.", ""] if parts else []


def budget_lines(mode: Mode, plan: Sequence[pipeline.PlanLine]) -> list[str]:
    """Env steps per trained model (one seed; a single-kitchen model: one kitchen) by algorithm, and CEC's
    against those of one single-kitchen model and of all of an algorithm's kitchens together; the paper
    trains every model for the same 3e9 steps (its section on the generator: "all other baselines, for 3
    billion steps"), 1:1."""
    steps: dict[str, int] = {}
    for p in plan:  # `trained_runs`' lines: each with its run's algorithm
        steps.setdefault(p.algorithm, p.env_steps)
    if "cec" not in steps:
        return []
    cec, k = steps["cec"], len(mode.kitchens)
    parts = [f"{TITLES[a]} {steps[a]:,} per model" for a in GENERALISTS if a in steps]
    single = [a for a in ALGORITHMS if a in steps and a not in (*GENERALISTS, "cec_finetune")]
    for n in sorted({steps[a] for a in single}):
        names = ", ".join(TITLES[a] for a in single if steps[a] == n)
        parts.append(
            f"{names} {n:,} per model, one per kitchen (CEC trains {cec / n:.1f}x the steps of one of their "
            f"models, {cec / (n * k):.1f}x those of all {k} together)"
        )
    if "cec_finetune" in steps:
        parts.append(f"CEC-Finetune {steps['cec_finetune']:,} per kitchen on top of its CEC seed's")
    return [
        f"Budget (env steps per seed): {'; '.join(parts)}. The paper trains every model for 3e9 steps (1:1)."
    ]


def _human_lines(
    mode: Mode, summary: dict[str, dict[str, SeedScores]], skipped: Sequence[SkippedEntry]
) -> list[str]:
    """What the human-proxy column holds, the paper's human study beside it, or why it is empty."""
    played = any(finite(s.human).size for scores in summary.values() for s in scores.values())
    if played:
        return TEMPLATES.lines("human", proxy=HUMAN_PROXY, proxies=mode.proxies, study=HUMAN_STUDY)
    reasons = sorted({s.reason for s in skipped if s.algorithm == HUMAN_PROXY})
    why = f"they could not play with the agents: {'; '.join(reasons)}" if reasons else "none in the table"
    return [f"With human proxies: not played ({why}).", ""]


def _time_lines(train_s: dict[str, float], played_s: float) -> list[str]:
    """The recorded time of the work behind the report, reused work included (empty when none is known)."""
    recorded = [t for t in train_s.values() if math.isfinite(t) and t > 0]
    if not recorded:  # a work folder from before training times were kept
        return []
    train = sum(recorded)
    unknown = "not recorded (played before play times were kept)"
    play = duration(played_s) if math.isfinite(played_s) else unknown
    return [
        f"Recorded times of the work behind these numbers, whichever invocation did it: training "
        f"{duration(train)} on the machine that trained (per run in the Training section; runs that share "
        f"it run side by side, so this is not its wall time); cross-play {play}.",
        "",
    ]


def _controls_machine_lines(ran_on: dict[str, Any]) -> list[str]:
    """Where the controls were played, when not where the zoo was (`--report-only` plays them)."""
    controls = ran_on.get("controls")
    if not controls or controls["machine"]["host"] == ran_on["machine"]["host"]:
        return []
    return [f"Controls played on: {_machine_text(controls['machine'])}; commit {controls['commit']}.", ""]


def _trained_at(ran_on: dict[str, Any]) -> str:
    """The commits that wrote the agents' checkpoints, where the folder's `machine.json` records them."""
    commits = ran_on.get("trained_at")
    if not commits:
        return ""
    many = "s" if len(commits) > 1 else ""
    return f"; the agents' last checkpoints written at {len(commits)} commit{many} ({', '.join(commits)})"


def _machine_text(m: Mapping[str, object]) -> str:
    return f"{m['device']} (JAX {m['jax']}), {m['cpu']} ({m['cpu_count']} cores), host {m['host']}"
