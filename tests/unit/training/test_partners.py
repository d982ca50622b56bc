"""Partner strategies (FCP, E3T) and CEC-Finetune inside the one rollout and update."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest

from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry
from cec.config import ConfigError, from_dict
from cec.training.config import TrainConfig
from cec.training.partners import PartnerConfig, PopulationEntry, mixture_log_probs
from cec.training.population import load_population
from cec.training.ppo import PPOConfig, make_batch, ppo_loss
from cec.training.rollout import rollout
from cec.training.run import train
from cec.training.trainer import Trainer

NUM_ENVS, NUM_STEPS, EPISODE = 32, 24, 6


def _config(tmp_path, algorithm="ippo", partner=None, **over):
    base = {
        "algorithm": algorithm,
        "num_envs": NUM_ENVS,
        "num_steps": NUM_STEPS,
        "total_env_steps": NUM_ENVS * NUM_STEPS * 2,
        "network": "small",
        "env": {"name": "dual_destination", "levels": "fixed", "dual_destination": {"max_steps": EPISODE}},
        "run_dir": str(tmp_path),
        "name": algorithm,
        "checkpoint": {"every_updates": 0, "milestones": [0.0, 0.5, 1.0]},
    }
    if partner is not None:
        base["partner"] = partner
    base.update(over)
    return from_dict(TrainConfig, base)


@pytest.fixture(scope="module")
def ippo_run(tmp_path_factory):
    """A 2-seed IPPO run on Dual Destination with milestones at updates 0, 1 and 2."""
    cfg = _config(tmp_path_factory.mktemp("pop"), num_seeds=2)
    return train(cfg, progress=False).run_dir


def _rollout(trainer: Trainer, population=None, key=0):
    state = jax.tree.map(lambda x: x[0], trainer.init())
    cfg = trainer.config
    levels = trainer.task.sample_levels(jax.random.PRNGKey(1), jnp.arange(cfg.num_envs), cfg.levels_per_env)
    fn = jax.jit(
        lambda p, c, lv, k, pop: rollout(
            p, c, lv, k, task=trainer.task, network=trainer.network, env_params=trainer.env_params,
            num_steps=cfg.num_steps, partner=cfg.partner, population=pop,
        )
    )  # fmt: skip
    return state, fn(state.params, state.carry, levels, jax.random.PRNGKey(key), population)[1]


def _biased_population(trainer: Trainer, actions: list[int]):
    """Partners that (almost) always play one fixed action each: member p plays actions[p]."""
    members = []
    for i, a in enumerate(actions):
        params = jax.tree.map(lambda x: x[0], trainer.init()).params
        params = jax.tree.map(lambda x: x, params)
        bias = np.zeros(trainer.task.num_actions, np.float32)
        bias[a] = 50.0
        params["params"]["actor_out"]["bias"] = jnp.asarray(bias) + 0 * i
        members.append(params)
    return jax.tree.map(lambda *xs: jnp.stack(xs), *members)


def test_fcp_partners_are_drawn_per_env_and_episode_from_the_population(tmp_path):
    cfg = _config(tmp_path, "fcp", {"kind": "fcp", "population": [{"run": "unused"}]})
    trainer = Trainer(cfg)
    _, traj = _rollout(trainer, _biased_population(trainer, [0, 1, 2]))
    seat = np.asarray(traj.learner_seat)  # [T, E]
    action = np.asarray(traj.action)
    partner_action = np.take_along_axis(action, (1 - seat)[..., None], axis=2)[..., 0]  # [T, E]
    assert set(np.unique(partner_action)) <= {0, 1, 2}  # every partner action is a member's
    episode = np.arange(NUM_STEPS) // EPISODE
    per_episode = {(t // EPISODE, e): set() for t in range(NUM_STEPS) for e in range(NUM_ENVS)}
    for t in range(NUM_STEPS):
        for e in range(NUM_ENVS):
            per_episode[(episode[t], e)].add((int(partner_action[t, e]), int(seat[t, e])))
    assert all(len(v) == 1 for v in per_episode.values())  # one partner and one seat per episode and env
    draws = [next(iter(v)) for v in per_episode.values()]
    members = np.bincount([a for a, _ in draws], minlength=3)
    seats = np.bincount([s for _, s in draws], minlength=2)
    assert members.min() > 0.2 * len(draws) and seats.min() > 0.3 * len(draws)  # per env, not per batch
    first_step = {int(partner_action[0, e]) for e in range(NUM_ENVS)}
    assert len(first_step) == 3  # different envs play different partners in the same rollout
    # the partner seat's stored log-prob is the member's own (near-deterministic) action probability
    partner_lp = np.take_along_axis(np.asarray(traj.log_prob), (1 - seat)[..., None], axis=2)[..., 0]
    assert np.all(partner_lp > -1e-6)


def test_fcp_batch_holds_no_partner_seat_terms(tmp_path):
    cfg = _config(tmp_path, "fcp", {"kind": "fcp", "population": [{"run": "unused"}]})
    trainer = Trainer(cfg)
    state, traj = _rollout(trainer, _biased_population(trainer, [3, 4]))
    batch = make_batch(traj, jnp.float32(1.0), 0.99, 0.95, learner_seat_only=True)
    seat = np.asarray(traj.learner_seat)
    assert batch.action.shape == (NUM_STEPS, NUM_ENVS)  # one sequence per env: the learner's seat
    np.testing.assert_array_equal(
        batch.action, np.take_along_axis(np.asarray(traj.action), seat[..., None], 2)[..., 0]
    )
    # scrambling everything the partner seat did leaves the learner's loss and gradient unchanged
    other = (1 - seat)[..., None]
    rng = np.random.default_rng(0)

    def scramble(x):
        x = np.array(x)
        noise = rng.integers(0, 5, x.shape).astype(x.dtype)
        mask = np.broadcast_to(
            (np.arange(2)[None, None, :] == other).reshape(other.shape[:2] + (2,) + (1,) * (x.ndim - 3)),
            x.shape,
        )
        return np.where(mask, noise, x)

    scrambled = traj._replace(
        obs=scramble(traj.obs), action=scramble(traj.action), log_prob=scramble(traj.log_prob),
        value=scramble(traj.value), shaped=scramble(traj.shaped),
    )  # fmt: skip
    batch2 = make_batch(scrambled, jnp.float32(1.0), 0.99, 0.95, learner_seat_only=True)
    grad = jax.grad(lambda p, b: ppo_loss(p, trainer.network, b, PPOConfig())[0])
    g1, g2 = grad(state.params, batch), grad(state.params, batch2)
    assert all(np.array_equal(a, b) for a, b in zip(jax.tree.leaves(g1), jax.tree.leaves(g2), strict=True))


def test_e3t_with_zero_epsilon_is_self_play(tmp_path):
    sp = Trainer(_config(tmp_path))
    e3t = Trainer(_config(tmp_path, "e3t", {"kind": "e3t", "epsilon": 0.0}))
    _, a = _rollout(sp)
    _, b = _rollout(e3t)
    np.testing.assert_array_equal(a.action, b.action)
    np.testing.assert_array_equal(a.log_prob, b.log_prob)  # behaviour = target policy exactly


def test_e3t_behaviour_log_probs_and_importance_ratio(tmp_path):
    eps = 0.5
    trainer = Trainer(_config(tmp_path, "e3t", {"kind": "e3t", "epsilon": eps}))
    state, traj = _rollout(trainer)
    from cec.agents.network import forward

    # recompute the policy's logits on the stored observations (LSTM replayed from the stored carry)
    t, e = traj.reward.shape
    flat = lambda x: x.reshape((t, e * 2, *x.shape[3:]))  # noqa: E731
    init = jax.tree.map(lambda x: x.reshape((e * 2, -1)), traj.init_lstm)
    _, logits, _ = forward(
        trainer.network, state.params, init, flat(traj.obs), jnp.repeat(traj.first, 2, axis=1)
    )
    logits = logits.reshape((t, e, 2, -1))
    act = np.asarray(traj.action)[..., None]
    pi = np.take_along_axis(np.asarray(jax.nn.log_softmax(logits)), act, -1)[..., 0]
    mix = np.take_along_axis(np.asarray(mixture_log_probs(logits, eps)), act, -1)[..., 0]
    mine = np.arange(2)[None, None, :] == np.asarray(traj.learner_seat)[..., None]
    stored = np.asarray(traj.log_prob)
    np.testing.assert_allclose(stored[mine], pi[mine], atol=1e-5)  # the learner's seat acted with pi
    np.testing.assert_allclose(stored[~mine], mix[~mine], atol=1e-5)  # the partner with the mixture
    np.testing.assert_allclose(np.exp(mix), (1 - eps) * np.exp(pi) + eps / 5, rtol=1e-5)
    # the trained rows are the learner's: before any gradient step the PPO ratio is exactly 1
    batch = make_batch(traj, jnp.float32(1.0), 0.99, 0.95, learner_seat_only=True)
    _, info = ppo_loss(state.params, trainer.network, batch, PPOConfig())
    assert abs(float(info.approx_kl)) < 1e-6 and float(info.clip_fraction) == 0.0


def _scripted_config(tmp_path, **partner):
    return _config(
        tmp_path, "cec_scripted", {"kind": "scripted", "scripted_epsilon": 0.0, **partner},
        env={"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": EPISODE}},
    )  # fmt: skip


@pytest.mark.parametrize("yields", [True, False])
def test_the_scripted_partner_plays_the_cooks_actions_and_the_learner_its_own(tmp_path, yields):
    from cec.envs.overcooked.scripted import scripted_actions, state_from_obs

    trainer = Trainer(_scripted_config(tmp_path, scripted_share=1.0, scripted_yields=yields))
    _, traj = _rollout(trainer)
    seat = np.asarray(traj.learner_seat)  # [T, E]
    partner = 1 - seat
    obs = np.take_along_axis(np.asarray(traj.obs), partner[..., None, None, None, None], axis=2)[:, :, 0]
    # the cook, from the partner seat's observation (that seat as seat 0), is what the partner seat did
    cook = jax.jit(
        jax.vmap(lambda o: scripted_actions(jax.random.PRNGKey(0), state_from_obs(o), 0.0, yields))
    )
    expected = np.asarray(cook(obs.reshape((-1, *obs.shape[2:]))))[:, 0].reshape(seat.shape)
    np.testing.assert_array_equal(
        np.take_along_axis(np.asarray(traj.action), partner[..., None], 2)[..., 0], expected
    )
    # the learner's seat still acts with its policy: untrained, it does not copy the cook
    mine = np.take_along_axis(np.asarray(traj.action), seat[..., None], 2)[..., 0]
    assert (mine != expected).mean() > 0.3
    # only the learner's seat trains
    assert trainer.config.sequences == NUM_ENVS


def test_scripted_partner_share_zero_is_self_play_and_share_half_draws_per_episode(tmp_path):
    cec = Trainer(_config(tmp_path, "cec", env={"name": "overcooked", "levels": "generator",
                                               "overcooked": {"max_steps": EPISODE}}))  # fmt: skip
    _, a = _rollout(cec)
    _, b = _rollout(Trainer(_scripted_config(tmp_path, scripted_share=0.0)))
    np.testing.assert_array_equal(a.action, b.action)  # the same keys: no script, the same game
    _, half = _rollout(Trainer(_scripted_config(tmp_path, scripted_share=0.5)))
    _, full = _rollout(Trainer(_scripted_config(tmp_path, scripted_share=1.0)))
    partner = 1 - np.asarray(half.learner_seat)
    theirs = lambda t: np.take_along_axis(np.asarray(t.action), partner[..., None], 2)[..., 0]  # noqa: E731
    # per episode (EPISODE steps), the partner seat played either the script or the policy throughout
    same = (theirs(half) == theirs(full)).reshape(NUM_STEPS // EPISODE, EPISODE, NUM_ENVS).mean(axis=1)
    scripted_episodes = same == 1.0
    assert 0.3 < scripted_episodes.mean() < 0.7


def test_scripted_both_seats_trains_self_play_episodes_whole_and_masks_only_the_cooks_seat(tmp_path):
    trainer = Trainer(_scripted_config(tmp_path, scripted_share=0.5, scripted_both_seats=True))
    assert trainer.config.sequences == 2 * NUM_ENVS  # both seats are in the batch
    state, traj = _rollout(trainer)
    batch = make_batch(traj, jnp.float32(1.0), 0.99, 0.95, mask_scripted_seat=True)
    seat, cook = np.asarray(traj.learner_seat), np.asarray(traj.partner_index) == 1  # [T, E]
    assert 0.2 < cook.mean() < 0.8
    expected = np.ones((NUM_STEPS, NUM_ENVS, 2))
    expected[cook, 1 - seat[cook]] = 0.0  # the cook's seat in its episodes; every other step weighs 1
    np.testing.assert_array_equal(batch.weight, expected.reshape((NUM_STEPS, 2 * NUM_ENVS)))
    # what the cook's seat did moves neither the loss nor its gradient; the learner's steps do
    grad = jax.grad(lambda p, b: ppo_loss(p, trainer.network, b, PPOConfig())[0])

    noise = jax.random.normal(jax.random.PRNGKey(3), batch.advantage.shape)

    def shifted(where):  # other advantages on those steps (not a constant: normalising removes that)
        return batch._replace(advantage=jnp.where(where, batch.advantage + 3.0 * noise, batch.advantage))

    g = grad(state.params, batch)
    same = grad(state.params, shifted(batch.weight == 0))
    moved = grad(state.params, shifted(batch.weight == 1))
    assert all(
        np.allclose(a, b, atol=1e-6) for a, b in zip(jax.tree.leaves(g), jax.tree.leaves(same), strict=True)
    )
    assert not all(
        np.allclose(a, b, atol=1e-6) for a, b in zip(jax.tree.leaves(g), jax.tree.leaves(moved), strict=True)
    )
    # normalised apart, the trained steps with the cook and those without it have mean 0 and deviation 1
    # each (the cook's spread no longer outweighs self-play's); the cook's own seat is left out of both
    apart = make_batch(traj, jnp.float32(1.0), 0.99, 0.95, mask_scripted_seat=True, normalise_apart=True)
    with_cook = np.repeat(cook, 2, axis=1)
    trained, adv = np.asarray(batch.weight) == 1, np.asarray(apart.advantage)
    for group in (trained & with_cook, trained & ~with_cook):
        assert abs(adv[group].mean()) < 1e-4 and abs(adv[group].std() - 1.0) < 1e-3
    raw = np.asarray(batch.advantage)
    assert raw[trained & with_cook].std() != pytest.approx(raw[trained & ~with_cook].std(), rel=0.05)
    # weights of 1 everywhere are the plain (unweighted) loss
    ones = batch._replace(weight=jnp.ones_like(batch.weight))
    plain = batch._replace(weight=None)
    a, b = (ppo_loss(state.params, trainer.network, x, PPOConfig())[1] for x in (ones, plain))
    np.testing.assert_allclose(np.asarray(a), np.asarray(b), rtol=1e-5, atol=1e-6)


def test_the_scripted_settings_are_refused_for_another_partner_kind():
    with pytest.raises(ConfigError, match="apply to kind scripted; this partner is 'e3t'"):
        PartnerConfig(kind="e3t", scripted_normalise_apart=True)


def test_a_game_without_a_script_refuses_the_scripted_partner(tmp_path):
    with pytest.raises(ConfigError, match="dual_destination has none"):
        _config(
            tmp_path,
            "cec_scripted",
            {"kind": "scripted"},
            env={"name": "dual_destination", "levels": "procedural"},
        )


def test_fcp_trains_with_a_population_of_checkpoints(ippo_run, tmp_path):
    spec = {"kind": "fcp", "population": [{"run": str(ippo_run), "seeds": [0, 1]}]}
    cfg = _config(tmp_path, "fcp", spec)
    pop = load_population(cfg.partner, cfg.env, cfg.network_config, Trainer(cfg).task.obs_shape)
    assert len(pop.names) == 6 and pop.names[0].endswith("/s0/u0")  # 2 seeds x first/middle/last
    first = load_policy(ZooEntry("x", str(ippo_run / "checkpoints/update_000000002"), seed=1)).params
    last = jax.tree.map(lambda x: x[-1], pop.params)  # seed 1 at the last milestone
    assert all(
        np.array_equal(a, b) for a, b in zip(jax.tree.leaves(first), jax.tree.leaves(last), strict=True)
    )
    result = train(cfg, progress=False)
    assert result.updates_done == 2 and (result.run_dir / "metrics.csv").exists()


def test_bad_population_specs_list_every_offending_entry(ippo_run, tmp_path):
    spec = PartnerConfig(
        kind="fcp",
        population=(
            PopulationEntry(run=str(tmp_path / "missing")),
            PopulationEntry(run=str(ippo_run), seeds=(7,), checkpoints=("last",)),
            PopulationEntry(run=str(ippo_run), seeds=(0,), checkpoints=("999",)),
        ),
    )
    cfg = _config(tmp_path, "fcp", {"kind": "fcp", "population": [{"run": str(ippo_run)}]})
    with pytest.raises(ConfigError) as info:
        load_population(spec, cfg.env, cfg.network_config, (5, 5, 4))
    text = str(info.value)
    assert "missing" in text and "seed 7" in text and "'999'" in text
    # a learner with another network cannot use the population
    other = _config(
        tmp_path, "fcp", {"kind": "fcp", "population": [{"run": str(ippo_run)}]}, network="reference"
    )
    with pytest.raises(ConfigError, match="different network"):
        train(other, progress=False)


def test_cec_finetune_starts_from_the_exact_checkpoint_parameters(ippo_run, tmp_path):
    cfg = _config(tmp_path, "cec_finetune", init_from=str(ippo_run), init_from_seed=1, num_seeds=2)
    state = Trainer(cfg).init()
    expected = load_policy(ZooEntry("x", str(ippo_run), seed=1)).params
    for seed in range(2):
        got = jax.tree.map(lambda x, s=seed: np.asarray(x[s]), state.params)
        assert all(
            np.array_equal(a, b) for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True)
        )
    with pytest.raises(ConfigError, match="init_from"):
        _config(tmp_path, "ippo", init_from=str(ippo_run))
    with pytest.raises(ConfigError, match="partner.kind"):
        _config(tmp_path, "fcp")


def test_partner_history_holds_the_partners_last_actions_and_resets_each_episode(tmp_path):
    trainer = Trainer(_config(tmp_path, "e3t", {"kind": "e3t", "epsilon": 0.5, "predict_partner": 3}))
    _, traj = _rollout(trainer)
    hist, action, first = np.asarray(traj.history), np.asarray(traj.action), np.asarray(traj.first)
    assert hist.shape == (NUM_STEPS, NUM_ENVS, 2, 3)
    for t in range(NUM_STEPS):
        start = t - (t % EPISODE)  # episodes are synchronised: EPISODE steps each
        for k in range(3):  # hist[t, e, s, -1 - k] is the partner's action k + 1 steps ago, in this episode
            back = t - 1 - k
            expected = action[back, :, ::-1] if back >= start else np.full((NUM_ENVS, 2), -1)
            np.testing.assert_array_equal(hist[t, :, :, -1 - k], expected)
    assert first[0].all()


def test_partner_model_loss_falls_with_a_fixed_partner(tmp_path):
    """E3T's partner model on a fixed, predictable partner (an FCP population of one member that always
    plays action 3): its cross-entropy falls from chance (log 5) towards 0 within a few updates."""
    spec = {"kind": "fcp", "population": [{"run": "unused"}], "predict_partner": 2}
    cfg = _config(tmp_path, "fcp", spec, total_env_steps=NUM_ENVS * NUM_STEPS * 30, ppo={"lr": 0.003})
    trainer = Trainer(cfg)
    plain = Trainer(_config(tmp_path, "fcp", {"kind": "fcp", "population": [{"run": "unused"}]}))
    trainer.population = _biased_population(plain, [3])  # members have no partner model
    state = trainer.init()
    state, metrics = trainer.train_call(30)(state)
    loss = np.asarray(metrics.loss.partner_loss)[0]
    assert loss[0] > 1.4 and loss[-3:].mean() < 0.3 * loss[0], loss


@pytest.mark.slow
def test_networks_with_and_without_a_partner_model_cross_play_exactly():
    """Cross-play embeds a network into one with a longer partner history by zero weights: same policy."""
    import dataclasses

    from cec.agents.network import ActorCritic, embed_partner_model, forward_partner, network_preset
    from cec.agents.policy import random_policy
    from cec.envs.task import EnvConfig
    from cec.evaluation.crossplay import EvalConfig, crossplay, eval_levels

    base = network_preset("small", "dual_destination")
    rng = np.random.default_rng(0)
    obs = jnp.asarray(rng.normal(size=(3, 4, 5, 5, 4)), jnp.float32)
    reset = jnp.asarray(rng.random((3, 4)) < 0.3)
    history = jnp.asarray(rng.integers(-1, 5, (3, 4, 4)), jnp.int32)
    target = dataclasses.replace(base, partner_history=4)
    big = ActorCritic(target, 5)
    for k in (0, 2):
        small = dataclasses.replace(base, partner_history=k)
        env = EnvConfig(name="dual_destination", levels="fixed")
        policy = random_policy(f"k{k}", jax.random.PRNGKey(k), env=env, network=small)
        net = ActorCritic(small, 5)
        carry = net.initial_carry((4,))
        if k:
            _, logits, value, pred = forward_partner(net, policy.params, carry, obs, reset, history[..., -k:])
        else:
            _, logits, value = net.apply(policy.params, carry, obs, reset)
        embedded = embed_partner_model(policy.params, small, target, 5)
        _, logits2, value2, pred2 = forward_partner(big, embedded, carry, obs, reset, history)
        np.testing.assert_allclose(logits2, logits, atol=1e-6)
        np.testing.assert_allclose(value2, value, atol=1e-6)
        if k:
            np.testing.assert_allclose(pred2, pred, atol=1e-6)
    env = EnvConfig(name="dual_destination", levels="fixed")
    plain = random_policy("ippo", jax.random.PRNGKey(7), env=env, network=base)
    e3t = random_policy("e3t", jax.random.PRNGKey(8), env=env, network=target, algorithm="e3t")
    table = crossplay(
        [plain, e3t], eval_levels("dual_destination", "fixed"), EvalConfig(levels="fixed", episodes=2)
    )
    pair = (table.policy_a == "ippo") & (table.policy_b == "e3t")
    assert not table.skipped and set(table.seat[pair].tolist()) == {0, 1}  # both seat orders played


def test_init_from_one_checkpoint_per_seed_continues_each_seed_from_its_own(ippo_run, tmp_path):
    """`init_from=a,b` (how exported CEC seeds are trained further, one vmapped run): seed i starts from
    checkpoint i's exact parameters; a count that matches neither 1 nor num_seeds is refused up front."""
    first, last = sorted(p for p in (ippo_run / "checkpoints").iterdir() if p.is_dir())[::2][:2]
    cfg = _config(tmp_path, "cec_finetune", init_from=f"{first},{last}", num_seeds=2, init_from_seed=0)
    state = Trainer(cfg).init()
    for seed, path in enumerate((first, last)):
        expected = load_policy(ZooEntry("x", str(path), seed=0)).params
        got = jax.tree.map(lambda x, s=seed: np.asarray(x[s]), state.params)
        assert all(
            np.array_equal(a, b) for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True)
        )
    assert not np.array_equal(*(np.asarray(x) for x in jax.tree.leaves(state.params)[0]))
    with pytest.raises(ConfigError, match="3 checkpoints for 2 seeds"):
        _config(tmp_path, "cec_finetune", init_from=f"{first},{last},{last}", num_seeds=2)
    # one checkpoint of as many seeds as the run and no init_from_seed: a run continued seed by seed
    # (under other settings, e.g. a lever switched on half-way); another count must pick its seed
    both = Trainer(_config(tmp_path, "cec_finetune", init_from=str(last), num_seeds=2)).init()
    for seed in range(2):
        expected = load_policy(ZooEntry("x", str(last), seed=seed)).params
        got = jax.tree.map(lambda x, s=seed: np.asarray(x[s]), both.params)
        assert all(
            np.array_equal(a, b) for a, b in zip(jax.tree.leaves(got), jax.tree.leaves(expected), strict=True)
        )
    with pytest.raises(ConfigError, match="give the entry a `seed`"):
        Trainer(_config(tmp_path, "cec_finetune", init_from=str(last), num_seeds=3)).init()


