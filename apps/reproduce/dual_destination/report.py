"""The report of `cec reproduce dual-destination`: our numbers beside the paper's, its orderings tested.

`write_report` writes `report.md`, `summary.json` and one `bar_plot` per variant (`plot_curves`: the
learning curves) from the scores
`summary` computed, beside the paper's numbers (`paper`), with the reasons it gives where a number
differs from the paper's or one of the paper's orderings fails (`reasons`).

Size: one report's sections in the order they appear, each with the sentences that say how to read it.
"""

from __future__ import annotations

import json
import math
from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING, Any

from apps.machine import duration
from apps.reproduce.dual_destination.modes import algorithm_of
from apps.reproduce.dual_destination.paper import (
    ABLATIONS,
    ALGORITHMS,
    LEVEL_SET_TITLES,
    LEVEL_SETS,
    ORACLE,
    ORACLE_FIXED,
    PAPER,
    ROWS,
    VARIANT_TITLES,
    VARIANTS,
    PaperNumber,
    paper_number,
)
from apps.reproduce.dual_destination.reasons import (
    TOLERANCE,
    cec_gap_reason,
    difference_reason,
    ordering_reason,
)
from apps.reproduce.dual_destination.summary import (
    ALPHA,
    LEARNED,
    ClaimResult,
    Score,
    check_ablations,
    check_claims,
)
from cec.evaluation.markdown import NONE, Templates, interval, p_value, pm, table
from cec.evaluation.plotting import pyplot

if TYPE_CHECKING:
    from apps.reproduce.dual_destination.modes import Mode


# ---------------------------------------------------------------------------------------------------------
# REPORT
# ---------------------------------------------------------------------------------------------------------


def _score(s: Score | None) -> str:
    """A score: its mean ± its standard error (3 decimals), or `NONE` where there is none."""
    return NONE if s is None else pm(s.mean, s.sem, 3)


def _paper_cell(p: PaperNumber | None) -> str:
    if p is None:
        return "not reported"
    if p.mean is None:
        return f"({p.text})"
    return pm(p.mean, p.sem, 3)


def _verdict(ours: Score | None, p: PaperNumber | None) -> str:
    if ours is None or p is None or p.mean is None:
        return ""
    d = ours.mean - p.mean
    return f"{d:+.3f}" + ("" if abs(d) <= TOLERANCE else f" (differs by {abs(d):.3f} > {TOLERANCE})")


def _fits(raw: Score | None, clipped: Score | None, p: PaperNumber | None) -> str:
    if raw is None or clipped is None or p is None or p.mean is None:
        return ""
    if abs(raw.mean - clipped.mean) < 0.01:
        return "either"
    return "raw" if abs(raw.mean - p.mean) < abs(clipped.mean - p.mean) else "clipped"


TEMPLATES = Templates(Path(__file__).parent / "templates")
Summaries = dict[str, dict[str, dict[str, dict[str, Score]]]]  # variant -> task set -> kind -> algorithm
ORDERINGS_HEAD = (
    "variant", "task set", "ordering", "difference [95% CI]", "p", "holds", "significant",
    "learned seeds only: difference, p, holds",
)  # fmt: skip
NUMBERS_HEAD = (
    "variant", "task set", "algorithm", "ours: XP mean ± SE", "XP clipped", "greedy XP", "greedy SP", "seeds",
    "paper", "ours − paper", "fits", "XP, learned seeds",
)  # fmt: skip


