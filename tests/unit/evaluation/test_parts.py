"""Scores by part of an evaluation set, read from the shipped seeds' committed validation table: the split
by kind adds up to the headline and the headline is the README's."""

from __future__ import annotations

from pathlib import Path

import pytest

from cec.evaluation.parts import part_scores, parts_markdown
from cec.evaluation.results import read_csv
from cec.levels.heldout import heldout_levels
from cec.levels.kinds import Kind

SHIPPED = Path(__file__).resolve().parents[3] / "benchmarks" / "results" / "overcooked" / "shipped"


def test_the_shipped_seeds_validation_parts() -> None:
    parts = part_scores(read_csv(SHIPPED / "heldout.csv"), "cec", dict(heldout_levels()))
    assert "classic" not in parts  # the table played only the generated kitchens: no empty part
    generated = parts["generated"]
    assert (generated.levels, generated.seeds) == (100, 4)
    assert generated.xp == pytest.approx(48.5, abs=0.05)  # the README's figure
    kinds = [parts[k.label] for k in Kind]
    assert sum(p.levels for p in kinds) == 100
    # each kind's pairs are means over its kitchens: the kitchen-weighted mean is the headline
    assert sum(p.xp * p.levels for p in kinds) / 100 == pytest.approx(generated.xp)
    assert parts[Kind.HANDOVER.label].xp < 15 < parts[Kind.BOTH_ALONE.label].xp
    assert "| hand-over needed | 23 |" in parts_markdown(parts)
