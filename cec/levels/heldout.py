"""The held-out evaluation set: the 5 classic kitchens and 100 generated ones, defined once, here.

The 100 generated kitchens were drawn by `generate` (default config, the classic kitchens excluded) from
the keys `PRNGKey(HELDOUT_SEED_BASE + i)`, i = 0..99, and are frozen in `data/heldout.txt`, so the set
never changes when the generator does (`python -m cec.levels.heldout_build --write` rebuilds the file;
`tests/unit/levels/test_heldout.py` checks the file still matches its seeds). Kitchens are identified by
content (`cec.levels.fingerprint`).
"""

from __future__ import annotations

from functools import cache
from pathlib import Path

import jax
import numpy as np

from cec.levels.ascii import from_ascii
from cec.levels.classic import classic_levels
from cec.levels.fingerprint import content_hash, fingerprint_host
from cec.levels.level import Level, stack_levels

DATA = Path(__file__).with_name("data") / "heldout.txt"
HELDOUT_SEED_BASE = 1_000_000
NUM_GENERATED = 100


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
