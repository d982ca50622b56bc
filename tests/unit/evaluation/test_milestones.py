"""`cec.evaluation.milestones`: a run's seeds with each other at each checkpoint, read back as XP and SP."""

from __future__ import annotations

import shutil
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cec.evaluation import milestones as ms
from cec.evaluation.crossplay import EvalConfig, eval_levels
from cec.evaluation.results import make_table
from cec.evaluation.stats import crossplay_estimate


def test_a_checkpoints_seeds_play_each_other_and_themselves_under_one_label(
    saved_run: tuple[Path, Path, Any], tmp_path: Path
) -> None:
    run = tmp_path / "r"
    shutil.copytree(saved_run[0], run)  # seeds 4 and 5 at update 0
    other = tmp_path / "other"
    shutil.copytree(saved_run[0], other)
    shutil.rmtree(other / "checkpoints")
    assert ms.checkpoints_by_update([run, other]) == {}  # only what every run of a population saved
    saved = ms.checkpoints_by_update([run])
    assert list(saved) == [0]

    levels = eval_levels("overcooked", "cramped_room")
    table = ms.play_milestone("ippo", saved[0], levels, EvalConfig(episodes=2, max_steps=24, pairs="self"))
    assert set(table.algorithm_a) == {ms.milestone_label("ippo", 0)} == {"ippo@0"}
    [point] = ms.milestone_points(table)
    assert (point.name, point.env_steps, point.seeds) == ("ippo", 0, (4, 5))
    # every pair was played (`pairs` is always `all`), both seat orders
    pairs = {(int(a), int(b)) for a, b in zip(table.seed_a, table.seed_b, strict=True)}
    assert pairs == {(4, 4), (5, 5), (4, 5)} and set(table.seat) == {0, 1}
    assert np.isnan(point.xp_se)  # the jackknife needs 3 seeds

    ms.plot_milestones([point], tmp_path / "curve.png", title="t")
    assert (tmp_path / "curve.png").stat().st_size > 0


def test_each_checkpoint_reads_back_as_its_own_seed_matrix() -> None:
    """Two checkpoints of one run in one table: each point from its own games; XP the mean over pairs of
    different seeds with the jackknife of `crossplay_estimate`, SP the mean of each seed with itself."""
    scores = {  # (env steps, seed a, seed b): team return
        (100, 1, 1): 10.0, (100, 2, 2): 20.0, (100, 3, 3): 30.0,
        (100, 1, 2): 4.0, (100, 1, 3): 6.0, (100, 2, 3): 8.0,
        (200, 1, 1): 40.0, (200, 2, 2): 40.0, (200, 3, 3): 40.0,
        (200, 1, 2): 0.0, (200, 1, 3): 0.0, (200, 2, 3): 60.0,
    }  # fmt: skip
    rows = [(k, seat) for k in scores for seat in (0, 1)]
    n = len(rows)
    label = [ms.milestone_label("cec", k[0]) for k, _ in rows]
    table = make_table({
        "policy_a": [f"{x}-s{k[1]}" for x, (k, _) in zip(label, rows, strict=True)], "algorithm_a": label,
        "seed_a": [k[1] for k, _ in rows],
        "policy_b": [f"{x}-s{k[2]}" for x, (k, _) in zip(label, rows, strict=True)], "algorithm_b": label,
        "seed_b": [k[2] for k, _ in rows], "level": ["cramped_room"] * n, "seat": [s for _, s in rows],
        "episode": [0] * n, "returns": [scores[k] for k, _ in rows], "deliveries": [0] * n,
        "collisions": [0] * n, "shaped_return": [0.0] * n, "env": ["overcooked"] * n,
        "episode_steps": [400] * n, "actions": ["sampled"] * n,
    })  # fmt: skip
    first, second = ms.milestone_points(table)
    assert (first.env_steps, second.env_steps) == (100, 200) and first.seeds == (1, 2, 3)
    assert first.xp == pytest.approx(6.0) and first.sp == pytest.approx(20.0)
    assert second.xp == pytest.approx(20.0) and second.sp == pytest.approx(40.0) and second.sp_se == 0.0
    m = np.array([[40.0, 0.0, 0.0], [0.0, 40.0, 60.0], [0.0, 60.0, 40.0]])
    assert second.xp_se == pytest.approx(crossplay_estimate(m).se) and second.xp_se > 0


def test_run_entries_name_each_seed_at_its_checkpoint_and_refuse_a_missing_one(
    saved_run: tuple[Path, Path, Any], tmp_path: Path
) -> None:
    run = tmp_path / "r"
    shutil.copytree(saved_run[0], run)  # seeds 4 and 5 at update 0
    entries = ms.run_entries([run])
    assert [(e.name, e.seed) for e in entries] == [("r-u0-s4", 4), ("r-u0-s5", 5)]
    assert ms.run_entries([run], 0) == entries
    with pytest.raises(ValueError, match="no checkpoint at update 7; it has \\[0\\]"):
        ms.run_entries([run], 7)
    shutil.rmtree(run / "checkpoints")
    with pytest.raises(ValueError, match="no checkpoints"):
        ms.run_entries([run])
