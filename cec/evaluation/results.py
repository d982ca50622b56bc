"""The one canonical cross-play result table: one row per episode played, in long format, saved as CSV.

Every analysis (`cec report`) is derived from this table. Columns, in file order:

    policy_a, algorithm_a, seed_a   the row's first policy (zoo entry name, algorithm label, seed)
    policy_b, algorithm_b, seed_b   its partner
    level                           level name (classic kitchen, generated_NNN, or a Dual Destination task)
    seat                            the seat policy A played (0 or 1; the partner played the other)
    episode                         episode index within (pairing, level, seat); same index = same keys
    return                          team (sparse) return of the episode
    deliveries                      Overcooked: soups delivered; Dual Destination: steps on a goal pair
    collisions                      steps on which a move was cancelled by the other agent
    shaped_return                   shaped return of both seats, unscaled (0 in Dual Destination)
    env, episode_steps, actions     the game, the episode length, `sampled` or `greedy`
    status, reason                  `ok`; or `skipped` with the reason for a zoo entry that could not be
                                    evaluated (one row naming the entry; the episode columns empty)

A pairing of two different policies is played in both seat orders (`seat` 0 and 1); self-play (A = B) is
one game, recorded with `seat` 0 (with common random numbers the swapped order is the same game).
A table committed compressed (`results.csv.gz` or `.bz2`) is read as it is (`stored` finds it).
"""

from __future__ import annotations

import bz2
import csv
import gzip
import math
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, TextIO

import numpy as np

from cec.agents.zoo import SkippedEntry

COLUMNS = (
    "policy_a",
    "algorithm_a",
    "seed_a",
    "policy_b",
    "algorithm_b",
    "seed_b",
    "level",
    "seat",
    "episode",
    "return",
    "deliveries",
    "collisions",
    "shaped_return",
    "env",
    "episode_steps",
    "actions",
    "status",
    "reason",
)
_STR = ("policy_a", "algorithm_a", "policy_b", "algorithm_b", "level", "env", "actions")
_INT = ("seed_a", "seed_b", "seat", "episode", "episode_steps")
_FLOAT = ("return", "deliveries", "collisions", "shaped_return")


class ResultsError(ValueError):
    """A results file is missing, malformed or mixes incompatible runs."""


@dataclass(frozen=True)
class EpisodeTable:
    """Played episodes as columns (numpy arrays of equal length N), plus the skipped zoo entries.

    String columns are object arrays; `seed_*`, `seat`, `episode`, `episode_steps` int64; the outcome
    columns float64. See the module docstring for their meaning.
    """

    policy_a: np.ndarray
    algorithm_a: np.ndarray
    seed_a: np.ndarray
    policy_b: np.ndarray
    algorithm_b: np.ndarray
    seed_b: np.ndarray
    level: np.ndarray
    seat: np.ndarray
    episode: np.ndarray
    returns: np.ndarray
    deliveries: np.ndarray
    collisions: np.ndarray
    shaped_return: np.ndarray
    env: np.ndarray
    episode_steps: np.ndarray
    actions: np.ndarray
    skipped: tuple[SkippedEntry, ...] = ()

    def __len__(self) -> int:
        return len(self.returns)

    def select(self, mask: np.ndarray) -> EpisodeTable:
        """The rows where `mask` (bool[N]) is set (skipped entries kept)."""
        cols = {name: getattr(self, name)[mask] for name in ARRAY_FIELDS}
        return EpisodeTable(**cols, skipped=self.skipped)

    @staticmethod
    def concat(tables: Sequence[EpisodeTable]) -> EpisodeTable:
        """All rows of `tables`, in order; skipped entries merged (each name once)."""
        if not tables:
            return empty_table()
        cols = {name: np.concatenate([getattr(t, name) for t in tables]) for name in ARRAY_FIELDS}
        seen: dict[str, SkippedEntry] = {}
        for t in tables:
            for s in t.skipped:
                seen.setdefault(s.name, s)
        return EpisodeTable(**cols, skipped=tuple(seen.values()))


#: EpisodeTable's array attributes: the columns (with `return` spelled `returns`), bar the status columns;
#: what a producer of rows fills (`make_table`).
ARRAY_FIELDS = tuple("returns" if c == "return" else c for c in COLUMNS if c not in ("status", "reason"))


def _column_of(field: str) -> str:
    return "return" if field == "returns" else field


