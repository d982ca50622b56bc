"""The one rollout function: scan over steps, vmapped envs, both seats batched through one network.

`rollout(params, carry, levels, key, ...)` is used by the single-process trainer, the Ray actors and the
evaluator (DESIGN.md rule 4). The carry holds everything that continues across rollouts (env states,
current observations, LSTM states, running episode returns), so consecutive rollouts continue episodes
seamlessly; `levels` is the per-env buffer of upcoming levels for auto-reset. Training plays self-play
(one parameter set for both seats); the evaluator passes `per_seat=True` and one parameter set per seat
(cross-play), and `greedy=True` for argmax actions.

Shapes: E envs, T steps, 2 seats; seat-major flattening `env * 2 + seat` wherever the two are merged.
"""

from __future__ import annotations

import dataclasses
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp

from cec.agents.network import ActorCritic, LSTMState, empty_history, forward, push_history, select_action
from cec.envs.task import Task, env_keys
from cec.training.partners import SELF_PLAY, PartnerConfig, mixture_log_probs

NUM_SEATS = 2


class RolloutCarry(NamedTuple):
    """What a rollout continues from (batched over E envs).

    Attributes:
        env_state: the envs' states.
        obs: [E, 2, ...] current observations.
        first: bool[E] the current observation is the first of an episode (the LSTM resets before it).
        lstm: `LSTMState` with [E, 2, H] leaves, the carry before the current observation.
        episode_return: float32[E] team (sparse) return of the running episodes so far.
        episode_shaped: float32[E] shaped return (both seats summed, unscaled) of the running episodes.
        learner_seat: int32[E] the learner's seat in the running episodes (partner strategies; 0 in
            self-play, where both seats are the learner's).
        partner_index: int32[E] the partner of the running episodes (FCP's population index; the `scripted`
            kind's 1 where the cook plays; else 0).
        history: int32[E, 2, K] each seat's view of its partner's last K actions (-1: none yet this
            episode), the input of E3T's partner model (K = `partner_history` of the network, may be 0).
        env_id: int32[E] each env's index in the whole batch. Every random draw of an env at a step comes
            from `fold_in(step key, env_id)`, so a slice of the envs (a Ray actor's share) plays exactly
            what the same envs play inside the full batch.
    """

    env_state: Any
    obs: jax.Array
    first: jax.Array
    lstm: LSTMState
    episode_return: jax.Array
    episode_shaped: jax.Array
    learner_seat: jax.Array
    partner_index: jax.Array
    history: jax.Array
    env_id: jax.Array


class Trajectory(NamedTuple):
    """T steps of E envs. Per-step fields have leading axes [T, E] (and a seat axis where per seat).

    Attributes:
        obs: [T, E, 2, ...] the observations the actions were taken on.
        first: bool[T, E] `obs` is the first of an episode.
        action: int32[T, E, 2].
        log_prob: float32[T, E, 2] behaviour log-probability of `action`.
        value: float32[T, E, 2] critic value of `obs`.
        reward: float32[T, E] team sparse reward.
        shaped: float32[T, E, 2] per-seat shaped reward (unscaled).
        done: bool[T, E] the episode ended with this step.
        collision: bool[T, E].
        episode_return: float32[T, E] the finished episode's team return where `done`, else 0.
        episode_shaped: float32[T, E] the finished episode's shaped return where `done`, else 0.
        learner_seat: int32[T, E] the learner's seat at each step (what trains when only it does).
        partner_index: int32[T, E] the running episode's partner (FCP's population index; the `scripted`
            kind's 1 where the cook plays the other seat; 0 otherwise).
        history: int32[T, E, 2, K] the partner-action history each seat's policy saw.
        init_lstm: `LSTMState` [E, 2, H], the carry before the first step (for replay in the update).
        last_value: float32[E, 2] critic value of the observation after the last step (bootstrap).
        state: with `record="state"`, the env states the actions were taken in, without their level
            ([T, E] leaves; `obs` is then None): a Ray actor ships these instead of observations and the
            learner recomputes `obs` (`cec.training.compact`).
        teacher_action: with `teacher`, int32[T, E, 2] what the game's scripted policy (greedy) would have
            done in each seat's place (the teacher loss's target, `PPOConfig.teacher_coef`); else None.
    """

    obs: jax.Array
    first: jax.Array
    action: jax.Array
    log_prob: jax.Array
    value: jax.Array
    reward: jax.Array
    shaped: jax.Array
    done: jax.Array
    collision: jax.Array
    episode_return: jax.Array
    episode_shaped: jax.Array
    learner_seat: jax.Array
    partner_index: jax.Array
    history: jax.Array
    init_lstm: LSTMState
    last_value: jax.Array
    state: Any = None
    teacher_action: Any = None


