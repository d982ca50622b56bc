"""The env adapters: JaxMARL's `MultiAgentEnv` API and a PettingZoo `ParallelEnv` over the one env.

The JaxMARL-style IPPO loop below is written here after the structure of JaxMARL's
`baselines/IPPO/ippo_ff_overcooked.py` (`make_train`: vmapped reset/step, batchify/unbatchify over
`env.agents`, shaped reward annealed into the reward, GAE, clipped PPO epochs over shuffled minibatches,
`LogWrapper`); the only substitutions are a tiny categorical distribution for `distrax.Categorical` (not
installed) and returning the metrics instead of logging them to wandb.
"""

from __future__ import annotations

import math
import warnings
from collections.abc import Callable
from typing import Any, NamedTuple

import flax.linen as nn
import jax
import jax.numpy as jnp
import numpy as np
import optax
import pytest
from flax.linen.initializers import constant, orthogonal
from flax.training.train_state import TrainState

from cec.envs import overcooked as oc
from cec.envs.overcooked.jaxmarl_api import Box, Discrete, OvercookedMultiAgentEnv
from cec.envs.overcooked.scripted import scripted_actions
from cec.levels import GRID_SIZE, LevelError, stack_levels
from cec.levels.generator import GeneratorConfig

# ---------------------------------------------------------------------------------------------------
# The adapter is the env: same key, state and actions -> same step
# ---------------------------------------------------------------------------------------------------


def _lockstep(env: OvercookedMultiAgentEnv, n_steps: int) -> dict[str, jax.Array]:
    """Drives `env.step` with the scripted cook (20% random actions), so that soups are cooked and
    delivered; at every step compares it with `oc.step` and, at episode ends, `env.reset`."""
    h, w = env.obs_shape[:2]

    def run(key: jax.Array) -> dict[str, jax.Array]:
        _, state = env.reset(key)

        def body(state: oc.EnvState, k: jax.Array) -> tuple[oc.EnvState, dict[str, jax.Array]]:
            k_act, k_step = jax.random.split(k)
            joint = scripted_actions(k_act, state, 0.2)
            actions = {a: joint[i] for i, a in enumerate(env.agents)}
            obs, nxt, rew, dones, info = env.step(k_step, state, actions)
            # What the adapter must be: MultiAgentEnv.step's key split, oc.step, then env.reset on done.
            k_env, k_reset = jax.random.split(k_step)
            ref = oc.step(k_env, state, joint, env.params)
            re_obs, re_state = env.reset(k_reset)
            want_state = jax.tree.map(lambda a, b: jnp.where(ref.done, a, b), re_state, ref.state)
            want_obs = jnp.where(ref.done, jnp.stack([re_obs[a] for a in env.agents]), ref.obs[:, :h, :w])
            pairs = zip(jax.tree.leaves(nxt), jax.tree.leaves(want_state), strict=True)
            same_state = jnp.all(jnp.stack([jnp.all(a == b) for a, b in pairs]))
            diffs = {
                "obs": jnp.any(jnp.stack([obs[a] for a in env.agents]) != want_obs),
                "state": ~same_state,
                "reward": jnp.any(jnp.stack([rew[a] for a in env.agents]) != ref.reward),
                "shaped": jnp.any(
                    jnp.stack([info["shaped_reward"][a] for a in env.agents]) != ref.shaped_reward
                ),
                "done": jnp.any(jnp.stack([dones[a] for a in [*env.agents, "__all__"]]) != ref.done),
                "resets": ref.done,
                "sparse": ref.reward > 0,
                "shaped_paid": jnp.any(ref.shaped_reward > 0),
            }
            return nxt, diffs

        _, diffs = jax.lax.scan(body, state, jax.random.split(key, n_steps))
        return {k: jnp.sum(v) for k, v in diffs.items()}

    return jax.device_get(jax.jit(run)(jax.random.PRNGKey(11)))


