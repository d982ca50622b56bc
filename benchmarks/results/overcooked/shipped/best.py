"""Which shipped partner `cec play serve --partner best` plays in each kitchen, chosen on validation, with
the test figure beside each choice:

    .venv/bin/cec humans import && .venv/bin/cec humans bc --kitchens cramped_room asymm_advantages \\
        coord_ring forced_coord counter_circuit       # the proxies: runs/humans/proxies/zoo.yaml
    .venv/bin/python benchmarks/results/overcooked/shipped/best.py
    cp /tmp/shipped-best/best.yaml cec/shipped/

Per classic kitchen the candidates are the kitchen's fine-tuned agents (`ft758m-<kitchen>`, `cec_finetune`:
from the CEC seeds; `ftteach-<kitchen>`, `cec_finetune_teacher`: from the kickstarted seeds) and each group of
generalist seeds (the CEC seeds, `cec`; the kickstarted seeds, `cec_teacher`); the one that cooks most on
average with the kitchen's validation proxy (`bc_<kitchen>`: cloned from the train games' people) is chosen,
and its figure with the test proxy (`hp_<kitchen>`, the test games' people, shipped) reports. One `cec eval`
per kitchen and proxy (400-step episodes, 4 per seat order, sampled actions, the evaluation's common random
numbers) into `best/<kitchen>_<bc|hp>.csv.bz2`. Every other kitchen (the generated ones, one a person
draws) gets the generalist group with the higher cross-play on the 100 generated validation kitchens of the
release tables (`heldout.csv`, `teacher/heldout.csv.bz2`). Writes `best.md` here and `best.yaml` to
`--work` (the file `cec/shipped/best.yaml` is, comment included).
"""

from __future__ import annotations

import argparse
import bz2
import subprocess
import sys
from collections.abc import Callable
from pathlib import Path

import numpy as np
import yaml

from cec.agents.zoo import OTHER_KITCHENS, SHIPPED_ZOO, SkippedEntry, load_zoo
from cec.evaluation.choice import ChoiceError, choose
from cec.evaluation.markdown import pm
from cec.evaluation.parts import part_scores
from cec.evaluation.results import read_csv
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import sem
from cec.humans.data import KITCHENS
from cec.levels.heldout import heldout_levels

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[3]
#: The generalist groups, with the release table of each on the validation kitchens.
GENERALISTS = {"cec": HERE / "heldout.csv", "cec_teacher": HERE / "teacher" / "heldout.csv.bz2"}
PROXY, BC = "human_proxy", "bc_proxy"
#: The fine-tuned agents by algorithm label, with the prefix of their shipped names (`<prefix>-<kitchen>`).
FINETUNED = {"cec_finetune": "ft758m", "cec_finetune_teacher": "ftteach"}
#: The comment of `cec/shipped/best.yaml`, so that the file written here is the one shipped, as it is.
HEADER = """\
# `cec play serve --partner best`: per classic kitchen, the shipped partner that cooked most with the
# validation proxy there (bc_<kitchen>: people of the train games; the hp_ proxies report); in every other
# kitchen the generalist seeds with the higher validation cross-play. Written by
# benchmarks/results/overcooked/shipped/best.py (best.md beside it has the figures).
"""


def zoo(kitchen: str, proxies: Path) -> dict:
    """The kitchen's candidates (the generalist groups' seeds, its fine-tuned agents) and both its proxies."""
    wanted = {f"hp_{kitchen}", *(f"{prefix}-{kitchen}" for prefix in FINETUNED.values())}
    shipped = [e for e in load_zoo(SHIPPED_ZOO) if e.algorithm in GENERALISTS or e.name in wanted]
    (bc,) = [e for e in load_zoo(proxies) if e.name == f"bc_{kitchen}"]
    entries = [{"name": e.name, "algorithm": e.algorithm, "seed": e.seed, "checkpoint": e.checkpoint,
                **({"levels": list(e.levels)} if e.levels else {})} for e in shipped]  # fmt: skip
    entries.append(
        {"name": bc.name, "algorithm": BC, "seed": 0, "checkpoint": bc.checkpoint, "levels": [kitchen]}
    )
    return {"policies": entries}


def with_proxy(table: Path, proxy_algorithm: str) -> tuple[dict[str, np.ndarray], list[SkippedEntry]]:
    """Per candidate (a generalist group, or a fine-tuned agent by its algorithm label), each of its seeds'
    mean return with the proxy (NaN where the proxy is missing: `choose` refuses it); and the entries of
    the candidates or the proxy that the evaluation skipped."""
    results = read_csv(table)
    m = seed_matrix(results)
    proxy = m.indices(proxy_algorithm)
    candidates = [a for a in (*GENERALISTS, *FINETUNED) if m.indices(a)]
    used = {*GENERALISTS, *FINETUNED, proxy_algorithm}
    skipped = [s for s in results.skipped if s.algorithm in used]
    return {a: m.partner_means(m.indices(a), proxy) for a in candidates}, skipped


def validation_crossplay() -> dict[str, float]:
    """Each generalist group's cross-play on the 100 generated validation kitchens, from its release table."""
    levels = dict(heldout_levels())
    return {a: part_scores(read_csv(t), a, levels)["generated"].xp for a, t in GENERALISTS.items()}


def main() -> int:
    try:
        return choose_best()
    except ChoiceError as err:  # a choice made without its validation figures: refused, nothing written
        print(f"{Path(__file__).name}: error: {err}", file=sys.stderr)
        return 2


