"""Cross-play of the shipped seeds over their GPU training: the 64M-step seeds (../cec64m/), then every
milestone of the four `benchmarks/gpu_session.sh window` calls that trained them on (1024 envs x 128 steps
per update and seed, so an update is 131,072 env steps per seed; each call's LR schedule starts anew).
Each point: `cec eval` of the four seeds at that checkpoint (held-out: 100 kitchens, 1 episode; classic: 5
kitchens, 4 episodes; 400 steps, both seat orders, the evaluation seed of every shipped evaluation),
cross-play with its jackknife SE over seeds.

    .venv/bin/python benchmarks/results/overcooked/shipped/window/curve.py     # writes curve.json, curve.png

The evaluations of the milestones are in curve/ (gzipped `cec eval` tables; the milestone policies
themselves, 1.3 MB each, were not kept in the repository).

Each point also carries its parts (`cec.evaluation.parts`: the held-out kitchens by kind, each classic
kitchen), and `budget.json` what a straight line in log env steps through the parts says: the gain per
doubling of the env steps, its jackknife SE over the four seeds (each seed left out in turn, every
milestone's cross-play recomputed over the other three), and the env steps at which the line reaches the
every-kitchen issue's targets. A reading of one recipe's curve (the LR restarted at each call), not a law.
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from cec.evaluation.parts import part_scores
from cec.evaluation.results import EpisodeTable, read_csv
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import jackknife_se
from cec.levels.classic import classic_levels
from cec.levels.heldout import heldout_levels

HERE = Path(__file__).parent
START = 64_012_288  # the shipped 64M seeds' env steps per seed
STEPS_PER_UPDATE = 131_072
# Each call's updates: the first ran its schedule to the end, the second was stopped after 1,810 (the 451M
# seeds), the third after 2,340 (the 758M seeds), the fourth after 940 (the 881M seeds). The LR restarted
# at each call's start: 2e-3 in the first three, 1e-3 in the fourth.
CALL_UPDATES = (1145, 1810, 2340, 940)
KEYS = ("heldout", "classic")
CALL_START = {
    w: START + sum(CALL_UPDATES[: w - 1]) * STEPS_PER_UPDATE for w in range(1, len(CALL_UPDATES) + 1)
}


# The parts fitted, and the every-kitchen issue's targets for the shipped seeds (and, for the hand-over
# kitchens, its 10.5M-step target too)
FITTED = {
    ("heldout", "hand-over needed"): (20, 40),
    ("heldout", "generated"): (55,),
    ("classic", "classic"): (30, 70),
    ("classic", "forced_coord"): (10, 30),
    ("classic", "counter_circuit"): (10, 30),
}


def point(table) -> dict[str, float]:  # noqa: ANN001
    m = seed_matrix(table)
    s = m.summary(m.indices("cec"))
    xp = s.crossplay()
    return {"xp": round(xp.mean, 2), "xp_se": round(xp.se, 2), "sp": round(float(np.mean(s.sp)), 2)}


def parts(table: EpisodeTable, key: str) -> dict[str, float]:
    """{part: cross-play} of one evaluation (held-out by kind, or each classic kitchen)."""
    levels = dict(heldout_levels()) if key == "heldout" else classic_levels()
    return {name: round(p.xp, 2) for name, p in part_scores(table, "cec", levels).items()}


def without_seed(table: EpisodeTable, seed: int) -> EpisodeTable:
    return table.select((table.seed_a != seed) & (table.seed_b != seed))


def line(steps: np.ndarray, y: np.ndarray) -> tuple[float, float]:
    """(gain per doubling of the env steps, value at the last point): the least-squares line in log2 steps."""
    slope, intercept = np.polyfit(np.log2(steps), y, 1)
    return float(slope), float(slope * np.log2(steps[-1]) + intercept)


def budget(tables: list[tuple[int, dict[str, EpisodeTable]]]) -> dict[str, dict]:
    """For each fitted part: the line through its cross-play over the milestones, the slope's jackknife SE
    over seeds, and the env steps per seed at which the line reaches each target."""
    steps = np.array([s for s, _ in tables], float)
    seeds = sorted({int(x) for x in tables[0][1]["heldout"].seed_a})
    # every milestone's parts, with all seeds (None) and with each seed left out, computed once per key
    scored = {
        (key, seed): [parts(t[key] if seed is None else without_seed(t[key], seed), key) for _, t in tables]
        for key in KEYS
        for seed in (None, *seeds)
    }
    out = {}
    for (key, part), targets in FITTED.items():
        slope, last = line(steps, np.array([p[part] for p in scored[key, None]]))
        loo = [line(steps, np.array([p[part] for p in scored[key, s]]))[0] for s in seeds]
        doublings = {str(t): (round((t - last) / slope, 1) if slope > 0 else None) for t in targets}
        out[f"{key}/{part}"] = {
            "per_doubling": round(slope, 2),
            "per_doubling_se": round(jackknife_se(np.array(loo)), 2),
            "at_last": round(last, 2),
            "last_env_steps": int(steps[-1]),
            "doublings_to_reach": doublings,
            "env_steps_to_reach": {
                t: (float(f"{steps[-1] * 2**d:.3g}") if d is not None else None) for t, d in doublings.items()
            },
        }
    return out


def main() -> None:
    evaluations = [(0, 0, START, {k: read_csv(HERE.parent / "cec64m" / f"{k}.csv") for k in KEYS})]
    for f in sorted((HERE / "curve").glob("window*-heldout-u*.csv.gz")):
        w, u = (int(x) for x in re.match(r"window(\d)-heldout-u(\d+)", f.name).groups())
        pair = {k: read_csv(f.with_name(f.name.replace("heldout", k))) for k in KEYS}
        evaluations.append((w, u, CALL_START[w] + u * STEPS_PER_UPDATE, pair))
    evaluations.sort(key=lambda e: e[2])
    rows = [
        {"window": w, "update": u, "env_steps": steps}
        | {k: point(t[k]) for k in KEYS}
        | {f"{k}_parts": parts(t[k], k) for k in KEYS}
        for w, u, steps, t in evaluations
    ]
    print(f"{'env steps/seed':>15s} {'held-out XP':>14s} {'SP':>6s} {'classic XP':>14s} {'SP':>6s}")
    for r in rows:
        h, c = r["heldout"], r["classic"]
        print(
            f"{r['env_steps'] / 1e6:14.0f}M {h['xp']:7.1f} ± {h['xp_se']:4.1f} {h['sp']:6.1f} "
            f"{c['xp']:7.1f} ± {c['xp_se']:4.1f} {c['sp']:6.1f}"
        )
    (HERE / "curve.json").write_text(json.dumps(rows, indent=1) + "\n")
    fits = budget([(steps, t) for _, _, steps, t in evaluations])
    (HERE / "budget.json").write_text(json.dumps(fits, indent=1) + "\n")
    for name, f in fits.items():
        reach = ", ".join(
            f"{t} after {d:+.1f} doublings ({f['env_steps_to_reach'][t]:.2g})"
            if d is not None
            else f"{t}: never"
            for t, d in f["doublings_to_reach"].items()
        )
        print(
            f"{name:28s} {f['at_last']:5.1f} at the end, "
            f"{f['per_doubling']:+5.2f} ± {f['per_doubling_se']:.2f} per doubling; {reach}"
        )

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    x = np.array([r["env_steps"] for r in rows]) / 1e6
    for key, label in (("heldout", "100 held-out kitchens"), ("classic", "5 classic kitchens")):
        y = np.array([r[key]["xp"] for r in rows])
        se = np.array([r[key]["xp_se"] for r in rows])
        ax.errorbar(x, y, yerr=se, marker="o", capsize=3, label=f"cross-play, {label}")
    for w in range(2, len(CALL_UPDATES) + 1):
        label = "a call starts (the LR restarts)" if w == 2 else None
        ax.axvline(CALL_START[w] / 1e6, color="grey", lw=0.8, ls=":", label=label)
    title = "Shipped CEC seeds 200-203 over their training (± jackknife SE over seeds)"
    save(fig, ax, ("env steps per seed (M)", "team return per 400 steps (20 per soup)", title), "curve.png")
    plot_budget(plt, rows, fits)


def save(fig, ax, labels: tuple[str, str, str], name: str) -> None:  # noqa: ANN001
    """Labels (x, y, title), legend, and the figure written to `name` beside this script."""
    ax.set_xlabel(labels[0])
    ax.set_ylabel(labels[1])
    ax.set_title(labels[2], fontsize=9)
    ax.legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(HERE / name, dpi=110)


def plot_budget(plt, rows: list[dict], fits: dict[str, dict]) -> None:  # noqa: ANN001
    """budget.png: the fitted parts over the env steps (log scale), their lines, the 20-per-400 mark."""
    fig, ax = plt.subplots(figsize=(6.5, 3.8))
    x = np.array([r["env_steps"] for r in rows], float)
    for name, f in fits.items():
        if name == "heldout/generated":
            continue
        key, part = name.split("/")
        y = [r[f"{key}_parts"][part] for r in rows]
        dots = ax.plot(
            x, y, marker="o", ms=3, lw=0.8, label=f"{name} ({f['per_doubling']:+.2f} per doubling)"
        )
        fit = f["at_last"] + f["per_doubling"] * np.log2(x / x[-1])
        ax.plot(x, fit, color=dots[0].get_color(), lw=1.6, alpha=0.6)
    ax.axhline(20, color="grey", lw=0.8, ls="--", label="20 per 400 steps (one soup)")
    ax.set_xscale("log", base=2)
    title = "Shipped CEC seeds: the hard parts over their training, least-squares lines"
    save(fig, ax, ("env steps per seed (log scale)", "cross-play per 400 steps", title), "budget.png")


if __name__ == "__main__":
    main()
