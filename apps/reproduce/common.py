"""What both reproductions share: a result table reused while what it depends on is unchanged."""

from __future__ import annotations

import json
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
    table = play()
    write_csv(table, results)
    key_file.write_text(json.dumps(key, indent=1) + "\n")
    return table
