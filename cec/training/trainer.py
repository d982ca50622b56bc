"""The single-process trainer: rollout + PPO update fused into one compiled call, seeds vmapped.

This is the paper's own topology and the embedded default on one machine:

    state = init(seeds)                          # params, Adam state, env + LSTM carries, keys, counters
    repeat: state, metrics = train_call(state)   # jit(vmap over seeds(scan over `updates_per_call` updates))
            write metrics rows, checkpoint when due, print progress   (`cec.training.loop`: the update loop)

Over several local devices (`devices`), the same program runs data-parallel: the state's env axis is
sharded over a one-axis mesh (`envs`) and everything else (parameters, Adam state, keys) replicated; XLA's
SPMD partitioner runs each device's envs where they live, and the PPO update splits each minibatch's
sequences over the devices (`cec.training.ppo.update`'s `mesh`), averaging the gradients. The program and
its random draws are one device's, so N devices give one device's updates to float rounding (sums are
taken in another order).

Everything random comes from the per-seed key in the state, and the state is checkpointed whole, so a
run interrupted between calls and resumed produces the same parameters as an uninterrupted one.
"""

from __future__ import annotations

import math
import os
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np
import optax
from jax.sharding import Mesh, NamedSharding, PartitionSpec

from cec import checkpoints
from cec.agents.network import ActorCritic, init_params
from cec.agents.policy import checkpoint_seeds, load_policy
from cec.agents.zoo import ZooEntry
from cec.config import ConfigError
from cec.envs.task import Task
from cec.training.config import TrainConfig
from cec.training.population import load_population
from cec.training.ppo import LossInfo, make_batch, make_optimizer, update
from cec.training.rollout import RolloutCarry, Trajectory, init_carry, rollout
from cec.training.schedules import anneal_to_zero


class TrainState(NamedTuple):
    """Everything a run continues from (leading axis S = seeds in the trainer).

    Attributes:
        params: network parameters.
        opt_state: Adam (and gradient-clipping) state, including the schedule's step count.
        carry: env states, observations, LSTM states and running returns of the rollout.
        key: uint32[2] the seed's PRNG key (split every update).
        update: int32[] updates done.
    """

    params: Any
    opt_state: Any
    carry: RolloutCarry
    key: jax.Array
    update: jax.Array


class UpdateMetrics(NamedTuple):
    """Per-update statistics of one seed (episode statistics over the episodes finished in the rollout)."""

    episodes: jax.Array
    mean_return: jax.Array
    mean_shaped_return: jax.Array
    collisions_per_episode: jax.Array
    shaping_weight: jax.Array
    learning_rate: jax.Array
    loss: LossInfo


def episode_stats(traj: Trajectory) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
    """(episodes finished in the rollout, their mean team return, mean shaped return, collisions per episode);
    the means are NaN when no episode finished."""
    done = traj.done.astype(jnp.float32)
    n = done.sum()
    safe = jnp.maximum(n, 1.0)
    nan = jnp.float32(jnp.nan)
    mean_return = jnp.where(n > 0, traj.episode_return.sum() / safe, nan)
    mean_shaped = jnp.where(n > 0, traj.episode_shaped.sum() / safe, nan)
    collisions = jnp.where(n > 0, traj.collision.astype(jnp.float32).sum() / safe, nan)
    return n, mean_return, mean_shaped, collisions


