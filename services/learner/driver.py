"""The driver of a distributed run: starts the learner as a Ray actor and keeps it going.

    code = run_distributed(train_config, distributed_config, store_config, resume=False)

The learner runs in its own Ray worker process (`ray.remote(Learner)`), so that a crash of that process is
survived: Ray restarts the actor and the driver calls `run(resume=True)` again, which continues from the
latest checkpoint with the run's exact counters. SIGINT/SIGTERM ask the learner to finish its update,
checkpoint and return (a second signal stops at once). Used by `cec up` and `cec train --distributed`.
"""

from __future__ import annotations

import contextlib
import logging
import os
import sys
import threading
import time
from pathlib import Path
from typing import Any, TextIO

from cec import checkpoints
from cec.config import ConfigError
from cec.signals import GracefulStop
from cec.training.config import TrainConfig
from cec.training.loop import RunStoppedError
from cec.training.run import RunFiles, record_resume_command, resume_command, trains_as
from cec.training.tracking import describe
from services.entry import AlreadyDone
from services.learner.config import DistributedConfig, check_streamed, xla_flags
from services.store import StoreConfig

log = logging.getLogger("cec.driver")

EXIT_INTERRUPTED = 130


def check_start(
    train: TrainConfig,
    dist: DistributedConfig,
    store: StoreConfig | None,
    resume: bool,
    resume_hint: str = "",
) -> None:
    """Everything that can be checked before a process starts: the config pair, the run directory and the
    checkpoint to resume, Redis and the level server (each failure a `ConfigError` naming the fix)."""
    dist.check(train)
    check_run(train, resume, resume_hint)
    if store is not None and dist.publish_checkpoints:
        from services.store import ControlPlane, StoreError

        try:
            ControlPlane.connect(store).close()
        except StoreError as err:
            raise ConfigError(str(err)) from err
    if dist.level_server and train.env.levels == "generator":
        check_streamed(train)
        check_level_server(dist.level_server, dist.level_token)


def check_run(train: TrainConfig, resume: bool, resume_hint: str = "") -> None:
    """The run directory: a run with checkpoints continues only with `resume`, and then only with the
    config its latest checkpoint was written with; the run's tracking: W&B installed when asked for
    (`ConfigError` naming the fix: `resume_hint`, this command continuing the run, when given). A run
    whose latest checkpoint is its last update is finished, started or resumed (`AlreadyDone`): said
    before anything starts, where resuming it started the whole stack to find nothing left to train."""
    train.tracking.check()
    files = RunFiles(train)
    latest = files.store.latest()
    if latest is not None and latest.update >= train.num_updates:
        with contextlib.suppress(checkpoints.CheckpointError):  # unreadable: refused below as it is
            if trains_as(checkpoints.read_meta(latest.path).get("config") or {}, train):
                raise AlreadyDone(
                    f"{files.run_dir} is finished: all {train.num_updates} updates trained, the last in "
                    f"{latest.path}. `cec status {files.run_dir}` shows it; to train again, give the new run "
                    "another name: name=NEW (under `cec up`: train.name=NEW)"
                )
    if files.store.directories() and not resume:
        hint = resume_hint or resume_command(files.run_dir)
        raise ConfigError(
            f"{files.run_dir} already has checkpoints; continue it with `{hint}`, or give this run another "
            "name: name=NEW (under `cec up`: train.name=NEW)"
        )
    if latest is not None:
        try:
            meta = checkpoints.read_meta(latest.path)
        except checkpoints.CheckpointError as err:
            raise ConfigError(f"cannot resume from {latest.path}: {err}") from err
        if not trains_as(meta.get("config") or {}, train):
            raise ConfigError(
                f"checkpoint {latest.path} was written with a different config; resume with the run's own "
                f"config ({files.run_dir / 'config.yaml'}) and no overrides, or start a new run (name=...)"
            )


def check_level_server(address: str, token: str = "", timeout: float = 10.0) -> None:
    import grpc

    from services.level_server.client import LevelClient

    client = LevelClient(address, token=token or None)
    try:
        client.wait_ready(timeout=timeout)
    except (grpc.FutureTimeoutError, grpc.RpcError) as err:
        raise ConfigError(
            f"the level server at {address} does not answer ({type(err).__name__}); start it with "
            "`cec level-server` or set distributed.level_server to its host:port"
        ) from err
    finally:
        client.close()


