"""The ledger of test-set reads: every time a test set was played, when, at which commit, and what played.

Validation chooses, test reports (DESIGN.md rule 13): a test set is read once per release, after the choice.
The ledger keeps that honest and visible. It lives with the sets (`data/test_reads.csv`), one row per read:

    date,commit,set,what,command
    2026-12-06,427ae9c,test,"the kickstarted seeds teach21m-s400..403, 1 episode per pairing and kitchen",...

`cec release` appends its row when it plays a test set (and reads the ledger to report how often the set
was read before); the rows before the service's first release were reconstructed from the commits that
added or changed a test-set table.
"""

from __future__ import annotations

import csv
import datetime
import io
import os
from pathlib import Path
from typing import NamedTuple

from cec.config import ConfigError

LEDGER = Path(__file__).with_name("data") / "test_reads.csv"
COLUMNS = ("date", "commit", "set", "what", "command")
#: The ledger is a few kB; a file larger than this is not a ledger.
MAX_BYTES = 1 << 20
#: The longest text kept in one field (a command line, a description).
MAX_FIELD = 500


class Read(NamedTuple):
    """One read of a test set."""

    date: str
    commit: str
    set: str
    what: str
    command: str


def reads(path: Path = LEDGER) -> list[Read]:
    """The ledger's rows, oldest first (none when it does not exist); `ConfigError` naming the file and the
    line for one that is not a ledger."""
    return _rows(_text(path), path)


def _text(path: Path) -> str:
    """The ledger's text ('' when it does not exist), read once and at most `MAX_BYTES` of it."""
    if not path.exists():
        return ""
    with path.open("rb") as f:
        data = f.read(MAX_BYTES + 1)
    if len(data) > MAX_BYTES:
        raise ConfigError(f"{path} is over {MAX_BYTES} bytes; it is not a test-set ledger")
    return data.decode("utf-8", errors="replace")


def _rows(text: str, path: Path) -> list[Read]:
    """The rows of a ledger's text (none for ''), or `ConfigError` naming `path` and the line."""
    if not text and not path.exists():
        return []
    rows = list(csv.reader(io.StringIO(text)))
    if not rows or tuple(rows[0]) != COLUMNS:
        raise ConfigError(f"{path}: line 1 must be the header {','.join(COLUMNS)}")
    out = []
    for line, row in enumerate(rows[1:], start=2):
        if len(row) != len(COLUMNS):
            raise ConfigError(f"{path}: line {line} has {len(row)} fields, not {len(COLUMNS)}")
        out.append(Read(*row))
    return out


def times_read(test_set: str, path: Path = LEDGER) -> int:
    """How often `test_set` was read before (rows of that set)."""
    return sum(r.set == test_set for r in reads(path))


def record(test_set: str, what: str, command: str, commit: str, path: Path = LEDGER) -> Read:
    """Appends one read (today's date) and returns it. The rows before it are kept as they were written,
    byte for byte (hand-written ones with their own quoting), once they were checked; the ledger is
    written whole to a temporary file and renamed, so that a full disk never leaves it torn."""
    clip = lambda text: " ".join(str(text).split())[:MAX_FIELD]  # noqa: E731 - one line, bounded
    row = Read(datetime.date.today().isoformat(), clip(commit), clip(test_set), clip(what), clip(command))
    kept = _text(path)
    _rows(kept, path)  # a ledger, or ConfigError before anything is written
    out = io.StringIO()
    out.write(kept if not kept or kept.endswith("\n") else kept + "\n")
    writer = csv.writer(out, lineterminator="\n")
    if not kept:
        writer.writerow(COLUMNS)
    writer.writerow(row)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(f".{path.name}.{os.getpid()}.tmp")
    tmp.write_text(out.getvalue(), encoding="utf-8")
    tmp.replace(path)
    return row