def test_scripted_where_needed_draws_the_cook_only_in_kitchens_that_need_a_hand_over(tmp_path):
    from cec.envs.overcooked.dynamics import needs_handover
    from cec.envs.overcooked.scripted import state_from_obs

    trainer = Trainer(_scripted_config(tmp_path, scripted_share=1.0, scripted_where_needed=True))
    _, traj = _rollout(trainer)
    obs = np.asarray(traj.obs)[:, :, 0]  # seat 0's view shows the whole kitchen and both seats
    needed = jax.jit(jax.vmap(lambda o: needs_handover(state_from_obs(o))))(obs.reshape((-1, *obs.shape[2:])))
    needed = np.asarray(needed).reshape(NUM_STEPS, NUM_ENVS)
    cook = np.asarray(traj.partner_index) == 1
    np.testing.assert_array_equal(cook, needed)  # share 1: the cook in every such episode, and only there
    assert 0.05 < needed.mean() < 0.6


def test_scripted_where_needed_is_refused_for_a_game_that_cannot_tell(tmp_path, monkeypatch):
    import dataclasses

    from cec.envs import registry

    blind = dataclasses.replace(registry.GAMES["overcooked"], needs_partner=None)
    monkeypatch.setattr(registry, "GAMES", {**registry.GAMES, "overcooked": blind})
    with pytest.raises(ConfigError, match="scripted_where_needed needs a game that tells"):
        _scripted_config(tmp_path, scripted_where_needed=True)
    with pytest.raises(ConfigError, match="apply to kind scripted"):
        PartnerConfig(kind="self_play", scripted_where_needed=True)