def _per_seat(x: jax.Array) -> jax.Array:
    """[E] -> [E * 2] (the same flag for both seats of an env)."""
    return jnp.repeat(x, NUM_SEATS, axis=0)


def policy_step(
    network: ActorCritic,
    params: Any,
    lstm: LSTMState,
    obs: jax.Array,
    first: jax.Array,
    history: jax.Array,
    *,
    per_seat: bool = False,
) -> tuple[LSTMState, jax.Array, jax.Array]:
    """One step of the policy for every seat of every env.

    Args:
        params: the shared parameters (self-play), or with `per_seat` each seat's own: every leaf has a
            leading axis of 2 (seat 0's, seat 1's), as in cross-play of two different policies.
        lstm: [E, 2, H] carries; obs: [E, 2, ...]; first: bool[E]; history: int32[E, 2, K] the partner's
            recent actions (the carry's; read only by networks with a partner model).
        per_seat: static; see `params`.

    Returns:
        (next lstm [E, 2, H], logits float32[E, 2, A], value float32[E, 2]).
    """
    models_partner = bool(network.config.partner_history)
    if per_seat:
        # Each seat's E rows through its own parameters: a vmap over the seat axis (batched matmuls).
        def seat(
            p: Any, carry: LSTMState, o: jax.Array, h: jax.Array
        ) -> tuple[LSTMState, jax.Array, jax.Array]:
            carry, logits, value = forward(
                network, p, carry, o[None], first[None], h[None] if models_partner else None
            )
            return carry, logits[0], value[0]

        out: tuple[LSTMState, jax.Array, jax.Array] = jax.vmap(seat, in_axes=(0, 1, 1, 1), out_axes=1)(
            params, lstm, obs, history
        )
        return out
    e = obs.shape[0]
    flat = jax.tree.map(lambda x: x.reshape((e * NUM_SEATS, -1)), lstm)
    hist = history.reshape((1, e * NUM_SEATS, -1)) if models_partner else None
    flat, logits, value = forward(
        network, params, flat, obs.reshape((1, e * NUM_SEATS, *obs.shape[2:])), _per_seat(first)[None], hist
    )
    lstm = jax.tree.map(lambda x: x.reshape((e, NUM_SEATS, -1)), flat)
    return lstm, logits[0].reshape((e, NUM_SEATS, -1)), value[0].reshape((e, NUM_SEATS))


def init_carry(
    task: Task,
    network: ActorCritic,
    env_params: Any,
    levels: Any,
    key: jax.Array,
    env_ids: jax.Array | None = None,
) -> RolloutCarry:
    """Starts E envs, one on each `levels[:, 0]` (a buffer with leading axes [E, K]).

    `env_ids` (int32[E], default 0..E-1) are the envs' indices in the whole batch; env i's reset key is
    `fold_in(key, i)`, so a slice of a batch starts as it does inside the batch.
    """
    first_levels = jax.tree.map(lambda x: x[:, 0], levels)
    e = jax.tree.leaves(first_levels)[0].shape[0]
    ids = jnp.arange(e, dtype=jnp.int32) if env_ids is None else jnp.asarray(env_ids, jnp.int32)
    obs, state = jax.vmap(task.reset, in_axes=(0, 0, None))(env_keys(key, ids), first_levels, env_params)
    zeros, ints = jnp.zeros(e, jnp.float32), jnp.zeros(e, jnp.int32)
    lstm = network.initial_carry((e, NUM_SEATS))
    history = empty_history((e, NUM_SEATS), network.config.partner_history)
    return RolloutCarry(state, obs, jnp.ones(e, bool), lstm, zeros, zeros, ints, ints, history, ids)


