"""Slices of a batch play what they play inside it, and compact trajectories expand to the real ones."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.config import from_dict
from cec.training.compact import CompactRollout, expand, from_bytes, nbytes, to_bytes
from cec.training.config import TrainConfig
from cec.training.rollout import RolloutCarry
from cec.training.trainer import Trainer


def _config(env: dict, algorithm: str, **kw: object) -> TrainConfig:
    data = dict(
        algorithm=algorithm, network="small", num_envs=6, num_steps=24, total_env_steps=6 * 24 * 2, env=env
    )
    data.update(kw)
    return from_dict(TrainConfig, data)


CASES = {
    "overcooked-generator": _config(
        {"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": 10}}, "cec"
    ),
    "dd-procedural": _config(
        {"name": "dual_destination", "levels": "procedural", "dual_destination": {"max_steps": 10}}, "cec"
    ),
}


def _slice(tree: object, lo: int, hi: int) -> object:
    return jax.tree.map(lambda x: x[lo:hi], tree)


def _concat_time_major(parts: list) -> object:  # Trajectory leaves are [T, E, ...]; init_lstm/last_value [E]
    return jax.tree.map(lambda *xs: jnp.concatenate(xs, axis=1 if xs[0].ndim > 1 else 0), *parts)


@pytest.mark.slow
@pytest.mark.parametrize("case", list(CASES))
def test_env_slices_play_what_they_play_in_the_full_batch(case: str) -> None:
    trainer = Trainer(CASES[case])
    state = trainer._init(jax.random.PRNGKey(3))
    _, k_levels, k_roll, _ = trainer.update_keys(state.key)
    full_carry, full = trainer.collect(state.params, state.carry, k_levels, k_roll)
    parts = []
    for lo, hi in ((0, 3), (3, 6)):  # two slices of one size: one more compiled program, not two
        carry, traj = trainer.collect(state.params, _slice(state.carry, lo, hi), k_levels, k_roll)
        parts.append((carry, traj))
        np.testing.assert_array_equal(traj.action, full.action[:, lo:hi])
        np.testing.assert_array_equal(traj.reward, full.reward[:, lo:hi])
        np.testing.assert_array_equal(traj.done, full.done[:, lo:hi])
        np.testing.assert_allclose(traj.log_prob, full.log_prob[:, lo:hi], atol=1e-5)
        np.testing.assert_array_equal(carry.obs, full_carry.obs[lo:hi])
    assert full.done.any(), "episodes must end inside the rollout for the level buffers to be exercised"


@pytest.mark.parametrize("case", list(CASES))
def test_compact_rollout_expands_to_the_recorded_observations(case: str) -> None:
    trainer = Trainer(CASES[case])
    state = trainer._init(jax.random.PRNGKey(5))
    _, k_levels, k_roll, _ = trainer.update_keys(state.key)
    levels = trainer.task.sample_levels(k_levels, state.carry.env_id, trainer.config.levels_per_env)
    # two rollouts in a row, so that the second starts mid-episode on levels from the first's buffer
    carry, _ = trainer.collect(state.params, state.carry, k_levels, k_roll, levels=levels)
    k2 = jax.random.fold_in(k_roll, 1)
    levels2 = trainer.task.sample_levels(
        jax.random.fold_in(k_levels, 1), carry.env_id, trainer.config.levels_per_env
    )
    _, want = trainer.collect(state.params, carry, k_levels, k2, levels=levels2)
    _, compact = trainer.collect(state.params, carry, k_levels, k2, levels=levels2, record="state")
    assert compact.obs is None
    shipped = CompactRollout(compact, carry.env_state.level, levels2)
    wire = to_bytes(shipped)
    back = from_bytes(shipped, wire)
    got = expand(trainer.task, trainer.env_params, back)
    np.testing.assert_array_equal(np.asarray(got.obs), np.asarray(want.obs))
    np.testing.assert_array_equal(got.action, want.action)
    assert got.state is None
    # the point of it: far fewer bytes than the observations
    assert len(wire) < 0.5 * nbytes(want)


def test_carry_holds_each_envs_index() -> None:
    trainer = Trainer(CASES["dd-procedural"])
    state = trainer._init(jax.random.PRNGKey(0))
    assert isinstance(state.carry, RolloutCarry)
    np.testing.assert_array_equal(state.carry.env_id, np.arange(6))
