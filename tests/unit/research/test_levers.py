"""`research/analyses/levers.py`: a lever's row is compared with the recipe part by part at equal steps."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import pytest

from tests.scripts import research


def _module() -> Any:
    return research("levers")


def _part(xp: float, se: float) -> dict[str, float]:
    return {"levels": 5, "xp": xp, "xp_se": se, "sp": xp, "seeds": 4}


def test_the_row_at_the_steps_asked_is_compared_and_holm_adjusted(tmp_path: Path) -> None:
    levers = _module()
    rows = [
        {"run": "r", "update": u, "env_steps_per_seed": steps, "seeds": [1, 2, 3, 4],
         "parts": {"generated": _part(xp, 1.0), "classic": _part(xp / 2, 1.0)}}
        for u, steps, xp in ((1, 5_000_000, 10.0), (2, 10_485_760, 30.0), (3, 20_000_000, 99.0))
    ]  # fmt: skip
    path = tmp_path / "lever.json"
    path.write_text(json.dumps({"rows": rows}))
    base = {"generated": _part(20.0, 1.0), "classic": _part(10.0, 1.0)}
    out = levers.compare({"x": path}, base, 10_485_760)["x"]
    assert out["row"]["update"] == 2  # the last row at or below the steps, never a later one
    assert out["parts"]["generated"]["diff"] == pytest.approx(10.0)
    p = [out["parts"][k]["p"] for k in ("generated", "classic")]
    assert out["parts"]["generated"]["p_holm"] == pytest.approx(min(1.0, 2 * min(p)))
    assert "| generated | 5 | 30.0 ± 1.0 (30.0) | 20.0 ± 1.0 (20.0) | +10.0" in levers.markdown({"x": out})
    curve = tmp_path / "curve.json"
    point = {"env_steps_per_seed": 10_485_760, "xp": 25.0, "xp_se": 1.0, "sp": 24.0, "seeds": list(range(8))}
    curve.write_text(json.dumps({"rows": [point]}))
    with_curve = levers.compare({"x": path}, base, 10_485_760, curve)["x"]["parts"]
    assert list(with_curve)[0] == levers.EQUAL_STEPS and with_curve[levers.EQUAL_STEPS]["diff"] == 5.0
    with pytest.raises(SystemExit, match="no row with parts"):
        levers.lever_row(path, 1_000)


def test_a_control_trained_beside_the_lever_is_read_part_by_part_at_the_same_steps(tmp_path: Path) -> None:
    levers = _module()

    def output(name: str, xp: float, steps: tuple[int, ...]) -> Path:
        rows = [{"run": name, "update": i, "env_steps_per_seed": n, "seeds": [1, 2, 3, 4],
                 "parts": {"generated": _part(xp, 1.0), "classic": _part(xp / 2, 1.0)}}
                for i, n in enumerate(steps)]  # fmt: skip
        path = tmp_path / f"{name}.json"
        path.write_text(json.dumps({"rows": rows}))
        return path

    lever = output("lever", 30.0, (5_000_000, 10_485_760))
    control = output("control", 20.0, (5_000_000, 10_485_760))
    far = {"generated": _part(99.0, 1.0)}  # the reproduction's table: not read with a control
    out = levers.compare({"x": lever}, far, 5_000_000, control=control)["x"]
    assert [out["parts"][k]["diff"] for k in ("generated", "classic")] == [10.0, 5.0]
    assert "trained beside it (control.json, 4 seeds)" in levers.markdown({"x": out})
    with pytest.raises(SystemExit, match="no row at 10,485,760"):
        levers.compare({"x": lever}, far, 10_485_760, control=output("control", 20.0, (5_000_000,)))


def test_a_lever_of_two_seeds_is_a_reading_without_an_error_or_a_test(tmp_path: Path) -> None:
    """One pair of seeds has no jackknife error: the table says so instead of printing nan."""
    levers = _module()
    two = {**_part(12.0, float("nan")), "seeds": 2}
    row = {"run": "r", "update": 1, "env_steps_per_seed": 5_000_000, "seeds": [1, 2]}
    row["parts"] = {"generated": two}
    path = tmp_path / "lever.json"
    path.write_text(json.dumps({"rows": [row]}))
    text = levers.markdown(levers.compare({"x": path}, {"generated": _part(20.0, 1.0)}, 5_000_000))
    assert "nan" not in text and "2 seeds: one pair" in text
    assert "| generated | 5 | 12.0 ± – (12.0) | 20.0 ± 1.0 (20.0) | -8.0 | – |" in text


def _table(path: Path, algorithm: str, score: dict[tuple[int, int], float]) -> Path:
    """A `cec eval` table of `algorithm`'s seeds on two test kitchens: each pairing's return from `score`."""
    from cec.evaluation.results import ARRAY_FIELDS, make_table, write_csv

    cols: dict[str, list[Any]] = {f: [] for f in ARRAY_FIELDS}
    for (a, b), ret in score.items():
        for level in ("test_000", "test_001"):
            row = {"policy_a": f"{algorithm}{a}", "algorithm_a": algorithm, "seed_a": a,
                   "policy_b": f"{algorithm}{b}", "algorithm_b": algorithm, "seed_b": b, "level": level,
                   "seat": 0, "episode": 0, "returns": ret, "deliveries": ret / 20, "collisions": 0.0,
                   "shaped_return": 0.0, "env": "overcooked", "episode_steps": 400,
                   "actions": "sampled"}  # fmt: skip
            for k, v in row.items():
                cols[k].append(v)
    return write_csv(make_table(cols), path)


def test_result_tables_of_the_test_set_compare_as_a_lever_and_its_control(tmp_path: Path) -> None:
    levers = _module()
    seeds = (1, 2, 3)
    lever = _table(
        tmp_path / "lever.csv", "x", {(a, b): 40.0 + 20 * (a == b) + a + b for a in seeds for b in seeds}
    )
    control = _table(tmp_path / "control.csv", "y", {(a, b): 20.0 + a * b for a in seeds for b in seeds})
    out = levers.compare({"x": lever}, {}, 10_485_760, control=control)["x"]
    assert out["row"]["seeds"] == [1, 2, 3] and out["row"]["env_steps_per_seed"] == 10_485_760
    generated = out["parts"]["generated"]
    # cross-play: the pairs of two different seeds; x: 40 + a + b -> 44.0, y: 20 + a * b -> 20 + 11 / 3
    assert generated["lever"]["xp"] == pytest.approx(44.0) and generated["lever"]["sp"] == pytest.approx(64.0)
    assert generated["diff"] == pytest.approx(44.0 - (20.0 + 11 / 3))
    mixed = _table(tmp_path / "mixed.csv", "x", {(1, 1): 1.0})
    mixed.write_text(mixed.read_text() + mixed.read_text().splitlines()[1].replace(",x,", ",z,", 1) + "\n")
    with pytest.raises(SystemExit, match="give one recipe's seeds per table"):
        levers.compare({"x": mixed}, {}, 10_485_760, control=control)
