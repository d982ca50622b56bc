"""Recorded human-human Overcooked games in this project's terms, and their safe on-disk format.

The games are Carroll et al.'s (2019) human-human trials of the five classic kitchens, as the
`overcooked-ai` package ships them (`apps/humans.py` reads them once, `cec humans import`). Each recorded
step becomes one row of `Steps`: the state before the step in `EnvState` terms, both seats' actions in our
action encoding, the recorded next state, and the recorded reward. Nothing of a person is kept beyond what
the data has: the trial's worker id (`participant`).

On disk (`cec humans import --out DIR`, default `data/humans`):

    DIR/train.npz, DIR/test.npz   the splits' arrays (`np.savez_compressed`, no pickled objects)
    DIR/meta.json                 {"format", "source", "splits": {split: {"sha256", "counts"}}}

`load_steps` checks the format, each file's SHA-256 and every array's shape, dtype and value range (NaN
and infinity included), in bounded memory (the arrays' declared sizes are checked before any is inflated),
and refuses a mismatch with a `HumanDataError` naming the file and the fix; nothing is unpickled.

Mapping (the data's layouts are ours, in the frame's top-left corner; `docs/humans.md`):
- positions `[x, y]` are our `(row, col) = (y, x)`; orientations `[dx, dy]` our facings;
- held `onion`/`dish`/`soup` are `Item.ONION`/`PLATE`/`DISH` (a soup outside a pot is always plated);
- a pot's soup `[onion, n, t]` is pot status `23 - n` while `n < 3`, else `max(20 - t, 0)` (the data's
  cook counter counts up from 1 on the step the third onion goes in; ours counts down from 19);
- actions `[dx, dy]` are the moves, `[0, 0]` stay, `"INTERACT"` interact;
- the data's kitchen names `random0`/`random3` are Forced Coordination/Counter Circuit.
"""

from __future__ import annotations

import hashlib
import json
import zipfile
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, fields
from functools import cache
from pathlib import Path
from typing import Any, BinaryIO

import numpy as np

from cec.config import ConfigError, open_user_file, read_user_json
from cec.envs.overcooked.state import MAX_ONIONS, POT_EMPTY, POT_FULL, POT_READY, Action
from cec.levels import GRID_SIZE, Direction, Item, Tile
from cec.levels.classic import classic_level

FORMAT = "cec-humans/1"
SPLITS = ("train", "test")
META_FILE = "meta.json"
#: Our classic kitchens, in the order of `Steps.kitchen` codes.
KITCHENS = ("cramped_room", "asymm_advantages", "coord_ring", "forced_coord", "counter_circuit")
#: The data's layout names -> ours.
DATA_KITCHENS = {
    "cramped_room": "cramped_room",
    "asymmetric_advantages": "asymm_advantages",
    "coordination_ring": "coord_ring",
    "random0": "forced_coord",
    "random3": "counter_circuit",
}
_FACING = {(0, -1): Direction.NORTH, (0, 1): Direction.SOUTH, (1, 0): Direction.EAST, (-1, 0): Direction.WEST}
_MOVES = {(0, -1): Action.UP, (0, 1): Action.DOWN, (1, 0): Action.RIGHT, (-1, 0): Action.LEFT}
_ITEMS = {"onion": Item.ONION, "dish": Item.PLATE, "soup": Item.DISH}
_STATE_FIELDS = ("agent_pos", "agent_dir", "agent_inv", "items", "pot")


class HumanDataError(ValueError):
    """Recorded games that cannot be read or converted; the message names the cause and the fix."""


@dataclass(frozen=True)
class Steps:
    """Recorded steps (one row each) of one split.

    Attributes:
        kitchen: uint8[N] index into `KITCHENS`.
        trial: int32[N] the game the step belongs to (0.. within the split, in recording order).
        participant: int32[N] the data's worker id of the game.
        time: int32[N] the step's index in its game (the data's game loop counter).
        agent_pos, agent_dir, agent_inv, items, pot: the state before the step (`EnvState` fields).
        actions: int8[N, 2] each seat's `Action`.
        next_agent_pos, next_agent_dir, next_agent_inv, next_items, next_pot: the recorded next state.
        reward: float32[N] the recorded team reward of the step (the data pays 5 per delivered soup).
    """

    kitchen: np.ndarray
    trial: np.ndarray
    participant: np.ndarray
    time: np.ndarray
    agent_pos: np.ndarray
    agent_dir: np.ndarray
    agent_inv: np.ndarray
    items: np.ndarray
    pot: np.ndarray
    actions: np.ndarray
    next_agent_pos: np.ndarray
    next_agent_dir: np.ndarray
    next_agent_inv: np.ndarray
    next_items: np.ndarray
    next_pot: np.ndarray
    reward: np.ndarray

    def __len__(self) -> int:
        return int(self.kitchen.shape[0])

    def select(self, mask: np.ndarray | slice) -> Steps:
        """The rows where `mask` (bool[N]) is true, those at the given indices, or a slice of them."""
        return Steps(**{f.name: getattr(self, f.name)[mask] for f in fields(self)})

    def state_fields(self) -> tuple[np.ndarray, ...]:
        """The state before each step as `EnvState(level, *fields)` takes it: agent_pos, agent_dir,
        agent_inv (int32), items, pot, time, episode (0)."""
        ints = (self.agent_pos, self.agent_dir, self.agent_inv)
        return (
            *(a.astype(np.int32) for a in ints),
            self.items,
            self.pot,
            self.time,
            np.zeros(len(self), np.int32),
        )

    def counts(self) -> dict[str, dict[str, int]]:
        """Per kitchen: steps, games and deliveries."""
        out = {}
        for k, name in enumerate(KITCHENS):
            here = self.kitchen == k
            out[name] = {
                "steps": int(here.sum()),
                "games": len(np.unique(self.trial[here])),
                "deliveries": int((self.reward[here] > 0).sum()),
            }
        return out


