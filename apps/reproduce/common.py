"""What both reproductions share: a result table reused while what it depends on is unchanged, and how long
playing it took."""

from __future__ import annotations

import json
import math
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any, TextIO

from apps.machine import log_line
from cec.evaluation.results import read_csv, write_csv


def cached_table(
    folder: Path, key: dict[str, Any], play: Callable[[], Any], *, label: str, log: TextIO
) -> Any:
    """The result table `folder/results.csv` an earlier invocation wrote when `key` (what it depends on,
    stored beside it in `results.key.json`) is unchanged, else `play()`'s table, written there. The key is
    written last, so an invocation interrupted while playing plays again."""
    results, key_file = folder / "results.csv", folder / "results.key.json"
    key = json.loads(json.dumps(key))  # as stored: tuples as lists
    if results.exists() and key_file.exists() and json.loads(key_file.read_text()) == key:
        log_line(log, "reproduce", f"{label}cross-play results found ({results}); not played again")
        return read_csv(results)
    log_line(log, "reproduce", f"{label}cross-play")
    key_file.unlink(missing_ok=True)
    t0 = time.perf_counter()
    table = play()
    write_csv(table, results)
    (folder / PLAY_TIME_FILE).write_text(json.dumps({"seconds": time.perf_counter() - t0}) + "\n")
    key_file.write_text(json.dumps(key, indent=1) + "\n")
    return table


PLAY_TIME_FILE = "results.time.json"


def play_seconds(folder: Path) -> float:
    """How long playing `folder/results.csv` took when `cached_table` played it (NaN if not recorded:
    a table played before the time was kept)."""
    try:
        return float(json.loads((folder / PLAY_TIME_FILE).read_text())["seconds"])
    except (OSError, ValueError, KeyError, TypeError):
        return math.nan
