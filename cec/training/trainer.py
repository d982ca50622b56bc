"""The single-process trainer: rollout + PPO update fused into one compiled call, seeds vmapped.

This is the paper's own topology and the embedded default on one machine:

    state = init(seeds)                          # params, Adam state, env + LSTM carries, keys, counters
    repeat: state, metrics = train_call(state)   # jit(vmap over seeds(scan over `updates_per_call` updates))
            write metrics rows, checkpoint when due, print progress

Everything random comes from the per-seed key in the state, and the state is checkpointed whole, so a
run interrupted between calls and resumed produces the same parameters as an uninterrupted one.
"""

from __future__ import annotations

import csv
import dataclasses
import json
import math
import os
import sys
import time
from pathlib import Path
from typing import Any, NamedTuple, TextIO

import jax
import jax.numpy as jnp
import optax
import yaml

from cec import checkpoints
from cec.agents.network import ActorCritic, init_params
from cec.agents.policy import load_policy
from cec.agents.zoo import ZooEntry
from cec.config import ConfigError
from cec.signals import GracefulStop
from cec.training.config import TrainConfig
from cec.training.population import load_population
from cec.training.ppo import LossInfo, make_batch, make_optimizer, update
from cec.training.rollout import RolloutCarry, Trajectory, init_carry, rollout
from cec.training.tasks import Task
from cec.training.tracking import Tracker, describe


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
        self._init = jax.jit(self.init_one)
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

    def init_one(self, key: jax.Array) -> TrainState:
        """The initial state of one seed from its key."""
        cfg = self.config
        key, k_params, k_levels, k_reset = jax.random.split(key, 4)
        params = init_params(self.network, k_params, self.task.obs_shape)
        levels = self.task.sample_levels(k_levels, self.env_ids, cfg.levels_per_env)
        carry = init_carry(self.task, self.network, self.env_params, levels, k_reset)
        return TrainState(params, self.optimizer.init(params), carry, key, jnp.zeros((), jnp.int32))

    def shaping_weight(self, update_index: jax.Array) -> jax.Array:
        """Weight of the shaped reward at an update: 1 falling linearly to 0 over the shaping horizon."""
        if self.shaping_horizon < 0:
            return jnp.float32(1.0)
        steps = update_index.astype(jnp.float32) * self.config.steps_per_update
        return jnp.clip(1.0 - steps / float(max(self.shaping_horizon, 1)), 0.0, 1.0)

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
    ) -> tuple[RolloutCarry, Trajectory]:
        """One rollout of the envs in `carry` (all of a seed's, or an actor's slice): levels drawn for those
        envs from `k_levels` unless given (streamed kitchens), then `rollout`."""
        cfg = self.config
        if levels is None:
            levels = self.task.sample_levels(k_levels, carry.env_id, cfg.levels_per_env)
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
        )

    def learn(
        self, params: Any, opt_state: Any, update_index: jax.Array, traj: Trajectory, k_update: jax.Array
    ) -> tuple[Any, Any, UpdateMetrics]:
        """The PPO update on one trajectory of a seed's envs (the trainer's and the Ray learner's)."""
        cfg = self.config
        weight = self.shaping_weight(update_index)
        batch = make_batch(traj, weight, cfg.ppo.gamma, cfg.ppo.gae_lambda, cfg.partner.learner_seat_only)
        lr = self.schedule(_adam_count(opt_state))
        params, opt_state, loss = update(
            params, opt_state, batch, k_update, network=self.network, optimizer=self.optimizer, config=cfg.ppo
        )
        n, mean_return, mean_shaped, collisions = episode_stats(traj)
        metrics = UpdateMetrics(
            n, mean_return, mean_shaped, collisions, weight, jnp.asarray(lr, jnp.float32), loss
        )
        return params, opt_state, metrics

    def update_step(self, state: TrainState, population: Any = None) -> tuple[TrainState, UpdateMetrics]:
        """One rollout and one PPO update for one seed (`population`: FCP's partners, else None)."""
        key, k_levels, k_roll, k_update = self.update_keys(state.key)
        carry, traj = self.collect(state.params, state.carry, k_levels, k_roll, population)
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

            call = jax.jit(jax.vmap(many, in_axes=(0, None)), donate_argnums=0)
            self._calls[n_updates] = lambda state: call(state, self.population)
        return self._calls[n_updates]

    def init(self) -> TrainState:
        """Initial state for all seeds (leading axis S)."""
        # Seeds are initialised one by one and stacked: on XLA:CPU (jax 0.10) a vmapped orthogonal init of
        # the network (batched QR) can deadlock at run time; the init is a one-off, so nothing is lost.
        cfg = self.config
        states = [self._init(jax.random.PRNGKey(cfg.seed + i)) for i in range(cfg.num_seeds)]
        state: TrainState = jax.tree.map(lambda *xs: jnp.stack(xs), *states)
        if cfg.init_from:  # CEC-Finetune: every seed starts from the checkpoint's exact parameters
            params = jax.tree.map(
                lambda x: jnp.broadcast_to(x, (cfg.num_seeds, *x.shape)), self.initial_params()
            )
            opt_state = jax.vmap(self.optimizer.init)(params)
            state = state._replace(params=params, opt_state=opt_state)
        return state

    def initial_params(self) -> Any:
        """The parameters of `init_from` (checked against this run's game, observations and network)."""
        cfg = self.config
        seed = None if cfg.init_from_seed < 0 else cfg.init_from_seed
        try:
            policy = load_policy(ZooEntry(name="init_from", checkpoint=cfg.init_from, seed=seed))
        except checkpoints.CheckpointError as err:
            raise ConfigError(f"init_from: {err}") from err
        if policy.env.name != cfg.env.name or policy.network != cfg.network_config:
            raise ConfigError(
                f"init_from {cfg.init_from} was trained on {policy.env.name} with network {policy.network}; "
                f"this run plays {cfg.env.name} with {cfg.network_config}: use a matching checkpoint/preset"
            )
        return policy.params

    def state_template(self) -> TrainState:
        """Shapes and dtypes of the state (no compute), for loading checkpoints."""
        keys = jax.ShapeDtypeStruct((self.config.num_seeds, 2), jnp.uint32)
        return jax.eval_shape(jax.vmap(self.init_one), keys)


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


