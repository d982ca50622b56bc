"""`cec reproduce`: the paper's results end to end, one command per game.

Every paper is a package with the same parts (`pipeline.PARTS`: modes, paper, plan, evaluate, summary,
report, command; `tests/unit/apps/test_reproduce_packages.py`), its numbers as data beside them:

pipeline.py              the skeleton every paper fills (plan, train, evaluate, summarise, report): a zoo's
                         spec, plan lines, training, loading its policies, `cached_table`, recorded training
                         and play times; seeds as units: `cec.evaluation.seeds`
dual_destination/        `cec reproduce dual-destination` (docs/reproduce.md; paper_dual_destination.yaml)
overcooked/              `cec reproduce overcooked` (docs/reproduce_overcooked.md; paper_overcooked.yaml)
paper_<game>.yaml        the paper's numbers each reproduction reports beside its own
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from apps.reproduce.dual_destination import command as dual_destination
from apps.reproduce.overcooked import command as overcooked

if TYPE_CHECKING:
    import argparse


def add_subcommands(sub: argparse._SubParsersAction[argparse.ArgumentParser]) -> None:
    """Registers `cec reproduce dual-destination` and `cec reproduce overcooked` on the `cec` command."""
    rep = sub.add_parser("reproduce", help="reproduce the paper's results end to end (docs/reproduce.md)")
    rep_sub = rep.add_subparsers(dest="reproduce_command", required=True)
    dual_destination.add_subcommand(rep_sub)
    overcooked.add_subcommand(rep_sub)
