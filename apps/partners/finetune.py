"""`cec partners finetune --family F --runs DIR [--ship]`: CEC-Finetune from shipped generalist seeds, per
classic kitchen, evaluated and its seed shipped: the fine-tuned seeds with each other, with the seeds they
started from, with the kitchen's human proxies and with the scripted cook, beside the same for the seeds they
started from (the control: the partner a person has without fine-tuning) and a partner that stays put.

    cec train --config configs/train/cec_finetune_teacher.yaml env.levels=KITCHEN run_dir=runs/ftteach \\
        name=ftteach-KITCHEN                                    # per kitchen (the families' READMEs)
    cec humans import && cec humans bc --kitchens cramped_room asymm_advantages coord_ring forced_coord \\
        counter_circuit                                         # the validation proxies (runs/humans/proxies)
    cec partners finetune --family ftteach --runs runs/ftteach --out DIR --ship
    cec partners best --ship                                    # then `--partner best` chooses again

Two families (`--family`), each the prefix of its runs (`<family>-<kitchen>`) and of its shipped agents:
`ft758m`, from the CEC seeds (`cec`, 758M env steps), shipped as `cec_finetune`; `ftteach`, from the
kickstarted seeds (`cec_teacher`, 21M), shipped as `cec_finetune_teacher`.

Per kitchen one cross-play (400-step episodes, 4 per pairing and seat order, sampled actions, common random
numbers) into `OUT/<kitchen>.csv.bz2`, kept (a second call reads it); then `OUT/summary.json` and
`OUT/summary.md`. Validation chooses, test reports (DESIGN.md rule 13), with people as in Carroll et al.:
the `bc_<kitchen>` proxy (`--proxies`, cloned from the train games' players) is the partner the choices are
made with, the shipped `hp_<kitchen>` proxy (the test games' players) reports. The seed shipped per kitchen
is the fine-tuned seed that cooked most with the bc proxy; `--ship` writes it as the one-seed checkpoint
`cec/shipped/<family>-<kitchen>` in place of the one there (its entry in `cec/shipped/zoo.yaml` replaced).
The hp proxies' and the cook's figures choose nothing. A choice without its figures (the bc proxy or a seed
skipped, `cec.evaluation.choice`) stops the command, exit 2, with nothing written or shipped.
"""

from __future__ import annotations

import argparse
import json
import math
import sys
from collections.abc import Callable
from pathlib import Path
from typing import Any, NamedTuple

import numpy as np

from apps.partners.tables import (
    BC,
    EPISODES,
    PROXY,
    STEPS,
    Tables,
    check_play_sizes,
    replace_entries,
    validation_proxy,
    write_atomic,
)
from cec.agents.zoo import SHIPPED_ZOO, ZooEntry, load_zoo
from cec.config import ConfigError
from cec.evaluation.choice import choose
from cec.evaluation.markdown import pm
from cec.evaluation.results import EpisodeTable
from cec.evaluation.seeds import seed_matrix
from cec.evaluation.stats import compare_crossplay_paired, sem
from cec.humans.data import KITCHENS

FINETUNE = "cec_finetune"


class Family(NamedTuple):
    """A family of fine-tuned agents (its runs' and shipped names' prefix is its key in `FAMILIES`)."""

    control: str  # the algorithm label of the shipped generalists it started from
    seeds: str  # how the tables name them
    shipped_as: str  # the algorithm label its shipped agents carry (`cec play serve --partner LABEL`)
    preset: str  # the training preset of its runs


FAMILIES = {
    "ft758m": Family("cec", "CEC seeds", "cec_finetune", "configs/train/cec_finetune_shipped.yaml"),
    "ftteach": Family(
        "cec_teacher", "kickstarted seeds", "cec_finetune_teacher", "configs/train/cec_finetune_teacher.yaml"
    ),
}


# ---------------------------------------------------------------------------------------------------------
# WHAT IS PLAYED
# ---------------------------------------------------------------------------------------------------------


def run_of(runs: Path, family: str, kitchen: str) -> Path:
    """The family's run of `kitchen`; `ConfigError` with its training command when it has no checkpoint."""
    from cec.agents.policy import resolve_checkpoint
    from cec.checkpoints import CheckpointError

    run = runs / f"{family}-{kitchen}"
    try:
        resolve_checkpoint(run)
    except CheckpointError as err:
        raise ConfigError(
            f"--runs {str(runs)!r}: no {family} run for {kitchen} ({err}); train it: cec train --config "
            f"{FAMILIES[family].preset} env.levels={kitchen} run_dir={runs} name={family}-{kitchen}, or give "
            "--runs the folder of the family's runs"
        ) from err
    return run


