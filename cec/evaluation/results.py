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
import io
import math
import os
from array import array
from collections.abc import Callable, Iterable, Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, BinaryIO, TextIO, cast

import numpy as np

from cec.agents.zoo import SkippedEntry
from cec.config import open_user_file

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
            reason = (
                s.reason if len(s.reason) <= REASON_MAX_CHARS else s.reason[: REASON_MAX_CHARS - 3] + "..."
            )
            writer.writerow([s.name, s.algorithm, s.seed, *blank, "skipped", reason])
    tmp.replace(path)
    return path


def _fmt(x: object) -> object:
    if isinstance(x, float | np.floating):
        v = float(x)
        return repr(int(v)) if v.is_integer() else repr(v)
    return x


# how a file committed compressed is decompressed while read, by its suffix
COMPRESSED: dict[str, Callable[[BinaryIO], io.BufferedIOBase]] = {
    ".gz": lambda raw: gzip.GzipFile(fileobj=raw, mode="rb"),
    ".bz2": lambda raw: bz2.BZ2File(raw, "rb"),
}
# the first bytes of each format, to refuse compressed bytes under a plain name
_MAGIC = {".gz": b"\x1f\x8b", ".bz2": b"BZh"}

#: The most bytes of one table read, after decompression (the largest committed table, the CPU
#: reproduction's, holds 34 MB in 294,000 rows): a larger one is refused, not read until memory runs out.
#: The environment's `CEC_RESULTS_MAX_BYTES` raises it (`cap`).
RESULTS_MAX_BYTES = 128 << 20
#: The most rows read of the tables one command reads (each costs 128 bytes parsed, `_Columns`, and a few
#: hundred more in a report's analysis: about half a GB at the cap; the largest committed table holds 294,000,
#: the 6-seed CPU reproduction's plays about 646,000: `cec reproduce overcooked --plan`);
#: `CEC_RESULTS_MAX_ROWS`.
RESULTS_MAX_ROWS = 1_000_000
#: The most policies ((algorithm, seed) pairs) of the tables one command reads: a report holds several
#: policy x policy matrices and draws one heatmap per algorithm (a zoo holds at most 512 entries;
#: the committed tables at most 48 policies); `CEC_RESULTS_MAX_POLICIES`.
RESULTS_MAX_POLICIES = 512
#: The most algorithms of the tables one command reads (a report draws a seed x seed panel for each, and
#: matplotlib's memory grows with them: 64 panels took `cec report` 560 MB past its start; the committed
#: tables hold at most 12); `CEC_RESULTS_MAX_ALGORITHMS`.
RESULTS_MAX_ALGORITHMS = 24
#: The most distinct level names of the tables one command reads (a report has a row per level; the
#: held-out, test and classic sets together are 210); `CEC_RESULTS_MAX_LEVELS`.
RESULTS_MAX_LEVELS = 10_000


#: The longest name (policy, algorithm, level, env, actions) of a row: a policy name is one path component
#: of at most 255 bytes (`cec.paths`), the kitchens' names are under 40 characters.
NAME_MAX_CHARS = 256
#: The longest reason of a skipped row (`cec eval` writes a checkpoint's error: a path and a sentence).
REASON_MAX_CHARS = 2_000


def check_name(column: str, text: str, limit: int = NAME_MAX_CHARS, *, lines: bool = False) -> None:
    """`ValueError` naming `column` when `text` is longer than `limit` characters (a report copies it into
    fixed-width tables) or holds a control character (a NUL, an escape: a report and a terminal would
    break on it; `lines`: line breaks and tabs allowed, as in an error message)."""
    if len(text) > limit:
        raise ValueError(f"{column} is longer than {limit} characters ({text[:40]!r}...)")
    allowed = "\n\r\t" if lines else ""
    if not text.isprintable() and any(not c.isprintable() and c not in allowed for c in text):
        bad = next(c for c in text if not c.isprintable() and c not in allowed)
        raise ValueError(f"{column} holds the control character {bad!r} ({text[:40]!r})")


