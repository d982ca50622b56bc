"""CEC-Finetune from shipped generalist seeds, per classic kitchen: its seeds with each other, with the seeds
they started from, with the human proxy of the kitchen and with the scripted cook, beside the same for the
seeds they started from (the control: the partner a person has without fine-tuning) and a partner that
stays put. Two families (`--family`): `ft758m`, from the CEC seeds (758M env steps), and `ftteach`, from the
kickstarted seeds (lever (u)'s release, 21M), each with its config and its folder here:

    # Forced Coordination and Counter Circuit twice as long (total_env_steps=1966080, and for ftteach
    # ppo.teacher_anneal_env_steps=1966080):
    cec train --config configs/train/cec_finetune_shipped.yaml env.levels=KITCHEN run_dir=runs/ft758m \\
        name=ft758m-KITCHEN
    .venv/bin/python benchmarks/results/overcooked/shipped/finetune/evaluate.py --runs runs/ft758m
    cec train --config configs/train/cec_finetune_teacher.yaml env.levels=KITCHEN run_dir=runs/ftteach \\
        name=ftteach-KITCHEN
    .venv/bin/python benchmarks/results/overcooked/shipped/finetune/evaluate.py --family ftteach   # teacher/

Per kitchen one `cec eval` (400-step episodes, 4 per pairing and seat order, sampled actions, common random
numbers) into `<kitchen>.csv.bz2`; then `summary.json` and `summary.md`.

Validation chooses, test reports (DESIGN rule 13), with people as in Carroll et al.: the `bc_<kitchen>`
proxy (`cec humans bc`, cloned from the train games' players; `--proxies`) is the partner the choices are
made with, the shipped `hp_<kitchen>` proxy (the test games' players) reports. The seed shipped per kitchen
is the fine-tuned seed that cooked most with the bc proxy (`--work`/ship.yaml, for `cec zoo export ship.yaml
--out cec/shipped`); which shipped partner `cec play serve --partner best` plays per kitchen is chosen by
`../best.py` among that seed and the shipped generalists. The hp proxies' and the cook's figures choose
nothing.
"""

from __future__ import annotations

import argparse
import bz2
import json
import math
import subprocess
import sys
from pathlib import Path
from typing import NamedTuple

import numpy as np
import yaml

from cec.agents.zoo import SHIPPED_ZOO, load_zoo
from cec.evaluation.choice import ChoiceError, choose
from cec.evaluation.markdown import pm
from cec.evaluation.results import read_csv
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import compare_crossplay_paired, sem
from cec.humans.data import KITCHENS

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[4]
FINETUNE, PROXY, BC = "cec_finetune", "human_proxy", "bc_proxy"


class Family(NamedTuple):
    """A family of fine-tuned agents (its runs' and shipped names' prefix is its key in `FAMILIES`)."""

    control: str  # the algorithm label of the shipped generalists it started from
    seeds: str  # how the tables name them
    shipped_as: str  # the algorithm label its shipped agents carry (`cec play serve --partner LABEL`)
    folder: Path  # its tables and summary


FAMILIES = {
    "ft758m": Family("cec", "CEC seeds", "cec_finetune", HERE),
    "ftteach": Family("cec_teacher", "kickstarted seeds", "cec_finetune_teacher", HERE / "teacher"),
}


def run_seeds(run: Path) -> list[int]:
    config = yaml.safe_load((run / "config.yaml").read_text())
    return [config["seed"] + i for i in range(config["num_seeds"])]


def zoo(kitchen: str, run: Path, seeds: list[int], proxies: Path, control: str) -> dict:
    """The kitchen's zoo: the fine-tuned seeds (the run's last checkpoint), the shipped seeds they started
    from (algorithm `control`) and the kitchen's test human proxy (as shipped), its validation proxy
    (`bc_<kitchen>` of `proxies`, as `bc_proxy`), the scripted cook and a partner that stays put."""
    shipped = [e for e in load_zoo(SHIPPED_ZOO) if e.algorithm == control or e.name == f"hp_{kitchen}"]
    (bc,) = [e for e in load_zoo(proxies) if e.name == f"bc_{kitchen}"]
    if not Path(bc.checkpoint).is_dir():  # it chooses the shipped seed: never go on without it
        raise SystemExit(f"{proxies}: bc_{kitchen} has no checkpoint at {bc.checkpoint}; run `cec humans bc`")
    return {
        "policies": [
            *(
                {"name": f"ft_{kitchen}_s{s}", "algorithm": FINETUNE, "seed": s, "checkpoint": str(run),
                 "levels": [kitchen]}
                for s in seeds
            ),
            *({"name": e.name, "algorithm": e.algorithm, "seed": e.seed, "checkpoint": e.checkpoint,
               **({"levels": list(e.levels)} if e.levels else {})} for e in shipped),
            {"name": bc.name, "algorithm": BC, "seed": 0, "checkpoint": bc.checkpoint, "levels": [kitchen]},
            {"name": "cook", "scripted": "cook"},
            {"name": "noop", "scripted": "noop"},
        ]
    }  # fmt: skip