class Trainer:
    """The jitted pieces of the training loop for one `TrainConfig` (`train()` below runs them)."""

    def __init__(self, config: TrainConfig) -> None:
        self.config = config
        self.task = Task.from_config(config.env)
        check_memory(config, self.task.obs_shape)
        self.network = ActorCritic(config.network_config, self.task.num_actions)
        self.env_params = config.env.params
        self.optimizer, self.schedule = make_optimizer(
            config.ppo, config.steps_per_update, config.total_env_steps
        )
        self.shaping_horizon = config.ppo.shaping_anneal_env_steps or config.total_env_steps // 2
        self._init_jit = jax.jit(self.init_one)
        self.mesh = device_mesh(config)
        self._calls: dict[int, Any] = {}
        self.population: Any = None  # FCP's partners' params (leading axis P); set by `load_partners`

    def load_partners(self) -> None:
        """Loads FCP's population (a `ConfigError` listing every unusable entry; a no-op otherwise)."""
        if self.config.partner.kind == "fcp" and self.population is None:
            pop = load_population(
                self.config.partner, self.config.env, self.config.network_config, self.task.obs_shape
            )
            self.population = pop.params
            self.population_names = pop.names

    # ---- pure, jittable pieces -------------------------------------------------------------------------

    def init_one(self, key: jax.Array, levels: Any = None) -> TrainState:
        """The initial state of one seed from its key (`levels`: its first level buffers, `init_levels(key)`,
        drawn here when not given)."""
        if levels is None:
            levels = self.init_levels(key)
        key, k_params, _, k_reset = jax.random.split(key, 4)
        params = init_params(self.network, k_params, self.task.obs_shape)
        carry = init_carry(self.task, self.network, self.env_params, levels, k_reset)
        return TrainState(params, self.optimizer.init(params), carry, key, jnp.zeros((), jnp.int32))

    def _init(self, key: jax.Array) -> TrainState:
        """`init_one`, compiled, for one seed; its first levels drawn outside that program, by the task's
        one compiled sampler (`Task.sample_levels`): the generator, the costliest part of an init to compile,
        is compiled once per process (and cached) for every Trainer of a task, not again in each init."""
        return self._init_jit(key, self.init_levels(key))

    def init_levels(self, key: jax.Array) -> Any:
        """The level buffers `init_one` starts a seed's envs on, from the seed's key."""
        k_levels = jax.random.split(key, 4)[2]
        return self.task.sample_levels(k_levels, self.env_ids, self.config.levels_per_env)

    def env_steps_at(self, update_index: jax.Array) -> jax.Array:
        """Env steps per seed before update `update_index` (traced float32), what the schedules read."""
        return jnp.asarray(update_index, jnp.float32) * self.config.steps_per_update

    def shaping_weight(self, update_index: jax.Array) -> jax.Array:
        """Weight of the shaped reward at an update: 1 falling linearly to 0 over the shaping horizon."""
        if self.shaping_horizon < 0:
            return jnp.float32(1.0)
        return anneal_to_zero(1.0, self.env_steps_at(update_index), max(self.shaping_horizon, 1))

    @property
    def env_ids(self) -> jax.Array:
        """int32[num_envs]: every env of a seed (a Ray actor plays a slice of these)."""
        return jnp.arange(self.config.num_envs, dtype=jnp.int32)

    def update_keys(self, key: jax.Array) -> tuple[jax.Array, jax.Array, jax.Array, jax.Array]:
        """(next key, levels key, rollout key, update key) of one update, from the seed's key."""
        k = jax.random.split(key, 4)
        return k[0], k[1], k[2], k[3]

    def collect(
        self,
        params: Any,
        carry: RolloutCarry,
        k_levels: jax.Array,
        k_roll: jax.Array,
        population: Any = None,
        *,
        record: str = "obs",
        levels: Any = None,
        update_index: jax.Array | None = None,
    ) -> tuple[RolloutCarry, Trajectory]:
        """One rollout of the envs in `carry` (all of a seed's, or an actor's slice): levels drawn for those
        envs from `k_levels` unless given (streamed kitchens), then `rollout`. With `config.level_repeats`
        R > 1 and the `update_index` given, only an update whose index R divides plays its draw; the others
        replay each env's current kitchen (the draw is made either way, so the random streams are the
        same). The `update_index` also sets the scripted partner's share where it is annealed
        (`partner.scripted_anneal_env_steps`)."""
        cfg = self.config
        if levels is None:
            levels = self.task.sample_levels(k_levels, carry.env_id, cfg.levels_per_env)
        if cfg.level_repeats > 1 and update_index is not None:
            levels = replay_current(levels, carry.env_state.level, update_index % cfg.level_repeats != 0)
        share = None
        if cfg.partner.scripted_anneal_env_steps and update_index is not None:
            share = cfg.partner.scripted_share_at(self.env_steps_at(update_index))
        return rollout(
            params,
            carry,
            levels,
            k_roll,
            task=self.task,
            network=self.network,
            env_params=self.env_params,
            num_steps=cfg.num_steps,
            partner=cfg.partner,
            population=population,
            record=record,
            scripted_share=share,
            teacher=cfg.ppo.teacher_coef > 0,
        )

    def learn(
        self, params: Any, opt_state: Any, update_index: jax.Array, traj: Trajectory, k_update: jax.Array
    ) -> tuple[Any, Any, UpdateMetrics]:
        """The PPO update on one trajectory of a seed's envs (the trainer's and the Ray learner's)."""
        cfg = self.config
        weight = self.shaping_weight(update_index)
        teacher = None
        if cfg.ppo.teacher_coef > 0:
            teacher = cfg.ppo.teacher_coef_at(self.env_steps_at(update_index))
        batch = make_batch(
            traj,
            weight,
            cfg.ppo.gamma,
            cfg.ppo.gae_lambda,
            learner_seat_only=cfg.partner.learner_seat_only,
            mask_scripted_seat=cfg.partner.masks_scripted_seat,
            normalise_apart=cfg.partner.scripted_normalise_apart,
            team_shaping=cfg.ppo.team_shaping,
            teacher_coef=teacher,
        )
        lr = self.schedule(_adam_count(opt_state))
        params, opt_state, loss = update(
            params, opt_state, batch, k_update, network=self.network, optimizer=self.optimizer,
            config=cfg.ppo, mesh=self.mesh,
        )  # fmt: skip
        n, mean_return, mean_shaped, collisions = episode_stats(traj)
        metrics = UpdateMetrics(
            n, mean_return, mean_shaped, collisions, weight, jnp.asarray(lr, jnp.float32), loss
        )
        return params, opt_state, metrics

    def update_step(self, state: TrainState, population: Any = None) -> tuple[TrainState, UpdateMetrics]:
        """One rollout and one PPO update for one seed (`population`: FCP's partners, else None)."""
        key, k_levels, k_roll, k_update = self.update_keys(state.key)
        carry, traj = self.collect(
            state.params, state.carry, k_levels, k_roll, population, update_index=state.update
        )
        params, opt_state, metrics = self.learn(state.params, state.opt_state, state.update, traj, k_update)
        return TrainState(params, opt_state, carry, key, state.update + 1), metrics

    def train_call(self, n_updates: int) -> Any:
        """The compiled call running `n_updates` updates for every seed.

        (state with leading axis S) -> (state, metrics with leading axes [S, n_updates]). FCP's population
        (`load_partners`) is an argument of the compiled call, shared by the seeds, not a constant in it.
        """
        if n_updates not in self._calls:

            def many(state: TrainState, population: Any) -> tuple[TrainState, UpdateMetrics]:
                step = lambda s, _: self.update_step(s, population)  # noqa: E731
                return jax.lax.scan(step, state, None, length=n_updates)

            shardings: dict[str, Any] = {}
            if self.mesh is not None:  # the state stays where `place` put it; metrics on every device
                replicated = NamedSharding(self.mesh, PartitionSpec())
                shardings["out_shardings"] = (self.state_shardings(self.state_template()), replicated)
            call = jax.jit(jax.vmap(many, in_axes=(0, None)), donate_argnums=0, **shardings)
            self._calls[n_updates] = lambda state: call(state, self.population)
        return self._calls[n_updates]

    def init(self) -> TrainState:
        """Initial state for all seeds (leading axis S)."""
        # Seeds are initialised one by one and stacked: on XLA:CPU (jax 0.10) a vmapped orthogonal init of
        # the network (batched QR) can deadlock at run time; the init is a one-off, so nothing is lost.
        cfg = self.config
        states = [self._init(jax.random.PRNGKey(cfg.seed + i)) for i in range(cfg.num_seeds)]
        state: TrainState = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
        if cfg.init_from:  # every seed from the checkpoint's exact parameters, or seed i from source i
            sources = [self.initial_params(path, seed) for path, seed in self.init_sources()]
            if len(sources) == 1:
                params = jax.tree.map(lambda x: jnp.broadcast_to(x, (cfg.num_seeds, *x.shape)), sources[0])
            else:
                params = jax.tree.map(lambda *xs: jnp.stack(xs), *sources)
            opt_state = jax.vmap(self.optimizer.init)(params)
            state = state._replace(params=params, opt_state=opt_state)
        return self.place(state)

    def state_shardings(self, state: TrainState) -> TrainState:
        """Where each leaf of a (stacked) state lives over the mesh: the carry's env axis (axis 1, after
        the seeds) split over the devices, everything else replicated."""
        assert self.mesh is not None
        replicated = NamedSharding(self.mesh, PartitionSpec())
        envs = NamedSharding(self.mesh, PartitionSpec(None, "envs"))
        return jax.tree.map(lambda _: replicated, state)._replace(
            carry=jax.tree.map(lambda _: envs, state.carry)
        )

    def place(self, state: TrainState) -> TrainState:
        """The state on this trainer's devices (as `init` returns it; a loaded checkpoint goes through
        here too). One device: unchanged."""
        if self.mesh is None:
            return state
        return jax.device_put(state, self.state_shardings(state))

    def replicate(self, tree: Any) -> Any:
        """`tree` copied onto every device of the mesh (the parameters and Adam state the Ray learner's
        data-parallel update takes). One device: unchanged."""
        if self.mesh is None:
            return tree
        return jax.device_put(tree, NamedSharding(self.mesh, PartitionSpec()))

    def init_sources(self) -> list[tuple[str, int | None]]:
        """(checkpoint, seed in it) of each `init_from` source: one checkpoint for every seed, one per seed,
        or, where one checkpoint holds exactly `num_seeds` seeds and no `init_from_seed` picks one, seed i
        from its i-th (a run continued seed by seed under other settings)."""
        cfg = self.config
        paths = cfg.init_from_paths
        if len(paths) == 1 and cfg.init_from_seed < 0 and cfg.num_seeds > 1:
            try:
                seeds = checkpoint_seeds(paths[0])
            except checkpoints.CheckpointError as err:
                raise ConfigError(f"init_from: {err}") from err
            if len(seeds) == cfg.num_seeds:
                return [(paths[0], seed) for seed in seeds]
        return [(path, None if cfg.init_from_seed < 0 else cfg.init_from_seed) for path in paths]

    def initial_params(self, path: str, seed: int | None) -> Any:
        """The parameters of seed `seed` (None: its only one) of an `init_from` checkpoint, checked against
        this run's game and network."""
        cfg = self.config
        try:
            policy = load_policy(ZooEntry(name="init_from", checkpoint=path, seed=seed))
        except checkpoints.CheckpointError as err:
            raise ConfigError(f"init_from: {err}") from err
        if policy.env.name != cfg.env.name or policy.network != cfg.network_config:
            raise ConfigError(
                f"init_from {path} was trained on {policy.env.name} with network {policy.network}; "
                f"this run plays {cfg.env.name} with {cfg.network_config}: use a matching checkpoint/preset"
            )
        return policy.params

    def state_template(self) -> TrainState:
        """Shapes and dtypes of the state (no compute), for loading checkpoints."""
        keys = jax.ShapeDtypeStruct((self.config.num_seeds, 2), jnp.uint32)
        return jax.eval_shape(jax.vmap(self.init_one), keys)