def test_an_annealed_scripted_share_falls_from_its_start_to_none_with_the_updates(tmp_path):
    steps_per_update = NUM_ENVS * NUM_STEPS
    annealed = _scripted_config(tmp_path, scripted_share=1.0, scripted_anneal_env_steps=4 * steps_per_update)
    trainer = Trainer(annealed)
    state = jax.tree.map(lambda x: x[0], trainer.init())
    collect = jax.jit(trainer.collect)

    def cook_share(update: int) -> float:
        _, traj = collect(state.params, state.carry, jax.random.PRNGKey(1), jax.random.PRNGKey(2),
                          update_index=jnp.int32(update))  # fmt: skip
        return float((np.asarray(traj.partner_index) == 1).mean())

    # update 0: every episode has the cook; halfway (update 2): about half; from update 4 on: none
    assert cook_share(0) == 1.0
    assert 0.25 < cook_share(2) < 0.75
    assert cook_share(4) == 0.0 and cook_share(9) == 0.0
    # the schedule itself, in env steps
    partner = trainer.config.partner
    np.testing.assert_allclose([float(partner.scripted_share_at(s * steps_per_update)) for s in (0, 1, 4, 8)],
                               [1.0, 0.75, 0.0, 0.0])  # fmt: skip
    with pytest.raises(ConfigError, match="scripted_anneal_env_steps must be >= 0"):
        PartnerConfig(kind="scripted", scripted_anneal_env_steps=-1)
    with pytest.raises(ConfigError, match="apply to kind scripted"):
        PartnerConfig(kind="self_play", scripted_anneal_env_steps=100)