def mean_se(x: np.ndarray) -> dict:
    """Mean and standard error over seeds, and the per-seed values."""
    x = np.asarray(x, np.float64)
    se = float(sem(x)) if x.size > 1 else math.nan
    return {"mean": float(np.mean(x)), "se": se, "n": int(x.size), "per_seed": [float(v) for v in x]}


def summarise(csv: Path, kitchen: str, control: str) -> dict:
    """The fine-tuned seeds beside the seeds they started from (`control`); under the keys `finetune` and
    `cec` (the latter whichever generalists `control` names). The choices (the seed shipped, `best`) are
    refused (`ChoiceError`) when the bc proxy or a seed is missing from the table or was skipped."""
    table = read_csv(csv)
    m = seed_matrix(table)
    ft, cec = m.indices(FINETUNE), m.indices(control)
    group = {a: m.indices(a) for a in (PROXY, BC, "cook", "noop")}
    fts, cecs = m.summary(ft), m.summary(cec)
    ft_bc, cec_bc = m.partner_means(ft, group[BC]), m.partner_means(cec, group[BC])
    used = [s for s in table.skipped if s.algorithm in (FINETUNE, control, BC)]
    by_seed = {f"{FINETUNE} seed {s}": s for s in fts.seeds}
    seed = by_seed[
        choose(
            {label: [v] for label, v in zip(by_seed, ft_bc, strict=True)},
            what=f"{csv}: the {FINETUNE} seed shipped for {kitchen} (with the bc proxy)",
            skipped=used,
        )
    ]
    best = choose(  # the control first: it stays the choice on a tie
        {control: cec_bc, FINETUNE: ft_bc},
        what=f"{csv}: the better of {control} and {FINETUNE} in {kitchen} (with the bc proxy)",
        skipped=used,
    )
    paired = compare_crossplay_paired(np.asarray(fts.matrix), np.asarray(cecs.matrix))
    ft_hp, cec_hp = m.partner_means(ft, group[PROXY]), m.partner_means(cec, group[PROXY])
    out = {
        "kitchen": kitchen,
        "shipped_seed": seed,  # validation: with the bc proxy
        "best": best,
        "finetune_seeds": list(fts.seeds),
        "cec_seeds": list(cecs.seeds),
        "finetune": {
            "self_play": mean_se(np.asarray(fts.sp)),
            "cross_play": fts.crossplay()._asdict(),
            "with_cec_seeds": mean_se(m.partner_means(ft, cec)),
            "with_human_proxy": mean_se(ft_hp),
            "with_bc_proxy": mean_se(ft_bc),
            "with_cook": mean_se(m.partner_means(ft, group["cook"])),
        },
        "cec": {
            "self_play": mean_se(np.asarray(cecs.sp)),
            "cross_play": cecs.crossplay()._asdict(),
            "with_human_proxy": mean_se(cec_hp),
            "with_bc_proxy": mean_se(cec_bc),
            "with_cook": mean_se(m.partner_means(cec, group["cook"])),
        },
        "controls": {
            "noop_with_cook": float(m.partner_means(group["noop"], group["cook"])[0]),
            "noop_with_human_proxy": float(m.partner_means(group["noop"], group[PROXY])[0]),
        },
        "finetune_vs_cec_cross_play_paired": paired._asdict(),
        "finetune_vs_cec_with_human_proxy_paired": {
            **mean_se(ft_hp - cec_hp),
            "note": "per seed pair (fine-tuned seed i minus the CEC seed it started from), with the proxy",
        },
    }
    return out


def fmt(d: dict) -> str:
    return pm(d["mean"], d.get("se"))


def _paired_proxy(row: dict) -> str:
    d = row["finetune_vs_cec_with_human_proxy_paired"]
    return f"{d['mean']:+.1f} ± {d['se']:.1f}"


def _num(row: dict, control: str) -> str:
    return f"{row['controls'][control]:.1f}"


