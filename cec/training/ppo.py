"""The one PPO update: GAE, clipped policy and value losses, entropy bonus, minibatches over whole sequences.

`update(...)` is used by the single-process trainer and by the distributed learner (DESIGN.md rule 4).
Each (env, seat) pair of a `Trajectory` is one sequence of T steps; minibatches hold whole sequences,
and the LSTM is replayed from the sequence's stored initial state with the stored episode-start flags,
so the replayed policy is exactly the behaviour policy at the first epoch (ratio 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import optax
from jax.sharding import Mesh, PartitionSpec

from cec.agents.network import ActorCritic, LSTMState, forward, forward_partner
from cec.config import ConfigError
from cec.training.rollout import NUM_SEATS, Trajectory
from cec.training.schedules import anneal_to_zero

#: The range of each PPO setting with one (name, low, high, low excluded): the weights of the loss's terms
#: are at most `MAX_WEIGHT` (the paper's are 0.005-1), Adam's step at most 1, the counts of env steps at
#: most what a checkpoint can record.
MAX_WEIGHT = 1e3
MAX_ENV_STEPS = 10**15
RANGES: tuple[tuple[str, float, float, bool], ...] = (
    ("lr", 0.0, 1.0, True),
    ("update_epochs", 1, 1_000, False),
    ("num_minibatches", 1, 1 << 16, False),
    ("clip_eps", 0.0, 10.0, True),
    ("ent_coef", 0.0, MAX_WEIGHT, False),
    ("vf_coef", 0.0, MAX_WEIGHT, False),
    ("partner_coef", 0.0, MAX_WEIGHT, False),
    ("teacher_coef", 0.0, MAX_WEIGHT, False),
    ("max_grad_norm", 0.0, 1e6, True),
    ("adam_eps", 0.0, 1.0, True),  # 0: a parameter with no gradient yet divides 0 by 0 (NaN)
    ("lr_anneal_env_steps", 0, MAX_ENV_STEPS, False),
    ("shaping_anneal_env_steps", -MAX_ENV_STEPS, MAX_ENV_STEPS, False),  # < 0: kept at 1
    ("teacher_anneal_env_steps", 0, MAX_ENV_STEPS, False),
)


@dataclass(frozen=True)
class PPOConfig:
    """PPO hyper-parameters; the defaults are the paper's PPO table (and its code's Adam settings).

    Attributes:
        lr: initial Adam learning rate.
        anneal_lr: linearly anneal the learning rate to 0 over `lr_anneal_env_steps`.
        lr_anneal_env_steps: env steps over which the learning rate reaches 0 (0: the run's total).
        update_epochs: passes over each rollout's data.
        num_minibatches: minibatches per epoch (whole env-seat sequences each).
        gamma: discount factor.
        gae_lambda: GAE lambda.
        clip_eps: PPO ratio clip, also the value clip.
        clip_value: clip the value loss around the behaviour values (PPO's value clipping, on in the paper's
            code); it limits how far the critic moves per update, which slows learning of large returns.
        ent_coef: entropy bonus coefficient.
        vf_coef: value loss coefficient.
        max_grad_norm: global gradient-norm clip.
        adam_eps: Adam epsilon.
        shaping_anneal_env_steps: env steps over which the shaped-reward weight falls linearly from 1 to 0
            (0: half of the run's total, as the paper's code; a negative value keeps it at 1).
        partner_coef: weight of the partner model's cross-entropy loss (networks with one: E3T).
        team_shaping: each seat is paid both seats' shaped rewards (the team's), not only its own; the paper
            (as JaxMARL) pays each seat its own. With its own only, a seat that puts an item where its partner
            uses it is paid nothing until a soup is delivered tens of steps later.
        teacher_coef: weight of a teacher loss, the cross-entropy of the game's scripted policy's action
            (`Game.scripted`, greedy) at each trained step under the learner's policy: the policy is pulled
            towards what the script would do in its place (kickstarting), beside the PPO objective. 0: none.
            Not in the paper.
        teacher_anneal_env_steps: > 0: the teacher's weight falls linearly from `teacher_coef` to 0 over this
            many env steps (`teacher_coef_at`); 0: it stays at `teacher_coef`.
    """

    lr: float = 3e-4
    anneal_lr: bool = True
    lr_anneal_env_steps: int = 0
    update_epochs: int = 4
    num_minibatches: int = 2
    gamma: float = 0.99
    gae_lambda: float = 0.95
    clip_eps: float = 0.2
    clip_value: bool = True
    ent_coef: float = 0.005
    vf_coef: float = 1.0
    max_grad_norm: float = 0.5
    adam_eps: float = 1e-5
    shaping_anneal_env_steps: int = 0
    partner_coef: float = 1.0
    team_shaping: bool = False
    teacher_coef: float = 0.0
    teacher_anneal_env_steps: int = 0

    def __post_init__(self) -> None:
        if self.lr <= 0 or self.update_epochs < 1 or self.num_minibatches < 1:
            raise ConfigError(f"ppo: lr must be > 0 and update_epochs, num_minibatches >= 1 (got {self})")
        if not (0 < self.gamma <= 1 and 0 <= self.gae_lambda <= 1 and self.clip_eps > 0):
            raise ConfigError("ppo: need 0 < gamma <= 1, 0 <= gae_lambda <= 1 and clip_eps > 0")
        if self.max_grad_norm <= 0 or min(self.ent_coef, self.vf_coef, self.partner_coef, self.adam_eps) < 0:
            raise ConfigError(
                "ppo: need max_grad_norm > 0 and ent_coef, vf_coef, partner_coef, adam_eps >= 0 "
                f"(got max_grad_norm={self.max_grad_norm}, ent_coef={self.ent_coef}, vf_coef={self.vf_coef}, "
                f"partner_coef={self.partner_coef}, adam_eps={self.adam_eps})"
            )
        if self.teacher_coef < 0 or self.teacher_anneal_env_steps < 0:
            raise ConfigError(
                "ppo: need teacher_coef >= 0 (0: no teacher) and teacher_anneal_env_steps >= 0 "
                f"(0: no anneal), got {self.teacher_coef} and {self.teacher_anneal_env_steps}"
            )
        # Then finite ranges: a weight far past any that trains (ppo.teacher_coef=1e30) overflows the
        # float32 gradients (grad_norm inf on every update) instead of failing here.
        for key, lo, hi, open_low in RANGES:
            value = getattr(self, key)
            if not (lo < value <= hi if open_low else lo <= value <= hi):
                raise ConfigError(
                    f"{key} must lie in {'(' if open_low else '['}{lo:g}, {hi:g}], got {value:g}"
                )

    def teacher_coef_at(self, env_steps: jax.Array) -> jax.Array:
        """The teacher loss's weight after `env_steps` env steps of training (traced)."""
        return anneal_to_zero(self.teacher_coef, env_steps, self.teacher_anneal_env_steps)


