"""The exact layout count: the documented number, and a brute-force enumeration on reduced configs."""

from __future__ import annotations

import itertools

import jax
import jax.numpy as jnp
import numpy as np
import pytest

from cec.levels import Level, Tile
from cec.levels.counting import count_layouts
from cec.levels.generator import OBJECT_TILES, GeneratorConfig
from cec.levels.solvability import check
from cec.levels.structures import NUM_TRANSFORMS, base_structures, transform

#: The documented size of the default generator's space (docs/generator.md).
DOCUMENTED_TOTAL = 163_906_694_314_034_832
PAPER_CLAIM = 1.16e17


def test_default_space_matches_the_documented_count_and_the_paper_claim() -> None:
    count = count_layouts(GeneratorConfig())
    assert count.total == DOCUMENTED_TOTAL
    assert count.total >= PAPER_CLAIM
    assert count.heldout_in_space == 105  # every held-out kitchen lies in the space; it is excluded
    assert count.emittable == DOCUMENTED_TOTAL - 105


def brute_force(name: str, config: GeneratorConfig) -> int:
    """Enumerates every placement of one object of each kind on reachable counters and every agent
    placement, keeps what the flood-fill check calls solvable, applies all 8 transforms and counts the
    distinct 9x9 levels."""
    st = next(s for s in base_structures() if s.name == name)
    h, w = st.shape
    reach = list(zip(*np.nonzero(st.reachable), strict=True))
    floor = list(zip(*np.nonzero(st.floor), strict=True))
    if st.n_regions == 2:
        pairs = [(a, b) for a in floor for b in floor if {st.regions[a], st.regions[b]} == {1, 2}]
    else:
        pairs = [(a, b) for a in floor for b in floor if a != b]
    base = np.where(st.floor, Tile.FLOOR, Tile.COUNTER).astype(np.uint8)
    kitchens = []
    for cells in itertools.permutations(reach, 4):
        k = base.copy()
        for cell, tile in zip(cells, OBJECT_TILES, strict=True):
            k[cell] = tile
        kitchens.append(k)
    kitchens_arr = np.stack(kitchens)  # (P, h, w)

    # solvability (independent of the transform, an isometry): one check per (objects, agents)
    grids = np.full((len(kitchens_arr), 9, 9), Tile.COUNTER, np.uint8)
    grids[:, :h, :w] = kitchens_arr
    p_idx, a_idx = np.meshgrid(np.arange(len(kitchens_arr)), np.arange(len(pairs)), indexing="ij")
    agents = np.asarray(pairs, np.int32)[a_idx.reshape(-1)]
    levels = Level(
        grid=jnp.asarray(grids[p_idx.reshape(-1)]),
        agent_pos=jnp.asarray(agents),
        agent_dir=jnp.zeros((agents.shape[0], 2), jnp.int32),
        size=jnp.tile(jnp.asarray([h, w], jnp.int32), (agents.shape[0], 1)),
    )
    solvable = np.asarray(jax.jit(jax.vmap(check))(levels).solvable)
    keep_p, keep_a = p_idx.reshape(-1)[solvable], a_idx.reshape(-1)[solvable]

    seen = set()
    for t in range(NUM_TRANSFORMS):
        moved = np.stack([transform(k, t) for k in kitchens_arr])
        oh, ow = moved.shape[1:]
        frame = np.full((len(moved), 9, 9), Tile.COUNTER, np.uint8)
        frame[:, :oh, :ow] = moved
        # where each kitchen cell lands under transform t
        index = transform(np.arange(h * w).reshape(h, w), t)
        dest = {int(v): (r, c) for (r, c), v in np.ndenumerate(index)}
        moved_pairs = [(dest[a[0] * w + a[1]], dest[b[0] * w + b[1]]) for a, b in pairs]
        for p, a in zip(keep_p, keep_a, strict=True):
            seen.add((frame[p].tobytes(), moved_pairs[a]))
    return len(seen)


ONE_EACH = {"onion_piles": (1, 1), "plate_piles": (1, 1), "pots": (1, 1), "goals": (1, 1)}


@pytest.mark.parametrize("name", ["forced_coord", "cramped_room"])
def test_count_matches_brute_force_on_reduced_configs(name: str) -> None:
    config = GeneratorConfig(structures=(name,), exclude_heldout=False, **ONE_EACH)  # type: ignore[arg-type]
    counted = count_layouts(config).total
    assert brute_force(name, config) == counted
