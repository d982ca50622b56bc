"""Learning tests on CPU with the `small` preset: PPO must actually improve the policy in a CI-sized budget.

Dual Destination, fixed task, self-play (configs/train/dd_ippo_quick.yaml): 128 envs x 100-step episodes,
gamma 0.9, LR 1e-3, 8 epochs x 8 minibatches. With the paper's PPO table the signal per update is too
small for a CPU test (the random policy meets the goal pair ~0.3 times per episode; the paper's code
trains 1e8 steps); with these settings the measured run passed 0.9 normalised (return 180 of 200) at
update 21 and reached the oracle's 191 (0.955). The test asks for > 0.9 averaged over the last 5 of
40 updates (512k env steps).

IPPO on Cramped Room (configs/train/quick_cpu.yaml: 64 envs x 128-step episodes, LR 1e-3, 4 minibatches,
full-weight shaping) cut to 40 updates (328k env steps): the agents learn the shaped sub-tasks (onions into
the pot, plates, soups picked up). The random policy's unscaled shaped return is about 9 per episode (both
seats); measured runs reached 26-35 by update 40. The test asks for twice the first five updates' value,
far outside the update-to-update noise. (Delivered soups start at ~330k steps; see docs/training.md.)
"""

import json
from pathlib import Path

from cec.config import load_config
from cec.training.config import TrainConfig
from cec.training.trainer import train

ROOT = Path(__file__).resolve().parents[2]


def _rows(result):
    return [json.loads(line) for line in (result.run_dir / "metrics.jsonl").read_text().splitlines()]


def test_dual_destination_fixed_task_self_play_reaches_090(tmp_path):
    cfg = load_config(TrainConfig, ROOT / "configs/train/dd_ippo_quick.yaml", [f"run_dir={tmp_path}"])
    rows = _rows(train(cfg, progress=False))
    last = [r["normalised_return"] for r in rows[-5:]]
    assert sum(last) / 5 > 0.9, last


def test_ippo_cramped_room_learns_the_shaped_subtasks(tmp_path):
    # configs/train/quick_cpu.yaml cut to 40 updates (the LR and shaping anneal over the shorter run).
    overrides = [f"run_dir={tmp_path}", f"total_env_steps={64 * 128 * 40}", "updates_per_call=10"]
    overrides += ["checkpoint.every_updates=0", "checkpoint.milestones=[]"]
    cfg = load_config(TrainConfig, ROOT / "configs/train/quick_cpu.yaml", overrides)
    rows = _rows(train(cfg, progress=False))
    first = sum(r["mean_shaped_return"] for r in rows[:5]) / 5
    last = sum(r["mean_shaped_return"] for r in rows[-5:]) / 5
    assert last > 2 * first, (first, last)
    assert rows[-1]["entropy"] < rows[0]["entropy"]