class Batch(NamedTuple):
    """A rollout flattened to N = E * 2 sequences, time-major [T, N, ...], ready for the loss."""

    obs: jax.Array
    first: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    advantage: jax.Array
    target: jax.Array
    history: jax.Array  # [T, N, K] the partner's recent actions each row's policy saw (K may be 0)
    partner_action: jax.Array  # [T, N] what the partner did at that step (the partner model's target)
    teacher_action: jax.Array | None  # [T, N] the scripted teacher's action (None: no teacher)
    teacher_coef: jax.Array | None  # [T, N] the teacher loss's weight now, the same at every step
    weight: jax.Array | None  # [T, N] each step's weight in the loss (None: all 1, plain means)
    init_lstm: LSTMState


class LossInfo(NamedTuple):
    """The loss and its terms: of one minibatch from `ppo_loss`, and per update (means over epochs and
    minibatches) from `update`, which adds the gradient's norm."""

    total_loss: jax.Array
    policy_loss: jax.Array
    value_loss: jax.Array
    entropy: jax.Array
    approx_kl: jax.Array
    clip_fraction: jax.Array
    partner_loss: jax.Array  # cross-entropy of the partner model's prediction (0 without one)
    teacher_loss: jax.Array  # cross-entropy of the scripted teacher's action under the policy (0 without one)
    grad_norm: jax.Array  # the gradient's global norm before clipping (0 from `ppo_loss`, which takes none)


