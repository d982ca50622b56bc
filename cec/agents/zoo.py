"""The partner zoo's manifest: the policies it names (name, algorithm, seed, checkpoint or scripted kind).

A zoo manifest is YAML or JSON (docs/evaluation.md):

    policies:
      - {name: cec_s0, algorithm: cec, seed: 0, checkpoint: runs/cec-s0/checkpoints/update_000001000}
      - {name: ippo_cramped_s0, algorithm: ippo, seed: 0, checkpoint: runs/ippo-cr-s0, levels: [cramped_room]}
    - {name: oracle, scripted: dd_oracle}      # a scripted policy (`cec.agents.scripted`), no checkpoint

`checkpoint` is a checkpoint directory or a run directory (its latest checkpoint); relative paths are
relative to the manifest's folder. Where a zoo is taken, a folder stands for its `zoo.yaml` and an http(s)
URL for the bundle `cec zoo export` published there (`cec.agents.bundle`: downloaded once, every file's
size and SHA-256 checked). `algorithm` and `seed` default to the checkpoint's metadata; `seed`
picks the seed out of a multi-seed checkpoint. `levels` (optional) restricts the entry to those levels
(single-task agents): a pairing is played on the levels both partners accept. `sha256` (optional, written
by `cec zoo build`) pins the checkpoint's state; `env`, `layout` and `env_steps` are descriptive only.

A malformed manifest is a `ConfigError` (nothing is evaluated), and so is one that is not a regular file,
is larger than `ZOO_MAX_BYTES` or has more than `ZOO_MAX_ENTRIES` entries. An entry whose checkpoint is
missing, corrupt or does not fit the evaluation is *skipped with its reason recorded* (`SkippedEntry`),
never silently dropped.

The package ships trained policies (`cec/shipped/zoo.yaml`, written by `cec zoo export`): the zoo name
`shipped` is that manifest wherever a zoo is taken (`cec eval --zoo shipped`, the evaluator, `cec play`),
and an entry's name stands for its checkpoint wherever a checkpoint is taken (`cec play serve --checkpoint
cec_cpu_s200`). A shipped checkpoint holds one seed's parameters only (`save_policy`), a few MB.

Turning entries into runnable policies is `cec.agents.policy` (`load_policy`, `load_policies`).
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from cec.agents.bundle import zoo_manifest
from cec.agents.scripted import scripted_kind
from cec.config import ConfigError, read_user_json, read_user_yaml

#: The longest entry name or algorithm label (a result table's names are capped so: `cec.evaluation.results`).
NAME_MAX_CHARS = 256
#: The zoo name that stands for the manifest of the policies shipped with the package.
SHIPPED = "shipped"
SHIPPED_ZOO = Path(__file__).resolve().parents[1] / "shipped" / "zoo.yaml"
#: Per kitchen, the shipped partner `cec play serve --partner best` plays there (a policy name or an algorithm
#: of the shipped zoo), chosen with people's clones (benchmarks/results/overcooked/shipped/finetune/).
SHIPPED_BEST = SHIPPED_ZOO.parent / "best.yaml"
#: The algorithm label of behaviour-cloned human proxies (`cec humans bc`): reports score agents with them
#: apart from the other algorithms (as people-like partners, not as ad-hoc agents).
HUMAN_PROXY = "human_proxy"
_ENTRY_KEYS = ("name", "algorithm", "seed", "checkpoint", "scripted", "levels", "sha256")
#: Descriptive keys `cec zoo build` also writes (not used to load the policy).
_INFO_KEYS = ("env", "layout", "env_steps")
#: The largest zoo manifest read (an entry is a few hundred bytes).
ZOO_MAX_BYTES = 1 << 20
#: The most entries a zoo may have: each loads a policy and joins every pairing, so 10,000 entries took
#: gigabytes and minutes before any output (the largest reproduction's zoo has 84).
ZOO_MAX_ENTRIES = 512


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
        scripted: a scripted policy kind (`cec.agents.scripted.SCRIPTED`, e.g. `dd_oracle`) played
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
class SkippedEntry:
    """A zoo entry that could not be loaded, and why (`cec.agents.policy.load_policies`; recorded in result
    tables, never silently dropped)."""

    name: str
    algorithm: str
    seed: int
    reason: str


def parse_zoo(data: Any, base_dir: str | Path = ".", *, where: str = "zoo") -> list[ZooEntry]:
    """Entries from manifest data: a list of entries, or a mapping with a `policies` list."""
    if isinstance(data, Mapping):
        extra = sorted(set(data) - {"policies"})
        if extra:
            raise ConfigError(f"{where}: unknown top-level key(s) {extra}; a zoo has one key, `policies`")
        data = data.get("policies")
    if not isinstance(data, list) or not data:
        raise ConfigError(f"{where}: expected a non-empty list of policies (see docs/evaluation.md)")
    if len(data) > ZOO_MAX_ENTRIES:
        raise ConfigError(
            f"{where}: {len(data):,} policies, more than the {ZOO_MAX_ENTRIES} a zoo may have "
            f"({__name__}.ZOO_MAX_ENTRIES); split it into several zoos"
        )
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
        if len(item["name"]) > NAME_MAX_CHARS or not item["name"].isprintable():
            raise ConfigError(
                f"{at}: `name` {item['name'][:40]!r} must be at most {NAME_MAX_CHARS} printable characters "
                "(no NUL, line break or other control character); rename the entry"
            )
        scripted = item.get("scripted")
        if scripted is not None:
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
        if algorithm is not None and (
            not isinstance(algorithm, str)
            or not algorithm
            or len(algorithm) > NAME_MAX_CHARS
            or not algorithm.isprintable()
        ):
            raise ConfigError(
                f"{at}: `algorithm` must be a non-empty string of at most {NAME_MAX_CHARS} printable "
                f"characters, got {str(algorithm)[:40]!r}"
            )
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
    `shipped` (`SHIPPED`) is the manifest of the policies shipped with the package; a folder is its
    `zoo.yaml`, an http(s) URL a bundle's (`cec.agents.bundle.zoo_manifest`)."""
    p = SHIPPED_ZOO if str(path) == SHIPPED else zoo_manifest(path)
    if not p.exists():
        raise ConfigError(f"zoo manifest {str(p)!r} does not exist (see docs/evaluation.md for the format)")
    read = read_user_json if p.suffix == ".json" else read_user_yaml
    data = read(p, "zoo manifest", ZOO_MAX_BYTES, f"{__name__}.ZOO_MAX_BYTES")
    return parse_zoo(data, p.parent, where=str(p))


#: The key of `SHIPPED_BEST` that names the partner of every kitchen it does not name.
OTHER_KITCHENS = "other_kitchens"


def best_shipped(level: str) -> str:
    """The shipped partner `--partner best` plays in `level`: what `SHIPPED_BEST` names for it, else what it
    names for `OTHER_KITCHENS`, else the CEC seeds (`cec`), the generalists."""
    if not SHIPPED_BEST.is_file():
        return "cec"
    data = read_user_yaml(SHIPPED_BEST, "shipped partner choice", ZOO_MAX_BYTES, f"{__name__}.ZOO_MAX_BYTES")
    if not isinstance(data, Mapping) or not all(isinstance(v, str) for v in data.values()):
        raise ConfigError(f"{SHIPPED_BEST}: expected a mapping of level name -> shipped policy or algorithm")
    return str(data.get(level, data.get(OTHER_KITCHENS, "cec")))


def shipped_entries() -> list[ZooEntry]:
    """The policies shipped with the package (empty when none are)."""
    return load_zoo(SHIPPED_ZOO) if SHIPPED_ZOO.is_file() else []
