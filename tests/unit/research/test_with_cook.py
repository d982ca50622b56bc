"""`research/analyses/with_cook.py`: seeds with the scripted cook, read per seed and by the learner's
side."""

from __future__ import annotations

import pytest

from cec.evaluation.results import ARRAY_FIELDS, make_table
from tests.scripts import research


def _table(rows: list[tuple[str, str, str, int, float]]):
    """Rows of (policy_a, policy_b, level, seat of a, team return)."""
    cols = {f: [] for f in ARRAY_FIELDS}
    for a, b, level, seat, ret in rows:
        values = dict(policy_a=a, algorithm_a="x", seed_a=0, policy_b=b, algorithm_b="x", seed_b=0,
                      level=level, seat=seat, episode=0, returns=ret, deliveries=ret / 20, collisions=0,
                      shaped_return=0, env="overcooked", episode_steps=400, actions="sampled")  # fmt: skip
        for f in ARRAY_FIELDS:
            cols[f].append(values[f])
    return make_table(cols)


def test_each_seed_is_read_with_the_cook_by_its_side_beside_self_play_and_cross_play() -> None:
    wc = research("with_cook")
    sides = {"k1": (True, False), "k2": (False, True)}  # the onion pile: seat 0's side in k1, seat 1's in k2
    table = _table([
        # the cook as policy_a in seat 0 of k1: the learner A sits in seat 1, off the onion side
        ("cook", "A", "k1", 0, 40.0), ("cook", "A", "k1", 1, 20.0),  # A in seat 0: the onion side
        ("A", "cook", "k2", 1, 60.0), ("A", "cook", "k2", 0, 0.0),   # A in seat 1 of k2: the onion side
        ("cook", "B", "k1", 0, 0.0), ("cook", "B", "k1", 1, 0.0),
        ("A", "A", "k1", 0, 20.0), ("B", "B", "k1", 0, 0.0),
        ("A", "B", "k1", 0, 40.0), ("A", "B", "k1", 1, 0.0),
        ("cook", "noop", "k1", 0, 0.0), ("cook", "cook", "k1", 0, 80.0),
    ])  # fmt: skip
    out = wc.summarise(table, ["A", "B"], sides)
    a = out["per_seed"]["A"]
    assert a["with_cook"] == {"episodes": 4, "return": 30.0, "delivered": 0.75}
    # on the onion side: 20 (k1, seat 0) and 60 (k2, seat 1); on the other: 40 (k1, seat 1) and 0 (k2, seat 0)
    assert a["with_cook_on_the_onion_side"]["return"] == pytest.approx(40.0)
    assert a["with_cook_on_the_other_side"]["return"] == pytest.approx(20.0)
    assert a["self_play"]["return"] == 20.0 and a["cross_play"]["return"] == 20.0
    assert out["per_seed"]["B"]["self_play"]["return"] == 0.0
    assert out["seeds_with_cook"]["episodes"] == 6
    assert out["seeds_with_cook_on_the_onion_side"]["episodes"] == 3  # A's two, B's seat 0 of k1
    assert out["seeds_cross_play"]["episodes"] == 2 and out["seeds_self_play"]["episodes"] == 2
    assert out["cook_with_noop"]["return"] == 0.0 and out["cook_with_cook"]["return"] == 80.0
    text = wc.markdown(out, {"kitchens": 2, "date": "d", "machine": "m", "command": "c", "max_steps": 400})
    assert "| A | 30.0 (75%) | 40.0 (100%) | 20.0 (50%) | 20.0 (100%) | 20.0 (50%) |" in text
