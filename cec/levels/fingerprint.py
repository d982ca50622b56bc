"""Identity of a kitchen by content: its 9x9 tiles and the two start cells, in either seat order (the start
facings do not count).

`content_hash` is a stable hex digest of that content (names a kitchen in files and on the wire);
`fingerprint` is a 64-bit JAX-side hash of the same content (jittable) that the generator compares against
to exclude the held-out set, and `fingerprint_host` the same values computed with NumPy.
"""

from __future__ import annotations

import hashlib

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.level import GRID_SIZE, Level

_W = np.random.default_rng(20250601).integers(1, 2**32, size=(2, GRID_SIZE * GRID_SIZE + 2), dtype=np.uint64)
_WEIGHTS = (_W | 1).astype(np.uint32)  # odd multipliers


def _content(level: Level) -> jax.Array:
    """int32[83]: the tiles, then the two start cells (flat index) in ascending order."""
    cells = level.agent_pos[..., 0] * GRID_SIZE + level.agent_pos[..., 1]
    return jnp.concatenate([level.grid.reshape(-1).astype(jnp.int32), jnp.sort(cells).astype(jnp.int32)])


def fingerprint(level: Level) -> jax.Array:
    """uint32[2]: a 64-bit hash of the level's content (jittable; vmap for batches)."""
    values = (_content(level) + 1).astype(jnp.uint32)
    return jnp.sum(values[None, :] * jnp.asarray(_WEIGHTS), axis=-1, dtype=jnp.uint32)


def fingerprint_host(level: Level) -> np.ndarray:
    """`fingerprint` computed with NumPy on the host (usable while JAX is tracing); the same values.

    Takes one level (-> uint32[2]) or a batch with leading axes (-> uint32[..., 2]).
    """
    grid = np.asarray(level.grid)
    lead = grid.shape[:-2]
    pos = np.asarray(level.agent_pos)
    cells = np.sort(pos[..., 0] * GRID_SIZE + pos[..., 1], axis=-1)
    values = (np.concatenate([grid.reshape(*lead, -1), cells], axis=-1) + 1).astype(np.uint32)
    return (values[..., None, :] * _WEIGHTS).sum(-1, dtype=np.uint32)  # uint32 arithmetic wraps as in JAX


def content_hash(level: Level) -> str:
    """A stable 16-hex-digit digest of one level's content (tiles and start cells, seat order ignored)."""
    return hashlib.sha256(np.asarray(_content(level), np.int32).tobytes()).hexdigest()[:16]
