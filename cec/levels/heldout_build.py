"""Rebuilds or checks the frozen validation and test files (`cec.levels.heldout`): draws their generated
kitchens from fixed seeds with today's generator and converts the kitchens people drew for overcooked-ai.

    python -m cec.levels.heldout_build          # exit 0 when data/heldout.txt and data/test.txt still match
    python -m cec.levels.heldout_build --write  # rewrite them (changes the evaluation sets: breaking)

The drawn kitchens come from an installed overcooked-ai (the `peers` extra; its layout files are read as
data, the package is not imported). Without it the check covers the generated kitchens only.
"""

from __future__ import annotations

import argparse
import re
from pathlib import Path

import jax
import jax.numpy as jnp
import numpy as np

from cec.levels.ascii import from_ascii, to_ascii
from cec.levels.classic import classic_levels
from cec.levels.fingerprint import content_hash, fingerprint, fingerprint_host
from cec.levels.generator import GeneratorConfig, generate_with_info
from cec.levels.heldout import (
    DATA,
    DRAWN_PREFIX,
    HELDOUT_SEED_BASE,
    NUM_GENERATED,
    TEST2_DATA,
    TEST2_SEED_BASE,
    TEST_DATA,
    TEST_SEED_BASE,
    heldout_levels,
    test_levels,
)
from cec.levels.level import Level, LevelError
from cec.levels.overcooked_ai import package_dir
from cec.levels.solvability import validate_solvable

#: overcooked-ai layouts that are the classic five or variants of them (other orders, one player).
CLASSIC_VARIANTS = frozenset(
    {"asymmetric_advantages", "coordination_ring", "counter_circuit", "counter_circuit_o_1order",
     "cramped_room", "cramped_room_o_3orders", "cramped_room_single", "forced_coordination"}
)  # fmt: skip
#: overcooked-ai's layout characters -> ours (`cec.levels.ascii`): X counter, D dish pile, S serving window.
_DRAWN_FROM, _DRAWN_TO = "XODPS 12", "WOBPX 01"
_GRID = re.compile(r'"grid"\s*:\s*"""(.*?)"""', re.S)


def build_generated(prefix: str, seed_base: int, excluded: list[Level]) -> list[tuple[str, Level]]:
    """Draws 100 generated kitchens named `<prefix>NNN` from seeds `seed_base + i`, none of `excluded`."""
    fps = np.stack([fingerprint_host(lv) for lv in excluded])
    config = GeneratorConfig()
    out: list[tuple[str, Level]] = []
    seen = {tuple(row) for row in fps.tolist()}
    seed = seed_base
    while len(out) < NUM_GENERATED:
        level, _ = generate_with_info(jax.random.PRNGKey(seed), config, jnp.asarray(fps))
        seed += 1
        fp = tuple(np.asarray(fingerprint(level)).tolist())
        if fp in seen:
            continue
        seen.add(fp)
        out.append((f"{prefix}{len(out):03d}", jax.device_get(level)))
    return out


def overcooked_ai_layouts() -> Path | None:
    """`overcooked_ai_py/data/layouts` of the installed overcooked-ai (None without it)."""
    package = package_dir()
    path = package / "data" / "layouts" if package is not None else None
    return path if path is not None and path.is_dir() else None


def convert_drawn(text: str) -> Level:
    """One overcooked-ai layout file's kitchen as a `Level`; `LevelError` naming why it cannot be one (too
    large for the 9x9 frame, tomatoes, not two players, unsolvable)."""
    found = _GRID.search(text)
    if found is None:
        raise LevelError('no "grid" string')
    grid = found.group(1)
    rows = [row.strip() for row in grid.strip().split("\n")]
    if len(rows) > 9 or max(map(len, rows)) > 9:
        raise LevelError(f"{len(rows)}x{max(map(len, rows))} does not fit the 9x9 frame")
    unknown = set("".join(rows)) - set(_DRAWN_FROM)
    if unknown:
        tomato = " (T: a tomato pile)" if "T" in unknown else ""
        raise LevelError(f"characters this game has no tile for: {sorted(unknown)}{tomato}")
    level = from_ascii("\n".join(row.translate(str.maketrans(_DRAWN_FROM, _DRAWN_TO)) for row in rows))
    problems = validate_solvable(level)
    if problems:
        raise LevelError("; ".join(problems))
    return level


