"""Cross-play of the shipped seeds over their GPU training: the 64M-step seeds (../cec64m/), then every
milestone of the four `benchmarks/gpu_session.sh window` calls that trained them on (1024 envs x 128 steps
per update and seed, so an update is 131,072 env steps per seed; each call's LR schedule starts anew).
Each point: `cec eval` of the four seeds at that checkpoint (held-out: 100 kitchens, 1 episode; classic: 5
kitchens, 4 episodes; 400 steps, both seat orders, the evaluation seed of every shipped evaluation),
cross-play with its jackknife SE over seeds.

    .venv/bin/python benchmarks/results/overcooked/shipped/window/curve.py     # writes curve.json, curve.png

The evaluations of the milestones are in curve/ (gzipped `cec eval` tables; the milestone policies
themselves, 1.3 MB each, were not kept in the repository).
"""

from __future__ import annotations

import json
import re
from pathlib import Path

import numpy as np

from cec.evaluation.results import read_csv
from cec.evaluation.seeds import seed_matrix

HERE = Path(__file__).parent
START = 64_012_288  # the shipped 64M seeds' env steps per seed
STEPS_PER_UPDATE = 131_072
# Each call's updates: the first ran its schedule to the end, the second was stopped after 1,810 (the 451M
# seeds), the third after 2,340 (the 758M seeds), the fourth after 940 (the 881M seeds). The LR restarted
# at each call's start: 2e-3 in the first three, 1e-3 in the fourth.
CALL_UPDATES = (1145, 1810, 2340, 940)
CALL_START = {
    w: START + sum(CALL_UPDATES[: w - 1]) * STEPS_PER_UPDATE for w in range(1, len(CALL_UPDATES) + 1)
}


def point(table) -> dict[str, float]:  # noqa: ANN001
    m = seed_matrix(table)
    s = m.summary(m.indices("cec"))
    xp = s.crossplay()
    return {"xp": round(xp.mean, 2), "xp_se": round(xp.se, 2), "sp": round(float(np.mean(s.sp)), 2)}


def main() -> None:
    rows = [{"window": 0, "update": 0, "env_steps": START}]
    rows[0] |= {k: point(read_csv(HERE.parent / "cec64m" / f"{k}.csv")) for k in ("heldout", "classic")}
    for f in sorted((HERE / "curve").glob("window*-heldout-u*.csv.gz")):
        w, u = (int(x) for x in re.match(r"window(\d)-heldout-u(\d+)", f.name).groups())
        steps = CALL_START[w] + u * STEPS_PER_UPDATE
        row = {"window": w, "update": u, "env_steps": steps, "heldout": point(read_csv(f))}
        row["classic"] = point(read_csv(f.with_name(f.name.replace("heldout", "classic"))))
        rows.append(row)
    rows.sort(key=lambda r: r["env_steps"])
    print(f"{'env steps/seed':>15s} {'held-out XP':>14s} {'SP':>6s} {'classic XP':>14s} {'SP':>6s}")
    for r in rows:
        h, c = r["heldout"], r["classic"]
        print(
            f"{r['env_steps'] / 1e6:14.0f}M {h['xp']:7.1f} ± {h['xp_se']:4.1f} {h['sp']:6.1f} "
            f"{c['xp']:7.1f} ± {c['xp_se']:4.1f} {c['sp']:6.1f}"
        )
    (HERE / "curve.json").write_text(json.dumps(rows, indent=1) + "\n")

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
    ax.set_xlabel("env steps per seed (M)")
    ax.set_ylabel("team return per 400 steps (20 per soup)")
    ax.set_title("Shipped CEC seeds 200-203 over their training (± jackknife SE over seeds)", fontsize=9)
    ax.legend(fontsize=8)
    fig.tight_layout()
    fig.savefig(HERE / "curve.png", dpi=110)


if __name__ == "__main__":
    main()