def rollout(
    params: Any,
    carry: RolloutCarry,
    levels: Any,
    key: jax.Array,
    *,
    task: Task,
    network: ActorCritic,
    env_params: Any,
    num_steps: int,
    per_seat: bool = False,
    greedy: bool = False,
    partner: PartnerConfig = SELF_PLAY,
    population: Any = None,
    record: str = "obs",
    scripted_share: jax.Array | None = None,
    teacher: bool = False,
) -> tuple[RolloutCarry, Trajectory]:
    """Plays `num_steps` steps of E envs in self-play (both seats act with `params`), or in cross-play.

    Args:
        params: network parameters (shared by both seats), or with `per_seat` each seat's own (leaves
            with a leading axis of 2; the evaluator's cross-play of two policies).
        carry: the `RolloutCarry` to continue from (E envs).
        levels: per-env level buffers, leading axes [E, K]; a finished episode continues on
            `levels[e, (episode + 1) % K]`.
        key: PRNG key for action sampling and the envs.
        task, network, num_steps: static; env_params: the game's settings (traced).
        per_seat: static; `params` holds one parameter set per seat (see `policy_step`).
        greedy: static; act with the most likely action instead of sampling (`log_prob` is still that
            action's log-probability).
        partner: static; the partner strategy (`cec.training.partners`): self-play, FCP or E3T.
        population: FCP's frozen partners' parameters (leaves with a leading axis P); None otherwise.
        record: static; `obs` records the observations (the trainer), `state` the env states without
            their level instead (the compact form Ray actors ship; see `Trajectory.state`).
        scripted_share: the scripted partner's share of episodes now (traced; the trainer's schedule,
            `PartnerConfig.scripted_share_at`); None: `partner.scripted_share`.
        teacher: static; also record what the game's scripted policy would do in each seat's place
            (`Trajectory.teacher_action`, the teacher loss's target).

    Returns:
        (carry after the last step, `Trajectory` with T = num_steps).
    """
    if record not in ("obs", "state"):
        raise ValueError(f"record must be 'obs' or 'state', got {record!r}")
    share = partner.scripted_share if scripted_share is None else scripted_share

    def body(c: RolloutCarry, step_key: jax.Array) -> tuple[RolloutCarry, dict[str, Any]]:
        # [E, 4, 2]: per env, keys for its actions, its env step, its seat draw and its partner draw
        keys = jax.vmap(lambda k: jax.random.split(k, 4))(env_keys(step_key, c.env_id))
        k_act, k_env, k_seat, k_partner = (keys[:, i] for i in range(4))
        seat, index = c.learner_seat, c.partner_index
        if partner.kind != "self_play":  # new episodes draw the learner's seat (and FCP partner) per env
            draw = jax.vmap(lambda k, n: jax.random.randint(k, (), 0, n), in_axes=(0, None))
            seat = jnp.where(c.first, draw(k_seat, NUM_SEATS), seat)
            if partner.kind == "fcp":
                p = jax.tree.leaves(population)[0].shape[0]
                index = jnp.where(c.first, draw(k_partner, p), index)
            elif partner.kind == "scripted":  # index 1: the scripted partner plays this episode
                coin = jax.vmap(jax.random.uniform)(k_partner) < share
                needs = task.game.needs_partner
                if partner.scripted_where_needed and needs is not None:  # TrainConfig: None is refused
                    coin = coin & jax.vmap(needs)(c.env_state)
                index = jnp.where(c.first, coin.astype(index.dtype), index)
        lstm, logits, value = policy_step(
            network, params, c.lstm, c.obs, c.first, c.history, per_seat=per_seat
        )
        log_probs = jax.nn.log_softmax(logits)  # [E, 2, A] of the distribution each seat acts with
        if partner.kind == "fcp":
            lstm, log_probs = _fcp_partner_step(network, population, c, seat, index, lstm, log_probs)
        elif partner.kind == "e3t":
            is_partner = (jnp.arange(NUM_SEATS)[None, :] != seat[:, None])[..., None]  # [E, 2, 1]
            log_probs = jnp.where(is_partner, mixture_log_probs(logits, partner.epsilon), log_probs)
        action = jax.vmap(select_action, in_axes=(0, 0, None))(k_act, log_probs, greedy)  # [E, 2]
        if partner.kind == "scripted":  # the partner seat's action (not trained on) is the script's
            action = _scripted_partner_actions(task, partner, k_partner, c.env_state, seat, index, action)
        log_prob = jnp.take_along_axis(log_probs, action[..., None], axis=-1)[..., 0]
        out = jax.vmap(task.step, in_axes=(0, 0, 0, 0, None))(k_env, c.env_state, action, levels, env_params)
        ep_return = c.episode_return + out.reward
        ep_shaped = c.episode_shaped + out.shaped.sum(-1)
        recorded = dict(
            obs=c.obs if record == "obs" else None,
            state=task.without_level(c.env_state) if record == "state" else None,
            first=c.first,
            action=action,
            log_prob=log_prob,
            value=value,
            reward=out.reward,
            shaped=out.shaped,
            done=out.done,
            collision=out.collision,
            episode_return=jnp.where(out.done, ep_return, 0.0),
            episode_shaped=jnp.where(out.done, ep_shaped, 0.0),
            learner_seat=seat,
            partner_index=index,
            history=c.history,
            teacher_action=_teacher_actions(task, k_act, c.env_state) if teacher else None,
        )
        zero = jnp.zeros_like(ep_return)
        nxt = RolloutCarry(
            out.state,
            out.obs,
            out.done,
            lstm,
            jnp.where(out.done, zero, ep_return),
            jnp.where(out.done, zero, ep_shaped),
            seat,
            index,
            _push_partner_actions(c.history, action, out.done),
            c.env_id,
        )
        return nxt, recorded

    final, steps = jax.lax.scan(body, carry, jax.random.split(key, num_steps))
    _, _, last_value = policy_step(
        network, params, final.lstm, final.obs, final.first, final.history, per_seat=per_seat
    )
    return final, Trajectory(**steps, init_lstm=carry.lstm, last_value=last_value)