def zoo(kitchen: str, run: Path, bc: ZooEntry, control: str, shipped: list[ZooEntry]) -> list[ZooEntry]:
    """The kitchen's zoo: the fine-tuned seeds (the run's last checkpoint), the shipped seeds they started
    from (algorithm `control`) and the kitchen's test human proxy (as shipped), its validation proxy `bc`,
    the scripted cook and a partner that stays put."""
    from cec.agents.policy import checkpoint_seeds

    finetuned = [
        ZooEntry(f"ft_{kitchen}_s{s}", str(run.resolve()), FINETUNE, s, (kitchen,))
        for s in checkpoint_seeds(str(run))
    ]
    started_from = [e for e in shipped if e.algorithm == control or e.name == f"hp_{kitchen}"]
    scripted = [ZooEntry(name, "", scripted=name) for name in ("cook", "noop")]
    return [*finetuned, *started_from, bc, *scripted]


# ---------------------------------------------------------------------------------------------------------
# THE CHOICE AND ITS FIGURES
# ---------------------------------------------------------------------------------------------------------


def mean_se(x: np.ndarray) -> dict:
    """Mean and standard error over seeds, and the per-seed values."""
    x = np.asarray(x, np.float64)
    se = float(sem(x)) if x.size > 1 else math.nan
    return {"mean": float(np.mean(x)), "se": se, "n": int(x.size), "per_seed": [float(v) for v in x]}


