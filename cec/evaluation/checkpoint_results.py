"""One checkpoint's evaluation results: the stored summary of a part and the run's result table.

The evaluator (`services.evaluator`) scores a checkpoint in *parts*, one per (partner group, level set).
`summarize` turns a part's episodes into the summary it stores (the means, the seed-level standard error and
the per-seed and per-partner breakdowns that `cec report` computes from the same table); `ResultFiles`
stages each part's episodes under the run directory and merges them into the checkpoint's long table
(`<results_dir>/<run>/eval/update_<N>.csv`, the format of `cec.evaluation.results`) without repeated
episodes (`dedupe`). Pure data and files: no store, no transport.
"""

from __future__ import annotations

import logging
import math
import shutil
from pathlib import Path
from typing import Any

import numpy as np

from cec.evaluation.results import EpisodeTable, ResultsError, read_csv, write_csv
from cec.evaluation.seeds import partner_means, seed_matrix
from cec.evaluation.stats import sem

log = logging.getLogger("cec.evaluation")

#: Summary statistics stored per part, as `<metric>_mean` (see `summarize`).
SUMMARY_METRICS = ("return", "score", "deliveries", "collisions", "shaped_return")


def _number(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def summarize(part: EpisodeTable, checkpoint_label: str, *, self_play: bool) -> dict[str, Any]:
    """The stored result of one part: the checkpoint's seeds with themselves or with one group's partners.

    Scores aggregate as `cec report` does: per pair (seed, partner) and level, the mean over episodes and
    seat orders; per pair, the mean over levels; `<metric>_mean` is the mean over pairs and `return_sem`
    its standard error over the checkpoint's seeds (each seed's mean over its partners; null with one
    seed). `score` is the return, or for Dual Destination the paper's normalised return / (2 x episode
    length). `per_seed` and `per_partner` (`algorithm/s<seed>`) break the
    mean return down. A part with no playable partner has `episodes` 0 and null scores.
    """
    out: dict[str, Any] = {
        "episodes": len(part),
        "partners": sorted({str(n) for n in part.policy_b} - {str(n) for n in part.policy_a}),
        "levels": sorted({str(n) for n in part.level}),
        "skipped": [{"name": s.name, "reason": s.reason} for s in part.skipped],
    }
    if len(part) == 0:
        out.update({f"{m}_mean": None for m in SUMMARY_METRICS})
        out.update(return_sem=None, pairs=0, per_seed={}, per_partner={})
        return out
    out.update(env=str(part.env[0]), episode_steps=int(part.episode_steps[0]), actions=str(part.actions[0]))
    for metric in SUMMARY_METRICS:
        m = seed_matrix(part, metric=metric)
        mine = m.indices(checkpoint_label)
        others = [j for j in range(len(m.policies)) if j not in mine]
        block = (
            m.scores[np.ix_(mine, mine)].diagonal()[:, None] if self_play else m.scores[np.ix_(mine, others)]
        )
        values = block[~np.isnan(block)]
        out[f"{metric}_mean"] = _number(values.mean())
        if metric == "return":
            out["pairs"] = int(values.size)
            per_seed = partner_means(block)  # seeds are the units: pairs share a seed and a partner
            out["return_sem"] = _number(sem(per_seed[np.isfinite(per_seed)]))
            out["per_seed"] = {
                str(m.policies[i].seed): _number(v) for i, v in zip(mine, per_seed, strict=True)
            }
            out["per_partner"] = (
                {}
                if self_play
                else {m.policies[j].label(): _number(np.nanmean(block[:, k])) for k, j in enumerate(others)}
            )
    return out


def dedupe(table: EpisodeTable) -> EpisodeTable:
    """The table without repeated episodes (same pairing, level, seat and episode): the last copy wins."""
    keys = list(zip(table.policy_a, table.policy_b, table.level, table.seat, table.episode, strict=True))
    seen: set[tuple] = set()
    keep = np.zeros(len(keys), bool)
    for i in range(len(keys) - 1, -1, -1):
        if keys[i] not in seen:
            seen.add(keys[i])
            keep[i] = True
    return table.select(keep)


class ResultFiles:
    """One checkpoint's result table in the run directory, built part by part.

    Parts are staged in `<run>/eval/.parts/update_<N>/<level_set>/<group>.csv`; `finish()` merges them
    (and an earlier table, if any) into `<run>/eval/update_<N>.csv` without repeated episodes, then removes
    the staging folder. Every file is written to a temporary name and renamed.

    Args:
        results_dir: the folder holding one folder per run.
        run_id: the checkpoint's run (a `/` in it becomes `_`; a leading `.` gets a `_` before it).
        update: the checkpoint's update number (`N`).
    """

    def __init__(self, results_dir: str | Path, run_id: str, update: int) -> None:
        run = run_id.replace("/", "_")
        run = "_" + run if run.startswith(".") else run
        base = Path(results_dir) / run / "eval"
        self.final = base / f"update_{update:09d}.csv"
        self.staging = base / ".parts" / f"update_{update:09d}"

    def part(self, group: str, level_set: str) -> Path:
        return self.staging / level_set / f"{group}.csv"

    def needs_rows(self, group: str, level_set: str) -> bool:
        """Whether the part's episodes are in no file yet."""
        return not self.final.exists() and not self.part(group, level_set).exists()

    def write_part(self, group: str, level_set: str, table: EpisodeTable) -> None:
        write_csv(table, self.part(group, level_set))

    def finish(self) -> Path:
        tables = []
        if self.final.exists():  # an earlier table of this checkpoint (its results were lost from Redis)
            try:
                tables.append(read_csv(self.final))
            except ResultsError as err:
                log.warning("replacing the unreadable result table %s: %s", self.final, err)
        tables += [read_csv(p) for p in sorted(self.staging.glob("*/*.csv"))]
        write_csv(dedupe(EpisodeTable.concat(tables)), self.final)
        shutil.rmtree(self.staging, ignore_errors=True)
        parts = self.staging.parent
        if parts.is_dir() and not any(parts.iterdir()):
            parts.rmdir()
        return self.final
