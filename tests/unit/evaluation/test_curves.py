"""Learning curves read back a run's own metrics rows, per seed, and plot them."""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np
import pytest

from cec.evaluation.curves import plot_learning_curves, read_curve, trailing_mean


def _write_run(path: Path) -> Path:
    path.mkdir()
    with open(path / "metrics.csv", "w", newline="") as f:
        w = csv.DictWriter(f, ["update", "env_steps", "seed", "mean_return", "mean_shaped_return", "entropy"])
        w.writeheader()
        for update in range(1, 6):
            for seed in (3, 4):
                w.writerow(
                    {
                        "update": update,
                        "env_steps": 1000 * update,
                        "seed": seed,
                        "mean_return": update * seed,
                        "mean_shaped_return": "",  # a missing value is skipped, not read as 0
                        "entropy": 1.0,
                    }
                )
    return path


def test_read_curve_splits_seeds_and_skips_missing_values(tmp_path: Path) -> None:
    run = _write_run(tmp_path / "run")
    curve = read_curve(run, "mean_return")
    assert sorted(curve) == [3, 4]
    steps, values = curve[4]
    np.testing.assert_array_equal(steps, [1000, 2000, 3000, 4000, 5000])
    np.testing.assert_array_equal(values, [4, 8, 12, 16, 20])
    assert read_curve(run, "mean_shaped_return") == {}
    with pytest.raises(FileNotFoundError, match="training run directory"):
        read_curve(tmp_path, "mean_return")


def test_trailing_mean_and_plot(tmp_path: Path) -> None:
    np.testing.assert_allclose(trailing_mean(np.array([2.0, 4.0, 6.0, 8.0]), 2), [2, 3, 5, 7])
    out = plot_learning_curves(
        {"a run": _write_run(tmp_path / "run")}, tmp_path / "c" / "curves.png", smooth=2
    )
    assert out.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    # one label over several run directories (one run per seed): each is read
    two = [tmp_path / "run", _write_run(tmp_path / "run2")]
    assert plot_learning_curves({"runs": two}, tmp_path / "two.png").read_bytes()[:4] == b"\x89PNG"
    with pytest.raises(FileNotFoundError, match="training run directory"):
        plot_learning_curves({"runs": [*two, tmp_path / "c"]}, tmp_path / "three.png")
