"""Cross-play and self-play of one algorithm's seeds on every part of validation and test, from the tables
`evaluate.sh` writes (heldout, classic and test, with the extension given: `.csv` or `.csv.bz2`):

    .venv/bin/python benchmarks/results/overcooked/shipped/parts.py DIR [EXT] [ALGORITHM] > DIR/parts.md
"""

from __future__ import annotations

import sys
from pathlib import Path

from cec.evaluation.parts import part_scores, parts_markdown
from cec.evaluation.results import read_csv
from cec.levels.heldout import heldout_levels, test_levels


def main(folder: Path, ext: str = ".csv", algorithm: str = "cec") -> None:
    sets = (
        ("validation (the set that chose the checkpoint)", ("heldout", "classic"), heldout_levels()),
        ("test (nothing chosen on it)", ("test",), test_levels()),
    )
    for title, tables, levels in sets:
        table = read_csv([folder / f"{t}{ext}" for t in tables])
        print(f"## {title}\n\n{parts_markdown(part_scores(table, algorithm, dict(levels)))}\n")


if __name__ == "__main__":
    main(Path(sys.argv[1]), *sys.argv[2:])
