"""Learning tests on CPU with the `small` preset: PPO must actually improve the policy in a CI-sized budget.

Dual Destination, fixed task, self-play (configs/train/dd_ippo_quick.yaml): 128 envs x 100-step episodes,
gamma 0.9, LR 1e-3, 8 epochs x 8 minibatches. With the paper's PPO table the signal per update is too
small for a CPU test (the random policy meets the goal pair ~0.3 times per episode; the paper's code
trains 1e8 steps); with these settings the measured run passed 0.9 normalised (return 180 of 200) at
update 21 and reached the oracle's 191 (0.955). The test asks for > 0.9 averaged over the last 5 of
40 updates (512k env steps).

IPPO on Cramped Room (configs/train/cramped_room_ci.yaml: 64 envs x 128-step episodes, an MLP on the
flattened observation (FC 64, FC 64, no CNN, no LSTM), LR 1e-2, no value clipping, Overcooked-AI's shaped
rewards at full weight), 80 updates (655k env steps): the agents deliver soups. The random policy's team
return is 0 (0.00-0.06 over the first five updates in every measured run); measured runs reached a mean team
return over the last 5 updates of 10.3, 19.1, 16.5, 15.8, 16.4, 8.2, 16.9 and 16.8 for seeds 0-7 (20 per
soup), in 43-46 s on one core. The test asks for >= 4 (a soup every five episodes), and for the unscaled
shaped return (~4 at first, 16-23 at the end) to double.
"""

import json
from pathlib import Path

from cec.config import load_config
from cec.training.config import TrainConfig
from cec.training.run import train

ROOT = Path(__file__).resolve().parents[2]


def _rows(result):
    return [json.loads(line) for line in (result.run_dir / "metrics.jsonl").read_text().splitlines()]


def test_dual_destination_fixed_task_self_play_reaches_090(tmp_path):
    cfg = load_config(TrainConfig, ROOT / "configs/train/dd_ippo_quick.yaml", [f"run_dir={tmp_path}"])
    rows = _rows(train(cfg, progress=False))
    last = [r["normalised_return"] for r in rows[-5:]]
    assert sum(last) / 5 > 0.9, last


def test_ippo_cramped_room_delivers_soups(tmp_path):
    # configs/train/cramped_room_ci.yaml as shipped: 80 updates, about 45 s on one core.
    cfg = load_config(TrainConfig, ROOT / "configs/train/cramped_room_ci.yaml", [f"run_dir={tmp_path}"])
    rows = _rows(train(cfg, progress=False))
    first, last = rows[:5], rows[-5:]
    returns = [r["mean_return"] for r in last]
    assert sum(returns) / 5 >= 4.0, returns  # 20 per soup: a soup every five episodes or more
    first_shaped = sum(r["mean_shaped_return"] for r in first) / 5
    last_shaped = sum(r["mean_shaped_return"] for r in last) / 5
    assert last_shaped > 2 * first_shaped, (first_shaped, last_shaped)
    assert rows[-1]["entropy"] < rows[0]["entropy"]
