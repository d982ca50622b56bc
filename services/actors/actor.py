"""A rollout actor: a slice of a seed's envs, their carries, a level feed and the jitted rollout.

The same object runs in the learner's process (`services.learner.pool.LocalPool`) and as a Ray actor
(`services.learner.ray_pool.RayPool`). Everything it exchanges with the learner is msgpack bytes or plain
numbers:

    actor = RolloutActor(train_config, index=0, env_start=0, env_stop=64)
    actor.reset(incarnation=0, carry=<bytes of its carry slice> or None, key=[..])
    batch = actor.rollout(weights, version=3, k_levels=[..], k_roll=[..])   # -> bytes (see `decode_batch`)

A batch carries its stamp (actor index, incarnation, policy version), the compact trajectory
(`cec.training.compact`) and the actor's stage timings and level-feed state, which the learner exports.

Levels: fixed tasks and Dual Destination are drawn locally from the learner's key exactly as the
single-process trainer draws them (so `sync` mode reproduces it); procedural kitchens come from the level
server through a reconnecting `LevelStreamBuffer`. If the server is unreachable and the buffer runs dry,
the actor keeps training on kitchens it has already received (counted as reused) instead of stalling.
"""

from __future__ import annotations

import logging
import os
import time
from typing import Any, NamedTuple

import jax
import jax.numpy as jnp
import numpy as np

from cec.training.compact import CompactRollout, from_bytes, to_bytes
from cec.training.config import TrainConfig
from cec.training.rollout import RolloutCarry, init_carry
from cec.training.trainer import Trainer

log = logging.getLogger("cec.actor")


class ActorStats(NamedTuple):
    """What the actor reports with each batch (exported by the learner's metrics endpoint)."""

    rollout_s: float  # the jitted rollout (and level feed), seconds
    encode_s: float  # serialising the batch
    levels_buffered: int  # streamed kitchens waiting in the local buffer
    levels_reused: int  # kitchens replayed from the local pool because the stream had none (cumulative)
    reconnects: int  # level-stream reconnections (cumulative)
    pid: int


class BatchHeader(NamedTuple):
    actor: int
    incarnation: int
    version: int
    env_start: int
    env_stop: int


class ActorNotReadyError(RuntimeError):
    """The actor has not been given its carry (a fresh or restarted process): call `reset` first."""