def _number_rows(summaries: dict[str, dict[str, dict[str, dict[str, Score]]]]) -> list[list[str]]:
    """The rows of `NUMBERS_HEAD`: each variant, task set and algorithm with an XP score."""
    rows = []
    for variant in [v for v in VARIANTS if v in summaries]:
        for level_set in LEVEL_SETS:
            kinds = summaries.get(variant, {}).get(level_set, {})
            for algo in ROWS:
                s = kinds.get("xp", {}).get(algo)
                if s is None:
                    continue
                clipped = kinds.get("xp_clipped", {}).get(algo)
                p = paper_number(variant, level_set, algo)
                greedy = [_score(kinds.get(k, {}).get(algo)) for k in ("greedy_xp", "greedy_sp")]
                learned = kinds.get("xp_learned", {}).get(algo)
                rows.append([
                    VARIANT_TITLES[variant], LEVEL_SET_TITLES[level_set], algo.upper(), _score(s),
                    _score(clipped), *greedy, str(s.n), _paper_cell(p), _verdict(s, p), _fits(s, clipped, p),
                    _score(learned) + ("" if learned is None else f" ({learned.n})"),
                ])  # fmt: skip
    return rows


def bar_plot(summary: dict[str, dict[str, dict[str, Score]]], variant: str, path: Path) -> Path:
    """The paper's bar figure for one variant: XP per algorithm on both task sets, standard error bars,
    the paper's values as black markers, the oracle's ceiling on the fixed task dashed."""
    plt = pyplot()
    fig, ax = plt.subplots(figsize=(6.4, 4.2))
    width = 0.26
    for k, algo in enumerate(ALGORITHMS):
        xs, means, errs = [], [], []
        for i, level_set in enumerate(LEVEL_SETS):
            s = summary.get(level_set, {}).get("xp", {}).get(algo)
            if s is None:
                continue
            xs.append(i + (k - 1) * width)
            means.append(s.mean)
            errs.append(0.0 if math.isnan(s.sem) else s.sem)
            p = paper_number(variant, level_set, algo)
            if p is not None and p.mean is not None:
                ax.plot([i + (k - 1) * width], [p.mean], "k_", markersize=18, mew=2)
        ax.bar(xs, means, width, yerr=errs, capsize=3, label=algo.upper())
    ax.axhline(ORACLE_FIXED, xmin=0.02, xmax=0.48, ls="--", color="grey", lw=1)
    ax.plot([], [], "k_", markersize=12, mew=2, label="paper")
    ax.set_xticks(range(len(LEVEL_SETS)), [LEVEL_SET_TITLES[s] for s in LEVEL_SETS])
    ax.set_ylabel("normalised cross-play (unseen seeds)")
    ax.set_title(f"Dual Destination, {VARIANT_TITLES[variant].lower()}")
    ax.set_ylim(min(-0.1, ax.get_ylim()[0]), 1.05)
    ax.axhline(0, color="k", lw=0.5)
    ax.plot([], [], ls="--", color="grey", lw=1, label="oracle")
    ax.legend(fontsize=8, ncols=5, loc="upper center", bbox_to_anchor=(0.5, -0.1), frameon=False)
    fig.tight_layout()
    fig.savefig(path, dpi=110)
    plt.close(fig)
    return path


def _recorded_times(meta: dict[str, Any]) -> str:
    """The recorded time of everything behind the report, reused work included: training per variant (the
    runs' own metrics) and the cross-play of each variant when it was played."""

    def per_variant(seconds: Mapping[str, float | None]) -> str:
        return ", ".join(
            f"{VARIANT_TITLES[v].split(' (')[0].lower()} "
            + ("not recorded (played before play times were kept)" if t is None else duration(t))
            for v, t in seconds.items()
        )

    train = {v: sum(float(t["seconds"]) for t in a.values()) for v, a in meta["training"].items()}
    played = meta.get("played_s", {})
    text = (
        "Recorded times of the work behind these numbers, whichever invocation did it: training "
        f"{per_variant(train)} of one core (per algorithm in the Training section)"
    )
    return text + (f"; cross-play {per_variant(played)}.\n" if played else ".\n")


TRAINING_HEAD = (
    "variant", "algorithm", "seeds", "env steps per seed", "training time", "return at the end",
    "entropy at the end", "first positive return (seed: env steps)",
)  # fmt: skip