def _scripted_partner_actions(
    task: Task,
    partner: PartnerConfig,
    keys: jax.Array,
    env_state: Any,
    seat: jax.Array,
    index: jax.Array,
    action: jax.Array,
) -> jax.Array:
    """[E, 2] `action` with the partner seat's replaced by the game's scripted policy where this episode's
    partner is the script (`index` 1). Its keys are folded from the partner draw's (the other partner kinds'
    random streams are unchanged)."""
    script = task.game.scripted
    assert script is not None  # TrainConfig refuses the kind for a game without one
    k_script = jax.vmap(lambda k: jax.random.fold_in(k, 1))(keys)
    scripted = jax.vmap(lambda k, s: script(k, s, partner.scripted_epsilon, partner.scripted_yields))(
        k_script, env_state
    )
    use = (jnp.arange(NUM_SEATS)[None, :] != seat[:, None]) & (index[:, None] == 1)
    return jnp.where(use, scripted, action)


def _teacher_actions(task: Task, keys: jax.Array, env_state: Any) -> jax.Array:
    """[E, 2] the game's scripted policy's greedy actions for both seats (no random actions: `epsilon` 0, so
    its keys, folded from the action keys, draw nothing that is used)."""
    script = task.game.scripted
    assert script is not None  # TrainConfig refuses a teacher for a game without one
    return jax.vmap(lambda k, s: script(jax.random.fold_in(k, 2), s, 0.0, True))(keys, env_state)


def _push_partner_actions(history: jax.Array, action: jax.Array, done: jax.Array) -> jax.Array:
    """Appends each seat's partner's latest action to its history ([E, 2, K]); cleared where episodes end."""
    if history.shape[-1] == 0:
        return history
    pushed = push_history(history, action[:, ::-1])  # seat s sees seat 1 - s
    return jnp.where(done[:, None, None], -1, pushed)


def _fcp_partner_step(
    network: ActorCritic,
    population: Any,
    c: RolloutCarry,
    seat: jax.Array,
    index: jax.Array,
    lstm: LSTMState,
    log_probs: jax.Array,
) -> tuple[LSTMState, jax.Array]:
    """Replaces the partner seat's LSTM state and action distribution by its population member's.

    Every member runs on every env's partner seat (one batched call per member, vmapped over members) and
    each env keeps its own member's output: P times the partner compute, no per-env parameter copies.
    The partner's LSTM state is kept in the partner seat's slot of the carry.
    """
    e = seat.shape[0]
    rows = jnp.arange(e)
    other = 1 - seat
    p_obs = c.obs[rows, other][None]  # [1, E, ...]
    p_lstm = jax.tree.map(lambda x: x[rows, other], c.lstm)  # [E, H]

    plain = ActorCritic(dataclasses.replace(network.config, partner_history=0), network.num_actions)

    def member(p: Any) -> tuple[LSTMState, jax.Array]:  # population members have no partner model
        carry, logits, _ = forward(plain, p, p_lstm, p_obs, c.first[None])
        return carry, logits[0]

    p_carry, p_logits = jax.vmap(member)(population)  # [P, E, H], [P, E, A]
    p_carry = jax.tree.map(lambda x: x[index, rows], p_carry)
    p_log_probs = jax.nn.log_softmax(p_logits[index, rows])  # [E, A]
    is_partner = jnp.arange(NUM_SEATS)[None, :] != seat[:, None]  # [E, 2]
    lstm = jax.tree.map(
        lambda mine, theirs: jnp.where(is_partner[..., None], theirs[:, None], mine), lstm, p_carry
    )
    return lstm, jnp.where(is_partner[..., None], p_log_probs[:, None], log_probs)
