"""The kitchens kept out of training, defined once, here: the validation set and the test set.

* **Validation** (`heldout_levels`, the level set `heldout`, historically "the held-out set"): the 5
  classic kitchens and 100 generated ones (`generated_000..099`). Recipes and checkpoints are chosen on it.
* **Test** (`test_levels`, the level set `test`): 100 more generated kitchens (`test_000..099`) and the
  kitchens drawn by people for other Overcooked work that fit the 9x9 frame (overcooked-ai 1.1.0's layouts
  other than the classic five and their variants, named `drawn_<layout>`). Nothing is chosen on it: a
  release is evaluated there once, after it was chosen on validation (DESIGN.md rule 13).
* **Second test** (`test2_levels`, the level set `test2`): 100 more generated kitchens (`test2_000..099`),
  drawn for the first release the service made (the first test set had been read six times by then; it is
  reported beside it as reused). Excluded from training like the others from the day it was drawn.

Every read of a test set is recorded in `data/test_reads.csv` (`cec.levels.ledger`).

The generated kitchens were drawn by `generate` (default config) from the keys `PRNGKey(SEED_BASE + i)`,
the validation ones with the classic kitchens excluded, the test ones with the whole validation set
excluded (the second test set with the first excluded too), and they are frozen in `data/heldout.txt`,
`data/test.txt` and `data/test2.txt`, so the sets never change when the
generator does (`python -m cec.levels.heldout_build --write` rebuilds the files; `tests/unit/levels/
test_heldout.py` checks they still match their seeds). The generator excludes both sets
(`heldout_fingerprints`). Kitchens are identified by content (`cec.levels.fingerprint`).
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
TEST_DATA = Path(__file__).with_name("data") / "test.txt"
TEST2_DATA = Path(__file__).with_name("data") / "test2.txt"
HELDOUT_SEED_BASE = 1_000_000
TEST_SEED_BASE = 2_000_000
TEST2_SEED_BASE = 3_000_000
NUM_GENERATED = 100
DRAWN_PREFIX = "drawn_"


def _parse(text: str) -> list[tuple[str, str, Level]]:
    out = []
    for block in text.strip().split("\n\n"):
        header, _, body = block.partition("\n")
        _, name, digest = header.split()
        out.append((name, digest, from_ascii(body)))
    return out


def _frozen(path: Path) -> list[tuple[str, Level]]:
    """The kitchens of a frozen set file, each checked against its recorded hash."""
    levels = []
    if path.exists():
        for name, digest, level in _parse(path.read_text()):
            if content_hash(level) != digest:
                raise ValueError(
                    f"{path}: {name} does not match its recorded hash {digest}; the file is corrupt"
                )
            levels.append((name, level))
    return levels


@cache
def heldout_levels() -> tuple[tuple[str, Level], ...]:
    """The 105 validation kitchens as (name, level): the 5 classic ones, then generated_000..099."""
    with jax.ensure_compile_time_eval():  # may first run while the generator is being traced
        return tuple([*classic_levels().items(), *_frozen(DATA)])


@cache
def test_levels() -> tuple[tuple[str, Level], ...]:
    """The test kitchens as (name, level): test_000..099, then the drawn ones (`drawn_<layout>`)."""
    with jax.ensure_compile_time_eval():
        return tuple(_frozen(TEST_DATA))


@cache
def test2_levels() -> tuple[tuple[str, Level], ...]:
    """The second test set as (name, level): test2_000..099."""
    with jax.ensure_compile_time_eval():
        return tuple(_frozen(TEST2_DATA))


def heldout_batch() -> Level:
    """The held-out set as one batched `Level` (leading axis 105)."""
    return stack_levels([lv for _, lv in heldout_levels()])


@cache
def heldout_fingerprints() -> np.ndarray:
    """uint32[E, 2] fingerprints of every kitchen kept out of training, validation and both test sets (what
    the generator excludes and the level server refuses)."""
    kept = (*heldout_levels(), *test_levels(), *test2_levels())
    return np.stack([fingerprint_host(lv) for _, lv in kept])