def _training_rows(training: dict[str, dict[str, Any]]) -> list[list[str]]:
    """The rows of `TRAINING_HEAD`: each variant's trained algorithms."""
    return [
        [
            VARIANT_TITLES[variant],
            algo.upper(),
            t["seeds"],
            f"{t['env_steps']:,}",
            f"{t['seconds'] / 60:.1f} min",
            f"{t['final_return']:.3f}",
            f"{t.get('final_entropy', math.nan):.2f}",
            _take_off(t.get("positive_at", {})),
        ]  # fmt: skip
        for variant, per in training.items()
        for algo in ROWS
        if (t := per.get(algo)) is not None
    ]


def _take_off(positive_at: Mapping[str, int | None]) -> str:
    """`200: 1.2e6, 201: never`: where each seed's training return first turned positive."""
    return (
        ", ".join(f"{s}: {'never' if at is None else f'{at:.1e}'}" for s, at in positive_at.items()) or NONE
    )


def write_report(out: Path, mode: Mode, summaries: Summaries, meta: dict[str, Any]) -> Path:
    """Writes `report.md`, `summary.json` and one bar plot per variant into `out`; returns the report."""
    out.mkdir(parents=True, exist_ok=True)
    claims = check_claims(summaries)
    training = meta.get("training", {})
    md = [
        *_header(mode, meta), *_numbers(summaries), *_orderings(summaries, claims, meta),
        *_cec_full(summaries, training), *ablation_section(summaries, training),
        *_differences(mode, summaries, meta), *_training(meta), *_conventions(summaries, meta),
        *_reference(summaries), *_bars(summaries, out), "## Timings\n",
        table(["stage", "seconds"], [[k, f"{v:.0f}"] for k, v in meta.get("stages", {}).items()], end="\n"),
    ]  # fmt: skip
    path = out / "report.md"
    path.write_text("\n".join(md) + "\n")
    (out / "summary.json").write_text(
        json.dumps(
            {
                "meta": meta,
                "mode": {
                    "name": mode.name,
                    "seeds": mode.seeds,
                    "steps": mode.steps,
                    "episodes": mode.episodes,
                },
                "summaries": {
                    v: {
                        ls: {k: {a: s.__dict__ for a, s in d.items()} for k, d in kinds.items()}
                        for ls, kinds in per.items()
                    }
                    for v, per in summaries.items()
                },  # fmt: skip
                "claims": [c.__dict__ for c in claims],
                "ablations": [c.__dict__ for c in check_ablations(summaries)],
                "paper": [p.__dict__ for p in PAPER],
            },
            indent=1,
            default=float,
        )
        + "\n"
    )
    return path


def _header(mode: Mode, meta: dict[str, Any]) -> list[str]:
    """The title, the command and machine, the recorded times, how to read a score and the budget."""
    md = [f"# Dual Destination: the paper's results reproduced ({mode.name} version)\n"]
    m = meta["machine"]
    md.append(
        f"Command: `{meta['command']}`. Machine: {m['cpu']} ({m['cpu_count']} cores, {m['device']}), host "
        f"`{m['host']}`, load average at the start {m.get('load_average_start')} and at the end "
        f"{m.get('load_average_1_5_15min')} (1/5/15 min). Date {meta['date']}, git {meta['git']}, "
        f"JAX {m['jax']}. Wall time {meta['wall_s'] / 60:.1f} min "
        f"(training {meta['train_s'] / 60:.1f}, evaluation {meta['eval_s'] / 60:.1f}).\n"
    )
    md.append(_recorded_times(meta))
    if meta.get("skipped_runs"):
        md.append(
            f"Training runs found finished by an earlier invocation and not trained again: "
            f"{', '.join(meta['skipped_runs'])} (their training time is in the Training section).\n"
        )
    md.append(TEMPLATES.fill("score"))
    budget = ", ".join(
        f"{a.upper()} {len(mode.seeds[a])} seeds x {mode.steps['full_obs'][a]:,} steps "
        f"({mode.presets[algorithm_of(a)]}"
        + (f" with {', '.join(ABLATIONS[a].overrides)})" if a in ABLATIONS else ")")
        for a in mode.rows
    )
    md.append(
        f"Budget per variant: {budget}; partial-obs and multi-task steps: "
        + "; ".join(
            f"{v}: " + ", ".join(f"{a} {mode.steps[v][a]:,}" for a in mode.rows) for v in VARIANTS[1:]
        )
        + f". Episodes per pair, seat order and level: {mode.episodes['fixed']} on the fixed task, "
        f"{mode.episodes['generated']} on each of {min(mode.generated_levels, 100)} held-out generated "
        "tasks. FCP's population: every IPPO seed at its first, middle and last milestone.\n"
    )
    return md