def _teacher_config(tmp_path, **ppo):
    return _config(
        tmp_path, "cec", ppo={"teacher_coef": 1.0, **ppo},
        env={"name": "overcooked", "levels": "generator", "overcooked": {"max_steps": EPISODE}},
    )  # fmt: skip


def test_the_teacher_records_the_cooks_greedy_action_for_each_seat_and_its_loss_pulls_the_policy_there(
    tmp_path,
):
    """Kickstarting (`ppo.teacher_coef`): the trajectory holds, per seat, what the scripted cook would have
    done in that seat's place; an update with only the teacher's loss makes those actions likelier."""
    from cec.envs.overcooked.scripted import scripted_actions, state_from_obs
    from cec.training.ppo import update

    trainer = Trainer(_teacher_config(tmp_path))
    state = jax.tree.map(lambda x: x[0], trainer.init())
    _, traj = jax.jit(trainer.collect)(
        state.params, state.carry, jax.random.PRNGKey(1), jax.random.PRNGKey(2), update_index=jnp.int32(0)
    )
    obs = np.asarray(traj.obs)  # [T, E, 2, ...]: each seat's view, that seat as seat 0
    cook = jax.jit(jax.vmap(lambda o: scripted_actions(jax.random.PRNGKey(0), state_from_obs(o), 0.0)[0]))
    expected = np.asarray(cook(obs.reshape((-1, *obs.shape[3:])))).reshape(obs.shape[:3])
    np.testing.assert_array_equal(np.asarray(traj.teacher_action), expected)
    acted = np.asarray(traj.action)
    assert (acted != expected).mean() > 0.3  # the untrained policy acts on its own, not as the cook

    # the teacher's cross-entropy alone (no policy, value or entropy terms) falls with a few Adam steps
    only_teacher = PPOConfig(vf_coef=0.0, ent_coef=0.0, teacher_coef=1.0)
    batch = make_batch(traj, jnp.float32(1.0), 0.99, 0.95, teacher_coef=jnp.float32(1.0))
    batch = batch._replace(advantage=jnp.zeros_like(batch.advantage))  # no policy gradient either
    adam = optax.adam(0.01)

    def step(params, opt_state, b, i):
        return update(params, opt_state, b, jax.random.PRNGKey(i), network=trainer.network, optimizer=adam,
                      config=only_teacher)  # fmt: skip

    params, opt_state, losses = state.params, adam.init(state.params), []
    for i in range(12):
        params, opt_state, info = step(params, opt_state, batch, i)
        losses.append(float(info.teacher_loss))
    assert losses[0] > 1.6 and losses[-1] < 0.8 * losses[0], losses  # chance: log 6 = 1.79
    # without a teacher the loss has no such term, and the batch needs the recorded actions to have one
    plain = batch._replace(teacher_action=None, teacher_coef=None)
    assert float(step(state.params, adam.init(state.params), plain, 0)[2].teacher_loss) == 0.0
    with pytest.raises(ValueError, match="teacher=True"):
        make_batch(
            traj._replace(teacher_action=None), jnp.float32(1.0), 0.99, 0.95, teacher_coef=jnp.float32(1.0)
        )


def test_the_teachers_weight_anneals_and_a_game_without_a_script_refuses_it(tmp_path):
    ppo = PPOConfig(teacher_coef=2.0, teacher_anneal_env_steps=1000)
    np.testing.assert_allclose(
        [float(ppo.teacher_coef_at(s)) for s in (0, 250, 1000, 5000)], [2.0, 1.5, 0.0, 0.0]
    )
    assert float(PPOConfig(teacher_coef=0.5).teacher_coef_at(10**9)) == 0.5
    with pytest.raises(ConfigError, match="teacher_coef >= 0"):
        PPOConfig(teacher_coef=-1.0)
    with pytest.raises(ConfigError, match="dual_destination has none: set ppo.teacher_coef to 0"):
        _config(tmp_path, "ippo", ppo={"teacher_coef": 1.0})
