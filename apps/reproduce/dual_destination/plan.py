"""What `cec reproduce dual-destination` trains, and training it: per variant one `cec zoo build` spec
(IPPO, then FCP with the IPPO run as its population, then CEC, then a mode's ablations), its runs sized for
`--plan`, and the builds (`--train-only` among several processes)."""

from __future__ import annotations

import math
import sys
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, TextIO

from apps.reproduce import pipeline
from apps.reproduce.dual_destination.modes import Mode, algorithm_of
from apps.reproduce.dual_destination.paper import ABLATIONS, VARIANTS
from cec.config import ConfigError

if TYPE_CHECKING:
    from apps.zoo_build import BuildResult

ROOT = Path(__file__).resolve().parents[3]


def _variant_overrides(variant: str, algorithm: str) -> list[str]:
    if variant == "partial_obs":
        return ["env.dual_destination.partial_obs=true"]
    if variant == "multi_task":
        levels = "procedural_multi_task" if algorithm_of(algorithm) == "cec" else "multi_task"
        return ["env.dual_destination.multi_task=true", f"env.levels={levels}"]
    return []


def zoo_spec(mode: Mode, variant: str) -> dict[str, object]:
    """The `cec zoo build` spec of one variant: IPPO, then FCP (population: the IPPO run), then CEC."""
    ippo_seeds = list(mode.seeds["ippo"])
    population = (
        f"[{{run: runs/ippo-s{ippo_seeds[0]}, seeds: {ippo_seeds}, checkpoints: [first, middle, last]}}]"
    )
    extra = {
        "ippo": ["checkpoint.milestones=[0.0,0.5,1.0]"],  # FCP's early, middle and final partners
        "fcp": [f"partner.population={population}"],
    }
    entries = []
    for row in mode.rows:
        preset, overrides = _run_config(mode, variant, row, extra.get(row, []))
        entry = {"preset": preset, "seeds": list(mode.seeds[row]), "name": row, "overrides": overrides}
        entries.append(entry | ({"label": row} if row in ABLATIONS else {}))
    return {"entries": entries}


def _run_config(mode: Mode, variant: str, row: str, extra: Sequence[str] = ()) -> tuple[str, list[str]]:
    """The preset (absolute: a spec that names it works from any directory) and the overrides of one row's
    run: its budget, the variant's settings, `extra`, the mode's overrides, and an ablation's last."""
    ablation = list(ABLATIONS[row].overrides) if row in ABLATIONS else []
    budget = f"total_env_steps={mode.steps[variant][row]}"
    overrides = [budget, *_variant_overrides(variant, row), *extra, *mode.overrides, *ablation]
    return str(ROOT / mode.presets[algorithm_of(row)]), overrides


def zoo(mode: Mode, variant: str, work: Path) -> pipeline.Zoo:
    """The variant's zoo: its spec in `work/<variant>/spec.yaml`, built into `work/<variant>/zoo`."""
    return pipeline.Zoo(
        work / variant, zoo_spec(mode, variant), f"`cec reproduce dual-destination` ({mode.name}, {variant})"
    )


def plan_lines(mode: Mode, work: Path, variants: Sequence[str] = VARIANTS) -> list[pipeline.PlanLine]:
    """Every training run of `variants` (one line per row, `zoo` its variant), with the estimate from
    `mode.seconds_per_update` (NaN where not measured) and the share already trained under `work`. Writes
    each variant's zoo spec there, as training does, and so refuses (`ConfigError`) a finished run trained
    with another config."""
    lines = []
    for variant in variants:
        plan = zoo(mode, variant, work).plan()
        for i, row in enumerate(mode.rows):
            runs = [r for r in plan if r.entry == i]
            lines.append(pipeline.plan_line(row, runs, mode.seconds_per_update.get(row, math.nan), variant))
    return lines


def _build_variant(
    mode: Mode, variant: str, work: Path, *, progress: bool, log: TextIO, wait: bool
) -> BuildResult:
    """Writes the variant's zoo spec and builds the zoo (resuming, skipping finished runs); returns
    `build_zoo`'s result. Raises `ConfigError` when the build was interrupted (run the command again)."""
    result = zoo(mode, variant, work).build(progress=progress, log=log, wait=wait)
    if result.interrupted:
        raise ConfigError(f"training of {variant} was interrupted; run the same command again to continue")
    return result


def train_variant(
    mode: Mode, variant: str, work: Path, *, progress: bool, log: TextIO
) -> tuple[Path, tuple[str, ...]]:
    """Trains the variant's zoo, waiting for runs other processes train; returns the manifest and the runs
    found finished."""
    result = _build_variant(mode, variant, work, progress=progress, log=log, wait=True)
    assert result.manifest is not None  # not interrupted, and it waited for every run
    return result.manifest, result.skipped


def train_only(
    mode: Mode, work: Path, variants: Sequence[str], *, progress: bool = True, log: TextIO = sys.stderr
) -> dict[str, Path]:
    """Trains `variants` (step 1 alone, as `--train-only`); returns each one's zoo manifest. A variant whose
    remaining runs other processes train is passed over until the later variants are done, so processes
    sharing a reproduction keep their cores busy instead of waiting on each other's runs."""
    manifests = {}
    for v in variants:
        result = _build_variant(mode, v, work, progress=progress, log=log, wait=False)
        if result.manifest is not None:
            manifests[v] = result.manifest
        else:
            pipeline.note(
                log, f"{v}: {', '.join(result.left)} trained by other processes; back to it at the end"
            )
    for v in variants:
        if v not in manifests:  # the rest is done: wait for the others' runs (and train any left over)
            manifests[v] = train_variant(mode, v, work, progress=progress, log=log)[0]
    return {v: manifests[v] for v in variants}
