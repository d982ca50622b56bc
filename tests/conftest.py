"""What every test layer shares: one JAX compilation cache per session, XLA:CPU at optimisation level 1
(`_lighter_xla_optimisation`), a local Redis, a saved run.

The suite compiles the same training and evaluation calls many times over: in process (each test builds
its own `Trainer`, whose jitted functions are new objects) and in the `cec` commands the CLI and e2e tests
start as child processes. JAX's persistent compilation cache, pointed at one fresh folder for the session
(its path exported, so children inherit it), compiles each program once; a test that sets its own
`JAX_COMPILATION_CACHE_DIR` keeps it. Set `CEC_TEST_JAX_CACHE=<dir>` to keep the cache between sessions
(everyday work), or `CEC_TEST_JAX_CACHE=off` to compile everything afresh.
"""

from __future__ import annotations

import importlib.util
import os
import shutil
import sys
import tempfile
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest

pytest_plugins = ["tests.own_process"]
_CACHE_ENV = "JAX_COMPILATION_CACHE_DIR"


def pytest_configure(config: pytest.Config) -> None:
    _lighter_xla_optimisation()
    chosen = os.environ.get("CEC_TEST_JAX_CACHE", "")
    if chosen == "off" or _CACHE_ENV in os.environ:
        return
    if chosen:
        Path(chosen).mkdir(parents=True, exist_ok=True)
        folder = chosen
    else:
        folder = tempfile.mkdtemp(prefix="cec-tests-jax-cache-")
        config.stash[_own_cache] = folder  # removed at the end of the session
    os.environ[_CACHE_ENV] = folder
    os.environ.setdefault("JAX_PERSISTENT_CACHE_MIN_COMPILE_TIME_SECS", "0.2")
    if importlib.util.find_spec("filelock") is not None:
        # A size bound turns on JAX's file lock: the many processes of the e2e tests (Ray actors, the
        # evaluator) then never read an entry another one is still writing.
        os.environ.setdefault("JAX_COMPILATION_CACHE_MAX_SIZE", str(4 << 30))
    if "jax" in sys.modules:  # imported by a plugin before this ran: its config is already read
        import jax

        jax.config.update("jax_compilation_cache_dir", folder)
        jax.config.update("jax_persistent_cache_min_compile_time_secs", 0.2)


_own_cache = pytest.StashKey[str]()
_OPT_FLAG = "--xla_backend_optimization_level"


def _lighter_xla_optimisation() -> None:
    """XLA:CPU's backend at optimisation level 1 for the session (exported: the `cec` children inherit it),
    unless `XLA_FLAGS` already names a level. Most of the suite's time is compiling small programs: level 1
    compiles a test-sized `Trainer` about 20% faster, and on the CPU recipe it trains about 3% slower with
    the same losses to the last bit (measured on the 2-vCPU Intel Xeon; level 0 halves compile time but runs
    1.5x slower and changes results). A test that needs the default sets `XLA_FLAGS` for its child."""
    flags = os.environ.get("XLA_FLAGS", "")
    if _OPT_FLAG not in flags:
        os.environ["XLA_FLAGS"] = f"{flags} {_OPT_FLAG}=1".strip()


def own_jax_cache(tmp_path: Path) -> dict[str, str]:
    """The environment for a child process with fake host devices (`--xla_force_host_platform_device_count`,
    a flag JAX's cache key leaves out): a compilation cache of its own, so that no executable compiled among
    N devices is read by the suite's one-device processes."""
    return {_CACHE_ENV: str(tmp_path / "jax-cache")}


def _heavy_tier() -> frozenset[str]:
    """The node ids in tests/heavy_tier.txt, which `make test` leaves out (the file says why)."""
    text = (Path(__file__).parent / "heavy_tier.txt").read_text()
    ids = (line.split("#", 1)[0].strip() for line in text.splitlines())
    return frozenset(nodeid for nodeid in ids if nodeid)


HEAVY = _heavy_tier()


def pytest_collection_modifyitems(config: pytest.Config, items: list[pytest.Item]) -> None:
    """The end-to-end tests (whole stacks of Ray processes, `cec up`, a browser, timing their recoveries)
    form one xdist group: under `--dist loadgroup` one worker runs them one at a time while the other
    workers take the rest of the suite. The tests of `HEAVY` are marked `heavy`."""
    e2e = Path(__file__).parent / "e2e"
    for item in items:
        if e2e in Path(str(item.path)).parents:
            item.add_marker(pytest.mark.xdist_group("e2e"))
        if item.nodeid in HEAVY:
            item.add_marker(pytest.mark.heavy)


def pytest_unconfigure(config: pytest.Config) -> None:
    folder = config.stash.get(_own_cache, None)
    if folder is not None:
        shutil.rmtree(folder, ignore_errors=True)


@pytest.fixture(scope="session")
def redis_server() -> Iterator[Any]:
    """One real `redis-server` on a free loopback port for the session (`services.store.LocalRedis`).

    Tests that share it keep apart by key prefix (`redis_config`); a test that stops or restarts Redis
    starts its own instead."""
    from services.store import LocalRedis

    with LocalRedis() as server:
        yield server


@pytest.fixture
def redis_config(redis_server: Any) -> Any:
    """A `StoreConfig` on the session's Redis under a key prefix of this test's own."""
    return redis_server.config(key_prefix=f"t{uuid.uuid4().hex[:8]}", retries=1)


@pytest.fixture(scope="session")
def saved_run(tmp_path_factory: pytest.TempPathFactory) -> tuple[Path, Path, Any]:
    """A real two-seed checkpoint (seeds 4, 5) of a tiny IPPO run on Cramped Room, written by the trainer's
    own checkpoint code: (run directory, checkpoint directory, the saved state). Read it; never modify it."""
    from cec import checkpoints
    from cec.config import from_dict
    from cec.training.config import TrainConfig
    from cec.training.run import config_dict
    from cec.training.trainer import Trainer

    root = tmp_path_factory.mktemp("run")
    config = from_dict(
        TrainConfig,
        {
            "algorithm": "ippo",
            "seed": 4,
            "num_seeds": 2,
            "num_envs": 2,
            "num_steps": 8,
            "total_env_steps": 16,
            "network": "small",
            "env": {"name": "overcooked", "levels": "cramped_room", "overcooked": {"max_steps": 8}},
            "run_dir": str(root),
            "name": "r",
        },
    )
    trainer = Trainer(config)
    state = trainer.init()
    path = checkpoints.CheckpointStore(root / "r", keep_last=2).save(
        state,
        update=0,
        env_steps=0,
        config=config_dict(config),
        metadata={"algorithm": "ippo", "seeds": [4, 5]},
        milestone=False,
    )
    return root / "r", path, state
