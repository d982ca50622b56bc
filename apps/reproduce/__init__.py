"""`cec reproduce`: the paper's results end to end, one module per game.

dual_destination.py   `cec reproduce dual-destination` (docs/reproduce.md)
overcooked.py         `cec reproduce overcooked` (docs/reproduce_overcooked.md)
common.py             what both share (`cached_table`)
"""

from __future__ import annotations

from typing import Any

from apps.reproduce import dual_destination, overcooked


def add_subcommands(sub: Any) -> None:
    """Registers `cec reproduce dual-destination` and `cec reproduce overcooked` on the `cec` command."""
    rep = sub.add_parser("reproduce", help="reproduce the paper's results end to end (docs/reproduce.md)")
    rep_sub = rep.add_subparsers(dest="reproduce_command", required=True)
    dual_destination.add_subcommand(rep_sub)
    overcooked.add_subcommand(rep_sub)
