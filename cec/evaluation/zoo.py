"""The partner zoo: a manifest of policies (name, algorithm, seed, checkpoint), and loading them.

A zoo manifest is YAML or JSON (docs/evaluation.md):

    policies:
      - {name: cec_s0, algorithm: cec, seed: 0, checkpoint: runs/cec-s0/checkpoints/update_000001000}
      - {name: ippo_cramped_s0, algorithm: ippo, seed: 0, checkpoint: runs/ippo-cr-s0, levels: [cramped_room]}
    - {name: oracle, scripted: dd_oracle}      # a scripted policy (`cec.evaluation.scripted`), no checkpoint

`checkpoint` is a checkpoint directory or a run directory (its latest checkpoint); relative paths are
relative to the manifest's folder. `algorithm` and `seed` default to the checkpoint's metadata; `seed`
picks the seed out of a multi-seed checkpoint. `levels` (optional) restricts the entry to those levels
(single-task agents): a pairing is played on the levels both partners accept. `sha256` (optional, written
by `cec zoo build`) pins the checkpoint's state; `env`, `layout` and `env_steps` are descriptive only.

A malformed manifest is a `ConfigError` (nothing is evaluated). An entry whose checkpoint is missing,
corrupt or does not fit the evaluation is *skipped with its reason recorded* (`SkippedEntry`), never
silently dropped.

The package ships trained policies (`cec/shipped/zoo.yaml`, written by `cec zoo export`): the zoo name
`shipped` is that manifest wherever a zoo is taken (`cec eval --zoo shipped`, the evaluator, `cec play`),
and an entry's name stands for its checkpoint wherever a checkpoint is taken (`cec play serve --checkpoint
cec_cpu_s200`). A shipped checkpoint holds one seed's parameters only (`save_policy`), a few MB.
"""

from __future__ import annotations

import json
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from functools import cache
from pathlib import Path
from typing import Any

import jax
import numpy as np
import yaml

from cec import checkpoints
from cec.agents.network import ActorCritic, NetworkConfig, init_params
from cec.config import ConfigError, from_dict
from cec.evaluation.results import SkippedEntry
from cec.training.config import TrainConfig
from cec.training.tasks import EnvConfig, Task

#: The zoo name that stands for the manifest of the policies shipped with the package.
SHIPPED = "shipped"
SHIPPED_ZOO = Path(__file__).resolve().parents[1] / "shipped" / "zoo.yaml"
_ENTRY_KEYS = ("name", "algorithm", "seed", "checkpoint", "scripted", "levels", "sha256")
#: Descriptive keys `cec zoo build` also writes (not used to load the policy).
_INFO_KEYS = ("env", "layout", "env_steps")


@dataclass(frozen=True)
class ZooEntry:
    """One policy of the zoo as the manifest names it.

    Attributes:
        name: unique label (used in the result table).
        checkpoint: checkpoint or run directory (absolute, or relative to the current directory); empty
            for a scripted entry.
        algorithm: algorithm label (`cec`, `ippo`, `fcp`, ...); None: the checkpoint's metadata.
        seed: which seed (also picks it out of a multi-seed checkpoint); None: the checkpoint's only seed.
        levels: level names this policy plays; None: every level of the evaluation.
        sha256: the checkpoint state's SHA-256 when the zoo was built; a checkpoint that no longer
            matches is skipped (it was replaced since).
        scripted: a scripted policy kind (`cec.evaluation.scripted.SCRIPTED`, e.g. `dd_oracle`) played
            instead of a checkpoint; `algorithm` defaults to the kind, `seed` to 0.
    """

    name: str
    checkpoint: str
    algorithm: str | None = None
    seed: int | None = None
    levels: tuple[str, ...] | None = None
    sha256: str | None = None
    scripted: str | None = None


