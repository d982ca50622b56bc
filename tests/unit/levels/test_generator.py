"""The procedural generator: solvable by construction, never held-out, within bounds, well spread."""

from __future__ import annotations

import jax
import jax.numpy as jnp
import numpy as np
import pytest
from scipy import stats

from cec.config import ConfigError, load_config
from cec.envs import overcooked as oc
from cec.levels import Tile, unstack_levels, validate_level
from cec.levels.fingerprint import fingerprint
from cec.levels.generator import GeneratorConfig, generate, generate_batch, generate_with_info
from cec.levels.heldout import heldout_fingerprints
from cec.levels.membership import in_space
from cec.levels.solvability import check, flood
from cec.levels.structures import NUM_TRANSFORMS

CONFIG = GeneratorConfig()
N_LEVELS = 2_000_000
CHUNK = 1 << 17


@jax.jit
def _summarise(key: jax.Array) -> dict[str, jax.Array]:
    levels, info = jax.vmap(lambda k: generate_with_info(k, CONFIG))(jax.random.split(key, CHUNK))
    fps = jax.vmap(fingerprint)(levels)
    held = jnp.any(jnp.all(fps[:, None, :] == jnp.asarray(heldout_fingerprints())[None], -1), -1)
    counts = jnp.stack([jnp.sum(levels.grid == t, axis=(1, 2)) for t in (2, 3, 4, 5)], axis=-1)
    return {
        "solvable": jnp.sum(jax.vmap(check)(levels).solvable),
        "heldout": jnp.sum(held),
        "count_min": counts.min(0),
        "count_max": counts.max(0),
        "structure": jnp.bincount(info.structure, length=len(CONFIG.structures)),
        "transform": jnp.bincount(info.transform, length=NUM_TRANSFORMS),
    }