def gae(
    reward: jax.Array, value: jax.Array, done: jax.Array, last_value: jax.Array, gamma: float, lam: float
) -> tuple[jax.Array, jax.Array]:
    """Generalised advantage estimation over time-major [T, ...] arrays.

    `done[t]` means the episode ended with step t, so neither the value nor the advantage of step t + 1
    (a new episode's first observation, after auto-reset) flows back into step t. Time-limit ends are
    treated as terminal, as in the paper's code.

    Returns:
        (advantages, value targets = advantages + value), both shaped like `reward`.
    """
    not_done = 1.0 - done.astype(jnp.float32)

    def back(
        carry: tuple[jax.Array, jax.Array], x: tuple[jax.Array, ...]
    ) -> tuple[tuple[jax.Array, jax.Array], jax.Array]:
        next_adv, next_value = carry
        r, v, nd = x
        delta = r + gamma * next_value * nd - v
        adv = delta + gamma * lam * nd * next_adv
        return (adv, v), adv

    _, adv = jax.lax.scan(
        back, (jnp.zeros_like(last_value), last_value), (reward, value, not_done), reverse=True
    )
    return adv, adv + value


def make_batch(
    traj: Trajectory,
    shaping_weight: jax.Array,
    gamma: float,
    lam: float,
    *,
    learner_seat_only: bool = False,
    mask_scripted_seat: bool = False,
    normalise_apart: bool = False,
    team_shaping: bool = False,
    teacher_coef: jax.Array | None = None,
) -> Batch:
    """Per-seat rewards (team reward + `shaping_weight` x own shaped reward), GAE, and seat flattening.

    `team_shaping`: each seat's shaped reward is both seats' (the team's) instead of its own.
    `teacher_coef`: the teacher loss's weight now (`PPOConfig.teacher_coef_at`), with a trajectory that
    recorded the teacher's actions (`rollout(..., teacher=True)`); None: no teacher loss.

    With `learner_seat_only` (partner strategies) the batch holds only the learner's own seat of every env
    (N = E sequences; the seat may change only where an episode starts, where the LSTM resets); otherwise
    both seats (N = 2E). `mask_scripted_seat` (both seats) gives the other seat of the episodes a scripted
    partner played (`partner_index` 1) weight 0: its actions were the script's, not the policy's.
    `normalise_apart`: the advantages of the steps played with the scripted partner and of those played
    without it are each brought to mean 0 and deviation 1 over the batch, so that neither kind of episode
    outweighs the other by the spread of its returns (a competent partner's episodes have several times
    self-play's; the minibatch normalisation of the loss then leaves them about as they are).
    """
    t, e = traj.reward.shape
    shaped = (
        jnp.broadcast_to(traj.shaped.sum(-1, keepdims=True), traj.shaped.shape)
        if team_shaping
        else traj.shaped
    )
    reward = traj.reward[..., None] + shaping_weight * shaped  # [T, E, 2]
    done = jnp.broadcast_to(traj.done[..., None], reward.shape)
    advantage, target = gae(reward, traj.value, done, traj.last_value, gamma, lam)
    partner_action = traj.action[..., ::-1]  # [T, E, 2]: seat s's partner is seat 1 - s

    if learner_seat_only:
        seat = traj.learner_seat  # [T, E]

        def rows(x: jax.Array) -> jax.Array:  # [T, E, 2, ...] -> [T, E, ...]: the learner's seat
            idx = seat.reshape((t, e, 1) + (1,) * (x.ndim - 3))
            return jnp.take_along_axis(x, idx, axis=2)[:, :, 0]

        first = traj.first
        init_lstm = jax.tree.map(
            lambda x: jnp.take_along_axis(x, seat[0][:, None, None], axis=1)[:, 0], traj.init_lstm
        )
    else:

        def rows(x: jax.Array) -> jax.Array:  # [T, E, 2, ...] -> [T, 2E, ...]: both seats
            return x.reshape((t, e * NUM_SEATS, *x.shape[3:]))

        first = jnp.repeat(traj.first, NUM_SEATS, axis=1)
        init_lstm = jax.tree.map(lambda x: x.reshape((e * NUM_SEATS, -1)), traj.init_lstm)

    weight = None
    if mask_scripted_seat:
        scripted = (jnp.arange(NUM_SEATS) != traj.learner_seat[..., None]) & (
            traj.partner_index[..., None] == 1
        )
        weight = rows(jnp.where(scripted, 0.0, 1.0))
    advantage = rows(advantage)
    if normalise_apart:
        with_script = rows(jnp.broadcast_to((traj.partner_index == 1)[..., None], reward.shape))
        trained = jnp.ones_like(advantage) if weight is None else weight
        advantage = jnp.where(
            with_script,
            _standardise(advantage, trained * with_script),
            _standardise(advantage, trained * ~with_script),
        )
    teacher_action = teacher_weight = None
    if teacher_coef is not None:
        if traj.teacher_action is None:
            raise ValueError("a teacher loss needs a trajectory recorded with rollout(..., teacher=True)")
        teacher_action = rows(traj.teacher_action)
        teacher_weight = jnp.broadcast_to(jnp.asarray(teacher_coef, jnp.float32), teacher_action.shape)
    return Batch(
        obs=rows(traj.obs),
        first=first,
        action=rows(traj.action),
        log_prob=rows(traj.log_prob),
        value=rows(traj.value),
        advantage=advantage,
        target=rows(target),
        history=rows(traj.history),
        partner_action=rows(partner_action),
        teacher_action=teacher_action,
        teacher_coef=teacher_weight,
        weight=weight,
        init_lstm=init_lstm,
    )


