"""How training is distributed: where the actors run, sync/async, staleness, the level feed, metrics."""

from __future__ import annotations

import os
from dataclasses import dataclass

from cec.config import ConfigError
from cec.training.config import TrainConfig
from services.ports import METRICS_PORTS

MODES = ("sync", "async")
POOLS = ("ray", "local")


@dataclass(frozen=True)
class DistributedConfig:
    """The distributed trainer's settings (the run itself is a `TrainConfig`).

    Attributes:
        mode: `sync`: every update waits for one batch from every actor, all collected with the current
            weights; with the same seed it reproduces the single-process trainer's learning curve. `async`:
            actors never wait; the learner updates on the first `num_actors` batches to arrive and drops
            those more than `max_policy_lag` versions old (PPO's ratio uses each batch's own behaviour
            log-probabilities).
        pool: where the learner and its actors run. `ray`: the learner and each actor a Ray actor (Ray
            restarts a dead one; across a cluster's nodes). `local`: all of them in the driver's process, no
            Ray (one machine; the same updates as `ray` in `sync` mode; nothing restarts a dead process).
        num_actors: rollout actors; each plays `num_envs / num_actors` of the run's envs.
        max_policy_lag: async only: the oldest weights (in versions behind the learner) a batch may be from.
        actor_cpus: CPUs Ray reserves per actor.
        actor_threads: 1: each actor's XLA:CPU kernels run on one thread (`--xla_cpu_multi_thread_eigen=
            false`), so that actors sharing a node do not oversubscribe its cores; 0: XLA's default (a
            thread per core the process may use). XLA has no flag for N threads: XLA sizes its pool from
            the process's CPU affinity, so give an actor N cores by limiting that (`taskset`).
        actor_max_restarts: how often Ray restarts a dead actor (-1: always), on any node that has room: a
            dead node's actors come back on the others.
        actor_resource: a custom Ray resource each actor takes one unit of, so that actors run only on the
            nodes that declare it (`ray start --resources='{"rollout": 8}'` hosts up to 8); empty: any node
            with the CPUs.
        actor_spread: place the actors on as many nodes as possible (Ray's SPREAD strategy), so that one
            node's death takes few of them; false: Ray packs them.
        learner_max_restarts: how often the driver restarts a dead learner, which resumes from its latest
            checkpoint.
        learner_gpus: GPUs Ray reserves for the learner (0: it runs JAX on a CPU; 1: Ray places it on a node
            with a free GPU, which its JAX uses, so that node needs JAX's CUDA build: `pip install -e
            '.[cuda]'`, as `cluster/config.yaml`'s head node does).
        learner_resource: a custom Ray resource the learner takes one unit of (pins it to the node that
            declares it, e.g. the head: `ray start --head --resources='{"learner": 1}'`); empty: anywhere.
        level_server: `host:port` of the level server that streams procedural kitchens to the actors
            (Overcooked `generator` runs); empty: actors draw levels themselves from the learner's keys.
        level_token: bearer token for the level server (empty: the CEC_LEVEL_SERVER_TOKEN variable).
        level_buffer_rollouts: kitchens each actor keeps buffered from the stream, in rollouts' worth: what
            it trains on through a level-server outage before it starts replaying kitchens it has seen.
        metrics_port: the learner's Prometheus `/metrics` port (0: a free port; -1: off).
        metrics_host: bind address of the metrics endpoint.
        publish_checkpoints: register the run and publish checkpoint events to Redis (the evaluator's feed).
        ray_address: Ray cluster to attach to (`auto`, `ray://host:10001`, ...); empty: start a local Ray.
        ray_num_cpus: CPUs of a local Ray (0: all of this machine's).
    """

    mode: str = "sync"
    pool: str = "ray"
    num_actors: int = 2
    max_policy_lag: int = 1
    actor_cpus: float = 1.0
    actor_threads: int = 1
    actor_max_restarts: int = -1
    actor_resource: str = ""
    actor_spread: bool = True
    learner_max_restarts: int = 3
    learner_gpus: float = 0.0
    learner_resource: str = ""
    level_server: str = ""
    level_token: str = ""
    level_buffer_rollouts: int = 8
    metrics_port: int = METRICS_PORTS["learner"]
    metrics_host: str = "127.0.0.1"
    publish_checkpoints: bool = True
    ray_address: str = ""
    ray_num_cpus: int = 0

    def __post_init__(self) -> None:
        if self.mode not in MODES:
            raise ConfigError(f"distributed.mode {self.mode!r} is unknown; choose one of {list(MODES)}")
        if self.pool not in POOLS:
            raise ConfigError(f"distributed.pool {self.pool!r} is unknown; choose one of {list(POOLS)}")
        if self.num_actors < 1:
            raise ConfigError(f"distributed.num_actors must be >= 1, got {self.num_actors}")
        if self.max_policy_lag < 0:
            raise ConfigError(f"distributed.max_policy_lag must be >= 0, got {self.max_policy_lag}")
        if self.level_buffer_rollouts < 1:
            raise ConfigError(
                f"distributed.level_buffer_rollouts must be >= 1, got {self.level_buffer_rollouts}"
            )
        if self.learner_gpus < 0:
            raise ConfigError(f"distributed.learner_gpus must be >= 0, got {self.learner_gpus}")
        if self.actor_cpus <= 0:
            raise ConfigError(f"distributed.actor_cpus must be > 0, got {self.actor_cpus}")
        if self.actor_threads not in (0, 1):
            raise ConfigError(
                f"distributed.actor_threads must be 1 (one XLA thread per actor) or 0 (XLA's default), got "
                f"{self.actor_threads}: XLA has no flag for N threads; it sizes its pool from the process's "
                "CPU affinity, so limit that (taskset) to give an actor N cores"
            )
        if self.metrics_port < -1 or self.metrics_port > 65535:
            raise ConfigError(
                f"distributed.metrics_port must be -1 (off), 0 (free) or a port, got {self.metrics_port}"
            )

    def check(self, train: TrainConfig) -> None:
        """Checks this distribution against the run (before any process starts)."""
        if train.num_seeds > 1 and train.devices != 1:
            raise ConfigError(
                f"num_seeds={train.num_seeds} with devices={train.devices}: the distributed learner vmaps "
                "its seeds on one device or splits one seed over several, not both; set devices=1 or "
                "num_seeds=1"
            )
        if train.level_repeats != 1:
            raise ConfigError(
                f"level_repeats={train.level_repeats} is built into `cec train` only; the distributed "
                "learner's actors draw (or stream) fresh kitchens every update: leave it at 1, or use "
                "cec train"
            )
        if self.learner_gpus and train.devices > self.learner_gpus:
            raise ConfigError(
                f"devices={train.devices}, but the learner has distributed.learner_gpus="
                f"{self.learner_gpus:g}; give it as many GPUs or lower devices (0: all of its GPUs)"
            )
        if train.num_envs % self.num_actors:
            raise ConfigError(
                f"num_envs={train.num_envs} must split evenly over distributed.num_actors={self.num_actors}"
            )


