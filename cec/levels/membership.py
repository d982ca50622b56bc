"""Whether a given level lies in the generator's space (host-side, for counting and for tests)."""

from __future__ import annotations

import numpy as np

from cec.levels.generator import OBJECT_TILES, GeneratorConfig
from cec.levels.level import Level, Tile
from cec.levels.solvability import validate_solvable
from cec.levels.structures import NUM_TRANSFORMS, base_structures, transform


def in_space(level: Level, config: GeneratorConfig) -> bool:
    """True if `generate` with `config` could produce `level` (ignoring held-out exclusion and facings)."""
    grid = np.asarray(level.grid)
    h, w = (int(v) for v in np.asarray(level.size))
    kitchen = grid[:h, :w]
    if np.any(
        np.delete(grid.reshape(-1), (np.arange(h)[:, None] * 9 + np.arange(w)).reshape(-1)) != Tile.COUNTER
    ):
        return False
    floor = kitchen == Tile.FLOOR
    by_name = {st.name: st for st in base_structures()}
    for name in config.structures:
        st = by_name[name]
        for t in range(NUM_TRANSFORMS):
            t_floor = transform(st.floor, t)
            if t_floor.shape != floor.shape or not np.array_equal(t_floor, floor):
                continue
            reachable = transform(st.reachable, t)
            allowed = reachable | (transform(st.decoy, t) if config.allow_decoys else False)
            objects = ~floor & (kitchen != Tile.COUNTER)
            if np.any(objects & ~allowed):
                return False
            for tile, (lo, hi) in zip(OBJECT_TILES, config.bounds, strict=True):
                n = int(np.sum(kitchen == tile))
                if not lo <= n <= hi or not np.any((kitchen == tile) & reachable):
                    return False
            cells = [tuple(p) for p in np.asarray(level.agent_pos).tolist()]
            if len(set(cells)) != 2 or any(
                not (0 <= r < h and 0 <= c < w) or not floor[r, c] for r, c in cells
            ):
                return False
            if st.n_regions == 2:
                regions = transform(st.regions, t)
                if {int(regions[r, c]) for r, c in cells} != {1, 2}:
                    return False
            return not validate_solvable(level, config.allow_decoys)
    return False