#: dtype, trailing shape and value range (inclusive) of every array of `Steps`.
_SPEC: dict[str, tuple[Any, tuple[int, ...], int, int]] = {
    "kitchen": (np.uint8, (), 0, len(KITCHENS) - 1),
    "trial": (np.int32, (), 0, 2**31 - 1),
    "participant": (np.int32, (), 0, 2**31 - 1),
    "time": (np.int32, (), 0, 2**31 - 1),
    "agent_pos": (np.int8, (2, 2), 0, GRID_SIZE - 1),
    "agent_dir": (np.int8, (2,), 0, len(Direction) - 1),
    "agent_inv": (np.int8, (2,), 0, len(Item) - 1),
    "items": (np.uint8, (GRID_SIZE, GRID_SIZE), 0, len(Item) - 1),
    "pot": (np.uint8, (GRID_SIZE, GRID_SIZE), 0, POT_EMPTY),
    "actions": (np.int8, (2,), 0, len(Action) - 1),
    "reward": (np.float32, (), 0, 1000),
}
_SPEC.update({f"next_{name}": _SPEC[name] for name in _STATE_FIELDS})


# ---------------------------------------------------------------------------------------------------------
# CONVERSION (one recorded step at a time, from the data's plain-data state)
# ---------------------------------------------------------------------------------------------------------


def convert_state(state: Mapping[str, Any], kitchen: str) -> dict[str, np.ndarray]:
    """One recorded state (the data's dict: players, objects) as `EnvState` arrays on our `kitchen`."""
    grid = _grid(kitchen)
    players = state.get("players")
    if not isinstance(players, Sequence) or len(players) != 2:
        raise HumanDataError(f"a state has {players!r} as players; two are expected")
    pos = np.zeros((2, 2), np.int8)
    facing = np.zeros((2,), np.int8)
    inv = np.zeros((2,), np.int8)
    for seat, player in enumerate(players):
        x, y = player["position"]
        if grid[y, x] != Tile.FLOOR:
            raise HumanDataError(f"seat {seat} stands on ({x}, {y}), not floor, in {kitchen}")
        pos[seat] = (y, x)
        facing[seat] = _lookup(_FACING, tuple(player["orientation"]), "orientation")
        held = player.get("held_object")
        inv[seat] = Item.NONE if held is None else _lookup(_ITEMS, held["name"], "held object")
    items = np.zeros((GRID_SIZE, GRID_SIZE), np.uint8)
    pot = np.where(grid == Tile.POT, POT_EMPTY, 0).astype(np.uint8)
    objects = state.get("objects", {})
    for obj in objects.values() if isinstance(objects, Mapping) else objects:
        x, y = obj["position"]
        if grid[y, x] == Tile.POT:
            pot[y, x] = _pot_status(obj)
        elif grid[y, x] == Tile.COUNTER:
            items[y, x] = _lookup(_ITEMS, obj["name"], "object")
        else:
            raise HumanDataError(
                f"a {obj['name']} lies on ({x}, {y}), tile {Tile(grid[y, x]).name}, in {kitchen}"
            )
    return {"agent_pos": pos, "agent_dir": facing, "agent_inv": inv, "items": items, "pot": pot}


@cache
def _grid(kitchen: str) -> np.ndarray:
    return np.asarray(classic_level(kitchen).grid)


