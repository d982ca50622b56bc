"""What `cec reproduce overcooked` trains: one `cec zoo build` spec (CEC and CEC-E3T on the generator, per
kitchen IPPO, FCP, E3T and CEC-Finetune), its runs sized for `--plan`, and the runs a work folder trained.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from pathlib import Path
from typing import Any

from apps.reproduce import pipeline
from apps.reproduce.overcooked.modes import ROOT, Mode
from cec.evaluation.curves import metrics_file


def run_name(algorithm: str, kitchen: str = "") -> str:
    return f"{algorithm}_{kitchen}" if kitchen else algorithm


def zoo_spec(mode: Mode) -> dict[str, Any]:
    """CEC first (the runs CEC-Finetune starts from) and CEC-E3T (the paper's appendix: CEC's kitchens with
    E3T's partner, epsilon 0.5 as the paper sets it there), then per kitchen IPPO, E3T, CEC-Finetune (one
    run per CEC seed) and FCP (its population: that kitchen's IPPO run): a kitchen's line-ups are played
    one algorithm at a time, FCP's last (`evaluate.lineups`), so a builder free before FCP can start takes
    the runs the earlier line-ups wait for."""
    preset = str(ROOT / mode.preset)  # absolute: the spec works from any directory
    common = list(mode.overrides)
    cec_seeds = list(mode.seeds["cec"])

    def entry(algo: str, seeds: Sequence[int], overrides: list[str], kitchen: str = "") -> dict[str, object]:
        return {
            "preset": preset,
            "seeds": list(seeds),
            "name": run_name(algo, kitchen),
            "overrides": [
                f"total_env_steps={mode.steps[algo]}",
                *overrides,
                *mode.tuned.get(algo, ()),
                *common,
            ],
        }

    cec_e3t = ["algorithm=cec_e3t", "partner.kind=e3t", "partner.epsilon=0.5", "partner.predict_partner=10"]
    entries = [entry("cec", cec_seeds, []), entry("cec_e3t", mode.seeds["cec_e3t"], cec_e3t)]
    for k in mode.kitchens:
        single = [f"env.levels={k}"]
        ippo = mode.seeds["ippo"]
        population = (
            f"[{{run: runs/{run_name('ippo', k)}-s{ippo[0]}, seeds: {list(ippo)}, "
            "checkpoints: [first, middle, last]}]"
        )
        entries += [
            entry("ippo", ippo, ["algorithm=ippo", *single, "checkpoint.milestones=[0.0,0.5,1.0]"], k),
            entry("e3t", mode.seeds["e3t"], ["algorithm=e3t", *single, "partner.kind=e3t",
                                             "partner.epsilon=0.55", "partner.predict_partner=10"], k),
        ]  # fmt: skip
        for cec_seed, ft_seed in zip(cec_seeds, mode.seeds["cec_finetune"], strict=True):
            start = [f"init_from=runs/cec-s{cec_seeds[0]}", f"init_from_seed={cec_seed}"]
            finetune = ["algorithm=cec_finetune", *start, *single, *mode.finetune]
            entries.append(entry("cec_finetune", [ft_seed], finetune, k))
        entries.append(entry("fcp", mode.seeds["fcp"], ["algorithm=fcp", *single, "partner.kind=fcp",
                                                        f"partner.population={population}"], k))  # fmt: skip
    return {"entries": entries}


def zoo(mode: Mode, work: Path) -> pipeline.Zoo:
    """The mode's zoo: its spec in `work/spec.yaml`, built into `work/zoo`."""
    return pipeline.Zoo(work, zoo_spec(mode), f"`cec reproduce overcooked` ({mode.name})")


def generalist_run(mode: Mode, work: Path, algorithm: str) -> Path:
    """The run directory of a generator-trained algorithm's seeds in the work folder."""
    return work / "zoo" / "runs" / f"{run_name(algorithm)}-s{mode.seeds[algorithm][0]}"


def trained_runs(mode: Mode, work: Path) -> tuple[list[pipeline.PlanLine], list[str]]:
    """The runs of the mode's plan as the work folder trained them, each read from its own `config.yaml`
    (a folder trained by an earlier version of the mode reports the steps it trained, not the mode's
    present ones), and the runs it lacks (without metrics: planning a run makes its folder)."""
    from cec.config import load_config
    from cec.training.config import TrainConfig

    runs, trained, missing = work / "zoo" / "runs", [], []
    for e in zoo_spec(mode)["entries"]:
        run = f"{e['name']}-s{e['seeds'][0]}"
        if not metrics_file(runs / run).is_file():
            missing.append(run)
            continue
        cfg = load_config(TrainConfig, runs / run / "config.yaml")
        size = (cfg.num_seeds, cfg.total_env_steps, cfg.num_updates)
        trained.append(pipeline.PlanLine(run, *size, math.nan, 1.0, algorithm=cfg.algorithm))
    return trained, missing


def plan_lines(mode: Mode, work: Path) -> list[pipeline.PlanLine]:
    """Every run of the mode's zoo, with the estimate from `mode.seconds_per_update` (x seeds) and the
    share of it already trained under `work`."""
    return [
        pipeline.plan_line(r.config.run_name, [r], mode.seconds_per_update.get(r.config.algorithm, math.nan))
        for r in zoo(mode, work).plan()
    ]
