"""`research/analyses/with_strangers.py`: a recipe's seeds with partners from outside it, read per group of
seeds."""

from __future__ import annotations

import pytest

from tests.scripts import research
from tests.unit.research.test_with_cook import _table


def test_each_group_is_the_mean_over_its_seeds_with_the_error_over_them_and_strangers_pairs_only() -> None:
    ws = research("with_strangers")
    table = _table([
        ("A1", "hp_forced_coord", "forced_coord", 0, 20.0),
        ("hp_forced_coord", "A1", "forced_coord", 0, 40.0),
        ("A2", "hp_forced_coord", "forced_coord", 0, 0.0),
        ("A1", "hp_cramped_room", "cramped_room", 0, 60.0),
        ("A2", "hp_cramped_room", "cramped_room", 0, 20.0),
        ("A1", "cec758m-s200", "gen-1", 0, 40.0), ("cec758m-s201", "A2", "gen-1", 0, 80.0),
        ("B1", "hp_forced_coord", "forced_coord", 0, 0.0),
        ("hp_forced_coord", "hp_forced_coord", "forced_coord", 0, 100.0),  # the proxy alone: no group's
        ("cec758m-s200", "cec758m-s200", "gen-1", 0, 100.0),
    ])  # fmt: skip
    out = ws.summarise(table, {"teacher": ["A1", "A2"], "control": ["B1"]})
    a = out["teacher"]
    assert a["forced_coord with its proxy"]["mean"] == pytest.approx(15.0)  # A1 30, A2 0
    assert a["forced_coord with its proxy"]["se"] == pytest.approx(15.0)  # stdev 21.2 over sqrt 2
    # the five kitchens pooled per seed first: A1 (20, 40, 60) -> 40, A2 (0, 20) -> 10
    assert a["classic five with the proxies"]["mean"] == pytest.approx(25.0)
    assert a["generated with the shipped seeds"] == {"mean": 60.0, "se": pytest.approx(20.0), "seeds": 2}
    assert out["control"] == {
        "forced_coord with its proxy": {"mean": 0.0, "se": None, "seeds": 1},
        "classic five with the proxies": {"mean": 0.0, "se": None, "seeds": 1},
    }
    text = ws.markdown(out, {"date": "d", "machine": "m", "command": "c", "max_steps": 400})
    assert "| forced_coord with its proxy | 15.0 ± 15.0 | 0.0 |" in text
    assert "| generated with the shipped seeds | 60.0 ± 20.0 | - |" in text
