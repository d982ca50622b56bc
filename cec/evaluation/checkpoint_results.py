"""One checkpoint's evaluation results: the stored summary of a part and the run's result table.

The evaluator (`services.evaluator`) scores a checkpoint in *parts*, one per (partner group, level set).
`summarize` turns a part's episodes into the summary it stores (the means, the seed-level standard error and
the per-seed and per-partner breakdowns that `cec report` computes from the same table); `ResultFiles`
stages each part's episodes under the run directory and merges them into the checkpoint's long table
(`<results_dir>/<run>/eval/update_<N>.csv`, the format of `cec.evaluation.results`) without repeated
episodes (`dedupe`). Pure data and files: no store, no transport.
"""

from __future__ import annotations

import csv
import io
import logging
import math
import shutil
from collections.abc import Iterable
from pathlib import Path
from typing import Any

import numpy as np

from cec.evaluation.results import EpisodeTable, ResultsError, read_csv, write_csv
from cec.evaluation.seeds import partner_means, seed_matrix
from cec.evaluation.stats import crossplay_estimate, sem

log = logging.getLogger("cec.evaluation")

#: Summary statistics stored per part, as `<metric>_mean` (see `summarize`).
SUMMARY_METRICS = ("return", "score", "deliveries", "collisions", "shaped_return")
#: What a part pairs the checkpoint's seeds with: zoo partners, each seed itself, or each other seed.
KINDS = ("partners", "self_play", "cross_play")
#: The run's training record (`<run>/eval/record.csv`): one row per scored checkpoint, partner group and
#: level set, what `cec status` shows during and after a run and what a release is chosen from.
RECORD = "record.csv"
RECORD_COLUMNS = (
    "update",
    "env_steps",
    "partner_group",
    "level_set",
    "return_mean",
    "return_sem",
    "episodes",
)


def _number(x: float) -> float | None:
    x = float(x)
    return x if math.isfinite(x) else None


def summarize(part: EpisodeTable, checkpoint_label: str, *, kind: str = "partners") -> dict[str, Any]:
    """The stored result of one part: the checkpoint's seeds with one group's partners (`partners`), each
    with itself (`self_play`) or each with every other seed of the checkpoint (`cross_play`: the seeds of
    one run never trained together, so this is the README's cross-play protocol within a run).

    Scores aggregate as `cec report` does: per pair (seed, partner) and level, the mean over episodes and
    seat orders; per pair, the mean over levels; `<metric>_mean` is the mean over pairs and `return_sem`
    its standard error over the checkpoint's seeds (each seed's mean over its partners; null with one
    seed; for `cross_play` the leave-one-seed-out jackknife, which counts that two seeds share a pair, null
    under three seeds). `score` is the return, or for Dual Destination the paper's normalised return /
    (2 x episode length). `per_seed` and `per_partner` (`algorithm/s<seed>`) break the mean return down.
    A part with no playable partner has `episodes` 0 and null scores.
    """
    if kind not in KINDS:
        raise ValueError(f"kind {kind!r} is not one of {KINDS}")
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
        within = m.scores[np.ix_(mine, mine)]
        if kind == "self_play":
            block = within.diagonal()[:, None]
        elif kind == "cross_play":
            block = np.where(np.eye(len(mine), dtype=bool), np.nan, within)
        else:
            block = m.scores[np.ix_(mine, others)]
        values = block[~np.isnan(block)]
        out[f"{metric}_mean"] = _number(values.mean()) if values.size else None
        if metric == "return":
            out["pairs"] = int(values.size)
            per_seed = partner_means(block)  # seeds are the units: pairs share a seed and a partner
            finite = per_seed[np.isfinite(per_seed)]
            spread = crossplay_estimate(block).se if kind == "cross_play" else sem(finite)
            out["return_sem"] = _number(spread)
            out["per_seed"] = {
                str(m.policies[i].seed): _number(v) for i, v in zip(mine, per_seed, strict=True)
            }
            out["per_partner"] = (
                {m.policies[j].label(): _number(np.nanmean(block[:, k])) for k, j in enumerate(others)}
                if kind == "partners"
                else {}
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

    @property
    def record_path(self) -> Path:
        return self.final.parent / RECORD

    def record(self, update: int, env_steps: int, results: Iterable[tuple[str, str, dict[str, Any]]]) -> Path:
        """Puts one checkpoint's summaries (partner group, level set, stored metrics) into the run's record
        (any earlier rows of the same update replaced; rows kept in update order), written to a temporary
        file and renamed. An unreadable record is started again from this checkpoint (and logged)."""
        path = self.record_path
        rows = [r for r in read_record(path) if r["update"] != update]
        for group, level_set, metrics in results:
            rows.append(
                {
                    "update": update,
                    "env_steps": env_steps,
                    "partner_group": group,
                    "level_set": level_set,
                    "return_mean": metrics.get("return_mean"),
                    "return_sem": metrics.get("return_sem"),
                    "episodes": metrics.get("episodes", 0),
                }
            )
        rows.sort(key=lambda r: (r["update"], r["partner_group"], r["level_set"]))
        out = io.StringIO()
        writer = csv.DictWriter(out, RECORD_COLUMNS, lineterminator="\n")
        writer.writeheader()
        writer.writerows({k: ("" if r[k] is None else r[k]) for k in RECORD_COLUMNS} for r in rows)
        path.parent.mkdir(parents=True, exist_ok=True)
        tmp = path.with_name(path.name + ".tmp")
        tmp.write_text(out.getvalue())
        tmp.replace(path)
        return path

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


def parse_record(text: str) -> list[dict[str, Any]]:
    """The rows of a training record's text (`RECORD_COLUMNS`; numbers parsed, a blank score None); rows
    that do not parse are left out."""
    rows = []
    for raw in csv.DictReader(io.StringIO(text)):
        try:
            rows.append(
                {
                    "update": int(raw["update"]),
                    "env_steps": int(raw["env_steps"]),
                    "partner_group": str(raw["partner_group"]),
                    "level_set": str(raw["level_set"]),
                    "return_mean": _optional(raw["return_mean"]),
                    "return_sem": _optional(raw["return_sem"]),
                    "episodes": int(raw["episodes"]),
                }
            )
        except (KeyError, TypeError, ValueError):
            continue
    return rows


def record_summary(rows: list[dict[str, Any]]) -> dict[str, Any]:
    """A training record's rows as `cec status` shows them: how many checkpoints were scored, the newest
    one's rows, and per `<partner group>|<level set>` its first score ([update, return]); {} for none."""
    if not rows:
        return {}
    last = max(r["update"] for r in rows)
    first: dict[str, Any] = {}
    for r in sorted(rows, key=lambda r: r["update"]):
        if r["return_mean"] is not None:
            first.setdefault(f"{r['partner_group']}|{r['level_set']}", [r["update"], r["return_mean"]])
    return {
        "checkpoints": len({r["update"] for r in rows}),
        "latest_update": last,
        "latest": [r for r in rows if r["update"] == last],
        "first": first,
    }


def read_record(path: Path, max_bytes: int = 16 << 20) -> list[dict[str, Any]]:
    """The rows of the training record at `path` (none when it is missing or unreadable; read bounded)."""
    try:
        with path.open("rb") as f:
            data = f.read(max_bytes + 1)
    except OSError:
        return []
    if len(data) > max_bytes:
        log.warning("training record %s is over %d bytes; starting it again", path, max_bytes)
        return []
    return parse_record(data.decode("utf-8", errors="replace"))


def _optional(text: str | None) -> float | None:
    if text is None or not text.strip():
        return None
    value = float(text)
    return value if math.isfinite(value) else None
