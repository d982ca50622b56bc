"""The ledger of test-set reads (`cec.levels.ledger`): each read appended, the rows before it untouched."""

from __future__ import annotations

import datetime
from pathlib import Path

import pytest

from cec.config import ConfigError
from cec.levels import ledger

HEADER = "date,commit,set,what,command\n"


def test_the_first_read_writes_the_header_and_its_row(tmp_path: Path) -> None:
    path = tmp_path / "data" / "reads.csv"
    row = ledger.record("test", "four seeds,\n one episode", "cec eval --levels test", "abc1234", path)
    assert row.date == datetime.date.today().isoformat() and row.what == "four seeds, one episode"
    assert ledger.reads(path) == [row] and path.read_text().startswith(HEADER)
    assert ledger.times_read("test", path) == 1 and ledger.times_read("test2", path) == 0


def test_rows_written_by_hand_keep_their_quoting_when_a_read_is_appended(tmp_path: Path) -> None:
    """A hand-written row quoted where the csv module would not quote stays byte for byte (the ledger is
    kept in git: a read must add one line to its diff, not rewrite others)."""
    path = tmp_path / "reads.csv"
    by_hand = HEADER + '2026-11-28,"92e0fc7",test,"the shipped seeds","evaluate.sh"'  # no final newline
    path.write_text(by_hand)
    ledger.record("test2", "the release", "cec release runs/x", "def5678", path)
    text = path.read_text()
    assert text.startswith(by_hand + "\n") and text.count("\n") == 3
    assert [r.set for r in ledger.reads(path)] == ["test", "test2"]


def test_a_file_that_is_not_a_ledger_is_refused_and_left_as_it_was(tmp_path: Path) -> None:
    path = tmp_path / "reads.csv"
    path.write_text("name,score\nx,1\n")
    with pytest.raises(ConfigError, match="header"):
        ledger.record("test", "x", "y", "z", path)
    assert path.read_text() == "name,score\nx,1\n"