# ---------------------------------------------------------------------------------------------------------
# HOST LOOP: run directory, metrics files, checkpoints, progress, signals
# ---------------------------------------------------------------------------------------------------------


class RunResult(NamedTuple):
    state: TrainState
    run_dir: Path
    updates_done: int
    interrupted: bool


def trains_as(written: dict, config: TrainConfig) -> bool:
    """Whether a checkpoint's recorded config (`written`) trains what `config` trains. Where the run lives
    (`run_dir`, `name`) and where its series go (`tracking`) are left out: a moved or copied run is the
    same run, and so is one that was written before `tracking` existed."""
    where = ("run_dir", "name", "tracking")
    ours = config_dict(config)
    return {k: v for k, v in written.items() if k not in where} == {
        k: v for k, v in ours.items() if k not in where
    }


def config_dict(config: TrainConfig) -> dict:
    """The config as plain data (YAML/JSON-safe; tuples become lists)."""
    return json.loads(json.dumps(dataclasses.asdict(config)))


def metrics_rows(config: TrainConfig, first_update: int, metrics: UpdateMetrics, sps: float) -> list[dict]:
    """One row per (update, seed) from metrics with leading axes [S, n]."""
    host = jax.device_get(metrics)
    loss = host.loss
    rows = []
    s_count, n = host.episodes.shape
    for j in range(n):
        upd = first_update + j + 1
        for s in range(s_count):
            row: dict[str, Any] = {
                "update": upd,
                "env_steps": upd * config.steps_per_update,
                "seed": config.seed + s,
                "episodes": int(host.episodes[s, j]),
                "mean_return": _num(host.mean_return[s, j]),
                "mean_shaped_return": _num(host.mean_shaped_return[s, j]),
                "collisions_per_episode": _num(host.collisions_per_episode[s, j]),
                "shaping_weight": _num(host.shaping_weight[s, j]),
                "learning_rate": _num(host.learning_rate[s, j]),
                **{name: _num(getattr(loss, name)[s, j]) for name in LossInfo._fields},
                "env_steps_per_s": round(sps, 1),
            }
            if config.env.game.normalised_score:  # always a column, so the CSV header has it
                ret = row["mean_return"]
                row["normalised_return"] = None if ret is None else ret / (2 * config.env.params.max_steps)
            rows.append(row)
    return rows


def _num(x: Any) -> float | None:
    v = float(x)
    return None if math.isnan(v) else v


