"""`cec.evaluation.seeds`: the one per-seed summary (seeds as units) both reproductions report."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cec.evaluation.results import make_table
from cec.evaluation.seeds import partner_means, seed_matrix, seed_summary
from cec.evaluation.stats import crossplay_estimate


def _table(pairs: list[tuple[str, int, str, int, float]]) -> object:
    rows = [(a, sa, b, sb, seat, r) for a, sa, b, sb, r in pairs for seat in (0, 1)]
    n = len(rows)
    return make_table(
        {
            "policy_a": [f"{r[0]}{r[1]}" for r in rows], "algorithm_a": [r[0] for r in rows],
            "seed_a": [r[1] for r in rows], "policy_b": [f"{r[2]}{r[3]}" for r in rows],
            "algorithm_b": [r[2] for r in rows], "seed_b": [r[3] for r in rows],
            "level": ["generated_000"] * n, "seat": [r[4] for r in rows], "episode": [0] * n,
            "returns": [r[5] for r in rows],
            "deliveries": [0] * n, "collisions": [0] * n, "shaped_return": [0.0] * n,
            "env": ["overcooked"] * n, "episode_steps": [400] * n, "actions": [6] * n,
        }
    )  # fmt: skip


def test_seed_summary_gives_each_seed_its_mean_with_the_others_and_the_jackknife() -> None:
    m = np.array([[80.0, 40.0, 20.0], [40.0, 80.0, 60.0], [20.0, 60.0, 100.0]])
    s = seed_summary(m, [7, 8, 9])
    assert s.seeds == (7, 8, 9) and s.xp == (30.0, 50.0, 40.0) and s.sp == (80.0, 80.0, 100.0)
    assert s.crossplay() == crossplay_estimate(m)
    assert s.crossplay().mean == pytest.approx(40.0) and math.isfinite(s.crossplay().se)
    assert seed_summary(np.array([[5.0]]), [1]).xp == (pytest.approx(math.nan, nan_ok=True),)
    with pytest.raises(ValueError, match="2 x 2"):
        seed_summary(np.ones((2, 3)), [1, 2])


def test_partner_means_leave_out_what_was_not_played() -> None:
    got = partner_means(np.array([[1.0, np.nan, 3.0], [np.nan, np.nan, np.nan]]))
    assert got[0] == 2.0 and np.isnan(got[1])
    assert np.isnan(partner_means(np.zeros((2, 0)))).all()  # no partners at all


def test_seed_matrix_summarises_an_algorithm_and_its_partners_from_a_table() -> None:
    table = _table([("cec", 0, "cec", 1, 40.0), ("cec", 0, "cec", 2, 20.0), ("cec", 1, "cec", 2, 60.0),
                    ("cec", 0, "cec", 0, 80.0), ("cec", 1, "cec", 1, 80.0), ("cec", 2, "cec", 2, 100.0),
                    ("cec", 0, "cook", 0, 20.0)])  # fmt: skip
    sm = seed_matrix(table, ["generated_000"])
    cec = sm.summary(sm.indices("cec"))
    assert cec.seeds == (0, 1, 2) and cec.xp == (30.0, 50.0, 40.0) and cec.sp == (80.0, 80.0, 100.0)
    cook = sm.partner_means(sm.indices("cec"), sm.indices("cook"))
    assert cook[0] == 20.0 and np.isnan(cook[1:]).all()
