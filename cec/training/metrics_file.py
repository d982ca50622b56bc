"""A run's metrics files (`metrics.jsonl`, `metrics.csv`) and the one way a run's files are rewritten.

`MetricsWriter` appends each update's rows to both files, and on resume trims them to the checkpoint the
run continues from (`truncate_after`). Trimming reads each file line by line in bounded memory (a regular
file only; a line longer than `LINE_MAX_BYTES` is refused), checks every row before anything is written, and
writes the rows it keeps to a temporary file beside the old one that then replaces it (`write_atomic`): a
malformed file, a full disk or a crash midway leaves the old file as it was.

What a crash or a full disk leaves at the end of a file (a last line without its newline, or a blank one) is
dropped with a warning naming the file, so the run continues from its last whole row; anything else that is
not a row (a line that is not JSON, a row without its integer `update`, a CSV header without an `update`
column, a row with more or fewer fields than its header) is a `RunFileError` naming the file and the line.
"""

from __future__ import annotations

import csv
import io
import json
import os
import sys
from collections.abc import Iterator
from pathlib import Path
from typing import Any, BinaryIO, TextIO

from cec.config import open_user_file

#: The longest line a metrics file may hold (a row is about 1 kB).
LINE_MAX_BYTES = 1 << 20


class RunFileError(ValueError):
    """A run's file cannot be read or rewritten; the message names the file (and line) and the fix."""


def write_atomic(path: Path, data: bytes) -> None:
    """Replaces `path` by `data`: written to `<path>.tmp`, synced, then renamed over `path`, so `path` is
    always either the old file or the new one. `RunFileError` naming the file and the cause when it cannot
    be written (the old file left as it was)."""
    tmp = path.with_name(path.name + ".tmp")
    with _Rewrite(path, tmp) as out:
        out.write(data)
    _replace(tmp, path)


def _lines(path: Path, kind: str) -> Iterator[tuple[int, bytes, bool]]:
    """(line number, its bytes without the line ending, whether it ended in a newline) of each line of
    `path`, read in bounded memory: a regular file only, lines of at most `LINE_MAX_BYTES`."""
    with open_user_file(path, kind, error=RunFileError) as f:
        number = 0
        while True:
            try:
                line = f.readline(LINE_MAX_BYTES + 1)
            except OSError as err:
                raise RunFileError(f"{kind} {path} cannot be read: {err.strerror or err}") from None
            if not line:
                return
            number += 1
            whole = line.endswith(b"\n")
            if len(line) > LINE_MAX_BYTES and not whole:
                raise RunFileError(
                    f"{kind} {path}, line {number}: longer than {LINE_MAX_BYTES:,} bytes, the most a row "
                    f"holds ({__name__}.LINE_MAX_BYTES); not a metrics file: move it away and run again"
                )
            yield number, line.rstrip(b"\r\n") if whole else line, whole


def _torn(body: bytes, whole: bool) -> bool:
    """What a crash or a full disk leaves as the last line: one cut before its newline, or a blank one."""
    return not whole or not body.strip(b" \t\r\x00")


#: The most bytes of `metrics.jsonl` read whole (`read_rows`: a row is about 1 kB, so about 250,000 rows).
ROWS_MAX_BYTES = 256 << 20


def read_rows(path: Path) -> list[dict[str, Any]]:
    """The rows of a run's `metrics.jsonl`, read in bounded memory: a regular file of at most
    `ROWS_MAX_BYTES`, lines of at most `LINE_MAX_BYTES`, each a JSON object (a torn last line, what a crash
    leaves, is left out); `RunFileError` naming the file and line otherwise."""
    rows: list[dict[str, Any]] = []
    read, torn = 0, None
    for number, body, whole in _lines(path, "metrics file"):
        read += len(body) + 1
        if read > ROWS_MAX_BYTES:
            raise RunFileError(
                f"metrics file {path} holds more than {ROWS_MAX_BYTES:,} bytes, the most read whole "
                f"({__name__}.ROWS_MAX_BYTES)"
            )
        if torn is not None:
            raise RunFileError(f"metrics file {path}, line {torn}: a blank or cut line; repair or remove it")
        if _torn(body, whole):
            torn = number
            continue
        try:
            row = json.loads(body)
        except (ValueError, RecursionError):
            raise RunFileError(f"metrics file {path}, line {number}: not a JSON row") from None
        if not isinstance(row, dict):
            raise RunFileError(f"metrics file {path}, line {number}: not a JSON object")
        rows.append(row)
    return rows