def check_cluster(dist: DistributedConfig, resources: dict[str, float]) -> None:
    """The custom resources the learner and actors are pinned to, against the cluster's
    (`ray.cluster_resources()`): one no node declares would leave them waiting forever, so it is a
    `ConfigError` naming the fix (an autoscaling cluster's node types declare theirs under `resources`;
    keep one such node up, `min_workers: 1`)."""
    wanted = {
        "distributed.learner_resource": (dist.learner_resource, 1),
        "distributed.actor_resource": (dist.actor_resource, dist.num_actors),
    }
    for field, (name, units) in wanted.items():
        if name and resources.get(name, 0) < units:
            raise ConfigError(
                f"{field}={name!r} needs {units} unit(s) of Ray resource {name!r}, but the cluster's "
                f"nodes declare {resources.get(name, 0):g}; start nodes with "
                f"`ray start ... --resources='{{\"{name}\": {units}}}'` or clear {field}"
            )


def learner_options(dist: DistributedConfig, devices: int = 1) -> dict[str, Any]:
    """Ray's options for the learner's process: no CPU reserved (it mostly waits on the actors), the GPUs
    of `learner_gpus`, and the JAX platform: the driver's `JAX_PLATFORMS` (CPU by default), or JAX's own
    choice (the GPUs Ray gave it) when the learner has GPUs. A CPU learner asked for `devices` > 1 gets
    that many host devices (XLA's `--xla_force_host_platform_device_count`), which test what a multi-GPU
    learner computes but share the node's cores."""
    platforms = os.environ.get("JAX_PLATFORMS", "" if dist.learner_gpus else "cpu")
    env_vars = {"JAX_PLATFORMS": platforms}
    if not dist.learner_gpus and devices > 1:
        env_vars["XLA_FLAGS"] = xla_flags(f"--xla_force_host_platform_device_count={devices}")
    return {
        "num_cpus": 0,
        "num_gpus": dist.learner_gpus,
        "resources": {dist.learner_resource: 1} if dist.learner_resource else None,
        "max_restarts": dist.learner_max_restarts,
        "max_task_retries": 0,
        "max_concurrency": 2,  # `stop` runs while `run` does
        "runtime_env": {"env_vars": env_vars},
    }


#: Ray's own wait for its head to answer a driver (seconds, default 60; Ray reads it from the environment,
#: and a head started by `cec up` inherits it): what to raise when a loaded machine answers slowly.
RAY_WAIT_VARIABLE = "RAY_gcs_server_request_timeout_seconds"


class RayStartError(ConfigError):
    """Ray's head could not be started or reached; the message names the cause and the setting to raise."""


def first_line(text: str, limit: int = 200) -> str:
    """The first non-empty line of `text`, clipped to `limit` characters (a cause, not a traceback)."""
    line = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
    return line if len(line) <= limit else line[: limit - 3] + "..."


def connect_ray(address: str, **options: Any) -> Any:
    """`ray.init(address)`; the learner's and actors' lines Ray forwards here carry no colour codes when
    stderr is not a terminal (a log file, a pipe), as Ray's RAY_COLOR_PREFIX=0 makes them. `RayStartError`
    naming the address and `RAY_WAIT_VARIABLE` when Ray cannot be reached."""
    import ray

    if not sys.stderr.isatty():
        os.environ.setdefault("RAY_COLOR_PREFIX", "0")
    try:
        return ray.init(address=address, **options)
    except Exception as err:  # Ray raises ConnectionError, TimeoutError, RuntimeError and types of its own
        raise RayStartError(
            f"cannot connect to Ray at {address} ({type(err).__name__}: {first_line(str(err))}). A heavily "
            f"loaded machine answers slowly: raise Ray's wait, e.g. {RAY_WAIT_VARIABLE}=300 in the "
            f"environment (Ray's default: 60 s), and check that the cluster runs (`ray status --address "
            f"{address}`)"
        ) from None


def disconnect_ray() -> None:
    import ray

    ray.shutdown()


