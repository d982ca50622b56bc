"""The partner zoo as the evaluator sees it: manifest + Redis entries, loaded once, grouped.

`PartnerZoo.snapshot()` re-reads the entry lists (the manifest file and `<prefix>:zoo` in Redis) and
returns every partner ready to play with its partner group, plus the entries that could not be loaded
(with the reason, as `cec eval` records them). Loaded parameters are cached by (entry, checkpoint
directory, state checksum), so a snapshot per checkpoint costs a few small file reads; an entry that points
at a run directory follows the run's newest checkpoint.
"""

from __future__ import annotations

import dataclasses
import logging
import re
from collections.abc import Sequence
from typing import NamedTuple

from cec import checkpoints
from cec.agents.policy import Policy, load_policy, resolve_checkpoint
from cec.agents.zoo import ZooEntry, load_zoo
from cec.config import ConfigError
from cec.envs.registry import GAMES
from cec.evaluation.results import SkippedEntry
from services.evaluator.config import EvaluatorConfig
from services.store import ControlPlane, PartnerRecord

log = logging.getLogger("cec.evaluator")

UNKNOWN_GROUP = "unknown"


class Partner(NamedTuple):
    """A zoo partner ready to play: its policy (name, labels, parameters) and its partner group."""

    policy: Policy
    group: str


class SkippedPartner(NamedTuple):
    """A zoo entry that is not played, why (`entry.reason`), and the group it would have been in."""

    entry: SkippedEntry
    group: str


class ZooSnapshot(NamedTuple):
    """The zoo at one moment: partners that play and entries that cannot (each with its group)."""

    partners: tuple[Partner, ...]
    skipped: tuple[SkippedPartner, ...]

    def for_game(self, env: str) -> ZooSnapshot:
        """The partners of game `env` (partners of another game are not part of that evaluation); the
        skipped entries stay (their game is unknown)."""
        return ZooSnapshot(tuple(p for p in self.partners if p.policy.env.name == env), self.skipped)

    def groups(self) -> list[str]:
        """Group names in first-seen order (manifest order, then Redis by name)."""
        seen: dict[str, None] = {}
        for group in [p.group for p in self.partners] + [s.group for s in self.skipped]:
            seen.setdefault(group, None)
        return list(seen)


def label(text: str) -> str:
    """`text` made a valid partner-group label (letters, digits, `_.:@+-`; at most 100 characters)."""
    clean = re.sub(r"[^A-Za-z0-9_.:@+-]", "_", text)
    if clean and not (clean[0].isalnum() or clean[0] == "_"):
        clean = "_" + clean
    return clean[:100] or UNKNOWN_GROUP


def entry_of_record(record: PartnerRecord) -> ZooEntry:
    """The zoo entry of a Redis partner; `env: overcooked:<classic kitchen>` restricts it to that kitchen."""
    game, _, layout = record.env.partition(":")
    known = GAMES.get(game)
    own_level = known is not None and known.single_task_own_level and layout in known.fixed_levels
    levels = (layout,) if own_level else None
    return ZooEntry(
        name=record.name,
        checkpoint=record.path,
        algorithm=record.algorithm or None,
        seed=record.seed,
        levels=levels,
        sha256=record.sha256 or None,
    )


def _overlap(a: ZooEntry | Policy, b: ZooEntry | Policy) -> bool:
    return a.levels is None or b.levels is None or bool(set(a.levels) & set(b.levels))


