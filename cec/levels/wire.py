"""The level server's wire format: `Level` batches and generator configs <-> `cec.levels.v1` messages.

A `LevelBatch` holds `count` levels as packed byte strings (81 tile bytes, 4 position bytes, 2 facing
bytes and 2 size bytes per level: 89 bytes a kitchen), so encoding and decoding are a few NumPy calls
whatever the batch size. Decoding checks lengths and value ranges of every level (a peer's bytes are
never trusted) and raises `WireError` naming the problem.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
from google.protobuf import message as _message
from google.protobuf import unknown_fields

from cec.config import ConfigError
from cec.levels.generator import GeneratorConfig
from cec.levels.level import GRID_SIZE, NUM_AGENTS, Level, LevelError, Tile, validate_level
from cec.levels.v1 import level_service_pb2 as pb

API_VERSION = "cec.levels.v1"
CELLS = GRID_SIZE * GRID_SIZE
BYTES_PER_LEVEL = CELLS + 2 * NUM_AGENTS + NUM_AGENTS + 2


class WireError(LevelError):
    """Bytes from a peer do not decode to valid levels (or a request carries fields this server lacks)."""


def encode(levels: Level, first_index: int = 0, names: Sequence[str] = ()) -> pb.LevelBatch:
    """A batched `Level` (leading axis N) or a single one -> `LevelBatch`."""
    grid = np.asarray(levels.grid)
    if grid.ndim == 2:
        grid = grid[None]
    n = grid.shape[0]
    as_bytes = [np.asarray(x).astype(np.uint8).reshape(n, -1) for x in (levels.agent_pos, levels.agent_dir,
                                                                          levels.size)]  # fmt: skip
    if names and len(names) != n:
        raise ValueError(f"{len(names)} names for {n} levels")
    return pb.LevelBatch(
        count=n,
        grid=grid.astype(np.uint8).tobytes(),
        agent_pos=as_bytes[0].tobytes(),
        agent_dir=as_bytes[1].tobytes(),
        size=as_bytes[2].tobytes(),
        first_index=first_index,
        names=list(names),
    )


def _field(batch: pb.LevelBatch, name: str, per_level: int) -> np.ndarray:
    raw = getattr(batch, name)
    if len(raw) != batch.count * per_level:
        raise WireError(
            f"LevelBatch.{name} has {len(raw)} bytes but count={batch.count} levels need "
            f"{batch.count * per_level} ({per_level} per level); encode levels with cec.levels.wire.encode"
        )
    return np.frombuffer(raw, dtype=np.uint8).reshape(batch.count, per_level)


def decode(batch: pb.LevelBatch, check: bool = True) -> Level:
    """`LevelBatch` -> batched `Level` of NumPy arrays (leading axis `count`; jit-ready).

    With `check`, every level is verified as `validate_level` would (vectorised), raising `WireError`.
    """
    grid = _field(batch, "grid", CELLS).reshape(batch.count, GRID_SIZE, GRID_SIZE)
    pos = _field(batch, "agent_pos", 2 * NUM_AGENTS).reshape(batch.count, NUM_AGENTS, 2).astype(np.int32)
    dirs = _field(batch, "agent_dir", NUM_AGENTS).astype(np.int32)
    size = _field(batch, "size", 2).astype(np.int32)
    levels = Level(grid=grid, agent_pos=pos, agent_dir=dirs, size=size)  # type: ignore[arg-type]
    if check and batch.count:
        bad = invalid_rows(levels)
        if bad.size:
            i = int(bad[0])
            one = Level(grid=grid[i], agent_pos=pos[i], agent_dir=dirs[i], size=size[i])
            try:
                validate_level(one)
                reason = "malformed"
            except LevelError as err:
                reason = str(err)
            raise WireError(f"{bad.size} of {batch.count} levels are malformed; level {i}: {reason}")
    return levels


def invalid_rows(levels: Level) -> np.ndarray:
    """Indices of the levels of a batch that fail the structural checks of `validate_level` (vectorised)."""
    grid, pos, dirs, size = (np.asarray(x) for x in (levels.grid, levels.agent_pos, levels.agent_dir,
                                                     levels.size))  # fmt: skip
    n = grid.shape[0]
    rows = np.arange(GRID_SIZE)
    h, w = size[:, 0], size[:, 1]
    ok = (h >= 1) & (h <= GRID_SIZE) & (w >= 1) & (w <= GRID_SIZE)
    ok &= np.all(grid <= max(Tile), axis=(1, 2))
    inside = (rows[None, :, None] < h[:, None, None]) & (rows[None, None, :] < w[:, None, None])
    ok &= np.all(inside | (grid == Tile.COUNTER), axis=(1, 2))
    for tile in (Tile.ONION_PILE, Tile.PLATE_PILE, Tile.POT, Tile.GOAL):
        ok &= np.any(grid == tile, axis=(1, 2))
    r, c = pos[..., 0], pos[..., 1]
    in_kitchen = (r < h[:, None]) & (c < w[:, None])
    on = grid[np.arange(n)[:, None], np.minimum(r, GRID_SIZE - 1), np.minimum(c, GRID_SIZE - 1)]
    ok &= np.all(in_kitchen & (on == Tile.FLOOR), axis=1)
    ok &= np.any(pos[:, 0] != pos[:, 1], axis=1)
    ok &= np.all(dirs <= 3, axis=1)
    return np.flatnonzero(~ok)


def reject_unknown_fields(msg: _message.Message, path: str = "") -> None:
    """Raises `WireError` if `msg` (or a nested message) carries fields this API version does not define."""
    name = path or msg.DESCRIPTOR.name
    fields = unknown_fields.UnknownFieldSet(msg)
    unknown = [fields[i].field_number for i in range(len(fields))]
    if unknown:
        raise WireError(
            f"{name} carries fields {unknown} that {API_VERSION} does not define; the client speaks a newer "
            "or different API: update the server or drop those fields"
        )
    for field, value in msg.ListFields():
        if field.message_type is None:
            continue
        items = value if field.is_repeated else [value]
        for item in items:
            reject_unknown_fields(item, f"{name}.{field.name}")


_BOUND_FIELDS = ("onion_piles", "plate_piles", "pots", "goals")


def config_to_proto(config: GeneratorConfig) -> pb.GeneratorConfig:
    """The whole config as a request's `GeneratorConfig` (every field set, so the server's defaults never
    stand in for a setting the client made). Raises `ConfigError` for a setting no level server honours."""
    if not config.exclude_heldout:
        raise ConfigError(
            "exclude_heldout=false cannot be honoured by a level server: it never streams the validation or "
            "test kitchens; draw such kitchens locally (cec.levels.generator) instead"
        )
    msg = pb.GeneratorConfig(
        structures=list(config.structures),
        count_decay=config.count_decay,
        allow_decoys=config.allow_decoys,
        handover_share=config.handover_share,
        structure_weights=list(config.structure_weights),
    )
    for name in _BOUND_FIELDS:
        lo, hi = getattr(config, name)
        getattr(msg, name).CopyFrom(pb.Bounds(min=lo, max=hi))
    return msg


def config_from_proto(msg: pb.GeneratorConfig, defaults: GeneratorConfig) -> GeneratorConfig:
    """Fields set in `msg` override `defaults`; raises `ConfigError` (naming the field) for bad values.

    The held-out exclusion is not a wire option: a server never streams the evaluation set. Weights given
    without structures apply to the defaults' structures (and must match their number).
    """
    changes: dict[str, object] = {}
    if msg.structures:
        changes["structures"] = tuple(msg.structures)
    for name in _BOUND_FIELDS:
        if msg.HasField(name):
            b = getattr(msg, name)
            if not (0 <= b.min <= 64 and 0 <= b.max <= 64):
                raise ConfigError(f"config.{name} = ({b.min}, {b.max}) is out of range; use 1 <= min <= max")
            changes[name] = (int(b.min), int(b.max))
    if msg.HasField("count_decay"):
        changes["count_decay"] = float(msg.count_decay)
    if msg.HasField("allow_decoys"):
        changes["allow_decoys"] = bool(msg.allow_decoys)
    if msg.HasField("handover_share"):
        changes["handover_share"] = float(msg.handover_share)
    if msg.structure_weights or "structures" in changes:  # new structures never keep the old weights
        changes["structure_weights"] = tuple(float(w) for w in msg.structure_weights)
    return defaults.replace(**changes) if changes else defaults