@pytest.mark.slow
def test_two_million_levels_are_solvable_never_heldout_within_bounds_and_uniform() -> None:
    chunks = [jax.device_get(_summarise(jax.random.PRNGKey(100 + i))) for i in range(-(-N_LEVELS // CHUNK))]
    total = CHUNK * len(chunks)
    assert total >= N_LEVELS
    assert sum(int(c["solvable"]) for c in chunks) == total
    assert sum(int(c["heldout"]) for c in chunks) == 0
    lows = np.min([c["count_min"] for c in chunks], axis=0)
    highs = np.max([c["count_max"] for c in chunks], axis=0)
    assert lows.tolist() == [lo for lo, _ in CONFIG.bounds]
    assert highs.tolist() == [hi for _, hi in CONFIG.bounds]
    for key, k in (("structure", len(CONFIG.structures)), ("transform", NUM_TRANSFORMS)):
        observed = np.sum([c[key] for c in chunks], axis=0)
        assert (observed > 0).all() and observed.shape == (k,)
        p = stats.chisquare(observed).pvalue  # expected: uniform
        assert p > 1e-4, f"{key} frequencies {observed.tolist()} are not uniform (p={p:.2g})"


def test_generated_levels_are_valid_levels_in_the_counted_space() -> None:
    batch = generate_batch(jax.random.PRNGKey(5), 200)
    for level in unstack_levels(jax.device_get(batch)):
        validate_level(level)
        assert in_space(level, CONFIG)


def test_every_generated_level_runs_in_the_env() -> None:
    batch = generate_batch(jax.random.PRNGKey(6), 64)
    keys = jax.random.split(jax.random.PRNGKey(0), 64)
    _, state = jax.vmap(oc.reset, in_axes=(0, 0, None))(keys, batch, oc.EnvParams())
    out = jax.vmap(oc.step, in_axes=(0, 0, 0, None))(
        keys, state, jnp.full((64, 2), 5, jnp.int32), oc.EnvParams()
    )
    assert out.obs.shape == (64, 2, 9, 9, 26)


def test_exclusion_resamples_a_level_it_would_otherwise_emit() -> None:
    key = jax.random.PRNGKey(11)
    plain = generate(key, CONFIG.replace(exclude_heldout=False))
    excluded, info = generate_with_info(key, CONFIG, fingerprint(plain)[None])
    assert int(info.resamples) >= 1
    assert not np.array_equal(np.asarray(excluded.grid), np.asarray(plain.grid)) or not np.array_equal(
        np.sort(np.asarray(excluded.agent_pos), 0), np.sort(np.asarray(plain.agent_pos), 0)
    )


def test_seat_order_does_not_hide_a_heldout_level() -> None:
    level = oc.classic_level("cramped_room")
    swapped = level.replace(agent_pos=level.agent_pos[::-1])
    np.testing.assert_array_equal(np.asarray(fingerprint(level)), np.asarray(fingerprint(swapped)))


def test_generation_is_deterministic_per_key() -> None:
    a, b = generate(jax.random.PRNGKey(3)), generate(jax.random.PRNGKey(3))
    np.testing.assert_array_equal(np.asarray(a.grid), np.asarray(b.grid))
    np.testing.assert_array_equal(np.asarray(a.agent_pos), np.asarray(b.agent_pos))


def test_split_kitchens_get_one_agent_per_side_in_both_seat_orders() -> None:
    config = CONFIG.replace(structures=("forced_coord",))
    batch = jax.device_get(generate_batch(jax.random.PRNGKey(8), 400, config))
    assert np.all(np.asarray(jax.vmap(check)(batch).reasons) == 0)
    grid, pos = np.asarray(batch.grid), np.asarray(batch.agent_pos)
    rows = np.arange(400)
    assert np.all(grid[rows, pos[:, 0, 0], pos[:, 0, 1]] == Tile.FLOOR)
    assert np.all(grid[rows, pos[:, 1, 0], pos[:, 1, 1]] == Tile.FLOOR)
    # never in one region: a flood fill from seat 0 does not reach seat 1
    reach = jax.vmap(lambda g, p: flood(g == Tile.FLOOR, p[0]))(batch.grid, batch.agent_pos)
    assert not np.any(np.asarray(reach)[rows, pos[:, 1, 0], pos[:, 1, 1]])
    seat0_first = (pos[:, 0, 0] * 9 + pos[:, 0, 1]) < (pos[:, 1, 0] * 9 + pos[:, 1, 1])
    assert 0.35 < seat0_first.mean() < 0.65  # either seat on either side


def test_decoys_only_when_allowed() -> None:
    with_decoys = jax.device_get(
        generate_batch(jax.random.PRNGKey(9), 2000, CONFIG.replace(allow_decoys=True))
    )
    reports = jax.vmap(check)(with_decoys)
    assert np.any(np.asarray(reports.reasons) & 32)  # some levels carry unreachable decoys...
    assert np.all(np.asarray(jax.vmap(lambda lv: check(lv, True))(with_decoys).solvable))  # ...all solvable


@pytest.mark.parametrize(
    ("changes", "message"),
    [
        ({"structures": ("kitchen_sink",)}, "unknown structures"),
        ({"structures": ()}, "structures is empty"),
        ({"pots": (0, 2)}, "1 <= min <= max"),
        ({"goals": (3, 2)}, "1 <= min <= max"),
        ({"onion_piles": (4, 5), "plate_piles": (4, 5), "pots": (2, 2)}, "'cramped_room' has 10 counters"),
        ({"count_decay": 0.0}, "count_decay"),
        ({"structure_weights": (1.0, 2.0)}, "positive weight to each of the 5 structures"),
        ({"structure_weights": (1.0, 1.0, 0.0, 1.0, 1.0)}, "drop it from structures"),
    ],
)
def test_impossible_configs_are_rejected_when_built(changes: dict[str, object], message: str) -> None:
    with pytest.raises(ConfigError, match=message):
        GeneratorConfig(**changes)  # type: ignore[arg-type]


def test_config_loads_from_yaml_overrides() -> None:
    config = load_config(GeneratorConfig, None, ["pots=[1, 2]", "structures=[cramped_room, forced_coord]"])
    assert config.pots == (1, 2) and config.structures == ("cramped_room", "forced_coord")
    with pytest.raises(ConfigError, match="forced_coord"):
        load_config(
            GeneratorConfig, None, ["structures=[forced_coord]", "onion_piles=[6, 6]", "plate_piles=[5, 5]"]
        )


def test_structure_weights_draw_the_structures_in_proportion() -> None:
    """Counter Circuit weighted 3 of 7 is drawn about three times as often as each other structure; every
    kitchen is still one the uniform generator can draw (same structures, transforms and objects)."""
    config = GeneratorConfig(structure_weights=(1.0, 1.0, 3.0, 1.0, 1.0))
    keys = jax.random.split(jax.random.PRNGKey(3), 4096)
    levels, info = jax.vmap(lambda k: generate_with_info(k, config))(keys)
    shares = np.bincount(np.asarray(info.structure), minlength=5) / len(keys)
    np.testing.assert_allclose(shares, np.array([1, 1, 3, 1, 1]) / 7, atol=0.03)
    assert np.all(np.asarray(jax.vmap(check)(levels).solvable))


def test_generate_batch_equals_vmapped_generate() -> None:
    keys = jax.random.split(jax.random.PRNGKey(21), 64)
    batch = generate_batch(jax.random.PRNGKey(21), 64)
    single = jax.vmap(generate, in_axes=(0, None))(keys, CONFIG)
    np.testing.assert_array_equal(np.asarray(batch.grid), np.asarray(single.grid))
    np.testing.assert_array_equal(np.asarray(batch.agent_pos), np.asarray(single.agent_pos))
