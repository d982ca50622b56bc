"""The learner: drives the rollout actors, applies the PPO update, publishes weights, checkpoints.

    learner = Learner(train_config, distributed_config, store_config, pool=LocalPool())
    summary = learner.run(resume=True)           # until the run's end, `stop()`, or `max_updates`

It is a plain object (DESIGN rule 5) that reaches its actors only through an `ActorPool`
(`services.learner.pool`): `LocalPool` keeps them in its own process (`distributed.pool=local`: the whole
actor-learner loop in one process, no Ray), `RayPool` makes them Ray actors. The driver (`cec up`, `cec train
--distributed`) runs the learner in-process with a `LocalPool`, or as a Ray actor with a `RayPool` so that Ray
restarts it if its process dies; `run(resume=True)` then continues from the latest checkpoint with exact
counters. Each update:

    sync:  weights -> pool.share (once) -> every actor's rollout(weights, version, k_levels, k_roll)
           -> concatenate the slices in env order -> expand observations -> Trainer.learn
    async: the same calls, but each actor is resubmitted with the newest weights the moment its batch
           lands; the update takes the first num_actors batches no older than max_policy_lag versions

The update is the single-process trainer's own `Trainer.learn`, keys come from the same per-update split
(`Trainer.update_keys`), and the checkpoint is the trainer's `TrainState` with one seed, so a `sync` run
reproduces `cec train` and either can resume the other's checkpoints. The loop around the updates (metrics
rows, progress line, checkpoints when due, the stop) is `cec train`'s too, `cec.training.loop.run_updates`:
the learner is its `UpdateSource`, one update a step, and adds the distributed part (the actors' carries
in each checkpoint, Prometheus metrics, Redis events).

With `devices` > 1 the update is data-parallel over the learner's devices (the trainer's mesh: each
minibatch split over them, gradients averaged); each actor plays its slice on one device.

Every update's metrics row (`metrics.jsonl`, `metrics.csv`, and the TensorBoard events of
`cec.training.tracking`) holds the trainer's columns plus the learner's own (`DISTRIBUTED_COLUMNS`): the
policy lag of the update's batches, the batches dropped while gathering them, and the actors' level feed.

Faults: a dead actor (its call raises `ActorLostError`) is restarted by Ray; the learner gives it a new
incarnation and a fresh carry and resubmits the rollout (batches stamped with an older incarnation are
dropped and counted).
Redis being down queues checkpoint events in the run's outbox; they are published when it returns.

Size: one class, `Learner`, whose sync and async paths share the actor slots, incarnations and the weight
publication they must keep consistent.
"""

from __future__ import annotations

import dataclasses
import logging
import os
import sys
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

import jax
import jax.numpy as jnp
import numpy as np

from cec.training.compact import CompactRollout, expand, from_bytes, to_bytes
from cec.training.config import TrainConfig
from cec.training.loop import RunStoppedError, UpdateSource, out_of_memory, run_updates
from cec.training.ppo import LossInfo
from cec.training.rollout import RolloutCarry
from cec.training.run import RunFiles
from cec.training.trainer import Trainer, TrainState, UpdateMetrics
from services import metrics as M  # noqa: N812 - the metric objects, read as M.NAME
from services.actors.actor import decode_batch
from services.learner.config import DistributedConfig
from services.learner.pool import ActorLostError, ActorPool, ActorSpec, LocalPool

if TYPE_CHECKING:
    from services.store import StoreConfig

log = logging.getLogger("cec.learner")

#: The learner's columns of a metrics row, after the trainer's (TensorBoard section `distributed`).
DISTRIBUTED_COLUMNS = (
    "policy_lag_mean",  # policy versions between a batch's weights and the update's, over its batches
    "policy_lag_max",
    "batches_stale",  # batches dropped while gathering this update's: older than max_policy_lag ...
    "batches_dead_incarnation",  # ... or from an actor process that has since been restarted
    "levels_buffered",  # streamed kitchens waiting in the actors' buffers (at their last batches)
    "level_reconnects",  # level-stream reconnections of the actors so far in this learner (cumulative)
    "levels_reused",  # kitchens replayed from the actors' pools for want of streamed ones (cumulative)
)


