"""Scores by part of an evaluation set: its generated kitchens, those by kind (`cec.levels.kinds`), its
named kitchens together and each. Every report and benchmark that splits a table by kitchen kind reads it
here, so the split and its figures are the same everywhere.

    parts = part_scores(read_csv("heldout.csv"), "cec", dict(heldout_levels()))
    for name, part in parts.items(): print(name, part.levels, part.xp, part.xp_se, part.sp)
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import NamedTuple

import numpy as np

from cec.evaluation import analysis as an
from cec.evaluation.markdown import pm, table
from cec.evaluation.results import EpisodeTable
from cec.evaluation.stats import crossplay_estimate, sem
from cec.levels.kinds import validation_parts
from cec.levels.level import Level


class PartScore(NamedTuple):
    """One algorithm's seeds with each other on one part: `levels` played, cross-play over pairs of two
    different seeds with its jackknife standard error over seeds, self-play with its standard error."""

    levels: int
    xp: float
    xp_se: float
    sp: float
    sp_se: float
    seeds: int


def part_scores(table: EpisodeTable, algorithm: str, levels: Mapping[str, Level]) -> dict[str, PartScore]:
    """{part: score} of `algorithm`'s seeds among themselves, for the parts of `levels` the table played."""
    own = table.select((table.algorithm_a == algorithm) & (table.algorithm_b == algorithm))
    played = set(own.level.astype(str))
    out = {}
    for part, names in validation_parts(levels).items():
        names = [n for n in names if n in played]
        if not names:
            continue
        m = an.seed_matrix(an.pair_level_scores(own, names), algorithm)
        est, sp = crossplay_estimate(m.values), np.diag(m.values)
        out[part] = PartScore(len(names), est.mean, est.se, float(sp.mean()), sem(sp), est.seeds)
    return out


def parts_markdown(parts: Mapping[str, PartScore]) -> str:
    """A Markdown table of `part_scores`."""
    rows = [[name, p.levels, pm(p.xp, p.xp_se), pm(p.sp, p.sp_se)] for name, p in parts.items()]
    return table(["part", "kitchens", "cross-play", "self-play"], rows)