def run_distributed(
    train: TrainConfig,
    dist: DistributedConfig,
    store: StoreConfig | None,
    *,
    resume: bool = False,
    max_updates: int | None = None,
    log_to: TextIO = sys.stderr,
    resume_hint: str = "",
) -> int:
    """Runs the learner until the run ends: in this process with its actors when `dist.pool` is `local`,
    else as a Ray actor (Ray must be initialised). 0, or 130 when interrupted. `resume_hint`: the command
    that continues this run, recorded in the run (`resume_command`) and printed when it stops early."""
    check_start(train, dist, store, resume, resume_hint)
    run_dir = Path(train.run_dir) / train.run_name
    if resume_hint:
        record_resume_command(run_dir, resume_hint)
    for line in describe(run_dir, train.tracking):
        print(line, file=log_to, flush=True)
    if dist.pool == "local":
        summary: dict | None = _run_here(train, dist, store, resume, max_updates)
    else:
        summary = _run_on_ray(train, dist, store, resume, max_updates, log_to)
    if summary is None:
        return 1
    if summary.get("error"):  # a non-finite update, the memory run out: one line and exit 2, like `cec train`
        raise RunStoppedError(summary["error"])
    line = f"learner: {summary['status']} after {summary['updates']} updates ({summary['run_dir']})"
    if summary["status"] == "interrupted":
        line += f"; continue with: {resume_command(run_dir)}"
    print(line, file=log_to, flush=True)
    return EXIT_INTERRUPTED if summary["status"] == "interrupted" else 0


def _run_here(
    train: TrainConfig,
    dist: DistributedConfig,
    store: StoreConfig | None,
    resume: bool,
    max_updates: int | None,
) -> dict:
    """The learner and its actors in this process (`LocalPool`)."""
    from services.learner.learner import Learner
    from services.learner.pool import LocalPool

    learner = Learner(train, dist, store, LocalPool())
    with GracefulStop("the learner finishes its update and checkpoints", on_first=learner.stop):
        return learner.run(resume=resume, max_updates=max_updates)


def _run_on_ray(
    train: TrainConfig,
    dist: DistributedConfig,
    store: StoreConfig | None,
    resume: bool,
    max_updates: int | None,
    log_to: TextIO,
) -> dict | None:
    """The learner as a Ray actor with Ray actors (`RayPool`), restarted when its process dies; None when
    it died more often than `learner_max_restarts`."""
    import ray

    from services.learner.learner import Learner
    from services.learner.ray_pool import RayPool

    check_cluster(dist, ray.cluster_resources())
    remote = ray.remote(Learner).options(**learner_options(dist, train.devices))
    learner: Any = remote.remote(train, dist, store, RayPool(dist))
    stopping = threading.Event()

    def stop() -> None:
        stopping.set()
        with contextlib.suppress(Exception):
            learner.stop.remote()

    restarts = 0
    with GracefulStop("the learner finishes its update and checkpoints", on_first=stop):
        while True:
            ref = learner.run.remote(
                resume=resume or restarts > 0, max_updates=max_updates, restarts=restarts
            )
            try:
                summary = dict(_wait(ref))
                break
            except ray.exceptions.RayActorError as err:
                restarts += 1
                if restarts > dist.learner_max_restarts >= 0:
                    print(f"the learner died {restarts} times; giving up: {err}", file=log_to, flush=True)
                    return None
                print(
                    f"the learner process died ({type(err).__name__}); Ray restarts it and it resumes from "
                    f"its latest checkpoint (restart {restarts})",
                    file=log_to,
                    flush=True,
                )
                # One death is one restart: calls made while Ray brings the process back fail too (on a
                # loaded machine that takes minutes), so wait for the new process before calling `run`.
                if not _restarted(learner):
                    print(f"Ray did not restart the learner; giving up: {err}", file=log_to, flush=True)
                    return None
                if stopping.is_set():  # the stop request went to the dead process: ask the new one
                    time.sleep(1.0)
                    stop()
    with contextlib.suppress(Exception):
        ray.kill(learner, no_restart=True)
    return summary


def _restarted(actor: Any) -> bool:
    """Waits until Ray has restarted a dead actor's process (it answers); False when Ray will not."""
    import ray

    while True:
        try:
            _wait(actor.__ray_ready__.remote())
            return True
        except ray.exceptions.ActorDiedError:  # out of restarts, or its node is gone for good
            return False
        except ray.exceptions.ActorUnavailableError:  # still coming back: ask again
            time.sleep(0.5)


def _wait(ref: Any) -> Any:
    """The result of a Ray call, waited for in short waits that keep the main thread responsive to
    signals."""
    import ray

    while True:
        ready, _ = ray.wait([ref], timeout=0.5)
        if ready:
            return ray.get(ref)