@pytest.mark.parametrize("source", ["cramped_room", "generator", "batch"])
def test_adapter_step_is_the_env_step_with_jaxmarl_auto_reset(source: str) -> None:
    levels: Any = stack_levels(list(oc.classic_levels().values())) if source == "batch" else source
    env = OvercookedMultiAgentEnv(levels, max_steps=50)
    counts = _lockstep(env, 400)
    assert {k: counts[k] for k in ("obs", "state", "reward", "shaped", "done")} == dict.fromkeys(
        ("obs", "state", "reward", "shaped", "done"), 0
    ), counts
    assert counts["resets"] == 400 // 50  # auto-reset happened, and was checked, 8 times
    assert counts["shaped_paid"] > 0 and counts["sparse"] > 0  # soups were cooked and delivered


def test_fixed_level_reset_is_the_env_reset_and_obs_is_cropped_like_jaxmarl() -> None:
    env = OvercookedMultiAgentEnv("forced_coord")
    level = oc.classic_level("forced_coord")
    key = jax.random.PRNGKey(5)
    obs, state = env.reset(key)
    ref_obs, ref_state = oc.reset(key, level)
    for a, b in zip(jax.tree.leaves(state), jax.tree.leaves(ref_state), strict=True):
        np.testing.assert_array_equal(np.asarray(a), np.asarray(b))
    assert env.obs_shape == (5, 5, 26)
    for i, agent in enumerate(env.agents):
        assert obs[agent].dtype == jnp.uint8 and obs[agent].shape == env.observation_space(agent).shape
        np.testing.assert_array_equal(np.asarray(obs[agent]), np.asarray(ref_obs[i, :5, :5]))
    # The whole frame on request; batches and the generator always give it.
    assert OvercookedMultiAgentEnv("forced_coord", crop=False).obs_shape == (GRID_SIZE, GRID_SIZE, 26)
    assert OvercookedMultiAgentEnv(GeneratorConfig(pots=(1, 2))).obs_shape == (GRID_SIZE, GRID_SIZE, 26)
    with pytest.raises(ValueError, match="crop=True needs one fixed kitchen"):
        OvercookedMultiAgentEnv("generator", crop=True)


def test_spaces_and_attributes_are_jaxmarls() -> None:
    env = OvercookedMultiAgentEnv("cramped_room")
    assert env.agents == ["agent_0", "agent_1"] and env.num_agents == 2
    act, obs = env.action_space(), env.observation_space("agent_1")
    assert isinstance(act, Discrete) and act.n == 6 and act.shape == ()
    assert isinstance(obs, Box) and obs.shape == (4, 5, 26)
    samples = jax.vmap(act.sample)(jax.random.split(jax.random.PRNGKey(0), 512))
    assert set(np.unique(np.asarray(samples)).tolist()) == set(range(6))
    assert bool(obs.contains(env.reset(jax.random.PRNGKey(0))[0]["agent_1"]))
    assert obs.sample(jax.random.PRNGKey(1)).shape == obs.shape
    avail = env.get_avail_actions(env.reset(jax.random.PRNGKey(0))[1])
    assert {k: v.shape for k, v in avail.items()} == {"agent_0": (6,), "agent_1": (6,)}


def test_bad_level_sources_are_refused_naming_the_choices() -> None:
    with pytest.raises(ValueError, match="cramped_room.*'generator'"):
        OvercookedMultiAgentEnv("cramped")
    with pytest.raises(TypeError, match="classic layout name"):
        OvercookedMultiAgentEnv(3)
    broken = oc.classic_level("cramped_room").replace(agent_pos=jnp.array([[0, 0], [1, 3]]))
    with pytest.raises(LevelError, match="agent 0 starts on a counter"):
        OvercookedMultiAgentEnv(broken)


