"""What the CPU reproduction at 6 seeds per algorithm, its single-kitchen baselines trained to the report's
plateau criterion, would cost on this machine, from the committed runs' metrics (issue 86, item 3). Prints
Markdown (`plan_6seeds.md` beside it):

    cd benchmarks/results/overcooked/cpu && ../../../../.venv/bin/python plan_6seeds.py > plan_6seeds.md

The plateau criterion is the report's (`apps/reproduce/overcooked/sections.py`, PLATEAU_SHARE): a group
levelled off when its team return per training episode (trailing mean of 10 updates, mean over seeds) rose
by at most 5% of its last value over the last quarter of its run. The projection is the report's too
(`plateau_quarters`): with R50, R75, R100 the return at a half, three quarters and all of the run, the rise
per quarter shrinks by rho = (R100 - R75) / (R75 - R50); an exponential approach R(t) = A - B rho^(4t/T)
through those points gives the first length (in quarters of the present run) whose own last quarter rises by
at most 5%. Where the rise did not slow (rho >= 1, or a rise too noisy to read: R75 <= R50), no projection:
the plan doubles the run and checks again. It is an extrapolation of the training return with its LR
schedule stretched over a longer run (the recipe anneals the LR over the run's total), so the plan's second
step reads the criterion off the new runs' metrics.

Cost: `seconds_per_update` of the CPU mode (`apps/reproduce/overcooked/modes.py`: s per update and seed on one
core, both cores training) x updates x seeds. The checkpoints of the 4-seed zoo are not kept, so 6 seeds means
training all 6 (the new seeds must play the old ones).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import yaml

from apps.reproduce.overcooked.modes import CPU, GENERALISTS, TITLES
from apps.reproduce.overcooked.sections import plateau_quarters
from cec.evaluation.curves import read_curve, trailing_mean

RUNS = Path(__file__).resolve().parent / "work" / "zoo" / "runs"
SEEDS = 6


def curve(algo: str, kitchen: str) -> np.ndarray:
    """The mean over seeds of the trailing mean (10 updates) of the team return per training episode."""
    runs = sorted(RUNS.glob(f"{algo}_{kitchen}-s*"))
    per_seed = [
        trailing_mean(v, 10) for r in runs for _, v in read_curve(r, "mean_return").values() if len(v)
    ]
    n = min(len(v) for v in per_seed)
    return np.mean([v[:n] for v in per_seed], axis=0)


def projection(m: np.ndarray) -> tuple[float, float, float, int | None]:
    """(last, rise over the last quarter, rho, quarters of the present run needed: the report's
    `plateau_quarters`; None: no projection)."""
    n = len(m)
    r50, r75, r100 = m[n // 2 - 1], m[(3 * n) // 4 - 1], m[-1]
    rise, before = r100 - r75, r75 - r50
    quarters = plateau_quarters(r50, r75, r100)
    rho = math.nan if quarters == 4 or before <= 0 else rise / before
    return float(r100), float(rise), rho, quarters


def main() -> None:
    spu = CPU.seconds_per_update
    rows, total_budget, total_plateau = [], 0.0, 0.0
    for algo in GENERALISTS:
        cfg = yaml.safe_load((RUNS / f"{algo}-s{CPU.seeds[algo][0]}" / "config.yaml").read_text())
        updates = cfg["total_env_steps"] // (cfg["num_envs"] * cfg["num_steps"])
        hours = spu[algo] * updates * SEEDS / 3600
        total_budget += hours
        total_plateau += hours
        steps = cfg["total_env_steps"]
        cells = f"{steps:,} | — | — | — | 1x | {hours:.2f} | {hours:.2f}"
        rows.append(f"| {TITLES[algo]} | generator | {cells} |")
    for algo in ("ippo", "fcp", "e3t", "cec_finetune"):
        for k in CPU.kitchens:
            cfg = yaml.safe_load(next(RUNS.glob(f"{algo}_{k}-s*")).joinpath("config.yaml").read_text())
            steps = cfg["total_env_steps"]
            updates = steps // (cfg["num_envs"] * cfg["num_steps"])
            last, rise, rho, quarters = projection(curve(algo, k))
            budget = spu[algo] * updates * SEEDS / 3600
            factor = 2.0 if quarters is None else quarters / 4
            plateau = budget * factor
            total_budget += budget
            total_plateau += plateau
            proj = "not slowing: 2x, then check" if quarters is None else f"{factor:g}x"
            rows.append(
                f"| {TITLES[algo]} | {k} | {steps:,} | {last:.1f} | {rise:+.1f} | "
                f"{'—' if math.isnan(rho) else f'{rho:.2f}'} | {proj} | {budget:.2f} | {plateau:.2f} |"
            )
    print("# The CPU reproduction at 6 seeds, baselines to their plateau: the plan and its cost\n")
    print(__doc__.split("\n\n", 2)[2].strip() + "\n")
    print("| algorithm | kitchen | env steps per seed now | return, last 10 updates | rise, last quarter | "
          "rho | projected run for the criterion | core-h, 6 seeds at the present budget | "
          "core-h, 6 seeds to the projection |")  # fmt: skip
    print("|---|---|---|---|---|---|---|---|---|")
    print("\n".join(rows))
    print(
        f"\nTotal, one core: {total_budget:.1f} core-h at the present budgets, {total_plateau:.1f} core-h "
        "with the baselines to their projected plateau; the machine's two cores halve the wall time (two zoo "
        "builders side by side), before the evaluation (the 4-seed zoo's: 41 min of cross-play; 6 seeds "
        "about (6/4)^2 = 2.25x the pairs)."
    )


if __name__ == "__main__":
    main()