@dataclass
class _FeedStats:
    """The learner's columns of a metrics row (`DISTRIBUTED_COLUMNS`): per update, and the level feed.

    The actors' level counters are cumulative per actor process; a restarted actor counts from 0 again,
    which is added on, not subtracted."""

    lags: list[int] = field(default_factory=list)
    stale: int = 0
    dead: int = 0
    buffered: dict[int, int] = field(default_factory=dict)
    totals: dict[str, int] = field(default_factory=lambda: {"reconnects": 0, "reused": 0})
    last: dict[tuple[str, int], int] = field(default_factory=dict)

    def actor(self, i: int, stats: Any) -> None:
        """An actor's `ActorStats` of a batch."""
        self.buffered[i] = int(stats.levels_buffered)
        for name, now in (("reconnects", int(stats.reconnects)), ("reused", int(stats.levels_reused))):
            before = self.last.get((name, i), 0)
            self.totals[name] += now - before if now >= before else now
            self.last[(name, i)] = now

    def columns(self) -> dict[str, float | int | None]:
        """This update's values, in the order of `DISTRIBUTED_COLUMNS` (the per-update ones start again)."""
        out: dict[str, float | int | None] = {
            "policy_lag_mean": float(np.mean(self.lags)) if self.lags else None,
            "policy_lag_max": max(self.lags) if self.lags else None,
            "batches_stale": self.stale,
            "batches_dead_incarnation": self.dead,
            "levels_buffered": sum(self.buffered.values()),
            "level_reconnects": self.totals["reconnects"],
            "levels_reused": self.totals["reused"],
        }
        self.lags, self.stale, self.dead = [], 0, 0
        return out


@dataclass
class _Slot:
    """The learner's view of one actor."""

    start: int
    stop: int
    incarnation: int = 0
    submitted: int = 0  # async: rollouts submitted (for its keys)


