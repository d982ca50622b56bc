"""`cec release`: a run's release chosen on validation only, its test sets played once (and recorded in the
ledger), its report written, and shipped only when not worse than what ships; through the command, on a
tiny run of three random seeds (small networks, one kitchen per set, short episodes)."""

from __future__ import annotations

import re
import subprocess
import sys
from pathlib import Path

import jax
import numpy as np
import pytest
import yaml

from cec import checkpoints
from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry, load_zoo
from cec.config import from_dict
from cec.evaluation.checkpoint_results import ResultFiles
from cec.levels import ledger
from cec.training.config import TrainConfig
from cec.training.run import config_dict
from cec.training.trainer import Trainer

REPO = Path(__file__).resolve().parents[3]
SEEDS = [10, 11, 12]
SETS = [
    "--validation", "generated_000", "--test", "test2_000", "--reused-test", "test_000",
    "--classic", "cramped_room", "--max-steps", "48",
]  # fmt: skip
ZOO = """policies:
  - {name: cook_a, algorithm: cooks, seed: 0, scripted: cook}
  - {name: cook_b, algorithm: cooks, seed: 1, scripted: cook}
  - {name: stay_a, algorithm: stayers, seed: 0, scripted: noop}
  - {name: stay_b, algorithm: stayers, seed: 1, scripted: noop}
  - {name: hp_cramped_room, algorithm: human_proxy, seed: 0, scripted: noop, levels: [cramped_room]}
"""


def _run(root: Path) -> Path:
    """A run of three seeds with random parameters at updates 2 and 4, and the evaluator's record of them
    (update 2 recorded best)."""
    config = from_dict(TrainConfig, {
        "algorithm": "cec", "num_seeds": len(SEEDS), "seed": SEEDS[0], "num_envs": 2, "num_steps": 8,
        "total_env_steps": 64, "network": "small", "run_dir": str(root), "name": "rel",
        "env": {"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": 16}},
    })  # fmt: skip
    template = Trainer(config).state_template()
    store = checkpoints.CheckpointStore(root / "rel", keep_last=10)
    for update, score in ((2, 5.0), (4, 3.0)):
        rng = np.random.default_rng(update)
        state = jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), template)
        params = jax.tree.map(lambda s, r=rng: r.normal(0.0, 0.5, s.shape).astype(s.dtype), template.params)
        store.save(state._replace(params=params), update=update, env_steps=update * 16,
                   config=config_dict(config), metadata={"algorithm": "cec", "seeds": SEEDS},
                   milestone=False)  # fmt: skip
        row = ("cross_play", "validation", {"return_mean": score, "return_sem": 1.0, "episodes": 6})
        ResultFiles(root, "rel", update).record(update, update * 16, [row])
    return root / "rel"


def _release(tmp: Path, *args: str) -> subprocess.CompletedProcess:
    cmd = [sys.executable, "-m", "apps.cli", "release", str(tmp / "rel"), "--prefix", "t1", *SETS,
           "--zoo", str(tmp / "shipped" / "zoo.yaml"), "--ledger", str(tmp / "reads.csv"),
           "--docs", str(tmp / "docs"), "--candidates", "1", *args]  # fmt: skip
    return subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=900)


@pytest.mark.slow
def test_release_chooses_on_validation_tests_once_and_ships_only_what_is_not_worse(tmp_path: Path) -> None:
    run = _run(tmp_path)
    (tmp_path / "shipped").mkdir()
    (tmp_path / "shipped" / "zoo.yaml").write_text(ZOO)
    # against two scripted cooks, random seeds are worse on validation: reported, not shipped
    first = _release(tmp_path, "--family", "cooks", "--ship")
    assert first.returncode == 2, first.stderr[-3000:]
    assert "not shipped" in first.stderr and "below the shipped cooks" in first.stderr, first.stderr[-2000:]
    assert "Traceback" not in first.stderr
    out = run / "release"
    choice = yaml.safe_load((out / "choice.json").read_text())
    candidates = {int(u): float(np.mean(v)) for u, v in choice["candidates"].items()}
    assert set(candidates) == {2, 4}  # the recorded best and the last
    assert choice["update"] == max(candidates, key=lambda u: (candidates[u], -u))
    readme = (out / "README.md").read_text()
    assert "not the paper's method" in readme and f"checkpoint of update {choice['update']}" in readme
    assert "read 0 time(s) before" in readme  # test2_000 is new; test_000 ...
    assert "| no (below the shipped seeds) |" in readme, "the report says that it does not ship"
    # 3 seeds against 2 cooks, each having played all the others: 10 splits of the pooled 5 seeds
    assert re.search(
        r"exact permutation test .*\| p [01]\.\d{3} \(the smallest it can be: 0\.100; 10 relabellings\)",
        readme,
    ), readme
    reads = ledger.reads(tmp_path / "reads.csv")
    assert [r.set for r in reads] == ["test2_000", "test_000"], reads
    assert yaml.safe_load((tmp_path / "shipped" / "zoo.yaml").read_text()) == yaml.safe_load(ZOO)
    # against partners that stay put it is not worse: shipped; the test sets are not played again
    second = _release(tmp_path, "--family", "stayers", "--ship")
    assert second.returncode == 0, second.stderr[-3000:]
    assert "playing test" not in second.stderr and "playing reused_test" not in second.stderr
    assert len(ledger.reads(tmp_path / "reads.csv")) == 2, "each test set read once"
    entries = load_zoo(str(tmp_path / "shipped" / "zoo.yaml"))
    assert [e.name for e in entries if e.algorithm == "stayers"] == [f"t1-s{s}" for s in SEEDS]
    assert {e.name for e in entries} >= {"cook_a", "cook_b", "hp_cramped_room"}, "the other entries kept"
    chosen = Path(choice["checkpoint"])
    for seed in SEEDS:
        shipped = load_policy(next(e for e in entries if e.name == f"t1-s{seed}"))
        trained = load_policy(ZooEntry("x", str(chosen), seed=seed))
        assert shipped.algorithm == "stayers" and shipped.seed == seed
        for a, b in zip(jax.tree.leaves(shipped.params), jax.tree.leaves(trained.params), strict=True):
            np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert (tmp_path / "docs" / "t1" / "README.md").read_text() == (out / "README.md").read_text()
    assert "| yes |" in (out / "README.md").read_text()
    assert (tmp_path / "docs" / "t1" / "record.png").stat().st_size > 0


def test_release_refuses_bad_input_before_playing(tmp_path: Path) -> None:
    (tmp_path / "empty").mkdir()
    cmd = [sys.executable, "-m", "apps.cli", "release", str(tmp_path / "empty"), "--prefix", "t1"]
    proc = subprocess.run(cmd, cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "has no checkpoint" in proc.stderr and "Traceback" not in proc.stderr
    proc = subprocess.run([*cmd, "--test", "nowhere_kitchen"], cwd=REPO, capture_output=True, text=True,
                          timeout=300)  # fmt: skip
    assert proc.returncode == 2 and "nowhere_kitchen" in proc.stderr, proc.stderr
    proc = subprocess.run([*cmd[:-1], "../up"], cwd=REPO, capture_output=True, text=True, timeout=300)
    assert proc.returncode == 2 and "--prefix" in proc.stderr, proc.stderr
