"""`cec reproduce`: the paper's results end to end, one command per game.

pipeline.py           the skeleton both fill (plan, train, evaluate, summarise, report): a zoo's spec,
                      plan lines, training, loading its policies, `cached_table`, recorded training and
                      play times; seeds as units: `cec.evaluation.seeds`
dual_destination.py   `cec reproduce dual-destination` (docs/reproduce.md): its plan, training,
                      evaluation and the command
dd_modes.py           its versions (quick, full, paper): presets, seeds, budgets, measured speeds
dd_paper.py           the paper's numbers and orderings (paper_dual_destination.yaml), the ablations
dd_summary.py         the scores and ordering tests computed from the runs
dd_reasons.py         why a number differs from the paper's or an ordering fails, from the same seeds
dd_report.py          its report (report.md, summary.json, bar plots, learning curves)
overcooked.py         `cec reproduce overcooked` (docs/reproduce_overcooked.md; paper_overcooked.yaml)
"""

from __future__ import annotations

from typing import Any

from apps.reproduce import overcooked
from apps.reproduce.dual_destination import command as dual_destination


def add_subcommands(sub: Any) -> None:
    """Registers `cec reproduce dual-destination` and `cec reproduce overcooked` on the `cec` command."""
    rep = sub.add_parser("reproduce", help="reproduce the paper's results end to end (docs/reproduce.md)")
    rep_sub = rep.add_subparsers(dest="reproduce_command", required=True)
    dual_destination.add_subcommand(rep_sub)
    overcooked.add_subcommand(rep_sub)