def test_adapter_outputs_have_jaxmarls_structure_and_values() -> None:
    """Beside JaxMARL 0.2.0's own Overcooked on Cramped Room: the same dict keys, shapes and values."""
    pytest.importorskip("jaxmarl", reason="needs the `peers` extra")
    from tests.parity.jaxmarl_bridge import make_jaxmarl_env

    params = oc.EnvParams(random_start_facing=False, max_steps=60)
    env = OvercookedMultiAgentEnv("cramped_room", params=params)
    jm = make_jaxmarl_env("cramped_room", 60, params)

    def run(key: jax.Array) -> tuple[Any, Any, jax.Array]:
        jm_obs, jm_state = jm.reset(key)
        _, state = env.reset(key)
        state = state.replace(agent_dir=jm_state.agent_dir_idx.astype(jnp.int32))  # JaxMARL's facings
        obs = env.get_obs(state)
        first = jnp.any(jnp.stack([obs[a] != jm_obs[a] for a in env.agents]))
        # Interact-heavy random play, so that pots fill and the shaped reward is paid.
        acts = jax.random.randint(key, (59, 2), 0, oc.NUM_ACTIONS)
        acts = jnp.where(jax.random.uniform(key, (59, 2)) < 0.4, oc.Action.INTERACT, acts)

        def body(carry: Any, a: jax.Array) -> tuple[Any, tuple[Any, Any]]:
            state, jm_state = carry
            actions = {"agent_0": a[0], "agent_1": a[1]}
            ours = env.step_env(key, state, actions)
            theirs = jm.step_env(key, jm_state, actions)
            strip = lambda out: (out[0], out[2], out[3], out[4])  # noqa: E731 - everything but the state
            return (ours[1], theirs[1]), (strip(ours), strip(theirs))

        _, (ours, theirs) = jax.lax.scan(body, (state, jm_state), acts)
        return ours, theirs, first

    ours, theirs, first = jax.jit(run)(jax.random.PRNGKey(2))
    assert not bool(first)
    assert jax.tree.structure(ours) == jax.tree.structure(theirs)
    for a, b in zip(jax.tree.leaves(ours), jax.tree.leaves(theirs), strict=True):
        assert a.shape == b.shape
        np.testing.assert_array_equal(np.asarray(a, np.float32), np.asarray(b, np.float32))
    assert float(np.sum(ours[3]["shaped_reward"]["agent_0"] + ours[3]["shaped_reward"]["agent_1"])) > 0


# ---------------------------------------------------------------------------------------------------
# A JaxMARL IPPO loop, unchanged but for the distribution and the logging
# ---------------------------------------------------------------------------------------------------


class Categorical:
    """What the loop uses of `distrax.Categorical`."""

    def __init__(self, logits: jax.Array) -> None:
        self.logits = jax.nn.log_softmax(logits)

    def sample(self, seed: jax.Array) -> jax.Array:
        return jax.random.categorical(seed, self.logits)

    def log_prob(self, value: jax.Array) -> jax.Array:
        return jnp.take_along_axis(self.logits, value[..., None].astype(jnp.int32), axis=-1)[..., 0]

    def entropy(self) -> jax.Array:
        return -jnp.sum(jnp.exp(self.logits) * self.logits, axis=-1)


class ActorCritic(nn.Module):
    action_dim: int
    activation: str = "tanh"

    @nn.compact
    def __call__(self, x: jax.Array) -> tuple[Categorical, jax.Array]:
        act = nn.relu if self.activation == "relu" else nn.tanh
        a = act(nn.Dense(64, kernel_init=orthogonal(np.sqrt(2)), bias_init=constant(0.0))(x))
        a = act(nn.Dense(64, kernel_init=orthogonal(np.sqrt(2)), bias_init=constant(0.0))(a))
        logits = nn.Dense(self.action_dim, kernel_init=orthogonal(0.01), bias_init=constant(0.0))(a)
        c = act(nn.Dense(64, kernel_init=orthogonal(np.sqrt(2)), bias_init=constant(0.0))(x))
        c = act(nn.Dense(64, kernel_init=orthogonal(np.sqrt(2)), bias_init=constant(0.0))(c))
        value = nn.Dense(1, kernel_init=orthogonal(1.0), bias_init=constant(0.0))(c)
        return Categorical(logits), jnp.squeeze(value, axis=-1)


class Transition(NamedTuple):
    done: jax.Array
    action: jax.Array
    value: jax.Array
    reward: jax.Array
    log_prob: jax.Array
    obs: jax.Array


def batchify(x: dict[str, jax.Array], agent_list: list[str], num_actors: int) -> jax.Array:
    stacked = jnp.stack([x[a] for a in agent_list])
    return stacked.reshape((num_actors, -1))