class MetricsWriter:
    """Appends metrics rows to `metrics.jsonl` and `metrics.csv` in the run directory."""

    def __init__(self, run_dir: Path) -> None:
        self.jsonl = run_dir / "metrics.jsonl"
        self.csv = run_dir / "metrics.csv"

    def write(self, rows: list[dict]) -> None:
        if not rows:
            return
        with open(self.jsonl, "a") as f:
            for row in rows:
                f.write(json.dumps(row) + "\n")
        new = not self.csv.exists()
        with open(self.csv, "a", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=list(rows[0]), extrasaction="ignore")
            if new:
                writer.writeheader()
            writer.writerows(rows)

    def truncate_after(self, update: int) -> None:
        """Drops rows past `update` (written after the checkpoint a resumed run continues from)."""
        if self.jsonl.exists():
            keep = [ln for ln in self.jsonl.read_text().splitlines() if json.loads(ln)["update"] <= update]
            self.jsonl.write_text("".join(ln + "\n" for ln in keep))
        if self.csv.exists():
            with open(self.csv, newline="") as f:
                reader = csv.DictReader(f)
                fields = reader.fieldnames or []
                kept = [r for r in reader if int(r["update"]) <= update]
            with open(self.csv, "w", newline="") as f:
                writer = csv.DictWriter(f, fieldnames=fields)
                writer.writeheader()
                writer.writerows(kept)


class Progress:
    """One status line per call: updates, env steps, steps/s, mean return, ETA (to stderr)."""

    def __init__(self, total_updates: int, steps_per_update: int, stream: TextIO = sys.stderr) -> None:
        self.total = total_updates
        self.spu = steps_per_update
        self.stream = stream

    def show(self, done: int, sps: float, mean_return: float | None, eta_s: float) -> None:
        ret = "n/a" if mean_return is None else f"{mean_return:.2f}"
        line = (
            f"update {done}/{self.total} ({100 * done / self.total:5.1f}%) | "
            f"{_si(done * self.spu)}/{_si(self.total * self.spu)} steps | {_si(sps)} steps/s | "
            f"return {ret} | ETA {_duration(eta_s)}"
        )
        print(line, file=self.stream, flush=True)


def _si(x: float) -> str:
    for unit, scale in (("G", 1e9), ("M", 1e6), ("k", 1e3)):
        if abs(x) >= scale:
            return f"{x / scale:.2f}{unit}"
    return f"{x:.0f}"


def _duration(seconds: float) -> str:
    if not math.isfinite(seconds):
        return "?"
    s = int(seconds)
    return f"{s // 3600}h{s % 3600 // 60:02d}m" if s >= 3600 else f"{s // 60}m{s % 60:02d}s"


