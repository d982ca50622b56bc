"""A fine-tuned family's shipped partners at the authors' 100-step episodes beside the same games at 400
steps (`steps100.sh` plays the 100-step tables; the 400-step ones are the family's, `finetune/evaluate.py`'s):
per classic kitchen, the shipped fine-tuned partner (one seed per kitchen, `cec/shipped/zoo.yaml`) with
itself, with the generalist seeds it started from, with the kitchen's test human proxy and with the scripted
cook, and the generalists with the proxy and the cook (the control). Team return per episode, the mean over
episodes (with the generalists: ± the standard error over their 4 seeds, each seed's mean first).

    cd benchmarks/results/overcooked/shipped
    ../../../../.venv/bin/python steps100_finetune.py ft758m > finetune/steps100/steps100.md
    ../../../../.venv/bin/python steps100_finetune.py ftteach > finetune/teacher/steps100/steps100.md
"""

from __future__ import annotations

import bz2
import csv
import sys
from pathlib import Path

import numpy as np
import yaml

from cec.agents.zoo import SHIPPED_ZOO
from cec.evaluation.markdown import pm
from cec.evaluation.stats import sem

HERE = Path(__file__).resolve().parent
KITCHENS = ("cramped_room", "asymm_advantages", "coord_ring", "forced_coord", "counter_circuit")
FAMILIES = {"ft758m": ("cec", HERE / "finetune"), "ftteach": ("cec_teacher", HERE / "finetune" / "teacher")}


def rows(path: Path) -> list[dict[str, str]]:
    with bz2.open(path, "rt") as f:
        return [r for r in csv.DictReader(f) if r["status"] == "ok"]


def mean_with(games: list[dict[str, str]], me: tuple[str, str], partner: tuple[str, str]) -> float:
    """The mean return of the episodes of `me` (algorithm, seed) with `partner`, either seat."""

    def who(r: dict[str, str], side: str) -> tuple[str, str]:
        return r[f"algorithm_{side}"], r[f"seed_{side}"]

    out = [
        float(r["return"])
        for r in games
        if {who(r, "a"), who(r, "b")} == {me, partner} and (me != partner or who(r, "a") == who(r, "b"))
    ]
    return float(np.mean(out)) if out else float("nan")


def main(prefix: str) -> None:
    generalist, folder = FAMILIES[prefix]
    shipped = yaml.safe_load(SHIPPED_ZOO.read_text())["policies"]
    gens = [str(e["seed"]) for e in shipped if e["algorithm"] == generalist]
    measures = ("with itself", "with the generalists it started from", "with the test human proxy",
                "with the scripted cook", "control: the generalists with the proxy",
                "control: the generalists with the cook")  # fmt: skip
    cells: dict[str, list[str]] = {f"{m}, {n} steps": [] for m in measures for n in (400, 100)}
    for k in KITCHENS:
        (entry,) = [e for e in shipped if e["name"] == f"{prefix}-{k}"]
        seed = str(entry["seed"])
        # the family's 400-step table names every fine-tuned seed `cec_finetune`, the 100-step one by the
        # label it is shipped with
        long_, short = folder / f"{k}.csv.bz2", folder / "steps100" / f"{k}.csv.bz2"
        for steps, path, label in ((400, long_, "cec_finetune"), (100, short, entry["algorithm"])):
            games = rows(path)
            me = (label, seed)
            per_gen = np.array([mean_with(games, me, (generalist, g)) for g in gens])
            gen_hp = np.array([mean_with(games, (generalist, g), ("human_proxy", "0")) for g in gens])
            gen_cook = np.array([mean_with(games, (generalist, g), ("cook", "0")) for g in gens])
            for what, value in (
                ("with itself", f"{mean_with(games, me, me):.1f}"),
                ("with the generalists it started from", pm(float(per_gen.mean()), sem(per_gen))),
                ("with the test human proxy", f"{mean_with(games, me, ('human_proxy', '0')):.1f}"),
                ("with the scripted cook", f"{mean_with(games, me, ('cook', '0')):.1f}"),
                ("control: the generalists with the proxy", pm(float(gen_hp.mean()), sem(gen_hp))),
                ("control: the generalists with the cook", pm(float(gen_cook.mean()), sem(gen_cook))),
            ):
                cells.setdefault(f"{what}, {steps} steps", []).append(value)
    names = ", ".join(f"{prefix}-{k}" for k in KITCHENS)
    print(f"# {prefix}: the shipped fine-tuned partners at 100 and 400 steps\n")
    print(
        f"Team return per episode (20 per soup) of {names} (one seed per kitchen), 4 episodes per pairing "
        "and seat order in its kitchen, sampled actions, the same draws at both lengths.\n"
    )
    print("| | " + " | ".join(KITCHENS) + " |")
    print("|---" * (len(KITCHENS) + 1) + "|")
    for key in cells:  # each measure at 400 steps, then at 100
        print(f"| {key} | " + " | ".join(cells[key]) + " |")


if __name__ == "__main__":
    main(sys.argv[1])
