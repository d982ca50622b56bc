"""Behaviour cloning of recorded human play: human proxies, the field's stand-in for people.

A proxy is our policy network (the CEC CPU recipe's: egocentric view, per-cell embedding, MLP) trained by
cross-entropy to predict each seat's recorded action from that seat's observation of the recorded state.
It trains on the train games and keeps the parameters of the epoch with the lowest cross-entropy on the
test games (early stopping). Both seats of every step are samples; an observation is computed exactly as
in play, with the game's own length as the episode length (the urgency channel).

A proxy is saved as a one-seed parameter checkpoint (`cec.agents.policy.save_policy`), algorithm
`human_proxy`, so it loads as a zoo entry like any trained agent (`cec eval --zoo`, `cec play`).
"""

from __future__ import annotations

import math
import sys
from dataclasses import dataclass
from functools import cache, partial
from typing import Any, TextIO

import jax
import jax.numpy as jnp
import numpy as np
import optax

from cec.agents.network import ActorCritic, NetworkConfig, forward, init_params
from cec.config import ConfigError
from cec.envs.overcooked.observation import get_obs
from cec.envs.overcooked.state import NUM_ACTIONS, EnvParams, EnvState
from cec.humans.data import KITCHENS, Steps
from cec.levels.classic import classic_level

#: The network of the CEC CPU recipe (configs/train/cec_overcooked_cpu.yaml), so proxies see as CEC does.
PROXY_NETWORK = NetworkConfig(
    conv_features=(),
    encoder_features=(128, 128),
    lstm_features=0,
    actor_features=(64,),
    critic_features=(64,),
    egocentric=True,
    cell_features=8,
)


@dataclass(frozen=True)
class BCConfig:
    """Training settings of one proxy.

    Attributes:
        epochs: passes over the train samples (the best epoch on the test games is kept).
        batch_size: samples per gradient step.
        lr: Adam learning rate.
        seed: parameter initialisation and sample order.
        network: the proxy's network; a proxy plays only with agents of the same architecture (cross-play
            batches both seats through one), so clone with theirs (`cec humans bc --preset`). Feed-forward
            only: proxies are cloned step by step, and an LSTM would play with a memory it never trained.
    """

    epochs: int = 30
    batch_size: int = 512
    lr: float = 1e-3
    seed: int = 0
    network: NetworkConfig = PROXY_NETWORK

    def __post_init__(self) -> None:
        if self.network.lstm_features:
            raise ConfigError(
                f"a human proxy's network has no memory (it is cloned step by step), this one has an LSTM of "
                f"{self.network.lstm_features}: pick a preset with lstm_features 0 (e.g. "
                "configs/train/cec_overcooked_cpu.yaml)"
            )
        if self.epochs < 1 or self.batch_size < 1 or self.lr <= 0:
            raise ConfigError(f"epochs and batch_size must be >= 1 and lr > 0, got {self}")


@dataclass(frozen=True)
class Samples:
    """(observation, action) pairs, one per seat and recorded step: obs uint8[M, 9, 9, 26], actions
    int32[M], with each sample's kitchen code and participant id."""

    obs: np.ndarray
    actions: np.ndarray
    kitchen: np.ndarray
    participant: np.ndarray

    def __len__(self) -> int:
        return int(self.actions.shape[0])

    def select(self, mask: np.ndarray) -> Samples:
        return Samples(self.obs[mask], self.actions[mask], self.kitchen[mask], self.participant[mask])


def samples(steps: Steps, *, batch: int = 4096) -> Samples:
    """Both seats' observations and recorded actions of every step."""
    length = np.zeros(len(steps), np.int32)
    for trial in np.unique(steps.trial):
        here = steps.trial == trial
        length[here] = steps.time[here].max() + 1
    obs = []
    for start in range(0, len(steps), batch):
        s = slice(start, start + batch)
        part = steps.select(s)
        kitchen = part.kitchen.astype(np.int32)
        obs.append(np.asarray(_observe(_levels(), kitchen, length[s], *part.state_fields())))
    both = np.concatenate(obs)  # [N, 2, 9, 9, 26]
    return Samples(
        obs=both.reshape((-1, *both.shape[2:])),
        actions=steps.actions.astype(np.int32).reshape(-1),
        kitchen=np.repeat(steps.kitchen, 2),
        participant=np.repeat(steps.participant, 2),
    )


@cache
def _levels() -> Any:
    levels = [classic_level(k) for k in KITCHENS]
    return jax.tree.map(lambda *xs: np.stack([np.asarray(x) for x in xs]), *levels)