def _pot_status(obj: Mapping[str, Any]) -> int:
    if obj["name"] != "soup":
        raise HumanDataError(f"a {obj['name']} lies in a pot; only soups are expected there")
    ingredient, onions, cooked = obj["state"]
    if ingredient != "onion" or not 1 <= onions <= MAX_ONIONS:
        raise HumanDataError(f"a pot holds {obj['state']!r}; only 1-3 onions are expected")
    if onions < MAX_ONIONS:
        return POT_EMPTY - onions
    return max(POT_FULL - int(cooked), POT_READY)


def convert_action(action: Any) -> int:
    """One seat's recorded action (`[dx, dy]` or `"INTERACT"`) as our `Action`."""
    if action == "INTERACT":
        return Action.INTERACT
    if isinstance(action, Sequence) and tuple(action) == (0, 0):
        return Action.STAY
    return _lookup(_MOVES, tuple(action) if isinstance(action, Sequence) else action, "action")


def _lookup(table: Mapping[Any, int], key: Any, what: str) -> int:
    if key not in table:
        raise HumanDataError(f"unknown {what} {key!r} in the recorded games; expected one of {list(table)}")
    return int(table[key])


def stack_steps(rows: Sequence[Mapping[str, Any]]) -> Steps:
    """`Steps` from per-step dicts (the `_SPEC` keys, next-state keys included)."""
    if not rows:
        raise HumanDataError("no recorded steps to stack")
    return Steps(
        **{name: np.asarray([r[name] for r in rows], dtype) for name, (dtype, *_rest) in _SPEC.items()}
    )


# ---------------------------------------------------------------------------------------------------------
# SAFE FORMAT
# ---------------------------------------------------------------------------------------------------------


def save_steps(splits: Mapping[str, Steps], out: str | Path, *, source: Mapping[str, Any]) -> Path:
    """Writes each split's arrays and `meta.json` (format, source, SHA-256 and counts per split)."""
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    meta: dict[str, Any] = {"format": FORMAT, "source": dict(source), "splits": {}}
    for split, steps in splits.items():
        _check(steps, split)
        path = out / f"{split}.npz"
        tmp = path.with_suffix(".tmp.npz")
        np.savez_compressed(tmp, **{f.name: getattr(steps, f.name) for f in fields(steps)})
        tmp.replace(path)
        meta["splits"][split] = {"sha256": _sha256(path), "counts": steps.counts()}
    (out / META_FILE).write_text(json.dumps(meta, indent=1) + "\n")
    return out / META_FILE


def load_steps(folder: str | Path, split: str) -> Steps:
    """One split of an imported folder, verified (format, SHA-256, shapes, dtypes, value ranges) in bounded
    memory: `meta.json` of at most `META_MAX_BYTES`, the split's file of at most `SPLIT_MAX_BYTES`, a zip
    whose arrays' declared sizes (read before any is inflated) add up to at most `SPLIT_MAX_BYTES`."""
    folder = Path(folder)
    meta_path = folder / META_FILE
    fix = "run `cec humans import` (it writes them)"
    if not meta_path.exists():
        raise HumanDataError(f"{meta_path} does not exist; {fix}")
    try:
        meta = read_user_json(meta_path, "human data file", META_MAX_BYTES, _setting("META_MAX_BYTES"))
    except ConfigError as err:
        raise HumanDataError(f"{err}; {fix} again") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise HumanDataError(f"{meta_path} is not of format {FORMAT}; {fix} again with this version")
    splits = meta.get("splits")
    if not isinstance(splits, dict) or not all(isinstance(v, dict) for v in splits.values()):
        raise HumanDataError(
            f"{meta_path}: `splits` is not a mapping of split -> {{sha256, counts}}; {fix} again"
        )
    if split not in splits:
        raise HumanDataError(f"{folder} has no split {split!r} (it has {sorted(map(str, splits))})")
    pinned = splits[split].get("sha256")
    if not isinstance(pinned, str) or len(pinned) != 64:
        raise HumanDataError(
            f"{meta_path}: splits.{split}.sha256 is not a SHA-256 (64 hex digits); {fix} again"
        )
    path = folder / f"{split}.npz"
    try:
        with open_user_file(path, "human data file", error=HumanDataError) as f:
            digest, size = _sha256_bounded(f, path)
    except HumanDataError as err:
        raise HumanDataError(f"{err}; {fix} again") from None
    if digest != pinned:
        raise HumanDataError(
            f"{path} is missing or not the file {meta_path} describes (SHA-256); {fix} again"
        )
    _check_members(path, size, fix)
    try:
        with np.load(path, allow_pickle=False) as data:
            steps = Steps(**{name: data[name] for name in _SPEC})
    except (ValueError, OSError, zipfile.BadZipFile, EOFError) as err:
        raise HumanDataError(f"{path} cannot be read as arrays ({str(err)[:200]}); {fix} again") from None
    _check(steps, str(path))
    return steps


