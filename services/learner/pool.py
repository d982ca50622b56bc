"""Where the learner's rollout actors live: the `ActorPool` seam, and the pool that keeps them in-process.

The learner talks to its actors only through a pool: it starts them, calls their methods (each call gives a
handle at once), waits for handles, reads results and shares the weights once per version with all of them.

    pool.start(specs)                                   # one `RolloutActor` per `ActorSpec`
    call = pool.call(i, "rollout", weights, version, k_levels, k_roll)
    pool.wait_all([call, ...]); done = pool.wait_any([call, ...])
    batch = pool.result(call)                           # `ActorLostError` when actor i's process died
    weights = pool.share(to_bytes(params))              # what `call` passes on to every actor

`LocalPool` (here) runs the actors as plain objects in the learner's process, each call when it is made:
`cec train --distributed --local` and the tests, no Ray. `RayPool` (`services.learner.ray_pool`, the one
module of the learner that imports Ray) runs each actor as a Ray actor Ray restarts when its process dies.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, fields
from typing import Any, Protocol

from cec.training.config import TrainConfig
from services.actors.actor import ActorNotReadyError, RolloutActor


class ActorLostError(RuntimeError):
    """An actor's process died (or restarted without its state) before answering a call; the learner
    gives it a new incarnation and fresh episodes (`reset`), then calls it again."""


@dataclass(frozen=True)
class ActorSpec:
    """What one actor is built from: its slice of the seed's envs and its level feed."""

    config: TrainConfig
    index: int
    env_start: int
    env_stop: int
    level_server: str = ""
    level_token: str = ""
    level_seed: int = 0
    level_buffer_rollouts: int = 8

    def args(self) -> tuple[Any, ...]:
        """`RolloutActor`'s constructor arguments, in its order (the fields' order)."""
        return tuple(getattr(self, f.name) for f in fields(self))

    def build(self) -> RolloutActor:
        return RolloutActor(*self.args())


class ActorPool(Protocol):
    """The learner's actors, wherever they run (see the module docstring)."""

    def start(self, specs: Sequence[ActorSpec]) -> None: ...

    def call(self, i: int, method: str, *args: Any) -> Any:
        """Starts `actor_i.method(*args)`; returns a handle for `wait_*` and `result` at once."""
        ...

    def wait_all(self, calls: Sequence[Any]) -> None: ...

    def wait_any(self, calls: Sequence[Any]) -> Any:
        """One of `calls` that has finished (waits for the first)."""
        ...

    def result(self, call: Any, timeout: float | None = None) -> Any:
        """The call's return value; `ActorLostError` if its actor died, its exception otherwise."""
        ...

    def share(self, value: Any) -> Any:
        """`value` as every actor receives it (stored once, passed by reference)."""
        ...

    def close(self) -> None: ...


@dataclass(frozen=True, eq=False)  # compared and hashed by identity: one handle per call
class _Done:
    """A finished in-process call."""

    value: Any = None
    error: BaseException | None = None


class LocalPool:
    """The actors as objects in this process; a call runs when it is made (so `wait_*` never waits)."""

    def __init__(self) -> None:
        self.actors: list[RolloutActor] = []

    def start(self, specs: Sequence[ActorSpec]) -> None:
        self.actors = [spec.build() for spec in specs]

    def call(self, i: int, method: str, *args: Any) -> _Done:
        try:
            return _Done(getattr(self.actors[i], method)(*args))
        except ActorNotReadyError as err:
            return _Done(error=ActorLostError(str(err)))
        except Exception as err:  # raised by `result`, where the learner reads it
            return _Done(error=err)

    def wait_all(self, calls: Sequence[Any]) -> None:
        return None

    def wait_any(self, calls: Sequence[Any]) -> Any:
        return calls[0]

    def result(self, call: Any, timeout: float | None = None) -> Any:
        if call.error is not None:
            raise call.error
        return call.value

    def share(self, value: Any) -> Any:
        return value

    def close(self) -> None:
        for actor in self.actors:
            actor.close()
        self.actors = []