class MetricsWriter:
    """Appends metrics rows to `metrics.jsonl` and `metrics.csv` in the run directory; trims them on
    resume."""

    def __init__(self, run_dir: Path) -> None:
        self.jsonl = run_dir / "metrics.jsonl"
        self.csv = run_dir / "metrics.csv"

    def write(self, rows: list[dict]) -> None:
        """Appends `rows` to both files (`RunFileError` naming the file when it cannot be written)."""
        if not rows:
            return
        # a resumed run keeps its file's columns (a newer version's extra ones are in the JSONL)
        header = self._header() if self.csv.exists() else []
        table = io.StringIO()
        writer = csv.DictWriter(table, fieldnames=header or list(rows[0]), extrasaction="ignore")
        if not header:
            writer.writeheader()
        writer.writerows(rows)
        for path, text in (
            (self.jsonl, "".join(json.dumps(row) + "\n" for row in rows)),
            (self.csv, table.getvalue()),
        ):
            try:
                with open(path, "a", newline="") as f:
                    f.write(text)
            except OSError as err:
                raise RunFileError(
                    f"cannot append to {path} ({err.strerror or err}); the run's last checkpoint is kept: "
                    "free space and resume it (a row cut short at the end of the file is dropped then)"
                ) from None

    def _header(self) -> list[str]:
        for _, body, _whole in _lines(self.csv, "metrics file"):
            return _csv_fields(self.csv, 1, body)
        return []

    def truncate_after(self, update: int, log: TextIO = sys.stderr) -> None:
        """Drops rows past `update` (written after the checkpoint a resumed run continues from), and a torn
        last line (with a warning on `log`). Both files are checked whole, their kept rows written to
        temporary files, before either replaces its file."""
        done: list[tuple[Path, Path]] = []
        try:
            for path, trim in ((self.jsonl, self._trim_jsonl), (self.csv, self._trim_csv)):
                if path.exists():
                    tmp = path.with_name(path.name + ".tmp")
                    with _Rewrite(path, tmp) as out:
                        changed = trim(update, out, log)
                    if changed:
                        done.append((path, tmp))
                    else:
                        tmp.unlink(missing_ok=True)
            for path, tmp in done:
                _replace(tmp, path)
        finally:
            for _, tmp in done:
                tmp.unlink(missing_ok=True)

    def _trim_jsonl(self, update: int, out: BinaryIO, log: TextIO) -> bool:
        """Writes the rows of `metrics.jsonl` up to `update` to `out`; whether any line was dropped."""
        dropped, torn = 0, None
        for number, body, whole in _lines(self.jsonl, "metrics file"):
            if torn is not None:  # a blank or cut line that is not the last
                raise RunFileError(f"metrics file {self.jsonl}, line {torn}: a blank or cut line; {_FIX}")
            if _torn(body, whole):
                torn, dropped = number, dropped + 1
                continue
            try:
                row = json.loads(body)
            except (ValueError, RecursionError):  # not JSON, an integer past Python's digit limit, too deep
                raise RunFileError(
                    f"metrics file {self.jsonl}, line {number}: not a JSON row; {_FIX}"
                ) from None
            at = _update_of(row.get("update") if isinstance(row, dict) else None)
            if at is None:
                raise RunFileError(
                    f"metrics file {self.jsonl}, line {number}: the row has no integer `update`; {_FIX}"
                )
            if at <= update:
                out.write(body + b"\n")
            else:
                dropped += 1
        if torn is not None:
            _warn_torn(self.jsonl, torn, log)
        return dropped > 0

    def _trim_csv(self, update: int, out: BinaryIO, log: TextIO) -> bool:
        """Writes the header and the rows of `metrics.csv` up to `update` to `out`; whether any line was
        dropped."""
        dropped, torn = 0, None
        fields: list[str] = []
        at_column = -1
        for number, body, whole in _lines(self.csv, "metrics file"):
            if torn is not None:
                raise RunFileError(f"metrics file {self.csv}, line {torn}: a blank or cut line; {_FIX}")
            if _torn(body, whole):
                torn, dropped = number, dropped + 1
                continue
            values = _csv_fields(self.csv, number, body)
            if number == 1:
                fields = values
                if "update" not in fields:
                    raise RunFileError(
                        f"metrics file {self.csv}, line 1: the header has no `update` column (it reads "
                        f"{body[:80]!r}); {_FIX}"
                    )
                at_column = fields.index("update")
                out.write(body + b"\r\n")
                continue
            if len(values) != len(fields):
                raise RunFileError(
                    f"metrics file {self.csv}, line {number}: the row has {len(values)} fields, its header "
                    f"{len(fields)}; {_FIX}"
                )
            at = _update_of(values[at_column], text=True)
            if at is None:
                raise RunFileError(
                    f"metrics file {self.csv}, line {number}: update {values[at_column][:40]!r} is not an "
                    f"integer; {_FIX}"
                )
            if at <= update:
                out.write(body + b"\r\n")
            else:
                dropped += 1
        if torn is not None:  # (a torn header alone leaves an empty file: the next write starts it again)
            _warn_torn(self.csv, torn, log)
        return dropped > 0


