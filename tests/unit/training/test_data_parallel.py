"""The data-parallel trainer (`devices`): N local devices train exactly what one device trains.

JAX fixes its device count when it starts, so the runs happen in a child process with N fake CPU devices
(`XLA_FLAGS=--xla_force_host_platform_device_count=4`), as a GPU box with 4 GPUs would see them.
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
from cec.training.trainer import Trainer
from tests.conftest import own_jax_cache

REPO = Path(__file__).resolve().parents[3]
NET = (
    "network_overrides={conv_features: [], encoder_features: [16], lstm_features: 8, actor_features: [16], "
    "critic_features: [16]}"
)
BASE = ["num_envs=8", "num_steps=16", "ppo.num_minibatches=2", "num_seeds=2", "total_env_steps=384", NET]

CHILD = textwrap.dedent(
    """
    import dataclasses, io, json, sys
    import jax, jax.numpy as jnp, numpy as np, optax
    from cec.config import ConfigError, load_config
    from cec.training.config import TrainConfig
    from cec.training.run import train
    from cec.training.trainer import Trainer

    base, out = json.loads(sys.argv[1]), sys.argv[2]
    def config(*more):
        return load_config(TrainConfig, "configs/train/quick_cpu.yaml", [*base, f"run_dir={out}", *more])
    def run(name, devices, **kw):
        return train(config(f"name={name}", f"devices={devices}"), progress=False, log=io.StringIO(), **kw)
    def largest_difference(a, b):
        diffs = jax.tree.map(lambda x, y: float(np.max(np.abs(np.asarray(x) - np.asarray(y)))), a, b)
        return max(jax.tree.leaves(diffs))
    def weighted_update_difference(t):
        # one update of a random batch whose steps weigh 0 or 1 (the scripted cook's seat's mask) on 4
        # devices and on one: the parameters' largest difference, and how far the weights moved them
        from cec.training.ppo import Batch, update
        p0 = jax.tree.map(lambda x: x[0], t.init())
        rng, (steps, n) = np.random.default_rng(0), (16, 16)
        draw = lambda dtype, high, *shape: jnp.asarray(rng.integers(0, high, (steps, n, *shape)), dtype)
        normal = lambda: jnp.asarray(rng.standard_normal((steps, n)), jnp.float32)
        batch = Batch(
            jnp.asarray(rng.standard_normal((steps, n, *t.task.obs_shape)), p0.carry.obs.dtype),
            jnp.zeros((steps, n), bool).at[0].set(True), draw(jnp.int32, 6), normal() - 1.8, normal(),
            normal(), normal(), draw(jnp.int32, 1, 0), draw(jnp.int32, 6), None, None, draw(jnp.float32, 2),
            jax.tree.map(lambda x: jnp.zeros((n, x.shape[-1]), x.dtype), p0.carry.lstm),
        )
        sgd = optax.sgd(1e-3)  # not Adam: its step would hide a wrong scale and magnify rounding
        # one epoch (2 minibatch steps): later epochs on this random batch (normal observations) compound
        # the devices' rounding: 1.5e-8 after one epoch, 1.5e-6 after four on an AMD EPYC
        ppo = dataclasses.replace(t.config.ppo, update_epochs=1)
        def step(b, mesh):
            return update(p0.params, sgd.init(p0.params), b, jax.random.PRNGKey(0), network=t.network,
                          optimizer=sgd, config=ppo, mesh=mesh)[0]
        one = step(batch, None)
        return [largest_difference(one, step(batch, t.mesh)),
                largest_difference(one, step(batch._replace(weight=None), None))]

    one, four = run("one", 1), run("four", 4)
    run("moved", 4, max_updates=1)  # interrupted after one update on 4 devices, resumed on one
    resumed = run("moved", 1, resume=True)
    try:
        Trainer(config("ppo.num_minibatches=8", "devices=4"))  # 2 sequences per minibatch
        refused = ""
    except ConfigError as err:
        refused = str(err)
    weighted = weighted_update_difference(Trainer(config("devices=4")))
    print(json.dumps({
        "devices": len(jax.local_devices()), "sharding": str(four.state.carry.obs.sharding.spec),
        "weighted": weighted,
        "params_four": largest_difference(one.state.params, four.state.params),
        "params_moved": largest_difference(one.state.params, resumed.state.params), "refused": refused,
    }))
    """
)


@pytest.mark.timeout(600)
def test_four_devices_train_what_one_device_trains_and_a_run_moves_between_devices(tmp_path: Path) -> None:
    """Two seeds, an LSTM, 3 updates of 8 envs x 16 steps: the parameters after N = 4 devices, and after a
    run that did one update on 4 devices and was resumed on one, equal one device's to float rounding; the
    rows of the metrics agree too (the resumed run's programs come from the child's own compilation cache)."""
    flags = f"{os.environ.get('XLA_FLAGS', '')} --xla_force_host_platform_device_count=4".strip()
    env = {**os.environ, "XLA_FLAGS": flags, "JAX_PLATFORMS": "cpu", **own_jax_cache(tmp_path)}
    proc = subprocess.run(
        [sys.executable, "-c", CHILD, json.dumps(BASE), str(tmp_path)],
        cwd=REPO, env=env, capture_output=True, text=True, timeout=540,
    )  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    result = json.loads(proc.stdout.strip().splitlines()[-1])
    assert result["devices"] == 4 and result["sharding"] == "P(None, 'envs')"
    assert result["params_four"] < 1e-5 and result["params_moved"] < 1e-5, result
    # steps weighted 0 (the scripted partner's seat) are left out alike on 4 devices and on one
    assert result["weighted"][0] < 1e-6 and result["weighted"][1] > 1e-5, result
    assert "each minibatch's 2 sequences must split evenly over the 4 devices" in result["refused"]
    rows = {n: [json.loads(x) for x in (tmp_path / n / "metrics.jsonl").read_text().splitlines()] for n in
            ("one", "four", "moved")}  # fmt: skip
    for name in ("four", "moved"):
        assert [r["update"] for r in rows[name]] == [r["update"] for r in rows["one"]] == [1, 1, 2, 2, 3, 3]
        for a, b in zip(rows["one"], rows[name], strict=True):
            assert b["total_loss"] == pytest.approx(a["total_loss"], rel=1e-4, abs=1e-6), name
            assert b["entropy"] == pytest.approx(a["entropy"], rel=1e-5), name


def test_devices_that_do_not_fit_are_refused_before_any_work() -> None:
    with pytest.raises(ConfigError, match="devices must be >= 0"):
        load_config(TrainConfig, None, ["devices=-1"])
    with pytest.raises(ConfigError, match="must split evenly over the 3 devices"):
        load_config(TrainConfig, None, ["num_envs=8", "devices=3"])
    two = load_config(TrainConfig, str(REPO / "configs/train/quick_cpu.yaml"), [*BASE[:3], "devices=2"])
    with pytest.raises(ConfigError, match="xla_force_host_platform_device_count=2"):
        Trainer(two)  # this process sees one CPU device
    every = load_config(TrainConfig, str(REPO / "configs/train/quick_cpu.yaml"), [*BASE[:3], "devices=0"])
    assert Trainer(every).mesh is None  # 0: every local device, here the one