def _standardise(x: jax.Array, weight: jax.Array | None, axis: str | None = None) -> jax.Array:
    """`x` less its (`weight`-ed, `_mean`) mean, over its deviation; inside `shard_map` (`axis`) with the
    whole minibatch's statistics from every device's share."""

    def stat(v: jax.Array) -> jax.Array:
        m = _mean(v, weight, axis)
        return m if axis is None else jax.lax.pmean(m, axis)

    mean = stat(x)
    return (x - mean) / (jnp.sqrt(stat(jnp.square(x - mean))) + 1e-8)


def _mean(x: jax.Array, weight: jax.Array | None, axis: str | None) -> jax.Array:
    """The (weighted) mean of a minibatch quantity. Inside `shard_map` (`axis`) with weights it is this
    device's weighted sum over the mean of the devices' weight sums, so that the devices' average is the
    whole minibatch's weighted mean (as a plain `mean` of equal shares is). A minibatch that weighs nothing
    has mean 0 (on every device: the devices' mean weight sum is 0 only when the whole minibatch's is)."""
    if weight is None:
        return x.mean()
    total = weight.sum() if axis is None else jax.lax.pmean(weight.sum(), axis)
    return (weight * x).sum() / jnp.where(total > 0, total, 1.0)


def ppo_loss(
    params: Any, network: ActorCritic, batch: Batch, config: PPOConfig, axis: str | None = None
) -> tuple[jax.Array, LossInfo]:
    """Clipped PPO objective on one minibatch of whole sequences (advantages normalised per minibatch).

    `axis`: inside `shard_map` over that mesh axis, `batch` is this device's share of the minibatch; the
    advantages are then normalised with the whole minibatch's mean and deviation (equal shares), and the
    loss is the share's (its gradients averaged over the devices give the whole minibatch's).

    Returns:
        (total loss, its `LossInfo`: the total and each term; `grad_norm` 0, as no gradient is taken here).
    """
    w = batch.weight
    partner_loss = jnp.float32(0.0)
    if network.config.partner_history:  # E3T: + the partner model's cross-entropy on the partner's action
        _, logits, value, partner_logits = forward_partner(
            network, params, batch.init_lstm, batch.obs, batch.first, batch.history
        )
        predicted = jax.nn.log_softmax(partner_logits)
        partner_loss = -_mean(
            jnp.take_along_axis(predicted, batch.partner_action[..., None], axis=-1), w, axis
        )
    else:
        _, logits, value = forward(network, params, batch.init_lstm, batch.obs, batch.first)
    log_probs = jax.nn.log_softmax(logits)
    log_prob = jnp.take_along_axis(log_probs, batch.action[..., None], axis=-1)[..., 0]
    entropy = _mean(-jnp.sum(jnp.exp(log_probs) * log_probs, axis=-1), w, axis)

    # VALUE LOSS, optionally clipped around the behaviour value.
    value_loss = jnp.square(value - batch.target)
    if config.clip_value:
        clipped = batch.value + jnp.clip(value - batch.value, -config.clip_eps, config.clip_eps)
        value_loss = jnp.maximum(value_loss, jnp.square(clipped - batch.target))
    value_loss = 0.5 * _mean(value_loss, w, axis)

    # POLICY LOSS.
    log_ratio = log_prob - batch.log_prob
    ratio = jnp.exp(log_ratio)
    if w is None and axis is None:
        adv = (batch.advantage - batch.advantage.mean()) / (batch.advantage.std() + 1e-8)
    else:  # the whole minibatch's (weighted) statistics, from every device's share
        adv = _standardise(batch.advantage, w, axis)
    surrogate = jnp.minimum(ratio * adv, jnp.clip(ratio, 1.0 - config.clip_eps, 1.0 + config.clip_eps) * adv)
    policy_loss = -_mean(surrogate, w, axis)

    total = policy_loss + config.vf_coef * value_loss - config.ent_coef * entropy
    total = total + config.partner_coef * partner_loss
    teacher_loss = jnp.float32(0.0)
    if batch.teacher_action is not None and batch.teacher_coef is not None:  # kickstarting
        cross_entropy = -jnp.take_along_axis(log_probs, batch.teacher_action[..., None], axis=-1)[..., 0]
        teacher_loss = _mean(cross_entropy, w, axis)
        total = total + _mean(batch.teacher_coef * cross_entropy, w, axis)
    approx_kl = _mean((ratio - 1.0) - log_ratio, w, axis)
    clip_fraction = _mean(jnp.abs(ratio - 1.0) > config.clip_eps, w, axis)
    info = LossInfo(
        total_loss=total,
        policy_loss=policy_loss,
        value_loss=value_loss,
        entropy=entropy,
        approx_kl=approx_kl,
        clip_fraction=clip_fraction,
        partner_loss=partner_loss,
        teacher_loss=teacher_loss,
        grad_norm=jnp.float32(0.0),
    )
    return total, info


