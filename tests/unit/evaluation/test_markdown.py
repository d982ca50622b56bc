"""cec.evaluation.markdown: figures with their uncertainty, tables and strict templates."""

from __future__ import annotations

import math
import string

import pytest

from cec.evaluation.markdown import NONE, fill, interval, p_value, pm, table


def test_pm_forms() -> None:
    assert pm(12.34, 1.26) == "12.3 ± 1.3"
    assert pm(12.34, math.nan) == "12.3"
    assert pm(12.34, None, 3) == "12.340"
    assert pm(12.34, math.nan, no_error="–") == "12.3 ± –"
    assert pm(math.nan, 1.0) == NONE
    assert pm(1.0, 0.5, n=4) == "1.0 ± 0.5 (n=4)"


def test_p_interval_table() -> None:
    assert p_value(0.01234) == "0.012" and p_value(math.nan) == NONE
    assert interval(-1.25, 2.0) == "[-1.2, +2.0]" and interval(math.nan, 1.0) == NONE
    assert table(["a", "b"], [[1, "x"]]) == "| a | b |\n|---|---|\n| 1 | x |"


def test_fill_refuses_unfilled_and_unused_holes() -> None:
    t = string.Template("# $title\n\n${body} costs $$3\n")
    assert fill(t, title="T", body="B") == "# T\n\nB costs $3\n"
    with pytest.raises(KeyError, match="body"):
        fill(t, title="T")
    with pytest.raises(ValueError, match="extra"):
        fill(t, title="T", body="B", extra="E")
    with pytest.raises(ValueError, match="stray"):
        fill(string.Template("costs $3"))
