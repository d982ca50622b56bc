"""Rebuilds or checks the frozen held-out file (`cec.levels.heldout`): draws the 100 generated held-out
kitchens from their fixed seeds with today's generator.

    python -m cec.levels.heldout_build           # exit 0 when data/heldout.txt still matches its seeds
    python -m cec.levels.heldout_build --write   # rewrite it (changes the held-out set: a breaking change)
"""

from __future__ import annotations

import argparse

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.ascii import to_ascii
from cec.levels.classic import classic_levels
from cec.levels.fingerprint import content_hash, fingerprint, fingerprint_host
from cec.levels.generator import GeneratorConfig, generate_with_info
from cec.levels.heldout import DATA, HELDOUT_SEED_BASE, NUM_GENERATED
from cec.levels.level import Level


def build_generated() -> list[tuple[str, Level]]:
    """Draws the 100 generated held-out kitchens from their fixed seeds (the classic ones excluded)."""
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