def cap(name: str, default: int | None = None) -> int:
    """The cap `name` (`RESULTS_MAX_BYTES`, ...): the environment's `CEC_<name>` where set, else `default`
    or this module's value. `ResultsError` naming the variable when it is not a positive integer."""
    text = os.environ.get(f"CEC_{name}")
    if text is None:
        return int(globals()[name]) if default is None else default
    try:
        value = int(text.strip().replace("_", ""))
    except ValueError:
        value = 0
    if value <= 0:
        raise ResultsError(f"CEC_{name} must be a positive integer, got {text[:40]!r}")
    return value


def _raise_hint(name: str) -> str:
    return f"split the table, or raise the cap if the table is genuine: CEC_{name}=N in the environment"


def stored(path: str | Path) -> Path:
    """`path`, or `path` + `.gz` or `.bz2` where only that is there: a file committed compressed (a large
    table, a long run's metrics) is read as it is."""
    plain = Path(path)
    if plain.is_file():
        return plain
    packed = (plain.with_name(plain.name + suffix) for suffix in COMPRESSED)
    return next((p for p in packed if p.is_file()), plain)


class _Capped(io.RawIOBase):
    """The bytes of `inner` (the file `raw`, or a decompressor over it) until `RESULTS_MAX_BYTES`; one more
    is a `ResultsError` naming the file, the cap and its setting, raised before the excess is read on."""

    def __init__(self, inner: io.BufferedIOBase, raw: BinaryIO, path: Path, kind: str) -> None:
        self.inner, self.raw, self.path, self.kind = inner, raw, path, kind
        self.max_bytes, self.total = cap("RESULTS_MAX_BYTES"), 0

    def readable(self) -> bool:
        return True

    def readinto(self, buffer: Any) -> int:
        view = memoryview(buffer).cast("B")
        n = self.inner.readinto(view[: max(1, min(len(view), self.max_bytes + 1 - self.total))]) or 0
        self.total += n
        if self.total > self.max_bytes:
            packed = " decompressed" if self.path.suffix in COMPRESSED else ""
            raise ResultsError(
                f"{self.kind} {str(self.path)!r} holds more than {self.max_bytes:,} bytes{packed}, the "
                f"most read ({__name__}.RESULTS_MAX_BYTES); {_raise_hint('RESULTS_MAX_BYTES')}"
            )
        return n

    def close(self) -> None:
        if not self.closed:
            self.inner.close()  # a decompressor leaves the file it reads open
            self.raw.close()
        super().close()


def open_text(path: Path, kind: str = "results file") -> TextIO:
    """`path` opened for reading UTF-8 text, decompressed where its name ends `.gz` or `.bz2`, in bounded
    memory: a regular file only, at most `RESULTS_MAX_BYTES` after decompression.
    `ResultsError` naming the file when it is not a regular file, holds compressed bytes under a plain name,
    or, while it is read, grows past the cap."""
    raw = open_user_file(path, kind, error=ResultsError)
    try:
        head = raw.read(3)
        raw.seek(0)
        unpack = COMPRESSED.get(path.suffix)
        packed = next((s for s, magic in _MAGIC.items() if head.startswith(magic)), None)
        if unpack is None and packed is not None:
            raise ResultsError(
                f"{kind} {str(path)!r} holds {packed[1:]}-compressed bytes but its name does not end "
                f"{packed}; rename it {path.name}{packed} (it is read decompressed then)"
            )
        inner = unpack(raw) if unpack else cast(io.BufferedIOBase, raw)
        capped = _Capped(inner, raw, path, kind)
        return io.TextIOWrapper(io.BufferedReader(capped), encoding="utf-8", newline="")
    except BaseException:
        raw.close()
        raise


