"""The distributed learner trains what `cec train` trains, on the release recipe: several seeds in one run
(vmapped, as `cec train` does), the scripted teacher's loss and the generator's coverage (hand-over
kitchens) all on, and every other setting the recipe can take moved off its value (`MOVED`). In `sync`
mode with the kitchens drawn as the single-process trainer draws them (no level server), the learner and
its actors in one process (`distributed.pool=local`) reach `cec train`'s parameters after a few updates,
seed by seed, to float rounding (the learner's update is compiled apart from the rollout, so the last
digits differ)."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest

from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry
from cec.config import load_config
from cec.training.config import TrainConfig
from cec.training.run import train
from services.learner.config import DistributedConfig
from services.learner.learner import Learner
from services.learner.pool import LocalPool

REPO = Path(__file__).resolve().parents[2]
RELEASE = str(REPO / "configs/train/cec_overcooked_teacher.yaml")
UPDATES = 3
TINY = [  # the release recipe, sized for a test: its teacher, coverage and network kept
    "num_seeds=2", "seed=5", "num_envs=8", "num_steps=32", "env.overcooked.max_steps=32",
    "total_env_steps=2560", "ppo.teacher_anneal_env_steps=2560", "updates_per_call=1",
    "ppo.num_minibatches=2", "checkpoint.every_updates=1", "checkpoint.milestones=[]",
]  # fmt: skip
#: A walk over the settings the recipe can take (services/learner/settings.py): each moved off the
#: preset's value, so that one the distributed path dropped or read differently parts the two runs.
MOVED = [
    "ppo.lr=0.003", "ppo.lr_anneal_env_steps=2048", "ppo.update_epochs=1", "ppo.gamma=0.97",
    "ppo.gae_lambda=0.9", "ppo.clip_eps=0.15", "ppo.clip_value=true", "ppo.ent_coef=0.02", "ppo.vf_coef=0.7",
    "ppo.max_grad_norm=0.3", "ppo.adam_eps=1e-6", "ppo.shaping_anneal_env_steps=2048",
    "ppo.team_shaping=true",
    "ppo.teacher_coef=0.5", "env.overcooked.delivery_reward=25", "env.overcooked.onion_in_pot_reward=2",
    "env.overcooked.soup_pickup_reward=4", "env.overcooked.plate_pickup_reward=2.5",
    "env.overcooked.random_start_facing=false", "env.overcooked.random_start_items=0.3",
    "env.overcooked.random_start_pot_onions=0.2", "env.generator.count_decay=0.7",
    "env.generator.pots=[1, 3]", "env.generator.structure_weights=[1, 2, 1, 1, 2]",
    "env.generator.handover_share=0.5", "network_overrides.egocentric_radius=4",
    "network_overrides.encoder_features=[64, 32]", "network_overrides.cell_features=6",
]  # fmt: skip


def _rows(run: Path) -> list[dict]:
    return [json.loads(line) for line in (run / "metrics.jsonl").read_text().splitlines()]


@pytest.mark.slow
def test_sync_learner_reproduces_cec_train_on_the_release_recipe_with_two_seeds(tmp_path: Path) -> None:
    base = [*TINY, *MOVED, f"run_dir={tmp_path}"]
    single = load_config(TrainConfig, RELEASE, [*base, "name=single"])
    assert single.ppo.teacher_coef > 0 and single.env.generator.handover_share > 0  # the recipe's levers
    train(single, progress=False, max_updates=UPDATES)
    dist = load_config(TrainConfig, RELEASE, [*base, "name=dist"])
    distributed = DistributedConfig(num_actors=2, mode="sync", pool="local", metrics_port=-1)
    Learner(dist, distributed, pool=LocalPool()).run(resume=False, max_updates=UPDATES)

    want, got = _rows(tmp_path / "single"), _rows(tmp_path / "dist")
    assert [(r["update"], r["seed"]) for r in got] == [(r["update"], r["seed"]) for r in want]
    assert {r["seed"] for r in got} == {5, 6}
    for a, b in zip(want, got, strict=True):
        key = (a["update"], a["seed"])
        assert b["total_loss"] == pytest.approx(a["total_loss"], rel=1e-3, abs=1e-5), key
        assert b["teacher_loss"] == pytest.approx(a["teacher_loss"], rel=1e-3, abs=1e-5), key
        assert b["mean_shaped_return"] == pytest.approx(a["mean_shaped_return"], rel=1e-5, abs=1e-6), key
    for seed in (5, 6):
        ref = load_policy(ZooEntry("single", str(tmp_path / "single"), seed=seed)).params
        new = load_policy(ZooEntry("dist", str(tmp_path / "dist"), seed=seed)).params
        diffs = [
            float(np.max(np.abs(np.asarray(x) - np.asarray(y))))
            for x, y in zip(_leaves(ref), _leaves(new), strict=True)
        ]
        assert max(diffs) < 1e-4, (seed, max(diffs))
    # the two seeds learned apart: a run of two seeds is not one seed twice
    s5 = load_policy(ZooEntry("dist", str(tmp_path / "dist"), seed=5)).params
    s6 = load_policy(ZooEntry("dist", str(tmp_path / "dist"), seed=6)).params
    assert max(float(np.max(np.abs(np.asarray(x) - np.asarray(y)))) for x, y in
               zip(_leaves(s5), _leaves(s6), strict=True)) > 1e-3  # fmt: skip


def _leaves(tree: object) -> list:
    import jax

    return jax.tree.leaves(tree)