def make_table(columns: Mapping[str, Iterable], skipped: Sequence[SkippedEntry] = ()) -> EpisodeTable:
    """Builds a table from per-field sequences (keys as `EpisodeTable` fields), with the right dtypes."""
    cols: dict[str, np.ndarray] = {}
    for field in ARRAY_FIELDS:
        col = _column_of(field)
        values = list(columns[field])
        if col in _STR:
            cols[field] = np.asarray(values, dtype=object).reshape(-1)
        elif col in _INT:
            cols[field] = np.asarray(values, dtype=np.int64).reshape(-1)
        else:
            cols[field] = np.asarray(values, dtype=np.float64).reshape(-1)
    lengths = {len(v) for v in cols.values()}
    if len(lengths) > 1:
        raise ValueError(f"result columns have different lengths: {sorted(lengths)}")
    return EpisodeTable(**cols, skipped=tuple(skipped))


def empty_table(skipped: Sequence[SkippedEntry] = ()) -> EpisodeTable:
    return make_table({f: [] for f in ARRAY_FIELDS}, skipped)


def write_csv(table: EpisodeTable, path: str | Path) -> Path:
    """Writes the table (episodes, then one row per skipped entry) to `path` as CSV."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp")
    with open(tmp, "w", newline="") as f:
        writer = csv.writer(f)
        writer.writerow(COLUMNS)
        arrays = [getattr(table, field) for field in ARRAY_FIELDS]
        for i in range(len(table)):
            row = [_fmt(a[i]) for a in arrays]
            writer.writerow([*row, "ok", ""])
        for s in table.skipped:
            blank = [""] * (len(COLUMNS) - 5)
            writer.writerow([s.name, s.algorithm, s.seed, *blank, "skipped", s.reason])
    tmp.replace(path)
    return path


def _fmt(x: object) -> object:
    if isinstance(x, float | np.floating):
        v = float(x)
        return repr(int(v)) if v.is_integer() else repr(v)
    return x


# how a file committed compressed is opened, by its suffix
COMPRESSED: dict[str, Callable[..., Any]] = {".gz": gzip.open, ".bz2": bz2.open}


def stored(path: str | Path) -> Path:
    """`path`, or `path` + `.gz` or `.bz2` where only that is there: a file committed compressed (a large
    table, a long run's metrics) is read as it is."""
    plain = Path(path)
    if plain.is_file():
        return plain
    packed = (plain.with_name(plain.name + suffix) for suffix in COMPRESSED)
    return next((p for p in packed if p.is_file()), plain)


def open_text(path: Path) -> TextIO:
    """`path` opened for reading text, decompressed where its name ends `.gz` or `.bz2`."""
    unpack = COMPRESSED.get(path.suffix)
    return unpack(path, "rt", newline="") if unpack else open(path, newline="")


def read_csv(paths: str | Path | Sequence[str | Path]) -> EpisodeTable:
    """Reads one or more results files (as `write_csv` writes them, or as `.gz`, `.bz2`) into one table.

    Raises `ResultsError` naming the file and the problem when a file is missing, cannot be decompressed,
    lacks a column or holds a value of the wrong type.
    """
    if isinstance(paths, str | Path):
        paths = [paths]
    tables = [_read_one(Path(p)) for p in paths]
    return EpisodeTable.concat(tables)


def _read_one(path: Path) -> EpisodeTable:
    if not path.is_file():
        raise ResultsError(f"results file {str(path)!r} does not exist; write one with `cec eval`")
    try:
        with open_text(path) as f:
            return _parse(path, csv.DictReader(f))
    except (OSError, EOFError) as err:  # gzip.BadGzipFile, bz2's bad data: OSError; a cut-off stream EOFError
        raise ResultsError(f"{path} cannot be read as a results file: {err}") from err


def _parse(path: Path, reader: csv.DictReader) -> EpisodeTable:
    cols: dict[str, list] = {f: [] for f in ARRAY_FIELDS}
    skipped: list[SkippedEntry] = []
    missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise ResultsError(
            f"{path} is not a cross-play results file: missing column(s) {missing} "
            f"(expected the columns of `cec eval`: {', '.join(COLUMNS)})"
        )
    for line, row in enumerate(reader, start=2):
        try:
            if row["status"] == "skipped":
                seed = int(row["seed_a"]) if row["seed_a"] else -1
                skipped.append(SkippedEntry(row["policy_a"], row["algorithm_a"], seed, row["reason"]))
                continue
            if row["status"] != "ok":
                raise ValueError(f"status must be ok or skipped, got {row['status']!r}")
            for field in ARRAY_FIELDS:
                col = _column_of(field)
                raw = row[col]
                if col in _STR:
                    cols[field].append(raw)
                elif col in _INT:
                    cols[field].append(int(raw))
                else:
                    v = float(raw)
                    if math.isnan(v) and col == "return":
                        raise ValueError("return is NaN")
                    cols[field].append(v)
        except (ValueError, TypeError) as err:
            raise ResultsError(f"{path}, line {line}: {err}") from err
    return make_table(cols, skipped)