class Learner(UpdateSource):
    """See the module docstring."""

    def __init__(
        self,
        train: TrainConfig,
        distributed: DistributedConfig,
        store: StoreConfig | None = None,
        pool: ActorPool | None = None,
    ) -> None:
        self.config = train
        self.dist = distributed
        self.dist.check(self.config)
        self.store = store
        self.pool: ActorPool = LocalPool() if pool is None else pool
        self.trainer = Trainer(self.config)
        self.trainer.load_partners()
        self.files = RunFiles(self.config)
        self._stop = threading.Event()
        self._learn = jax.jit(self._learn_fn, donate_argnums=(0, 1))
        self.endpoint = None
        if self.dist.metrics_port >= 0:
            self.endpoint = M.MetricsEndpoint(
                self.dist.metrics_port, self.dist.metrics_host, "learner", key="distributed.metrics_port"
            )
            log.info("learner metrics on %s", self.endpoint.url)
        self.plane: Any = None
        self.slots: list[_Slot] = []
        self._held: dict[int, tuple[Any, Any]] = {}  # async: a batch per actor waiting for the next update
        self.feed = _FeedStats()

    # ---- pure pieces -------------------------------------------------------------------------------------

    def _learn_fn(
        self, params: Any, opt_state: Any, update: jax.Array, rollout: CompactRollout, key: jax.Array
    ) -> tuple[Any, Any, Any]:
        """Every seed's update (leading seed axis on all but `update`), as `cec train` vmaps its seeds."""

        def one(params: Any, opt_state: Any, rollout: CompactRollout, key: jax.Array) -> tuple[Any, Any, Any]:
            traj = expand(self.trainer.task, self.trainer.env_params, rollout)
            return self.trainer.learn(params, opt_state, update, traj, key)

        if self.config.num_seeds == 1:  # no vmap: one seed may be split over `devices` (the trainer's mesh)
            out = one(*jax.tree.map(lambda x: x[0], (params, opt_state, rollout, key)))
            return jax.tree.map(lambda x: x[None], out)
        return jax.vmap(one)(params, opt_state, rollout, key)

    def _seed_keys(self) -> jax.Array:
        return jax.random.split(jax.random.PRNGKey(0), self.config.num_seeds)

    def _slice_template(self) -> CompactRollout:
        """Shapes of one actor's `CompactRollout`, every seed's (to decode its bytes)."""
        n = self.config.num_envs // self.dist.num_actors

        def shaped(k: jax.Array) -> CompactRollout:
            state = self.trainer.init_one(k)
            carry = jax.tree.map(lambda x: x[:n], state.carry)
            levels = self.trainer.task.sample_levels(k, carry.env_id, self.config.levels_per_env)
            _, traj = self.trainer.collect(
                state.params, carry, k, k, self.trainer.population, record="state", levels=levels
            )
            return CompactRollout(traj, carry.env_state.level, levels)

        return jax.eval_shape(jax.vmap(shaped), self._seed_keys())

    def _carry_template(self) -> RolloutCarry:
        """Shapes of one actor's carry, every seed's."""
        n = self.config.num_envs // self.dist.num_actors
        return jax.eval_shape(
            jax.vmap(lambda k: jax.tree.map(lambda x: x[:n], self.trainer.init_one(k).carry)),
            self._seed_keys(),
        )

    # ---- control ------------------------------------------------------------------------------------------

    def stop(self) -> None:
        """Asks `run` to finish the current update, checkpoint and return (SIGINT/SIGTERM of the driver)."""
        self._stop.set()

    def ping(self) -> int:
        return os.getpid()

    def metrics_url(self) -> str:
        return "" if self.endpoint is None else self.endpoint.url

    def run(self, resume: bool = True, max_updates: int | None = None, restarts: int = 0) -> dict:
        """Trains to the end of the run (or `max_updates` more updates, or `stop()`); returns a summary.

        `restarts`: how often the driver restarted this learner (exported as a metric)."""
        self.config.tracking.check()
        with self.files.opened(self.trainer.state_template(), resume, sys.stderr) as (loaded, done, tracker):
            M.LEARNER_RESTARTS.set(restarts)
            state = self.trainer.init() if loaded is None else loaded  # leading seed axis
            self._connect_store(resume=loaded is not None)
            self._start_actors(state.carry)
            status, error = "failed", ""
            try:
                self._begin(state, done)
                # no resume hint: the driver gives it (`cec up` and `cec train --distributed` differ)
                outcome = run_updates(
                    self, self.files, tracker, done, max_updates=max_updates, stop=self._stop.is_set
                )
                done = outcome.done
                # a stop asked for during the last update lets the run finish
                status = "interrupted" if outcome.stopped and done < outcome.stop_at else "finished"
            except RunStoppedError as err:  # before the update was written or saved: the driver says so
                log.error("%s", err)
                error = str(err)
            finally:
                partial = status == "finished" and done < self.config.num_updates  # max_updates reached
                self._set_status("interrupted" if partial else status)
                self._close_actors()
        summary = {"updates": done, "status": status, "run_dir": str(self.files.run_dir)}
        return {**summary, "error": error} if error else summary

    # ---- the update source of `run_updates`: one update per step from the actors' batches --------------

    def _begin(self, state: TrainState, done: int) -> None:
        """The update loop's state at update `done` (attributes of a run, made here): the seeds' weights on
        the learner's devices and published to the actors, their optimiser states and keys."""
        self._template = self._slice_template()
        self._params, self._opt_state = self.trainer.replicate((state.params, state.opt_state))  # `devices`
        self._key = state.key
        self._version = done
        self._weights = self._publish(self._params, self._version)
        self._pending: dict[Any, int] = {}  # async: in-flight rollout -> slot index

    def step(self, done: int, n: int) -> UpdateMetrics:
        """Update `done + 1` (`n` is 1): the actors' batches for the published weights, the PPO update on
        them, the new weights published."""
        self._key, k_levels, k_roll, k_update = jax.vmap(self.trainer.update_keys)(self._key)
        if self.dist.mode == "sync":
            parts = self._sync_batches(self._weights, self._version, k_levels, k_roll, self._template)
        else:
            parts = self._async_batches(
                self._weights, self._version, self._key, self._pending, self._template
            )
        t_update = time.perf_counter()
        rollout = _concat_slices(parts)
        try:
            self._params, self._opt_state, metrics = self._learn(
                self._params, self._opt_state, jnp.int32(done), rollout, k_update
            )
            jax.block_until_ready(self._params)
        except jax.errors.JaxRuntimeError as err:
            stop = out_of_memory(self.config, err, "the learner's update")
            if stop is None:
                raise
            raise stop from None
        M.LEARNER_STAGE_SECONDS.labels("update").inc(time.perf_counter() - t_update)
        self._version = done + 1
        self._weights = self._publish(self._params, self._version)
        return jax.tree.map(lambda x: x[:, None], metrics)  # [seeds, updates] of the loop's rows

    def state(self) -> TrainState:
        """The run's state with every actor's carry (gathered from them), with its leading seed axis."""
        carry = self._gather_carry(self._key[0])
        update = jnp.full((self.config.num_seeds,), self._version, jnp.int32)
        return TrainState(self._params, self._opt_state, carry, self._key, update)

    def extra_columns(self) -> dict[str, Any]:
        return self.feed.columns()

    def sections(self) -> dict[str, str]:
        return {c: "distributed" for c in DISTRIBUTED_COLUMNS}

    def after_update(self, done: int, metrics: UpdateMetrics, sps: float) -> None:
        self._record(jax.tree.map(lambda x: x[:, -1], metrics), sps)
        self._heartbeat()

    def on_save(self, path: Path, seconds: float) -> None:
        M.LEARNER_CHECKPOINTS.inc()
        M.LEARNER_LAST_CHECKPOINT.set(time.time())
        M.LEARNER_STAGE_SECONDS.labels("checkpoint").inc(seconds)
        log.info("checkpoint %s", path)
        self._publish_checkpoint(path)

    # ---- actors -----------------------------------------------------------------------------------------

    def _start_actors(self, carry: RolloutCarry) -> None:
        cfg, d = self.config, self.dist
        n = cfg.num_envs // d.num_actors
        token = d.level_token or os.environ.get("CEC_LEVEL_SERVER_TOKEN", "")
        one_device = dataclasses.replace(cfg, devices=1)  # an actor plays its slice on its one device
        specs = [
            ActorSpec(
                one_device, i, i * n, (i + 1) * n, d.level_server, token, cfg.seed * 1000 + i,
                d.level_buffer_rollouts,
            )
            for i in range(d.num_actors)
        ]  # fmt: skip
        self.pool.start(specs)
        self.slots = [_Slot(s.env_start, s.env_stop) for s in specs]
        calls = [self.pool.call(i, "reset", 0, to_bytes(_envs(carry, s.start, s.stop))) for i, s in
                 enumerate(self.slots)]  # fmt: skip
        for call in calls:
            self.pool.result(call)
        log.info("%d actors ready (%d envs each, %s mode)", d.num_actors, n, d.mode)

    def _revive(self, i: int, key: jax.Array) -> None:
        """After slot i's actor died: wait for its restart, give it a new incarnation and fresh episodes."""
        slot = self.slots[i]
        slot.incarnation += 1
        M.ACTOR_RESTARTS.inc()
        fresh = np.asarray(jax.random.fold_in(key, 10_000 + 97 * i + slot.incarnation))
        log.warning("actor %d died; waiting for its restart (incarnation %d)", i, slot.incarnation)
        deadline = time.monotonic() + 300
        while True:
            try:
                self.pool.result(self.pool.call(i, "reset", slot.incarnation, None, fresh), timeout=120)
                return
            except ActorLostError as err:
                if time.monotonic() > deadline:
                    raise RuntimeError(f"actor {i} did not come back after a crash: {err}") from err
                time.sleep(0.5)

    def _submit(self, i: int, weights: Any, version: int, k_levels: Any, k_roll: Any) -> Any:
        return self.pool.call(i, "rollout", weights, version, np.asarray(k_levels), np.asarray(k_roll))

    def _fetch(self, i: int, ref: Any) -> tuple[Any, Any] | None:
        """(header, rollout bytes) of a finished rollout, or None if its actor died (it is revived)."""
        t0 = time.perf_counter()
        try:
            data = self.pool.result(ref)
        except ActorLostError as err:
            log.warning("actor %d: rollout lost (%s)", i, err)
            return None
        header, stats, payload = decode_batch(data)
        self.feed.actor(i, stats)
        M.LEARNER_STAGE_SECONDS.labels("transfer").inc(time.perf_counter() - t0)
        M.LEARNER_STAGE_SECONDS.labels("rollout").inc(stats.rollout_s)
        M.ACTOR_ROLLOUT_SECONDS.labels(str(i)).inc(stats.rollout_s)
        M.ACTOR_LEVEL_BUFFER.labels(str(i)).set(stats.levels_buffered)
        _catch_up(M.ACTOR_LEVEL_RECONNECTS.labels(str(i)), stats.reconnects)
        _catch_up(M.ACTOR_LEVELS_REUSED.labels(str(i)), stats.levels_reused)
        M.LEARNER_BYTES_RECEIVED.inc(len(data))
        envs = (header.env_stop - header.env_start) * self.config.num_seeds
        M.LEARNER_AGENT_STEPS_RECEIVED.inc(2 * envs * self.config.num_steps)
        return header, payload

    def _accept(self, i: int, header: Any, version: int) -> bool:
        slot = self.slots[i]
        if header.incarnation != slot.incarnation:
            M.LEARNER_BATCHES.labels("dead_incarnation").inc()
            self.feed.dead += 1
            return False
        lag = version - header.version
        if lag > self.dist.max_policy_lag and self.dist.mode == "async":
            M.LEARNER_BATCHES.labels("stale").inc()
            self.feed.stale += 1
            return False
        M.LEARNER_POLICY_LAG.observe(lag)
        self.feed.lags.append(lag)
        M.LEARNER_BATCHES.labels("accepted").inc()
        return True

    def _sync_batches(self, weights: Any, version: int, k_levels: Any, k_roll: Any, template: Any) -> list:
        refs = [self._submit(i, weights, version, k_levels, k_roll) for i in range(len(self.slots))]
        t0 = time.perf_counter()
        self.pool.wait_all(refs)
        M.LEARNER_STAGE_SECONDS.labels("wait").inc(time.perf_counter() - t0)
        parts = []
        for i, ref in enumerate(refs):
            while True:
                got = self._fetch(i, ref)
                if got is not None and self._accept(i, got[0], version):
                    parts.append(from_bytes(template, got[1]))
                    break
                if got is None:
                    self._revive(i, k_roll[0])
                ref = self._submit(i, weights, version, k_levels, k_roll)
        return parts

    def _async_keys(self, key: jax.Array, i: int) -> tuple[Any, Any]:
        slot = self.slots[i]
        slot.submitted += 1
        k = jax.random.fold_in(jax.random.fold_in(key, i), slot.submitted)
        keys = jax.random.split(k, 2 * self.config.num_seeds).reshape(2, self.config.num_seeds, -1)
        return keys[0], keys[1]  # levels and rollout keys of every seed

    def _async_batches(self, weights: Any, version: int, key: Any, pending: dict, template: Any) -> list:
        """One batch from every actor (its whole slice, so an update sees every env), taken as they land;
        an actor that delivers again before the others is resubmitted at once and its batch held for the
        next update (a newer one replaces it)."""
        root = jax.random.PRNGKey(self.config.seed + 7919)  # actors' own key chain, not the learner's
        busy = set(pending.values())
        for i in range(len(self.slots)):
            if i not in busy:
                pending[self._submit(i, weights, version, *self._async_keys(root, i))] = i
        parts: dict[int, Any] = {}
        for i, (header, payload) in sorted(self._held.items()):
            if self._accept(i, header, version):
                parts[i] = from_bytes(template, payload)
        self._held.clear()
        while len(parts) < len(self.slots):
            t0 = time.perf_counter()
            ready = self.pool.wait_any(list(pending))
            M.LEARNER_STAGE_SECONDS.labels("wait").inc(time.perf_counter() - t0)
            i = pending.pop(ready)
            got = self._fetch(i, ready)
            if got is None:
                self._revive(i, root)
            pending[self._submit(i, weights, version, *self._async_keys(root, i))] = i  # never idle
            if got is None:
                continue
            if i in parts:
                if i in self._held:
                    M.LEARNER_BATCHES.labels("stale").inc()  # replaced by a newer one before its turn
                    self.feed.stale += 1
                self._held[i] = got
            elif self._accept(i, got[0], version):
                parts[i] = from_bytes(template, got[1])
        return [parts[i] for i in sorted(parts)]

    def _gather_carry(self, key: Any) -> RolloutCarry:
        """Every actor's carry, concatenated in env order (axis 1, after the seeds; for the checkpoint)."""
        template = self._carry_template()
        parts = []
        for i in range(len(self.slots)):
            while True:
                try:
                    parts.append(from_bytes(template, self.pool.result(self.pool.call(i, "carry_bytes"))))
                    break
                except ActorLostError:
                    self._revive(i, key)
        return jax.tree.map(lambda *xs: jnp.concatenate([jnp.asarray(x) for x in xs], axis=1), *parts)

    def _close_actors(self) -> None:
        self.pool.close()
        self.slots = []

    # ---- weights, checkpoints, Redis, metrics --------------------------------------------------------------

    def _publish(self, params: Any, version: int) -> Any:
        t0 = time.perf_counter()
        ref = self.pool.share(to_bytes(params))
        M.LEARNER_POLICY_VERSION.set(version)
        M.LEARNER_STAGE_SECONDS.labels("publish").inc(time.perf_counter() - t0)
        return ref

    def _publish_checkpoint(self, path: Path) -> None:
        """Tells Redis of a new checkpoint (queued in the run's outbox while Redis is down)."""
        if self.plane is None:
            return
        from services.store import CheckpointEvent, StoreError

        try:
            result = self.plane.publish_checkpoint(
                CheckpointEvent.from_checkpoint(path, self.config.run_name)
            )
            M.LEARNER_REDIS_UP.set(result.outcome != "queued")
            if result.outcome == "queued":
                log.warning(
                    "Redis unreachable: checkpoint event %s queued in the outbox", result.checkpoint_id
                )
        except StoreError as err:
            M.LEARNER_REDIS_UP.set(0)
            log.error("could not publish checkpoint %s: %s (kept in the outbox)", path, err)
        M.LEARNER_CHECKPOINT_EVENTS_QUEUED.set(len(self.plane.pending_outbox()))

    def _connect_store(self, resume: bool) -> None:
        if not (self.dist.publish_checkpoints and self.store is not None):
            return
        from cec.training.run import config_dict
        from services.store import ControlPlane

        self.plane = ControlPlane.connect(self.store, outbox_dir=self.files.run_dir)
        self.plane.register_run(
            self.config.run_name, config=config_dict(self.config), algorithm=self.config.algorithm
        )
        self.plane.flush_outbox()  # events queued before a crash or an outage
        M.LEARNER_REDIS_UP.set(1)

    def _heartbeat(self) -> None:
        if self.plane is None:
            return
        from services.store import StoreError

        try:
            if self.plane.pending_outbox():
                self.plane.flush_outbox()
            self.plane.heartbeat(self.config.run_name)
            M.LEARNER_REDIS_UP.set(1)
        except StoreError:
            M.LEARNER_REDIS_UP.set(0)
        M.LEARNER_CHECKPOINT_EVENTS_QUEUED.set(len(self.plane.pending_outbox()))

    def _set_status(self, status: str) -> None:
        if self.plane is None:
            return
        from services.store import StoreError

        try:
            self.plane.set_run_status(self.config.run_name, status)
        except StoreError as err:
            log.warning("could not record run status %s: %s", status, err)

    def _record(self, metrics: UpdateMetrics, sps: float) -> None:
        """An update's metrics (leading seed axis) on the learner's Prometheus endpoint: the seeds' mean."""
        host = jax.tree.map(lambda x: np.mean(np.asarray(x), axis=0), jax.device_get(metrics))
        M.LEARNER_UPDATES.inc()
        M.LEARNER_ENV_STEPS.inc(self.config.steps_per_update * self.config.num_seeds)
        M.LEARNER_STEPS_PER_SECOND.set(sps)
        if np.isfinite(host.mean_return):
            M.LEARNER_EPISODE_RETURN.set(float(host.mean_return))
            M.LEARNER_SHAPED_RETURN.set(float(host.mean_shaped_return))
        for name in LossInfo._fields:
            M.LEARNER_LOSS.labels(name).set(float(getattr(host.loss, name)))


