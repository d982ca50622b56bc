"""The exact number of distinct kitchens the generator can emit, by combinatorics (no sampling).

A kitchen is identified by its 9x9 tiles and its two start cells in seat order. For one base structure S
(see `structures.py`), the levels before the transform are

    X_S = {object placements} x {agent placements}

* agent placements: ordered pairs of distinct floor cells (one in each region for a split kitchen, either
  seat on either side): F(F-1), or 2 F1 F2;
* object placements: every assignment of onion piles, plate piles, pots and goals to counters with each
  kind's count within its bounds, objects only on reachable counters (or, with decoys, anywhere inside the
  kitchen provided each kind has a reachable instance), and, for a split kitchen, solvable. Solvability of a
  split kitchen depends only on which classes of counter (left-only, right-only, shared, unreachable) hold
  each kind and on whether a shared counter stays bare, so we count by class: a dynamic program over the
  four kinds whose state is the cells used per class and the presence flags, each step choosing
  binomial(free cells of the class, count) cells.

A transform T and T' give the same levels exactly when T^-1 T' maps the floor onto itself, so S contributes
(8 / |G_S|) |X_S| distinct levels, G_S being its floor's symmetry group; no two structures share a floor in
any orientation (checked), so the total is the sum over structures. `count_layouts` also reports how many
held-out kitchens lie in the space (the generator never emits those).
"""

from __future__ import annotations

import itertools
from collections import defaultdict
from dataclasses import dataclass
from math import comb

import numpy as np

from cec.levels.generator import GeneratorConfig
from cec.levels.structures import NUM_TRANSFORMS, Structure, base_structures, symmetry_count, transform

ONION, PLATE, POT, GOAL = range(4)


@dataclass(frozen=True)
class StructureCount:
    name: str
    object_placements: int
    agent_placements: int
    orientations: int

    @property
    def levels(self) -> int:
        return self.object_placements * self.agent_placements * self.orientations


@dataclass(frozen=True)
class LayoutCount:
    per_structure: tuple[StructureCount, ...]
    heldout_in_space: int

    @property
    def total(self) -> int:
        """Distinct solvable kitchens in the generator's space."""
        return sum(s.levels for s in self.per_structure)

    @property
    def emittable(self) -> int:
        """Distinct kitchens the generator can actually emit (the space minus the held-out set)."""
        return self.total - self.heldout_in_space


def _solvable_split(present: dict[tuple[int, str], bool], handover: bool) -> bool:
    """Solvability of a split kitchen from which counter classes hold each kind (L, R, S = shared)."""

    def on(side: str, kind: int) -> bool:
        return present[(kind, side)] or present[(kind, "S")]

    if handover:  # every kind is present somewhere reachable (counts >= 1, one reachable instance)
        return True
    for pot_class in ("L", "R", "S"):
        if not present[(POT, pot_class)]:
            continue
        sides = ("L", "R") if pot_class == "S" else (pot_class,)
        fill = any(on(x, ONION) for x in sides)
        serve = any(on(y, PLATE) and on(y, GOAL) for y in sides)
        if fill and serve:
            return True
    return False


def count_object_placements(st: Structure, config: GeneratorConfig) -> int:
    """Object placements of one structure (see module docstring)."""
    if st.n_regions == 2:
        only_l = st.access(1) & ~st.access(2)
        only_r = st.access(2) & ~st.access(1)
        sizes = {"L": int(only_l.sum()), "R": int(only_r.sum()), "S": int(st.shared.sum())}
    else:
        sizes = {"A": int(st.reachable.sum())}
    if config.allow_decoys:
        sizes["U"] = int(st.decoy.sum())
    classes = list(sizes)
    reachable_classes = [c for c in classes if c != "U"]

    # state: (cells used per class, frozenset of (kind, class) present) -> number of placements
    states: dict[tuple[tuple[int, ...], frozenset[tuple[int, str]]], int] = {
        (tuple(0 for _ in classes), frozenset()): 1
    }
    for kind, (lo, hi) in enumerate(config.bounds):
        nxt: dict[tuple[tuple[int, ...], frozenset[tuple[int, str]]], int] = defaultdict(int)
        for (used, present), ways in states.items():
            for split in itertools.product(*(range(0, hi + 1) for _ in classes)):
                n = sum(split)
                if not lo <= n <= hi:
                    continue
                if sum(split[classes.index(c)] for c in reachable_classes) == 0:
                    continue  # every kind needs an instance an agent can reach
                w = ways
                for i, c in enumerate(classes):
                    w *= comb(sizes[c] - used[i], split[i])
                if w == 0:
                    continue
                new_used = tuple(u + k for u, k in zip(used, split, strict=True))
                new_present = present | {(kind, c) for i, c in enumerate(classes) if split[i] > 0}
                nxt[(new_used, frozenset(new_present))] += w
        states = dict(nxt)

    total = 0
    for (used, present), ways in states.items():
        if st.n_regions == 2:
            flags = {(k, c): (k, c) in present for k in range(4) for c in ("L", "R", "S")}
            if not _solvable_split(flags, handover=used[classes.index("S")] < sizes["S"]):
                continue
        total += ways
    return total


def count_agent_placements(st: Structure) -> int:
    if st.n_regions == 2:
        return 2 * int((st.regions == 1).sum()) * int((st.regions == 2).sum())
    f = int(st.floor.sum())
    return f * (f - 1)


def _check_floors_distinct(structures: tuple[Structure, ...]) -> None:
    seen: dict[bytes, str] = {}
    for st in structures:
        for t in range(NUM_TRANSFORMS):
            floor = transform(st.floor, t)
            frame = np.zeros((9, 9), bool)
            frame[: floor.shape[0], : floor.shape[1]] = floor
            key = frame.tobytes()
            if seen.setdefault(key, st.name) != st.name:
                raise AssertionError(f"{st.name} and {seen[key]} share a floor in some orientation")


def count_layouts(config: GeneratorConfig = GeneratorConfig()) -> LayoutCount:
    """Exact number of distinct solvable kitchens in the generator's space for `config`."""
    from cec.levels.heldout import heldout_levels
    from cec.levels.membership import in_space

    by_name = {st.name: st for st in base_structures()}
    structures = tuple(by_name[n] for n in config.structures)
    _check_floors_distinct(tuple(base_structures()))
    per = tuple(
        StructureCount(
            name=st.name,
            object_placements=count_object_placements(st, config),
            agent_placements=count_agent_placements(st),
            orientations=NUM_TRANSFORMS // symmetry_count(st),
        )
        for st in structures
    )
    heldout = sum(1 for _, lv in heldout_levels() if in_space(lv, config))
    return LayoutCount(per_structure=per, heldout_in_space=heldout)