def _numbers(summaries: Summaries) -> list[str]:
    """Our numbers beside the paper's, a row per variant, task set and algorithm."""
    md = ["## Our numbers beside the paper's\n"]
    missing = [VARIANT_TITLES[v] for v in VARIANTS if v not in summaries]
    if missing:
        md.append(f"Not run for this report: {', '.join(missing)} (`--variants`).\n")
    md.append(TEMPLATES.fill("numbers", learned=LEARNED, table=table(NUMBERS_HEAD, _number_rows(summaries))))
    return md


def _orderings(summaries: Summaries, claims: list[ClaimResult], meta: dict[str, Any]) -> list[str]:
    """The paper's orderings tested over seeds, and why each that does not hold fails."""
    by_learned = {
        (c.variant, c.level_set, c.better, c.worse): c for c in check_claims(summaries, "xp_learned")
    }
    rows = []
    for c in claims:
        lc = by_learned.get((c.variant, c.level_set, c.better, c.worse))
        among = (
            NONE if lc is None else f"{lc.diff:+.3f}, p {p_value(lc.p)}, {'yes' if lc.holds else '**no**'}"
        )
        rows.append([
            VARIANT_TITLES[c.variant], LEVEL_SET_TITLES[c.level_set],
            f"{c.better.upper()} > {c.worse.upper()}", f"{c.diff:+.3f} {interval(c.ci_low, c.ci_high, 3)}",
            p_value(c.p), "yes" if c.holds else "**no**", "yes" if c.significant else "no", among,
        ])  # fmt: skip
    md = [TEMPLATES.fill("orderings", alpha=ALPHA, learned=LEARNED, table=table(ORDERINGS_HEAD, rows))]
    held = sum(c.holds for c in claims)
    sig = sum(c.significant for c in claims)
    md.append(f"{held} of {len(claims)} orderings hold, {sig} of them significantly.\n")
    conventions = meta.get("conventions", {})
    training = meta.get("training", {})
    failed = [
        ordering_reason(
            c,
            summaries[c.variant][c.level_set],
            conventions.get(c.variant),
            {a: t.get("final_entropy", math.nan) for a, t in training.get(c.variant, {}).items()},
        )
        for c in claims
        if not c.holds
    ]
    if failed:
        md.append("Where an ordering does not hold, what the same seeds' self-play (SP) shows:\n")
        md.extend(failed)
        md.append("")
    return md


def _cec_full(summaries: Summaries, training: dict[str, Any]) -> list[str]:
    """CEC, fully observable, against the paper's values (none without them)."""
    cec_full = [
        (
            ls,
            summaries.get("full_obs", {}).get(ls, {}).get("xp", {}).get("cec"),
            paper_number("full_obs", ls, "cec"),
        )
        for ls in LEVEL_SETS
    ]
    lines = []
    for ls, s, p in cec_full:
        if s is not None and p is not None and p.mean is not None:
            ok = abs(s.mean - p.mean) <= TOLERANCE
            sp = summaries["full_obs"][ls].get("sp", {}).get("cec")
            why = cec_gap_reason(s, p.mean, sp, training.get("full_obs", {}).get("cec", {}))
            lines.append(
                f"- CEC, fully observable, {LEVEL_SET_TITLES[ls]}: {s.mean:.3f} vs the paper's {p.mean:.3f}: "
                + ("within" if ok else f"**not within** (by {abs(s.mean - p.mean):.3f})")
                + f" {TOLERANCE}."
                + ("" if ok else f" Why: {why}")
            )
    return ["## CEC, fully observable, against the paper's values\n", *lines, ""] if lines else []