def check_streamed(train: TrainConfig) -> None:
    """A `ConfigError` naming the setting when a run whose kitchens stream from a level server asks for
    what no level server streams (before any process starts)."""
    if train.env.levels == "generator" and not train.env.generator.exclude_heldout:
        raise ConfigError(
            "env.generator.exclude_heldout=false: a level server never streams the validation or test "
            "kitchens, and this run's kitchens stream from one; remove the setting"
        )


def actor_env(dist: DistributedConfig) -> dict[str, str]:
    """The environment of each rollout actor process Ray starts: CPU JAX unless the driver chose another
    platform, and with `actor_threads=1` XLA:CPU's kernels on one thread."""
    env = {"JAX_PLATFORMS": os.environ.get("JAX_PLATFORMS", "cpu")}
    if dist.actor_threads == 1:
        env["XLA_FLAGS"] = xla_flags("--xla_cpu_multi_thread_eigen=false")
    return env


def xla_flags(*own: str) -> str:
    """`XLA_FLAGS` for a process Ray starts: this process's own flags (a user's `--xla_dump_to`, a lighter
    optimisation level) kept, then `own`, which XLA reads last and so wins where both name a flag."""
    return " ".join(f for f in (os.environ.get("XLA_FLAGS", ""), *own) if f).strip()