def read_csv(paths: str | Path | Sequence[str | Path]) -> EpisodeTable:
    """Reads one or more results files (as `write_csv` writes them, or as `.gz`, `.bz2`) into one table.

    Raises `ResultsError` naming the file and the problem when a file is missing, cannot be decompressed,
    lacks a column, holds more than `RESULTS_MAX_BYTES` (decompressed), or when the files together hold
    more than `RESULTS_MAX_ROWS` rows, `RESULTS_MAX_POLICIES` policies or `RESULTS_MAX_LEVELS` levels (each
    raised by its `CEC_` variable: `cap`), or a row that is not a played episode: a value of the wrong
    type, a non-finite outcome, a seat other than 0 or 1, a negative episode or length (with its line).
    """
    if isinstance(paths, str | Path):
        paths = [paths]
    columns = _Columns()
    for p in paths:
        _read_one(Path(p), columns)
    return columns.table()


def _read_one(path: Path, columns: _Columns) -> None:
    if not path.is_file():
        raise ResultsError(f"results file {str(path)!r} does not exist; write one with `cec eval`")
    try:
        with open_text(path) as f:
            reader = csv.DictReader(f)
            try:
                _parse(path, reader, columns)
            except (csv.Error, UnicodeDecodeError) as err:  # a field over csv's limit, bytes not UTF-8
                raise ResultsError(
                    f"{path}, line {reader.line_num + 1}: {err}; a results file holds short text fields in "
                    "UTF-8 (write it with `cec eval`)"
                ) from None
    except (OSError, EOFError) as err:  # gzip.BadGzipFile, bz2's bad data: OSError; a cut-off stream EOFError
        raise ResultsError(f"{path} cannot be read as a results file: {err}") from err


#: `_Columns.add`'s plan: each parsed column in ARRAY_FIELDS order, with its kind (0 a string, 1 an integer,
#: 2 a float); `_CAPPED`: where algorithm_a, seed_a, algorithm_b, seed_b and level sit in it.
_PLAN = tuple((c, 0 if c in _STR else 1 if c in _INT else 2) for c in (_column_of(f) for f in ARRAY_FIELDS))
_CAPPED = tuple(ARRAY_FIELDS.index(f) for f in ("algorithm_a", "seed_a", "algorithm_b", "seed_b", "level"))


class _Columns:
    """Rows parsed into compact columns, 8 bytes a value (a string as the index of its one copy), so rows
    cost 128 bytes each however they are written (Python lists of floats cost 4x that: a 1.1M-row table of
    distinct values took `cec report` 1 GB past its start); the caps (`cap`) counted as rows come."""

    def __init__(self) -> None:
        self.values = {f: array("d" if _column_of(f) in _FLOAT else "q") for f in ARRAY_FIELDS}
        self._arrays = tuple(self.values.values())  # in ARRAY_FIELDS order, as `_PLAN`
        self.codes: dict[str, int] = {}  # each distinct string once, however many rows repeat it
        self.strings: list[str] = []
        self.policies: set[tuple[int, int]] = set()
        self.levels: set[int] = set()
        self.algorithms: set[int] = set()
        self.skipped: list[SkippedEntry] = []
        self.rows = 0
        self.max_rows = cap("RESULTS_MAX_ROWS")
        self.max_policies = cap("RESULTS_MAX_POLICIES")
        self.max_levels = cap("RESULTS_MAX_LEVELS")
        self.max_algorithms = cap("RESULTS_MAX_ALGORITHMS")

    def code(self, text: str) -> int:
        code = self.codes.get(text)
        if code is None:
            code = self.codes[text] = len(self.strings)
            self.strings.append(text)
        return code

    def add(self, row: Mapping[str, str]) -> None:
        """One played episode's row (`ValueError` naming the field that is not one). The hot loop of reading
        a table (a million rows): one pass over a plan made once, the caps checked only when a set grew."""
        parsed: list[int | float] = []
        codes = self.codes
        for col, kind in _PLAN:
            raw = row[col]
            if kind == 0:
                code = codes.get(raw)
                if code is None:  # a string not seen before: checked once
                    check_name(col, raw)
                    code = self.code(raw)
                parsed.append(code)
            elif kind == 1:
                parsed.append(_integer(col, raw))
            else:
                v = float(raw)
                if not math.isfinite(v):
                    raise ValueError(f"{col} must be a finite number, got {raw[:80]!r}")
                parsed.append(v)
        for values, v in zip(self._arrays, parsed, strict=True):
            values.append(v)  # type: ignore[arg-type]  # an int or float by its column's typecode
        alg_a, seed_a, alg_b, seed_b, level = (parsed[i] for i in _CAPPED)
        grew = len(self.policies), len(self.levels), len(self.algorithms)
        self.policies.add((int(alg_a), int(seed_a)))
        self.policies.add((int(alg_b), int(seed_b)))
        self.levels.add(int(level))
        self.algorithms.update((int(alg_a), int(alg_b)))
        if grew != (len(self.policies), len(self.levels), len(self.algorithms)):
            self._check_caps()

    def _check_caps(self) -> None:
        for name, n, limit, what in (
            (
                "RESULTS_MAX_POLICIES",
                len(self.policies),
                self.max_policies,
                "policies ((algorithm, seed) pairs)",
            ),
            ("RESULTS_MAX_LEVELS", len(self.levels), self.max_levels, "level names"),
            ("RESULTS_MAX_ALGORITHMS", len(self.algorithms), self.max_algorithms, "algorithms"),
        ):
            if n > limit:
                raise ValueError(
                    f"more than {limit:,} {what} with the rows read before it, the most one command reads "
                    f"({__name__}.{name}); {_raise_hint(name)}"
                )

    def table(self) -> EpisodeTable:
        names = np.empty(len(self.strings), dtype=object)
        names[:] = self.strings
        cols: dict[str, np.ndarray] = {}
        for field, values in self.values.items():
            if _column_of(field) in _STR:
                cols[field] = names[np.frombuffer(values, dtype=np.int64)] if values else names[:0]
            else:
                cols[field] = np.array(values, dtype=np.float64 if values.typecode == "d" else np.int64)
            del values[:]
        seen: dict[str, SkippedEntry] = {}
        for s in self.skipped:
            seen.setdefault(s.name, s)
        return EpisodeTable(**cols, skipped=tuple(seen.values()))