class RolloutActor:
    """Rollouts of envs `env_start:env_stop` of one seed (see the module docstring)."""

    def __init__(
        self,
        config: TrainConfig,
        index: int,
        env_start: int,
        env_stop: int,
        level_server: str = "",
        level_token: str = "",
        level_seed: int = 0,
        level_buffer_rollouts: int = 8,
    ) -> None:
        self.config = config
        self.index, self.env_start, self.env_stop = index, env_start, env_stop
        self.trainer = Trainer(self.config)
        self.trainer.load_partners()
        self.env_ids = jnp.arange(env_start, env_stop, dtype=jnp.int32)
        self.incarnation = -1
        self.carry: RolloutCarry | None = None
        self.version = -1
        self.params: Any = None
        self.seeds = config.num_seeds  # every leaf below has this leading axis: the seeds, vmapped
        params_of = jax.vmap(lambda k: self.trainer.init_one(k).params)
        self._params_template = jax.eval_shape(params_of, self._keys())
        self._collect = jax.jit(self._collect_fn)
        self._init_carry = jax.jit(self._init_carry_fn)
        self.levels_reused = 0
        self._pool: Any = None  # the last kitchens received (reused during a level-server outage)
        self.stream = None
        if level_server and self.trainer.task.levels == "generator":
            from services.level_server.client import LevelStreamBuffer

            per_rollout = (env_stop - env_start) * self.config.levels_per_env * config.num_seeds
            self.stream = LevelStreamBuffer(
                level_server,
                seed=level_seed,
                capacity=level_buffer_rollouts * per_rollout,
                batch_size=min(512, level_buffer_rollouts * per_rollout),
                config=self.config.env.generator,
                token=level_token or None,
            )
        log.info("actor %d: envs %d..%d, pid %d", index, env_start, env_stop, os.getpid())

    # ---- jitted pieces -------------------------------------------------------------------------------

    def _keys(self, key: jax.Array | None = None) -> jax.Array:
        """One key per seed from `key` (shapes only when None)."""
        return jax.random.split(jax.random.PRNGKey(0) if key is None else key, self.seeds)

    def _init_carry_fn(self, keys: jax.Array, levels: Any) -> RolloutCarry:
        """Fresh episodes of every seed's envs (keys [S], levels [S, E, K])."""

        def one(key: jax.Array, levels: Any) -> RolloutCarry:
            task, network, params = self.trainer.task, self.trainer.network, self.trainer.env_params
            return init_carry(task, network, params, levels, key, self.env_ids)

        return jax.vmap(one)(keys, levels)

    def _collect_fn(
        self,
        params: Any,
        carry: RolloutCarry,
        k_levels: jax.Array,
        k_roll: jax.Array,
        levels: Any,
        version: jax.Array,
    ) -> tuple[RolloutCarry, CompactRollout]:
        """Every seed's rollout (leading seed axis on all but `version`), as `cec train` vmaps its seeds."""
        if levels is None:
            levels = self._local_levels(k_levels)

        def one(
            params: Any, carry: RolloutCarry, k_levels: jax.Array, k_roll: jax.Array, levels: Any
        ) -> tuple[RolloutCarry, CompactRollout]:
            start_level = carry.env_state.level
            # the weights' version is the learner's update count: the update index of this rollout
            carry, traj = self.trainer.collect(
                params,
                carry,
                k_levels,
                k_roll,
                self.trainer.population,
                record="state",
                levels=levels,
                update_index=version,
            )
            return carry, CompactRollout(traj, start_level, levels)

        return jax.vmap(one)(params, carry, k_levels, k_roll, levels)

    def _local_levels(self, keys: jax.Array) -> Any:
        """[S, E, K] level buffers drawn here from each seed's key, as the single-process trainer draws."""
        k = self.config.levels_per_env
        return jax.vmap(lambda key: self.trainer.task.sample_levels(key, self.env_ids, k))(keys)

    # ---- the learner's calls ---------------------------------------------------------------------------

    def reset(self, incarnation: int, carry: bytes | None = None, key: Any = None) -> int:
        """Takes up `incarnation`: continues from `carry` (bytes of this slice's `RolloutCarry`) or, when
        None, starts new episodes from `key` (uint32[2]; split over the seeds). Returns the process id (for
        fault tests)."""
        if carry is not None:
            template = jax.eval_shape(self._init_carry_fn, self._keys(), self._levels(None, True))
            self.carry = jax.tree.map(jnp.asarray, from_bytes(template, carry))
        else:
            k = jnp.asarray(key, jnp.uint32) if key is not None else jax.random.PRNGKey(0)
            levels = self._levels(self._keys(jax.random.fold_in(k, 1)), False)
            self.carry = self._init_carry(self._keys(k), levels)
        self.incarnation = incarnation
        return os.getpid()

    def rollout(self, weights: bytes, version: int, k_levels: Any, k_roll: Any) -> bytes:
        """One rollout with the weights of `version` (msgpack bytes; decoded once per version)."""
        if self.carry is None:
            raise ActorNotReadyError(f"actor {self.index} has no carry yet (restarted?): reset it first")
        t0 = time.perf_counter()
        if version != self.version:
            self.params = jax.tree.map(jnp.asarray, from_bytes(self._params_template, weights))
            self.version = version
        k_levels = jnp.asarray(k_levels, jnp.uint32)
        levels = self._levels(k_levels, False) if self.stream is not None else None
        self.carry, compact = self._collect(
            self.params, self.carry, k_levels, jnp.asarray(k_roll, jnp.uint32), levels, jnp.int32(version)
        )
        jax.block_until_ready(compact)
        t1 = time.perf_counter()
        header = BatchHeader(self.index, self.incarnation, version, self.env_start, self.env_stop)
        stats = self._stats(t1 - t0, 0.0)
        payload = to_bytes(compact)
        stats = stats._replace(encode_s=time.perf_counter() - t1)
        return to_bytes({"header": header._asdict(), "stats": stats._asdict(), "rollout": payload})

    def carry_bytes(self) -> bytes:
        """This slice's carry (the learner checkpoints the concatenation of every actor's)."""
        if self.carry is None:
            raise ActorNotReadyError(f"actor {self.index} has no carry yet")
        return to_bytes(self.carry)

    def ping(self) -> int:
        return os.getpid()

    def close(self) -> None:
        if self.stream is not None:
            self.stream.close()

    # ---- levels ------------------------------------------------------------------------------------------

    def _levels(self, keys: Any, shape_only: bool) -> Any:
        """[S, E, K] level buffers: streamed kitchens when there is a level server (the seeds share the
        stream, each taking its own kitchens), else local draws from each seed's key (`keys`: [S])."""
        s, n, k = self.seeds, self.env_stop - self.env_start, self.config.levels_per_env
        if self.stream is None or shape_only:
            return self._local_levels(self._keys() if keys is None else keys)
        want = s * n * k
        try:  # the first kitchens are worth waiting for; later ones only briefly
            flat = self.stream.take(want, timeout=None if self._pool is None else 1.0)
            self._pool = flat
        except TimeoutError:  # outage: replay received kitchens in a fresh random order
            self.levels_reused += want
            size = int(self._pool.grid.shape[0])
            idx = np.asarray(jax.random.randint(jax.random.fold_in(keys[0], 7), (want,), 0, size))
            flat = jax.tree.map(lambda x: x[idx], self._pool)
        return jax.tree.map(lambda x: jnp.asarray(x).reshape((s, n, k, *x.shape[1:])), flat)

    def _stats(self, rollout_s: float, encode_s: float) -> ActorStats:
        s = self.stream
        return ActorStats(
            rollout_s,
            encode_s,
            0 if s is None else s.buffered,
            self.levels_reused,
            0 if s is None else s.stats.reconnects,
            os.getpid(),
        )


def decode_batch(data: bytes) -> tuple[BatchHeader, ActorStats, bytes]:
    """(header, stats, compact rollout bytes) of a batch from `RolloutActor.rollout`."""
    msg = _restore(data)
    return BatchHeader(**msg["header"]), ActorStats(**msg["stats"]), msg["rollout"]


def _restore(data: bytes) -> dict:
    from flax import serialization

    msg = serialization.msgpack_restore(data)
    msg["header"] = {k: int(v) for k, v in msg["header"].items()}
    msg["stats"] = {k: (float(v) if k.endswith("_s") else int(v)) for k, v in msg["stats"].items()}
    return msg