def choose_best() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--proxies", default="runs/humans/proxies/zoo.yaml", help="`cec humans bc`'s zoo")
    ap.add_argument("--work", default="/tmp/shipped-best", help="zoos, raw tables, best.yaml")
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--summarise-only", action="store_true", help="read the tables already in --tables")
    ap.add_argument("--tables", default=str(HERE / "best"), help="the tables' folder (default: best/ here)")
    ap.add_argument("--markdown", default=str(HERE / "best.md"), help="where best.md goes (default: here)")
    args = ap.parse_args()
    work, tables, proxies = Path(args.work), Path(args.tables), Path(args.proxies).resolve()
    work.mkdir(parents=True, exist_ok=True)
    tables.mkdir(exist_ok=True)
    best: dict[str, str] = {}
    rows = []
    for kitchen in KITCHENS:
        scores, skipped, manifest = {}, {}, work / f"zoo_{kitchen}.yaml"
        if not args.summarise_only:
            manifest.write_text(yaml.safe_dump(zoo(kitchen, proxies), sort_keys=False))
        for proxy, algorithm in (("bc", BC), ("hp", PROXY)):
            table = tables / f"{kitchen}_{proxy}.csv.bz2"
            if not args.summarise_only:
                raw = work / f"{kitchen}_{proxy}.csv"
                cmd = [str(ROOT / ".venv/bin/cec"), "eval", "--zoo", str(manifest), "--levels", kitchen,
                       "--episodes", str(args.episodes), "--max-steps", "400",
                       "--pairs", f"with:{proxy}_{kitchen}", "--out", str(raw)]  # fmt: skip
                print("$", " ".join(cmd), flush=True)
                subprocess.run(cmd, check=True, cwd=ROOT)
                table.write_bytes(bz2.compress(raw.read_bytes(), 9))
            scores[proxy], skipped[proxy] = with_proxy(table, algorithm)
        chosen = choose(  # on validation: with the bc proxy (the hp figures report)
            scores["bc"], what=f"{kitchen}: the partner of `--partner best`", skipped=skipped["bc"]
        )
        best[kitchen] = f"{FINETUNED[chosen]}-{kitchen}" if chosen in FINETUNED else chosen
        rows.append((kitchen, best[kitchen], chosen, scores))
        print(f"{kitchen}: `--partner best` plays {best[kitchen]}", flush=True)
    xp = validation_crossplay()
    best[OTHER_KITCHENS] = choose(
        {a: [v] for a, v in xp.items()}, what="every other kitchen: the generalists of `--partner best`"
    )
    (work / "best.yaml").write_text(HEADER + yaml.safe_dump(best, sort_keys=False))
    Path(args.markdown).write_text(markdown(rows, xp, best[OTHER_KITCHENS]))
    print(Path(args.markdown).read_text())
    print(f"to ship: cp {work}/best.yaml cec/shipped/")
    return 0


def markdown(rows: list, xp: dict[str, float], other: str) -> str:
    names = {
        "cec": "the CEC seeds (`cec`, 758M)",
        "cec_teacher": "the kickstarted seeds (`cec_teacher`, 21M)",
        "cec_finetune": "the kitchen's agent fine-tuned from the CEC seeds (`ft758m-<kitchen>`)",
        "cec_finetune_teacher": "... from the kickstarted seeds (`ftteach-<kitchen>`)",
    }
    out = [
        "# `cec play serve --partner best`: the partner of each kitchen",
        "",
        "Written by `best.py` (its docstring has the commands). Team return per 400 steps with the kitchen's",
        "proxy, mean over the candidate's seeds ± SE (4 episodes per seat order); the validation proxy",
        "(`bc_<kitchen>`, people of the train games) chooses, the test proxy (`hp_<kitchen>`) reports.",
        "The bc proxies are not shipped: `cec humans bc` clones them again, and a clone made on another",
        "machine plays differently (the fine-tuned agents' bc figures here are not those of",
        "finetune/README.md), so every candidate is played with the same clone in one run.",
        "",
        "| candidate | " + " | ".join(f"{k}: bc (validation) / hp (test)" for k, _, _, _ in rows) + " |",
        "|---|" + "---|" * len(rows),
    ]
    for a, label in names.items():
        if not all(a in s["bc"] for _, _, _, s in rows):
            continue  # not shipped for every kitchen
        cells = []
        for _, _, _, s in rows:
            bc, hp = s["bc"][a], s["hp"][a]
            cells.append(f"{pm(float(np.mean(bc)), float(sem(bc)) if bc.size > 1 else None)} / "
                         f"{pm(float(np.mean(hp)), float(sem(hp)) if hp.size > 1 else None)}")  # fmt: skip
        out.append(f"| {label} | " + " | ".join(cells) + " |")
    out.append("| **chosen** | " + " | ".join(f"**{b}**" for _, b, _, _ in rows) + " |")

    def test_mean(pick: Callable[[str], str]) -> float:  # over the kitchens, the hp figure of the pick
        return float(np.mean([np.mean(s["hp"][pick(c)]) for _, _, c, s in rows]))

    chosen = test_mean(lambda c: c)
    alone = ", ".join(f"`{a}` alone {test_mean(lambda b, a=a: a):.1f}" for a in GENERALISTS)
    out += [
        "",
        f"With the test proxies, what `--partner best` plays scores {chosen:.1f} per 400 steps over the five "
        f"kitchens ({alone}).",
        "",
        "Every other kitchen: the generalists with the higher cross-play on the 100 generated validation",
        "kitchens (their release tables): "
        + ", ".join(f"`{a}` {v:.1f}" for a, v in xp.items())
        + f"; chosen: **{other}**.",
        "",
    ]
    return "\n".join(out)


if __name__ == "__main__":
    sys.exit(main())
