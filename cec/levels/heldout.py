"""The held-out evaluation set: the 5 classic kitchens and 100 generated ones, defined once, here.

The 100 generated kitchens were drawn by `generate` (default config, the classic kitchens excluded) from
the keys `PRNGKey(HELDOUT_SEED_BASE + i)`, i = 0..99, and are frozen in `data/heldout.txt`, so the set
never changes when the generator does (`python -m cec.levels.heldout --write` rebuilds the file;
`tests/unit/test_heldout.py` checks the file still matches its seeds).

Identity of a kitchen is its content: the 9x9 tiles and the two start cells, in either seat order (the
start facings do not count). `content_hash` is a stable hex digest of that; `fingerprint` is a 64-bit
JAX-side hash of the same content that the generator compares against to exclude the set.
"""

from __future__ import annotations

import argparse
import hashlib
from functools import cache
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.ascii import from_ascii, to_ascii
from cec.levels.classic import classic_levels
from cec.levels.level import GRID_SIZE, Level, stack_levels

DATA = Path(__file__).with_name("data") / "heldout.txt"
HELDOUT_SEED_BASE = 1_000_000
NUM_GENERATED = 100

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


def _parse(text: str) -> list[tuple[str, str, Level]]:
    out = []
    for block in text.strip().split("\n\n"):
        header, _, body = block.partition("\n")
        _, name, digest = header.split()
        out.append((name, digest, from_ascii(body)))
    return out


@cache
def heldout_levels() -> tuple[tuple[str, Level], ...]:
    """The 105 held-out kitchens as (name, level): the 5 classic ones, then generated_000..099."""
    with jax.ensure_compile_time_eval():  # may first run while the generator is being traced
        levels = list(classic_levels().items())
        if DATA.exists():
            for name, digest, level in _parse(DATA.read_text()):
                if content_hash(level) != digest:
                    raise ValueError(
                        f"{DATA}: {name} does not match its recorded hash {digest}; the file is corrupt"
                    )
                levels.append((name, level))
    return tuple(levels)


def heldout_batch() -> Level:
    """The held-out set as one batched `Level` (leading axis 105)."""
    return stack_levels([lv for _, lv in heldout_levels()])


@cache
def heldout_fingerprints() -> np.ndarray:
    """uint32[105, 2] fingerprints of the held-out set (what the generator excludes)."""
    return np.stack([fingerprint_host(lv) for _, lv in heldout_levels()])


def build_generated() -> list[tuple[str, Level]]:
    """Draws the 100 generated held-out kitchens from their fixed seeds (the classic ones excluded)."""
    from cec.levels.generator import GeneratorConfig, generate_with_info

    classic = np.stack([fingerprint_host(lv) for lv in classic_levels().values()])
    config = GeneratorConfig()
    out: list[tuple[str, Level]] = []
    seen = {tuple(row) for row in classic.tolist()}
    seed = HELDOUT_SEED_BASE
    while len(out) < NUM_GENERATED:
        level, _ = generate_with_info(jax.random.PRNGKey(seed), config, jnp.asarray(classic))
        seed += 1
        fp = tuple(np.asarray(fingerprint(level)).tolist())
        if fp in seen:
            continue
        seen.add(fp)
        out.append((f"generated_{len(out):03d}", jax.device_get(level)))
    return out


def render_file(levels: list[tuple[str, Level]]) -> str:
    return "\n\n".join(f"# {name} {content_hash(lv)}\n{to_ascii(lv)}" for name, lv in levels) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Rebuild or check the frozen held-out set file.")
    ap.add_argument("--write", action="store_true", help=f"rewrite {DATA}")
    args = ap.parse_args(argv)
    text = render_file(build_generated())
    if args.write:
        DATA.parent.mkdir(parents=True, exist_ok=True)
        DATA.write_text(text)
        print(f"wrote {NUM_GENERATED} levels to {DATA}")
        return 0
    same = DATA.exists() and DATA.read_text() == text
    print("held-out file matches its seeds" if same else "held-out file differs from its seeds")
    return 0 if same else 1


if __name__ == "__main__":
    raise SystemExit(main())
