"""Policies: trained parameters or a scripted kind, with what is needed to run them, and their checkpoints.

A `Policy` is what cross-play, the evaluator, FCP's partner population, `init_from` and `cec play` run.
`load_policy` turns a zoo entry (`cec.agents.zoo.ZooEntry`) into one: a checkpoint directory or run
directory (a training state with every seed: the entry's seed is picked out of it; or one seed's parameters
written by `save_policy`), a shipped policy's name, or a scripted kind (`scripted_policy`,
`cec.agents.scripted`). Checksums and shapes are verified on load (`cec.checkpoints`).
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import jax
import numpy as np

from cec import checkpoints
from cec.agents.network import ActorCritic, NetworkConfig, init_params, network_of, network_preset
from cec.agents.scripted import scripted_kind
from cec.agents.zoo import SkippedEntry, ZooEntry, shipped_entries
from cec.config import ConfigError, from_dict
from cec.envs.registry import game
from cec.envs.task import EnvConfig, Task


@dataclass(frozen=True)
class Policy:
    """A policy ready for cross-play: parameters plus what is needed to run them.

    Attributes:
        name, algorithm, seed: its labels in the result table.
        params: network parameters (no seed axis); None for a scripted policy.
        network: the architecture the parameters belong to (a placeholder for a scripted policy).
        env: the training environment's config (game, and the settings its observations depend on).
        levels: level names it plays (None: all).
        scripted: the scripted kind it plays instead of a network (`cec.agents.scripted`), or None.
    """

    name: str
    algorithm: str
    seed: int
    params: Any
    network: NetworkConfig
    env: EnvConfig
    levels: tuple[str, ...] | None = None
    scripted: str | None = None


def random_policy(
    name: str,
    key: jax.Array,
    *,
    env: EnvConfig | None = None,
    network: NetworkConfig | None = None,
    algorithm: str = "random",
    seed: int = 0,
    levels: tuple[str, ...] | None = None,
) -> Policy:
    """A randomly initialised policy (tests, benchmarks, a chance-level partner); default `small` network."""
    env = env or EnvConfig()
    network = network or network_preset("small", env.name)
    params = _jitted_init(Task.from_config(env), network)(key)
    return Policy(name, algorithm, seed, params, network, env, levels)


@cache
def _jitted_init(task: Task, network: NetworkConfig) -> Any:
    net = ActorCritic(network, task.num_actions)
    return jax.jit(lambda key: init_params(net, key, task.obs_shape))


@cache
def _param_shapes(obs_shape: tuple[int, ...], num_actions: int, network: NetworkConfig) -> Any:
    net = ActorCritic(network, num_actions)
    return jax.eval_shape(lambda key: init_params(net, key, obs_shape), jax.random.PRNGKey(0))


def _param_template(env: EnvConfig, network: NetworkConfig) -> Any:
    """Zeros shaped as one seed's parameters: what `checkpoints.load` checks a file against. From shapes
    alone (no compiled init), cached per observation shape and network, not per kitchen: a zoo of
    single-kitchen policies loads without compiling once per kitchen."""
    task = Task.from_config(env)
    shapes = _param_shapes(tuple(task.obs_shape), task.num_actions, network)
    return jax.tree.map(lambda s: np.zeros(s.shape, s.dtype), shapes)


def scripted_policy(
    kind: str,
    name: str | None = None,
    *,
    env: EnvConfig | None = None,
    algorithm: str | None = None,
    seed: int = 0,
    levels: tuple[str, ...] | None = None,
) -> Policy:
    """A `Policy` that plays the scripted `kind` (no parameters; its `network` is only a placeholder).

    Args:
        kind: a key of `SCRIPTED`.
        name, algorithm: labels in the result table (default: the kind).
        env: the env settings it plays when it leads an evaluation (only scripted policies in it); with
            networks in the evaluation it plays theirs. Default: the kind's game with default settings.
        seed, levels: as for any zoo entry.
    """
    spec = scripted_kind(kind)
    if env is None:
        env = EnvConfig(name=spec.env, levels=game(spec.env).default_levels)
    if env.name != spec.env:
        raise ConfigError(f"scripted policy {kind!r} plays {spec.env}, not {env.name}")
    return Policy(
        name or kind,
        algorithm or kind,
        seed,
        None,
        network_preset("small", spec.env),
        env,
        levels,
        scripted=kind,
    )


def resolve_checkpoint(path: str | Path) -> Path:
    """A checkpoint directory, a run directory's latest checkpoint, or the name of a shipped policy;
    `CheckpointError` if none of these."""
    p = Path(path)
    if (p / checkpoints.META_FILE).is_file():
        return p
    if not p.exists():
        shipped = {e.name: e.checkpoint for e in shipped_entries()}
        if str(path) in shipped:
            return Path(shipped[str(path)])
        names = f"; shipped policies: {', '.join(sorted(shipped))}" if shipped else ""
        raise checkpoints.CheckpointError(
            f"checkpoint {str(p)!r} is missing (no such file or directory){names}"
        )
    latest = checkpoints.CheckpointStore(p, keep_last=1).latest()
    if latest is None:
        raise checkpoints.CheckpointError(
            f"{str(p)!r} is neither a checkpoint (no {checkpoints.META_FILE}) nor a run directory with "
            "checkpoints/update_*"
        )
    return latest.path


def save_policy(
    policy: Policy, path: str | Path, *, config: dict, env_steps: int, update: int, code_version: str = ""
) -> Path:
    """Writes one policy's parameters (no optimiser state, no seed axis) as a checkpoint `load_policy`
    reads: `config` is the training config it came from, kept for its network and environment, and
    `code_version` the commit that trained it (recorded when given)."""
    if policy.params is None:
        raise ValueError(f"policy {policy.name!r} is scripted: it has no parameters to save")
    metadata: dict[str, Any] = {"algorithm": policy.algorithm, "seeds": [policy.seed], "params_only": True}
    if code_version:
        metadata["code_version"] = code_version
    return checkpoints.save(
        path, policy.params, update=update, env_steps=env_steps, config=config, metadata=metadata
    )


def load_policy(entry: ZooEntry) -> Policy:
    """Loads one entry's parameters (checksum and shapes verified by `cec.checkpoints.load`).

    Raises `CheckpointError` (missing, corrupt, unknown config, seed not in the checkpoint) with the cause.
    A scripted entry becomes its scripted policy (`scripted_policy`).
    """
    if entry.scripted is not None:
        seed = 0 if entry.seed is None else entry.seed
        return scripted_policy(
            entry.scripted, entry.name, algorithm=entry.algorithm, seed=seed, levels=entry.levels
        )
    path = resolve_checkpoint(entry.checkpoint)
    meta = checkpoints.read_meta(path)
    if entry.sha256 is not None and meta.get("sha256") != entry.sha256:
        raise checkpoints.CheckpointError(
            f"checkpoint {path} is not the one the zoo was built with (state SHA-256 "
            f"{str(meta.get('sha256'))[:12]}..., the manifest says {entry.sha256[:12]}...); rebuild the zoo "
            "or fix the entry"
        )
    config = _run_fields(path, meta)
    metadata = meta.get("metadata", {})
    if metadata.get("params_only"):  # one seed's parameters (`save_policy`)
        params, _ = checkpoints.load(path, _param_template(config.env, config.network_config))
        seed = int(metadata["seeds"][0])
        if entry.seed is not None and entry.seed != seed:
            raise checkpoints.CheckpointError(
                f"checkpoint {path} holds seed {seed}, not seed {entry.seed}; fix the entry's `seed`"
            )
        algorithm = entry.algorithm or str(metadata.get("algorithm", config.algorithm))
        params = jax.tree.map(np.asarray, params)
        return Policy(entry.name, algorithm, seed, params, config.network_config, config.env, entry.levels)
    seeds = [int(s) for s in metadata.get("seeds", [config.seed + i for i in range(config.num_seeds)])]
    one = _param_template(config.env, config.network_config)
    template = jax.tree.map(lambda x: np.zeros((len(seeds), *x.shape), x.dtype), one)
    stacked, _ = checkpoints.load(path, template, part="params")  # a training state: its parameters only
    if entry.seed is None:
        if len(seeds) != 1:
            raise checkpoints.CheckpointError(
                f"checkpoint {path} holds seeds {seeds}; give the entry a `seed` to pick one"
            )
        seed = seeds[0]
    else:
        seed = entry.seed
        if seed not in seeds:
            raise checkpoints.CheckpointError(
                f"checkpoint {path} holds seeds {seeds}, not seed {seed}; fix the entry's `seed`"
            )
    index = seeds.index(seed)
    params = jax.tree.map(lambda x: np.asarray(x[index]), stacked)
    algorithm = entry.algorithm or str(metadata.get("algorithm", config.algorithm))
    return Policy(entry.name, algorithm, seed, params, config.network_config, config.env, entry.levels)


def checkpoint_seeds(checkpoint: str) -> list[int]:
    """The seeds a checkpoint (or a run directory's latest) holds, in their order in its state."""
    path = resolve_checkpoint(checkpoint)
    meta = checkpoints.read_meta(path)
    config = _run_fields(path, meta)
    default = [config.seed + i for i in range(config.num_seeds)]
    return [int(s) for s in meta.get("metadata", {}).get("seeds", default)]


def _run_fields(path: Path, meta: dict[str, Any]) -> _RunFields:
    try:
        return _RunFields.of(meta["config"])
    except (ConfigError, KeyError, TypeError) as err:
        raise checkpoints.CheckpointError(
            f"checkpoint {path} holds a config this code cannot read ({err}); re-export it with this "
            "version or evaluate it with the version that wrote it"
        ) from err


@dataclass(frozen=True)
class _RunFields:
    """What a policy needs of the training config its checkpoint holds (not the whole `TrainConfig`)."""

    algorithm: str
    seed: int
    num_seeds: int
    env: EnvConfig
    network_config: NetworkConfig

    @classmethod
    def of(cls, config: dict[str, Any]) -> _RunFields:
        env = from_dict(EnvConfig, config["env"], where="env")
        overrides = config.get("network_overrides")
        network = network_of(
            str(config["network"]),
            None if overrides is None else from_dict(NetworkConfig, overrides, where="network_overrides"),
            env.name,
            int((config.get("partner") or {}).get("predict_partner", 0)),
        )
        return cls(str(config["algorithm"]), int(config["seed"]), int(config["num_seeds"]), env, network)


def load_policies(entries: Sequence[ZooEntry]) -> tuple[list[Policy], list[SkippedEntry]]:
    """Loads every entry; those that cannot be loaded are returned as `SkippedEntry` with the reason."""
    policies: list[Policy] = []
    skipped: list[SkippedEntry] = []
    for entry in entries:
        try:
            policies.append(load_policy(entry))
        except (checkpoints.CheckpointError, ConfigError, OSError, ValueError) as err:
            skipped.append(
                SkippedEntry(
                    entry.name,
                    entry.algorithm or "",
                    -1 if entry.seed is None else entry.seed,
                    f"{type(err).__name__}: {err}",
                )
            )
    return policies, skipped