def _catch_up(counter: Any, total: int) -> None:
    """Raises a counter to an actor's cumulative count (a restarted actor counts from 0 again)."""
    counter.inc(max(0, total - counter._value.get()))


def _envs(tree: Any, start: int, stop: int) -> Any:
    """Envs `start:stop` of every seed (leaves [S, E, ...])."""
    return jax.tree.map(lambda x: x[:, start:stop], tree)


def _concat_slices(parts: list[CompactRollout]) -> CompactRollout:
    """The actors' rollouts (in env order; every leaf after its seed axis) as one rollout of all the envs."""
    traj_axis = {name: (1 if name in ("init_lstm", "last_value") else 2) for name in parts[0].traj._fields}
    cat = lambda axis, *xs: np.concatenate([np.asarray(x) for x in xs], axis=axis)  # noqa: E731
    traj = parts[0].traj._replace(
        **{
            name: jax.tree.map(
                lambda *xs, a=traj_axis[name]: cat(a, *xs), *[getattr(p.traj, name) for p in parts]
            )
            for name in parts[0].traj._fields
            if getattr(parts[0].traj, name) is not None
        }
    )
    start = jax.tree.map(lambda *xs: cat(1, *xs), *[p.start_level for p in parts])
    levels = jax.tree.map(lambda *xs: cat(1, *xs), *[p.levels for p in parts])
    return CompactRollout(traj, start, levels)
