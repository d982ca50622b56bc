"""What both reproductions share: a result table reused while what it depends on is unchanged, how long
playing it took, and how long a training run took."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from apps.machine import log_line
from cec.evaluation.curves import metrics_file, read_metrics_csv
from cec.evaluation.results import COMPRESSED, read_csv, stored, write_csv


def cached_table(
    folder: Path, key: dict[str, Any], play: Callable[[], Any], *, label: str, log: TextIO
) -> Any:
    """The result table `folder/results.csv` an earlier invocation wrote when `key` (what it depends on,
    stored beside it in `results.key.json`) is unchanged, else `play()`'s table, written there with the time
    `play()` took (`PLAY_TIME_FILE`) unless it recorded its own (a table of cached parts: the parts' times).
    The key is written last, so an invocation interrupted while playing plays again."""
    results, key_file = results_file(folder), folder / "results.key.json"
    key = json.loads(json.dumps(key))  # as stored: tuples as lists
    if results.exists() and key_file.exists() and json.loads(key_file.read_text()) == key:
        log_line(log, "reproduce", f"{label}cross-play results found ({results}); not played again")
        return read_csv(results)
    log_line(log, "reproduce", f"{label}cross-play")
    key_file.unlink(missing_ok=True)
    for suffix in COMPRESSED:  # a committed table the new one replaces
        (folder / f"results.csv{suffix}").unlink(missing_ok=True)
    time_file = folder / PLAY_TIME_FILE
    time_file.unlink(missing_ok=True)
    t0 = time.perf_counter()
    table = play()
    write_csv(table, folder / "results.csv")
    if not time_file.exists():
        time_file.write_text(json.dumps({"seconds": time.perf_counter() - t0}) + "\n")
    key_file.write_text(json.dumps(key, indent=1) + "\n")
    return table


def results_file(folder: Path) -> Path:
    """`folder`'s cross-play table: `results.csv`, or `results.csv.gz` or `.bz2` where only that is there (a
    work folder committed with its tables compressed; read as it is)."""
    return stored(folder / "results.csv")


PLAY_TIME_FILE = "results.time.json"


def play_seconds(folder: Path) -> float:
    """How long playing `folder/results.csv` took when `cached_table` played it (NaN if not recorded:
    a table played before the time was kept)."""
    try:
        return float(json.loads((folder / PLAY_TIME_FILE).read_text())["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return math.nan


def train_seconds(rows: list[dict[str, Any]]) -> float:
    """The training time a run's metrics rows record, also for a run an invocation found finished: each
    update's env steps per seed times the run's seeds, over the update's env steps/s (of all its seeds);
    compilation and checkpointing not included. 0 for no rows."""
    if not rows:
        return 0.0
    seeds = len({r["seed"] for r in rows})
    ordered = sorted({r["update"]: r for r in rows}.values(), key=lambda r: r["update"])
    sizes = np.diff([0, *(r["env_steps"] for r in ordered)])
    return float(
        sum(
            seeds * size / max(r.get("env_steps_per_s") or math.inf, 1e-9)
            for size, r in zip(sizes, ordered, strict=True)
        )
    )


def read_metrics(run_dir: Path) -> list[dict[str, Any]]:
    """A run's `metrics.jsonl` rows, or where a committed run folder kept only its `metrics.csv` (or
    `metrics.csv.gz`), that table's rows; [] when it has none yet."""
    path = run_dir / "metrics.jsonl"
    if path.is_file():
        return [json.loads(line) for line in path.read_text().splitlines() if line.strip()]
    return read_metrics_csv(run_dir) if metrics_file(run_dir).is_file() else []