#: The largest `meta.json` read (it is a few kB).
META_MAX_BYTES = 1 << 20
#: The largest split file read, and the most its arrays may take once inflated (the published train split
#: is ~17 MB of arrays); checked on the zip's declared sizes and the arrays' headers before anything is
#: inflated, so a small file that would inflate to gigabytes is refused without reading it.
SPLIT_MAX_BYTES = 256 << 20


def _setting(name: str) -> str:
    return f"{__name__}.{name}"


def _sha256_bounded(f: BinaryIO, path: Path) -> tuple[str, int]:
    """The SHA-256 and size of an open file, read in chunks; `HumanDataError` past `SPLIT_MAX_BYTES`."""
    digest, size = hashlib.sha256(), 0
    while chunk := f.read(1 << 20):
        size += len(chunk)
        if size > SPLIT_MAX_BYTES:
            raise HumanDataError(
                f"human data file {str(path)!r} is larger than {SPLIT_MAX_BYTES:,} bytes, the most read "
                f"({_setting('SPLIT_MAX_BYTES')})"
            )
        digest.update(chunk)
    return digest.hexdigest(), size


def _check_members(path: Path, size: int, fix: str) -> None:
    """`HumanDataError` unless `path` is a zip of exactly the `_SPEC` arrays (`NAME.npy`, stored or
    deflated), each declaring in its header the dtype and trailing shape `_SPEC` gives, one row count, and
    together at most `SPLIT_MAX_BYTES` inflated: all read from the zip's directory and the arrays' headers,
    before any array is inflated."""
    if not zipfile.is_zipfile(path):
        raise HumanDataError(f"{path} is not a .npz archive (a zip of .npy arrays); {fix} again")
    declared, rows = 0, set()
    try:
        with zipfile.ZipFile(path) as archive:
            infos = {i.filename: i for i in archive.infolist()}
            want = {f"{name}.npy" for name in _SPEC}
            if set(infos) != want:
                extra, lacking = sorted(set(infos) - want)[:5], sorted(want - set(infos))[:5]
                raise HumanDataError(
                    f"{path} holds other arrays than a split has (unexpected {extra}, lacking {lacking}); "
                    f"{fix} again"
                )
            for name, (dtype, shape, _lo, _hi) in _SPEC.items():
                info = infos[f"{name}.npy"]
                declared += info.file_size
                if declared > SPLIT_MAX_BYTES:
                    raise HumanDataError(
                        f"{path}: its arrays would take more than {SPLIT_MAX_BYTES:,} bytes inflated, the "
                        f"most read ({_setting('SPLIT_MAX_BYTES')}; the file is {size:,} bytes); {fix} again"
                    )
                with archive.open(info) as member:
                    version = np.lib.format.read_magic(member)
                    header = (
                        np.lib.format.read_array_header_1_0(member)
                        if version == (1, 0)
                        else np.lib.format.read_array_header_2_0(member)
                    )
                got_shape, _fortran, got_dtype = header
                if got_dtype != np.dtype(dtype) or tuple(got_shape[1:]) != shape or len(got_shape) < 1:
                    raise HumanDataError(
                        f"{path}: array {name} is {got_dtype}{list(got_shape)}, expected "
                        f"{np.dtype(dtype)}[N, {', '.join(map(str, shape))}]; {fix} again"
                    )
                if int(np.prod(got_shape)) * got_dtype.itemsize > info.file_size:
                    raise HumanDataError(
                        f"{path}: array {name} declares {list(got_shape)} but its member is only "
                        f"{info.file_size:,} bytes; {fix} again"
                    )
                rows.add(int(got_shape[0]))
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
        raise HumanDataError(
            f"{path} is not a readable .npz archive ({str(err)[:200]}); {fix} again"
        ) from None
    if len(rows) != 1:
        raise HumanDataError(f"{path}: its arrays have different row counts {sorted(rows)}; {fix} again")


def _check(steps: Steps, where: str) -> None:
    n = len(steps)
    for name, (dtype, shape, lo, hi) in _SPEC.items():
        a = getattr(steps, name)
        if a.dtype != dtype or a.shape != (n, *shape):
            raise HumanDataError(
                f"{where}: array {name} is {a.dtype}{list(a.shape)}, expected {np.dtype(dtype)}{[n, *shape]}"
            )
        if np.issubdtype(a.dtype, np.floating) and not np.isfinite(a).all():
            bad = int(a.size - np.isfinite(a).sum())
            raise HumanDataError(f"{where}: array {name} has {bad} NaN or infinite value(s)")
        if n and (a.min() < lo or a.max() > hi):
            raise HumanDataError(f"{where}: array {name} has values outside [{lo}, {hi}]")


def _sha256(path: Path) -> str:
    with open_user_file(path, "human data file", error=HumanDataError) as f:
        return _sha256_bounded(f, path)[0]