@jax.jit
def _observe(levels, kitchen, length, *state):  # type: ignore[no-untyped-def]
    level = jax.tree.map(lambda x: x[kitchen], levels)
    return _observe_states(EnvState(level, *state), length)


def seat_observations(states: EnvState, length: np.ndarray) -> np.ndarray:
    """Both seats' observations, uint8[N, 2, 9, 9, 26], of a batch of states (every leaf, the level's
    included, with a leading axis N), each as in play with `length[i]` its episode length: the
    observations `samples` computes, for states recorded elsewhere (`cec play`'s rounds)."""
    return np.asarray(_observe_states(states, np.asarray(length, np.int32)))


@jax.jit
def _observe_states(states, length):  # type: ignore[no-untyped-def]
    def one(state, length):  # type: ignore[no-untyped-def]
        return get_obs(state, EnvParams(max_steps=length))

    return jax.vmap(one)(states, length)


@dataclass(frozen=True)
class BCResult:
    """A trained proxy: parameters of the best epoch and its figures (per epoch: train and test
    cross-entropy, test accuracy)."""

    params: Any
    best_epoch: int
    test_cross_entropy: float
    test_accuracy: float
    history: list[dict[str, float]]


def train_bc(
    train: Samples, test: Samples, config: BCConfig = BCConfig(), *, log: TextIO = sys.stderr, label: str = ""
) -> BCResult:
    """Trains one proxy on `train`, early-stopped on `test` (lowest cross-entropy)."""
    net = ActorCritic(config.network, NUM_ACTIONS)
    key = jax.random.PRNGKey(config.seed)
    key, k_init = jax.random.split(key)
    params = init_params(net, k_init, train.obs.shape[1:])
    opt = optax.adam(config.lr)
    opt_state = opt.init(params)
    step = _train_step(net, opt)
    rng = np.random.default_rng(config.seed)
    best: tuple[float, int, float, Any] = (math.inf, -1, 0.0, params)
    history = []
    per_epoch = max(1, len(train) // config.batch_size)
    for epoch in range(1, config.epochs + 1):
        order = rng.permutation(len(train))
        losses = []
        for b in range(per_epoch):
            idx = order[b * config.batch_size : (b + 1) * config.batch_size]
            params, opt_state, loss = step(params, opt_state, train.obs[idx], train.actions[idx])
            losses.append(float(loss))
        ce, acc = evaluate_bc(params, test, config.network)
        history.append({"epoch": epoch, "train_ce": float(np.mean(losses)), "test_ce": ce, "test_acc": acc})
        print(
            f"[bc{(' ' + label) if label else ''}] epoch {epoch}/{config.epochs}: train CE "
            f"{np.mean(losses):.3f}, test CE {ce:.3f}, test accuracy {acc:.3f}",
            file=log,
            flush=True,
        )
        if ce < best[0]:
            best = (ce, epoch, acc, params)
    ce, epoch, acc, params = best
    return BCResult(jax.tree.map(np.asarray, params), epoch, ce, acc, history)


def evaluate_bc(
    params: Any, data: Samples, network: NetworkConfig = PROXY_NETWORK, *, batch: int = 8192
) -> tuple[float, float]:
    """(mean cross-entropy, accuracy of the most likely action) of `params` (of `network`) on `data`."""
    net = ActorCritic(network, NUM_ACTIONS)
    ce_sum, hits = 0.0, 0
    for start in range(0, len(data), batch):
        logits = _logits(net, params, data.obs[start : start + batch])
        actions = jnp.asarray(data.actions[start : start + batch])
        ce_sum += float(optax.softmax_cross_entropy_with_integer_labels(logits, actions).sum())
        hits += int((jnp.argmax(logits, axis=-1) == actions).sum())
    return ce_sum / len(data), hits / len(data)


@partial(jax.jit, static_argnums=0)
def _logits(net: ActorCritic, params: Any, obs: jax.Array) -> jax.Array:
    carry = net.initial_carry((obs.shape[0],))
    _, logits, _ = forward(net, params, carry, obs[None], jnp.zeros((1, obs.shape[0]), bool))
    return logits[0]


def _train_step(net: ActorCritic, opt: optax.GradientTransformation) -> Any:
    def loss_fn(params: Any, obs: jax.Array, actions: jax.Array) -> jax.Array:
        logits = _logits(net, params, obs)
        return optax.softmax_cross_entropy_with_integer_labels(logits, actions).mean()

    @jax.jit
    def step(params: Any, opt_state: Any, obs: jax.Array, actions: jax.Array) -> Any:
        loss, grads = jax.value_and_grad(loss_fn)(params, obs, actions)
        updates, opt_state = opt.update(grads, opt_state, params)
        return optax.apply_updates(params, updates), opt_state, loss

    return step