class RunFiles:
    """A run directory's files: config, metrics rows, checkpoints (shared by the trainer and the learner).

    `open` takes the run directory's lock (`checkpoints.RunBusyError` when another process trains it),
    checks the directory (a run with checkpoints continues only with `resume`), loads the latest checkpoint
    into the trainer's state template (refusing one written with another config), trims metrics rows
    written after it, and returns the state and update count to continue from (None, 0: a new run).
    `tracker` opens the run's TensorBoard/W&B writer; `close` drops the lock.
    """

    def __init__(self, config: TrainConfig) -> None:
        self.config = config
        self.run_dir = Path(config.run_dir) / config.run_name
        self.store = checkpoints.CheckpointStore(self.run_dir, config.checkpoint.keep_last)
        self.writer = MetricsWriter(self.run_dir)
        self.lock = checkpoints.RunLock(self.run_dir)
        total = config.num_updates
        self.milestones = sorted({min(total, max(0, round(f * total))) for f in config.checkpoint.milestones})
        self.metadata = {
            "algorithm": config.algorithm,
            "seeds": [config.seed + i for i in range(config.num_seeds)],
            "env": config.env.name,
            "levels": config.env.levels,
            "network": config.network,
            "code_version": checkpoints.code_version(),
            "jax_version": jax.__version__,
        }

    def open(self, template: TrainState, resume: bool, log: TextIO) -> tuple[TrainState | None, int]:
        self.lock.acquire()
        try:
            return self._open(template, resume, log)
        except BaseException:
            self.lock.release()
            raise

    def close(self) -> None:
        self.lock.release()

    def _open(self, template: TrainState, resume: bool, log: TextIO) -> tuple[TrainState | None, int]:
        if self.store.directories() and not resume:
            raise checkpoints.CheckpointError(
                f"{self.run_dir} already has checkpoints; resume it with --resume {self.run_dir} "
                "or choose another name or run_dir"
            )
        latest = self.store.load_latest(template, log)
        if latest is None:
            self.writer.truncate_after(0)  # rows of an attempt killed before its first checkpoint
            (self.run_dir / "config.yaml").write_text(
                yaml.safe_dump(config_dict(self.config), sort_keys=False)
            )
            return None, 0
        state, meta = latest
        name = self.store.path(int(meta["update"])).name
        if not trains_as(meta["config"], self.config):
            raise checkpoints.CheckpointError(
                f"checkpoint {name} of {self.run_dir} was written with a different config; resume with the "
                f"run's own config ({self.run_dir / 'config.yaml'}) and no overrides"
            )
        done = int(meta["update"])
        self.writer.truncate_after(done)
        print(f"resuming {self.run_dir} from update {done} ({name})", file=log, flush=True)
        return state, done

    def due(self, prev: int, done: int) -> tuple[bool, bool]:
        """(a checkpoint is due after going from update `prev` to `done`, it is a milestone)."""
        every = self.config.checkpoint.every_updates
        crossed = any(prev < m <= done for m in self.milestones)
        return crossed or (every > 0 and done // every > prev // every), crossed

    def tracker(self, done: int) -> Tracker:
        """The run's `train` writer of TensorBoard events (and W&B), continuing after update `done`."""
        return Tracker(
            self.run_dir,
            self.config.tracking,
            name=self.config.run_name,
            role="train",
            resume_step=done * self.config.steps_per_update,
            run_config=config_dict(self.config),
        )

    def save(self, state: TrainState, update: int, milestone: bool) -> Path:
        return self.store.save(
            state,
            update=update,
            env_steps=update * self.config.steps_per_update,
            config=config_dict(self.config),
            metadata=self.metadata,
            milestone=milestone,
        )


def train(
    config: TrainConfig,
    *,
    resume: bool = False,
    max_updates: int | None = None,
    progress: bool = True,
    log: TextIO = sys.stderr,
) -> RunResult:
    """Runs (or resumes) a training run to its end, or until interrupted or `max_updates` more updates.

    The run directory `<run_dir>/<name>` gets `config.yaml`, `metrics.jsonl`, `metrics.csv`,
    `checkpoints/` and, per `config.tracking`, TensorBoard events in `tb/` (the metrics rows' values, at
    their env steps) and a W&B mirror. A run directory that already has checkpoints is only continued with
    `resume=True`.
    """
    config.tracking.check()  # W&B asked for and not installed: said before any work
    trainer = Trainer(config)
    trainer.load_partners()  # a bad population stops the run here, before any work
    files = RunFiles(config)
    loaded, done = files.open(trainer.state_template(), resume, log)
    tracker = None
    try:
        tracker = files.tracker(done)
        for line in describe(files.run_dir, config.tracking):
            print(line, file=log, flush=True)
        return _train_loop(trainer, files, tracker, loaded, done, max_updates, progress, log)
    finally:
        if tracker is not None:
            tracker.close()
        files.close()


def _train_loop(
    trainer: Trainer,
    files: RunFiles,
    tracker: Tracker,
    loaded: TrainState | None,
    done: int,
    max_updates: int | None,
    progress: bool,
    log: TextIO,
) -> RunResult:
    config = files.config
    run_dir, writer = files.run_dir, files.writer
    state = trainer.init() if loaded is None else loaded
    total = config.num_updates
    stop_at = total if max_updates is None else min(total, done + max_updates)
    per_call = config.updates_per_call
    meter = Progress(total, config.steps_per_update * config.num_seeds, log)
    if done == 0 and 0 in files.milestones:
        files.save(state, 0, milestone=True)
    interrupted = False
    with GracefulStop("finishing the current call, then saving a checkpoint") as flag:
        while done < stop_at:
            n = min(per_call, stop_at - done)
            if progress and n not in trainer._calls:
                print(f"compiling the training call ({n} update(s) per call)...", file=log, flush=True)
            call = trainer.train_call(n)
            t0 = time.perf_counter()
            state, metrics = call(state)
            jax.block_until_ready(state)
            dt = time.perf_counter() - t0
            sps = n * config.steps_per_update * config.num_seeds / dt
            rows = metrics_rows(config, done, metrics, sps)
            writer.write(rows)
            tracker.log_rows(rows)
            prev, done = done, done + n
            if progress:
                returns = [
                    r["mean_return"] for r in rows[-config.num_seeds :] if r["mean_return"] is not None
                ]
                meter.show(
                    done, sps, sum(returns) / len(returns) if returns else None, (total - done) * dt / n
                )
            due, crossed = files.due(prev, done)
            interrupted = flag.stop
            if due or done == stop_at or interrupted:
                files.save(state, done, milestone=crossed)
            if interrupted:
                print(
                    f"interrupted at update {done}; checkpoint saved. Continue with: "
                    f"cec train --resume {run_dir}",
                    file=log,
                    flush=True,
                )
                break
    return RunResult(state, run_dir, done, interrupted)
