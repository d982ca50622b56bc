"""The learner's actors as Ray actors: `RayPool`, the `ActorPool` (`services.learner.pool`) of `cec up` and
`cec train --distributed`. Ray restarts an actor whose process dies (`actor_max_restarts`); its calls then
raise `ActorLostError` and the learner resets it. The only module of the learner and the actors that
imports Ray.
"""

from __future__ import annotations

import contextlib
from collections.abc import Sequence
from typing import Any

import ray

from services.actors.actor import ActorNotReadyError, RolloutActor
from services.learner.config import DistributedConfig, actor_env
from services.learner.pool import ActorLostError, ActorSpec


class RayPool:
    """One Ray actor per `ActorSpec`, placed and restarted as `DistributedConfig` says."""

    def __init__(self, dist: DistributedConfig) -> None:
        self.dist = dist
        self.handles: list[Any] = []

    def start(self, specs: Sequence[ActorSpec]) -> None:
        d = self.dist
        remote = ray.remote(RolloutActor).options(
            num_cpus=d.actor_cpus,
            resources={d.actor_resource: 1} if d.actor_resource else None,
            scheduling_strategy="SPREAD" if d.actor_spread else "DEFAULT",
            max_restarts=d.actor_max_restarts,
            max_task_retries=0,
            runtime_env={"env_vars": actor_env(d)},
        )
        self.handles = [remote.remote(*s.args()) for s in specs]

    def call(self, i: int, method: str, *args: Any) -> Any:
        return getattr(self.handles[i], method).remote(*args)

    def wait_all(self, calls: Sequence[Any]) -> None:
        ray.wait(list(calls), num_returns=len(calls))

    def wait_any(self, calls: Sequence[Any]) -> Any:
        ready, _ = ray.wait(list(calls), num_returns=1)
        return ready[0]

    def result(self, call: Any, timeout: float | None = None) -> Any:
        try:
            return ray.get(call, timeout=timeout)
        except (ray.exceptions.RayActorError, ray.exceptions.GetTimeoutError, ActorNotReadyError) as err:
            raise ActorLostError(f"{type(err).__name__}: {err}") from err

    def share(self, value: Any) -> Any:
        return ray.put(value)

    def close(self) -> None:
        for handle in self.handles:
            with contextlib.suppress(Exception):  # already gone
                ray.kill(handle, no_restart=True)
        self.handles = []