class _Rewrite:
    """`tmp` opened for writing the new contents of `path`; synced on a clean exit, removed on an error
    (`RunFileError` naming `path` for a write that fails: a full disk)."""

    def __init__(self, path: Path, tmp: Path) -> None:
        self.path, self.tmp = path, tmp

    def __enter__(self) -> BinaryIO:
        try:
            self.file: BinaryIO = open(self.tmp, "wb")  # noqa: SIM115 (closed in __exit__)
        except OSError as err:
            raise _unwritable(self.path, err) from None
        return self.file

    def __exit__(self, kind: type[BaseException] | None, err: BaseException | None, tb: object) -> None:
        try:
            if kind is None:
                self.file.flush()
                os.fsync(self.file.fileno())
            self.file.close()
        except OSError as failure:
            self.tmp.unlink(missing_ok=True)
            raise _unwritable(self.path, failure) from None
        if kind is not None:
            self.tmp.unlink(missing_ok=True)
            if issubclass(kind, OSError) and isinstance(err, OSError):
                raise _unwritable(self.path, err) from None


def _replace(tmp: Path, path: Path) -> None:
    try:
        os.replace(tmp, path)
    except OSError as err:
        raise _unwritable(path, err) from None


def _unwritable(path: Path, err: OSError) -> RunFileError:
    return RunFileError(
        f"cannot write {path} ({err.strerror or err}); it was left as it was. Free space (or fix the "
        "folder's permissions) and run the command again"
    )


_FIX = "the file was left as it was: repair or remove that line (or move the file away) and resume again"


def _warn_torn(path: Path, line: int, log: TextIO) -> None:
    print(
        f"warning: {path}: its last line (line {line}) is blank or was cut short (a crash or a full disk); "
        "dropped: the run continues from the last whole row",
        file=log,
        flush=True,
    )


def _csv_fields(path: Path, number: int, body: bytes) -> list[str]:
    try:
        return next(csv.reader([body.decode()]), [])
    except (csv.Error, UnicodeDecodeError) as err:
        raise RunFileError(f"metrics file {path}, line {number}: not a CSV row ({err}); {_FIX}") from None


def _update_of(value: Any, text: bool = False) -> int | None:
    """`value` as an update count (an integer >= 0; from a CSV field when `text`), else None."""
    if text:
        ok = isinstance(value, str) and 0 < len(value) <= 18 and value.isascii() and value.isdigit()
        return int(value) if ok else None
    return value if isinstance(value, int) and not isinstance(value, bool) and value >= 0 else None


__all__ = ["LINE_MAX_BYTES", "ROWS_MAX_BYTES", "MetricsWriter", "RunFileError", "read_rows", "write_atomic"]
