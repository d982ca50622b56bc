"""Every training setting reaches where it acts in the distributed learner, or is refused by name at start.

`services/learner/settings.py` places each `TrainConfig` field: honoured (what reads it) or refused. A field
added to `TrainConfig` and placed nowhere fails here; each refusal is checked through `cec up`, with Ray and
with `distributed.pool=local`, before anything starts. That the honoured ones act as `cec train` reads them
is `test_learner_release.py` (the release recipe with every setting it takes moved off its value, to float
rounding) and `tests/e2e/test_distributed.py` (Dual Destination, with Ray); that the generator's reach the
level server, `tests/unit/levels/test_level_wire.py` and `test_level_server.py`."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import pytest

from services.learner.settings import HONOURED, REFUSED, placed, setting_paths

REPO = Path(__file__).resolve().parents[2]


def test_every_training_setting_is_placed_and_every_placement_names_a_setting() -> None:
    paths = list(setting_paths())
    assert len(paths) > 50 and "ppo.teacher_coef" in paths and "env.generator.handover_share" in paths
    unplaced = [p for p in paths if placed(p) is None]
    assert unplaced == [], f"place these in services/learner/settings.py (honoured or refused): {unplaced}"
    for key in [*HONOURED, *REFUSED]:  # no stale entry: each names a setting or a group of them
        assert any(p == key or (key.endswith(".*") and p.startswith(key[:-1])) for p in paths), key


@pytest.mark.parametrize("pool", ["ray", "local"])
@pytest.mark.parametrize(
    ("overrides", "named"),
    [
        (["train.level_repeats=2"], "level_repeats"),
        (["train.env.generator.exclude_heldout=false"], "env.generator.exclude_heldout"),
        (["train.devices=2"], "devices=2"),  # with the main job's two seeds
    ],
)
def test_a_refused_setting_stops_cec_up_by_name_before_anything_starts(
    tmp_path: Path, pool: str, overrides: list[str], named: str
) -> None:
    cmd = [sys.executable, "-m", "apps.cli", "up", f"distributed.pool={pool}", "level_server_port=0",
           "evaluator_metrics_port=0", "distributed.metrics_port=0", f"train.run_dir={tmp_path}",
           "train.name=walk", *overrides]  # fmt: skip
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2, proc.stderr[-2000:]
    assert named in proc.stderr and "Traceback" not in proc.stderr, proc.stderr
    assert proc.stderr.count("\n") == 1, proc.stderr  # one line: the refusal and its fix
    assert not (tmp_path / "walk" / "redis").exists(), "nothing was started"
