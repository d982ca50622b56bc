"""PPO pieces against plain-Python references: GAE, the clipped loss, the optimizer schedule."""

import inspect

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.agents import LSTMState
from cec.agents.network import NetworkConfig
from cec.training.ppo import Batch, PPOConfig, gae, make_batch, make_optimizer, ppo_loss


def _gae_loop(reward, value, done, last_value, gamma, lam):
    t_max = len(reward)
    adv = np.zeros_like(reward)
    next_adv, next_value = np.zeros_like(last_value), last_value
    for t in reversed(range(t_max)):
        nd = 1.0 - done[t]
        delta = reward[t] + gamma * next_value * nd - value[t]
        next_adv = delta + gamma * lam * nd * next_adv
        adv[t] = next_adv
        next_value = value[t]
    return adv


def test_gae_matches_a_python_loop_with_episode_ends():
    rng = np.random.default_rng(0)
    t, n = 37, 6
    reward = rng.normal(size=(t, n)).astype(np.float32)
    value = rng.normal(size=(t, n)).astype(np.float32)
    done = rng.random((t, n)) < 0.15
    last = rng.normal(size=n).astype(np.float32)
    adv, target = gae(
        jnp.asarray(reward), jnp.asarray(value), jnp.asarray(done), jnp.asarray(last), 0.99, 0.95
    )
    want = _gae_loop(reward, value, done.astype(np.float32), last, 0.99, 0.95)
    np.testing.assert_allclose(adv, want, rtol=1e-5, atol=1e-5)
    np.testing.assert_allclose(target, want + value, rtol=1e-5, atol=1e-5)


def test_gae_does_not_bootstrap_across_an_episode_end():
    reward = jnp.array([[1.0], [0.0]])
    value = jnp.array([[0.0], [100.0]])
    done = jnp.array([[True], [False]])
    adv, _ = gae(reward, value, done, jnp.array([0.0]), 0.9, 1.0)
    assert float(adv[0, 0]) == pytest.approx(1.0)  # the next episode's 100 never leaks back


class _FixedOutputs:
    """Stands in for the network: 'params' are the logits and values the loss should see."""

    config = NetworkConfig()  # no partner model

    def apply(self, params, carry, obs, first, history=None):
        return carry, params["logits"], params["value"]


def test_ppo_loss_matches_hand_computed_values():
    cfg = PPOConfig(clip_eps=0.2, vf_coef=0.5, ent_coef=0.01)
    # Two timesteps, one sequence, three actions.
    logits = jnp.array([[[0.0, 1.0, 2.0]], [[1.0, 0.0, 0.0]]])
    value = jnp.array([[1.0], [0.5]])
    action = jnp.array([[2], [0]])
    old_log_prob = jnp.array([[-1.0], [-0.5]])
    old_value = jnp.array([[0.7], [0.9]])
    advantage = jnp.array([[2.0], [-1.0]])
    target = jnp.array([[1.5], [0.0]])
    batch = Batch(
        obs=jnp.zeros((2, 1, 1)),
        first=jnp.zeros((2, 1), bool),
        action=action,
        log_prob=old_log_prob,
        value=old_value,
        advantage=advantage,
        target=target,
        history=jnp.zeros((2, 1, 0), jnp.int32),
        partner_action=jnp.zeros((2, 1), jnp.int32),
        teacher_action=None,
        teacher_coef=None,
        weight=None,
        init_lstm=LSTMState(jnp.zeros((1, 1)), jnp.zeros((1, 1))),
    )
    total, info = ppo_loss({"logits": logits, "value": value}, _FixedOutputs(), batch, cfg)
    pg, vf, ent, kl, clipfrac = (
        info.policy_loss,
        info.value_loss,
        info.entropy,
        info.approx_kl,
        info.clip_fraction,
    )
    assert float(info.total_loss) == float(total) and float(info.grad_norm) == 0.0  # no gradient taken here

    # By hand, in numpy.
    lp = np.asarray(jax.nn.log_softmax(logits))
    new_lp = np.array([lp[0, 0, 2], lp[1, 0, 0]])
    ratio = np.exp(new_lp - np.array([-1.0, -0.5]))
    a = np.array([2.0, -1.0])
    a = (a - a.mean()) / (a.std() + 1e-8)
    pg_want = -np.mean(np.minimum(ratio * a, np.clip(ratio, 0.8, 1.2) * a))
    v, v_old, r = np.array([1.0, 0.5]), np.array([0.7, 0.9]), np.array([1.5, 0.0])
    v_clip = v_old + np.clip(v - v_old, -0.2, 0.2)  # [0.9, 0.7]
    vf_want = 0.5 * np.mean(np.maximum((v - r) ** 2, (v_clip - r) ** 2))
    p = np.exp(lp)
    ent_want = -np.mean(np.sum(p * lp, axis=-1))
    assert float(pg) == pytest.approx(pg_want, rel=1e-5)
    assert float(vf) == pytest.approx(vf_want, rel=1e-5)
    assert float(ent) == pytest.approx(ent_want, rel=1e-5)
    assert float(total) == pytest.approx(pg_want + 0.5 * vf_want - 0.01 * ent_want, rel=1e-5)
    assert float(clipfrac) == pytest.approx(np.mean(np.abs(ratio - 1) > 0.2))
    assert float(info.partner_loss) == 0.0 and float(info.teacher_loss) == 0.0
    assert float(kl) == pytest.approx(np.mean((ratio - 1) - np.log(ratio)), rel=1e-4)
    # weighted (the scripted cook's seat weighs 0): the second step leaves every term
    only_first = batch._replace(weight=jnp.array([[1.0], [0.0]]))
    _, first = ppo_loss({"logits": logits, "value": value}, _FixedOutputs(), only_first, cfg)
    pg1, vf1, ent1 = first.policy_loss, first.value_loss, first.entropy
    assert float(vf1) == pytest.approx(0.5 * max((1.0 - 1.5) ** 2, (0.9 - 1.5) ** 2), rel=1e-5)
    assert float(ent1) == pytest.approx(-np.sum(p[0, 0] * lp[0, 0]), rel=1e-5)
    assert float(pg1) == pytest.approx(0.0, abs=1e-6)  # one step's advantage, normalised alone, is 0


def test_learning_rate_anneals_linearly_to_zero_over_the_run():
    cfg = PPOConfig(lr=1e-3, update_epochs=4, num_minibatches=2)
    _, schedule = make_optimizer(
        cfg, steps_per_update=100, total_env_steps=1000
    )  # 10 updates = 80 grad steps
    assert float(schedule(0)) == pytest.approx(1e-3)
    assert float(schedule(40)) == pytest.approx(5e-4)
    assert float(schedule(80)) == pytest.approx(0.0)
    _, constant = make_optimizer(PPOConfig(anneal_lr=False), 100, 1000)
    assert float(constant(10_000)) == pytest.approx(3e-4)


def test_make_batchs_flags_are_keyword_only():
    """Four booleans in a row are read wrong by position; each flag is named where it is given."""
    params = inspect.signature(make_batch).parameters
    flags = [name for name, p in params.items() if p.default is not inspect.Parameter.empty]
    assert {"learner_seat_only", "mask_scripted_seat", "normalise_apart", "team_shaping"} <= set(flags)
    assert all(params[name].kind is inspect.Parameter.KEYWORD_ONLY for name in flags)
