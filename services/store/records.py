"""The records of the control plane: runs, checkpoint events (and what publishing or flushing them did),
delivered messages, zoo partners and evaluation results; `checkpoint_id` names a checkpoint."""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import asdict, dataclass, field, fields
from pathlib import Path
from typing import Any, NamedTuple

import yaml

RUN_STATUSES = ("starting", "running", "interrupted", "finished", "failed")


def _check_name(value: str, what: str) -> str:
    if not isinstance(value, str) or not value or len(value) > 200:
        raise ValueError(f"{what} must be a non-empty string of at most 200 characters, got {value!r}")
    if any(c.isspace() or not c.isprintable() or c == "|" for c in value):
        raise ValueError(f"{what} {value!r} must not contain spaces, control characters or '|'")
    return value


@dataclass(frozen=True)
class RunRecord:
    """A training run in the registry.

    Attributes:
        run_id: the run's name (its directory under `run_dir`).
        algorithm: `cec`, `ippo`, ...
        status: one of RUN_STATUSES.
        started_at: Unix time of the first registration (a resumed run keeps it).
        heartbeat_at: Unix time of the last heartbeat (or registration).
        config: the run's configuration as YAML or JSON text (`config_dict()` parses it).
    """

    run_id: str
    algorithm: str
    status: str
    started_at: float
    heartbeat_at: float
    config: str

    def config_dict(self) -> dict[str, Any]:
        data = yaml.safe_load(self.config) if self.config else {}
        return dict(data) if isinstance(data, Mapping) else {}


def checkpoint_id(run_id: str, update: int) -> str:
    """The id of a run's checkpoint after `update` updates: `<run_id>/update_<9 digits>`."""
    return f"{run_id}/update_{update:09d}"


@dataclass(frozen=True)
class CheckpointEvent:
    """A checkpoint was written (the fields of `meta.json` a consumer needs before opening it).

    Attributes:
        run_id: the run that wrote it.
        update: PPO updates done when it was saved.
        env_steps: joint environment steps per seed when it was saved.
        path: checkpoint directory (as the learner's machine sees it).
        sha256: checksum of `state.msgpack` (from `meta.json`).
        algorithm: the run's algorithm.
        seed: the run's base seed (seed i of a multi-seed checkpoint is `seed + i`).
        created_at: Unix time it was written.
    """

    run_id: str
    update: int
    env_steps: int
    path: str
    sha256: str
    algorithm: str
    seed: int
    created_at: float

    @property
    def checkpoint_id(self) -> str:
        return checkpoint_id(self.run_id, self.update)

    @classmethod
    def from_checkpoint(cls, path: str | Path, run_id: str) -> CheckpointEvent:
        """The event of a checkpoint directory written by `cec.checkpoints.save` (from its `meta.json`)."""
        from cec import checkpoints  # imports JAX; only the learner needs this

        meta = checkpoints.read_meta(path)
        info, config = meta.get("metadata", {}), meta.get("config", {})
        seeds = info.get("seeds") or [config.get("seed", 0)]
        return cls(
            run_id=run_id,
            update=int(meta["update"]),
            env_steps=int(meta["env_steps"]),
            path=str(path),
            sha256=str(meta["sha256"]),
            algorithm=str(info.get("algorithm", config.get("algorithm", ""))),
            seed=int(seeds[0]),
            created_at=(Path(path) / checkpoints.META_FILE).stat().st_mtime,
        )

    def to_fields(self) -> dict[str, str]:
        """The stream entry: every field as text, plus `checkpoint_id`."""
        out = {"checkpoint_id": self.checkpoint_id}
        out.update({k: repr(v) if isinstance(v, float) else str(v) for k, v in asdict(self).items()})
        return out

    @classmethod
    def from_fields(cls, data: Mapping[str, Any]) -> CheckpointEvent:
        """Parses a stream entry or outbox record; ValueError names what is missing or malformed."""
        kinds = {f.name: f.type for f in fields(cls)}
        missing = [k for k in kinds if k not in data]
        if missing:
            raise ValueError(f"checkpoint event lacks {', '.join(missing)}")
        try:
            event = cls(
                run_id=str(data["run_id"]),
                update=int(data["update"]),
                env_steps=int(data["env_steps"]),
                path=str(data["path"]),
                sha256=str(data["sha256"]),
                algorithm=str(data["algorithm"]),
                seed=int(data["seed"]),
                created_at=float(data["created_at"]),
            )
        except (TypeError, ValueError) as err:
            raise ValueError(f"malformed checkpoint event: {err}") from err
        if not math.isfinite(event.created_at) or event.update < 0 or event.env_steps < 0:
            raise ValueError(
                f"malformed checkpoint event: created_at {data['created_at']!r} must be a finite Unix time, "
                f"update {event.update} and env_steps {event.env_steps} must be >= 0"
            )
        if "checkpoint_id" in data and data["checkpoint_id"] != event.checkpoint_id:
            raise ValueError(f"checkpoint_id {data['checkpoint_id']!r} does not match run_id and update")
        return event


class PublishResult(NamedTuple):
    """What `publish_checkpoint` did.

    outcome: `published` (a new stream entry), `duplicate` (that checkpoint id was published before;
    `entry_id` is the first entry) or `queued` (Redis unreachable; the event waits in the outbox).
    """

    checkpoint_id: str
    outcome: str
    entry_id: str | None


class FlushResult(NamedTuple):
    """What `flush_outbox` did: events now in Redis (`published` or found `duplicate`), events left."""

    delivered: int
    remaining: int


@dataclass(frozen=True)
class CheckpointMessage:
    """A checkpoint event delivered to a consumer; acknowledge it with `CheckpointConsumer.ack`.

    Attributes:
        entry_id: the stream entry id.
        event: the checkpoint event.
        redelivered: it was delivered before (to this consumer before a restart, or to a dead one).
    """

    entry_id: str
    event: CheckpointEvent
    redelivered: bool = False


@dataclass(frozen=True)
class PartnerRecord:
    """One partner of the zoo.

    Attributes:
        name: unique label (`ippo_cramped_room_s0`, `fcp_s1`, ...).
        algorithm: how it was trained (`ippo`, `fcp`, `e3t`, `cec`, `cec_finetune`, ...).
        seed: its training seed.
        env: the environment and levels it was trained on (`overcooked:cramped_room`,
            `overcooked:procedural`, `dual_destination:fixed`, ...).
        env_steps: environment steps it was trained for.
        path: its checkpoint directory.
        sha256: checksum of the checkpoint's `state.msgpack`.
        added_at: Unix time it was added (set by `add_partner` when 0).
    """

    name: str
    algorithm: str
    seed: int
    env: str
    env_steps: int
    path: str
    sha256: str
    added_at: float = 0.0


@dataclass(frozen=True)
class EvalResult:
    """Scores of one checkpoint against one partner group on one level set.

    Attributes:
        checkpoint_id: the scored checkpoint.
        partner_group: which partners (`zoo`, `self`, `ippo`, a partner name, ...).
        level_set: which levels (`classic`, `heldout`, `cramped_room`, ...).
        metrics: JSON values by name (`return_mean`, `return_iqm`, `episodes`, ...).
        written_at: Unix time of the (last) write.
    """

    checkpoint_id: str
    partner_group: str
    level_set: str
    metrics: dict[str, Any] = field(default_factory=dict)
    written_at: float = 0.0
