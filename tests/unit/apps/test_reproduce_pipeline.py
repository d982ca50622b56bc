"""The reproductions' cached tables when two invocations work on one folder at once (two builders of one
work folder, one per core): each table is played once, by whichever claims it first, and the line-ups'
scratch folder outlives neither an error nor the last invocation in it."""

from __future__ import annotations

import io
import threading
from pathlib import Path

import pytest

from apps.reproduce import pipeline
from cec.evaluation.results import ARRAY_FIELDS, EpisodeTable, make_table


def _table(returns: float) -> EpisodeTable:
    """One episode whose team return is `returns`."""
    text = {"policy_a", "algorithm_a", "policy_b", "algorithm_b", "level", "env", "actions"}
    row = {f: ["x"] if f in text else [0] for f in ARRAY_FIELDS}
    return make_table({**row, "returns": [returns]})


def test_two_invocations_share_the_tables_out_and_each_table_is_played_once(tmp_path: Path) -> None:
    """The other invocation claims the first table; this one plays the two it has not claimed, waits for
    the first and reads it from the folder; the other then finds the two this one played."""
    key = {"what": "line-ups"}
    played: list[tuple[str, int]] = []
    claimed, go_on = threading.Event(), threading.Event()

    def jobs(who: str) -> list[pipeline.Job]:
        def play(k: int) -> EpisodeTable:
            played.append((who, k))
            if who == "other" and k == 0:
                claimed.set()
                assert go_on.wait(30)  # holds the first table's lock until this invocation has waited
            if who == "this" and k == 2:
                go_on.set()
            return _table(float(k))

        return [
            pipeline.Job(tmp_path / f"part-{k}", key, f"line-up {k + 1} of 3: ", lambda k=k: play(k))
            for k in range(3)
        ]

    results: dict[str, list[EpisodeTable]] = {}

    def other_invocation() -> None:
        results["other"] = pipeline.shared_tables(jobs("other"), log=io.StringIO())

    other = threading.Thread(target=other_invocation)
    other.start()
    assert claimed.wait(30)
    log = io.StringIO()
    results["this"] = pipeline.shared_tables(jobs("this"), log=log, poll_s=0.01)
    other.join(30)
    assert sorted(played) == [("other", 0), ("this", 1), ("this", 2)]  # each table played once
    for who in ("this", "other"):  # both have every table, in order
        assert [float(t.returns[0]) for t in results[who]] == [0.0, 1.0, 2.0]
    assert "line-up 1 of 3: played by another invocation; waiting for its table" in log.getvalue()
    # a later invocation plays nothing: every table is in its folder under the same key
    again = pipeline.shared_tables(jobs("later"), log=io.StringIO())
    assert [float(t.returns[0]) for t in again] == [0.0, 1.0, 2.0] and len(played) == 3
    # another key (the zoo changed): played again
    changed = pipeline.cached_table(
        tmp_path / "part-0", {"what": "else"}, lambda: _table(9.0), label="", log=log
    )
    assert float(changed.returns[0]) == 9.0


def test_a_table_whose_play_failed_is_played_by_the_next_invocation(tmp_path: Path) -> None:
    """An error (or Ctrl-C) while playing leaves no table and no claim behind."""

    def fail() -> EpisodeTable:
        raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        pipeline.cached_table(tmp_path / "t", {"k": 1}, fail, label="", log=io.StringIO())
    table = pipeline.cached_table(tmp_path / "t", {"k": 1}, lambda: _table(3.0), label="", log=io.StringIO())
    assert float(table.returns[0]) == 3.0


def test_a_builder_between_runs_plays_only_the_tables_nobody_else_plays(tmp_path: Path) -> None:
    """`play_unclaimed`: a table stored under its key is read, not played; one another invocation holds
    is left to it without waiting; the rest are played."""
    from cec.checkpoints import RunLock

    played: list[int] = []

    def job(k: int, key: object = "same") -> pipeline.Job:
        return pipeline.Job(tmp_path / f"part-{k}", {"k": key}, f"part {k}: ",
                            lambda: played.append(k) or _table(float(k)))  # fmt: skip

    pipeline.cached_table(
        tmp_path / "part-0", {"k": "same"}, lambda: _table(0.0), label="", log=io.StringIO()
    )
    (tmp_path / "part-1").mkdir()
    lock = RunLock(tmp_path / "part-1").acquire()  # another builder is playing it
    try:
        assert pipeline.play_unclaimed([job(0), job(1), job(2)], log=io.StringIO()) == 1
    finally:
        lock.release()
    assert played == [2]
    assert pipeline.play_unclaimed([job(0), job(1), job(2, key="changed")], log=io.StringIO()) == 2
    assert played == [2, 1, 2]  # the one released, and the one whose key changed


def test_two_invocations_write_the_report_one_after_the_other(tmp_path: Path) -> None:
    """The second waits for the first to leave the report's folder before it writes there."""
    events: list[str] = []
    inside, leave = threading.Event(), threading.Event()

    def first() -> None:
        with pipeline.held(tmp_path, what="the report", log=io.StringIO()):
            events.append("first in")
            inside.set()
            assert leave.wait(30)
            events.append("first out")

    thread = threading.Thread(target=first)
    thread.start()
    assert inside.wait(30)
    log = io.StringIO()
    threading.Timer(0.2, leave.set).start()
    with pipeline.held(tmp_path, what="the report", log=log, poll_s=0.01):
        events.append("second in")
    thread.join(30)
    assert events == ["first in", "first out", "second in"]
    assert "another invocation is writing the report; waiting for it" in log.getvalue()