def _differences(mode: Mode, summaries: Summaries, meta: dict[str, Any]) -> list[str]:
    """Each XP that differs from the paper's by more than the tolerance, with its reason."""
    md = ["## Where our numbers differ from the paper's by more than 0.05\n"]
    diffs = []
    for variant in VARIANTS:
        for level_set in LEVEL_SETS:
            for algo in ALGORITHMS:
                s = summaries.get(variant, {}).get(level_set, {}).get("xp", {}).get(algo)
                p = paper_number(variant, level_set, algo)
                if (
                    s is not None
                    and p is not None
                    and p.mean is not None
                    and abs(s.mean - p.mean) > TOLERANCE
                ):
                    kinds = summaries[variant][level_set]
                    diffs.append(
                        f"- {VARIANT_TITLES[variant]}, {LEVEL_SET_TITLES[level_set]}, {algo.upper()}: "
                        f"{s.mean:.3f} vs {p.mean:.3f} ({s.mean - p.mean:+.3f}). "
                        + difference_reason(
                            s,
                            p.mean,
                            kinds.get("sp", {}).get(algo),
                            kinds.get("oracle", {}).get(algo),
                            trained_on_set=algo == "cec" or level_set == "fixed",
                        )
                    )
    md.extend(diffs or ["None."])
    md.append("")
    why = meta.get("why", mode.why)
    if diffs and why:
        md.append(why)
        md.append("")
    return md


def _training(meta: dict[str, Any]) -> list[str]:
    """Each run's training from its metrics, and the learning curves (none without training records)."""
    if not meta.get("training"):
        return []
    md = [TEMPLATES.fill("training", table=table(TRAINING_HEAD, _training_rows(meta["training"])))]
    md += [f"![{VARIANT_TITLES[v]}: learning curves]({name})\n" for v, name in meta.get("curves", {}).items()]
    return md


def _conventions(summaries: Summaries, meta: dict[str, Any]) -> list[str]:
    """The goal each seed's greedy self-play settles on (none without recorded conventions)."""
    if not meta.get("conventions"):
        return []
    rows = []
    for variant, per in meta["conventions"].items():
        for algo in ROWS:
            seeds = per.get(algo, {})
            sp = summaries.get(variant, {}).get("fixed", {}).get("sp", {}).get(algo)
            own = {} if sp is None else dict(zip(sp.seeds, sp.samples, strict=False))
            if seeds:
                listed = ", ".join(
                    f"{seed}: {goal}" + (f" ({own[int(seed)]:.2f})" if int(seed) in own else "")
                    for seed, goal in sorted(seeds.items())
                )
                distinct = len({g for g in seeds.values() if g != "no goal"})
                rows.append([VARIANT_TITLES[variant], algo.upper(), listed, str(distinct)])
    head = ["variant", "algorithm", "seed: seat 0's goal (SP)", "distinct conventions"]
    return [TEMPLATES.fill("conventions", table=table(head, rows))]


def _reference(summaries: Summaries) -> list[str]:
    """Self-play and the score with the oracle partner: what a seed can do with itself and with the best."""
    rows = []
    for variant in VARIANTS:
        for level_set in LEVEL_SETS:
            kinds = summaries.get(variant, {}).get(level_set, {})
            for algo in (*ROWS, ORACLE):
                sp, wo = kinds.get("sp", {}).get(algo), kinds.get("oracle", {}).get(algo)
                if sp is None and wo is None:
                    continue
                partner = NONE if algo == ORACLE else _score(wo)
                rows.append([VARIANT_TITLES[variant], LEVEL_SET_TITLES[level_set], algo, _score(sp), partner])
    head = ["variant", "task set", "algorithm", "SP", "with oracle partner"]
    return [TEMPLATES.fill("reference", table=table(head, rows))]