class PartnerZoo:
    """The evaluator's zoo: manifest entries and (optionally) Redis partners, grouped per the config.

    Args:
        config: the evaluator's config (`zoo`, `redis_zoo`, `group_by`, `groups`).
        plane: the control plane (for `redis_zoo`).
    """

    def __init__(self, config: EvaluatorConfig, plane: ControlPlane | None) -> None:
        self.config = config
        self.plane = plane
        self._explicit = {name: g.name for g in config.groups for name in g.partners}
        self._cache: dict[tuple[ZooEntry, str, str], Policy] = {}
        self._manifest: list[ZooEntry] = []
        self._warned: set[str] = set()
        if config.zoo:
            self._manifest = load_zoo(config.zoo)  # a bad manifest stops the service at start-up

    def entries(self) -> list[ZooEntry]:
        """Manifest entries (re-read; the last good list if the file became unreadable), then Redis ones."""
        if self.config.zoo:
            try:
                self._manifest = load_zoo(self.config.zoo)
            except ConfigError as err:
                self._warn_once(
                    f"manifest:{err}", f"zoo manifest unreadable, keeping the last good one: {err}"
                )
        entries = [e for e in self._manifest if self._wanted(e.algorithm)]
        if self.config.redis_zoo and self.plane is not None:
            names = {e.name for e in entries}
            for record in self.plane.list_partners():
                if record.name in names:
                    self._warn_once(
                        f"dup:{record.name}",
                        f"zoo partner {record.name!r} is in the manifest and in Redis; "
                        "using the manifest's entry",
                    )
                    continue
                if self._wanted(record.algorithm or None):
                    entries.append(entry_of_record(record))
        return entries

    def _wanted(self, algorithm: str | None) -> bool:
        """Whether an entry of this algorithm label plays (`zoo_algorithms`; an unlabelled entry is judged
        by its checkpoint's label once loaded)."""
        return not self.config.zoo_algorithms or algorithm is None or algorithm in self.config.zoo_algorithms

    def snapshot(self) -> ZooSnapshot:
        """Every entry loaded (from the cache when its checkpoint is unchanged) or skipped with the reason."""
        partners: list[Partner] = []
        skipped: list[SkippedPartner] = []
        for entry in self.entries():
            try:
                policy = self._load(entry)
            except (checkpoints.CheckpointError, ConfigError, OSError, ValueError) as err:
                reason = f"{type(err).__name__}: {err}"
                self._warn_once(
                    f"skip:{entry.name}:{reason}", f"zoo partner {entry.name!r} skipped: {reason}"
                )
                seed = -1 if entry.seed is None else entry.seed
                group = self.group_of(entry.name, entry.algorithm or UNKNOWN_GROUP)
                skipped.append(
                    SkippedPartner(SkippedEntry(entry.name, entry.algorithm or "", seed, reason), group)
                )
                continue
            if not self._wanted(policy.algorithm):
                continue
            clash = next(
                (
                    p.policy.name
                    for p in partners
                    if (p.policy.algorithm, p.policy.seed) == (policy.algorithm, policy.seed)
                    and _overlap(p.policy, policy)
                ),
                None,
            )
            group = self.group_of(entry.name, policy.algorithm)
            if clash is not None:  # the analyses identify a policy by (algorithm, seed) on each level
                reason = (
                    f"it is {policy.algorithm} seed {policy.seed} like zoo entry {clash!r} on a shared "
                    "level; give one of them another seed or algorithm label"
                )
                skipped.append(
                    SkippedPartner(SkippedEntry(entry.name, policy.algorithm, policy.seed, reason), group)
                )
                continue
            partners.append(Partner(policy, group))
        return ZooSnapshot(tuple(partners), tuple(skipped))

    def group_of(self, name: str, algorithm: str) -> str:
        """The partner group of zoo entry `name` (explicit groups first, then `group_by`)."""
        if name in self._explicit:
            return self._explicit[name]
        if self.config.group_by == "partner":
            return label(name)
        if self.config.group_by == "zoo":
            return "zoo"
        return label(algorithm)

    def _load(self, entry: ZooEntry) -> Policy:
        path = resolve_checkpoint(entry.checkpoint)
        sha = str(checkpoints.read_meta(path).get("sha256", ""))
        key = (entry, str(path), sha)
        if key not in self._cache:
            self._cache[key] = load_policy(dataclasses.replace(entry, checkpoint=str(path)))
        return self._cache[key]

    def _warn_once(self, key: str, message: str) -> None:
        if key not in self._warned:
            self._warned.add(key)
            log.warning(message)


def names_in(partners: Sequence[Partner], group: str) -> list[str]:
    """Names of the partners of one group."""
    return [p.policy.name for p in partners if p.group == group]
