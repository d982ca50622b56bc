"""The Ray learner's data-parallel update (`devices`): over N devices it computes one device's update.

The learner runs `Trainer.learn` with the trainer's mesh (`tests/unit/training/test_data_parallel.py`
checks the trainer itself); this checks the learner's own compiled update on a batch an actor played. JAX
fixes its device count at start, so it runs in a child process with 2 fake CPU devices, the count
`learner_options` gives a CPU learner asked for `devices=2` (the whole Ray path runs in
`tests/e2e/test_multinode.py`).
"""

from __future__ import annotations

import json
import os
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest

from cec.config import ConfigError, load_config
from cec.training.config import TrainConfig
from services.learner.config import DistributedConfig, actor_env
from services.learner.driver import learner_options
from tests.conftest import own_jax_cache

REPO = Path(__file__).resolve().parents[2]

CHILD = textwrap.dedent(
    """
    import dataclasses, json, sys
    import jax, jax.numpy as jnp, numpy as np
    from cec.config import load_config
    from cec.training.compact import from_bytes, to_bytes
    from cec.training.config import TrainConfig
    from services.learner.config import DistributedConfig
    from services.actors.actor import RolloutActor, decode_batch
    from services.learner.learner import Learner

    out = sys.argv[1]
    def learner(devices):
        cfg = load_config(TrainConfig, "configs/train/dd_ippo_quick.yaml", [
            "num_envs=8", "num_steps=16", "ppo.num_minibatches=2", f"devices={devices}", f"run_dir={out}",
            f"name=d{devices}", "network_overrides={conv_features: [], encoder_features: [16], "
            "lstm_features: 8, actor_features: [16], critic_features: [16]}"])
        return Learner(cfg, DistributedConfig(num_actors=1, metrics_port=-1))
    one, two = learner(1), learner(2)
    state = jax.tree.map(lambda x: x[None], one.trainer.init_one(jax.random.PRNGKey(0)))  # [seeds]
    actor = RolloutActor(dataclasses.replace(one.config, devices=1), 0, 0, 8)
    actor.reset(0, to_bytes(state.carry))
    _, k_levels, k_roll, k_update = jax.vmap(one.trainer.update_keys)(state.key)
    _, _, raw = decode_batch(actor.rollout(to_bytes(state.params), 0, k_levels, k_roll))
    rollout = from_bytes(one._slice_template(), raw)
    results = {}
    for name, lrn in (("one", one), ("two", two)):
        copies = jax.tree.map(jnp.copy, (state.params, state.opt_state))  # `_learn` donates them
        params, opt_state = lrn.trainer.replicate(copies)  # as `Learner.run` places them
        results[name] = lrn._learn(params, opt_state, jnp.int32(0), rollout, k_update)
    diffs = jax.tree.map(lambda a, b: float(np.max(np.abs(np.asarray(a) - np.asarray(b)))),
                         results["one"][0], results["two"][0])
    on = len(jax.tree.leaves(results["two"][0])[0].sharding.device_set)
    print(json.dumps({"devices": len(jax.local_devices()), "params": max(jax.tree.leaves(diffs)), "on": on,
                      "loss": [float(results[n][2].loss.total_loss[0]) for n in ("one", "two")]}))
    """
)


@pytest.mark.timeout(300)
def test_the_learners_update_on_two_devices_is_its_update_on_one(tmp_path: Path) -> None:
    flags = learner_options(DistributedConfig(), devices=2)["runtime_env"]["env_vars"]["XLA_FLAGS"]
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu", **own_jax_cache(tmp_path)}
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, str(tmp_path)],
        cwd=REPO,
        env=env,
        capture_output=True,
        text=True,
        timeout=280,
    )
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["devices"] == 2 and result["on"] == 2, "the update ran on both devices"
    assert result["params"] < 1e-5, result
    assert result["loss"][1] == pytest.approx(result["loss"][0], rel=1e-5)


def test_learner_devices_are_checked_against_its_gpus_before_any_process_starts() -> None:
    train = load_config(TrainConfig, str(REPO / "configs/train/dd_ippo_quick.yaml"), ["devices=4"])
    with pytest.raises(ConfigError, match="learner_gpus=2; give it as many GPUs or lower devices"):
        DistributedConfig(learner_gpus=2).check(train)
    DistributedConfig(learner_gpus=4).check(train)
    gpu = learner_options(DistributedConfig(learner_gpus=4), devices=4)["runtime_env"]["env_vars"]
    assert "XLA_FLAGS" not in gpu, "a GPU learner sees the GPUs Ray gives it, no fake devices"


def test_the_drivers_own_xla_flags_reach_the_learner_and_the_actors(monkeypatch: pytest.MonkeyPatch) -> None:
    """A user's `XLA_FLAGS` (a dump folder, an optimisation level) are kept in the processes Ray starts,
    before the flags the learner and the actors need, which XLA reads last."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/dump")
    flags = learner_options(DistributedConfig(), devices=2)["runtime_env"]["env_vars"]["XLA_FLAGS"]
    assert flags == "--xla_dump_to=/tmp/dump --xla_force_host_platform_device_count=2"
    monkeypatch.delenv("XLA_FLAGS")
    assert learner_options(DistributedConfig(), devices=2)["runtime_env"]["env_vars"]["XLA_FLAGS"] == (
        "--xla_force_host_platform_device_count=2"
    )


def test_the_actors_xla_flags_are_flags_xla_reads(monkeypatch: pytest.MonkeyPatch) -> None:
    """XLA ignores a word without `--` in `XLA_FLAGS` (`intra_op_parallelism_threads=1`, an often-copied
    remedy, did nothing here) and aborts on an unknown `--` flag: every word the actors get is an XLA flag
    that a JAX process starts with, and a thread count XLA cannot honour is refused with the fix."""
    monkeypatch.setenv("XLA_FLAGS", "--xla_dump_to=/tmp/dump")
    flags = actor_env(DistributedConfig())["XLA_FLAGS"]
    assert flags == "--xla_dump_to=/tmp/dump --xla_cpu_multi_thread_eigen=false"
    monkeypatch.delenv("XLA_FLAGS")
    env = {**os.environ, **actor_env(DistributedConfig())}
    assert all(word.startswith("--xla_") for word in env["XLA_FLAGS"].split())
    code = "import jax, jax.numpy as jnp; print(float(jax.jit(lambda x: x @ x)(jnp.eye(4)).sum()))"
    proc = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert proc.returncode == 0 and proc.stdout.strip() == "4.0", proc.stderr[-2000:]
    assert "XLA_FLAGS" not in actor_env(DistributedConfig(actor_threads=0))  # XLA's own threads
    with pytest.raises(ConfigError, match=r"actor_threads must be 1 .* or 0 .*got 2.*limit that \(taskset\)"):
        DistributedConfig(actor_threads=2)


def test_level_repeats_is_refused_by_the_distributed_learner_before_any_process_starts() -> None:
    train = load_config(TrainConfig, str(REPO / "configs/train/dd_cec_quick.yaml"), ["level_repeats=4"])
    with pytest.raises(ConfigError, match="level_repeats=4 is built into `cec train` only"):
        DistributedConfig().check(train)
    DistributedConfig().check(load_config(TrainConfig, str(REPO / "configs/train/dd_cec_quick.yaml"), []))