def summarise(table: EpisodeTable, where: Path, kitchen: str, control: str) -> dict:
    """The fine-tuned seeds beside the seeds they started from (`control`); under the keys `finetune` and
    `cec` (the latter whichever generalists `control` names). The choices (the seed shipped, `best`) are
    refused (`ChoiceError`) when the bc proxy or a seed is missing from the table (`where`) or was skipped."""
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
            what=f"{where}: the {FINETUNE} seed shipped for {kitchen} (with the bc proxy)",
            skipped=used,
        )
    ]
    best = choose(  # the control first: it stays the choice on a tie
        {control: cec_bc, FINETUNE: ft_bc},
        what=f"{where}: the better of {control} and {FINETUNE} in {kitchen} (with the bc proxy)",
        skipped=used,
    )
    paired = compare_crossplay_paired(np.asarray(fts.matrix), np.asarray(cecs.matrix))
    ft_hp, cec_hp = m.partner_means(ft, group[PROXY]), m.partner_means(cec, group[PROXY])
    return {
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


def _fmt(d: dict) -> str:
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
    lines: list[tuple[str, Callable[[dict], str]]] = [
        ("CEC-Finetune cross-play (jackknife SE over seeds)", lambda r: _fmt(r["finetune"]["cross_play"])),
        ("CEC-Finetune self-play", lambda r: _fmt(r["finetune"]["self_play"])),
        (f"the shipped {seeds}, cross-play (the control)", lambda r: _fmt(r["cec"]["cross_play"])),
        (f"the shipped {seeds}, self-play", lambda r: _fmt(r["cec"]["self_play"])),
        (
            f"fine-tuned minus the {seeds}' cross-play, paired (95% t interval, p)",
            lambda r: "{diff:+.1f} [{ci_low:+.1f}, {ci_high:+.1f}], p = {p:.2g}".format(
                **r["finetune_vs_cec_cross_play_paired"]
            ),
        ),
        (f"CEC-Finetune with the {seeds}", lambda r: _fmt(r["finetune"]["with_cec_seeds"])),
        ("validation: CEC-Finetune with the bc proxy", lambda r: _fmt(r["finetune"]["with_bc_proxy"])),
        (f"validation: the {seeds} with the bc proxy", lambda r: _fmt(r["cec"]["with_bc_proxy"])),
        ("**test: CEC-Finetune with the hp proxy**", lambda r: _fmt(r["finetune"]["with_human_proxy"])),
        (f"**test: the {seeds} with the hp proxy**", lambda r: _fmt(r["cec"]["with_human_proxy"])),
        (f"test: fine-tuned minus the {seeds} with the hp proxy, per seed pair", _paired_proxy),
        ("control: a partner that stays put, with the proxy", lambda r: _num(r, "noop_with_human_proxy")),
        ("CEC-Finetune with the scripted cook", lambda r: _fmt(r["finetune"]["with_cook"])),
        (f"the {seeds} with the scripted cook", lambda r: _fmt(r["cec"]["with_cook"])),
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


# ---------------------------------------------------------------------------------------------------------
# THE COMMAND
# ---------------------------------------------------------------------------------------------------------


def evaluate(args: argparse.Namespace, say: Callable[[str], None]) -> list[dict]:
    """Every kitchen's table (played or read), its summary and choice; then the summary, then `--ship`."""
    family, spec = args.family, FAMILIES[args.family]
    runs, out = (Path(p.replace("<family>", family)) for p in (args.runs, args.out))
    zoo_path = Path(args.zoo)
    kitchens = args.kitchens.split(",")
    unknown = sorted(set(kitchens) - set(KITCHENS))
    if unknown:
        raise ConfigError(
            f"--kitchens: {unknown} are not classic kitchens; give some of {','.join(KITCHENS)}"
        )
    shipped = load_zoo(zoo_path)
    if args.ship:  # every run there before anything is played
        for kitchen in kitchens:
            run_of(runs, family, kitchen)
    tables = Tables(out, say)
    rows = []
    for kitchen in kitchens:

        def entries(kitchen: str = kitchen) -> list[ZooEntry]:
            bc = validation_proxy(Path(args.proxies).resolve(), kitchen)
            return zoo(kitchen, run_of(runs, family, kitchen), bc, spec.control, shipped)

        table = tables.get(kitchen, entries, kitchen, episodes=args.episodes, steps=args.max_steps)
        rows.append(summarise(table, tables.path(kitchen), kitchen, spec.control))
        say(markdown(rows[-1:], spec.seeds))
        say(f"{kitchen}: ships seed {rows[-1]['shipped_seed']}")
    write_atomic(out / "summary.json", json.dumps(rows, indent=1) + "\n")
    write_atomic(out / "summary.md", markdown(rows, spec.seeds))
    say(f"summary: {out / 'summary.md'}")
    if args.ship:
        ship(family, runs, rows, zoo_path, say)
    else:
        say("to ship: the same command with --ship; then `cec partners best --ship` for `--partner best`")
    return rows


def ship(family: str, runs: Path, rows: list[dict], zoo_path: Path, say: Callable[[str], None]) -> None:
    """Each kitchen's chosen seed as the one-seed checkpoint `<family>-<kitchen>` beside `zoo_path`, its
    entry there replaced."""
    from cec import checkpoints
    from cec.agents.policy import load_policy, resolve_checkpoint, save_policy

    entries: list[dict[str, Any]] = []
    for row in rows:
        kitchen, name = row["kitchen"], f"{family}-{row['kitchen']}"
        run = run_of(runs, family, kitchen)
        meta = checkpoints.read_meta(resolve_checkpoint(run))
        policy = load_policy(
            ZooEntry(name, str(run), FAMILIES[family].shipped_as, int(row["shipped_seed"]), (kitchen,))
        )
        saved = save_policy(
            policy,
            zoo_path.parent / name,
            config=meta["config"],
            env_steps=int(meta["env_steps"]),
            update=int(meta["update"]),
            code_version=str(meta.get("metadata", {}).get("code_version", "")),
        )
        entries.append(
            {
                "name": name,
                "algorithm": policy.algorithm,
                "seed": policy.seed,
                "checkpoint": name,
                "env": policy.env.name,
                "layout": meta["config"].get("env", {}).get("levels", ""),
                "env_steps": int(meta["env_steps"]),
                "sha256": checkpoints.read_meta(saved)["sha256"],
                "levels": [kitchen],
            }
        )
    replace_entries(zoo_path, entries)
    names = ", ".join(f"{e['name']} (seed {e['seed']})" for e in entries)
    say(f"shipped {names} into {zoo_path}; now `cec partners best --ship` chooses `--partner best` again")


def add_parser(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "finetune",
        help="per classic kitchen, the fine-tuned seed that ships (chosen with the validation proxies)",
        description=__doc__,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument(
        "--family",
        choices=FAMILIES,
        required=True,
        help="the fine-tuned agents: their runs' and shipped names' prefix (ft758m: from the CEC seeds; "
        "ftteach: from the kickstarted seeds)",
    )
    p.add_argument("--runs", default="runs/<family>", help="folder of the runs <family>-<kitchen>")
    p.add_argument(
        "--out",
        default="runs/partners/<family>",
        help="the tables (a second call reads them; delete one to play it again) and the summary",
    )
    p.add_argument("--kitchens", default=",".join(KITCHENS), help="comma-separated (default: the five)")
    p.add_argument("--episodes", type=int, default=EPISODES, help="per pairing and seat order")
    p.add_argument("--max-steps", type=int, default=STEPS, help=f"episode length (default {STEPS})")
    p.add_argument(
        "--proxies", default="runs/humans/proxies/zoo.yaml", help="`cec humans bc`'s zoo: the bc_ proxies"
    )
    p.add_argument("--zoo", default=str(SHIPPED_ZOO), help="the shipped zoo: the seeds started from, hp_")
    p.add_argument("--ship", action="store_true", help="ship each kitchen's chosen seed into --zoo's folder")
    p.set_defaults(func=_cmd_finetune)


def _cmd_finetune(args: argparse.Namespace) -> int:
    check_play_sizes(args.episodes, args.max_steps)
    evaluate(args, say=lambda m: print(m, file=sys.stderr, flush=True))
    return 0