@dataclass(frozen=True)
class Policy:
    """A policy ready for cross-play: parameters plus what is needed to run them.

    Attributes:
        name, algorithm, seed: its labels in the result table.
        params: network parameters (no seed axis); None for a scripted policy.
        network: the architecture the parameters belong to (a placeholder for a scripted policy).
        env: the training environment's config (game, and the settings its observations depend on).
        levels: level names it plays (None: all).
        scripted: the scripted kind it plays instead of a network (`cec.evaluation.scripted`), or None.
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
    from cec.agents.network import network_preset

    env = env or EnvConfig()
    network = network or network_preset("small", env.name)
    params = _jitted_init(Task.from_config(env), network)(key)
    return Policy(name, algorithm, seed, params, network, env, levels)


@cache
def _jitted_init(task: Task, network: NetworkConfig) -> Any:
    net = ActorCritic(network, task.num_actions)
    return jax.jit(lambda key: init_params(net, key, task.obs_shape))


# ---------------------------------------------------------------------------------------------------------
# MANIFEST
# ---------------------------------------------------------------------------------------------------------


def parse_zoo(data: Any, base_dir: str | Path = ".", *, where: str = "zoo") -> list[ZooEntry]:
    """Entries from manifest data: a list of entries, or a mapping with a `policies` list."""
    if isinstance(data, Mapping):
        extra = sorted(set(data) - {"policies"})
        if extra:
            raise ConfigError(f"{where}: unknown top-level key(s) {extra}; a zoo has one key, `policies`")
        data = data.get("policies")
    if not isinstance(data, list) or not data:
        raise ConfigError(f"{where}: expected a non-empty list of policies (see docs/evaluation.md)")
    entries: list[ZooEntry] = []
    for i, item in enumerate(data):
        at = f"{where}: policies[{i}]"
        if not isinstance(item, Mapping):
            raise ConfigError(f"{at} must be a mapping with keys {list(_ENTRY_KEYS)}, got {item!r}")
        unknown = sorted(set(item) - set(_ENTRY_KEYS) - set(_INFO_KEYS))
        if unknown:
            raise ConfigError(f"{at}: unknown key(s) {unknown}; valid keys: {list(_ENTRY_KEYS + _INFO_KEYS)}")
        if not isinstance(item.get("name"), str) or not item["name"]:
            raise ConfigError(f"{at}: `name` is required and must be a non-empty string")
        scripted = item.get("scripted")
        if scripted is not None:
            from cec.evaluation.scripted import scripted_kind

            if not isinstance(scripted, str):
                raise ConfigError(f"{at}: `scripted` must be a scripted policy kind, got {scripted!r}")
            try:
                scripted_kind(scripted)
            except ConfigError as err:
                raise ConfigError(f"{at}: {err}") from err
            if "checkpoint" in item or "sha256" in item:
                raise ConfigError(
                    f"{at}: a `scripted` entry has no `checkpoint` or `sha256`; give one or the other"
                )
        elif not isinstance(item.get("checkpoint"), str) or not item["checkpoint"]:
            raise ConfigError(
                f"{at}: `checkpoint` is required and must be a non-empty string (or give `scripted`)"
            )
        algorithm = item.get("algorithm")
        if algorithm is not None and (not isinstance(algorithm, str) or not algorithm):
            raise ConfigError(f"{at}: `algorithm` must be a non-empty string, got {algorithm!r}")
        seed = item.get("seed")
        if seed is not None and (isinstance(seed, bool) or not isinstance(seed, int)):
            raise ConfigError(f"{at}: `seed` must be an integer, got {seed!r}")
        levels = item.get("levels")
        if levels is not None:
            if not isinstance(levels, list) or not levels or not all(isinstance(x, str) for x in levels):
                raise ConfigError(f"{at}: `levels` must be a non-empty list of level names, got {levels!r}")
            levels = tuple(levels)
        sha256 = item.get("sha256")
        if sha256 is not None and (not isinstance(sha256, str) or len(sha256) != 64):
            raise ConfigError(f"{at}: `sha256` must be a 64-digit hex string, got {sha256!r}")
        if scripted is not None:
            entries.append(ZooEntry(item["name"], "", algorithm, seed, levels, None, scripted))
            continue
        path = Path(item["checkpoint"])
        if not path.is_absolute():
            path = Path(base_dir) / path
        entries.append(ZooEntry(item["name"], str(path), algorithm, seed, levels, sha256))
    names = [e.name for e in entries]
    dupes = sorted({n for n in names if names.count(n) > 1})
    if dupes:
        raise ConfigError(f"{where}: policy names must be unique; repeated: {dupes}")
    return entries


def load_zoo(path: str | Path) -> list[ZooEntry]:
    """Reads a zoo manifest (YAML or JSON); relative checkpoint paths are relative to its folder. The name
    `shipped` (`SHIPPED`) is the manifest of the policies shipped with the package."""
    p = SHIPPED_ZOO if str(path) == SHIPPED else Path(path)
    if not p.is_file():
        raise ConfigError(f"zoo manifest {str(p)!r} does not exist (see docs/evaluation.md for the format)")
    try:
        data = json.loads(p.read_text()) if p.suffix == ".json" else yaml.safe_load(p.read_text())
    except (yaml.YAMLError, json.JSONDecodeError) as err:
        raise ConfigError(f"zoo manifest {str(p)!r} is not valid YAML/JSON: {err}") from err
    return parse_zoo(data, p.parent, where=str(p))


# ---------------------------------------------------------------------------------------------------------
# CHECKPOINTS -> POLICIES
# ---------------------------------------------------------------------------------------------------------


def shipped_entries() -> list[ZooEntry]:
    """The policies shipped with the package (empty when none are)."""
    return load_zoo(SHIPPED_ZOO) if SHIPPED_ZOO.is_file() else []


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


def save_policy(policy: Policy, path: str | Path, *, config: dict, env_steps: int, update: int) -> Path:
    """Writes one policy's parameters (no optimiser state, no seed axis) as a checkpoint `load_policy`
    reads: `config` is the training config it came from, kept for its network and environment."""
    if policy.params is None:
        raise ValueError(f"policy {policy.name!r} is scripted: it has no parameters to save")
    metadata = {"algorithm": policy.algorithm, "seeds": [policy.seed], "params_only": True}
    return checkpoints.save(
        path, policy.params, update=update, env_steps=env_steps, config=config, metadata=metadata
    )


@cache
def _state_template(config_json: str) -> Any:
    from cec.training.trainer import Trainer

    config = from_dict(TrainConfig, json.loads(config_json))
    return Trainer(config).state_template()


def load_policy(entry: ZooEntry) -> Policy:
    """Loads one entry's parameters (checksum and shapes verified by `cec.checkpoints.load`).

    Raises `CheckpointError` (missing, corrupt, unknown config, seed not in the checkpoint) with the cause.
    A scripted entry becomes its scripted policy (`cec.evaluation.scripted.scripted_policy`).
    """
    if entry.scripted is not None:
        from cec.evaluation.scripted import scripted_policy

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
    try:
        config = from_dict(TrainConfig, meta["config"])
    except (ConfigError, KeyError, TypeError) as err:
        raise checkpoints.CheckpointError(
            f"checkpoint {path} holds a config this code cannot read ({err}); re-export it with this "
            "version or evaluate it with the version that wrote it"
        ) from err
    metadata = meta.get("metadata", {})
    if metadata.get("params_only"):  # one seed's parameters (`save_policy`)
        template = _jitted_init(Task.from_config(config.env), config.network_config)(jax.random.PRNGKey(0))
        params, _ = checkpoints.load(path, template)
        seed = int(metadata["seeds"][0])
        if entry.seed is not None and entry.seed != seed:
            raise checkpoints.CheckpointError(
                f"checkpoint {path} holds seed {seed}, not seed {entry.seed}; fix the entry's `seed`"
            )
        algorithm = entry.algorithm or str(metadata.get("algorithm", config.algorithm))
        params = jax.tree.map(np.asarray, params)
        return Policy(entry.name, algorithm, seed, params, config.network_config, config.env, entry.levels)
    state, _ = checkpoints.load(path, _state_template(json.dumps(meta["config"], sort_keys=True)))
    seeds = [int(s) for s in metadata.get("seeds", [config.seed + i for i in range(config.num_seeds)])]
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
    params = jax.tree.map(lambda x: np.asarray(x[index]), state.params)
    algorithm = entry.algorithm or str(metadata.get("algorithm", config.algorithm))
    return Policy(entry.name, algorithm, seed, params, config.network_config, config.env, entry.levels)


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