def replay_current(levels: Any, current: Any, keep: jax.Array) -> Any:
    """Level buffers ([E, K] leaves) holding each env's `current` level ([E] leaves) in every slot where
    `keep` (a bool scalar), else `levels` unchanged."""

    def pick(fresh: jax.Array, now: jax.Array) -> jax.Array:
        return jnp.where(keep, jnp.broadcast_to(now[:, None], fresh.shape), fresh)

    return jax.tree.map(pick, levels, current)


def device_mesh(config: TrainConfig) -> Mesh | None:
    """The one-axis mesh (`envs`) of the run's `devices` local devices; None for one device. A
    `ConfigError` when the process sees fewer devices than asked for."""
    devices = jax.local_devices()
    n = config.devices or len(devices)
    if n > len(devices):
        raise ConfigError(
            f"devices = {n}, but this process sees {len(devices)} {devices[0].platform} device(s); lower "
            "devices (0: all of them), or on a CPU start the process with "
            f"XLA_FLAGS=--xla_force_host_platform_device_count={n}"
        )
    config.check_devices(n)
    return Mesh(np.asarray(devices[:n]), ("envs",)) if n > 1 else None


def device_memory_bytes() -> int:
    """Memory of the first JAX device: its allocator's limit on an accelerator, physical RAM on a CPU."""
    stats = jax.devices()[0].memory_stats() or {}
    if "bytes_limit" in stats:
        return int(stats["bytes_limit"])
    return os.sysconf("SC_PHYS_PAGES") * os.sysconf("SC_PAGE_SIZE")


def check_memory(config: TrainConfig, obs_shape: tuple[int, ...]) -> None:
    """`ConfigError` when one update's observations alone (float32, every seed, env, step and seat; the
    least any rollout keeps) exceed the device's memory: a run that could only crash, refused before any
    work instead of after minutes of compiling or an out-of-memory kill."""
    need = config.num_seeds * config.steps_per_update * 2 * math.prod(obs_shape) * 4
    have = device_memory_bytes()
    if need > have:
        raise ConfigError(
            f"one update's observations need {need / 2**30:,.1f} GiB (num_seeds {config.num_seeds} x "
            f"num_envs {config.num_envs} x num_steps {config.num_steps} x 2 seats x {math.prod(obs_shape)} "
            f"floats), more than the {have / 2**30:,.1f} GiB of {jax.devices()[0].device_kind}; lower "
            "num_envs, num_steps or num_seeds"
        )


def _adam_count(opt_state: Any) -> jax.Array:
    """The gradient-step count inside the optimizer state (drives the LR schedule)."""
    is_adam = lambda x: isinstance(x, optax.ScaleByAdamState)  # noqa: E731
    (adam,) = [x for x in jax.tree.leaves(opt_state, is_leaf=is_adam) if is_adam(x)]
    return adam.count