def _parse(path: Path, reader: csv.DictReader, columns: _Columns) -> None:
    missing = [c for c in COLUMNS if c not in (reader.fieldnames or [])]
    if missing:
        raise ResultsError(
            f"{path} is not a cross-play results file: missing column(s) {missing} "
            f"(expected the columns of `cec eval`: {', '.join(COLUMNS)})"
        )
    for row in reader:
        line = reader.line_num
        columns.rows += 1
        if columns.rows > columns.max_rows:
            raise ResultsError(
                f"{path} holds more than {columns.max_rows:,} rows (with the tables read before it), the "
                f"most one command reads ({__name__}.RESULTS_MAX_ROWS); {_raise_hint('RESULTS_MAX_ROWS')}"
            )
        try:
            if None in row or None in row.values():  # DictReader's filler for a short row, key of a long one
                fields = sum(v is not None for k, v in row.items() if k is not None) + len(
                    row.get(None) or ()
                )
                raise ValueError(
                    f"the row has {fields} fields, a results file {len(reader.fieldnames or ())}"
                )
            if row["status"] == "skipped":
                seed = int(row["seed_a"]) if row["seed_a"] else -1
                check_name("policy_a", row["policy_a"])
                check_name("algorithm_a", row["algorithm_a"])
                check_name("reason", row["reason"], REASON_MAX_CHARS, lines=True)
                columns.skipped.append(SkippedEntry(row["policy_a"], row["algorithm_a"], seed, row["reason"]))
                continue
            if row["status"] != "ok":
                raise ValueError(f"status must be ok or skipped, got {str(row['status'])[:80]!r}")
            columns.add(row)
        except (ValueError, TypeError, OverflowError) as err:  # OverflowError: an integer past int64
            raise ResultsError(f"{path}, line {line}: {err}") from err


def _integer(col: str, raw: str) -> int:
    value = int(raw)
    if col == "seat" and value not in (0, 1):
        raise ValueError(f"seat must be 0 or 1 (the seat policy A played), got {value}")
    if col in ("episode", "episode_steps") and value < 0:
        raise ValueError(f"{col} must be >= 0, got {value}")
    return value