def markdown(rows: list[dict], seeds: str) -> str:
    """The table of `rows`; `seeds` names the generalists they started from (`FAMILIES`)."""
    head = (
        "| team return per 400 steps (20 per soup), 4 seeds | "
        + " | ".join(r["kitchen"] for r in rows)
        + " |\n|---|"
        + "---|" * len(rows)
    )
    lines = [
        ("CEC-Finetune cross-play (jackknife SE over seeds)", lambda r: fmt(r["finetune"]["cross_play"])),
        ("CEC-Finetune self-play", lambda r: fmt(r["finetune"]["self_play"])),
        (f"the shipped {seeds}, cross-play (the control)", lambda r: fmt(r["cec"]["cross_play"])),
        (f"the shipped {seeds}, self-play", lambda r: fmt(r["cec"]["self_play"])),
        (
            f"fine-tuned minus the {seeds}' cross-play, paired (95% t interval, p)",
            lambda r: "{diff:+.1f} [{ci_low:+.1f}, {ci_high:+.1f}], p = {p:.2g}".format(
                **r["finetune_vs_cec_cross_play_paired"]
            ),
        ),
        (f"CEC-Finetune with the {seeds}", lambda r: fmt(r["finetune"]["with_cec_seeds"])),
        ("validation: CEC-Finetune with the bc proxy", lambda r: fmt(r["finetune"]["with_bc_proxy"])),
        (f"validation: the {seeds} with the bc proxy", lambda r: fmt(r["cec"]["with_bc_proxy"])),
        ("**test: CEC-Finetune with the hp proxy**", lambda r: fmt(r["finetune"]["with_human_proxy"])),
        (f"**test: the {seeds} with the hp proxy**", lambda r: fmt(r["cec"]["with_human_proxy"])),
        (f"test: fine-tuned minus the {seeds} with the hp proxy, per seed pair", _paired_proxy),
        ("control: a partner that stays put, with the proxy", lambda r: _num(r, "noop_with_human_proxy")),
        ("CEC-Finetune with the scripted cook", lambda r: fmt(r["finetune"]["with_cook"])),
        (f"the {seeds} with the scripted cook", lambda r: fmt(r["cec"]["with_cook"])),
        ("control: a partner that stays put, with the cook", lambda r: _num(r, "noop_with_cook")),
    ]  # fmt: skip
    body = "\n".join(f"| {title} | " + " | ".join(f(r) for r in rows) + " |" for title, f in lines)

    def over_kitchens(agent: str, column: str) -> str:
        return f"{np.mean([r[agent][column]['mean'] for r in rows]):.1f}"

    means = (
        f"\nMeans over the {len(rows)} kitchens: cross-play CEC-Finetune "
        f"{over_kitchens('finetune', 'cross_play')}, the {seeds} {over_kitchens('cec', 'cross_play')}; "
        f"test, with the hp proxies: CEC-Finetune {over_kitchens('finetune', 'with_human_proxy')}, "
        f"the {seeds} {over_kitchens('cec', 'with_human_proxy')}.\n"
    )
    return head + "\n" + body + "\n" + means


def main() -> int:
    try:
        return evaluate()
    except ChoiceError as err:  # a choice made without its validation figures: refused, nothing written
        print(f"{Path(__file__).name}: error: {err}", file=sys.stderr)
        return 2


def evaluate() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument(
        "--family",
        choices=FAMILIES,
        default="ft758m",
        help="which fine-tuned agents: their runs' "
        "and shipped names' prefix (ft758m: from the CEC seeds; ftteach: from the kickstarted seeds)",
    )
    ap.add_argument("--runs", default="runs/<family>", help="folder of the runs <family>-<kitchen>")
    ap.add_argument("--work", default="/tmp/<family>-eval", help="folder for the zoos and raw tables")
    ap.add_argument("--kitchens", default=",".join(KITCHENS))
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--proxies", default="runs/humans/proxies/zoo.yaml", help="`cec humans bc`'s zoo")
    ap.add_argument("--out", help="folder for the tables and the summary (default: the family's, here)")
    ap.add_argument("--summarise-only", action="store_true", help="read the tables already in --out")
    args = ap.parse_args()
    family, (control, seeds_label, shipped_as, folder) = args.family, FAMILIES[args.family]
    runs, work = (Path(p.replace("<family>", family)) for p in (args.runs, args.work))
    out = Path(args.out) if args.out else folder
    out.mkdir(parents=True, exist_ok=True)
    work.mkdir(parents=True, exist_ok=True)
    rows, ship = [], []
    for kitchen in args.kitchens.split(","):
        run = runs / f"{family}-{kitchen}"
        table = out / f"{kitchen}.csv.bz2"
        if not args.summarise_only:
            seeds = run_seeds(run)
            manifest = work / f"zoo_{kitchen}.yaml"
            manifest.write_text(
                yaml.safe_dump(
                    zoo(kitchen, run.resolve(), seeds, Path(args.proxies).resolve(), control), sort_keys=False
                )
            )
            raw = work / f"{kitchen}.csv"
            cmd = [str(ROOT / ".venv/bin/cec"), "eval", "--zoo", str(manifest), "--levels", kitchen,
                   "--episodes", str(args.episodes), "--max-steps", "400", "--out", str(raw)]  # fmt: skip
            print("$", " ".join(cmd), flush=True)
            subprocess.run(cmd, check=True, cwd=ROOT)
            table.write_bytes(bz2.compress(raw.read_bytes(), 9))
        row = summarise(table, kitchen, control)
        rows.append(row)
        name = f"{family}-{kitchen}"
        ship.append({"name": name, "algorithm": shipped_as, "seed": row["shipped_seed"],
                     "checkpoint": str(run.resolve()), "levels": [kitchen]})  # fmt: skip
        print(markdown(rows[-1:], seeds_label), flush=True)
        print(f"{kitchen}: ships seed {row['shipped_seed']}")
    (work / "ship.yaml").write_text(yaml.safe_dump({"policies": ship}, sort_keys=False))
    print(f"to ship: cec zoo export {work}/ship.yaml --out cec/shipped; then ../best.py for `--partner best`")
    (out / "summary.json").write_text(json.dumps(rows, indent=1) + "\n")
    (out / "summary.md").write_text(markdown(rows, seeds_label))
    print(markdown(rows, seeds_label))
    return 0


if __name__ == "__main__":
    sys.exit(main())