def _bars(summaries: Summaries, out: Path) -> list[str]:
    """One bar plot per variant, written into `out`."""
    md = ["## Bar plots\n"]
    for variant in VARIANTS:
        if variant in summaries:
            name = f"bars_{variant}.png"
            bar_plot(summaries[variant], variant, out / name)
            md.append(f"![{VARIANT_TITLES[variant]}]({name})\n")
    return md


def _positive(t: dict[str, Any]) -> str:
    """Whether a training reached a positive reward: the seeds' mean, else which seeds did on their own."""
    if t["best_return"] > 0:
        return "yes"
    seeds = {s: b for s, b in t.get("best_by_seed", {}).items() if b > 0}
    if not seeds:
        return "no"
    listed = ", ".join(f"{s}: best {b:.2f}" for s, b in seeds.items())
    return f"not the mean over seeds; {len(seeds)} of {t['seeds']} seeds did ({listed})"


def ablation_section(
    summaries: dict[str, dict[str, dict[str, dict[str, Score]]]], training: dict[str, dict[str, Any]]
) -> list[str]:
    """The report's lines on each ablation present: the paper's claim, the ablation's training return
    (best and at the end: did it reach a positive reward?) beside its algorithm's, and its XP against the
    algorithm's with the seed-level test; none when no ablation was trained."""
    tests = check_ablations(summaries)
    md: list[str] = []
    for label, ablation in ABLATIONS.items():
        trained = [
            (v, per[label], per.get(ablation.algorithm)) for v, per in training.items() if label in per
        ]
        mine = [c for c in tests if c.worse == label]
        if not trained and not mine:
            continue
        a, b = ablation.algorithm.upper(), ablation.title
        md.append(f"## Ablation: {b}\n")
        shorter = [
            VARIANT_TITLES[v].lower() for v, t, base in trained if base and t["env_steps"] < base["env_steps"]
        ]
        md.append(
            f"The paper: “{ablation.claim}.” Here: {b} (`{label}`) trained with {a}'s preset and "
            f"`{' '.join(ablation.overrides)}`, nothing else changed"
            + (
                f" but, {' and '.join(shorter)}, a smaller budget than {a}'s (the env steps below): its XP "
                f"test against {a} there favours {a}'s longer training.\n"
                if shorter
                else ".\n"
            )
        )
        if trained:
            head = [
                "variant", f"env steps per seed: {b} / {a}", f"training return: {b}, best / at the end",
                f"{a}, best / at the end", "positive reward reached",
            ]  # fmt: skip
            rows = []
            for variant, t, base in trained:
                other = NONE if base is None else f"{base['best_return']:.3f} / {base['final_return']:.3f}"
                steps = f"{t['env_steps']:,} / " + (NONE if base is None else f"{base['env_steps']:,}")
                mine_t = f"{t['best_return']:.3f} / {t['final_return']:.3f}"
                rows.append([VARIANT_TITLES[variant], steps, mine_t, other, _positive(t)])
            md.append(table(head, rows, end="\n"))
        if mine:
            md.append(f"XP of {a} and of {b} (the jackknife over seeds, as for the orderings):\n")
            head = ["variant", "task set", f"{a} XP", f"{b} XP", "difference [95% CI]", "p", f"{a} better"]
            rows = []
            for c in mine:
                xp = summaries[c.variant][c.level_set]["xp"]
                verdict = ("yes" if c.holds else "**no**") + (" (significant)" if c.significant else "")
                diff = f"{c.diff:+.3f} [{c.ci_low:+.3f}, {c.ci_high:+.3f}]"
                rows.append([
                    VARIANT_TITLES[c.variant], LEVEL_SET_TITLES[c.level_set], _score(xp[c.better]),
                    _score(xp[c.worse]), diff, p_value(c.p), verdict,
                ])  # fmt: skip
            md.append(table(head, rows, end="\n"))
    return md


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