def build_drawn(
    layouts: Path, excluded: list[tuple[str, Level]]
) -> tuple[list[tuple[str, Level]], dict[str, str]]:
    """The drawn kitchens of `layouts` (sorted by name) and {layout: why it was left out}."""
    seen = {content_hash(lv): name for name, lv in excluded}
    out: list[tuple[str, Level]] = []
    skipped: dict[str, str] = {}
    for file in sorted(layouts.glob("*.layout")):
        if file.stem in CLASSIC_VARIANTS:
            skipped[file.stem] = "a classic kitchen or a variant of one"
            continue
        try:
            level = convert_drawn(file.read_text())
        except LevelError as err:
            skipped[file.stem] = str(err)
            continue
        if (same := seen.get(content_hash(level))) is not None:
            skipped[file.stem] = f"the same kitchen as {same}"
            continue
        seen[content_hash(level)] = f"{DRAWN_PREFIX}{file.stem}"
        out.append((seen[content_hash(level)], level))
    return out, skipped


def build_validation() -> list[tuple[str, Level]]:
    """The 100 generated validation kitchens (the classic ones excluded)."""
    return build_generated("generated_", HELDOUT_SEED_BASE, list(classic_levels().values()))


def build_test(layouts: Path | None) -> tuple[list[tuple[str, Level]], dict[str, str]]:
    """The test set: 100 generated kitchens (the validation set excluded), then the drawn ones."""
    validation = list(heldout_levels())
    generated = build_generated("test_", TEST_SEED_BASE, [lv for _, lv in validation])
    if layouts is None:
        return generated, {}
    drawn, skipped = build_drawn(layouts, validation + generated)
    return generated + drawn, skipped


def build_test2() -> list[tuple[str, Level]]:
    """The second test set: 100 generated kitchens, the validation and the first test set excluded."""
    excluded = [lv for _, lv in (*heldout_levels(), *test_levels())]
    return build_generated("test2_", TEST2_SEED_BASE, excluded)


def render_file(levels: list[tuple[str, Level]]) -> str:
    return "\n\n".join(f"# {name} {content_hash(lv)}\n{to_ascii(lv)}" for name, lv in levels) + "\n"


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description="Rebuild or check the frozen validation and test set files.")
    ap.add_argument("--write", action="store_true", help=f"rewrite {DATA}, {TEST_DATA} and {TEST2_DATA}")
    args = ap.parse_args(argv)
    layouts = overcooked_ai_layouts()
    test, skipped = build_test(layouts)
    for layout, why in skipped.items():
        print(f"overcooked-ai layout {layout!r} left out: {why}")
    files = {DATA: render_file(build_validation()), TEST_DATA: render_file(test)}
    files[TEST2_DATA] = render_file(build_test2())
    if args.write:
        if layouts is None:
            raise SystemExit("overcooked-ai is not installed (pip install -e '.[peers]'): the drawn test "
                             "kitchens come from its layout files")  # fmt: skip
        for path, text in files.items():
            path.parent.mkdir(parents=True, exist_ok=True)
            path.write_text(text)
            print(f"wrote {text.count('# ')} levels to {path}")
        return 0
    differ = []
    for path, text in files.items():
        recorded = path.read_text() if path.exists() else ""
        if layouts is None:  # only the generated kitchens can be checked
            recorded = "\n\n".join(b for b in recorded.split("\n\n") if not b.startswith(f"# {DRAWN_PREFIX}"))
            recorded += "" if recorded.endswith("\n") or not recorded else "\n"
        if recorded != text:
            differ.append(path.name)
    print(f"{', '.join(differ)} differ(s) from the seeds" if differ else "the set files match their seeds")
    return 1 if differ else 0


if __name__ == "__main__":
    raise SystemExit(main())