def unbatchify(x: jax.Array, agent_list: list[str], num_envs: int, num_actors: int) -> dict[str, jax.Array]:
    x = x.reshape((num_actors, num_envs, -1))
    return {a: x[i] for i, a in enumerate(agent_list)}


def make_train(config: dict[str, Any], env: Any) -> Callable[[jax.Array], dict[str, Any]]:
    """JaxMARL's `make_train`, with `env` passed in where it calls `jaxmarl.make(...)`."""
    config["NUM_ACTORS"] = env.num_agents * config["NUM_ENVS"]
    config["NUM_UPDATES"] = config["TOTAL_TIMESTEPS"] // config["NUM_STEPS"] // config["NUM_ENVS"]
    config["MINIBATCH_SIZE"] = config["NUM_ACTORS"] * config["NUM_STEPS"] // config["NUM_MINIBATCHES"]
    if config["LOG_WRAPPER"]:
        from jaxmarl.wrappers.baselines import LogWrapper

        env = LogWrapper(env, replace_info=False)

    def linear_schedule(count: jax.Array) -> jax.Array:
        frac = 1.0 - (count // (config["NUM_MINIBATCHES"] * config["UPDATE_EPOCHS"])) / config["NUM_UPDATES"]
        return config["LR"] * frac

    rew_shaping_anneal = optax.linear_schedule(
        init_value=1.0, end_value=0.0, transition_steps=config["REW_SHAPING_HORIZON"]
    )

    def train(rng: jax.Array) -> dict[str, Any]:
        # INIT NETWORK (JaxMARL calls the spaces without an agent)
        network = ActorCritic(env.action_space().n, activation=config["ACTIVATION"])
        rng, _rng = jax.random.split(rng)
        init_x = jnp.zeros(env.observation_space().shape).flatten()
        network_params = network.init(_rng, init_x)
        tx = optax.chain(
            optax.clip_by_global_norm(config["MAX_GRAD_NORM"]),
            optax.adam(learning_rate=linear_schedule if config["ANNEAL_LR"] else config["LR"], eps=1e-5),
        )
        train_state = TrainState.create(apply_fn=network.apply, params=network_params, tx=tx)

        # INIT ENV
        rng, _rng = jax.random.split(rng)
        reset_rng = jax.random.split(_rng, config["NUM_ENVS"])
        obsv, env_state = jax.vmap(env.reset, in_axes=(0,))(reset_rng)

        def _update_step(runner_state: Any, unused: Any) -> tuple[Any, Any]:
            def _env_step(runner_state: Any, unused: Any) -> tuple[Any, Any]:
                train_state, env_state, last_obs, update_step, rng = runner_state
                rng, _rng = jax.random.split(rng)
                obs_batch = batchify(last_obs, env.agents, config["NUM_ACTORS"])
                # (JaxMARL prints this shape here)
                assert obs_batch.shape == (config["NUM_ACTORS"], math.prod(env.observation_space().shape))
                pi, value = network.apply(train_state.params, obs_batch)
                action = pi.sample(seed=_rng)
                log_prob = pi.log_prob(action)
                env_act = unbatchify(action, env.agents, config["NUM_ENVS"], env.num_agents)
                env_act = {k: v.flatten() for k, v in env_act.items()}

                rng, _rng = jax.random.split(rng)
                rng_step = jax.random.split(_rng, config["NUM_ENVS"])
                obsv, env_state, reward, done, info = jax.vmap(env.step, in_axes=(0, 0, 0))(
                    rng_step, env_state, env_act
                )
                info["reward"] = reward["agent_0"]
                current_timestep = update_step * config["NUM_STEPS"] * config["NUM_ENVS"]
                reward = jax.tree.map(
                    lambda x, y: x + y * rew_shaping_anneal(current_timestep), reward, info["shaped_reward"]
                )
                transition = Transition(
                    batchify(done, env.agents, config["NUM_ACTORS"]).squeeze(),
                    action,
                    value,
                    batchify(reward, env.agents, config["NUM_ACTORS"]).squeeze(),
                    log_prob,
                    obs_batch,
                )
                runner_state = (train_state, env_state, obsv, update_step, rng)
                return runner_state, (transition, info)

            runner_state, (traj_batch, info) = jax.lax.scan(
                _env_step, runner_state, None, config["NUM_STEPS"]
            )

            # CALCULATE ADVANTAGE
            train_state, env_state, last_obs, update_step, rng = runner_state
            last_obs_batch = batchify(last_obs, env.agents, config["NUM_ACTORS"])
            _, last_val = network.apply(train_state.params, last_obs_batch)

            def _calculate_gae(traj_batch: Transition, last_val: jax.Array) -> tuple[jax.Array, jax.Array]:
                def _get_advantages(gae_and_next_value: Any, transition: Transition) -> tuple[Any, jax.Array]:
                    gae, next_value = gae_and_next_value
                    done, value, reward = transition.done, transition.value, transition.reward
                    delta = reward + config["GAMMA"] * next_value * (1 - done) - value
                    gae = delta + config["GAMMA"] * config["GAE_LAMBDA"] * (1 - done) * gae
                    return (gae, value), gae

                _, advantages = jax.lax.scan(
                    _get_advantages,
                    (jnp.zeros_like(last_val), last_val),
                    traj_batch,
                    reverse=True,
                    unroll=16,
                )
                return advantages, advantages + traj_batch.value

            advantages, targets = _calculate_gae(traj_batch, last_val)

            # UPDATE NETWORK
            def _update_epoch(update_state: Any, unused: Any) -> tuple[Any, Any]:
                def _update_minbatch(train_state: TrainState, batch_info: Any) -> tuple[TrainState, Any]:
                    traj_batch, advantages, targets = batch_info

                    def _loss_fn(
                        params: Any, traj_batch: Transition, gae: jax.Array, targets: jax.Array
                    ) -> Any:
                        pi, value = network.apply(params, traj_batch.obs)
                        log_prob = pi.log_prob(traj_batch.action)

                        value_pred_clipped = traj_batch.value + (value - traj_batch.value).clip(
                            -config["CLIP_EPS"], config["CLIP_EPS"]
                        )
                        value_losses = jnp.square(value - targets)
                        value_losses_clipped = jnp.square(value_pred_clipped - targets)
                        value_loss = 0.5 * jnp.maximum(value_losses, value_losses_clipped).mean()

                        ratio = jnp.exp(log_prob - traj_batch.log_prob)
                        gae = (gae - gae.mean()) / (gae.std() + 1e-8)
                        loss_actor1 = ratio * gae
                        loss_actor2 = (
                            jnp.clip(ratio, 1.0 - config["CLIP_EPS"], 1.0 + config["CLIP_EPS"]) * gae
                        )
                        loss_actor = -jnp.minimum(loss_actor1, loss_actor2).mean()
                        entropy = pi.entropy().mean()

                        total_loss = (
                            loss_actor + config["VF_COEF"] * value_loss - config["ENT_COEF"] * entropy
                        )
                        return total_loss, (value_loss, loss_actor, entropy)

                    grad_fn = jax.value_and_grad(_loss_fn, has_aux=True)
                    total_loss, grads = grad_fn(train_state.params, traj_batch, advantages, targets)
                    train_state = train_state.apply_gradients(grads=grads)
                    return train_state, total_loss

                train_state, traj_batch, advantages, targets, rng = update_state
                rng, _rng = jax.random.split(rng)
                batch_size = config["MINIBATCH_SIZE"] * config["NUM_MINIBATCHES"]
                assert batch_size == config["NUM_STEPS"] * config["NUM_ACTORS"]
                permutation = jax.random.permutation(_rng, batch_size)
                batch = (traj_batch, advantages, targets)
                batch = jax.tree.map(lambda x: x.reshape((batch_size,) + x.shape[2:]), batch)
                shuffled_batch = jax.tree.map(lambda x: jnp.take(x, permutation, axis=0), batch)
                minibatches = jax.tree.map(
                    lambda x: jnp.reshape(x, [config["NUM_MINIBATCHES"], -1] + list(x.shape[1:])),
                    shuffled_batch,
                )
                train_state, total_loss = jax.lax.scan(_update_minbatch, train_state, minibatches)
                update_state = (train_state, traj_batch, advantages, targets, rng)
                return update_state, total_loss

            update_state = (train_state, traj_batch, advantages, targets, rng)
            update_state, loss_info = jax.lax.scan(_update_epoch, update_state, None, config["UPDATE_EPOCHS"])
            train_state = update_state[0]
            metric = info
            current_timestep = update_step * config["NUM_STEPS"] * config["NUM_ENVS"]
            metric["shaped_reward"] = metric["shaped_reward"]["agent_0"]
            metric["shaped_reward_annealed"] = metric["shaped_reward"] * rew_shaping_anneal(current_timestep)
            rng = update_state[-1]
            update_step = update_step + 1
            metric = jax.tree.map(lambda x: x.mean(), metric)
            metric["update_step"] = update_step
            metric["env_step"] = update_step * config["NUM_STEPS"] * config["NUM_ENVS"]
            metric["total_loss"] = loss_info[0].mean()  # instead of wandb.log(metric)
            runner_state = (train_state, env_state, last_obs, update_step, rng)
            return runner_state, metric

        rng, _rng = jax.random.split(rng)
        runner_state = (train_state, env_state, obsv, 0, _rng)
        runner_state, metric = jax.lax.scan(_update_step, runner_state, None, config["NUM_UPDATES"])
        return {"runner_state": runner_state, "metrics": metric}

    return train


CONFIG = {
    "LR": 2.5e-4,
    "NUM_ENVS": 4,
    "NUM_STEPS": 32,
    "TOTAL_TIMESTEPS": 4 * 32 * 3,  # 3 updates
    "UPDATE_EPOCHS": 2,
    "NUM_MINIBATCHES": 2,
    "GAMMA": 0.99,
    "GAE_LAMBDA": 0.95,
    "CLIP_EPS": 0.2,
    "ENT_COEF": 0.01,
    "VF_COEF": 0.5,
    "MAX_GRAD_NORM": 0.5,
    "ACTIVATION": "tanh",
    "ANNEAL_LR": True,
    "REW_SHAPING_HORIZON": 2_500_000,
}


@pytest.mark.parametrize(
    ("levels", "log_wrapper"),
    [("cramped_room", True), ("generator", False)],
    ids=["cramped_room-LogWrapper", "generator"],
)
def test_jaxmarl_ippo_loop_trains_on_the_adapter(levels: str, log_wrapper: bool) -> None:
    if log_wrapper:
        pytest.importorskip("jaxmarl", reason="JaxMARL's LogWrapper needs the `peers` extra")
    env = OvercookedMultiAgentEnv(levels, max_steps=20)  # short episodes: several end in every rollout
    config = {**CONFIG, "LOG_WRAPPER": log_wrapper}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", DeprecationWarning)
        train = jax.jit(make_train(config, env))
        out = jax.device_get(train(jax.random.PRNGKey(0)))
    metrics = out["metrics"]
    assert config["NUM_UPDATES"] == 3
    assert np.asarray(metrics["update_step"]).tolist() == [1, 2, 3]
    assert np.all(np.isfinite(metrics["total_loss"]))
    assert np.all(np.isfinite(metrics["shaped_reward"]))
    final_obs = out["runner_state"][2]
    assert {k: v.shape for k, v in final_obs.items()} == {
        a: (config["NUM_ENVS"], *env.obs_shape) for a in env.agents
    }
    if log_wrapper:  # JaxMARL's LogWrapper saw the adapter's episodes end (20 steps, 32-step rollouts)
        assert np.all(metrics["returned_episode"] > 0)
        assert np.all(metrics["returned_episode_lengths"] > 0)
    # The parameters moved.
    params = out["runner_state"][0].params
    assert all(np.all(np.isfinite(x)) for x in jax.tree.leaves(params))


# ---------------------------------------------------------------------------------------------------
# PettingZoo
# ---------------------------------------------------------------------------------------------------


def test_pettingzoo_parallel_api_and_seed_tests_pass() -> None:
    pytest.importorskip("pettingzoo", reason="needs the `pettingzoo` extra")
    from pettingzoo.test import parallel_api_test, parallel_seed_test

    from cec.envs.overcooked.pettingzoo_api import OvercookedParallelEnv

    env = OvercookedParallelEnv("cramped_room", max_steps=40)
    parallel_api_test(env, num_cycles=100)
    parallel_seed_test(lambda: OvercookedParallelEnv("generator", max_steps=30), num_cycles=60)


def test_pettingzoo_env_plays_the_env_and_refuses_bad_input() -> None:
    pytest.importorskip("pettingzoo", reason="needs the `pettingzoo` extra")
    from cec.envs.overcooked.pettingzoo_api import OvercookedParallelEnv

    env = OvercookedParallelEnv("cramped_room", max_steps=5, render_mode="rgb_array", tile_size=16)
    obs, infos = env.reset(seed=1)
    assert set(obs) == set(env.possible_agents) and set(infos) == set(env.possible_agents)
    assert all(
        isinstance(o, np.ndarray) and o.dtype == np.uint8 and o.shape == (4, 5, 26) for o in obs.values()
    )
    assert all(env.observation_space(a).contains(obs[a]) for a in env.agents)
    frame = env.render()
    assert isinstance(frame, np.ndarray) and frame.shape == (4 * 16, 5 * 16, 3)

    # Same seed, same start; the dynamics are the one env's.
    _, state = env.env.reset(jax.random.split(jax.random.PRNGKey(1))[1])
    np.testing.assert_array_equal(obs["agent_0"], np.asarray(env.env.get_obs(state)["agent_0"]))
    ref = oc.step(jax.random.PRNGKey(0), state, jnp.array([oc.Action.RIGHT, oc.Action.LEFT]), env.env.params)
    obs, rew, term, trunc, info = env.step({"agent_0": 2, "agent_1": np.int64(3)})
    np.testing.assert_array_equal(obs["agent_1"], np.asarray(ref.obs[1, :4, :5]))
    assert rew == {"agent_0": 0.0, "agent_1": 0.0} and not any(term.values()) and not any(trunc.values())
    assert info == {"agent_0": {"shaped_reward": 0.0}, "agent_1": {"shaped_reward": 0.0}}

    with pytest.raises(ValueError, match="no action for"):
        env.step({"agent_0": 0})
    with pytest.raises(ValueError, match="one integer in 0..5"):
        env.step({"agent_0": 6, "agent_1": 0})
    with pytest.raises(ValueError, match="one integer in 0..5"):
        env.step({"agent_0": 1.0, "agent_1": 0})
    for _ in range(4):
        _, _, term, trunc, _ = env.step({"agent_0": 4, "agent_1": 4})
    assert trunc == {"agent_0": True, "agent_1": True} and term == {"agent_0": False, "agent_1": False}
    assert env.agents == []
    with pytest.raises(RuntimeError, match="call reset"):
        env.step({})
    with pytest.raises(ValueError, match="render_mode"):
        OvercookedParallelEnv(render_mode="human")
    text = OvercookedParallelEnv(render_mode="ansi")
    text.reset(seed=0)
    assert "seat 0" in str(text.render())


@pytest.mark.parametrize("bad", [jnp.float32(2.7), jnp.float32(jnp.nan), jnp.bool_(True)])
def test_the_jaxmarl_adapter_refuses_actions_that_are_not_integers(bad: jax.Array) -> None:
    """A cast would play NaN as `up` and 2.7 as `right`: a non-integer action is refused, naming the agent
    (in `jit` too: the dtype is known while tracing)."""
    env = OvercookedMultiAgentEnv("cramped_room", max_steps=50)
    key = jax.random.PRNGKey(0)
    _, state = env.reset(key)
    actions = {env.agents[0]: jnp.int32(4), env.agents[1]: bad}
    with pytest.raises(TypeError, match=rf"the action of {env.agents[1]} must be an integer"):
        env.step(key, state, actions)
    env.step(key, state, {env.agents[0]: 4, env.agents[1]: jnp.int32(5)})  # Python and JAX integers play
