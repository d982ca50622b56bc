"""Base wall structures of the generator and the dihedral transforms, precomputed once on the host.

A structure is a classic kitchen stripped of its objects and agents: its floor and counters. From the
floor we derive everything the generator and the layout count need:

* regions: connected floor components (1 for most kitchens, 2 for Asymmetric Advantages and Forced
  Coordination, whose halves only meet across counters);
* reachable counters: counters next to floor (objects there can be used); decoy counters: the others;
* access[i]: counters next to region i; shared counters: next to both regions (hand-over points).

Transforms are the 8 symmetries of the square (4 rotations, each optionally mirrored), applied to the
kitchen before it is placed in the top-left corner of the 9x9 frame. Everything is stored in the canonical
9x9 frame, flattened to 81 cells, and stacked over structures so that JAX code can index it by a traced
structure id.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cache

import numpy as np

from cec.levels.classic import CLASSIC_NAMES, classic_level
from cec.levels.level import GRID_SIZE, Tile

CELLS = GRID_SIZE * GRID_SIZE
NUM_TRANSFORMS = 8
#: Transform names, by index: k quarter turns counter-clockwise, then a left-right mirror if "m".
TRANSFORM_NAMES = ("r0", "r90", "r180", "r270", "m.r0", "m.r90", "m.r180", "m.r270")


def transform(array: np.ndarray, t: int) -> np.ndarray:
    """Applies dihedral transform `t` (0..7) to a 2-D array: `t % 4` quarter turns, mirrored if t >= 4."""
    out = np.rot90(array, t % 4)
    return np.fliplr(out) if t >= 4 else out


def adjacent(mask: np.ndarray) -> np.ndarray:
    """Cells with a `mask` cell among their four neighbours."""
    p = np.pad(mask, 1)
    return p[:-2, 1:-1] | p[2:, 1:-1] | p[1:-1, :-2] | p[1:-1, 2:]


def floor_regions(floor: np.ndarray) -> np.ndarray:
    """int[h, w]: 0 on counters, 1..n for the connected floor components (4-neighbourhood)."""
    labels = np.zeros(floor.shape, np.int32)
    n = 0
    for start in zip(*np.nonzero(floor), strict=True):
        if labels[start]:
            continue
        n += 1
        stack = [start]
        labels[start] = n
        while stack:
            r, c = stack.pop()
            for dr, dc in ((-1, 0), (1, 0), (0, 1), (0, -1)):
                rr, cc = r + dr, c + dc
                inside = 0 <= rr < floor.shape[0] and 0 <= cc < floor.shape[1]
                if inside and floor[rr, cc] and not labels[rr, cc]:
                    labels[rr, cc] = n
                    stack.append((rr, cc))
    return labels


@dataclass(frozen=True)
class Structure:
    """One base wall structure, in its own (h, w) kitchen frame."""

    name: str
    floor: np.ndarray  # bool[h, w]
    regions: np.ndarray  # int[h, w], 0 = counter, 1..n = floor component
    n_regions: int

    @property
    def shape(self) -> tuple[int, int]:
        return (int(self.floor.shape[0]), int(self.floor.shape[1]))

    @property
    def counters(self) -> np.ndarray:
        return ~self.floor

    @property
    def reachable(self) -> np.ndarray:
        """Counters next to floor."""
        return self.counters & adjacent(self.floor)

    @property
    def decoy(self) -> np.ndarray:
        """Counters next to no floor: objects there can never be used."""
        return self.counters & ~adjacent(self.floor)

    def access(self, region: int) -> np.ndarray:
        """Counters next to floor region `region` (1-based)."""
        return self.counters & adjacent(self.regions == region)

    @property
    def shared(self) -> np.ndarray:
        """Counters next to two different regions (empty for one-region kitchens)."""
        if self.n_regions < 2:
            return np.zeros_like(self.floor)
        return self.access(1) & self.access(2)


def structure_from_kitchen(name: str, kitchen: np.ndarray) -> Structure:
    """Strips a kitchen's objects (they become counters); agents' cells are floor already."""
    floor = np.asarray(kitchen) == Tile.FLOOR
    regions = floor_regions(floor)
    n = int(regions.max())
    if n not in (1, 2):
        raise ValueError(f"structure {name!r} has {n} floor regions; the generator supports 1 or 2")
    return Structure(name=name, floor=floor, regions=regions, n_regions=n)


@cache
def base_structures() -> tuple[Structure, ...]:
    """The five classic kitchens' wall structures, in the paper's order."""
    return tuple(structure_from_kitchen(n, classic_level(n).kitchen()) for n in CLASSIC_NAMES)


@dataclass(frozen=True)
class StructureTables:
    """Stacked per-structure arrays in the canonical 9x9 frame (flattened), for JAX code.

    Shapes: S structures, T = 8 transforms, 81 cells.
    """

    names: tuple[str, ...]
    floor: np.ndarray  # bool[S, 81]
    reachable: np.ndarray  # bool[S, 81]
    decoy: np.ndarray  # bool[S, 81]
    access: np.ndarray  # bool[S, 2, 81]; for one-region kitchens both rows equal `reachable`
    shared: np.ndarray  # bool[S, 81]
    region_floor: np.ndarray  # bool[S, 2, 81]; for one-region kitchens both rows are all floor
    divided: np.ndarray  # bool[S]
    src: np.ndarray  # int32[S, T, 81]: output cell -> canonical cell, -1 = frame padding
    dst: np.ndarray  # int32[S, T, 81]: canonical cell -> output cell, -1 = outside the kitchen
    size: np.ndarray  # int32[S, T, 2]: (height, width) of the transformed kitchen


def _frame(a: np.ndarray) -> np.ndarray:
    out = np.zeros((GRID_SIZE, GRID_SIZE), dtype=a.dtype)
    out[: a.shape[0], : a.shape[1]] = a
    return out.reshape(-1)


def build_tables(structures: tuple[Structure, ...]) -> StructureTables:
    s_count = len(structures)
    src = np.full((s_count, NUM_TRANSFORMS, CELLS), -1, np.int32)
    dst = np.full((s_count, NUM_TRANSFORMS, CELLS), -1, np.int32)
    size = np.zeros((s_count, NUM_TRANSFORMS, 2), np.int32)
    for s, st in enumerate(structures):
        h, w = st.shape
        canon = (np.arange(h)[:, None] * GRID_SIZE + np.arange(w)[None, :]).astype(np.int32)
        for t in range(NUM_TRANSFORMS):
            moved = transform(canon, t)
            oh, ow = moved.shape
            size[s, t] = (oh, ow)
            out_cells = (np.arange(oh)[:, None] * GRID_SIZE + np.arange(ow)[None, :]).reshape(-1)
            src[s, t, out_cells] = moved.reshape(-1)
            dst[s, t, moved.reshape(-1)] = out_cells

    def both(st: Structure, one: np.ndarray, per_region: list[np.ndarray]) -> np.ndarray:
        rows = per_region if st.n_regions == 2 else [one, one]
        return np.stack([_frame(r) for r in rows])

    return StructureTables(
        names=tuple(st.name for st in structures),
        floor=np.stack([_frame(st.floor) for st in structures]),
        reachable=np.stack([_frame(st.reachable) for st in structures]),
        decoy=np.stack([_frame(st.decoy) for st in structures]),
        access=np.stack(
            [
                both(st, st.reachable, [st.access(1), st.access(2)] if st.n_regions == 2 else [])
                for st in structures
            ]
        ),
        shared=np.stack([_frame(st.shared) for st in structures]),
        region_floor=np.stack(
            [
                both(st, st.floor, [st.regions == 1, st.regions == 2] if st.n_regions == 2 else [])
                for st in structures
            ]
        ),
        divided=np.array([st.n_regions == 2 for st in structures]),
        src=src,
        dst=dst,
        size=size,
    )


def symmetry_count(st: Structure) -> int:
    """Number of the 8 transforms that map the structure's floor onto itself (its symmetry group order)."""
    return sum(
        1
        for t in range(NUM_TRANSFORMS)
        if transform(st.floor, t).shape == st.floor.shape and np.array_equal(transform(st.floor, t), st.floor)
    )