def _sharded_grads(grad_fn: Any, mesh: Mesh, network: ActorCritic, config: PPOConfig) -> Any:
    """(params, minibatch) -> ((loss, aux), grads) with the minibatch's sequences split over `mesh`'s
    `envs` axis: per-device losses and gradients, averaged over the devices."""
    sequences = PartitionSpec(None, "envs")  # time-major fields [T, N, ...]
    specs: Any = Batch._make([*([sequences] * (len(Batch._fields) - 1)), PartitionSpec("envs")])

    devices = mesh.shape["envs"]

    def local(params: Any, mb: Batch) -> Any:
        (loss, aux), grads = grad_fn(params, network, mb, config, "envs")
        # `params` are the same on every device, so shard_map's autodiff sums their gradients over the
        # devices: the sum of the shares' mean-loss gradients, N times the whole minibatch's
        grads = jax.tree.map(lambda g: g / devices, grads)
        return jax.lax.pmean((loss, aux), "envs"), grads

    return jax.shard_map(local, mesh=mesh, in_specs=(PartitionSpec(), specs), out_specs=PartitionSpec())


def make_optimizer(
    config: PPOConfig, steps_per_update: int, total_env_steps: int
) -> tuple[optax.GradientTransformation, optax.Schedule]:
    """Adam with global-norm clipping, and its learning-rate schedule (of the gradient-step count):
    linear from `lr` to 0 over the annealing horizon, or constant."""
    if config.anneal_lr:
        horizon = config.lr_anneal_env_steps or total_env_steps
        grad_steps = max(1, horizon // steps_per_update) * config.update_epochs * config.num_minibatches
        schedule = optax.linear_schedule(config.lr, 0.0, grad_steps)
    else:
        schedule = optax.constant_schedule(config.lr)
    tx = optax.chain(
        optax.clip_by_global_norm(config.max_grad_norm), optax.adam(schedule, eps=config.adam_eps)
    )
    return tx, schedule


def update(
    params: Any,
    opt_state: Any,
    batch: Batch,
    key: jax.Array,
    *,
    network: ActorCritic,
    optimizer: optax.GradientTransformation,
    config: PPOConfig,
    mesh: Mesh | None = None,
) -> tuple[Any, Any, LossInfo]:
    """`update_epochs` x `num_minibatches` Adam steps on one rollout's `Batch`.

    `mesh` (one axis, `envs`; the data-parallel trainer's): each minibatch's sequences are split over its
    devices, each device computes the loss and gradients of its share (`shard_map`), and the gradients are
    averaged over the devices (an all-reduce). The advantages are normalised with the whole minibatch's
    statistics, so the step equals one device's to float rounding.

    Returns:
        (new params, new optimizer state, `LossInfo` averaged over the gradient steps).
    """
    n = batch.action.shape[1]
    m = config.num_minibatches
    if n % m:
        raise ValueError(f"{n} sequences (envs x 2 seats) do not split into {m} minibatches")
    grad_fn = jax.value_and_grad(ppo_loss, has_aux=True)

    def minibatch_step(carry: tuple[Any, Any], idx: jax.Array) -> tuple[tuple[Any, Any], jnp.ndarray]:
        p, o = carry
        time_major = jax.tree.map(lambda x: jnp.take(x, idx, axis=1), batch[:-1])
        mb = Batch._make([*time_major, jax.tree.map(lambda x: x[idx], batch.init_lstm)])
        if mesh is None:
            (_, info), grads = grad_fn(p, network, mb, config)
        else:
            (_, info), grads = _sharded_grads(grad_fn, mesh, network, config)(p, mb)
        updates, o = optimizer.update(grads, o, p)
        p = optax.apply_updates(p, updates)
        return (p, o), jnp.stack(info._replace(grad_norm=optax.tree.norm(grads)))

    def epoch(carry: tuple[Any, Any], epoch_key: jax.Array) -> tuple[tuple[Any, Any], jnp.ndarray]:
        order = jax.random.permutation(epoch_key, n).reshape((m, n // m))
        return jax.lax.scan(minibatch_step, carry, order)

    (params, opt_state), stats = jax.lax.scan(
        epoch, (params, opt_state), jax.random.split(key, config.update_epochs)
    )
    return params, opt_state, LossInfo(*stats.reshape((-1, len(LossInfo._fields))).mean(0))
